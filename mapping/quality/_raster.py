"""Raster precision and recall of G inside coverage, and all figures of one map."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mapping.files import json_safe
from mapping.quality._geometry import (
    cell_centres,
    distance_to_walls,
    observed_wall_mask,
    wall_samples,
)
from mapping.quality._p99 import DEFAULT_FRACTIONS, MapQuality, evaluate
from mapping.quality._walls import WallQuality, evaluate_walls
from mapping.wallmap import WallMap

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class RasterQuality:
    """Raster precision and recall, threshold relative to max(G), inside coverage."""

    fraction: float
    threshold: float
    tol_m: float
    strong_cells: int
    observed_cells: int
    observed_wall_share: float
    precision: float
    recall: float

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dictionary (NaN as null)."""
        return json_safe(asdict(self))


def evaluate_raster(wallmap: WallMap, true_segments: FloatArray, fraction: float = 0.2,
                    tol_m: float = 0.10, coverage: BoolArray | None = None) -> RasterQuality:
    """Raster precision/recall of ``wallmap.G``: strong = ``G >= fraction * max(G)``, both
    inside ``coverage`` (default ``wallmap.coverage``); see the module docstring.

    ``observed_wall_share`` is the share of the true wall samples inside coverage (the recall's
    denominator).
    """
    if not (0 < fraction <= 1 and tol_m > 0):
        raise ValueError(f"fraction must be in (0, 1] and tol_m > 0, got {fraction}, {tol_m}")
    cov = wallmap.coverage if coverage is None else np.asarray(coverage, dtype=bool)
    if cov.shape != wallmap.shape:
        raise ValueError(f"coverage must have shape {wallmap.shape}, got {cov.shape}")
    G = wallmap.G
    g_max = float(G[cov].max()) if cov.any() else 0.0
    threshold = fraction * g_max if g_max > 0 else math.inf
    strong = (G >= threshold) & cov
    spacing = wallmap.resolution_m / 4
    samples = wall_samples(true_segments, spacing)
    seen = observed_wall_mask(true_segments, cov, wallmap.x_m, wallmap.y_m, spacing)
    n_strong = int(strong.sum())
    centres = cell_centres(wallmap)[strong]
    precision = recall = math.nan
    if n_strong:
        precision = float(np.mean(distance_to_walls(centres, true_segments) <= tol_m))
    if seen.any():
        d_wall = cKDTree(centres).query(samples[seen])[0] if n_strong else np.full(1, np.inf)
        recall = float(np.mean(d_wall <= tol_m))
    return RasterQuality(fraction=fraction, threshold=threshold, tol_m=tol_m,
                         strong_cells=n_strong, observed_cells=int(cov.sum()),
                         observed_wall_share=float(seen.mean()), precision=precision,
                         recall=recall)


# ---- everything for one map --------------------------------------------------------------
@dataclass(frozen=True)
class MapReport:
    """All quality figures of one map: ``walls``, ``raster`` and ``fraction_of_p99``."""

    walls: WallQuality
    raster: RasterQuality
    fraction_of_p99: MapQuality

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dictionary (NaN as null)."""
        return {"walls": self.walls.to_dict(), "raster": self.raster.to_dict(),
                "fraction_of_p99": json_safe(self.fraction_of_p99.to_dict())}


def evaluate_map(wallmap: WallMap, true_segments: FloatArray, observed: BoolArray | None = None,
                 *, tol_m: float = 0.10, share: float = 0.8, fraction_of_max: float = 0.2,
                 p99_fractions: tuple[float, ...] = DEFAULT_FRACTIONS,
                 spacing_m: float = 0.01) -> MapReport:
    """Wall-level, raster and p99-relative quality of ``wallmap`` against the true walls.

    ``observed`` (one entry per point of ``wall_samples(true_segments, spacing_m)``) defaults
    to the samples in ``wallmap.coverage`` (:func:`observed_wall_mask`).
    """
    if observed is None:
        observed = observed_wall_mask(true_segments, wallmap.coverage, wallmap.x_m,
                                      wallmap.y_m, spacing_m)
    walls = evaluate_walls(wallmap.walls_m, true_segments, observed, tol_m, share,
                           pair=wallmap.wall_pair, spacing_m=spacing_m)
    raster = evaluate_raster(wallmap, true_segments, fraction_of_max, tol_m)
    return MapReport(walls=walls, raster=raster,
                     fraction_of_p99=evaluate(wallmap, true_segments, p99_fractions, tol_m))

