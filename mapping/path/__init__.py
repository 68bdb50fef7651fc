"""Constant-speed trajectories of the sonar robot (paper Sec. 4, Fig. 4).

A path is a `Trajectory`: a chain of straight lines and circular arcs (an arc spline) at
exactly constant speed (default `PAPER_SPEED_M_S`, 0.1 m/s), so position, velocity, heading,
speed and yaw rate are exact and vectorized, velocity is continuous through every joint, and
outside ``[0, duration_s]`` the robot keeps moving straight along the end tangents.

Entry points: the constructors `polyline_path` (segments joined by tangent arcs),
`curve_path` (a cubic spline through points, turned into biarcs) and `stationary_path`; the
built-in paths `builtin_path`, `builtin_path_names`, `builtin_path_description`,
`builtin_path_scene`; wall clearance `path_inside`, `min_wall_distance_m`.

Notes
-----
Private modules: ``_trajectory`` holds `Trajectory`, evaluated by the numba kernel in
``_kernels`` (one pass for position and velocity; its numpy twin is in the tests);
``_construct`` the constructors; ``_builtin`` the built-in paths (``paper-a``, ``paper-b``
and ``<scene>-straight`` / ``<scene>-curve``) and the clearance checks.
"""

from __future__ import annotations

from mapping.path._builtin import (
    builtin_path,
    builtin_path_description,
    builtin_path_names,
    builtin_path_scene,
    min_wall_distance_m,
    path_inside,
)
from mapping.path._construct import (
    curve_path,
    polyline_path,
    stationary_path,
)
from mapping.path._trajectory import (
    PAPER_SPEED_M_S,
    Trajectory,
)

__all__ = [
    "PAPER_SPEED_M_S",
    "Trajectory",
    "builtin_path",
    "builtin_path_description",
    "builtin_path_names",
    "builtin_path_scene",
    "curve_path",
    "min_wall_distance_m",
    "path_inside",
    "polyline_path",
    "stationary_path",
]
