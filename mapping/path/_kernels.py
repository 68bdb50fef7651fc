"""numba kernel of :mod:`mapping.path` (private; imported only by ``mapping/path/_trajectory.py``).

The kernels take the path as one :class:`_Primitives` record, built once per call by
:meth:`mapping.path.Trajectory.position_velocity`. The plain numpy twin lives with the tests
(``tests/mapping/path/naive.py``), which compare the two.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from mapping.numba_config import NUMBA_FLAGS, PARALLEL


class _Primitives(NamedTuple):
    """A :class:`~mapping.path.Trajectory` as the kernels read it."""

    speed: float  # cruise speed, m/s
    s0: np.ndarray  # (K,) arc length at the start of each primitive
    x0: np.ndarray  # (K,) start point
    y0: np.ndarray
    th0: np.ndarray  # (K,) start heading
    kappa: np.ndarray  # (K,) curvature
    total: float  # arc length of the path
    end_x: float  # exact end point and heading of the last primitive
    end_y: float
    end_th: float


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _position_velocity_parallel(
    t: np.ndarray, n_chunks: int, path: _Primitives, pos: np.ndarray, vel: np.ndarray
) -> None:
    """:func:`_position_velocity` over ``n_chunks`` contiguous chunks of ``t`` in parallel."""
    n = t.size
    for c in numba.prange(n_chunks):
        lo = c * n // n_chunks
        hi = (c + 1) * n // n_chunks
        _position_velocity(t, lo, hi, path, pos, vel)


@numba.njit(**NUMBA_FLAGS)
def _position_velocity(
    t: np.ndarray, first: int, stop: int, path: _Primitives, pos: np.ndarray, vel: np.ndarray
) -> None:
    """Position and velocity at times ``t[first:stop]`` into ``pos`` and ``vel`` (n, 2).

    Arc length ``s = speed t``; primitive ``j`` is the last with ``s0[j] <= s`` (0 before the
    start); ``p = p0 + ds sinc(kappa ds / 2) (cos, sin)(th0 + kappa ds / 2)``, heading
    ``th0 + kappa ds``. Before 0 the first primitive is followed as a straight line; after
    ``total`` the path continues straight from the end point ``(end_x, end_y)`` at ``end_th``.
    """
    speed, s0, x0, y0, th0, kappa = path.speed, path.s0, path.x0, path.y0, path.th0, path.kappa
    total, end_x, end_y, end_th = path.total, path.end_x, path.end_y, path.end_th
    k_prims = s0.size
    for i in range(first, stop):
        s = speed * t[i]
        if s > total:
            ds = s - total
            th = end_th
            px = end_x + ds * math.cos(th)
            py = end_y + ds * math.sin(th)
        else:
            lo = 0
            hi = k_prims
            while lo < hi:
                mid = (lo + hi) // 2
                if s0[mid] <= s:
                    lo = mid + 1
                else:
                    hi = mid
            j = lo - 1
            if j < 0:
                j = 0
            ds = s - s0[j]
            k = kappa[j] if s >= 0.0 else 0.0
            half = 0.5 * k * ds
            chord = ds if half == 0.0 else ds * math.sin(half) / half
            m = th0[j] + half
            px = x0[j] + chord * math.cos(m)
            py = y0[j] + chord * math.sin(m)
            th = th0[j] + 2.0 * half
        pos[i, 0] = px
        pos[i, 1] = py
        vel[i, 0] = speed * math.cos(th)
        vel[i, 1] = speed * math.sin(th)
