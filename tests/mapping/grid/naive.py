"""Plain numpy twin of the numba kernel of :mod:`mapping.grid` (tests and benchmarks only).

The same geometry as ``mapping/grid/_kernels.py._backproject`` (eqs. 2-4, intended or
literal), vectorized over the cells; ``test_grid.py`` compares it with
:func:`mapping.grid.backproject`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def backproject_numpy(
    shape: tuple[int, int], ox: float, oy: float, res: float, H: FloatArray, r0: float,
    dr: float, px: float, py: float, heading: float, radius: float, literal: bool,
) -> FloatArray:
    """Twin of ``_kernels._backproject``: returns the block's contribution to G (eq. 5)."""
    ny, nx = shape
    n_max = H.shape[0] - 1
    n_samples = H.shape[1]
    iy, ix = np.mgrid[0:ny, 0:nx]
    out = np.zeros(shape)
    if literal:
        mxp, myp = math.floor(px / res + 0.5), math.floor(py / res + 0.5)
        mx = math.floor(ox / res + 0.5) + ix - mxp
        my = math.floor(oy / res + 0.5) + iy - myp
        r = np.sqrt((mx * res) ** 2 + (my * res) ** 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            safe = np.where(mx == 0, 1, mx)
            ang = np.where(mx == 0, np.sign(my) * np.pi / 2, np.arctan(my / safe))
        row = np.floor(np.abs(ang - heading) * n_max / np.pi + 0.5).astype(np.int64)
        n = np.floor((r - r0) / dr + 0.5).astype(np.int64)
        ok = ((mx != 0) | (my != 0)) & (r <= radius) & (row >= 0) & (row <= n_max)
        ok &= (n >= 0) & (n < n_samples)
        out[ok] = H[row[ok], n[ok]]
        return out
    dx = ox + ix * res - px
    dy = oy + iy * res - py
    r = np.sqrt(dx * dx + dy * dy)
    diff = np.mod(np.arctan2(dy, dx) - heading + np.pi, 2 * np.pi) - np.pi
    row = np.minimum(np.floor(np.abs(diff) * n_max / np.pi + 0.5).astype(np.int64), n_max)
    half = 0.5 * res
    r_lo = np.hypot(np.maximum(np.abs(dx) - half, 0), np.maximum(np.abs(dy) - half, 0))
    r_hi = np.hypot(np.abs(dx) + half, np.abs(dy) + half)
    lo = np.maximum(np.ceil((r_lo - r0) / dr).astype(np.int64), 0)
    hi = np.minimum(np.floor((r_hi - r0) / dr).astype(np.int64), n_samples - 1)
    for j in zip(*np.nonzero(r <= radius), strict=True):
        a, b = lo[j], hi[j]
        if a > b:
            n = math.floor((r[j] - r0) / dr + 0.5)
            out[j] = H[row[j], n] if 0 <= n < n_samples else 0.0
        else:
            out[j] = H[row[j], a:b + 1].max()
    return out
