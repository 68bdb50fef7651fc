"""numba kernels of the sensor model; imported only by :mod:`localization.sensor`.

Each kernel has a plain numpy twin (``*_numpy``) that the tests compare it with.

The kernels are serial on purpose (``nogil``, no ``prange``): one filter update is a few
milliseconds, the HTTP service runs many sessions' updates in parallel threads, and on this
shared 2-core machine a parallel region waiting for its second thread cost 10-20 ms per call
(measured: 2.5 ms per update with one thread vs 18-25 ms with two under load).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from mapping.numba_config import NUMBA_FLAGS


@numba.njit(**NUMBA_FLAGS)
def _score_kernel(
    g: NDArray[np.float32],
    nx_pad: int,
    cos_tab: NDArray[np.float64],
    sin_tab: NDArray[np.float64],
    r_entry: NDArray[np.float64],
    j_entry: NDArray[np.int64],
    base: NDArray[np.int64],
    ux: NDArray[np.float64],
    uy: NDArray[np.float64],
    hb: NDArray[np.int64],
    cell: NDArray[np.int64],
    s1: NDArray[np.float64],
    s2: NDArray[np.float64],
    val: NDArray[np.float64],
    m_mean: float,
    m_norm: float,
    n_samp: int,
    out: NDArray[np.float64],
) -> None:
    """Pearson correlation of a sparse measurement with the polar samples of ``g``.

    Particle i sits ``(ux[i], uy[i])`` cells (each in [-0.5, 0.5]) from the centre of the
    cell with padded flat index ``base[i]``, with heading bin ``hb[i]``; polar sample
    ``s = k * n_angles + j`` is the cell nearest to that point plus
    ``r_k (cos_tab[hb, j], sin_tab[hb, j])`` (offsets rounded relative to the cell, so a
    cell centre reproduces the heading-0 table exactly). Only the measurement's non-zero
    entries (values ``val``) enter, so the cross term is a sparse dot product; entry ``t``
    is polar sample ``(k, j)``, given as its range in cells ``r_entry[t] = r_cells[k]`` and
    its angle index ``j_entry[t] = j`` (split once per measurement by :func:`score`: an
    integer division per entry and particle cost more than half of the kernel's time). The
    sample sum and sum of squares come from the per-cell tables ``s1`` and ``s2``.
    ``cell[i] < 0`` marks a particle off the map (``out = nan``).
    """
    for i in range(base.shape[0]):
        c = cell[i]
        if c < 0:
            out[i] = np.nan
            continue
        h = hb[i]
        b = base[i]
        x = ux[i] + 0.5
        y = uy[i] + 0.5
        cos_h = cos_tab[h]
        sin_h = sin_tab[h]
        dot = 0.0
        for t in range(val.shape[0]):
            j = j_entry[t]
            r = r_entry[t]
            dx = int(math.floor(r * cos_h[j] + x))
            dy = int(math.floor(r * sin_h[j] + y))
            dot += val[t] * g[b + dy * nx_pad + dx]
        var = s2[c] - s1[c] * s1[c] / n_samp
        out[i] = (dot - m_mean * s1[c]) / (m_norm * math.sqrt(var)) if var > 1e-18 else 0.0


def _score_numpy(
    g: NDArray[np.float32], nx_pad: int, cos_tab: NDArray[np.float64],
    sin_tab: NDArray[np.float64], r_cells: NDArray[np.float64], base: NDArray[np.int64],
    ux: NDArray[np.float64], uy: NDArray[np.float64], hb: NDArray[np.int64],
    cell: NDArray[np.int64], s1: NDArray[np.float64], s2: NDArray[np.float64],
    idx: NDArray[np.int64], val: NDArray[np.float64], m_mean: float, m_norm: float,
    n_samp: int,
) -> NDArray[np.float64]:
    """Plain numpy twin of :func:`_score_kernel` (returns the scores)."""
    out = np.full(base.shape[0], np.nan)
    ok = cell >= 0
    n_angles = cos_tab.shape[1]
    k, j = idx // n_angles, idx % n_angles
    h = hb[ok][:, None]
    dx = np.floor(r_cells[k][None, :] * cos_tab[h, j[None, :]] + (ux[ok][:, None] + 0.5))
    dy = np.floor(r_cells[k][None, :] * sin_tab[h, j[None, :]] + (uy[ok][:, None] + 0.5))
    p = g[base[ok][:, None] + (dy * nx_pad + dx).astype(np.int64)].astype(np.float64)
    c = cell[ok]
    var = s2[c] - s1[c] ** 2 / n_samp
    num = p @ val - m_mean * s1[c]
    out[ok] = np.where(var > 1e-18, num / (m_norm * np.sqrt(np.maximum(var, 1e-18))), 0.0)
    return out


def score(
    g: NDArray[np.float32], nx_pad: int, cos_tab: NDArray[np.float64],
    sin_tab: NDArray[np.float64], r_cells: NDArray[np.float64], base: NDArray[np.int64],
    ux: NDArray[np.float64], uy: NDArray[np.float64], hb: NDArray[np.int64],
    cell: NDArray[np.int64], s1: NDArray[np.float64], s2: NDArray[np.float64],
    idx: NDArray[np.int64], val: NDArray[np.float64], m_mean: float, m_norm: float,
    n_samp: int,
) -> NDArray[np.float64]:
    """Split the entries ``idx`` into range and angle once, allocate the output and run
    :func:`_score_kernel` (same arguments as :func:`_score_numpy`)."""
    n_angles = cos_tab.shape[1]
    r_entry = np.ascontiguousarray(r_cells[idx // n_angles], dtype=np.float64)
    j_entry = np.ascontiguousarray(idx % n_angles, dtype=np.int64)
    out = np.empty(base.shape[0], dtype=np.float64)
    _score_kernel(g, nx_pad, cos_tab, sin_tab, r_entry, j_entry, base, ux, uy, hb, cell, s1,
                  s2, np.ascontiguousarray(val, dtype=np.float64), m_mean, m_norm, n_samp, out)
    return out


@numba.njit(**NUMBA_FLAGS)
def _range_kernel(
    ring: NDArray[np.float32], cell: NDArray[np.int64], m0: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """Pearson correlation of the range profile ``m0`` (zero mean, unit norm) with the ring
    sums ``ring[cell[i]]`` of G around each particle's cell (``cell < 0``: nan)."""
    n_r = ring.shape[1]
    for i in range(cell.shape[0]):
        c = cell[i]
        if c < 0:
            out[i] = np.nan
            continue
        s_mp = 0.0
        s_p = 0.0
        s_pp = 0.0
        for k in range(n_r):
            p = float(ring[c, k])
            s_mp += m0[k] * p
            s_p += p
            s_pp += p * p
        var = s_pp - s_p * s_p / n_r
        out[i] = s_mp / math.sqrt(var) if var > 1e-18 else 0.0


def _range_numpy(ring: NDArray[np.float32], cell: NDArray[np.int64],
                 m0: NDArray[np.float64]) -> NDArray[np.float64]:
    """Plain numpy twin of :func:`_range_kernel`."""
    out = np.full(cell.shape[0], np.nan)
    ok = cell >= 0
    p = ring[cell[ok]].astype(np.float64)
    pc = p - p.mean(axis=1, keepdims=True)
    norm = np.sqrt((pc**2).sum(axis=1))
    out[ok] = np.where(norm > 1e-9, (pc @ m0) / np.maximum(norm, 1e-9), 0.0)
    return out


def score_range(ring: NDArray[np.float32], cell: NDArray[np.int64],
                m0: NDArray[np.float64]) -> NDArray[np.float64]:
    """Allocate the output and run :func:`_range_kernel`."""
    out = np.empty(cell.shape[0], dtype=np.float64)
    _range_kernel(ring, cell, m0, out)
    return out
