"""Never confidently wrong behind a face (issue 14): the held-out stack room (fresh14o,
``scenes/stacks.json``), mapped from its curve through the west end and the south aisle,
localized straight down the middle aisle (``stacks-line``) as the localization benchmark does
(image sources up to order 3, SNR 10 dB, odometry noise, 2000 particles, tracked start).

The built map holds stack A's south face (heard from the south aisle) but not its north face
0.4 m behind it. Read as a two-sided wall, that face explains the echo of the unmapped north
face from a pose 40 cm south of the truth, and the filter once reported ``converged`` there
(6 blocks in the benchmark). The wall fit records that the face was heard from the south only
(``WallMap.wall_side``), and the echo model predicts nothing from its back."""

from __future__ import annotations

import dataclasses
import zlib

import numpy as np
import pytest

from localization.estimate import default_start_cov
from localization.particle_filter import FilterConfig, ParticleFilter, block_odometry
from localization.sensor import SensorConfig, build_tables
from mapping.angles import wrap_angle
from mapping.build import BuildParams, RunSource, build_map
from mapping.heatmap import heatmap_of_run
from mapping.signal import SonarConfig
from mapping.simulate import simulate_run
from mapping.simulate.ism import IsmConfig

CONFIG = SonarConfig()


def _run(path: str, speed_m_s: float, snr_db: float | None):  # type: ignore[no-untyped-def]
    from benchmarks._heldout import heldout_path, heldout_scene

    traj = heldout_path(path).trajectory(speed_m_s)
    seed = zlib.crc32(f"{path}@{speed_m_s:g}".encode())
    n = int(traj.duration_s / CONFIG.block_s)
    return simulate_run(heldout_scene("stacks"), traj, CONFIG, n,
                        IsmConfig(max_order=3, max_path_m=12.0, snr_db=snr_db),
                        np.random.default_rng(seed), seed=seed)


@pytest.fixture(scope="module")
def stacks():  # type: ignore[no-untyped-def]
    wm = build_map([RunSource.from_run(_run("stacks-curve", 0.1, None), "stacks-curve")],
                   BuildParams(method="walls"))
    run = _run("stacks-line", 0.125, 10.0)
    rng = np.random.default_rng(zlib.crc32(b"odometry:stacks-line"))
    run = dataclasses.replace(
        run, speed_m_s=run.speed_m_s + rng.normal(0.0, 0.005, run.n_blocks),
        yaw_rate_rad_s=run.yaw_rate_rad_s + rng.normal(0.0, 0.005, run.n_blocks))
    return wm, run


def _wrong_converged(tables, run) -> tuple[int, float]:  # type: ignore[no-untyped-def]
    """Blocks reported converged while > 30 cm or > 15 deg off, and the largest error (m)."""
    v, w, dt = block_odometry(run.speed_m_s, run.yaw_rate_rad_s, run.t_s, CONFIG.block_s)
    pf = ParticleFilter(tables, FilterConfig(n_particles=2000), np.random.default_rng(0),
                        pose=run.pose[0], cov=default_start_cov())
    wrong, worst = 0, 0.0
    for k in range(run.n_blocks):
        est = pf.step(heatmap_of_run(run, k), float(v[k]), float(w[k]), float(dt[k]))
        err = float(np.hypot(*(est.pose[:2] - run.pose[k, :2])))
        head = abs(float(wrap_angle(est.pose[2] - run.pose[k, 2])))
        worst = max(worst, err)
        wrong += est.status == "converged" and (err > 0.3 or head > np.radians(15))
    return wrong, worst


def test_the_stack_face_is_heard_from_the_south_aisle_only(stacks) -> None:  # type: ignore[no-untyped-def]
    """Ground truth: stack A spans x 2.6-6.6, y 2.0-2.4; the curve never enters the middle
    aisle. The map's wall on y = 2.0 is one-sided, heard from the south (y < 2); every
    fitted wall is one-sided (the curve saw each from one side only)."""
    wm, _ = stacks
    seg = wm.walls_m.reshape(-1, 2, 2)
    face = [i for i, s in enumerate(seg)
            if np.all(np.abs(s[:, 1] - 2.0) < 0.05) and np.min(s[:, 0]) < 4.0 < np.max(s[:, 0])]
    assert face, wm.walls_m
    for i in face:
        d = seg[i, 1] - seg[i, 0]
        south_side = np.sign(d[0] * (1.0 - seg[i, 0, 1]) - d[1] * (4.0 - seg[i, 0, 0]))
        assert wm.wall_side[i] == south_side
    assert np.all(wm.wall_side != 0)


def test_no_block_converged_while_wrong_down_the_middle_aisle(stacks) -> None:  # type: ignore[no-untyped-def]
    """With faces no block is ``converged`` while > 30 cm / 15 deg off; the control (the
    same map read two-sided) shows the failure this guards against."""
    wm, run = stacks
    tables = build_tables(wm, SensorConfig(model="echo"), sonar=CONFIG)
    assert tables.wall_side is not None
    wrong, _ = _wrong_converged(tables, run)
    assert wrong == 0
    control, worst = _wrong_converged(dataclasses.replace(tables, wall_side=None), run)
    assert control > 0 and worst > 0.3
