"""What every forward model (image source, FDTD) shares: inputs, one simulated block, a run.

An engine is a generator ``iter_blocks(scene, trajectory, config, n_blocks, engine_config,
rng)`` yielding :class:`SimBlock` in order; :func:`assemble_run` turns the blocks into a
:class:`~mapping.runfile.Run`. Engines accept any objects with the methods of
:class:`SceneLike` and :class:`TrajectoryLike` (``mapping.scene.Scene`` and
``mapping.path.Trajectory`` are the real ones).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.run import Run
from mapping.signal import SonarConfig

FloatArray = NDArray[np.float64]


class SceneLike(Protocol):
    """Wall segments and their reflection coefficients."""

    @property
    def name(self) -> str: ...

    def segments(self) -> FloatArray: ...

    def reflection_coefficients(self) -> FloatArray: ...

    def to_json(self) -> str: ...


class TrajectoryLike(Protocol):
    """A trajectory: pose and velocity at any time (constant velocity outside its span)."""

    @property
    def name(self) -> str: ...

    @property
    def duration_s(self) -> float: ...

    def position(self, t_s: ArrayLike) -> FloatArray: ...

    def velocity(self, t_s: ArrayLike) -> FloatArray: ...

    def pose(self, t_s: ArrayLike) -> FloatArray: ...

    def speed_m_s(self, t_s: ArrayLike) -> FloatArray: ...

    def yaw_rate_rad_s(self, t_s: ArrayLike) -> FloatArray: ...


@dataclass(frozen=True)
class PathTable:
    """Ground truth of the echo paths heard in one block (arrays over paths).

    Attributes
    ----------
    order : ndarray of int, shape (n,)
        Number of reflections.
    walls : tuple of tuple of int
        Wall ids in the order the sound hits them.
    delay_s : ndarray, shape (n,)
        Retarded round-trip delay at the block midpoint.
    doppler_factor : ndarray, shape (n,)
        Time-compression factor ``1 - d tau / dt`` at the midpoint (> 1 when approaching).
    angle_to_velocity_rad : ndarray, shape (n,)
        Angle in [0, pi] between the velocity and the direction the echo arrives from.
    reflection : ndarray, shape (n,)
        Product of the reflection coefficients.
    amplitude : ndarray, shape (n,)
        Reflection product times spreading at the midpoint.
    """

    order: NDArray[np.int64]
    walls: tuple[tuple[int, ...], ...]
    delay_s: FloatArray
    doppler_factor: FloatArray
    angle_to_velocity_rad: FloatArray
    reflection: FloatArray
    amplitude: FloatArray

    @property
    def n(self) -> int:
        """Number of paths."""
        return int(self.order.size)


@dataclass(frozen=True)
class SimBlock:
    """One simulated sonar block and its ground truth.

    Attributes
    ----------
    index : int
        Block number k (samples start at k * block_samples).
    samples : ndarray, float64 (block_samples,)
        Microphone signal (direct wave excluded).
    t_s : float
        Block start time.
    pose : ndarray, shape (3,)
        True x_m, y_m, heading_rad at the block midpoint.
    speed_m_s : float
        Recorded (odometry) speed, possibly noisy: the block's mean
        (:func:`block_mean_odometry`).
    yaw_rate_rad_s : float
        Recorded yaw rate: the block's mean, the heading change over the block divided by
        its length (:func:`block_mean_odometry`), as wheel odometry integrates it.
    paths : PathTable
        Echo paths heard in the block.
    """

    index: int
    samples: FloatArray
    t_s: float
    pose: FloatArray
    speed_m_s: float
    yaw_rate_rad_s: float
    paths: PathTable
    meta: dict[str, Any] = field(default_factory=dict)


def block_mean_odometry(trajectory: TrajectoryLike, t0_s: float, t1_s: float
                        ) -> tuple[float, float]:
    """The odometry of the block ``[t0_s, t1_s]``: mean speed (9-point Simpson rule) and mean
    yaw rate (the heading change over the block, wrapped, divided by its length).

    A robot's odometry integrates its wheels: the rotation it reports for a block is the
    rotation that happened. The rate at the block's midpoint is not: on a rounded corner
    that ends inside a block it misses the rest of the turn (measured on the kitchen-line
    run: a 90 deg corner reported as 73 deg, the filter lost after every sharp turn).
    """
    if not t1_s > t0_s:
        raise ValueError(f"block must have t1_s > t0_s, got {t0_s}, {t1_s}")
    t = np.linspace(t0_s, t1_s, 9)
    v = np.asarray(trajectory.speed_m_s(t), dtype=np.float64).ravel()
    simpson = np.array([1, 4, 2, 4, 2, 4, 2, 4, 1], dtype=np.float64) / 24.0
    h = np.asarray(trajectory.pose(np.array([t0_s, t1_s])), dtype=np.float64).reshape(2, 3)[:, 2]
    turn = (h[1] - h[0] + np.pi) % (2.0 * np.pi) - np.pi
    return float(simpson @ v), float(turn / (t1_s - t0_s))


def assemble_run(
    blocks: Iterable[SimBlock],
    config: SonarConfig,
    scene_json: str | None,
    meta: dict[str, Any],
) -> Run:
    """Collect simulated blocks (in order) into a :class:`~mapping.runfile.Run`.

    Raises ``ValueError`` if no block is given.
    """
    items = list(blocks)
    if not items:
        raise ValueError("assemble_run needs at least one block")
    return Run(
        config=config,
        samples=np.stack([b.samples for b in items]).astype(np.float32),
        t_s=np.array([b.t_s for b in items], dtype=np.float64),
        speed_m_s=np.array([b.speed_m_s for b in items], dtype=np.float64),
        yaw_rate_rad_s=np.array([b.yaw_rate_rad_s for b in items], dtype=np.float64),
        pose=np.stack([b.pose for b in items]).astype(np.float64),
        scene=scene_json,
        meta=dict(meta),
    )
