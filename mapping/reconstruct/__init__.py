"""Beyond the paper: inverting the back-projection (``build-map --method inverse``).

The paper's map G (eq. 5) is a back-projection, the *adjoint* of a linear forward model that
predicts heat maps from reflectors. This package solves that model instead: non-negative,
l1-regularised least squares by FISTA over strengths of specular wall elements (O normal-axis
orientations per cell), so observations compete for explanations and a mirror ghost that
predicts echoes the other poses did not hear loses to the true wall.

Entry points: `reconstruct_inverse` (heat maps + poses -> G and solver info) with its
parameters `InverseParams`; the pieces: `observations_from_heatmaps` / `pool_heatmap`
(floor-removed heat maps max-pooled into range bins, `Observations`), `build_operator`
(`Operator`, ``y = A x``; `backproject_observations` is its adjoint summed over
orientations, the paper's back-projection), the free-space and occlusion constraints
(`free_radii`, `forbidden_unknowns`, `occluded`), `operator_norm_sq`, `fista_nonneg_l1`,
`prune_speckle`.

Notes
-----
Private modules: ``_observations`` (parameters, pooled observations, the Doppler point spread
`doppler_kappa`), ``_operator`` (the sparse forward model and its constraints), ``_solver``
(FISTA and the reconstruction).
"""

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
