"""Plain numpy twins of the numba kernels of :mod:`mapping.heatmap` (tests and benchmarks only).

Slow and written for reading: the same arithmetic as ``mapping/heatmap/_kernels.py`` (whose
docstrings define it), vectorized over samples instead of looped. ``test_heatmap.py`` compares
each kernel with its twin on random inputs and edge cases.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from mapping.heatmap import STRIP_STEP_RAD

FloatArray = NDArray[np.float64]


def resample_fold_numpy(
    ext: FloatArray, origin: float, centre: float, alphas: FloatArray, n_periods: int,
    period: int, table: FloatArray,
) -> FloatArray:
    """Twin of ``_kernels._resample_fold``: returns ``out`` (alphas.size, period)."""
    taps = table.shape[1]
    q = table.shape[0] - 1
    half = taps // 2 - 1
    n = np.arange(n_periods * period, dtype=np.float64)
    out = np.empty((alphas.size, period))
    for d, a in enumerate(alphas):
        x = origin + centre + a * (n - centre)
        i = np.floor(x)
        p = np.floor((x - i) * q + 0.5).astype(np.int64)
        idx = i.astype(np.int64)[:, None] - half + np.arange(taps)[None, :]
        values = np.sum(ext[idx] * table[p], axis=1)
        out[d] = values.reshape(n_periods, period).sum(axis=0)
    return out


def spectral_bank_numpy(
    spec: NDArray, nf: int, ext: FloatArray, origin: int, n_block: int, centre: float,
    icentre: int, alphas: FloatArray, period: int, taps: int, table: FloatArray,
    per_unit: int, conj_tx: NDArray, strip_step_rad: float = STRIP_STEP_RAD,
) -> NDArray[np.complex128]:
    """Twin of ``_kernels._spectral_bank``: returns ``out`` (alphas.size, period).

    ``spec`` is the one-sided spectrum (nf / 2 + 1 bins) that the kernel receives
    Hermitian-extended (see :func:`hermitian_extended`).
    """
    n_q = period // 2 + 1
    q = np.arange(n_q, dtype=np.float64)
    grid = np.arange(table.shape[0]) / per_unit
    out = np.zeros((alphas.size, period), dtype=np.complex128)
    for d, a in enumerate(alphas):
        xi = q * (nf / (a * period))
        fl = np.floor(xi)
        j = (fl.astype(np.int64) - taps // 2 + 1)[:, None] + np.arange(taps)[None, :]
        w = np.stack([np.interp(xi - fl, grid, table[:, t]) for t in range(taps)], axis=1)
        jm = j % nf
        low = jm < spec.size
        g = np.where(low, spec[np.where(low, jm, 0)], np.conj(spec[np.where(low, 0, nf - jm)]))
        acc = np.sum(w * g, axis=1)
        lo = math.ceil(centre - a * (centre + 0.5))
        hi = math.ceil(centre + a * (n_block - 0.5 - centre))
        strips = [(lo, 0, 1.0) if lo < 0 else (0, lo, -1.0),
                  (n_block, hi, 1.0) if hi > n_block else (hi, n_block, -1.0)]
        delta = 2.0 * np.pi / (a * period)
        for start, stop, sign in strips:
            acc = acc + strip_numpy(ext, origin, start, stop, sign, icentre, delta, n_q,
                                    strip_step_rad)
        phase = -2.0 * np.pi / period * (centre * (1.0 - 1.0 / a) + icentre / a) * q
        out[d, :n_q] = acc * np.exp(1j * phase) * conj_tx / a
    return out


def strip_numpy(
    ext: FloatArray, origin: int, start: int, stop: int, sign: float, icentre: int,
    delta: float, n_q: int, strip_step_rad: float = STRIP_STEP_RAD,
) -> NDArray[np.complex128]:
    """Twin of ``_kernels._add_strip`` (returns the added term)."""
    q = np.arange(n_q, dtype=np.float64)
    n_s = stop - start
    if n_s <= 0:
        return np.zeros(n_q, dtype=np.complex128)
    k = origin + np.arange(start, stop)
    ok = (k >= 0) & (k < ext.size)
    vals = np.where(ok, sign * ext[np.clip(k, 0, ext.size - 1)], 0.0)
    coarse = max(1, int(strip_step_rad / (delta * n_s)))
    qg = np.arange((n_q - 1) // coarse + 2) * coarse
    t = np.exp(-1j * delta * np.outer(qg, np.arange(n_s))) @ vals
    smooth = np.interp(q, qg, t.real) + 1j * np.interp(q, qg, t.imag)
    return np.asarray(smooth * np.exp(-1j * delta * (start - icentre) * q))


def hermitian_extended(spec: NDArray, pad: int) -> tuple[FloatArray, FloatArray]:
    """The kernel's input layout: ``G[j]`` for j in [-pad, n + pad) at index ``pad + j``
    (real and imaginary parts), from the rfft ``spec`` (n bins, even length) by
    ``G[-j] = G[nf - j] = conj G[j]``."""
    n = spec.size
    nf = 2 * (n - 1)
    j = np.arange(-pad, n + pad) % nf
    g = np.where(j < n, spec[np.minimum(j, n - 1)], np.conj(spec[np.clip(nf - j, 0, n - 1)]))
    return np.ascontiguousarray(g.real), np.ascontiguousarray(g.imag)
