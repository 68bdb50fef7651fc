"""The paper's two mapping claims (Sec. 5) as orderings on short image-source runs.

* Fig. 6: path B (a large curve) leaves less ghost energy than path A (straight at pi/4);
* Fig. 7: ghost energy falls as the number of repetitions M grows.

Short stretches of the paper's paths keep the simulation small: 10 blocks of path A around
point (a) and 10 blocks of path B's tightest turn; M = 4 vs 10 over the same stretch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from mapping.build import BuildParams, RunSource, build_map
from mapping.grid import GridParams
from mapping.path import builtin_path
from mapping.quality import evaluate
from mapping.scene import builtin_scene
from mapping.signal import SonarConfig
from mapping.simulate import simulate_run
from mapping.simulate.ism import IsmConfig


@dataclass(frozen=True)
class Shifted:
    """A trajectory started ``t0_s`` seconds in (TrajectoryLike)."""

    base: Any
    t0_s: float

    @property
    def name(self) -> str:
        return f"{self.base.name}+{self.t0_s:g}s"

    @property
    def duration_s(self) -> float:
        return float(self.base.duration_s - self.t0_s)

    def position(self, t_s: Any) -> Any:
        return self.base.position(np.asarray(t_s) + self.t0_s)

    def velocity(self, t_s: Any) -> Any:
        return self.base.velocity(np.asarray(t_s) + self.t0_s)

    def pose(self, t_s: Any) -> Any:
        return self.base.pose(np.asarray(t_s) + self.t0_s)

    def speed_m_s(self, t_s: Any) -> Any:
        return self.base.speed_m_s(np.asarray(t_s) + self.t0_s)

    def yaw_rate_rad_s(self, t_s: Any) -> Any:
        return self.base.yaw_rate_rad_s(np.asarray(t_s) + self.t0_s)


def _ghost(path: str, t0_s: float, seconds: float, repetitions: int) -> float:
    config = SonarConfig(repetitions=repetitions)
    scene = builtin_scene("paper")
    n = int(round(seconds / config.block_s))
    run = simulate_run(scene, Shifted(builtin_path(path), t0_s), config, n,
                       IsmConfig(order=2), np.random.default_rng(0))
    wm = build_map([RunSource.from_run(run)], BuildParams(grid=GridParams(radius_m=4.0)))
    return evaluate(wm, scene.segments()).ghost_energy


@pytest.fixture(scope="module")
def ghosts() -> dict[str, float]:
    return {
        "A10": _ghost("paper-a", 9.0, 10.3, 10),
        "B10": _ghost("paper-b", 36.0, 10.3, 10),
        "B4": _ghost("paper-b", 36.0, 10.3, 4),
    }


@pytest.mark.slow
def test_curved_path_b_has_less_ghost_energy_than_straight_path_a(ghosts: dict) -> None:
    assert ghosts["B10"] < ghosts["A10"]


@pytest.mark.slow
def test_ghost_energy_falls_as_m_grows(ghosts: dict) -> None:
    assert ghosts["B10"] < ghosts["B4"]
