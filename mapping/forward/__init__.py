"""Forward model of the heat map: the specular echoes walls give, and the eq. 1 map they make.

Given walls (segments with a reflection strength), a pose, a speed and the `SonarConfig`,
`echoes` lists the specular image-source paths a monostatic moving sonar hears at the block
centre (range, Doppler cosine, folded heat-map angle, amplitude, walls, specular points,
arrival bearing); `render_heatmap` turns an echo list into the heat map eq. 1 would give, on
the same axes as `mapping.heatmap.doppler_heatmap`, with the point-spread function derived
from the signal (`point_spread`, `drift_samples`: no blur parameter); `predicted_heatmap`
does both. `echoes_batch` gives many poses in one call (numba, parallel over poses) for the
particle filter. `required_order` says how many reflection orders a scene needs;
`match_echoes` and `heatmap_correlation` check a prediction against a measured map.
A fitted map's near-right corners are heard once at their vertex when
``ForwardParams.right_corner_tol_deg`` > 0 (`right_corners`, `shared_vertices`,
`vertex_paths`).

Notes
-----
Private modules: ``_echoes`` (`WallSet`, `ForwardParams`, `Echoes`, `EchoBatch`, the
wrappers), ``_render`` (point-spread tables and rendering), ``_order`` (`required_order`),
``_compare`` (peak matching, correlation), ``_corners`` (right corners at the vertex),
``_vertical`` (floor and ceiling: `vertical_images`, and `with_vertical` adding every
echo's copies through them),
``_kernels`` (the numba kernels: path enumeration
and tracing, rendering; their numpy twins are in ``tests/mapping/forward/naive.py``).
"""

from __future__ import annotations

from mapping.forward._compare import (
    echo_cells,
    heatmap_correlation,
    local_maxima,
    match_echoes,
)
from mapping.forward._corners import right_corners, shared_vertices, vertex_paths
from mapping.forward._echoes import (
    DEFAULT_PARAMS,
    MAX_ORDER,
    SPREADING_POWER,
    EchoBatch,
    Echoes,
    ForwardParams,
    WallSet,
    echoes,
    echoes_batch,
)
from mapping.forward._order import DEFAULT_LEVEL, required_order
from mapping.forward._render import (
    COINCIDENT_COS,
    COINCIDENT_RANGE,
    PSF_HALF_WIDTH,
    PSF_UPSAMPLE,
    drift_samples,
    point_spread,
    predicted_heatmap,
    psf_tables,
    render_heatmap,
)
from mapping.forward._vertical import vertical_images, with_vertical

__all__ = [
    "COINCIDENT_COS",
    "COINCIDENT_RANGE",
    "DEFAULT_LEVEL",
    "DEFAULT_PARAMS",
    "MAX_ORDER",
    "PSF_HALF_WIDTH",
    "PSF_UPSAMPLE",
    "SPREADING_POWER",
    "EchoBatch",
    "Echoes",
    "ForwardParams",
    "WallSet",
    "drift_samples",
    "echo_cells",
    "echoes",
    "echoes_batch",
    "heatmap_correlation",
    "local_maxima",
    "match_echoes",
    "point_spread",
    "predicted_heatmap",
    "psf_tables",
    "render_heatmap",
    "required_order",
    "vertical_images",
    "with_vertical",
    "right_corners",
    "shared_vertices",
    "vertex_paths",
]
