"""Polar heat maps to the Cartesian wall map G (paper Sec. 2.2, eqs. 2-5).

Each block's polar heat map ``H[n_theta, n_tau]`` (angle from the direction of travel,
one-way range) is read at every map cell around the robot's tracked pose and added into G.
Because the heat map only knows ``|angle|`` from the direction of travel, a cell at ``+theta``
and its mirror at ``-theta`` read the same row: that is the paper's left/right mirror, kept
on purpose (it is what the paper's method does).

Two geometries are offered (``GridParams.literal``):

intended (default)
    ``n_theta = round(|wrap(atan2(dy, dx) - phi)| N / pi)`` with ``(dx, dy)`` the exact offset of
    the cell centre from the tracked pose (no rounding of the pose to the grid), and the cell
    takes the *maximum* of ``H[n_theta, :]`` over the range interval the cell square covers
    (nearest point to farthest corner). A 50 mm cell is wider than the +-17 mm echo peak, so
    reading only the centre's range sample leaves dotted walls.
literal (``literal=True``, for reproduction)
    Eqs. 2-5 as printed: ``arctan(m_y / m_x)`` (which loses the quadrant), the unwrapped
    difference ``|arctan(.) - phi|`` (cells whose index falls outside ``0..N`` add nothing),
    the pose rounded to the grid (eq. 5, +-25 mm), and the single range sample
    ``round(2 fs r / c)`` at the cell centre (eq. 4).

Noise floor (``GridParams.floor``): the envelope is never negative, so summing blocks would
pile up the noise floor everywhere. With ``floor="median"`` (default) each block's median over
the whole heat map is subtracted and the result clipped at 0 before it is placed; ``"none"``
keeps the paper's plain sum.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping.grid import _kernels as _grid_kernels
from mapping.heatmap import HeatMap
from mapping.wallmap import WallMap

FloatArray = NDArray[np.float64]
_FLOORS = ("median", "none", "pNN (e.g. p90)")


def _check_floor(floor: str) -> float | None:
    """Percentile of the floor (50 for "median"), None for "none"; ValueError otherwise."""
    if floor == "none":
        return None
    if floor == "median":
        return 50.0
    if floor.startswith("p"):
        try:
            q = float(floor[1:])
        except ValueError:
            q = -1.0
        if 0 < q < 100:
            return q
    raise ValueError(f"floor must be one of {_FLOORS}, got {floor!r}")


@dataclass(frozen=True)
class GridParams:
    """Parameters of the paper's reconstruction (eqs. 2-5).

    Parameters
    ----------
    resolution_m : float
        Grid step Delta x_m = Delta y_m (50 mm, paper Table 1).
    radius_m : float
        Cells farther than this from the pose receive nothing from the block; also the margin
        by which the map extent grows around the tracked poses.
    literal : bool
        Use eqs. 2-5 exactly as printed (see the module notes) instead of the intended geometry.
    floor : str
        Per-block noise-floor removal: "median" (subtract the block median, clip at 0), "pNN"
        (subtract the NN-th percentile of the block, e.g. "p90") or "none".
    skip_unobservable : bool
        Skip blocks whose heat map has ``direction_observable`` False (counted, not added).
    """

    resolution_m: float = 0.05
    radius_m: float = 6.0
    literal: bool = False
    floor: str = "median"
    skip_unobservable: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.resolution_m) and 0.001 <= self.resolution_m <= 10.0):
            raise ValueError(f"resolution_m must be in [0.001, 10] m, got {self.resolution_m}")
        if not (math.isfinite(self.radius_m) and self.radius_m > 0):
            raise ValueError(f"radius_m must be > 0, got {self.radius_m}")
        _check_floor(self.floor)

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON parameters (stored in the map file)."""
        return asdict(self)


@dataclass(frozen=True)
class GridExtent:
    """A map grid: centre of cell [0, 0] (multiples of the resolution) and shape (ny, nx)."""

    origin_m: tuple[float, float]
    shape: tuple[int, int]
    resolution_m: float

    def zeros(self) -> FloatArray:
        """An all-zero G of this extent."""
        return np.zeros(self.shape, dtype=np.float64)


def map_extent(poses: FloatArray, radius_m: float, resolution_m: float) -> GridExtent:
    """Grid covering every finite pose plus ``radius_m``, aligned to multiples of the step.

    Alignment makes the literal eq. 5 (``m_xg - round(x_p / dx)``) exact on the grid.

    Raises
    ------
    ValueError
        If ``poses`` is not (n, >=2) or holds no finite row.
    """
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] < 2:
        raise ValueError(f"poses must have shape (n, 2 or 3), got {poses.shape}")
    xy = poses[np.isfinite(poses[:, :2]).all(axis=1), :2]
    if xy.shape[0] == 0:
        raise ValueError("poses holds no tracked (finite) pose")
    lo = np.floor((xy.min(axis=0) - radius_m) / resolution_m).astype(np.int64)
    hi = np.ceil((xy.max(axis=0) + radius_m) / resolution_m).astype(np.int64)
    shape = (int(hi[1] - lo[1] + 1), int(hi[0] - lo[0] + 1))
    return GridExtent((float(lo[0] * resolution_m), float(lo[1] * resolution_m)), shape,
                      float(resolution_m))


def union_extent(extents: Iterable[GridExtent]) -> GridExtent:
    """Smallest aligned extent containing every extent (same resolution required)."""
    items = list(extents)
    if not items:
        raise ValueError("extents must not be empty")
    res = items[0].resolution_m
    if any(abs(e.resolution_m - res) > 1e-12 for e in items):
        raise ValueError("extents must share one resolution_m")
    lo = np.array([[round(e.origin_m[0] / res), round(e.origin_m[1] / res)] for e in items])
    hi = lo + np.array([[e.shape[1] - 1, e.shape[0] - 1] for e in items])
    lo_all, hi_all = lo.min(axis=0), hi.max(axis=0)
    return GridExtent((float(lo_all[0] * res), float(lo_all[1] * res)),
                      (int(hi_all[1] - lo_all[1] + 1), int(hi_all[0] - lo_all[0] + 1)), res)


def remove_floor(H: FloatArray, floor: str = "median") -> FloatArray:
    """Per-block noise floor removal: ``max(H - percentile(H, q), 0)`` or ``H`` unchanged.

    ``floor`` is "median" (q = 50), "pNN" (q = NN, e.g. "p90") or "none".
    """
    q = _check_floor(floor)
    H = np.asarray(H, dtype=np.float64)
    if q is None:
        return H
    return np.maximum(H - np.percentile(H, q), 0.0)


def _check_heatmap(heatmap: HeatMap) -> tuple[float, float]:
    """(r0, dr) of the heat map's range axis; ValueError on a malformed heat map."""
    H = heatmap.H
    if H.ndim != 2 or H.shape[0] < 2 or H.shape[1] < 2:
        raise ValueError(f"heatmap.H must be (n_dirs >= 2, P >= 2), got {H.shape}")
    if heatmap.ranges_m.shape != (H.shape[1],) or heatmap.angles_rad.shape != (H.shape[0],):
        raise ValueError("heatmap.ranges_m / angles_rad do not match heatmap.H")
    n = H.shape[0] - 1
    if not np.allclose(heatmap.angles_rad, np.pi * np.arange(n + 1) / n, atol=1e-9):
        raise ValueError("heatmap.angles_rad must be pi * n / N for n = 0..N")
    dr = float(heatmap.ranges_m[1] - heatmap.ranges_m[0])
    if not dr > 0:
        raise ValueError(f"heatmap.ranges_m must increase, step {dr}")
    return float(heatmap.ranges_m[0]), dr


def _check_pose(pose: FloatArray) -> tuple[float, float, float]:
    p = np.asarray(pose, dtype=np.float64)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ValueError(f"pose must be 3 finite values (x_m, y_m, heading_rad), got {p}")
    return float(p[0]), float(p[1]), float(p[2])


def _check_grid(G: FloatArray, extent: GridExtent, literal: bool) -> None:
    if G.shape != extent.shape or G.dtype != np.float64 or not G.flags.c_contiguous:
        raise ValueError(f"G must be C-contiguous float64 of shape {extent.shape}")
    if literal:
        o = np.asarray(extent.origin_m) / extent.resolution_m
        if np.any(np.abs(o - np.round(o)) > 1e-6):
            raise ValueError("literal=True needs origin_m on multiples of resolution_m "
                             "(use map_extent)")


def backproject(
    G: FloatArray, extent: GridExtent, heatmap: HeatMap, pose: FloatArray, params: GridParams
) -> None:
    """Add one block's Cartesian heat map (eqs. 2-4) into ``G`` in place (eq. 5).

    Parameters
    ----------
    G : ndarray, shape extent.shape, float64, C-contiguous
        The map being accumulated; modified in place.
    extent : GridExtent
        Geometry of ``G``; its resolution overrides ``params.resolution_m``.
    heatmap : HeatMap
        Polar heat map of the block (noise floor removed here per ``params.floor``).
    pose : ndarray, shape (3,)
        Tracked x_m, y_m and direction of travel phi_p (rad) at the block midpoint.
    params : GridParams
    """
    r0, dr = _check_heatmap(heatmap)
    px, py, phi = _check_pose(pose)
    _check_grid(G, extent, params.literal)
    H = np.ascontiguousarray(remove_floor(heatmap.H, params.floor))
    _grid_kernels._backproject(G, extent.origin_m[0], extent.origin_m[1], extent.resolution_m,
                               H, r0, dr, px, py, phi, params.radius_m, params.literal)


def cartesian_heatmap(
    heatmap: HeatMap, pose: FloatArray, extent: GridExtent, params: GridParams | None = None
) -> FloatArray:
    """One block's heat map in world coordinates, H-hat of eq. 2 placed at the pose (Fig. 5)."""
    params = params or GridParams()
    G = extent.zeros()
    backproject(G, extent, heatmap, pose, params)
    return G



def accumulate(
    heatmaps: Iterable[HeatMap | None], poses: FloatArray, params: GridParams | None = None,
    extent: GridExtent | None = None,
) -> tuple[FloatArray, GridExtent, dict[str, int]]:
    """Sum of the blocks' Cartesian heat maps over the run, eq. 5.

    Parameters
    ----------
    heatmaps : iterable of HeatMap
        One per block (a generator is fine); ``None`` entries are skipped as untracked.
    poses : ndarray, shape (n_blocks, 3)
        Tracked poses; NaN rows are untracked blocks (skipped and counted).
    params : GridParams, optional
    extent : GridExtent, optional
        Map grid; by default :func:`map_extent` of the tracked poses.

    Returns
    -------
    G, extent, counts
        ``counts`` has ``blocks_used``, ``blocks_untracked`` and ``blocks_unobservable``.
    """
    params = params or GridParams()
    poses = np.asarray(poses, dtype=np.float64)
    if extent is None:
        extent = map_extent(poses, params.radius_m, params.resolution_m)
    G = extent.zeros()
    counts = {"blocks_used": 0, "blocks_untracked": 0, "blocks_unobservable": 0}
    for k, hm in enumerate(heatmaps):
        if k >= poses.shape[0]:
            raise ValueError(f"more heat maps than poses ({poses.shape[0]})")
        if hm is None or not np.all(np.isfinite(poses[k])):
            counts["blocks_untracked"] += 1
            continue
        if params.skip_unobservable and not hm.direction_observable:
            counts["blocks_unobservable"] += 1
            continue
        backproject(G, extent, hm, poses[k], params)
        counts["blocks_used"] += 1
    return G, extent, counts


def to_wallmap(
    G: FloatArray, extent: GridExtent, params: GridParams, sonar: str = "",
    provenance: dict[str, Any] | None = None, method: str = "paper",
) -> WallMap:
    """Wrap an accumulated G as a :class:`WallMap`."""
    return WallMap(G=G, origin_m=extent.origin_m, resolution_m=extent.resolution_m, sonar=sonar,
                   method=method, params=params.to_dict(), provenance=dict(provenance or {}))
