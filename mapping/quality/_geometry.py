"""Geometry of the quality figures: distances to wall segments, samples along them, which
samples the runs observed, cell centres."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mapping.wallmap import WallMap

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def _check_segments(segments: FloatArray) -> FloatArray:
    seg = np.asarray(segments, dtype=np.float64)
    if seg.ndim != 3 or seg.shape[1:] != (2, 2) or seg.shape[0] < 1:
        raise ValueError(f"segments must have shape (W >= 1, 2, 2), got {seg.shape}")
    if not np.all(np.isfinite(seg)):
        raise ValueError("segments contains NaN or inf")
    return seg


def distance_to_walls(points: FloatArray, segments: FloatArray) -> FloatArray:
    """Euclidean distance from each point (..., 2) to the nearest segment of (W, 2, 2)."""
    seg = _check_segments(segments)
    p = np.asarray(points, dtype=np.float64)
    flat = p.reshape(-1, 2)
    best = np.full(flat.shape[0], np.inf)
    for a, b in seg:
        ab = b - a
        denom = float(ab @ ab)
        t = np.zeros(flat.shape[0]) if denom == 0 else np.clip((flat - a) @ ab / denom, 0, 1)
        d = np.hypot(*(flat - (a + t[:, None] * ab)).T)
        best = np.minimum(best, d)
    return best.reshape(p.shape[:-1])


def wall_samples(segments: FloatArray, spacing_m: float) -> FloatArray:
    """Points along every segment at most ``spacing_m`` apart, shape (n, 2)."""
    seg = _check_segments(segments)
    if not spacing_m > 0:
        raise ValueError(f"spacing_m must be > 0, got {spacing_m}")
    pts = []
    for a, b in seg:
        n = max(int(math.ceil(np.hypot(*(b - a)) / spacing_m)), 1)
        t = (np.arange(n) + 0.5) / n
        pts.append(a + t[:, None] * (b - a))
    return np.concatenate(pts)


def cell_centres(wallmap: WallMap) -> FloatArray:
    """World coordinates of every cell centre, shape (ny, nx, 2)."""
    x, y = np.meshgrid(wallmap.x_m, wallmap.y_m)
    return np.stack([x, y], axis=-1)



def wall_sample_index(segments: FloatArray, spacing_m: float) -> NDArray[np.int64]:
    """Index of the segment each point of :func:`wall_samples` lies on, shape (n,)."""
    seg = _check_segments(segments)
    if not spacing_m > 0:
        raise ValueError(f"spacing_m must be > 0, got {spacing_m}")
    counts = [max(int(math.ceil(np.hypot(*(b - a)) / spacing_m)), 1) for a, b in seg]
    return np.repeat(np.arange(seg.shape[0], dtype=np.int64), counts)


def observed_wall_mask(true_segments: FloatArray, coverage: BoolArray, x_m: FloatArray,
                       y_m: FloatArray, spacing_m: float) -> BoolArray:
    """Which samples of the true walls lie in an observed cell.

    Parameters
    ----------
    true_segments : ndarray, shape (W, 2, 2)
        True walls, metres.
    coverage : ndarray, shape (ny, nx), bool
        Observed cells (``WallMap.coverage``, :func:`mapping.coverage.coverage_mask`).
    x_m, y_m : ndarray, shapes (nx,) and (ny,)
        Cell-centre coordinates of the regular grid of ``coverage``.
    spacing_m : float
        Sample spacing along the walls (as passed to :func:`wall_samples`).

    Returns
    -------
    ndarray, shape (n,), bool
        One entry per point of ``wall_samples(true_segments, spacing_m)``: True when the cell
        holding it (nearest cell centre) is observed; False outside the grid.
    """
    cov = np.asarray(coverage, dtype=bool)
    x, y = np.asarray(x_m, dtype=np.float64), np.asarray(y_m, dtype=np.float64)
    if cov.shape != (y.size, x.size):
        raise ValueError(f"coverage must have shape (ny, nx) = {(y.size, x.size)}, "
                         f"got {cov.shape}")
    pts = wall_samples(true_segments, spacing_m)
    step = float(x[1] - x[0]) if x.size > 1 else float(y[1] - y[0]) if y.size > 1 else 1.0
    ix = np.round((pts[:, 0] - x[0]) / step).astype(np.int64)
    iy = np.round((pts[:, 1] - y[0]) / step).astype(np.int64)
    inside = (ix >= 0) & (ix < x.size) & (iy >= 0) & (iy < y.size)
    out = np.zeros(pts.shape[0], dtype=bool)
    out[inside] = cov[iy[inside], ix[inside]]
    return out


def observed_near_points(true_segments: FloatArray, points_m: FloatArray, spacing_m: float,
                         radius_m: float) -> BoolArray:
    """Which samples of the true walls lie within ``radius_m`` of a heard point.

    ``points_m`` (k, 2) are points the runs heard, e.g. the specular points of the true walls
    from every tracked pose; the result has one entry per point of
    ``wall_samples(true_segments, spacing_m)``.
    """
    pts = wall_samples(true_segments, spacing_m)
    heard = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    if not radius_m > 0:
        raise ValueError(f"radius_m must be > 0, got {radius_m}")
    if heard.shape[0] == 0:
        return np.zeros(pts.shape[0], dtype=bool)
    d, _ = cKDTree(heard).query(pts)
    return np.asarray(d <= radius_m)


def _segment_distances(points: FloatArray, segments: FloatArray) -> FloatArray:
    """Distance from each point (m, 2) to each segment (n, 2, 2), shape (m, n)."""
    a, b = segments[None, :, 0, :], segments[None, :, 1, :]
    ab = b - a
    denom = np.sum(ab * ab, axis=-1)
    rel = points[:, None, :] - a
    t = np.clip(np.sum(rel * ab, axis=-1) / np.where(denom > 0, denom, 1.0), 0.0, 1.0)
    return np.asarray(np.hypot(*np.moveaxis(rel - t[..., None] * ab, -1, 0)))


def _line_angle_deg(u: FloatArray, v: FloatArray) -> float:
    """Angle between two undirected lines with directions u, v, degrees in [0, 90]."""
    cross = abs(float(u[0] * v[1] - u[1] * v[0]))
    return float(np.degrees(np.arctan2(cross, abs(float(u @ v)))))



