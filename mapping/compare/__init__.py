"""The FDTD reference against the image-source engine (paper Sec. 3 against Sec. 2).

The two engines hear the same scene differently in two known ways, and this package accounts
for both: (1) grid dispersion and band -- `render_paths` rebuilds an image-source block path by
path from its path table, band-limited like the FDTD's source (`grid_band`) and given each
path's predicted dispersion along its own direction (`dispersion_phase`, `fdtd_length_m`);
(2) paths the image-source model leaves out -- diffraction at free wall ends
(`specular_path`, `edge_diffraction_paths`; geometry only, after Keller; the wall ends and
wedges themselves, and the image-source engine's diffraction term, are in
`mapping.simulate.ism`).
The geometric truth of specular paths (`specular_echo`, `valid_wall_sequences`) is shared by
the benchmark (``benchmarks/fdtd_paper.py``) and the tests.

Entry points: `compare_block` (both engines on one block -> `BlockComparison`),
`comparison_heatmaps`, `residual_waveform`, `correlation`; heat-map bookkeeping:
`heatmap_angle_rad` (the angle a path shows in the eq. 1 heat map), `local_maxima`,
`window_peak`, `nearest_prediction`; waveform agreement: `band_limited`, `residual_energy`,
`lag_s`.

Notes
-----
Private modules: ``_block`` (the comparison of one block), ``_geometry`` (specular and
edge-diffracted paths), ``_paths`` (band, dispersion and heat-map bookkeeping).
"""

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
    band_limited,
    dispersion_phase,
    fdtd_length_m,
    grid_band,
    heatmap_angle_rad,
    lag_s,
    local_maxima,
    render_paths,
    residual_energy,
    window_peak,
)

__all__ = [
    "BlockComparison",
    "EdgePath",
    "band_limited",
    "GeometricEcho",
    "compare_block",
    "comparison_heatmaps",
    "correlation",
    "dispersion_phase",
    "edge_diffraction_paths",
    "edge_echo_range_m",
    "fdtd_length_m",
    "grid_band",
    "heatmap_angle_rad",
    "image_point",
    "lag_s",
    "leg_blocked",
    "local_maxima",
    "nearest_prediction",
    "path_angles_rad",
    "path_length_m",
    "render_paths",
    "residual_energy",
    "residual_waveform",
    "retarded",
    "specular_echo",
    "specular_path",
    "valid_wall_sequences",
    "window_peak",
]
