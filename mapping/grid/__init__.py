"""The wall map G by back-projection of heat maps (paper Sec. 2.2, eqs. 2-5).

Each block's polar heat map ``H[n_theta, n_tau]`` is read at every map cell within a radius of
the block's tracked pose and added into G. A cell at ``+theta`` from the direction of travel
and its mirror at ``-theta`` read the same row: the paper's left/right mirror, kept on purpose.
Two geometries (`GridParams` ``literal``): the intended one (default: exact pose, angle by
``atan2`` wrapped before ``abs``, the maximum of H over the range interval the cell covers)
and eqs. 2-5 as printed (``literal=True``). Each block's noise floor is removed first
(`GridParams` ``floor``, `remove_floor`).

Entry points: `backproject` (heat maps + poses -> G on a `GridExtent`), `accumulate` (add
into an existing G), `map_extent` / `union_extent` (aligned extents covering the poses),
`cartesian_heatmap` (one block drawn in world coordinates).

Notes
-----
Private modules: ``_backprojection`` holds the geometry, the floor removal and the public
functions; ``_kernels`` the numba kernel (rows of G in parallel, deterministic), which the tests
compare with its numpy twin (``tests/mapping/grid/naive.py``).
"""

from __future__ import annotations

from mapping.grid._backprojection import (
    GridExtent,
    GridParams,
    accumulate,
    backproject,
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
    "cartesian_heatmap",
    "map_extent",
    "remove_floor",
    "union_extent",
]
