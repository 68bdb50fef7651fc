"""TODO docstring."""

from __future__ import annotations

from mapping.grid._backprojection import (
    GridExtent,
    GridParams,
    accumulate,
    backproject,
    backproject_numpy,
    cartesian_heatmap,
    map_extent,
    remove_floor,
    union_extent,
)

__all__ = [
    "GridExtent",
    "GridParams",
    "accumulate",
    "backproject",
    "backproject_numpy",
    "cartesian_heatmap",
    "map_extent",
    "remove_floor",
    "union_extent",
]
