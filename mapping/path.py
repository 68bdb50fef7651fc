"""Constant-speed trajectories of the sonar robot (issue 3, item 2; paper Sec. 4, Fig. 4).

Every trajectory is an *arc spline*: a chain of primitives, each a straight line or a circular
arc given by its start point, start heading, curvature ``kappa`` and length. Position at arc
length ``s`` into a primitive is exact and cheap::

    heading(s) = theta0 + kappa s
    p(s) = p0 + s sinc(kappa s / 2) [cos(theta0 + kappa s / 2), sin(theta0 + kappa s / 2)]

(evaluated in a numba kernel, ``_path_kernels.py``, with a numpy twin for the tests),
so speed is constant *exactly* (``|velocity| = speed``), velocity is continuous (C1) wherever
consecutive primitives share their end tangent, and yaw rate is ``speed * kappa``.

- :func:`polyline_path`: straight segments joined by circular arcs tangent to both.
- :func:`curve_path`: a cubic spline through the points, turned into an arc spline by fitting a
  biarc between closely spaced spline samples (each pair matches the spline's points and
  tangents), so the curve is C1 with piecewise-constant curvature and exact constant speed.
- :func:`stationary_path`: speed 0 at a fixed pose.

Outside ``[0, duration_s]`` the robot continues at constant velocity along the end tangents
(before ``t = 0`` along the start tangent, after the end along the end tangent), so a
retarded-time solve slightly before the start or after the end is well defined.

The paper's robot moves at 0.1 m/s, so one 1.023 s block covers 0.1023 m; paths of 2-6 m
give 20-60 blocks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicSpline

if TYPE_CHECKING:
    from mapping.scene import Scene

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
        end tangents. Runs in a numba kernel (twin: :func:`position_velocity_numpy`).
        """
        from mapping._path_kernels import _position_velocity, _position_velocity_parallel

        t = np.ascontiguousarray(t_s, dtype=np.float64)
        if t.ndim != 1:
            raise ValueError(f"t_s must be a 1-D array, got shape {t.shape}")
        pos = np.empty((t.size, 2))
        vel = np.empty((t.size, 2))
        ex, ey, eth = self._end_state()
        args = (self.cruise_speed_m_s, self.s0_m, self.x0_m, self.y0_m, self.theta0_rad,
                self.kappa_1_m, self.total_length_m, ex, ey, eth, pos, vel)
        if t.size >= _PARALLEL_MIN_TIMES:
            import numba

            _position_velocity_parallel(t, numba.get_num_threads(), *args)
        else:  # threads cost more than they save on small inputs (and on a busy machine)
            _position_velocity(t, 0, t.size, *args)
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


def wrap_angle(theta_rad: ArrayLike) -> FloatArray:
    """Wrap angles to (-pi, pi] (ROS REP-103 yaw); exact for inputs already in range.

    ``theta - 2 pi round(theta / 2 pi)`` leaves |theta| <= pi untouched (no ``+ pi - pi``
    round-off) and the two boundary fixes keep -pi out of the result even when rounding
    lands on it (the float just above pi used to come back as -pi).
    """
    th = np.asarray(theta_rad, dtype=np.float64)
    w = th - 2.0 * np.pi * np.round(th / (2.0 * np.pi))
    w = np.where(w <= -np.pi, w + 2.0 * np.pi, w)
    return np.asarray(np.where(w > np.pi, w - 2.0 * np.pi, w))


def position_velocity_numpy(trajectory: Trajectory,
                            t_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Plain numpy twin of :meth:`Trajectory.position_velocity` (same formulas; for tests)."""
    tr = trajectory
    s, ds, idx, kappa = tr._locate(t_s)
    x0, y0, th0 = tr.x0_m[idx], tr.y0_m[idx], tr.theta0_rad[idx]
    after = s > tr.total_length_m
    if after.any():  # continue from the end point along the end tangent
        end = tr._end_state()
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


# ---- construction ------------------------------------------------------------------------
@dataclass
class _Builder:
    """Accumulates line/arc primitives (start point, heading, curvature, length)."""

    x: list[float]
    y: list[float]
    theta: list[float]
    kappa: list[float]
    length: list[float]

    def add(self, p: NDArray[np.float64], theta: float, kappa: float, length: float) -> None:
        if length > 1e-12:
            self.x.append(float(p[0]))
            self.y.append(float(p[1]))
            self.theta.append(theta)
            self.kappa.append(kappa)
            self.length.append(length)

    def build(self, speed_m_s: float, name: str) -> Trajectory:
        lengths = np.asarray(self.length)
        s0 = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
        return Trajectory(
            s0_m=s0, x0_m=np.asarray(self.x), y0_m=np.asarray(self.y),
            theta0_rad=np.asarray(self.theta), kappa_1_m=np.asarray(self.kappa),
            total_length_m=float(lengths.sum()), cruise_speed_m_s=float(speed_m_s), name=name,
        )


def _check_speed(speed_m_s: float) -> None:
    if not (math.isfinite(speed_m_s) and speed_m_s > 0):
        raise ValueError(f"speed_m_s must be finite and > 0, got {speed_m_s}")


def _check_points(points_m: ArrayLike, minimum: int) -> FloatArray:
    pts = np.asarray(points_m, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < minimum:
        raise ValueError(f"points_m must have shape (n >= {minimum}, 2), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("points_m must be finite")
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    if np.any(seg <= 1e-9):
        i = int(np.argmax(seg <= 1e-9))
        raise ValueError(f"points_m has a zero-length segment between points {i} and {i + 1}")
    return pts


def polyline_path(points_m: ArrayLike, speed_m_s: float = PAPER_SPEED_M_S,
                  corner_radius_m: float = 0.3, name: str = "") -> Trajectory:
    """Straight segments through ``points_m`` joined by circular arcs tangent to both.

    Parameters
    ----------
    points_m : array (n >= 2, 2)
        Corner points; the path starts at the first and ends at the last.
    speed_m_s : float
        Constant speed, > 0 (paper: 0.1 m/s).
    corner_radius_m : float
        Radius of every rounding arc, > 0. At a corner turning by ``phi`` the arc starts
        ``r tan(|phi| / 2)`` before the corner; these set-backs must fit in each segment.
    name : str
        Label of the trajectory.

    Raises
    ------
    ValueError
        Naming ``points_m`` (shape, non-finite, zero-length segment, U-turn),
        ``corner_radius_m`` (<= 0 or too large for a segment) or ``speed_m_s``.
    """
    _check_speed(speed_m_s)
    pts = _check_points(points_m, 2)
    if not (math.isfinite(corner_radius_m) and corner_radius_m > 0):
        raise ValueError(f"corner_radius_m must be finite and > 0, got {corner_radius_m}")
    d = np.diff(pts, axis=0)
    seg_len = np.linalg.norm(d, axis=1)
    u = d / seg_len[:, None]
    headings = np.arctan2(u[:, 1], u[:, 0])
    turns = wrap_angle(np.diff(headings))  # turn at interior corner i+1
    if np.any(np.abs(turns) >= np.pi - 1e-9):
        i = int(np.argmax(np.abs(turns) >= np.pi - 1e-9)) + 1
        raise ValueError(f"points_m reverses direction at point {i} (a U-turn cannot be rounded)")
    setback = corner_radius_m * np.tan(np.abs(turns) / 2)
    need = np.concatenate([[0.0], setback]) + np.concatenate([setback, [0.0]])
    if np.any(need > seg_len * (1 + 1e-12)):
        # largest radius that fits every segment
        tan_half = np.tan(np.abs(turns) / 2)
        per_r = np.concatenate([[0.0], tan_half]) + np.concatenate([tan_half, [0.0]])
        with np.errstate(divide="ignore", over="ignore"):
            r_max = float(np.min(np.where(per_r > 0, seg_len / per_r, np.inf)))
        i = int(np.argmax(need > seg_len * (1 + 1e-12)))
        raise ValueError(
            f"corner_radius_m = {corner_radius_m} does not fit segment {i} "
            f"(length {seg_len[i]:.4g} m); it must be <= {r_max:.4g} m for these points_m"
        )
    b = _Builder([], [], [], [], [])
    theta = float(headings[0])
    start = pts[0]
    for i in range(len(seg_len)):
        end_cut = setback[i] if i < len(turns) else 0.0
        start_cut = setback[i - 1] if i > 0 else 0.0
        b.add(start, theta, 0.0, float(seg_len[i] - start_cut - end_cut))
        if i < len(turns):
            phi = float(turns[i])
            arc_start = pts[i + 1] - end_cut * u[i]
            if phi != 0.0:
                b.add(arc_start, theta, math.copysign(1.0 / corner_radius_m, phi),
                      corner_radius_m * abs(phi))
            theta += phi  # unwrapped heading keeps arcs continuous
            start = pts[i + 1] + setback[i] * u[i + 1]
    if not b.length:  # cannot happen: segments have length > 0
        raise ValueError("points_m gives an empty path")
    return b.build(speed_m_s, name)


def _biarc(b: _Builder, p0: FloatArray, t0: FloatArray, theta0: float,
           p1: FloatArray, t1: FloatArray) -> float:
    """Append the equal-parameter biarc from (p0, t0) to (p1, t1); returns the end heading."""
    v = p1 - p0
    tsum = t0 + t1
    a = 2.0 * (1.0 - float(t0 @ t1))
    bb = float(v @ tsum)
    c = float(v @ v)
    denom = bb + math.sqrt(max(bb * bb + a * c, 0.0))
    if not denom > 0:
        raise ValueError("points_m gives a spline that turns back on itself between samples; "
                         "spread the points more evenly")
    d = c / denom  # stable root of a d^2 + 2 b d - c = 0
    joint = 0.5 * (p0 + d * t0 + p1 - d * t1)
    theta = _arc_to(b, p0, theta0, joint)
    return _arc_to(b, joint, theta, p1)


def _arc_to(b: _Builder, p0: FloatArray, theta0: float, p1: FloatArray) -> float:
    """Append the arc leaving ``p0`` at heading ``theta0`` and reaching ``p1``; end heading."""
    w = p1 - p0
    chord = math.hypot(w[0], w[1])
    alpha = math.atan2(math.cos(theta0) * w[1] - math.sin(theta0) * w[0],
                       math.cos(theta0) * w[0] + math.sin(theta0) * w[1])
    length = chord if alpha == 0.0 else chord * alpha / math.sin(alpha)
    b.add(p0, theta0, 2.0 * alpha / length if length > 0 else 0.0, length)
    return theta0 + 2.0 * alpha


def curve_path(points_m: ArrayLike, speed_m_s: float = PAPER_SPEED_M_S, closed: bool = False,
               name: str = "", max_step_m: float = 0.05) -> Trajectory:
    """Smooth C1 curve through ``points_m`` at exactly constant speed.

    A cubic spline through the points (chord-length parameter; periodic if ``closed``,
    natural ends otherwise) is sampled at most ``max_step_m`` apart and every pair of
    consecutive samples is joined by a biarc matching the spline's points and unit tangents.
    The path passes exactly through every point; its curvature is piecewise constant and
    follows the spline's.

    Parameters
    ----------
    points_m : array (n, 2)
        Points to pass through; n >= 2 (n >= 3 if ``closed``).
    speed_m_s : float
        Constant speed, > 0.
    closed : bool
        Return to the first point with a matching tangent (a loop).
    name : str
        Label of the trajectory.
    max_step_m : float
        Largest spacing of the spline samples joined by biarcs, > 0.

    Raises
    ------
    ValueError
        Naming ``points_m``, ``speed_m_s`` or ``max_step_m``.
    """
    _check_speed(speed_m_s)
    pts = _check_points(points_m, 3 if closed else 2)
    if not (math.isfinite(max_step_m) and max_step_m > 0):
        raise ValueError(f"max_step_m must be finite and > 0, got {max_step_m}")
    if closed:
        if np.linalg.norm(pts[-1] - pts[0]) <= 1e-9:
            pts = pts[:-1]
        pts = np.vstack([pts, pts[:1]])
        if pts.shape[0] < 4:
            raise ValueError("points_m must hold >= 3 distinct points for a closed curve")
    u = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    spline = CubicSpline(u, pts, bc_type="periodic" if closed else "natural")
    n_sub = np.maximum(1, np.ceil(np.diff(u) / max_step_m).astype(int))
    knots = np.concatenate([np.linspace(u[i], u[i + 1], n_sub[i] + 1)[:-1]
                            for i in range(len(n_sub))] + [u[-1:]])
    p = spline(knots)
    tan = spline(knots, 1)
    norm = np.linalg.norm(tan, axis=1)
    if np.any(norm <= 1e-12):
        raise ValueError("points_m gives a spline with a cusp; spread the points more evenly")
    tan = tan / norm[:, None]
    p[-1] = pts[-1]  # exact end (and exact closure for a loop)
    b = _Builder([], [], [], [], [])
    theta = math.atan2(tan[0, 1], tan[0, 0])
    for i in range(len(knots) - 1):
        theta = _biarc(b, p[i], tan[i], theta, p[i + 1], tan[i + 1])
    return b.build(speed_m_s, name)


def stationary_path(xy_m: ArrayLike, heading_rad: float, duration_s: float,
                    name: str = "") -> Trajectory:
    """A robot standing at ``xy_m`` facing ``heading_rad`` for ``duration_s`` (speed 0)."""
    xy = np.asarray(xy_m, dtype=np.float64)
    if xy.shape != (2,) or not np.all(np.isfinite(xy)):
        raise ValueError(f"xy_m must be 2 finite numbers, got {xy_m!r}")
    if not math.isfinite(heading_rad):
        raise ValueError(f"heading_rad must be finite, got {heading_rad}")
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"duration_s must be finite and > 0, got {duration_s}")
    return Trajectory(
        s0_m=np.zeros(1), x0_m=xy[:1].copy(), y0_m=xy[1:].copy(),
        theta0_rad=np.array([float(wrap_angle(heading_rad))]), kappa_1_m=np.zeros(1),
        total_length_m=0.0, cruise_speed_m_s=0.0, hold_s=float(duration_s), name=name,
    )


# ---- clearance ---------------------------------------------------------------------------
def min_wall_distance_m(scene: Scene, trajectory: Trajectory, step_m: float = 0.01) -> float:
    """Smallest distance from the path (sampled every ``step_m`` of arc length) to any wall.

    The sampled minimum overestimates the true one by at most ``step_m / 2``.
    """
    if not (math.isfinite(step_m) and step_m > 0):
        raise ValueError(f"step_m must be finite and > 0, got {step_m}")
    n = max(2, int(math.ceil(trajectory.length_m / step_m)) + 1)
    t = np.linspace(0.0, trajectory.duration_s, n)
    p = trajectory.position(t)
    seg = scene.segments()
    a, ab = seg[:, 0], seg[:, 1] - seg[:, 0]
    rel = p[:, None, :] - a[None]
    lam = np.clip(np.einsum("nwk,wk->nw", rel, ab) / np.einsum("wk,wk->w", ab, ab), 0.0, 1.0)
    d = np.linalg.norm(rel - lam[..., None] * ab[None], axis=2)
    return float(d.min())


def path_inside(scene: Scene, trajectory: Trajectory, clearance_m: float = 0.3,
                step_m: float = 0.01) -> bool:
    """True if the path keeps at least ``clearance_m`` (less ``step_m / 2``) from every wall.

    It therefore never crosses a wall; which side of the walls it runs on is set by its
    start point (use one inside the room).
    """
    return min_wall_distance_m(scene, trajectory, step_m) >= clearance_m - 0.5 * step_m


# ---- built-in paths ----------------------------------------------------------------------
_PATHS: dict[str, tuple[str, str, tuple[tuple[float, float], ...], str]] = {
    # name: (kind, scene, points, description)
    "paper-a": ("line", "paper", ((1.0, 1.0), (3.5, 3.5)),
                "paper path A: straight at pi/4 from (1, 1) through (a) = (2, 2) to (3.5, 3.5)"),
    "paper-b": ("curve", "paper", ((1.0, 1.3), (1.2, 2.8), (2.3, 3.45), (3.6, 3.3),
                                   (3.95, 2.4), (3.3, 1.85)),
                "paper path B: a large curve sweeping the heading through ~250 degrees"),
    "shoebox-straight": ("line", "shoebox", ((0.5, 0.8), (3.5, 2.2)), "diagonal across the room"),
    "shoebox-curve": ("loop", "shoebox", ((1.3, 0.9), (2.7, 0.9), (3.1, 1.5), (2.7, 2.1),
                                          (1.3, 2.1), (0.9, 1.5)), "one lap around the room"),
    "l-room-straight": ("line", "l-room", ((0.6, 1.0), (4.4, 1.0)), "along the bottom arm"),
    "l-room-curve": ("curve", "l-room", ((4.0, 1.0), (2.5, 1.0), (1.1, 1.3), (1.0, 2.8),
                                         (1.0, 4.0)), "round the inner corner of the L"),
    "corridor-straight": ("line", "corridor", ((0.5, 1.0), (6.0, 1.0)),
                          "down the centre line of the corridor"),
    "corridor-curve": ("curve", "corridor", ((0.6, 0.6), (2.0, 1.4), (3.5, 0.6), (5.0, 1.4),
                                             (6.0, 0.9)), "weaving down the corridor"),
    "pillar-straight": ("line", "pillar", ((0.5, 0.9), (4.5, 0.9)), "past the column"),
    "pillar-curve": ("curve", "pillar", ((1.0, 1.0), (2.5, 0.8), (3.9, 1.2), (4.0, 2.8),
                                         (2.5, 3.2)), "half a lap around the column"),
}


def builtin_path_names() -> list[str]:
    """Names of the built-in paths (each belongs to the scene named by its prefix)."""
    return list(_PATHS)


def builtin_path_scene(name: str) -> str:
    """Name of the built-in scene the built-in path ``name`` was drawn for."""
    _check_path_name(name)
    return _PATHS[name][1]


def builtin_path_description(name: str) -> str:
    """One-line description of the built-in path ``name``."""
    _check_path_name(name)
    return _PATHS[name][3]


def _check_path_name(name: str) -> None:
    if name not in _PATHS:
        raise ValueError(f"path name must be one of {builtin_path_names()}, got {name!r}")


def builtin_path(name: str, speed_m_s: float = PAPER_SPEED_M_S) -> Trajectory:
    """The built-in path ``name`` (see :func:`builtin_path_names`) at ``speed_m_s``."""
    _check_path_name(name)
    kind, _, points, _ = _PATHS[name]
    if kind == "line":
        return polyline_path(points, speed_m_s=speed_m_s, name=name)
    return curve_path(points, speed_m_s=speed_m_s, closed=(kind == "loop"), name=name)
