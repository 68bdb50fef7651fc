"""Request and response models of the HTTP API (pydantic lives at the edges).

Frames and units follow ROS REP-103: x forward/east, y left/north, yaw counter-clockwise from
the x axis in radians, wrapped to (-pi, pi]; positions in metres in the map frame. The
6x6 covariance is ROS ``geometry_msgs/PoseWithCovariance`` order (x, y, z, roll, pitch, yaw),
row-major, with the planar entries filled and z/roll/pitch zero, as AMCL publishes it.
"""

from __future__ import annotations

import math
import re
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    field_validator,
    model_validator,
)

#: Identifiers of maps, sessions and run files: safe as file names.
ID_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"
MapId = Annotated[str, Field(pattern=ID_PATTERN, description="map identifier")]

#: Largest sequence number (fits a JSON double exactly).
MAX_SEQ = 2**53 - 1
#: Odometry limits accepted for one block.
MAX_SPEED_M_S = 5.0
MAX_YAW_RATE_RAD_S = 10.0
MAX_COORD_M = 1.0e4

#: Allowed values of the main request fields, quoted in 422 bodies.
FIELD_RANGES = {
    "seq": "integer, last committed seq + 1 .. + OMNISONAR_MAX_SEQ_GAP (first: 0 .. gap)",
    "fs_hz": "the map's sampling rate (40000 for Table 1)",
    "speed_m_s": f"finite, -{MAX_SPEED_M_S} <= speed_m_s <= {MAX_SPEED_M_S}",
    "yaw_rate_rad_s": f"finite, -{MAX_YAW_RATE_RAD_S} <= yaw_rate_rad_s <= {MAX_YAW_RATE_RAD_S}",
    "encoding": "float32 or int16",
    "x": f"finite, |x| <= {MAX_COORD_M:g} m",
    "y": f"finite, |y| <= {MAX_COORD_M:g} m",
    "yaw": "finite, |yaw| <= 2 pi",
    "particles": "integer >= 10 (and <= OMNISONAR_MAX_PARTICLES)",
    "max": "integer 1..20000",
}

Coord = Annotated[float, Field(ge=-MAX_COORD_M, le=MAX_COORD_M, allow_inf_nan=False)]
Yaw = Annotated[float, Field(ge=-2 * math.pi, le=2 * math.pi, allow_inf_nan=False)]


class _Strict(BaseModel):
    """Request bodies: unknown fields refused, no coercion (``"2000"`` is not a number,
    ``"yes"`` not a boolean, ``true`` not an integer)."""

    model_config = ConfigDict(extra="forbid", strict=True)


_INT_TEXT = re.compile(r"[0-9]{1,19}")
_FLOAT_TEXT = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]{1,3})?")


def _plain_int(v: Any) -> Any:
    """Query text of an integer: decimal digits only (no ``1_0``, sign, space or ``true``)."""
    if isinstance(v, str) and not _INT_TEXT.fullmatch(v):
        raise ValueError("must be written with decimal digits only")
    return v


def _plain_float(v: Any) -> Any:
    """Query text of a number: decimal or exponent notation (no ``1_0``, space, ``nan``)."""
    if isinstance(v, str) and not _FLOAT_TEXT.fullmatch(v):
        raise ValueError("must be a decimal number (e.g. 0.25 or 4e4)")
    return v


#: Validator of an integer query parameter: decimal digits only.
PlainInt = BeforeValidator(_plain_int)


class Pose2D(_Strict):
    """Planar pose in the map frame (REP-103)."""

    x: Coord = Field(description="metres")
    y: Coord = Field(description="metres")
    yaw: Yaw = Field(description="radians, counter-clockwise from x; output in (-pi, pi]")


class ErrorBody(BaseModel):
    """Every 4xx/5xx answer: a code, a message and, for bad input, the field and its range."""

    error: str
    detail: str
    field: str | None = None
    allowed: str | None = None
    errors: list[dict[str, object]] | None = None


# ---- maps ---------------------------------------------------------------------------------
class MapInfo(BaseModel):
    """Metadata of one stored map (no G values; see ``/maps/{id}/image.png``)."""

    id: str
    shape: tuple[int, int] = Field(description="(ny, nx) cells")
    origin_m: tuple[float, float] = Field(description="centre of cell [0, 0]")
    resolution_m: float
    extent_m: tuple[float, float, float, float] = Field(description="xmin, xmax, ymin, ymax")
    method: str
    params: dict[str, object]
    provenance: dict[str, object]
    sonar: dict[str, object]
    size_bytes: int
    sha256: str = Field(description="SHA-256 of the stored file; sessions pin it")


class MapList(BaseModel):
    maps: list[MapInfo]
    building: list[str] = Field(description="map ids whose build job is still running")


class BuildRequest(_Strict):
    """Batch build of a map from run files already in the server's runs directory."""

    runs: list[Annotated[str, Field(pattern=ID_PATTERN)]] = Field(
        min_length=1, max_length=1000, description="run file names in OMNISONAR_RUNS_DIR"
    )
    map_id: MapId
    method: str = Field("paper", pattern=r"^[a-z0-9_-]{1,32}$")
    overwrite: bool = False


class Job(BaseModel):
    """A background map build."""

    id: str
    kind: Literal["build", "default-map"]
    map_id: str
    status: Literal["queued", "running", "done", "failed"]
    progress: float = Field(ge=0.0, le=1.0)
    message: str = ""
    created_at: float
    finished_at: float | None = None


# ---- sessions -----------------------------------------------------------------------------
class SessionCreate(_Strict):
    """``POST /sessions``: a filter on a map, tracked from a pose or global."""

    map_id: MapId
    filter: Literal["pf", "grid"] = "pf"
    particles: int = Field(2000, ge=10, description="particle count (pf); capped by settings")
    seed: int | None = Field(None, ge=0, le=2**63 - 1)
    initial_pose: Pose2D | None = Field(None, description="omit (or global=true) for global")
    initial_covariance: list[list[float]] | None = Field(
        None, description="3x3 covariance of (x, y, yaw) in m^2, m*rad, rad^2 (default with "
        "initial_pose: 10 cm in x and y, 10 deg in yaw, independent)"
    )
    global_: bool = Field(False, alias="global", description="uniform over the mapped region")
    beta: float | None = Field(
        None, gt=0, le=100_000, description="sensor sharpness for this session (default: the "
        "server's, 200); `omnisonar calibrate` picks an honest one per map")
    sound_speed_m_s: float | None = Field(
        None, ge=300, le=380, description="speed of sound in the robot's air for this session "
        "(331.3 sqrt(1 + T/273.15) m/s at T deg C; `omnisonar stream --temperature` sends it); "
        "default: the map's sonar config. Ranges and Doppler angles scale with it: 1.7 % for "
        "10 K")
    sonar_height_m: float | None = Field(
        None, gt=0, le=10, description="the sonar's height above the floor (m): the echo "
        "model then also predicts every wall echo's copies off the floor (and the ceiling)")
    ceiling_height_m: float | None = Field(
        None, gt=0, le=50, description="the ceiling's height (m), with sonar_height_m")
    open_map: Literal["uncertain", "confirm"] = Field(
        "uncertain", description="a global start, or a filter that lost its track and found a "
        "place again, on a map built from runs with an open wall end (free space the map "
        "knows nothing of): never reported converged ('uncertain'), "
        "or as on a closed map ('confirm': the robot is known to be in the mapped part)")

    model_config = ConfigDict(extra="forbid", populate_by_name=True, strict=True)

    @field_validator("initial_covariance")
    @classmethod
    def _covariance(cls, v: list[list[float]] | None) -> list[list[float]] | None:
        if v is None:
            return v
        return check_covariance(v)

    @model_validator(mode="after")
    def _init_mode(self) -> SessionCreate:
        if self.global_ and self.initial_pose is not None:
            raise ValueError("give either initial_pose (tracked) or global=true, not both")
        if self.initial_pose is None and self.initial_covariance is not None:
            raise ValueError("initial_covariance needs initial_pose")
        return self

    @property
    def is_global(self) -> bool:
        return self.initial_pose is None


def check_covariance(v: list[list[float]]) -> list[list[float]]:
    """Validate a 3x3 symmetric positive semi-definite covariance given as nested lists."""
    if len(v) != 3 or any(len(row) != 3 for row in v):
        raise ValueError("initial_covariance must be 3x3")
    a = np.asarray(v, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        raise ValueError("initial_covariance must be finite")
    if np.abs(a).max() > 1e6:
        raise ValueError("initial_covariance entries must be within +-1e6")
    if not np.allclose(a, a.T, rtol=1e-9, atol=1e-12):
        raise ValueError("initial_covariance must be symmetric")
    if np.linalg.eigvalsh(a).min() < -1e-12:  # the filters' own test, so they never refuse it
        raise ValueError("initial_covariance must be positive semi-definite")
    return [[float(x) for x in row] for row in a]


class Mode(BaseModel):
    pose: Pose2D
    weight: float


class Estimate(BaseModel):
    """The filter's answer after one block."""

    session_id: str
    seq: int | None = Field(description="sequence number of the last committed block")
    frame_id: str = "map"
    pose: Pose2D
    covariance: list[list[float]] = Field(description="3x3 covariance of (x, y, yaw), best mode")
    covariance_ros: list[float] = Field(
        description="36 values, row-major 6x6 over (x, y, z, roll, pitch, yaw)"
    )
    covariance_all: list[list[float]] | None = Field(
        None, description="3x3 covariance of the whole particle set"
    )
    modes: list[Mode]
    ess: float = Field(description="effective sample size")
    converged: bool
    direction_observable: bool
    likelihood_scale: float = Field(
        1.0, description="share of this block's log-likelihood applied (1: all; less when "
        "the update was tempered to keep enough particles alive)")
    status: Literal["converged", "uncertain", "lost"] = Field(
        "uncertain", description="converged: one compact mode, inside the map's coverage and "
        "(echo model) the block explained at the estimate; uncertain: several modes, outside "
        "the coverage, nothing heard or one unexplained block; lost: unexplained blocks in a "
        "row (the filter is re-localizing)")
    fit: float | None = Field(
        None, description="echo model: how well the estimate explains the block, in [0, 1] "
        "(null for the G models or a block without echoes)")
    covered: bool = Field(True, description="the estimate lies where the map has evidence")
    refined: bool = Field(False, description="pose and covariance come from the Gaussian "
                          "refinement of the converged mode on the block's echoes (echo model) "
                          "rather than from the particles; modes are always the particles'")
    reckoned: bool = Field(False, description="pose and covariance are dead reckoning from the "
                           "last confirmed convergence (status never converged): the particles "
                           "went to a look-alike the blocks do not prefer by the prior odds of "
                           "a kidnap, or where the map predicts no echo; modes hold it")
    reason: str = Field("", description="particle filter: why the status is not converged "
                        "(empty when it is): unexplained, misfit, no_echo, outside_coverage, "
                        "rivals, spread, confirming, jump_held, reconfirming, rival_doubt, "
                        "open_map (docs: localization guide)")
    processing_ms: float = Field(description="server time for this update")


class SessionInfo(BaseModel):
    id: str
    map_id: str
    map_sha256: str | None = Field(None, description="SHA-256 of the map file the session "
                                   "runs on (an overwritten map never changes it)")
    filter: Literal["pf", "grid"]
    particles: int
    seed: int
    beta: float | None = Field(None, description="sensor sharpness asked for at creation "
                               "(null: the server's default)")
    sound_speed_m_s: float | None = Field(None, description="speed of sound asked for at "
                                          "creation (null: the map's)")
    sonar_height_m: float | None = Field(None, description="sonar height asked for (null: a "
                                         "2-D room)")
    ceiling_height_m: float | None = Field(None, description="ceiling height asked for")
    open_map: Literal["uncertain", "confirm"] = Field(
        "uncertain", description="what a global start or a re-localization on an open map "
        "reports (see POST /sessions)")
    created_at: float
    last_active_at: float
    expires_in_s: float
    last_seq: int | None
    n_updates: int
    estimate: Estimate | None


Seq = Annotated[int, Field(ge=0, le=MAX_SEQ, description="increasing per session: each block "
                          "last+1 .. last+OMNISONAR_MAX_SEQ_GAP (first: 0 .. the gap)")]
FsHz = Annotated[float, Field(gt=0, allow_inf_nan=False, description="must equal the map's fs")]
Speed = Annotated[float, Field(ge=-MAX_SPEED_M_S, le=MAX_SPEED_M_S, allow_inf_nan=False,
                               description="m/s, forward positive")]
YawRate = Annotated[float, Field(ge=-MAX_YAW_RATE_RAD_S, le=MAX_YAW_RATE_RAD_S,
                                 allow_inf_nan=False, description="rad/s, counter-clockwise")]
_QF = BeforeValidator(_plain_float)
Encoding = Literal["float32", "int16"]


class BlockQuery(BaseModel):
    """Query parameters of a raw (``application/octet-stream``) block: its odometry.

    ``seq``, ``fs_hz`` and ``speed_m_s`` are required for raw blocks (the handler says which
    is missing); a JSON block carries them in its body and takes no query parameters.
    """

    seq: Annotated[Seq | None, BeforeValidator(_plain_int)] = None
    fs_hz: Annotated[FsHz | None, _QF] = None
    speed_m_s: Annotated[Speed | None, _QF] = None
    yaw_rate_rad_s: Annotated[YawRate, _QF] = 0.0
    encoding: Encoding = Field("float32", description="float32, or int16 (full scale 32768)")


class BlockJSON(_Strict):
    """A block as JSON: the samples base64-encoded, the odometry alongside."""

    seq: Seq
    fs_hz: FsHz
    speed_m_s: Speed
    yaw_rate_rad_s: YawRate = 0.0
    encoding: Encoding = "float32"
    samples_b64: str = Field(description="little-endian samples, base64 (RFC 4648)")


class Particles(BaseModel):
    """A downsampled view of the particle set, for display."""

    n_total: int
    x: list[float]
    y: list[float]
    yaw: list[float]
    weight: list[float]
