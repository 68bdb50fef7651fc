"""A symmetric room and the echo model: the prior decides between twins, the data cannot.

A 4 m x 3 m rectangle looks the same from a pose and from its images under the room's
symmetries (two mirrors and the half turn). From a tracked start the motion since the start
rules the images out, so the filter must stay on its side and say ``converged``; from a
global start nothing does, so it must report the images as modes and never say
``converged`` (issue 14: not a coin flip). Blocks are the forward model's heat maps of the
true walls (:func:`mapping.forward.predicted_heatmap`), scored on the ideal map.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from localization.estimate import PoseEstimate
from localization.particle_filter import FilterConfig, ParticleFilter, jumped, propose
from localization.sensor import SensorConfig, SensorTables, build_tables, prepare_measurement
from mapping.angles import wrap_angle
from mapping.forward import WallSet, predicted_heatmap
from mapping.signal import SonarConfig
from mapping.wallmap import wallmap_from_walls
from tests.localization.helpers import trajectory

FloatArray = NDArray[np.float64]
DT = 1.023
SONAR = SonarConfig()
ROOM = np.array([[0.0, 0.0, 4.0, 0.0], [4.0, 0.0, 4.0, 3.0],
                 [4.0, 3.0, 0.0, 3.0], [0.0, 3.0, 0.0, 0.0]])
START = np.array([0.6, 0.8, 0.44])
ODO = [(0.12, 0.0)] * 18 + [(0.12, 0.25)] * 4
TIGHT = np.diag([0.03**2, 0.03**2, math.radians(3.0) ** 2])


@pytest.fixture(scope="module")
def tables() -> SensorTables:
    return build_tables(wallmap_from_walls(ROOM), SensorConfig(model="echo"))


@pytest.fixture(scope="module")
def run() -> tuple[FloatArray, list]:
    truth = trajectory(START, ODO, DT)
    walls = WallSet.from_array(ROOM)
    return truth, [predicted_heatmap(walls, p, 0.12, SONAR) for p in truth]


def _images(p: FloatArray) -> FloatArray:
    """The pose and its images under the rectangle's symmetries."""
    x, y, h = p
    return np.array([[x, y, h], [4 - x, y, wrap_angle(math.pi - h)],
                     [x, 3 - y, wrap_angle(-h)], [4 - x, 3 - y, wrap_angle(h + math.pi)]])


def _err(a: FloatArray, b: FloatArray) -> tuple[float, float]:
    return (float(np.hypot(*(a[:2] - b[:2]))),
            math.degrees(abs(float(wrap_angle(a[2] - b[2])))))


def _drive(pf: ParticleFilter, run: tuple[FloatArray, list]) -> list[PoseEstimate]:
    truth, hms = run
    out = []
    for k, hm in enumerate(hms):
        v, w = ODO[k - 1] if k else (ODO[0][0], 0.0)
        out.append(pf.step(hm, v, w, DT if k else 0.0))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_tracked_start_stays_on_its_side_of_the_symmetry(
        tables: SensorTables, run: tuple[FloatArray, list], seed: int) -> None:
    """Before the anchor (``ParticleFilter.anchored``) the twins injected for the status
    made the heaviest mode alternate with the mirror image (benchmark: 91-199 cm RMSE on
    the shoebox, corridor, L-room and pillar straight runs from a tracked start)."""
    pf = ParticleFilter(tables, FilterConfig(n_particles=1000), np.random.default_rng(seed),
                        pose=run[0][0], cov=TIGHT)
    ests = _drive(pf, run)
    errs = [_err(e.pose, t) for e, t in zip(ests, run[0], strict=True)]
    assert max(e[0] for e in errs) < 0.05 and max(e[1] for e in errs) < 5.0
    assert sum(e.status == "converged" for e in ests) >= 0.8 * len(ests)
    assert pf.anchored


@pytest.mark.parametrize("seed", [0, 1])
def test_a_global_start_reports_the_images_and_is_never_converged(
        tables: SensorTables, run: tuple[FloatArray, list], seed: int) -> None:
    pf = ParticleFilter(tables, FilterConfig(n_particles=2000), np.random.default_rng(seed))
    ests = _drive(pf, run)
    assert not pf.anchored
    assert all(e.status != "converged" for e in ests)
    last, images = ests[-1], _images(run[0][-1])
    # the estimate is one of the images, and another image is among the reported modes
    assert min(_err(last.pose, im)[0] for im in images) < 0.1
    near = {int(np.argmin([_err(m.mean, im)[0] for im in images])) for m in last.modes
            if min(_err(m.mean, im)[0] for im in images) < 0.1}
    assert len(near) >= 2


def test_jumped_compares_the_estimate_with_dead_reckoning() -> None:
    prev = np.array([1.0, 1.0, 0.0])
    assert not jumped(None, prev, 0.2, 0.0, 1.0, 0.5, math.radians(30))
    assert not jumped(prev, np.array([1.2, 1.0, 0.0]), 0.2, 0.0, 1.0, 0.5, math.radians(30))
    assert jumped(prev, np.array([1.2, 1.0, math.pi]), 0.2, 0.0, 1.0, 0.5, math.radians(30))
    assert jumped(prev, np.array([2.0, 1.0, 0.0]), 0.2, 0.0, 1.0, 0.5, math.radians(30))


def test_gated_proposals_stay_near_the_estimate(tables: SensorTables,
                                                run: tuple[FloatArray, list]) -> None:
    truth, hms = run
    meas = prepare_measurement(hms[10], tables.config)
    rng = np.random.default_rng(4)
    poses = np.tile(truth[10], (400, 1))
    gate = (truth[10], 0.5, math.radians(30))
    out = propose(poses, 200, tables, meas, 4, rng, gate)
    moved = np.any(out != poses, axis=1)
    assert moved.sum() > 0
    d = np.hypot(*(out[:, :2] - truth[10, :2]).T)
    h = np.abs(wrap_angle(out[:, 2] - truth[10, 2]))
    assert np.all(d <= 0.5) and np.all(h <= math.radians(30))
    # far from every wall echo there is nothing to propose: the particles stay as they were
    far = (np.array([50.0, 50.0, 0.0]), 0.1, 0.1)
    np.testing.assert_array_equal(propose(poses, 200, tables, meas, 4, rng, far), poses)
