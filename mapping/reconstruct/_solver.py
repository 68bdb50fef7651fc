"""Beyond the paper: invert the back-projection instead of only summing it.

The paper's map G (eq. 5) is a back-projection: every cell reads the heat map at its range and
|angle| from each pose. That is the *adjoint* of a linear forward model that predicts heat maps
from reflectors on the grid. Inverting the forward model (non-negative, l1-regularised least
squares, solved with FISTA) lets the observations compete for explanations: a mirror ghost
that explains one pose's echo but predicts echoes the other poses did not see loses against
the true wall, which explains all of them.

Forward model (specular wall elements)
    A wall reflects specularly: a wall element at cell ``c`` whose normal axis has direction
    ``psi`` echoes back to the sonar only from poses on (or near) its normal line. The
    unknowns are non-negative strengths ``x[o, c]`` of elements at cell ``c`` with normal axis
    ``psi_o = pi * o / O`` (an axis, so ``o`` spans only pi). Seen from pose ``k`` at range
    ``r`` and bearing ``beta``, the element adds ``w_o(beta) x[o, c]`` to the heat-map bin
    ``(n_theta, n_r)`` with ``n_theta = round(|wrap(beta - phi_k)| N / pi)`` (the same row as
    eqs. 2-3, so the mirror ambiguity is in the model) and ``n_r = round(r / bin_m)``, where
    ``w_o`` linearly interpolates ``beta mod pi`` between neighbouring orientations
    (``sum_o w_o = 1``). A corner, which retro-reflects to every pose, is a cell with many
    orientations. The isotropic point-reflector model (one unknown per cell seen from every
    pose) is the special case ``O = 1``; it is wrong for specular walls, which echo only
    from their perpendicular foot.
Observations
    Each block's heat map after the per-block floor removal of :mod:`mapping.grid`,
    max-pooled over range bins of ``bin_m`` (default: the map resolution), up to
    ``radius_m``: ``y_k[n_theta, n_r]``.
Adjoint
    ``A^T y`` summed over orientations is the paper's back-projection of the pooled heat maps
    (nearest row, nearest range bin, exact pose): tested.
Solver
    ``min_x 0.5 ||A x - y||^2 + lam ||x||_1`` subject to ``x >= 0``, FISTA with step
    ``1 / ||A||^2`` (power iteration), ``lam = lam_rel * max(A^T y)``. Only cells whose
    back-projection exceeds ``active_fraction`` of its 99th percentile are unknowns (the rest
    have no evidence and stay 0). The map is ``G = sum_o x[o]``, pruned below
    ``prune_fraction`` of its 99th percentile.

Modules: :mod:`mapping.reconstruct_observations` (parameters, pooled observations),
:mod:`mapping.reconstruct_operator` (the forward operator and the free-space and occlusion
constraints); this module holds the solver (FISTA, reweighting, occlusion rounds, pruning)
and re-exports the public names of the other two.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from mapping.grid import GridExtent, GridParams
from mapping.reconstruct._observations import (
    InverseParams,
    Observations,
)
from mapping.reconstruct._operator import (
    Operator,
    backproject_observations,
    build_operator,
    forbidden_unknowns,
    free_radii,
    operator_norm_sq,
)

FloatArray = NDArray[np.float64]


def fista_nonneg_l1(op: Operator, y: FloatArray, lam: float | FloatArray, iterations: int,
                    lipschitz: float, x0: FloatArray | None = None
                    ) -> tuple[FloatArray, list[float]]:
    """FISTA for ``min 0.5 ||A x - y||^2 + lam sum(x)`` with ``x >= 0``.

    Returns the solution and the objective every 10th iteration (and the last).
    """
    x = np.zeros((op.orientations, op.cells.size)) if x0 is None else x0.copy()
    z = x.copy()
    t = 1.0
    step = 1.0 / lipschitz
    history = []
    for i in range(iterations):
        resid = op.forward(z) - y
        x_new = np.maximum(z - step * (op.adjoint(resid) + lam), 0.0)
        t_new = 0.5 * (1.0 + math.sqrt(1.0 + 4.0 * t * t))
        z = x_new + ((t - 1.0) / t_new) * (x_new - x)
        x, t = x_new, t_new
        if i % 10 == 0 or i == iterations - 1:
            history.append(0.5 * float(np.sum((op.forward(x) - y) ** 2))
                           + float(np.sum(lam * x)))
    return x, history


def _solve(obs: Observations, extent: GridExtent, cells: NDArray[np.int64],
           forbidden: NDArray[np.bool_], grid: GridParams, params: InverseParams,
           rng: np.random.Generator, walls_xy: FloatArray | None
           ) -> tuple[Operator, FloatArray, float, float, list[float]]:
    """Build the operator (with occluders if given) and solve (with reweighting rounds)."""
    op = build_operator(obs, extent, cells, params.orientations, grid.radius_m, walls_xy,
                        params.occlusion_margin_m)
    if forbidden.any():  # zero the columns: those unknowns stay at 0 under the solver
        allowed = sp.diags((~forbidden).ravel().astype(np.float64))
        op = Operator(sp.csr_matrix(op.A @ allowed), op.cells, op.orientations,
                      op.data_shape, op.map_shape)
    y = obs.Y
    lip = operator_norm_sq(op, rng) * 1.05
    lam = params.lam_rel * float(op.adjoint(y).max())
    x, hist = fista_nonneg_l1(op, y, lam, params.iterations, lip)
    for _ in range(params.reweight_rounds):
        pos_x = x[x > 0]
        if pos_x.size == 0:
            break
        scale = float(np.percentile(pos_x, 99))
        eps = params.reweight_eps
        weights = params.reweight_gain * eps / (x / scale + eps)
        x, more = fista_nonneg_l1(op, y, lam * weights, params.iterations, lip, x0=x)
        hist += more
    return op, x, lam, lip, hist


def prune_speckle(G: FloatArray, fraction: float) -> tuple[FloatArray, float]:
    """G with cells below ``fraction`` of its 99th percentile (of G > 0) set to 0, and the
    share of G's energy removed."""
    pos = G[G > 0]
    if fraction <= 0 or pos.size == 0:
        return G, 0.0
    small = (G > 0) & (G < fraction * np.percentile(pos, 99))
    out = G.copy()
    out[small] = 0.0
    return out, float(G[small].sum() / G.sum())


def reconstruct_inverse(
    obs: Observations, extent: GridExtent, grid: GridParams, params: InverseParams,
    rng: np.random.Generator | None = None,
) -> tuple[FloatArray, dict[str, Any]]:
    """Map G by inverting the back-projection (see the module docstring).

    Returns
    -------
    G : ndarray, shape extent.shape
        Sum over orientations of the non-negative reflector strengths.
    info : dict
        Active cells, lambda, Lipschitz constant, first and last objective values.
    """
    rng = rng or np.random.default_rng(0)
    back = backproject_observations(obs, extent, grid.radius_m).ravel()
    pos = back[back > 0]
    if pos.size == 0:
        return np.zeros(extent.shape), {"active_cells": 0}
    cells = np.nonzero(back >= params.active_fraction * np.percentile(pos, 99))[0]
    cells = cells[back[cells] > 0]
    radii = free_radii(obs, params.free_fraction, params.free_margin_m)
    forbidden = forbidden_unknowns(obs, extent, cells, params.orientations, radii,
                                   params.free_full_m)
    op, x, lam, lip, hist = _solve(obs, extent, cells, forbidden, grid, params, rng, None)
    for _ in range(params.occlusion_rounds):
        G = op.to_map(x)
        pos_g = G[G > 0]
        if pos_g.size == 0:
            break
        strong = np.nonzero(G.ravel() >= params.occluder_fraction * np.percentile(pos_g, 99))[0]
        nx = extent.shape[1]
        walls_xy = np.column_stack([extent.origin_m[0] + extent.resolution_m * (strong % nx),
                                    extent.origin_m[1] + extent.resolution_m * (strong // nx)])
        op, x, lam, lip, more = _solve(obs, extent, cells, forbidden, grid, params, rng,
                                       walls_xy)
        hist += more
    G, pruned = prune_speckle(op.to_map(x), params.prune_fraction)
    info = {"active_cells": int(cells.size), "lambda": lam, "lipschitz": lip,
            "forbidden_unknowns": int(forbidden.sum()),
            "objective_first": hist[0], "objective_last": hist[-1],
            "nnz": int(op.A.nnz), "pruned_energy_share": pruned}
    return G, info
