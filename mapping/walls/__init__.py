"""Vector wall maps fitted with the forward model of the heat map (issue 13, item 2).

The sonar hears a wall at its specular point, an inside corner at its vertex, and parallel
walls and corners again by multiple bounces. So the heat maps of a run are read as a list of
echo peaks (`run_peaks`, `heatmap_peaks`), and walls are chosen so that the forward model
(:mod:`mapping.forward`) explains those peaks (`fit_walls`):

- every peak fixes a tangent line of its wall (range ``r`` from the pose, normal within the
  Doppler beam of its direction, both sides); a Hough vote over all peaks proposes lines;
- a robust line fit on ranges (precise) and Doppler cosines (coarse) refines each; its
  specular points give the observed extent; walls meeting at an inside corner are joined
  where a corner echo is heard;
- walls are kept only while they pay for their parameters (BIC) and explain something the
  others do not: parallel-wall flutter, corner echoes and image walls behind real walls are
  explained by multi-bounce paths of the walls kept, and are not walls;
- a wall heard only from a straight path cannot be told from its mirror about the path: both
  are kept, flagged ambiguous and paired, never resolved by guess.
- each wall records the side it was heard from: a wall heard from one side is a face, and
  what is behind it (the far side of a shelf stack or a column) was never heard.

Entry points: `run_peaks` (a run -> `PeakObservations`), `fit_walls` (peaks -> `FittedWalls`);
:func:`mapping.build.build_map` with ``method="walls"`` does both over many runs and stores
the result in a `mapping.wallmap.WallMap`.

Notes
-----
Private modules: ``_peaks`` (peaks of a heat map and of a run), ``_lines`` (Hough votes,
inliers, the line fit), ``_explain`` (which peaks a wall set explains, occlusion),
``_fit`` (the greedy pass and the final checks).
"""

from __future__ import annotations

from mapping.walls._fit import EXPLAINED_WARNING, FittedWalls, WallFitParams, fit_walls
from mapping.walls._peaks import (
    PeakObservations,
    PeakParams,
    Peaks,
    concat_peaks,
    heatmap_peaks,
    run_peaks,
)

__all__ = [
    "EXPLAINED_WARNING",
    "FittedWalls",
    "PeakObservations",
    "PeakParams",
    "Peaks",
    "WallFitParams",
    "concat_peaks",
    "fit_walls",
    "heatmap_peaks",
    "run_peaks",
]
