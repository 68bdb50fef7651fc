"""Test doubles for the service's session store (never used by the shipped service).

``OdometryTracker`` integrates the odometry of each block on a small noisy pose set: its
output is checkable by hand (dead reckoning), it keeps an rng in its state, and it can be
told to fail *after* mutating its state, which is what the store's restore-on-failure must
undo. It lets the store and the HTTP layer be tested independently of the real filter.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from localization.estimate import Mode, PoseEstimate
from mapping.signal import SonarConfig
from service.sessions import BlockInput, FilterSpec, InvalidSpec


class OdometryTracker:
    def __init__(self, spec: FilterSpec, config: SonarConfig) -> None:
        self.config = config
        self.spec = spec
        rng = np.random.default_rng(spec.seed)
        start = np.asarray(spec.initial_pose or (0.0, 0.0, 0.0))
        self.poses = start + 0.01 * rng.standard_normal((spec.particles, 3))
        self.rng_state: Any = rng.bit_generator.state
        self.fail_after_mutation = False

    def update(self, block: BlockInput) -> PoseEstimate:
        rng = np.random.default_rng()
        rng.bit_generator.state = self.rng_state
        dt = block.dt_s
        h = self.poses[:, 2]
        self.poses[:, 0] += block.speed_m_s * dt * np.cos(h)
        self.poses[:, 1] += block.speed_m_s * dt * np.sin(h)
        self.poses[:, 2] += block.yaw_rate_rad_s * dt + 1e-3 * rng.standard_normal(h.size)
        self.rng_state = rng.bit_generator.state
        if self.fail_after_mutation or float(np.abs(block.samples).max()) > 1e3:
            raise ValueError("samples out of range (test double)")
        return self.estimate(abs(block.speed_m_s) > 0.004)

    def estimate(self, observable: bool = True) -> PoseEstimate:
        m = self.poses.mean(axis=0)
        cov = np.cov(self.poses.T)
        return PoseEstimate(
            pose=m, cov=cov, mean_all=m, cov_all=cov, modes=(Mode(1.0, m, cov),),
            ess=float(self.poses.shape[0]), converged=True, direction_observable=observable,
            updated=True, model="odometry")

    def reinit_global(self) -> None:
        rng = np.random.default_rng()
        rng.bit_generator.state = self.rng_state
        n = self.poses.shape[0]
        self.poses = np.column_stack([rng.uniform(0, 4, n), rng.uniform(0, 3, n),
                                      rng.uniform(-math.pi, math.pi, n)])
        self.rng_state = rng.bit_generator.state

    def state_dict(self) -> dict[str, Any]:
        return {"poses": self.poses.copy(), "rng": self.rng_state}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.poses = np.array(state["poses"], dtype=np.float64)
        self.rng_state = state["rng"]

    def particles(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        n = self.poses.shape[0]
        return self.poses.copy(), np.full(n, 1.0 / n)


class OdometryFactory:
    """Factory of :class:`OdometryTracker` on any map id in ``map_ids``."""

    def __init__(self, map_ids: set[str] | None = None,
                 config: SonarConfig | None = None) -> None:
        self.map_ids = map_ids
        self.config = config or SonarConfig()
        self.created: list[OdometryTracker] = []

    def _check(self, map_id: str) -> None:
        if self.map_ids is not None and map_id not in self.map_ids:
            raise InvalidSpec("map_id", f"map_id {map_id!r} unknown")

    def create(self, map_id: str, spec: FilterSpec) -> OdometryTracker:
        self._check(map_id)
        t = OdometryTracker(spec, self.config)
        self.created.append(t)
        return t

    def restore(self, map_id: str, spec: FilterSpec, state: dict[str, Any]) -> OdometryTracker:
        t = self.create(map_id, spec)
        t.load_state_dict(state)
        return t
