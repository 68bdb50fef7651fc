"""Analytic echo of a moving monostatic sonar: the independent truth for the heat map.

A co-located loudspeaker and microphone move at constant velocity on a straight line,

    p(t) = v (t - t_ref) (cos h, sin h),

next to ONE reflector: an infinite rigid wall (a line) or one point reflector. The received
signal is computed from geometry alone: for every sample time t the exact retarded two-way
delay tau(t) is solved (no Doppler formula is used), and the echo is

    r(t) = R * A(t) * s(t - tau(t)),

with ``s = transmitted_at`` (the band-limited transmitted signal), R the reflection factor and
A the spherical spreading (1 / path length for the wall's image source, 1 / (r1 r2) for the
point). Sample n of the run is taken at ``t = n / fs`` (block k: ``(k B + n) / fs``), the same
clock as the transmission.

Targets are placed relative to the sonar at ``t_ref``: the wall's normal (sonar -> wall) and
the point's bearing are angles from the direction of travel, positive to the left.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from mapping.run import Run
from mapping.signal import SonarConfig, transmitted_at

FloatArray = NDArray[np.float64]

_MAX_ITER = 60
_TOL_S = 1e-14


@dataclass(frozen=True)
class Motion:
    """Straight-line constant-velocity motion: at ``t_ref_s`` the sonar is at the origin.

    ``speed_m_s`` >= 0 along ``heading_rad`` (direction of travel, world frame).
    """

    speed_m_s: float
    heading_rad: float = 0.0
    t_ref_s: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.speed_m_s) and 0.0 <= self.speed_m_s < 34.0):
            raise ValueError(f"Motion.speed_m_s must be in [0, 34) m/s, got {self.speed_m_s}")
        if not (math.isfinite(self.heading_rad) and math.isfinite(self.t_ref_s)):
            raise ValueError("Motion.heading_rad and Motion.t_ref_s must be finite")

    def position(self, t_s: FloatArray) -> FloatArray:
        """Sonar position (..., 2) in metres at times ``t_s``."""
        s = self.speed_m_s * (np.asarray(t_s, dtype=np.float64) - self.t_ref_s)
        return np.stack([s * math.cos(self.heading_rad), s * math.sin(self.heading_rad)], -1)

    @property
    def velocity(self) -> FloatArray:
        """Velocity vector (2,) in m/s."""
        h = self.heading_rad
        return np.array([self.speed_m_s * math.cos(h), self.speed_m_s * math.sin(h)])


@dataclass(frozen=True)
class Wall:
    """Infinite rigid wall: perpendicular distance at ``t_ref`` and the angle of its normal
    (from the sonar towards the wall) relative to the direction of travel, left positive."""

    distance_m: float
    normal_angle_rad: float
    reflection: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.distance_m) and self.distance_m > 0):
            raise ValueError(f"Wall.distance_m must be positive, got {self.distance_m}")
        if not (math.isfinite(self.normal_angle_rad) and math.isfinite(self.reflection)):
            raise ValueError("Wall.normal_angle_rad and Wall.reflection must be finite")


@dataclass(frozen=True)
class PointReflector:
    """Point reflector at ``range_m`` and ``bearing_rad`` (from the direction of travel, left
    positive) from the sonar at ``t_ref``."""

    range_m: float
    bearing_rad: float
    reflection: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.range_m) and self.range_m > 0):
            raise ValueError(f"PointReflector.range_m must be positive, got {self.range_m}")
        if not (math.isfinite(self.bearing_rad) and math.isfinite(self.reflection)):
            raise ValueError("PointReflector.bearing_rad and reflection must be finite")


Target = Wall | PointReflector


@dataclass(frozen=True)
class EchoTruth:
    """Geometric truth of the echo received at one time.

    ``delay_s`` is the exact retarded two-way delay, ``range_m = c delay / 2`` (what the heat
    map's range axis measures), ``distance_m`` the geometric distance (wall: perpendicular;
    point: sonar to point) at that time, ``angle_rad`` in [0, pi] the angle between the
    velocity and the wall normal / the direction to the point.
    """

    delay_s: float
    range_m: float
    distance_m: float
    angle_rad: float


def _wall_frame(motion: Motion, wall: Wall) -> tuple[FloatArray, float]:
    """World unit normal (sonar -> wall) and offset D with the wall = {x : n.x = D}."""
    phi = motion.heading_rad + wall.normal_angle_rad
    return np.array([math.cos(phi), math.sin(phi)]), wall.distance_m


def _point_position(motion: Motion, point: PointReflector) -> FloatArray:
    phi = motion.heading_rad + point.bearing_rad
    return point.range_m * np.array([math.cos(phi), math.sin(phi)])


def _fixed_point(f: object, guess: FloatArray) -> FloatArray:
    """Iterate ``tau <- f(tau)`` (a contraction with factor ~v/c) to ``_TOL_S``."""
    tau = guess
    for _ in range(_MAX_ITER):
        new = f(tau)  # type: ignore[operator]
        if np.max(np.abs(new - tau), initial=0.0) < _TOL_S:
            return np.asarray(new)
        tau = new
    raise RuntimeError("retarded-delay iteration did not converge")  # pragma: no cover


def echo_delay_s(
    t_s: FloatArray, motion: Motion, target: Target, sound_speed_m_s: float
) -> FloatArray:
    """Exact two-way retarded delay of the echo received at times ``t_s``.

    Wall (image source): solve ``|p(t) - I(t - tau)| = c tau`` with ``I`` the mirror image of
    the emitting position. Point: receive leg ``tau2 = |p(t) - q| / c`` (explicit), then
    ``|q - p(t - tau2 - tau1)| = c tau1``. Both by fixed-point iteration (contraction v/c).
    """
    t = np.asarray(t_s, dtype=np.float64)
    c = float(sound_speed_m_s)
    rx = motion.position(t)
    if isinstance(target, Wall):
        normal, offset = _wall_frame(motion, target)

        def wall_leg(tau: FloatArray) -> FloatArray:
            emit = motion.position(t - tau)
            image = emit + 2.0 * (offset - emit @ normal)[..., None] * normal
            return np.asarray(np.linalg.norm(rx - image, axis=-1) / c)

        d0 = offset - rx @ normal
        return _fixed_point(wall_leg, 2.0 * d0 / c)
    q = _point_position(motion, target)
    tau2 = np.linalg.norm(rx - q, axis=-1) / c

    def point_leg(tau1: FloatArray) -> FloatArray:
        emit = motion.position(t - tau2 - tau1)
        return np.asarray(np.linalg.norm(q - emit, axis=-1) / c)

    return np.asarray(tau2 + _fixed_point(point_leg, tau2))


def echo_samples(
    t_s: FloatArray, config: SonarConfig, motion: Motion, target: Target, *, spreading: bool = True
) -> FloatArray:
    """Received echo ``R A(t) s(t - tau(t))`` at times ``t_s`` (direct wave excluded).

    ``spreading=False`` sets A = 1 (unit-amplitude echo), handy for amplitude checks.
    """
    t = np.asarray(t_s, dtype=np.float64)
    c = config.sound_speed_m_s
    tau = echo_delay_s(t, motion, target, c)
    if not spreading:
        amp = np.ones_like(t)
    elif isinstance(target, Wall):
        amp = 1.0 / (c * tau)
    else:
        q = _point_position(motion, target)
        r2 = np.linalg.norm(motion.position(t) - q, axis=-1)
        amp = 1.0 / (np.maximum(c * tau - r2, 1e-9) * r2)
    return np.asarray(target.reflection * amp * transmitted_at(t - tau, config))


def echo_truth(t_s: float, motion: Motion, target: Target, sound_speed_m_s: float) -> EchoTruth:
    """Geometric truth (delay, range, distance, angle) of the echo received at ``t_s``."""
    tau = float(echo_delay_s(np.array([t_s]), motion, target, sound_speed_m_s)[0])
    rx = motion.position(np.array([t_s]))[0]
    heading = np.array([math.cos(motion.heading_rad), math.sin(motion.heading_rad)])
    if isinstance(target, Wall):
        normal, offset = _wall_frame(motion, target)
        direction, distance = normal, float(offset - rx @ normal)
    else:
        diff = _point_position(motion, target) - rx
        distance = float(np.linalg.norm(diff))
        direction = diff / distance
    # atan2 of (|cross|, dot), not acos(dot): acos loses half the digits near 0 and pi
    # (hypothesis found 6.1e-8 for a 6.0e-8 rad bearing)
    cross = float(direction[0] * heading[1] - direction[1] * heading[0])
    angle = math.atan2(abs(cross), float(direction @ heading))
    return EchoTruth(tau, sound_speed_m_s * tau / 2.0, distance, angle)


def synthetic_run(
    config: SonarConfig,
    target: Target,
    speed_m_s: float,
    *,
    n_blocks: int = 3,
    ref_block: int | None = None,
    heading_rad: float = 0.0,
    spreading: bool = True,
) -> Run:
    """Run of ``n_blocks`` blocks past one target; the target geometry holds at the midpoint
    of ``ref_block`` (default: the middle block).

    Poses are the true sonar positions at block midpoints; ``meta["truth"]`` lists the
    :class:`EchoTruth` of each block midpoint, ``meta["target"]`` the target.
    """
    if not isinstance(n_blocks, int) or n_blocks < 1:
        raise ValueError(f"n_blocks must be a positive integer, got {n_blocks!r}")
    ref = n_blocks // 2 if ref_block is None else ref_block
    if not 0 <= ref < n_blocks:
        raise ValueError(f"ref_block must be in 0..{n_blocks - 1}, got {ref}")
    b, fs = config.block_samples, config.fs_hz
    mids = (np.arange(n_blocks, dtype=np.float64) + 0.5) * config.block_s
    motion = Motion(speed_m_s, heading_rad, float(mids[ref]))
    samples = np.empty((n_blocks, b), dtype=np.float32)
    for k in range(n_blocks):
        t = (k * b + np.arange(b)) / fs
        samples[k] = echo_samples(t, config, motion, target, spreading=spreading)
    pos = motion.position(mids)
    pose = np.column_stack([pos, np.full(n_blocks, heading_rad)])
    truth = [asdict(echo_truth(float(t), motion, target, config.sound_speed_m_s)) for t in mids]
    kind = "wall" if isinstance(target, Wall) else "point"
    return Run(
        config=config,
        samples=samples,
        t_s=np.arange(n_blocks, dtype=np.float64) * config.block_s,
        speed_m_s=np.full(n_blocks, float(speed_m_s)),
        yaw_rate_rad_s=np.zeros(n_blocks),
        pose=pose,
        scene=None,
        meta={"engine": "synthetic", "target": {"kind": kind, **asdict(target)},
              "truth": truth, "ref_block": ref, "motion": asdict(motion),
              "spreading": spreading},
    )


def run_truth(run: Run, k: int) -> EchoTruth:
    """The :class:`EchoTruth` stored by :func:`synthetic_run` for block ``k``."""
    return EchoTruth(**run.meta["truth"][k])


def run_motion(run: Run) -> Motion:
    """The :class:`Motion` of a run made by :func:`synthetic_run`."""
    return Motion(**run.meta["motion"])


def run_target(run: Run) -> Target:
    """The target of a run made by :func:`synthetic_run`."""
    fields = dict(run.meta["target"])
    kind = fields.pop("kind")
    return Wall(**fields) if kind == "wall" else PointReflector(**fields)


def target_json(target: Target) -> str:
    """JSON of a target (for logs and run metadata)."""
    kind = "wall" if isinstance(target, Wall) else "point"
    return json.dumps({"kind": kind, **asdict(target)})
