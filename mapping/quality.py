"""Map quality against the true walls: precision, recall, ghost energy, Chamfer distance.

The paper shows its maps as images only; these numbers make maps comparable.

Definitions (``G`` the map, ``D(c)`` the distance from cell centre ``c`` to the nearest true
wall segment):

strong cell
    ``G(c) >= fraction * P``, with ``P`` the ``percentile`` (99 by default) of the map's
    *positive* cells (the empty margin around the runs would otherwise drag it to 0).
    Corners retro-reflect into the same cell from every pose and dominate ``max(G)``, which is
    why a high percentile, not the maximum, sets the scale; results are reported at several
    fractions.
precision
    Share of strong cells with ``D(c) <= tol_m`` (10 cm).
recall
    Share of the true wall length (walls sampled every ``resolution / 4``) lying within
    ``tol_m`` of a strong cell centre.
ghost energy
    ``sum(G[D > ghost_m]) / sum(G)`` with ``ghost_m`` = 20 cm: the share of the map's energy
    farther than 20 cm from any wall (mirror images, multiple-reflection images, noise).
    Independent of the threshold.
Chamfer distance
    Symmetric mean: ``(mean over strong cells of D + mean over wall samples of the distance to
    the nearest strong cell) / 2``, in metres.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mapping.wallmap import WallMap

FloatArray = NDArray[np.float64]

#: Threshold fractions reported by default.
DEFAULT_FRACTIONS: tuple[float, ...] = (0.25, 0.5, 0.75)


@dataclass(frozen=True)
class QualityAtThreshold:
    """Precision, recall and Chamfer distance at one strong-cell threshold."""

    fraction: float
    threshold: float
    strong_cells: int
    precision: float
    recall: float
    chamfer_m: float


@dataclass(frozen=True)
class MapQuality:
    """Quality of a map against true walls (see the module docstring for the definitions)."""

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
    """Precision, recall, ghost energy and Chamfer distance of ``wallmap`` against walls.

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
