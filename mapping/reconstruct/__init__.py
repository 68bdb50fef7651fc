"""TODO docstring."""

from __future__ import annotations

from mapping.reconstruct._observations import (
    InverseParams,
    Observations,
    concat_observations,
    doppler_kappa,
    observations_from_heatmaps,
    pool_heatmap,
)
from mapping.reconstruct._operator import (
    Operator,
    backproject_observations,
    build_operator,
    forbidden_unknowns,
    free_radii,
    occluded,
    operator_norm_sq,
)
from mapping.reconstruct._solver import (
    fista_nonneg_l1,
    prune_speckle,
    reconstruct_inverse,
)

__all__ = [
    "InverseParams",
    "Observations",
    "Operator",
    "backproject_observations",
    "build_operator",
    "concat_observations",
    "doppler_kappa",
    "fista_nonneg_l1",
    "forbidden_unknowns",
    "free_radii",
    "observations_from_heatmaps",
    "occluded",
    "operator_norm_sq",
    "pool_heatmap",
    "prune_speckle",
    "reconstruct_inverse",
]
