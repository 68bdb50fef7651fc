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
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from mapping.grid import GridExtent, GridParams, remove_floor
from mapping.heatmap import HeatMap
from mapping.signal import SonarConfig

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class InverseParams:
    """Parameters of the inverse reconstruction.

    Parameters
    ----------
    orientations : int
        Number O of normal-axis orientations per cell (1 = isotropic point reflectors).
    bin_m : float or None
        Range bin of the observations in metres (None: the map resolution).
    lam_rel : float
        l1 weight relative to ``max(A^T y)``.
    iterations : int
        FISTA iterations.
    active_fraction : float
        Cells whose back-projection is below this fraction of its 99th percentile are fixed at 0.
    free_fraction, free_margin_m : float
        Free-space constraint: in each block, the first range bin whose strongest row reaches
        ``free_fraction`` of the block's maximum is the nearest reflector (the nearest point of a
        specular wall is its perpendicular foot, which echoes; corners echo from anywhere); cells
        closer to the pose than that range minus ``free_margin_m`` are fixed at 0. Set
        ``free_fraction = 0`` to disable. Within ``free_full_m`` of the pose every orientation is
        ruled out (a full free disc); beyond it only the elements that would have echoed to
        the pose (their normal points at it), because a non-specular wall end closer than
        the nearest echo gives no echo of its own.
    reweight_rounds, reweight_eps, reweight_gain : int, float, float
        Reweighted l1 (Candes, Wakin & Boyd 2008): after each solve the weight of unknown i
        becomes ``gain * eps / (x_i / s + eps)`` with ``s`` the 99th percentile of x > 0, and
        the problem is solved again from the last solution. Sparser maps, less bias on strong
        cells.
    occlusion_rounds, occluder_fraction, occlusion_margin_m : int, float, float
        Occlusion: after a solve, cells above ``occluder_fraction`` of the 99th percentile of
        the map are taken as walls; the operator is rebuilt so that a cell farther than the
        first such wall along its bearing (plus ``occlusion_margin_m``) is invisible from that
        pose, and the problem is solved again. Multiple-reflection echoes, which the
        back-projection places behind the walls, then have nothing to explain them.
    prune_fraction : float
        After solving, cells of G below this fraction of its 99th percentile (of G > 0) are
        set to 0: the solver's residual speckle (support pruning). Off by default: it lowers
        the ghost energy a little but raises the 99th percentile of the remaining positive
        cells that the quality thresholds scale with, which costs recall (README numbers).
    doppler_spread : bool
        Model the Doppler bank's angular point spread ``|sinc(kappa dcos)|`` (see
        :func:`doppler_kappa`) in the operator. Off by default: on the image-source runs it
        made the operator 5x denser and did not improve precision/recall (README numbers).
    """

    orientations: int = 16
    bin_m: float | None = None
    lam_rel: float = 0.01
    iterations: int = 200
    active_fraction: float = 0.15
    free_fraction: float = 0.3
    free_margin_m: float = 0.1
    free_full_m: float = 1.0
    doppler_spread: bool = False
    prune_fraction: float = 0.0
    reweight_rounds: int = 0
    occlusion_rounds: int = 0
    occluder_fraction: float = 0.5
    occlusion_margin_m: float = 0.2
    reweight_eps: float = 0.1
    reweight_gain: float = 2.0

    def __post_init__(self) -> None:
        if not 1 <= self.orientations <= 360:
            raise ValueError(f"orientations must be in 1..360, got {self.orientations}")
        if self.bin_m is not None and not (math.isfinite(self.bin_m) and self.bin_m > 0):
            raise ValueError(f"bin_m must be > 0 or None, got {self.bin_m}")
        if not 0 <= self.lam_rel < 1:
            raise ValueError(f"lam_rel must be in [0, 1), got {self.lam_rel}")
        if not 1 <= self.iterations <= 100_000:
            raise ValueError(f"iterations must be in 1..100000, got {self.iterations}")
        if not 0 <= self.free_fraction <= 1:
            raise ValueError(f"free_fraction must be in [0, 1], got {self.free_fraction}")
        if not self.free_margin_m >= 0:
            raise ValueError(f"free_margin_m must be >= 0, got {self.free_margin_m}")
        if not 0 <= self.prune_fraction < 1:
            raise ValueError(f"prune_fraction must be in [0, 1), got {self.prune_fraction}")
        if not 0 <= self.active_fraction < 1:
            raise ValueError(f"active_fraction must be in [0, 1), got {self.active_fraction}")

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON parameters."""
        return asdict(self)


@dataclass(frozen=True)
class Observations:
    """Range-pooled heat maps of the used blocks: ``Y[k, n_theta, n_r]`` at ``poses[k]``.

    ``kappa[k]`` is the Doppler point-spread parameter of block k (0: no spread modelled).
    """

    Y: FloatArray
    poses: FloatArray
    bin_m: float
    kappa: FloatArray

    @property
    def n_dirs(self) -> int:
        """Rows N + 1 of each heat map."""
        return int(self.Y.shape[1])


def pool_heatmap(heatmap: HeatMap, bin_m: float, radius_m: float, floor: str) -> FloatArray:
    """Floor-removed heat map max-pooled into range bins ``round(r / bin_m)`` up to radius."""
    H = remove_floor(heatmap.H, floor)
    n_bins = int(math.floor(radius_m / bin_m + 0.5)) + 1
    b = np.floor(heatmap.ranges_m / bin_m + 0.5).astype(np.int64)
    keep = b < n_bins
    out = np.zeros((H.shape[0], n_bins))
    np.maximum.at(out.T, b[keep], H[:, keep].T)
    return out


def doppler_kappa(speed_m_s: float, config: SonarConfig) -> float:
    """Carrier cycles of delay drift per unit of cos(angle) mismatch over a block.

    A row of the Doppler bank that misses the echo's ``cos(theta)`` by ``dcos`` leaves a
    residual compression ``2 v dcos / c``; over the block (``T = M P / fs``) the delay drifts
    by ``2 v T dcos / c`` seconds, i.e. ``kappa * dcos`` carrier cycles with
    ``kappa = 2 |v| T f_c / c``, and the coherent sum falls like ``|sinc(kappa dcos)|``
    (first zero at ``dcos = 1 / kappa``: 0.17 for Table 1 at 0.1 m/s). This is the model's
    angular point-spread function; larger M narrows it (paper Fig. 7).
    """
    return 2.0 * abs(speed_m_s) * config.block_s * config.carrier_hz / config.sound_speed_m_s


def observations_from_heatmaps(
    heatmaps: Iterable[HeatMap | None], poses: FloatArray, grid: GridParams,
    params: InverseParams, config: SonarConfig | None = None,
) -> tuple[Observations, dict[str, int]]:
    """Pool every tracked, observable block's heat map; counts as in :func:`grid.accumulate`.

    With ``config`` and ``params.doppler_spread`` the Doppler point-spread parameter of each
    block comes from :func:`doppler_kappa` at the heat map's speed; otherwise none is modelled.
    """
    poses = np.asarray(poses, dtype=np.float64)
    bin_m = params.bin_m or grid.resolution_m
    Y, used, kappa = [], [], []
    counts = {"blocks_used": 0, "blocks_untracked": 0, "blocks_unobservable": 0}
    for k, hm in enumerate(heatmaps):
        if hm is None or not np.all(np.isfinite(poses[k])):
            counts["blocks_untracked"] += 1
        elif grid.skip_unobservable and not hm.direction_observable:
            counts["blocks_unobservable"] += 1
        else:
            Y.append(pool_heatmap(hm, bin_m, grid.radius_m, grid.floor))
            used.append(k)
            use = config is not None and params.doppler_spread
            kappa.append(doppler_kappa(hm.speed_m_s, config) if use and config else 0.0)
            counts["blocks_used"] += 1
    n_dirs = Y[0].shape[0] if Y else 2
    n_bins = Y[0].shape[1] if Y else 1
    arr = np.array(Y) if Y else np.zeros((0, n_dirs, n_bins))
    return Observations(arr, poses[used].reshape(-1, 3), bin_m, np.array(kappa)), counts


def concat_observations(parts: list[Observations]) -> Observations:
    """Observations of several runs, in order."""
    parts = [p for p in parts if p.Y.shape[0] > 0]
    if not parts:
        raise ValueError("no observations to reconstruct from")
    return Observations(np.concatenate([p.Y for p in parts]),
                        np.concatenate([p.poses for p in parts]), parts[0].bin_m,
                        np.concatenate([p.kappa for p in parts]))


# ---- the linear operator ----------------------------------------------------------------
@dataclass(frozen=True)
class Operator:
    """Sparse forward model ``y = A x`` over active cells (see the module docstring)."""

    A: sp.csr_matrix
    cells: NDArray[np.int64]  # flat indices into the map of the active cells
    orientations: int
    data_shape: tuple[int, int, int]
    map_shape: tuple[int, int]

    def forward(self, x: FloatArray) -> FloatArray:
        """Predicted observations, shape ``data_shape``, from ``x`` (O, n_active)."""
        return np.asarray(self.A @ x.ravel()).reshape(self.data_shape)

    def adjoint(self, y: FloatArray) -> FloatArray:
        """``A^T y`` as (O, n_active)."""
        return np.asarray(self.AT @ y.ravel()).reshape(self.orientations, -1)

    @property
    def AT(self) -> sp.csr_matrix:
        """``A^T`` as CSR (cached)."""
        cached = self.__dict__.get("_AT")
        if cached is None:
            cached = sp.csr_matrix(self.A.T)
            object.__setattr__(self, "_AT", cached)
        return cached

    def to_map(self, x: FloatArray) -> FloatArray:
        """Sum over orientations placed on the full grid."""
        G = np.zeros(self.map_shape[0] * self.map_shape[1])
        G[self.cells] = x.sum(axis=0)
        return G.reshape(self.map_shape)


def _geometry(obs: Observations, extent: GridExtent, cells: NDArray[np.int64], k: int,
              radius_m: float) -> tuple[NDArray[np.int64], NDArray[np.int64], FloatArray,
                                        NDArray[np.bool_], FloatArray]:
    """Row, bin, bearing, validity and |angle from travel| of ``cells`` seen from block k."""
    ny, nx = extent.shape
    res = extent.resolution_m
    x = extent.origin_m[0] + res * (cells % nx)
    y = extent.origin_m[1] + res * (cells // nx)
    px, py, phi = obs.poses[k]
    dx, dy = x - px, y - py
    r = np.hypot(dx, dy)
    beta = np.arctan2(dy, dx)
    n_max = obs.n_dirs - 1
    diff = np.mod(beta - phi + np.pi, 2 * np.pi) - np.pi
    row = np.minimum(np.floor(np.abs(diff) * n_max / np.pi + 0.5).astype(np.int64), n_max)
    b = np.floor(r / obs.bin_m + 0.5).astype(np.int64)
    ok = (r <= radius_m) & (b < obs.Y.shape[2])
    return row, b, beta, ok, np.abs(diff)


def backproject_observations(obs: Observations, extent: GridExtent,
                             radius_m: float) -> FloatArray:
    """The paper's back-projection of pooled heat maps (nearest row and bin, exact pose)."""
    cells = np.arange(extent.shape[0] * extent.shape[1])
    G = np.zeros(cells.size)
    for k in range(obs.Y.shape[0]):
        row, b, _, ok, _ = _geometry(obs, extent, cells, k, radius_m)
        G[ok] += obs.Y[k][row[ok], b[ok]]
    return G.reshape(extent.shape)


def free_radii(obs: Observations, free_fraction: float, margin_m: float) -> FloatArray:
    """Per block, the radius around the pose with no reflector (see ``InverseParams``)."""
    if free_fraction <= 0:
        return np.zeros(obs.Y.shape[0])
    strongest = obs.Y.max(axis=1)  # (K, n_bins)
    peak = strongest.max(axis=1, keepdims=True)
    hit = (strongest >= free_fraction * peak) & (peak > 0)
    first = np.where(hit.any(axis=1), hit.argmax(axis=1), 0)
    return np.maximum((first - 0.5) * obs.bin_m - margin_m, 0.0)


def forbidden_unknowns(obs: Observations, extent: GridExtent, cells: NDArray[np.int64],
                       orientations: int, radii: FloatArray,
                       full_m: float = 0.0) -> NDArray[np.bool_]:
    """Unknowns ``(o, cell)`` ruled out by the free-space constraint, shape (O, n_cells).

    An element whose normal points at pose k (it would echo there) but lies closer than that
    block's nearest echo does not exist. Elements of other orientations are not constrained
    (a wall end near the pose is not specular from there and gives no echo).
    """
    nx = extent.shape[1]
    res = extent.resolution_m
    x = extent.origin_m[0] + res * (cells % nx)
    y = extent.origin_m[1] + res * (cells // nx)
    out = np.zeros((orientations, cells.size), dtype=bool)
    for (px, py, _), rad in zip(obs.poses, radii, strict=True):
        d2 = (x - px) ** 2 + (y - py) ** 2
        full = min(rad, full_m)
        out[:, d2 < full * full] = True
        j = np.nonzero(d2 < rad * rad)[0]
        if j.size == 0:
            continue
        if orientations == 1:
            out[0, j] = True
            continue
        u = np.mod(np.arctan2(y[j] - py, x[j] - px), np.pi) / (np.pi / orientations)
        o0 = np.floor(u).astype(np.int64)
        f = u - o0
        o0 %= orientations
        out[o0[f < 0.75], j[f < 0.75]] = True
        o1 = (o0 + 1) % orientations
        out[o1[f > 0.25], j[f > 0.25]] = True
    return out


def occluded(pose: FloatArray, x: NDArray[np.floating], y: NDArray[np.floating],
             walls_xy: FloatArray, res: float, margin_m: float,
             n_bins: int = 720) -> NDArray[np.bool_]:
    """Points (x, y) hidden from ``pose`` behind the wall cells ``walls_xy`` (n, 2).

    The first wall range per bearing bin (each wall cell covering the bins its width spans)
    is compared with the point's range plus ``margin_m``.
    """
    px, py = pose[0], pose[1]
    bw = 2 * np.pi / n_bins
    first = np.full(n_bins, np.inf)
    if walls_xy.shape[0]:
        wr = np.hypot(walls_xy[:, 0] - px, walls_xy[:, 1] - py)
        wb = np.arctan2(walls_xy[:, 1] - py, walls_xy[:, 0] - px)
        half = np.arctan2(0.75 * res, np.maximum(wr, res))
        lo = np.floor((wb - half) / bw).astype(np.int64)
        hi = np.floor((wb + half) / bw).astype(np.int64)
        for off in range(int((hi - lo).max()) + 1):
            m = lo + off <= hi
            np.minimum.at(first, (lo[m] + off) % n_bins, wr[m])
    r = np.hypot(x - px, y - py)
    b = np.floor(np.arctan2(y - py, x - px) / bw).astype(np.int64) % n_bins
    return np.asarray(r > first[b] + margin_m)


def build_operator(obs: Observations, extent: GridExtent, cells: NDArray[np.int64],
                   orientations: int, radius_m: float, walls_xy: FloatArray | None = None,
                   occlusion_margin_m: float = 0.2) -> Operator:
    """The sparse forward operator over ``cells`` (flat map indices).

    With ``walls_xy`` (n, 2) a cell hidden behind those wall cells from a pose does not
    contribute to that pose's observation (see :func:`occluded`).
    """
    K, n_dirs, n_bins = obs.Y.shape
    n_act = cells.size
    rows_all, cols_all, vals_all = [], [], []
    cos_rows = np.cos(np.pi * np.arange(n_dirs) / (n_dirs - 1))
    for k in range(K):
        row, b, beta, ok, ang = _geometry(obs, extent, cells, k, radius_m)
        if walls_xy is not None:
            nx = extent.shape[1]
            cx = extent.origin_m[0] + extent.resolution_m * (cells % nx)
            cy = extent.origin_m[1] + extent.resolution_m * (cells // nx)
            ok &= ~occluded(obs.poses[k], cx, cy, walls_xy, extent.resolution_m,
                            occlusion_margin_m)
        j = np.nonzero(ok)[0]
        if orientations == 1:
            o_cols, o_w = [j], [np.ones(j.size)]
        else:
            u = np.mod(beta[j], np.pi) / (np.pi / orientations)
            o0 = np.floor(u).astype(np.int64)
            f = u - o0
            o0 %= orientations
            o_cols = [o0 * n_act + j, (o0 + 1) % orientations * n_act + j]
            o_w = [1.0 - f, f]
        kap = float(obs.kappa[k])
        if kap > 0:  # Doppler point spread over the rows: |sinc(kappa dcos)|, main lobe
            spread = [(n, np.abs(np.sinc(kap * (cos_rows[n] - np.cos(ang[j])))),
                       np.abs(kap * (cos_rows[n] - np.cos(ang[j]))) < 1.0)
                      for n in range(n_dirs)]
        else:
            spread = [(-1, np.ones(j.size), np.ones(j.size, dtype=bool))]
        for n, w_row, m in spread:
            rr = row[j][m] if n < 0 else np.full(int(m.sum()), n)
            data_idx = (k * n_dirs + rr) * n_bins + b[j][m]
            for cols, w in zip(o_cols, o_w, strict=True):
                rows_all.append(data_idx)
                cols_all.append(cols[m])
                vals_all.append(w[m] * w_row[m])
    A = sp.csr_matrix(
        (np.concatenate(vals_all), (np.concatenate(rows_all), np.concatenate(cols_all))),
        shape=(K * n_dirs * n_bins, orientations * n_act))
    return Operator(A, cells, orientations, (K, n_dirs, n_bins), extent.shape)


def operator_norm_sq(op: Operator, rng: np.random.Generator, iterations: int = 30) -> float:
    """Largest eigenvalue of ``A^T A`` by power iteration (``||A||^2``)."""
    x = rng.random((op.orientations, op.cells.size))
    lam = 0.0
    for _ in range(iterations):
        z = op.adjoint(op.forward(x))
        lam = float(np.linalg.norm(z))
        if lam == 0:
            return 0.0
        x = z / lam
    return lam


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
