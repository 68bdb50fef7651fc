"""The sparse linear forward model of the inverse reconstruction (:mod:`mapping.reconstruct`).

:class:`Operator` maps strengths ``x[o, c]`` of specular wall elements (cell ``c``, normal
axis ``psi_o = pi o / O``) to predicted pooled heat maps, ``y = A x``; its adjoint summed
over orientations is the paper's back-projection (eq. 5, :func:`backproject_observations`).
Also the constraints the solver uses: the free space around each pose
(:func:`free_radii`, :func:`forbidden_unknowns`) and occlusion behind wall cells
(:func:`occluded`), and ``||A||^2`` by power iteration (:func:`operator_norm_sq`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from mapping.grid import GridExtent
from mapping.reconstruct._observations import FloatArray, Observations


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
