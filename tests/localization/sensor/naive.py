"""Slow, plain numpy twins of the sensor model's numba kernels, used only by the tests
(and as the baseline of ``benchmarks/localization_bench.py``).

:func:`score_poses_numpy` is the twin of :func:`localization.sensor.score_poses`: the pose
indexing, then the correlation model as one dense gather of every particle's polar samples
at the measurement's entries, or the range model from centred ring profiles.
:func:`naive_echo` is the twin of the echo kernel (``score_echo``), written from the formula
in its docstring.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from localization.sensor import Measurement, SensorTables
from localization.sensor._kernels import (  # only to type the echo kernel's twin
    _EchoPeaks,
    _EchoTerms,
)

FloatArray = NDArray[np.float64]


def index_poses(tables: SensorTables, poses: FloatArray) -> tuple[
        NDArray[np.int64], FloatArray, FloatArray, NDArray[np.int64], NDArray[np.int64]]:
    """Padded flat index of each pose's nearest cell, its offset (ux, uy) from that cell's
    centre in cells, its heading bin and its map cell (-1 off the map)."""
    cfg = tables.config
    c = (poses[:, :2] - np.asarray(tables.origin_m)) / tables.resolution_m
    near = np.floor(c + 0.5)
    u = c - near
    u = np.where(np.abs(u) < 1e-9, 0.0, u)       # cell centres exactly
    ix, iy = near[:, 0].astype(np.int64), near[:, 1].astype(np.int64)
    iy0, iy1, ix0, ix1 = tables.active
    on = (ix >= ix0) & (ix < ix1) & (iy >= iy0) & (iy < iy1)
    hb = np.rint(poses[:, 2] * cfg.n_headings / (2 * np.pi)).astype(np.int64) % cfg.n_headings
    cell = np.where(on, iy * tables.shape[1] + ix, -1).astype(np.int64)
    base = np.where(on, (iy + tables.pad) * tables.nx_pad + ix + tables.pad, 0)
    return base.astype(np.int64), u[:, 0], u[:, 1], hb, cell


def score_numpy(tables: SensorTables, measurement: Measurement, base: NDArray[np.int64],
                ux: FloatArray, uy: FloatArray, hb: NDArray[np.int64],
                cell: NDArray[np.int64]) -> FloatArray:
    """Twin of the correlation kernel ``_score_kernel`` (returns the scores)."""
    g, nx_pad, r_cells = tables.g, tables.nx_pad, tables.r_cells
    cos_tab, sin_tab, s1, s2 = tables.cos_tab, tables.sin_tab, tables.s1, tables.s2
    idx, val = measurement.idx, measurement.val
    out = np.full(base.shape[0], np.nan)
    ok = cell >= 0
    n_angles = cos_tab.shape[1]
    k, j = idx // n_angles, idx % n_angles
    h = hb[ok][:, None]
    dx = np.floor(r_cells[k][None, :] * cos_tab[h, j[None, :]] + (ux[ok][:, None] + 0.5))
    dy = np.floor(r_cells[k][None, :] * sin_tab[h, j[None, :]] + (uy[ok][:, None] + 0.5))
    p = g[base[ok][:, None] + (dy * nx_pad + dx).astype(np.int64)].astype(np.float64)
    c = cell[ok]
    var = s2[c] - s1[c] ** 2 / tables.n_samples
    num = p @ val - measurement.m_mean * s1[c]
    out[ok] = np.where(var > 1e-18,
                       num / (measurement.m_norm * np.sqrt(np.maximum(var, 1e-18))), 0.0)
    return out


def range_numpy(ring: NDArray[np.float32], cell: NDArray[np.int64],
                m0: FloatArray) -> FloatArray:
    """Twin of the range kernel ``_range_kernel``: correlation of ``m0`` (zero mean, unit
    norm) with each cell's centred ring profile (``cell < 0``: nan)."""
    out = np.full(cell.shape[0], np.nan)
    ok = cell >= 0
    p = ring[cell[ok]].astype(np.float64)
    pc = p - p.mean(axis=1, keepdims=True)
    norm = np.sqrt((pc**2).sum(axis=1))
    out[ok] = np.where(norm > 1e-9, (pc @ m0) / np.maximum(norm, 1e-9), 0.0)
    return out


def score_poses_numpy(tables: SensorTables, measurement: Measurement,
                      poses: FloatArray) -> FloatArray:
    """Twin of :func:`localization.sensor.score_poses` (poses (n, 3); nan off the map)."""
    poses = np.asarray(poses, dtype=np.float64)
    base, ux, uy, hb, cell = index_poses(tables, poses)
    if measurement.model == "range":
        return range_numpy(tables.ring, cell, measurement.dense)
    return score_numpy(tables, measurement, base, ux, uy, hb, cell)


def naive_echo(count: NDArray[np.int64], pr: FloatArray, pc: FloatArray, pa: FloatArray,
               peaks: _EchoPeaks, terms: _EchoTerms,
               map_sigma: FloatArray | None = None,
               amplitude: FloatArray | None = None) -> FloatArray:
    """Twin of the echo kernel ``score_echo``: (n, 3) of (ll, explained, heard) per pose.

    Straight from the kernel's docstring, one pose at a time with dense (peak, echo) arrays:
    ``kappa_jk = exp(-(dr/s_k)^2/2 - (dc/sig_c)^2/2)``, ``s_k^2 = sig_r^2 + map_sigma_k^2``
    (range only without ``use_cos``) over the predicted echoes in ``[r_min, r_max]``;
    ``ll = sum_j w_j log(eps + (1 - eps) max_k kappa'_jk) + sum_k log(1 - p_k (1 - max_j
    kappa'_jk))`` with ``p_k = p_max clip((a_k / a_max - rel_lo) / (rel_hi - rel_lo), 0, 1)``
    (``a_max`` the pose's strongest echo in the window, ``p_k = 0`` if none is positive);
    ``kappa'_jk = alpha_j kappa_jk``: ``alpha_j = 1`` unless levels are compared (``sig_a >
    0``, two or more peaks): peak j's predicted level ``L_j = sum_k kappa_jk l_k`` over the
    echoes with a positive amplitude ``l_k``, the gain ``g`` the mean of ``la_j - log L_j``
    over the peaks with ``L_j > 0`` weighted ``w_j max_k kappa_jk``, and there ``alpha_j =
    exp(-((la_j - log L_j - g) / sig_a)^2 / 2)``; ``L_j`` adds only the pairs the kernel
    keeps (``kappa >= exp(-18)``).
    explained ``sum w_j max_k kappa / sum w_j`` (1 without weight), heard ``sum p_k max_j
    kappa / sum p_k`` (1 when nothing is expected), both from kappa. Row i reads only its
    first ``count[i]`` entries (the rest is padding). No cut-off: the kernel skips pairs with
    ``kappa < exp(-18)``, which the caller allows for in its tolerance.
    """
    w = np.asarray(peaks.w, dtype=np.float64)
    la = np.asarray(peaks.la, dtype=np.float64)
    amp = pa if amplitude is None else amplitude
    out = np.empty((count.shape[0], 3))
    for i in range(count.shape[0]):
        k = int(count[i])
        r, c, a, lv = pr[i, :k], pc[i, :k], pa[i, :k], amp[i, :k]
        ms = np.zeros(k) if map_sigma is None else map_sigma[i, :k]
        inside = (r >= terms.r_min) & (r <= terms.r_max)
        r, c, a, lv, ms = r[inside], c[inside], a[inside], lv[inside], ms[inside]
        s_k = np.sqrt(peaks.sig_r**2 + ms**2)
        e = 0.5 * ((peaks.r[:, None] - r[None, :]) / s_k[None, :]) ** 2
        if peaks.use_cos:
            e = e + 0.5 * ((peaks.c[:, None] - c[None, :]) / peaks.sig_c) ** 2
        kappa = np.exp(-e)                                   # (n_meas, n_pred)
        a_max = float(a.max(initial=0.0))
        rel = a / a_max if a_max > 0.0 else np.zeros_like(a)
        p = terms.p_max * np.clip((rel - terms.rel_lo) / (terms.rel_hi - terms.rel_lo), 0.0, 1.0)
        explained = (float(np.sum(w * kappa.max(axis=1, initial=0.0)) / w.sum())
                     if w.sum() > 0.0 else 1.0)
        heard = (float(np.sum(p * kappa.max(axis=0, initial=0.0)) / p.sum())
                 if p.sum() > 0.0 else 1.0)
        alpha = np.ones(la.size)
        if terms.sig_a > 0 and la.size >= 2:
            # the level adds the pairs the kernel keeps (kappa >= exp(-18)), so a peak with
            # no such pair has none (a vanishing kappa must not set the gain)
            lev = np.where(kappa >= math.exp(-18.0), kappa, 0.0) @ np.where(lv > 0, lv, 0.0)
            use = lev > 0
            wt = w[use] * kappa.max(axis=1, initial=0.0)[use]
            if wt.sum() > 0:
                g = float(np.sum(wt * (la[use] - np.log(lev[use]))) / wt.sum())
                alpha[use] = np.exp(-0.5 * ((la[use] - np.log(lev[use]) - g) / terms.sig_a) ** 2)
        kappa_l = alpha[:, None] * kappa
        best_meas = kappa_l.max(axis=1, initial=0.0)
        best_pred = kappa_l.max(axis=0, initial=0.0)
        ll = (np.sum(w * np.log(terms.eps + (1.0 - terms.eps) * best_meas))
              + np.sum(np.log(1.0 - p * (1.0 - best_pred))))
        out[i] = (ll, explained, heard)
    return out


def end_weights_numpy(seg: FloatArray, end_sigma: FloatArray, wall_idx: NDArray[np.int64],
                      points_m: FloatArray) -> FloatArray:
    """Twin of ``_kernels._end_weights_kernel`` (the numpy ``end_weights`` it replaced):
    ``Phi(s0 / sigma0) Phi(s1 / sigma1)`` per bounce, product over a path's bounces."""
    from scipy.special import ndtr

    valid = wall_idx >= 0
    wi = np.where(valid, wall_idx, 0)
    a, b = seg[wi, 0], seg[wi, 1]
    sig0, sig1 = end_sigma[wi, 0], end_sigma[wi, 1]
    length = np.hypot(*(b - a).transpose(-1, *range(b.ndim - 1)))
    u = (b - a) / np.maximum(length, 1e-12)[..., None]
    p = np.nan_to_num(points_m)
    s0 = np.sum((p - a) * u, axis=-1)
    s1 = np.sum((b - p) * u, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = (np.where(sig0 > 0, ndtr(s0 / sig0), 1.0)
             * np.where(sig1 > 0, ndtr(s1 / sig1), 1.0))
    return np.asarray(np.where(valid, w, 1.0).prod(axis=-1))


def map_sigma_numpy(seg: FloatArray, wall_sigma: FloatArray, wall_idx: NDArray[np.int64],
                    points_m: FloatArray) -> FloatArray:
    """Twin of ``_kernels._map_sigma_kernel`` (the numpy ``map_range_sigma`` it replaced)."""
    mid = 0.5 * (seg[:, 0] + seg[:, 1])
    valid = wall_idx >= 0
    wi = np.where(valid, wall_idx, 0)
    along = np.hypot(*(np.nan_to_num(points_m) - mid[wi]).transpose(3, 0, 1, 2))
    var = np.where(valid, wall_sigma[wi, 0] ** 2 + (along * wall_sigma[wi, 1]) ** 2,
                   0.0).sum(axis=2)
    return np.asarray(np.sqrt(var))


def faces_numpy(seg: FloatArray, side: NDArray[np.int64], poses: FloatArray,
                count: NDArray[np.int64], wall_idx: NDArray[np.int64], points_m: FloatArray,
                tol_m: float) -> NDArray[np.bool_]:
    """Twin of ``_kernels._faces_kernel``, echo by echo in plain Python: every bounce of
    the echo starts (at the pose, then at the previous bounce point) no more than ``tol_m``
    behind the line of a one-sided wall; padding is False."""
    n, k, order = wall_idx.shape
    out = np.zeros((n, k), dtype=bool)
    for i in range(n):
        for j in range(min(int(count[i]), k)):
            start = np.asarray(poses[i, :2], dtype=np.float64)
            ok = True
            for r in range(order):
                w = int(wall_idx[i, j, r])
                if w < 0:
                    break
                a, b = seg[w, 0], seg[w, 1]
                d = b - a
                off = (d[0] * (start[1] - a[1]) - d[1] * (start[0] - a[0])) / max(
                    float(np.hypot(*d)), 1e-12)
                if side[w] != 0 and off * side[w] < -tol_m:
                    ok = False
                    break
                start = np.nan_to_num(points_m[i, j, r])
            out[i, j] = ok
    return out


def compact_numpy(keep: NDArray[np.bool_], f: FloatArray, order: NDArray[np.int64],
                  walls: NDArray[np.int64], points: FloatArray
                  ) -> tuple[NDArray[np.int64], FloatArray, NDArray[np.int64],
                             NDArray[np.int64], FloatArray]:
    """Twin of ``_kernels._compact_kernel``, row by row in plain Python: the kept echoes in
    their order, then padding (NaN, 0, -1, NaN)."""
    n, k = keep.shape
    f_out = np.full(f.shape, np.nan)
    order_out = np.zeros(order.shape, dtype=np.int64)
    walls_out = np.full(walls.shape, -1, dtype=np.int64)
    points_out = np.full(points.shape, np.nan)
    count = np.zeros(n, dtype=np.int64)
    for i in range(n):
        kept = [j for j in range(k) if keep[i, j]]
        count[i] = len(kept)
        for w, j in enumerate(kept):
            f_out[:, i, w] = f[:, i, j]
            order_out[i, w] = order[i, j]
            walls_out[i, w] = walls[i, j]
            points_out[i, w] = points[i, j]
    return count, f_out, order_out, walls_out, points_out
