"""The percentile-relative figures (``fraction_of_p99``): thresholds at fractions of the 99th
percentile of the positive cells over the whole map, ghost energy, Chamfer distance."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mapping.quality._geometry import cell_centres, distance_to_walls, wall_samples
from mapping.wallmap import WallMap

FloatArray = NDArray[np.float64]


#: Threshold fractions reported by default.
DEFAULT_FRACTIONS: tuple[float, ...] = (0.25, 0.5, 0.75)


@dataclass(frozen=True)
class QualityAtThreshold:
    """Precision, recall and Chamfer distance at one threshold relative to the p99 of G > 0."""

    fraction: float
    threshold: float
    strong_cells: int
    precision: float
    recall: float
    chamfer_m: float


@dataclass(frozen=True)
class MapQuality:
    """Percentile-relative quality of a map (``fraction_of_p99``, see the module docstring)."""

    ghost_energy: float
    percentile: float
    tol_m: float
    ghost_m: float
    at: tuple[QualityAtThreshold, ...]

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dictionary."""
        d = asdict(self)
        d["at"] = [asdict(a) for a in self.at]
        return d

    def get(self, fraction: float) -> QualityAtThreshold:
        """The entry at ``fraction`` (ValueError if it was not evaluated)."""
        for a in self.at:
            if math.isclose(a.fraction, fraction):
                return a
        raise ValueError(f"fraction must be one of {[a.fraction for a in self.at]}, "
                         f"got {fraction}")



def strong_threshold(G: FloatArray, fraction: float, percentile: float = 99.0) -> float:
    """``fraction`` times the ``percentile`` of the positive cells of ``G`` (inf if none)."""
    if not 0 < fraction <= 10:
        raise ValueError(f"fraction must be in (0, 10], got {fraction}")
    if not 0 < percentile <= 100:
        raise ValueError(f"percentile must be in (0, 100], got {percentile}")
    pos = G[G > 0]
    if pos.size == 0:
        return math.inf
    return float(fraction * np.percentile(pos, percentile))


def evaluate(
    wallmap: WallMap, segments: FloatArray, fractions: tuple[float, ...] = DEFAULT_FRACTIONS,
    tol_m: float = 0.10, ghost_m: float = 0.20, percentile: float = 99.0,
) -> MapQuality:
    """Percentile-relative figures of ``wallmap`` against walls (``fraction_of_p99``).

    Precision, recall and Chamfer distance with strong-cell thresholds relative to the
    ``percentile`` of the positive cells over the whole map, and the ghost energy (see the
    module docstring: these are not the figures that say how good a map is; use
    :func:`evaluate_map`).

    Parameters
    ----------
    wallmap : WallMap
    segments : ndarray, shape (W, 2, 2)
        True wall segments (e.g. ``Scene.segments()``), metres.
    fractions : tuple of float
        Strong-cell thresholds as fractions of the ``percentile`` of the positive cells.
    tol_m, ghost_m : float
        Precision/recall tolerance (10 cm) and ghost distance (20 cm).
    """
    if not (tol_m > 0 and ghost_m > 0):
        raise ValueError(f"tol_m and ghost_m must be > 0, got {tol_m}, {ghost_m}")
    G = wallmap.G
    centres = cell_centres(wallmap)
    D = distance_to_walls(centres, segments)
    total = float(G.sum())
    ghost = float(G[D > ghost_m].sum() / total) if total > 0 else float("nan")
    samples = wall_samples(segments, wallmap.resolution_m / 4)
    at = []
    for f in fractions:
        thr = strong_threshold(G, f, percentile)
        strong = G >= thr
        n = int(strong.sum())
        if n == 0:
            at.append(QualityAtThreshold(f, thr, 0, float("nan"), 0.0, float("nan")))
            continue
        d_strong = D[strong]
        tree = cKDTree(centres[strong])
        d_wall, _ = tree.query(samples)
        at.append(QualityAtThreshold(
            fraction=f, threshold=thr, strong_cells=n,
            precision=float(np.mean(d_strong <= tol_m)),
            recall=float(np.mean(d_wall <= tol_m)),
            chamfer_m=float(0.5 * (d_strong.mean() + d_wall.mean())),
        ))
    return MapQuality(ghost_energy=ghost, percentile=percentile, tol_m=tol_m, ghost_m=ghost_m,
                      at=tuple(at))


