"""Constant-speed trajectories of the sonar robot (issue 3, item 2; paper Sec. 4, Fig. 4).

Every trajectory is an *arc spline*: a chain of primitives, each a straight line or a circular
arc given by its start point, start heading, curvature ``kappa`` and length. Position at arc
length ``s`` into a primitive is exact and cheap::

    heading(s) = theta0 + kappa s
    p(s) = p0 + s sinc(kappa s / 2) [cos(theta0 + kappa s / 2), sin(theta0 + kappa s / 2)]

(evaluated in a numba kernel, ``_kernels.py``, with a numpy twin in the tests),
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

The code is split by topic: :mod:`mapping.trajectory` (the :class:`Trajectory` type, its
evaluation, :func:`wrap_angle`) and :mod:`mapping.path_construct` (the three constructors).
This module holds the clearance checks and the built-in paths and re-exports the others.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from mapping.path._construct import curve_path, polyline_path
from mapping.path._trajectory import PAPER_SPEED_M_S, Trajectory

if TYPE_CHECKING:
    from mapping.scene import Scene



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
