"""Held-out scenes and paths: rooms the mapping defaults were never tuned on (issue 13).

The scenes are hand-written scene JSON files in the top-level ``scenes/`` folder (the format of
:mod:`mapping.scene`); their paths are in ``scenes/paths.json``::

    {"<path name>": {"scene": "<scene name>", "kind": "line" | "curve" | "loop",
                     "points": [[x, y], ...], "description": "...",
                     "group": "held-out" | "fresh" | "fresh14" | "fresh14b" | "fresh14c"
                              | "fresh14d" | "fresh14e" | "fresh14f" | "fresh14g"
                              | "fresh14h" | "fresh14i" | "fresh14j" | "fresh14k"
                              | "fresh14l" | "fresh14m" | "fresh14n" | "fresh14o"
                              | "fresh14p" | "fresh14q" | "fresh14r"},
     ...}

``line`` is :func:`mapping.path.polyline_path` through the points (straight segments with
rounded corners), ``curve`` is :func:`mapping.path.curve_path` through them and ``loop`` the
closed curve. Every scene has one path named ``<scene>-curve``: the curved run the wall-map
benchmark maps. ``group`` (default ``"held-out"``) sorts the paths for the benchmark:
``"fresh"`` marks scenes written after the wall fit was developed, so nobody looked at them
while tuning it, ``"fresh14"`` scenes written for issue 14 that no localization code was
tuned on, ``"fresh14b"`` scenes written after the filter's rivals were fixed and
``"fresh14c"`` after the Gaussian refinement, ``"fresh14d"`` after the echo model began
comparing levels, ``"fresh14e"`` after the fresh14d rerun, before any measurement with the
filter's next change, ``"fresh14f"`` after the filter's silent-map rule, before any
measurement of it on new rooms, ``"fresh14g"`` after the filter's rule that on a built map
only missing predicted echoes count as evidence for a jump, before any measurement of it on
new rooms, ``"fresh14h"`` after the filter's rules that a global start on a map built from
runs confirms only after 8 agreeing blocks and that a block counts as evidence for a jump only
where at least 1.5 predicted echoes go unheard, before any measurement of them on new rooms,
``"fresh14i"`` at the start of session 31, before any of that session's filter changes and
before any measurement on them, ``"fresh14j"`` at the start of session 32, before any
measurement on them, ``"fresh14k"`` at the start of session 33, before any measurement on
them, ``"fresh14l"`` at the start of session 34, before any measurement on them,
``"fresh14m"`` at the start of session 35, before any measurement on them, ``"fresh14n"`` at
the start of session 37, before any measurement on them, ``"fresh14o"`` in session 39,
before any measurement on them, ``"fresh14p"`` in session 41, before any measurement on
them, ``"fresh14q"`` in session 42, before any measurement on them, and ``"fresh14r"`` in
session 43, before any measurement on them (nothing was run on any of these before they were
committed).
This loader lives here, not in ``mapping``, so the package never reads files by path.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping.path import PAPER_SPEED_M_S, Trajectory, curve_path, polyline_path
from mapping.scene import Scene

SCENES_DIR = Path(__file__).resolve().parents[1] / "scenes"
PATH_KINDS = ("line", "curve", "loop")
PATH_GROUPS = ("held-out", "fresh", "fresh14", "fresh14b", "fresh14c", "fresh14d",
               "fresh14e", "fresh14f", "fresh14g", "fresh14h", "fresh14i", "fresh14j",
               "fresh14k", "fresh14l", "fresh14m", "fresh14n", "fresh14o", "fresh14p",
               "fresh14q", "fresh14r")


@dataclass(frozen=True)
class PathSpec:
    """One hand-designed path: name, scene name, kind, points (m), description and group."""

    name: str
    scene: str
    kind: str
    points_m: NDArray[np.float64]
    description: str
    group: str = "held-out"

    def trajectory(self, speed_m_s: float = PAPER_SPEED_M_S) -> Trajectory:
        """The constant-speed trajectory of this path."""
        if self.kind == "line":
            return polyline_path(self.points_m, speed_m_s=speed_m_s, name=self.name)
        return curve_path(self.points_m, speed_m_s=speed_m_s, closed=self.kind == "loop",
                          name=self.name)


def heldout_scene_names() -> list[str]:
    """Names of the held-out scenes (one ``scenes/<name>.json`` each), sorted."""
    return sorted(p.stem for p in SCENES_DIR.glob("*.json") if p.name != "paths.json")


def heldout_scene(name: str) -> Scene:
    """The held-out scene ``name``; ``ValueError`` naming the choices if there is none."""
    if name not in heldout_scene_names():
        raise ValueError(f"scene name must be one of {heldout_scene_names()}, got {name!r}")
    return Scene.from_json((SCENES_DIR / f"{name}.json").read_text(encoding="utf-8"))


@cache
def _path_table() -> dict[str, dict[str, Any]]:
    raw = json.loads((SCENES_DIR / "paths.json").read_text(encoding="utf-8"))
    if not isinstance(raw, dict):
        raise ValueError("scenes/paths.json must be an object of name -> path")
    return raw


def heldout_path_names(scene: str | None = None) -> list[str]:
    """Names of the held-out paths, in file order (only those of ``scene`` if given)."""
    return [n for n, p in _path_table().items() if scene is None or p.get("scene") == scene]


def heldout_path(name: str) -> PathSpec:
    """The held-out path ``name``; ``ValueError`` naming the bad field."""
    table = _path_table()
    if name not in table:
        raise ValueError(f"path name must be one of {list(table)}, got {name!r}")
    entry = table[name]
    kind = entry.get("kind")
    if kind not in PATH_KINDS:
        raise ValueError(f"path {name!r}: field 'kind' must be one of {PATH_KINDS}, got {kind!r}")
    points = np.asarray(entry.get("points"), dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2 or points.shape[0] < 2:
        raise ValueError(f"path {name!r}: field 'points' must be (n >= 2, 2), got {points.shape}")
    group = entry.get("group", "held-out")
    if group not in PATH_GROUPS:
        raise ValueError(f"path {name!r}: field 'group' must be one of {PATH_GROUPS}, "
                         f"got {group!r}")
    return PathSpec(name=name, scene=str(entry.get("scene")), kind=kind, points_m=points,
                    description=str(entry.get("description", "")), group=group)
