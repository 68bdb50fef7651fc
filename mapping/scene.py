"""Scenes: wall segments with reflection coefficients, as hand-written JSON (issue 3, item 1).

A scene is a list of straight wall segments in the plane (the paper's 2-D setting, Sec. 3-4).
Each wall reflects with a pressure reflection coefficient ``R`` given either directly
(``reflection``) or through the specific acoustic impedance of its surface
(``impedance_pa_s_m``, normal incidence)::

    R = (Z - rho c) / (Z + rho c)

``Z = inf`` is the rigid wall of the paper's Table 2 (``R = 1``), ``Z = rho c`` absorbs
everything (``R = 0``) and ``Z = 0`` is pressure-release (``R = -1``). A wall that gives
neither is rigid.

File format (JSON; ``"inf"`` is accepted for a rigid impedance)::

    {"name": "shoebox", "description": "4 m x 3 m rectangle",
     "rho_kg_m3": 1.293, "sound_speed_m_s": 340.0,
     "walls": [{"name": "south", "start": [0, 0], "end": [4, 0]},
               {"name": "east", "start": [4, 0], "end": [4, 3], "reflection": 0.9},
               {"name": "north", "start": [4, 3], "end": [0, 3], "impedance_pa_s_m": "inf"},
               {"name": "west", "start": [0, 3], "end": [0, 0], "impedance_pa_s_m": 4000}]}

Built-in scenes (:func:`builtin_scene`) are Python data here, so this module reads no files.
``paper`` is a *reconstruction* of the paper's Fig. 4 from its text (the figure itself is
not available); see :data:`PAPER_WALL3_NOTE` for how Wall 3 was placed.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import (
    BaseModel,
    ConfigDict,
    PrivateAttr,
    ValidationError,
    field_serializer,
    field_validator,
    model_validator,
)

#: Air at the paper's Table 2 values: rho_0 = 1.293 kg/m^3, c_a = 340 m/s.
DEFAULT_RHO_KG_M3 = 1.293
DEFAULT_SOUND_SPEED_M_S = 340.0


def reflection_from_impedance(impedance_pa_s_m: float, rho_c_pa_s_m: float) -> float:
    """Normal-incidence pressure reflection coefficient ``R = (Z - rho c) / (Z + rho c)``.

    Parameters
    ----------
    impedance_pa_s_m : float
        Specific acoustic impedance Z of the wall surface in Pa s/m, ``>= 0``; ``inf`` is rigid.
    rho_c_pa_s_m : float
        Characteristic impedance rho c of the medium in Pa s/m, ``> 0``.

    Returns
    -------
    float
        R in [-1, 1]; 1 for ``Z = inf`` (paper Table 2), 0 for ``Z = rho c``.
    """
    if not rho_c_pa_s_m > 0 or not math.isfinite(rho_c_pa_s_m):
        raise ValueError(f"rho_c_pa_s_m must be finite and > 0, got {rho_c_pa_s_m}")
    if math.isnan(impedance_pa_s_m) or impedance_pa_s_m < 0:
        raise ValueError(f"impedance_pa_s_m must be >= 0 (or inf), got {impedance_pa_s_m}")
    if math.isinf(impedance_pa_s_m):
        return 1.0
    return (impedance_pa_s_m - rho_c_pa_s_m) / (impedance_pa_s_m + rho_c_pa_s_m)


class Wall(BaseModel):
    """One straight wall segment from ``start`` to ``end`` (metres, scene coordinates).

    Give at most one of ``reflection`` (R, ``|R| <= 1``) and ``impedance_pa_s_m``
    (Z >= 0 or ``inf``); neither means rigid (R = 1).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    start: tuple[float, float]
    end: tuple[float, float]
    reflection: float | None = None
    impedance_pa_s_m: float | None = None
    name: str = ""

    # rho c of the medium; set by the Scene that holds this wall (default: air, Table 2).
    _rho_c_pa_s_m: float = PrivateAttr(default=DEFAULT_RHO_KG_M3 * DEFAULT_SOUND_SPEED_M_S)

    @model_validator(mode="after")
    def _check(self) -> Wall:
        label = f"wall {self.name!r}" if self.name else "wall"
        for field in ("start", "end"):
            xy = getattr(self, field)
            if not all(math.isfinite(v) for v in xy):
                raise ValueError(f"{label}: field '{field}' must be finite, got {list(xy)}")
        if math.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1]) <= 1e-9:
            raise ValueError(
                f"{label}: zero-length wall (fields 'start' and 'end' are both {list(self.start)})"
            )
        if self.reflection is not None and self.impedance_pa_s_m is not None:
            raise ValueError(
                f"{label}: give field 'reflection' or field 'impedance_pa_s_m', not both"
            )
        r = self.reflection
        if r is not None and not (math.isfinite(r) and abs(r) <= 1.0):
            raise ValueError(f"{label}: field 'reflection' must satisfy |R| <= 1, got {r}")
        z = self.impedance_pa_s_m
        if z is not None and (math.isnan(z) or z < 0):
            raise ValueError(
                f"{label}: field 'impedance_pa_s_m' must be >= 0 or 'inf', got {z}"
            )
        return self

    @field_serializer("impedance_pa_s_m")
    def _ser_impedance(self, z: float | None) -> float | str | None:
        return "inf" if z is not None and math.isinf(z) else z

    @property
    def length_m(self) -> float:
        """Length of the segment in metres."""
        return math.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1])

    @property
    def reflection_coefficient(self) -> float:
        """Pressure reflection coefficient R (rigid = 1; from Z with the scene's rho c)."""
        return self.reflection_coefficient_for(self._rho_c_pa_s_m)

    def reflection_coefficient_for(self, rho_c_pa_s_m: float) -> float:
        """R of this wall in a medium of characteristic impedance ``rho_c_pa_s_m`` (Pa s/m)."""
        if self.reflection is not None:
            return float(self.reflection)
        if self.impedance_pa_s_m is not None:
            return reflection_from_impedance(self.impedance_pa_s_m, rho_c_pa_s_m)
        return 1.0


class Scene(BaseModel):
    """A named set of walls in a medium of density ``rho_kg_m3`` and sound speed ``c``."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str
    description: str = ""
    walls: list[Wall]
    rho_kg_m3: float = DEFAULT_RHO_KG_M3
    sound_speed_m_s: float = DEFAULT_SOUND_SPEED_M_S

    @field_validator("walls")
    @classmethod
    def _copy_walls(cls, walls: list[Wall]) -> list[Wall]:
        if not walls:
            raise ValueError("a scene needs at least one wall")
        # copies, so setting the medium below never touches a Wall shared with another scene
        return [w.model_copy() for w in walls]

    @model_validator(mode="after")
    def _check(self) -> Scene:
        for field in ("rho_kg_m3", "sound_speed_m_s"):
            v = getattr(self, field)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"scene field '{field}' must be finite and > 0, got {v}")
        rho_c = self.rho_kg_m3 * self.sound_speed_m_s
        for w in self.walls:
            w._rho_c_pa_s_m = rho_c
        return self

    # ---- arrays for the engines -------------------------------------------------------
    def segments(self) -> NDArray[np.float64]:
        """Wall segments as a float64 array (W, 2, 2): ``[[x0, y0], [x1, y1]]`` per wall."""
        return np.array([[w.start, w.end] for w in self.walls], dtype=np.float64)

    def reflection_coefficients(self) -> NDArray[np.float64]:
        """Pressure reflection coefficient R of every wall, float64 (W,)."""
        rho_c = self.rho_kg_m3 * self.sound_speed_m_s
        return np.array([w.reflection_coefficient_for(rho_c) for w in self.walls],
                        dtype=np.float64)

    def bounds_m(self) -> tuple[float, float, float, float]:
        """Bounding box of all walls: ``(xmin, ymin, xmax, ymax)`` in metres."""
        pts = self.segments().reshape(-1, 2)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])

    # ---- JSON -----------------------------------------------------------------------
    def to_json(self) -> str:
        """JSON text of the scene (rigid impedance written as ``"inf"``)."""
        return self.model_dump_json(indent=2)

    @classmethod
    def from_json(cls, text: str) -> Scene:
        """Parse and validate scene JSON; ``ValueError`` naming the wall and field on error."""
        try:
            raw = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"scene JSON is not valid JSON: {exc}") from exc
        if not isinstance(raw, dict):
            raise ValueError(f"scene JSON must be an object, got {type(raw).__name__}")
        try:
            return cls.model_validate(raw)
        except ValidationError as exc:
            raise ValueError(_describe(exc, raw)) from None


def _describe(exc: ValidationError, raw: dict[str, Any]) -> str:
    """One readable line per pydantic error, naming the wall index and name."""
    lines = []
    walls_raw = raw.get("walls")
    walls: list[Any] = walls_raw if isinstance(walls_raw, list) else []
    for err in exc.errors():
        loc = list(err["loc"])
        where = "scene"
        if len(loc) >= 2 and loc[0] == "walls" and isinstance(loc[1], int):
            i = loc[1]
            name = walls[i].get("name", "") if i < len(walls) and isinstance(walls[i], dict) else ""
            where = f"walls[{i}]" + (f" ({name!r})" if name else "")
            loc = loc[2:]
        field = ".".join(str(p) for p in loc)
        msg = str(err["msg"]).removeprefix("Value error, ")
        if msg.startswith("wall") and ": " in msg:  # the wall's own label; `where` names it
            msg = msg.split(": ", 1)[1]
        lines.append(f"{where}" + (f" field '{field}'" if field else "") + f": {msg}")
    return "invalid scene: " + "; ".join(lines)


# ---- built-in scenes ------------------------------------------------------------------
def _polygon(name: str, description: str, corners: list[tuple[float, float]],
             wall_names: list[str] | None = None) -> Scene:
    """Closed room from its corners (counter-clockwise); wall i runs corner i -> i+1."""
    n = len(corners)
    names = wall_names or [f"wall {i + 1}" for i in range(n)]
    walls = [Wall(start=corners[i], end=corners[(i + 1) % n], name=names[i]) for i in range(n)]
    return Scene(name=name, description=description, walls=walls)


#: y of Wall 3 in the ``paper`` reconstruction, and where its segment starts (x).
PAPER_WALL3_Y_M = 1.36
PAPER_WALL3_X0_M = 2.3

PAPER_WALL3_NOTE = (
    "Wall 3 is not located by the paper's text; it is placed so that the 3-bounce echo "
    "walls 1 -> 2 -> 3 seen from point (a) = (2, 2) while heading pi/4 lands where Sec. 5 "
    "reports its image, (5.5, 1). That image means a one-way range |(5.5, 1) - (2, 2)| = 3.64 m "
    "(round trip 7.28 m) and, by the mixed Doppler of emission and reception, "
    "(cos theta_dep + cos theta_arr) / 2 = cos(angle of the image from the heading) = 0.486. "
    "A search over all straight lines for Wall 3 with valid specular points on walls 1 and 2 "
    "gives one family only: a horizontal wall at y = 1.36 m (R round trip 7.27 m, mean cosine "
    "0.486), bouncing at (2.61, 1.36). The segment starts at x = 2.3 m so that the foot of the "
    "perpendicular from (a), (2, 1.36), is off the wall: Wall 3 gives no first-order echo at "
    "(a), as the paper says ('the other wall surfaces are out of sight'), and it meets Wall 2 "
    "in a right-angle corner at (4.5, 1.36) ('the values are large at the corners')."
)


def _paper() -> Scene:
    y3, x3 = PAPER_WALL3_Y_M, PAPER_WALL3_X0_M
    walls = [
        Wall(name="wall 1", start=(0.5, 4.0), end=(4.5, 4.0)),
        Wall(name="wall 2", start=(4.5, 4.0), end=(4.5, y3)),
        Wall(name="wall 3", start=(4.5, y3), end=(x3, y3)),
    ]
    return Scene(
        name="paper",
        description=(
            "RECONSTRUCTION of the paper's Fig. 4 from its text (5 m x 5 m domain, rigid walls, "
            "open elsewhere): Wall 1 at y = 4, Wall 2 at x = 4.5, corner (4.5, 4); point (a) = "
            "(2, 2). " + PAPER_WALL3_NOTE
        ),
        walls=walls,
    )


_BUILDERS = {
    "paper": _paper,
    "shoebox": lambda: _polygon(
        "shoebox", "4 m x 3 m rigid rectangle (not square: only 2-fold symmetry)",
        [(0.0, 0.0), (4.0, 0.0), (4.0, 3.0), (0.0, 3.0)], ["south", "east", "north", "west"]),
    "l-room": lambda: _polygon(
        "l-room", "non-convex L-shaped room, 5 m x 5 m with 2 m wide arms, rigid walls",
        [(0.0, 0.0), (5.0, 0.0), (5.0, 2.0), (2.0, 2.0), (2.0, 5.0), (0.0, 5.0)]),
    "corridor": lambda: _polygon(
        "corridor", "10 m x 2 m rigid corridor: long and symmetric (a failure case for "
        "localization)", [(0.0, 0.0), (10.0, 0.0), (10.0, 2.0), (0.0, 2.0)],
        ["south", "east", "north", "west"]),
    "pillar": lambda: Scene(
        name="pillar",
        description="5 m x 4 m rigid room with a free-standing 0.6 m square column centred "
                    "at (2.5, 2.0) (4 walls of its own; its edges would diffract in reality)",
        walls=_polygon("room", "", [(0.0, 0.0), (5.0, 0.0), (5.0, 4.0), (0.0, 4.0)],
                       ["south", "east", "north", "west"]).walls
        + [Wall(name=f"pillar {side}", start=a, end=b) for side, a, b in [
            ("south", (2.2, 1.7), (2.8, 1.7)), ("east", (2.8, 1.7), (2.8, 2.3)),
            ("north", (2.8, 2.3), (2.2, 2.3)), ("west", (2.2, 2.3), (2.2, 1.7))]],
    ),
}


def builtin_scene_names() -> list[str]:
    """Names of the built-in scenes, addressable as ``builtin:NAME``."""
    return list(_BUILDERS)


def builtin_scene(name: str) -> Scene:
    """The built-in scene ``name`` (see :func:`builtin_scene_names`)."""
    if name not in _BUILDERS:
        raise ValueError(f"scene name must be one of {builtin_scene_names()}, got {name!r}")
    return _BUILDERS[name]()
