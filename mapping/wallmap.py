"""The wall map: evidence G on a Cartesian grid (paper Sec. 2.2, eq. 5), the fitted walls, and
the cells the runs observed.

A :class:`WallMap` carries two descriptions of the same room. ``G`` is the paper's picture of
back-projected (or inverted) echo energy, one value per cell. ``walls_m`` is the vector map: wall
segments fitted to the runs, each with a reflection strength and a 1-sigma uncertainty. A
straight path cannot tell left from right, so a wall heard only from a straight stretch is kept
as *two* mirror hypotheses, both flagged ``wall_ambiguous`` and pointing at each other through
``wall_pair``; nothing chooses a side by guess. ``coverage`` marks the cells the runs observed
(:func:`mapping.coverage.coverage_mask`); everything else is unknown, not empty.

Maps of the grid methods ("paper", "inverse") and maps read from ``omnisonar-map-1`` files have
no walls (``walls_m`` of shape (0, 4)) and a coverage of every cell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def _no_walls() -> FloatArray:
    return np.zeros((0, 4), dtype=np.float64)


def _unset() -> NDArray[Any]:
    """Sentinel of an optional array field: replaced by its default in ``__post_init__``."""
    return np.zeros((), dtype=np.float64)  # 0-d: never a valid value of these fields


@dataclass(frozen=True)
class WallMap:
    """Accumulated wall evidence G on a regular grid, the fitted walls and the observed cells.

    Attributes
    ----------
    G : ndarray, shape (ny, nx)
        Map values; ``G[iy, ix]`` is the cell whose centre is
        ``(origin_m[0] + ix * resolution_m, origin_m[1] + iy * resolution_m)``.
    origin_m : tuple of float
        World coordinates (x, y) in metres of the centre of cell ``G[0, 0]``.
    resolution_m : float
        Cell size in metres (50 mm by default, paper Table 1).
    sonar : str
        JSON of the SonarConfig the map was built with.
    method : str
        Reconstruction method ("walls", "paper", "inverse").
    params : dict
        Method parameters.
    provenance : dict
        Input run files and checksums, block counts.
    walls_m : ndarray, shape (n, 4), float64
        Fitted wall segments ``x0, y0, x1, y1`` in metres (map frame). Default: no walls.
    wall_strength : ndarray, shape (n,), float64
        Reflection strength of each wall (>= 0, in the units of the fit). Default: 1 per wall.
    wall_sigma : ndarray, shape (n, 3), float64
        1-sigma uncertainty of each wall: normal offset (m), angle (rad), endpoints (m); NaN
        where not estimated. Default: NaN.
    wall_ambiguous : ndarray, shape (n,), bool
        True for a wall heard only from a straight path: it and its mirror about the path are
        both kept. Default: False.
    wall_pair : ndarray, shape (n,), int64
        Index of the mirror hypothesis of an ambiguous wall, or -1. Default: -1.
    coverage : ndarray, shape (ny, nx), bool
        Cells the runs observed (within range of a tracked pose, in line of sight).
        Default: every cell.

    Raises
    ------
    ValueError
        Naming the field whose shape, dtype or values are wrong (non-finite G or walls,
        negative strength or sigma, a pair index out of range or not mutual, a pair on a wall not
        flagged ambiguous).
    """

    G: FloatArray
    origin_m: tuple[float, float]
    resolution_m: float
    sonar: str = ""
    method: str = "paper"
    params: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)
    walls_m: FloatArray = field(default_factory=_no_walls)
    wall_strength: FloatArray = field(default_factory=_unset)
    wall_sigma: FloatArray = field(default_factory=_unset)
    wall_ambiguous: BoolArray = field(default_factory=_unset)
    wall_pair: NDArray[np.int64] = field(default_factory=_unset)
    coverage: BoolArray = field(default_factory=_unset)

    def __post_init__(self) -> None:
        if self.G.ndim != 2 or min(self.G.shape) < 1:
            raise ValueError(f"WallMap.G must be a non-empty 2-D array, got shape {self.G.shape}")
        if not np.all(np.isfinite(self.G)):
            raise ValueError("WallMap.G contains NaN or inf")
        if not (np.isfinite(self.resolution_m) and self.resolution_m > 0):
            raise ValueError(f"WallMap.resolution_m must be > 0, got {self.resolution_m}")
        walls = np.asarray(self.walls_m, dtype=np.float64)
        if walls.ndim != 2 or walls.shape[1] != 4:
            raise ValueError(f"WallMap.walls_m must have shape (n, 4), got {walls.shape}")
        if not np.all(np.isfinite(walls)):
            raise ValueError("WallMap.walls_m contains NaN or inf")
        n = walls.shape[0]
        self._set("walls_m", walls)
        self._set("wall_strength", self._per_wall("wall_strength", (n,), np.float64, 1.0))
        self._set("wall_sigma", self._per_wall("wall_sigma", (n, 3), np.float64, np.nan))
        self._set("wall_ambiguous", self._per_wall("wall_ambiguous", (n,), np.bool_, False))
        self._set("wall_pair", self._per_wall("wall_pair", (n,), np.int64, -1))
        self._set("coverage", self._per_wall("coverage", self.G.shape, np.bool_, True))
        self._check_wall_values()

    def _set(self, name: str, value: NDArray[Any]) -> None:
        object.__setattr__(self, name, value)

    def _per_wall(self, name: str, shape: tuple[int, ...], dtype: Any, default: Any
                  ) -> NDArray[Any]:
        raw = np.asarray(getattr(self, name))
        if raw.ndim == 0:  # not given
            return np.full(shape, default, dtype=dtype)
        if raw.shape != shape:
            raise ValueError(f"WallMap.{name} must have shape {shape}, got {raw.shape}")
        if dtype is np.bool_ and raw.size and raw.dtype != np.bool_:
            raise ValueError(f"WallMap.{name} must be boolean, got dtype {raw.dtype}")
        if dtype is np.int64 and raw.size and not np.issubdtype(raw.dtype, np.integer):
            raise ValueError(f"WallMap.{name} must be integer, got dtype {raw.dtype}")
        return np.asarray(raw, dtype=dtype)

    def _check_wall_values(self) -> None:
        n = self.n_walls
        if not np.all(np.isfinite(self.wall_strength) & (self.wall_strength >= 0)):
            raise ValueError("WallMap.wall_strength must be finite and >= 0")
        sigma = self.wall_sigma
        if np.any(np.isinf(sigma)) or np.any(sigma < 0):
            raise ValueError("WallMap.wall_sigma must be >= 0 (NaN where not estimated)")
        pair = self.wall_pair
        if np.any((pair < -1) | (pair >= n)) or np.any(pair == np.arange(n)):
            raise ValueError(f"WallMap.wall_pair must be -1 or another wall's index in [0, {n})")
        paired = np.flatnonzero(pair >= 0)
        if np.any(pair[pair[paired]] != paired):
            raise ValueError("WallMap.wall_pair must be mutual: pair[pair[i]] == i")
        if np.any(~self.wall_ambiguous[paired]):
            raise ValueError("WallMap.wall_ambiguous must be True on every wall with a pair")

    @property
    def n_walls(self) -> int:
        """Number of fitted walls."""
        return int(self.walls_m.shape[0])

    @property
    def wall_end_sigma(self) -> FloatArray:
        """1-sigma of each wall end's position along the wall, m, shape (n, 2) (ends
        ``a = walls_m[:, :2]``, ``b = walls_m[:, 2:]``): 0 at a corner, about half the
        spacing of the wall's specular points where the runs looked past the end and heard
        no more wall, large where they never looked past it (the wall may go on). The wall
        fit records it in ``provenance["fit"]["end_sigma_m"]``
        (:func:`mapping.walls.fit_walls`); NaN where the map does not say (older maps, maps
        made from geometry)."""
        fit = self.provenance.get("fit")
        es = fit.get("end_sigma_m") if isinstance(fit, dict) else None
        out = np.full((self.n_walls, 2), np.nan)
        if es is not None:
            a = np.asarray(es, dtype=np.float64)
            if a.shape == out.shape and np.all(~np.isfinite(a) | (a >= 0)):
                out = a
        return out

    @property
    def wall_side(self) -> NDArray[np.int64]:
        """The side each wall was heard from, shape (n,): +1 left of its direction
        ``a = walls_m[:, :2] -> b = walls_m[:, 2:]``, -1 right, 0 both or not said. A
        specular sonar hears a wall's face towards it; a wall heard from one side only is a
        face whose back (the far side of a shelf stack, a column, the outside of a room) was
        never heard, so the echo model predicts no echo from it there. The wall fit records
        it in ``provenance["fit"]["heard_side"]`` (:func:`mapping.walls.fit_walls`); 0 where
        the map does not say (older maps, maps made from geometry: every wall two-sided)."""
        fit = self.provenance.get("fit")
        hs = fit.get("heard_side") if isinstance(fit, dict) else None
        out = np.zeros(self.n_walls, dtype=np.int64)
        if hs is not None:
            a = np.asarray(hs)
            if a.shape == out.shape and a.size and np.all(np.isin(a, (-1, 0, 1))):
                out = a.astype(np.int64)
        return out

    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx)."""
        return (int(self.G.shape[0]), int(self.G.shape[1]))

    @property
    def x_m(self) -> FloatArray:
        """Cell-centre x coordinates, shape (nx,)."""
        return np.asarray(self.origin_m[0] + self.resolution_m * np.arange(self.G.shape[1]),
                          dtype=np.float64)

    @property
    def y_m(self) -> FloatArray:
        """Cell-centre y coordinates, shape (ny,)."""
        return np.asarray(self.origin_m[1] + self.resolution_m * np.arange(self.G.shape[0]),
                          dtype=np.float64)

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the cell edges, for plotting."""
        h = 0.5 * self.resolution_m
        return (self.x_m[0] - h, self.x_m[-1] + h, self.y_m[0] - h, self.y_m[-1] + h)

    def world_to_cell(self, xy_m: FloatArray) -> FloatArray:
        """Fractional (ix, iy) cell coordinates of world points ``xy_m`` (..., 2)."""
        xy = np.asarray(xy_m, dtype=np.float64)
        return (xy - np.asarray(self.origin_m)) / self.resolution_m


def rasterize_walls(walls_m: FloatArray, x_m: FloatArray, y_m: FloatArray) -> BoolArray:
    """Cells of a regular grid that wall segments pass through (lines one cell wide).

    Parameters
    ----------
    walls_m : ndarray, shape (n, 4)
        Segments ``x0, y0, x1, y1`` in metres.
    x_m, y_m : ndarray, shapes (nx,) and (ny,)
        Cell-centre coordinates of a regular grid (uniform step, as ``WallMap.x_m``/``y_m``).

    Returns
    -------
    ndarray, shape (ny, nx), bool
        True on every cell whose square a segment crosses (the segment is sampled every 1/8
        cell, so a corner clipped by less than that may be missed). Parts outside the grid are
        dropped.
    """
    walls = np.asarray(walls_m, dtype=np.float64).reshape(-1, 4)
    x = np.asarray(x_m, dtype=np.float64)
    y = np.asarray(y_m, dtype=np.float64)
    out = np.zeros((y.size, x.size), dtype=bool)
    if walls.shape[0] == 0 or x.size == 0 or y.size == 0:
        return out
    step = float(x[1] - x[0]) if x.size > 1 else float(y[1] - y[0]) if y.size > 1 else 1.0
    for x0, y0, x1, y1 in walls:
        n = max(int(np.ceil(8.0 * np.hypot(x1 - x0, y1 - y0) / step)), 1) + 1
        t = np.linspace(0.0, 1.0, n)
        ix = np.round((x0 + t * (x1 - x0) - x[0]) / step).astype(np.int64)
        iy = np.round((y0 + t * (y1 - y0) - y[0]) / step).astype(np.int64)
        ok = (ix >= 0) & (ix < x.size) & (iy >= 0) & (iy < y.size)
        out[iy[ok], ix[ok]] = True
    return out


def wallmap_from_walls(walls_m: FloatArray, strength: FloatArray | None = None,
                       resolution_m: float = 0.05, margin_m: float = 1.0) -> WallMap:
    """An ideal map of known walls (a scene's, a floor plan's): G = 1 on the rasterized walls,
    the walls as the vector map, coverage everywhere.

    Parameters
    ----------
    walls_m : ndarray, shape (n >= 1, 4)
        Segments ``x0, y0, x1, y1``.
    strength : ndarray (n,), optional
        Reflection strength per wall (default 1).
    resolution_m, margin_m : float
        Cell size and the margin around the walls' bounding box.
    """
    walls = np.asarray(walls_m, dtype=np.float64).reshape(-1, 4)
    if walls.shape[0] == 0 or not np.all(np.isfinite(walls)):
        raise ValueError("walls_m must hold at least one finite segment (n, 4)")
    if not (math.isfinite(resolution_m) and 0 < resolution_m <= 1):
        raise ValueError(f"resolution_m must be in (0, 1] m, got {resolution_m!r}")
    if not (math.isfinite(margin_m) and 0 <= margin_m <= 100):
        raise ValueError(f"margin_m must be in [0, 100] m, got {margin_m!r}")
    pts = walls.reshape(-1, 2)
    lo = pts.min(axis=0) - margin_m
    n = np.ceil((pts.max(axis=0) + margin_m - lo) / resolution_m).astype(int) + 1
    x = lo[0] + resolution_m * np.arange(n[0])
    y = lo[1] + resolution_m * np.arange(n[1])
    G = rasterize_walls(walls, x, y).astype(np.float64)
    s = np.ones(walls.shape[0]) if strength is None else np.asarray(strength, dtype=np.float64)
    return WallMap(G=G, origin_m=(float(lo[0]), float(lo[1])), resolution_m=resolution_m,
                   walls_m=walls, wall_strength=s)
