"""Coverage: the cells of a map grid that the runs observed.

A cell is *observed* when it lies within ``max_range_m`` of at least one tracked pose and, when
walls are given, the straight segment from that pose to the cell centre crosses no wall. A cell
that a wall passes through (:func:`mapping.wallmap.rasterize_walls`) is seen from the side of
the wall the pose is on: the wall itself is observed, what lies behind it is not.

Coverage is what the sonar *could* have observed, not what it heard: a wall is heard only at its
specular points, so a cell inside coverage may still carry no echo. Map quality
(:mod:`mapping.quality`) is scored inside coverage, and the map file stores it so that cells
outside read as unknown rather than empty.

Pure numpy: per pose, the window of cells within range, one orientation test per wall over it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mapping.wallmap import rasterize_walls

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def _check(poses: FloatArray, x_m: FloatArray, y_m: FloatArray, max_range_m: float,
           walls_m: FloatArray | None) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] < 2:
        raise ValueError(f"poses must have shape (n, 3) (or (n, 2)), got {p.shape}")
    x = np.asarray(x_m, dtype=np.float64)
    y = np.asarray(y_m, dtype=np.float64)
    for name, a in (("x_m", x), ("y_m", y)):
        if a.ndim != 1 or a.size < 1 or not np.all(np.isfinite(a)):
            raise ValueError(f"{name} must be a non-empty finite 1-D array, got shape {a.shape}")
        if a.size > 1 and not np.all(np.diff(a) > 0):
            raise ValueError(f"{name} must be increasing")
    if not (np.isfinite(max_range_m) and max_range_m > 0):
        raise ValueError(f"max_range_m must be > 0, got {max_range_m}")
    w = np.zeros((0, 4)) if walls_m is None else np.asarray(walls_m, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] != 4 or not np.all(np.isfinite(w)):
        raise ValueError(f"walls_m must be a finite (n, 4) array, got shape {w.shape}")
    tracked = p[np.all(np.isfinite(p[:, :2]), axis=1), :2]
    return tracked, x, y, w


def _orient(ax: float, ay: float, bx: float, by: float, px: FloatArray, py: FloatArray
            ) -> FloatArray:
    """Sign of the turn a -> b -> p (+1 left, -1 right, 0 collinear)."""
    return np.sign((bx - ax) * (py - ay) - (by - ay) * (px - ax))


def _blocked(pose: FloatArray, wall: FloatArray, cx: FloatArray, cy: FloatArray) -> BoolArray:
    """Cells (cx, cy) strictly beyond ``wall`` whose sight line from ``pose`` meets it (end
    points included)."""
    px, py = float(pose[0]), float(pose[1])
    ax, ay, bx, by = (float(v) for v in wall)
    side_pose = np.sign((bx - ax) * (py - ay) - (by - ay) * (px - ax))
    if side_pose == 0:  # pose on the wall's line: the wall hides nothing
        return np.zeros(cx.shape, dtype=bool)
    beyond = _orient(ax, ay, bx, by, cx, cy) == -side_pose
    # a sight line through an end point is blocked too: rays leak through no corner
    return beyond & (_orient(px, py, ax, ay, cx, cy) * _orient(px, py, bx, by, cx, cy) <= 0)


def _distance_to_segment(point: FloatArray, wall: FloatArray) -> float:
    a, b = wall[:2], wall[2:]
    ab = b - a
    denom = float(ab @ ab)
    t = 0.0 if denom == 0 else min(max(float((point - a) @ ab) / denom, 0.0), 1.0)
    return float(np.hypot(*(point - (a + t * ab))))


def _window(axis: FloatArray, centre: float, half_width: float) -> tuple[int, int]:
    """Index range [i0, i1) of the sorted ``axis`` within ``half_width`` of ``centre``."""
    return (int(np.searchsorted(axis, centre - half_width, "left")),
            int(np.searchsorted(axis, centre + half_width, "right")))


def coverage_mask(poses: FloatArray, x_m: FloatArray, y_m: FloatArray, max_range_m: float,
                  walls_m: FloatArray | None = None) -> BoolArray:
    """Cells within ``max_range_m`` of a tracked pose and, with walls, in its line of sight.

    Parameters
    ----------
    poses : ndarray, shape (n, 3)
        Tracked poses ``x_m, y_m, heading_rad`` (heading unused); rows with NaN (untracked
        blocks) are skipped.
    x_m, y_m : ndarray, shapes (nx,) and (ny,)
        Increasing cell-centre coordinates of the grid (``WallMap.x_m``, ``WallMap.y_m``).
    max_range_m : float
        Largest range the runs could observe (the build radius), metres.
    walls_m : ndarray, shape (w, 4), optional
        Walls ``x0, y0, x1, y1`` that block the line of sight. A cell the wall passes through
        counts as seen from either side.

    Returns
    -------
    ndarray, shape (ny, nx), bool
        True on observed cells; all False when no pose is tracked.

    Raises
    ------
    ValueError
        Naming the argument of the wrong shape or value.
    """
    tracked, x, y, walls = _check(poses, x_m, y_m, max_range_m, walls_m)
    seen = np.zeros((y.size, x.size), dtype=bool)
    on_wall = [rasterize_walls(w[None, :], x, y) for w in walls]
    r2 = max_range_m * max_range_m
    for pose in tracked:
        ix0, ix1 = _window(x, float(pose[0]), max_range_m)
        iy0, iy1 = _window(y, float(pose[1]), max_range_m)
        if ix0 >= ix1 or iy0 >= iy1:
            continue
        cx, cy = np.meshgrid(x[ix0:ix1], y[iy0:iy1])
        visible = (cx - pose[0]) ** 2 + (cy - pose[1]) ** 2 <= r2
        for wall, wall_cells in zip(walls, on_wall, strict=True):
            if _distance_to_segment(pose, wall) > max_range_m:  # cannot hide a cell in range
                continue
            hidden = _blocked(pose, wall, cx, cy) & ~wall_cells[iy0:iy1, ix0:ix1]
            visible &= ~hidden
        seen[iy0:iy1, ix0:ix1] |= visible
    return seen
