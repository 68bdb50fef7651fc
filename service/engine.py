"""The service's only link to the computation: blocks in, filter estimates out.

The HTTP layer and the session store talk to a :class:`Tracker` (one live filter) made by a
:class:`TrackerFactory`. :class:`LocalizationFactory` is the real one: it turns a block into a
heat map with :func:`mapping.heatmap.doppler_heatmap` and steps a filter from
``localization``. Nothing in this module computes a pose itself; it converts between the
core's dataclasses and plain values for the API.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from mapping.signal import SonarConfig


def wrap_angle(a: float) -> float:
    """Wrap an angle to (-pi, pi] (ROS REP-103 yaw)."""
    w = math.remainder(float(a), 2 * math.pi)  # in [-pi, pi]
    return math.pi if w <= -math.pi else w


@dataclass(frozen=True)
class FilterSpec:
    """What a session asked for at creation."""

    kind: str = "pf"
    particles: int = 2000
    seed: int = 0
    initial_pose: tuple[float, float, float] | None = None
    initial_covariance: tuple[tuple[float, ...], ...] | None = None
    beta: float | None = None       # sensor sharpness; None: the server's default

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FilterSpec:
        pose = d.get("initial_pose")
        cov = d.get("initial_covariance")
        return cls(
            kind=str(d["kind"]), particles=int(d["particles"]), seed=int(d["seed"]),
            initial_pose=None if pose is None else (float(pose[0]), float(pose[1]),
                                                     float(pose[2])),
            initial_covariance=None if cov is None else tuple(tuple(map(float, r)) for r in cov),
            beta=None if d.get("beta") is None else float(d["beta"]),
        )


@dataclass(frozen=True)
class BlockInput:
    """One validated block: samples (B,) float64 and the odometry over it."""

    seq: int
    samples: NDArray[np.float64]
    fs_hz: float
    speed_m_s: float
    yaw_rate_rad_s: float
    dt_s: float = 0.0  # set by the store: previous committed block's midpoint to this one's


#: Longest odometry step passed to a filter (localization.motion accepts dt <= 60 s).
MAX_STEP_S = 60.0


def block_dt_s(seq: int, last_seq: int | None, block_s: float) -> float:
    """Time from the previous committed block's midpoint to block ``seq``'s (0 at first).

    A gap in ``seq`` (lost blocks) lengthens the step; it is capped at :data:`MAX_STEP_S`.
    """
    if last_seq is None:
        return 0.0
    return min(float(seq - last_seq) * block_s, MAX_STEP_S)


@dataclass(frozen=True)
class EstimateOut:
    """A filter estimate in plain values (yaw wrapped to (-pi, pi])."""

    pose: tuple[float, float, float]
    covariance: tuple[tuple[float, float, float], ...]
    modes: tuple[tuple[float, float, float, float], ...]  # x, y, yaw, weight
    ess: float
    converged: bool
    direction_observable: bool
    covariance_all: tuple[tuple[float, float, float], ...] | None = None
    processing_ms: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)

    def with_processing_ms(self, ms: float) -> EstimateOut:
        return replace(self, processing_ms=float(ms))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EstimateOut:
        cov_all = d.get("covariance_all")
        return cls(
            pose=_tuple3(d["pose"]),
            covariance=tuple(_tuple3(r) for r in d["covariance"]),
            modes=tuple((float(m[0]), float(m[1]), float(m[2]), float(m[3])) for m in d["modes"]),
            ess=float(d["ess"]), converged=bool(d["converged"]),
            direction_observable=bool(d["direction_observable"]),
            covariance_all=None if cov_all is None else tuple(_tuple3(r) for r in cov_all),
            processing_ms=float(d.get("processing_ms", 0.0)),
            extra=dict(d.get("extra", {})),
        )

    def covariance_ros(self) -> list[float]:
        """Row-major 6x6 over (x, y, z, roll, pitch, yaw); z/roll/pitch rows zero (AMCL)."""
        c6 = np.zeros((6, 6))
        idx = [0, 1, 5]
        c6[np.ix_(idx, idx)] = np.asarray(self.covariance)
        return [float(v) for v in c6.ravel()]


def _tuple3(v: Any) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


class Tracker(Protocol):
    """One live filter on one map."""

    config: SonarConfig

    def update(self, block: BlockInput) -> EstimateOut: ...

    def reinit_global(self) -> None: ...

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: dict[str, Any]) -> None: ...

    def particles(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """``(poses (n, 3), weights (n,))`` or None when the filter has no particles."""
        ...


class TrackerFactory(Protocol):
    """Makes trackers on stored maps."""

    def create(self, map_id: str, spec: FilterSpec) -> Tracker: ...

    def restore(self, map_id: str, spec: FilterSpec, state: dict[str, Any]) -> Tracker: ...
