"""Plain numpy twin of the numba kernel of :mod:`mapping.path` (tests and benchmarks only).

The same formulas as ``mapping/path/_kernels.py``, vectorized over the times and written from
the public fields of :class:`~mapping.path.Trajectory`; ``test_path.py`` compares the two.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.path import Trajectory

FloatArray = NDArray[np.float64]


def end_state(tr: Trajectory) -> tuple[float, float, float]:
    """Exact end point and heading of the last primitive."""
    ds = tr.total_length_m - float(tr.s0_m[-1])
    k, th0 = float(tr.kappa_1_m[-1]), float(tr.theta0_rad[-1])
    half = 0.5 * k * ds
    chord = ds * float(np.sinc(half / np.pi))
    return (float(tr.x0_m[-1]) + chord * math.cos(th0 + half),
            float(tr.y0_m[-1]) + chord * math.sin(th0 + half), th0 + 2 * half)


def position_velocity_numpy(tr: Trajectory, t_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Twin of :meth:`Trajectory.position_velocity`: position (n, 2) and velocity (n, 2).

    Arc length ``s = speed t``; primitive = last with ``s0 <= s`` (the first before the
    start, followed straight); after the end, straight on from the end point and heading.
    """
    t = np.asarray(t_s, dtype=np.float64)
    s = tr.cruise_speed_m_s * t
    idx = np.clip(np.searchsorted(tr.s0_m, s, side="right") - 1, 0, tr.s0_m.size - 1)
    ds = s - tr.s0_m[idx]
    before, after = s < 0.0, s > tr.total_length_m
    kappa = np.where(before | after, 0.0, tr.kappa_1_m[idx])
    x0, y0, th0 = tr.x0_m[idx], tr.y0_m[idx], tr.theta0_rad[idx]
    if after.any():  # continue from the end point along the end tangent
        end = end_state(tr)
        x0 = np.where(after, end[0], x0)
        y0 = np.where(after, end[1], y0)
        th0 = np.where(after, end[2], th0)
        ds = np.where(after, s - tr.total_length_m, ds)
    half = 0.5 * kappa * ds
    chord = ds * np.sinc(half / np.pi)
    mid = th0 + half
    pos = np.column_stack([x0 + chord * np.cos(mid), y0 + chord * np.sin(mid)])
    theta = th0 + 2.0 * half
    v = tr.cruise_speed_m_s
    return pos, np.column_stack([v * np.cos(theta), v * np.sin(theta)])
