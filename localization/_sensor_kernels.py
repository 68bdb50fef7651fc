"""numba kernels of the sensor model; imported only by :mod:`localization.sensor`.

Each kernel has a plain numpy twin (``*_numpy``) that the tests compare it with.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from mapping._numba_config import NUMBA_FLAGS, PARALLEL


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _score_kernel(
    g: NDArray[np.float32],
    offsets: NDArray[np.int32],
    base: NDArray[np.int64],
    lut: NDArray[np.int64],
    cell: NDArray[np.int64],
    s1: NDArray[np.float64],
    s2: NDArray[np.float64],
    idx: NDArray[np.int64],
    val: NDArray[np.float64],
    m_mean: float,
    m_norm: float,
    n_samp: int,
    out: NDArray[np.float64],
) -> None:
    """Pearson correlation of a sparse measurement with the polar samples of ``g``.

    For particle i the samples are ``g[base[i] + offsets[lut[i], s]]``; only the ``idx``
    entries (values ``val``) of the measurement are non-zero, so the cross term is a sparse
    dot product, and the sample sum and sum of squares come from the per-cell tables ``s1``
    and ``s2``. ``cell[i] < 0`` marks a particle off the map (``out = nan``).
    """
    n = base.shape[0]
    for i in numba.prange(n):
        c = cell[i]
        if c < 0:
            out[i] = np.nan
            continue
        b = base[i]
        row = offsets[lut[i]]
        dot = 0.0
        for t in range(idx.shape[0]):
            dot += val[t] * g[b + row[idx[t]]]
        var = s2[c] - s1[c] * s1[c] / n_samp
        out[i] = (dot - m_mean * s1[c]) / (m_norm * math.sqrt(var)) if var > 1e-18 else 0.0


def _score_numpy(
    g: NDArray[np.float32], offsets: NDArray[np.int32], base: NDArray[np.int64],
    lut: NDArray[np.int64], cell: NDArray[np.int64], s1: NDArray[np.float64],
    s2: NDArray[np.float64], idx: NDArray[np.int64], val: NDArray[np.float64],
    m_mean: float, m_norm: float, n_samp: int,
) -> NDArray[np.float64]:
    """Plain numpy twin of :func:`_score_kernel` (returns the scores)."""
    out = np.full(base.shape[0], np.nan)
    ok = cell >= 0
    p = g[base[ok, None] + offsets[lut[ok]][:, idx]].astype(np.float64)
    c = cell[ok]
    var = s2[c] - s1[c] ** 2 / n_samp
    num = p @ val - m_mean * s1[c]
    out[ok] = np.where(var > 1e-18, num / (m_norm * np.sqrt(np.maximum(var, 1e-18))), 0.0)
    return out


def score(
    g: NDArray[np.float32], offsets: NDArray[np.int32], base: NDArray[np.int64],
    lut: NDArray[np.int64], cell: NDArray[np.int64], s1: NDArray[np.float64],
    s2: NDArray[np.float64], idx: NDArray[np.int64], val: NDArray[np.float64],
    m_mean: float, m_norm: float, n_samp: int,
) -> NDArray[np.float64]:
    """Allocate the output and run :func:`_score_kernel`."""
    out = np.empty(base.shape[0], dtype=np.float64)
    _score_kernel(g, offsets, base, lut, cell, s1, s2, idx, val, m_mean, m_norm, n_samp, out)
    return out


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _range_kernel(
    ring: NDArray[np.float32], cell: NDArray[np.int64], m0: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """Pearson correlation of the range profile ``m0`` (zero mean, unit norm) with the ring
    sums ``ring[cell[i]]`` of G around each particle's cell (``cell < 0``: nan)."""
    n_r = ring.shape[1]
    for i in numba.prange(cell.shape[0]):
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
