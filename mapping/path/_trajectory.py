"""The constant-speed arc-spline trajectory of the sonar robot and its evaluation.

A :class:`Trajectory` is a chain of primitives, each a straight line or a circular arc given
by its start point, start heading, curvature ``kappa`` and length. Position at arc length
``s`` into a primitive is exact and cheap::

    heading(s) = theta0 + kappa s
    p(s) = p0 + s sinc(kappa s / 2) [cos(theta0 + kappa s / 2), sin(theta0 + kappa s / 2)]

(evaluated in a numba kernel, ``_kernels.py``, whose numpy twin lives with the tests), so
speed is constant *exactly*, and yaw
rate is ``speed * kappa``. Outside ``[0, duration_s]`` the robot continues at constant
velocity along the end tangents. Also :func:`wrap_angle`, the project's (-pi, pi] wrap.
The constructors live in :mod:`mapping.path_construct`; :mod:`mapping.path` re-exports all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.angles import wrap_angle

FloatArray = NDArray[np.float64]

#: Inputs at least this long use the multi-threaded kernel.
_PARALLEL_MIN_TIMES = 200_000

#: Default robot speed of the paper (Sec. 4) in m/s.
PAPER_SPEED_M_S = 0.1


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A constant-speed arc-spline trajectory; all methods take a 1-D array of times ``t_s``.

    Parameters
    ----------
    s0_m : ndarray (K,)
        Arc length at the start of each primitive, increasing from 0.
    x0_m, y0_m : ndarray (K,)
        Start point of each primitive.
    theta0_rad : ndarray (K,)
        Heading (direction of travel) at the start of each primitive, unwrapped.
    kappa_1_m : ndarray (K,)
        Signed curvature of each primitive (0 = straight, > 0 turns left).
    total_length_m : float
        Arc length of the whole path; the last primitive ends there.
    cruise_speed_m_s : float
        Constant speed along the path (0 for a stationary path).
    hold_s : float
        Duration of a stationary path (ignored when the speed is > 0).
    name : str
        Label (built-in paths use their name).
    """

    s0_m: FloatArray
    x0_m: FloatArray
    y0_m: FloatArray
    theta0_rad: FloatArray
    kappa_1_m: FloatArray
    total_length_m: float
    cruise_speed_m_s: float
    hold_s: float = 0.0
    name: str = ""

    def __post_init__(self) -> None:
        arrays = (self.s0_m, self.x0_m, self.y0_m, self.theta0_rad, self.kappa_1_m)
        k = self.s0_m.shape
        if len(k) != 1 or k[0] < 1 or any(a.shape != k for a in arrays):
            raise ValueError("s0_m, x0_m, y0_m, theta0_rad, kappa_1_m must share a shape (K >= 1,)")
        if not all(np.all(np.isfinite(a)) for a in arrays):
            raise ValueError("trajectory primitives must be finite")
        if self.s0_m[0] != 0.0 or np.any(np.diff(self.s0_m) < 0):
            raise ValueError("s0_m must start at 0 and not decrease")
        if not (math.isfinite(self.cruise_speed_m_s) and self.cruise_speed_m_s >= 0):
            raise ValueError(f"cruise_speed_m_s must be >= 0, got {self.cruise_speed_m_s}")
        for a in arrays:  # a frozen trajectory: its arrays are read-only too
            a.flags.writeable = False

    # ---- scalar facts ------------------------------------------------------------------
    @property
    def duration_s(self) -> float:
        """Time to travel the path (``length / speed``; the hold time if stationary)."""
        if self.cruise_speed_m_s == 0.0:
            return self.hold_s
        return self.total_length_m / self.cruise_speed_m_s

    @property
    def length_m(self) -> float:
        """Arc length of the path in metres."""
        return self.total_length_m

    # ---- evaluation --------------------------------------------------------------------
    def _locate(
        self, t_s: ArrayLike
    ) -> tuple[FloatArray, FloatArray, NDArray[np.intp], FloatArray]:
        """Arc length ``s``, offset ``ds`` into the primitive, its index and effective kappa."""
        t = np.asarray(t_s, dtype=np.float64)
        if t.ndim != 1:
            raise ValueError(f"t_s must be a 1-D array, got shape {t.shape}")
        s = self.cruise_speed_m_s * t
        idx = np.searchsorted(self.s0_m, s, side="right") - 1
        np.clip(idx, 0, self.s0_m.size - 1, out=idx)
        ds = s - self.s0_m[idx]
        kappa = self.kappa_1_m[idx]
        # outside [0, L]: straight lines along the end tangents
        before, after = s < 0.0, s > self.total_length_m
        if before.any() or after.any():
            kappa = np.where(before | after, 0.0, kappa)
        return s, ds, idx, kappa

    def _heading_unwrapped(self, t_s: ArrayLike) -> FloatArray:
        s, ds, idx, kappa = self._locate(t_s)
        theta = self.theta0_rad[idx] + kappa * ds
        after = s > self.total_length_m
        if after.any():  # the last primitive may be an arc: freeze its end heading
            k_last = self.kappa_1_m[-1]
            end_theta = self.theta0_rad[-1] + k_last * (self.total_length_m - self.s0_m[-1])
            theta = np.where(after, end_theta, theta)
        return theta

    def position_velocity(self, t_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Position (n, 2) in m and velocity (n, 2) in m/s at times ``t_s``, in one pass.

        Outside ``[0, duration_s]`` the robot moves straight at constant velocity along the
        end tangents. Runs in a numba kernel.
        """
        from mapping.path._kernels import (
            _position_velocity,
            _position_velocity_parallel,
            _Primitives,
        )

        t = np.ascontiguousarray(t_s, dtype=np.float64)
        if t.ndim != 1:
            raise ValueError(f"t_s must be a 1-D array, got shape {t.shape}")
        pos = np.empty((t.size, 2))
        vel = np.empty((t.size, 2))
        ex, ey, eth = self._end_state()
        path = _Primitives(self.cruise_speed_m_s, self.s0_m, self.x0_m, self.y0_m,
                           self.theta0_rad, self.kappa_1_m, self.total_length_m, ex, ey, eth)
        if t.size >= _PARALLEL_MIN_TIMES:
            import numba

            _position_velocity_parallel(t, numba.get_num_threads(), path, pos, vel)
        else:  # threads cost more than they save on small inputs (and on a busy machine)
            _position_velocity(t, 0, t.size, path, pos, vel)
        return pos, vel

    def position(self, t_s: ArrayLike) -> FloatArray:
        """Position (n, 2) in metres at times ``t_s`` (extrapolated straight outside [0, T])."""
        return self.position_velocity(t_s)[0]

    def velocity(self, t_s: ArrayLike) -> FloatArray:
        """Velocity (n, 2) in m/s: ``speed * (cos heading, sin heading)``."""
        return self.position_velocity(t_s)[1]

    def _end_state(self) -> tuple[float, float, float]:
        """Exact end point and heading of the last primitive."""
        ds = self.total_length_m - float(self.s0_m[-1])
        k, th0 = float(self.kappa_1_m[-1]), float(self.theta0_rad[-1])
        half = 0.5 * k * ds
        chord = ds * float(np.sinc(half / np.pi))
        return (float(self.x0_m[-1]) + chord * math.cos(th0 + half),
                float(self.y0_m[-1]) + chord * math.sin(th0 + half), th0 + 2 * half)

    def heading_rad(self, t_s: ArrayLike) -> FloatArray:
        """Direction of travel (n,) wrapped to (-pi, pi]."""
        return wrap_angle(self._heading_unwrapped(t_s))

    def pose(self, t_s: ArrayLike) -> FloatArray:
        """Pose (n, 3): ``[x_m, y_m, heading_rad]`` with heading wrapped to (-pi, pi]."""
        return np.column_stack([self.position(t_s), self.heading_rad(t_s)])

    def speed_m_s(self, t_s: ArrayLike) -> FloatArray:
        """Signed speed (n,) in m/s (constant here; negative would mean reversing)."""
        t = np.asarray(t_s, dtype=np.float64)
        return np.full(t.shape, self.cruise_speed_m_s)

    def yaw_rate_rad_s(self, t_s: ArrayLike) -> FloatArray:
        """Yaw rate (n,) in rad/s: ``speed * kappa`` (0 on straights and outside [0, T])."""
        _, _, _, kappa = self._locate(t_s)
        return self.cruise_speed_m_s * kappa
