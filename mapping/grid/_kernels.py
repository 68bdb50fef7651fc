"""numba kernels of :mod:`mapping.grid` (private; imported only by
``mapping/grid/_backprojection.py``).

The plain numpy twin lives with the tests (``tests/mapping/grid/naive.py``), which compare
it with :func:`mapping.grid.backproject`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mapping.numba_config import NUMBA_FLAGS, PARALLEL


@numba.njit(**NUMBA_FLAGS)
def _round_half_up(x: float) -> int:
    return int(math.floor(x + 0.5))


@numba.njit(**NUMBA_FLAGS)
def _cell_value(
    H: np.ndarray, xc: float, yc: float, half: float, px: float, py: float,
    heading: float, r0: float, dr: float, n_max: int, radius: float,
) -> float:
    """Intended geometry: atan2, wrapped |angle difference|, max of H over the cell's range."""
    dx = xc - px
    dy = yc - py
    r = math.sqrt(dx * dx + dy * dy)
    if r > radius:
        return 0.0
    diff = math.atan2(dy, dx) - heading
    diff = (diff + math.pi) % (2.0 * math.pi) - math.pi
    row = _round_half_up(abs(diff) * n_max / math.pi)
    if row > n_max:
        row = n_max
    # nearest point of the cell square and its farthest corner
    ex = max(abs(dx) - half, 0.0)
    ey = max(abs(dy) - half, 0.0)
    r_lo = math.sqrt(ex * ex + ey * ey)
    fx = abs(dx) + half
    fy = abs(dy) + half
    r_hi = math.sqrt(fx * fx + fy * fy)
    n_samples = H.shape[1]
    lo = int(math.ceil((r_lo - r0) / dr))
    hi = int(math.floor((r_hi - r0) / dr))
    if lo < 0:
        lo = 0
    if hi > n_samples - 1:
        hi = n_samples - 1
    if lo > hi:
        n = _round_half_up((r - r0) / dr)
        if n < 0 or n > n_samples - 1:
            return 0.0
        return H[row, n]
    best = H[row, lo]
    for n in range(lo + 1, hi + 1):
        if H[row, n] > best:
            best = H[row, n]
    return best


@numba.njit(**NUMBA_FLAGS)
def _cell_value_literal(
    H: np.ndarray, mx: int, my: int, res: float, heading: float, r0: float, dr: float,
    n_max: int, radius: float,
) -> float:
    """Eqs. 2-4 as printed: arctan(m_y/m_x), unwrapped difference, centre sample."""
    if mx == 0 and my == 0:
        return 0.0
    r = math.sqrt((mx * res) ** 2 + (my * res) ** 2)
    if r > radius:
        return 0.0
    if mx == 0:
        ang = math.pi / 2 if my > 0 else -math.pi / 2
    else:
        ang = math.atan(my / mx)
    row = _round_half_up(abs(ang - heading) * n_max / math.pi)
    if row < 0 or row > n_max:
        return 0.0
    n = _round_half_up((r - r0) / dr)
    if n < 0 or n > H.shape[1] - 1:
        return 0.0
    return H[row, n]


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _backproject(
    G: np.ndarray, ox: float, oy: float, res: float, H: np.ndarray, r0: float, dr: float,
    px: float, py: float, heading: float, radius: float, literal: bool,
) -> None:
    """Add one block's Cartesian heat map (eqs. 2-4) into G in place (eq. 5).

    Rows of G are independent, so the parallel loop is deterministic.
    """
    ny, nx = G.shape
    n_max = H.shape[0] - 1
    if literal:
        mxp = _round_half_up(px / res)
        myp = _round_half_up(py / res)
        cx = mxp * res
        cy = myp * res
    else:
        cx = px
        cy = py
    ix0 = max(int(math.floor((cx - radius - ox) / res)), 0)
    ix1 = min(int(math.ceil((cx + radius - ox) / res)), nx - 1)
    iy0 = max(int(math.floor((cy - radius - oy) / res)), 0)
    iy1 = min(int(math.ceil((cy + radius - oy) / res)), ny - 1)
    if ix0 > ix1 or iy0 > iy1:
        return
    mx0 = _round_half_up(ox / res)
    my0 = _round_half_up(oy / res)
    for iy in numba.prange(iy0, iy1 + 1):
        yc = oy + iy * res
        for ix in range(ix0, ix1 + 1):
            if literal:
                v = _cell_value_literal(
                    H, mx0 + ix - mxp, my0 + iy - myp, res, heading, r0, dr, n_max, radius
                )
            else:
                v = _cell_value(
                    H, ox + ix * res, yc, 0.5 * res, px, py, heading, r0, dr, n_max, radius
                )
            G[iy, ix] += v
