"""Constructors of constant-speed trajectories (paper Sec. 4, Fig. 4).

- :func:`polyline_path`: straight segments joined by circular arcs tangent to both.
- :func:`curve_path`: a cubic spline through the points, turned into an arc spline by fitting a
  biarc between closely spaced spline samples (each pair matches the spline's points and
  tangents), so the curve is C1 with piecewise-constant curvature and exact constant speed.
- :func:`stationary_path`: speed 0 at a fixed pose.

Each returns a :class:`~mapping.trajectory.Trajectory`; :mod:`mapping.path` re-exports them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicSpline

from mapping.angles import wrap_angle
from mapping.path._trajectory import PAPER_SPEED_M_S, FloatArray, Trajectory


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
