"""TODO docstring."""

from __future__ import annotations

from mapping.compare._block import (
    BlockComparison,
    compare_block,
    comparison_heatmaps,
    correlation,
    residual_waveform,
)
from mapping.compare._geometry import (
    EdgePath,
    GeometricEcho,
    edge_diffraction_paths,
    edge_echo_range_m,
    free_wall_ends,
    image_point,
    leg_blocked,
    nearest_prediction,
    path_angles_rad,
    path_length_m,
    retarded,
    specular_echo,
    specular_path,
    valid_wall_sequences,
)
from mapping.compare._paths import (
    dispersion_phase,
    fdtd_length_m,
    grid_band,
    heatmap_angle_rad,
    local_maxima,
    render_paths,
    window_peak,
)

__all__ = [
    "BlockComparison",
    "EdgePath",
    "GeometricEcho",
    "compare_block",
    "comparison_heatmaps",
    "correlation",
    "dispersion_phase",
    "edge_diffraction_paths",
    "edge_echo_range_m",
    "fdtd_length_m",
    "free_wall_ends",
    "grid_band",
    "heatmap_angle_rad",
    "image_point",
    "leg_blocked",
    "local_maxima",
    "nearest_prediction",
    "path_angles_rad",
    "path_length_m",
    "render_paths",
    "residual_waveform",
    "retarded",
    "specular_echo",
    "specular_path",
    "valid_wall_sequences",
    "window_peak",
]
