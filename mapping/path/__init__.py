"""TODO docstring."""

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
    position_velocity_numpy,
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
    "position_velocity_numpy",
    "stationary_path",
]
