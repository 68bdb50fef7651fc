"""Map quality against the true walls: wall-level and raster precision/recall, and the
older percentile-relative figures.

The paper shows its maps as images only; these numbers make maps comparable. Every figure is
scored on what the runs *could observe*: a wall no pose came near says nothing about the map.
With ``tol_m`` = 10 cm and ``D(c)`` the distance from a cell centre ``c`` to the nearest true wall:

**Observed part of the true walls** (:func:`observed_wall_mask`, :func:`observed_near_points`)
    The true walls are sampled every ``spacing_m`` (1 cm; :func:`wall_samples`, with the wall of
    each sample from :func:`wall_sample_index`). A sample is observed when the map cell that
    holds it is in the map's ``coverage`` (cells within range and line of sight of a tracked
    pose, :mod:`mapping.coverage`), or, with :func:`observed_near_points`, when it lies within a
    radius of a point the runs heard (e.g. the specular points of the forward model). A boolean
    mask over the samples is what :func:`evaluate_walls` takes as ``observed``.

**Wall level** (:func:`evaluate_walls`, fitted walls ``walls_m`` against true segments)
    *found*: a true wall with an observed part is found when at least ``share`` (80 %) of its
    observed samples lie within ``tol_m`` of a fitted wall (any fitted wall: a wall fitted in
    two pieces counts). A true wall whose observed part is shorter than ``tol_m`` (a corner
    glimpsed in passing) is *unobserved* and left out.
    *true positive*: a fitted wall with at least ``share`` of its length (sampled the same way)
    within ``tol_m`` of a true wall (observed or not). Otherwise it is *false*, except when it is
    the flagged mirror (``pair``) of a true positive: a straight path cannot tell left from
    right, so such a wall is reported as *ambiguous* and counts neither way.
    ``recall = found / observed true walls``;
    ``precision = true positives / (fitted walls - ambiguous)``; NaN when a denominator is 0.
    For each found true wall the fitted wall covering most of its observed samples is its
    *match*: the angle error is the angle between the two lines (degrees, 0-90) and the endpoint
    error of each end the runs observed (the end sample is observed) is the distance from that
    true end to the nearer end of the match (a wall fitted in several pieces reports its largest
    piece).

**Raster** (:func:`evaluate_raster`, the grid ``G``, scored inside ``coverage``)
    *strong cell*: ``G(c) >= fraction * max(G)`` (0.2), with cell and maximum taken inside
    coverage (a ghost behind a wall neither counts nor sets the scale). *precision*: share of
    strong cells with ``D(c) <= tol_m``. *recall*: share of the true-wall samples (every
    ``resolution / 4``) inside coverage that lie within ``tol_m`` of a strong cell centre.

**Fraction of p99** (:func:`evaluate`, kept for comparison with earlier numbers; reported as
``fraction_of_p99``)
    strong cell: ``G(c) >= fraction * P``, ``P`` the ``percentile`` (99) of the map's *positive*
    cells, over the *whole* map; precision as above; recall over *all* true wall length
    (sampled every ``resolution / 4``), seen or not. A percentile scale sits far below max(G)
    (retro-reflecting corners dominate the maximum), so these thresholds mark many cells strong
    and read as low precision and high recall: they rank maps, they do not say how good one is.
    *ghost energy*: ``sum(G[D > ghost_m]) / sum(G)`` with ``ghost_m`` = 20 cm, threshold-free.
    *Chamfer distance*: ``(mean over strong cells of D + mean over wall samples of the distance
    to the nearest strong cell) / 2``, metres.

:func:`evaluate_map` computes all three for one :class:`~mapping.wallmap.WallMap`.

Notes
-----
Private modules: ``_geometry`` (distances, samples, observed masks), ``_walls`` (wall level),
``_raster`` (raster inside coverage and `evaluate_map`), ``_p99`` (the percentile-relative
figures).
"""

from __future__ import annotations

from mapping.quality._geometry import (
    cell_centres,
    distance_to_walls,
    observed_near_points,
    observed_wall_mask,
    wall_sample_index,
    wall_samples,
)
from mapping.quality._p99 import (
    DEFAULT_FRACTIONS,
    MapQuality,
    QualityAtThreshold,
    evaluate,
    strong_threshold,
)
from mapping.quality._raster import (
    MapReport,
    RasterQuality,
    evaluate_map,
    evaluate_raster,
)
from mapping.quality._walls import (
    WallMatch,
    WallQuality,
    evaluate_walls,
)

__all__ = [
    "DEFAULT_FRACTIONS",
    "MapQuality",
    "MapReport",
    "QualityAtThreshold",
    "RasterQuality",
    "WallMatch",
    "WallQuality",
    "cell_centres",
    "distance_to_walls",
    "evaluate",
    "evaluate_map",
    "evaluate_raster",
    "evaluate_walls",
    "observed_near_points",
    "observed_wall_mask",
    "strong_threshold",
    "wall_sample_index",
    "wall_samples",
]
