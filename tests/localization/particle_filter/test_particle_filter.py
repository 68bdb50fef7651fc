"""Tests of the particle filter: functions vs object, accuracy, failure modes, checkpoints.

Inputs are independent of the simulation pipeline: a rasterized wall map and heat maps
synthesized from the same wall segments by geometry (tests/_localization_helpers.py).
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from localization.estimate import PoseEstimate
from localization.particle_filter import (
    FilterConfig,
    ParticleFilter,
    init_tracked,
    predict,
    resample,
    temper_to_ess,
    weigh,
)
from localization.resampling import effective_sample_size
from localization.sensor import SensorConfig, SensorTables, build_tables, prepare_measurement
from mapping.angles import circular_std, pose_error, wrap_angle
from mapping.heatmap import HeatMap
from tests.localization.helpers import (
    ASYMMETRIC_ROOM,
    CORRIDOR,
    odometry_step,
    rasterize,
    synthetic_heatmap,
    synthetic_track,
    trajectory,
)

DT = 1.023
#: Curved path inside ASYMMETRIC_ROOM: straight, left arc, straight, left arc, straight.
ODO = [(0.2, 0.0)] * 4 + [(0.2, 0.35)] * 5 + [(0.2, 0.0)] * 2 + [(0.2, 0.3)] * 6 + \
    [(0.2, 0.0)] * 5
START = np.array([0.8, 0.6, 0.0])
TIGHT = np.diag([0.05**2, 0.05**2, math.radians(5) ** 2])
#: Symmetric about y = 1.5 (an isosceles trapezoid): mirror images about the travel axis.
MIRROR_ROOM = np.array([
    [[0.0, 0.0], [5.0, 0.4]], [[5.0, 0.4], [5.0, 2.6]], [[5.0, 2.6], [0.0, 3.0]],
    [[0.0, 3.0], [0.0, 0.0]],
])


@pytest.fixture(scope="module")
def run() -> tuple[np.ndarray, list[HeatMap]]:
    return synthetic_track(ASYMMETRIC_ROOM, START, ODO, DT, seed=11)


def _odometry(k: int) -> tuple[float, float, float]:
    return odometry_step(ODO, DT, k)


def _state_bytes(pf: ParticleFilter) -> dict[str, bytes]:
    return {k: v.tobytes() for k, v in pf.state_dict().items()}


def test_object_and_functions_agree(tables: SensorTables,
                                    run: tuple[np.ndarray, list[HeatMap]]) -> None:
    truth, hms = run
    cfg = FilterConfig(n_particles=400, augmented=False)
    pf = ParticleFilter(tables, cfg, np.random.default_rng(5), pose=truth[0], cov=TIGHT)
    rng = np.random.default_rng(5)
    poses = init_tracked(truth[0], TIGHT, 400, rng)
    log_w = np.full(400, -math.log(400))
    resampled = 0
    for k in range(6):
        v, w, dt = _odometry(k)
        pf.step(hms[k], v, w, dt)
        poses = predict(poses, v, w, dt, cfg.motion, rng)
        log_w, _, _ = weigh(log_w, poses, tables, prepare_measurement(hms[k], tables.config),
                            cfg.min_ess_fraction)
        if effective_sample_size(log_w) < 0.5 * 400:
            poses, log_w = resample(poses, log_w, rng)
            resampled += 1
        np.testing.assert_array_equal(pf.poses, poses)
        np.testing.assert_array_equal(pf.log_w, log_w)
    assert resampled > 0


def test_tracking_accuracy(tables: SensorTables, run: tuple[np.ndarray, list[HeatMap]]) -> None:
    """Tracked start: position RMSE <= 3 cm and heading RMSE <= 3 deg over the run."""
    truth, hms = run
    pf = ParticleFilter(tables, FilterConfig(n_particles=1000), np.random.default_rng(1),
                        pose=truth[0], cov=TIGHT)
    errs = np.array([pose_error(pf.step(hms[k], *_odometry(k)).pose, truth[k])
                     for k in range(len(truth))])
    assert math.sqrt(np.mean(errs[:, 0] ** 2)) <= 0.03
    assert math.degrees(math.sqrt(np.mean(errs[:, 1] ** 2))) <= 3.0


def test_global_localization_converges(tables: SensorTables,
                                       run: tuple[np.ndarray, list[HeatMap]]) -> None:
    """From a uniform start in the asymmetric room: within 5 cm / 5 deg by block 12 (of 23)
    and staying there; ``converged`` in at least half of those blocks."""
    truth, hms = run
    pf = ParticleFilter(tables, FilterConfig(n_particles=1500), np.random.default_rng(2))
    ests = [pf.step(hms[k], *_odometry(k)) for k in range(len(truth))]
    for k in range(12, len(truth)):
        e_pos, e_head = pose_error(ests[k].pose, truth[k])
        assert e_pos <= 0.05 and e_head <= math.radians(5), k
    # augmented-MCL injections (on by default) pull the best mode's weight below the 0.9
    # of ``converged`` now and then while tracking; most blocks still report converged
    assert sum(e.converged for e in ests[12:]) >= 0.5 * len(ests[12:])


def test_state_dict_round_trip(tables: SensorTables,
                               run: tuple[np.ndarray, list[HeatMap]]) -> None:
    """Checkpoint through np.savez (no pickle) and continue: identical to never stopping."""
    truth, hms = run
    pf = ParticleFilter(tables, FilterConfig(n_particles=300), np.random.default_rng(3))
    for k in range(3):
        pf.step(hms[k], *_odometry(k))
    buf = io.BytesIO()
    np.savez(buf, **pf.state_dict())  # type: ignore[arg-type]
    buf.seek(0)
    with np.load(buf, allow_pickle=False) as npz:
        clone = ParticleFilter.from_state_dict({k: npz[k] for k in npz.files}, tables)
    for k in range(3, 6):
        a, b = pf.step(hms[k], *_odometry(k)), clone.step(hms[k], *_odometry(k))
        np.testing.assert_array_equal(a.pose, b.pose)
    assert _state_bytes(pf) == _state_bytes(clone)
    with pytest.raises(ValueError, match="format"):
        ParticleFilter.from_state_dict({"format": np.array("nope")}, tables)


def _bad(hm: HeatMap, kind: str) -> HeatMap:
    if kind == "nan":
        H = hm.H.copy()
        H[3, 100] = np.nan
        return dataclasses.replace(hm, H=H)
    if kind == "zeros":
        return dataclasses.replace(hm, H=np.zeros_like(hm.H))
    if kind == "wrong_length":
        return dataclasses.replace(hm, H=hm.H[:, :-7])
    return dataclasses.replace(hm, angles_rad=hm.angles_rad[::-1].copy())


@pytest.mark.parametrize("kind", ["nan", "zeros", "wrong_length", "bad_axis", "odometry"])
def test_bad_block_rejected_state_unchanged(tables: SensorTables,
                                            run: tuple[np.ndarray, list[HeatMap]],
                                            kind: str) -> None:
    truth, hms = run
    pf = ParticleFilter(tables, FilterConfig(n_particles=200), np.random.default_rng(4),
                        pose=truth[0], cov=TIGHT)
    pf.step(hms[0], *_odometry(0))
    before = _state_bytes(pf)
    with pytest.raises(ValueError):
        if kind == "odometry":
            pf.step(hms[1], math.nan, 0.0, DT)
        else:
            pf.step(_bad(hms[1], kind), *_odometry(1))
    assert _state_bytes(pf) == before
    pf.step(hms[1], *_odometry(1))   # and it still works


def test_silent_block_predicts_only(tables: SensorTables,
                                    run: tuple[np.ndarray, list[HeatMap]]) -> None:
    truth, _ = run
    pf = ParticleFilter(tables, FilterConfig(n_particles=200), np.random.default_rng(6),
                        pose=truth[0], cov=TIGHT)
    log_w, mean_x = pf.log_w.copy(), pf.poses[:, 0].mean()
    est = pf.step(None, 0.2, 0.0, DT)
    assert not est.updated and est.model == "none"
    np.testing.assert_array_equal(pf.log_w, log_w)
    assert pf.poses[:, 0].mean() - mean_x == pytest.approx(0.2 * DT, abs=0.01)


def test_stationary_robot_never_invents_a_bearing(tables: SensorTables) -> None:
    """10 blocks at speed 0: the heading spread does not shrink (>= 90 % of the start)."""
    truth = np.array([1.5, 1.2, 0.7])
    cov = np.diag([0.05**2, 0.05**2, math.radians(40) ** 2])
    pf = ParticleFilter(tables, FilterConfig(n_particles=1000), np.random.default_rng(7),
                        pose=truth, cov=cov)
    start = circular_std(pf.poses[:, 2], np.exp(pf.log_w))
    rng = np.random.default_rng(8)
    for _ in range(10):
        est = pf.step(synthetic_heatmap(ASYMMETRIC_ROOM, truth, 0.0, rng), 0.0, 0.0, DT)
        assert not est.direction_observable and est.model == "range"
    assert circular_std(pf.poses[:, 2], np.exp(pf.log_w)) >= 0.9 * start
    assert pose_error(est.pose, truth)[0] <= 0.1


def test_straight_path_keeps_mirror_modes_until_turn() -> None:
    """Room symmetric about y = 1.5; driving straight along +x at y = 1.9 the mirror pose
    at y = 1.1 explains every block equally: once the prior's middle has died out (block 4)
    both modes hold 0.3-0.7 of the weight up to the turn (block 8). After the robot turns,
    one mode (the truth) holds >= 0.9 within 6 blocks."""
    tables = build_tables(rasterize(MIRROR_ROOM), SensorConfig(max_range_m=4.5))
    odo = [(0.2, 0.0)] * 8 + [(0.2, 0.4)] * 6
    truth = trajectory(np.array([0.8, 1.9, 0.0]), odo, DT)
    rng = np.random.default_rng(9)
    pf = ParticleFilter(tables, FilterConfig(n_particles=5000, augmented=False),
                        np.random.default_rng(10), pose=np.array([0.8, 1.5, 0.0]),
                        cov=np.diag([0.05**2, 0.35**2, math.radians(4) ** 2]))
    ests = []
    for k in range(len(truth)):
        v, w = odo[k - 1] if k else (0.2, 0.0)
        ests.append(pf.step(synthetic_heatmap(MIRROR_ROOM, truth[k], 0.2, rng), v, w,
                            DT if k else 0.0))
    for est, pose in zip(ests[4:9], truth[4:9], strict=True):
        ys = sorted(m.mean[1] for m in est.modes[:2])
        assert ys == pytest.approx([3.0 - pose[1], pose[1]], abs=0.1)
        assert all(0.3 <= m.weight <= 0.7 for m in est.modes[:2])
    last = ests[-1]
    assert last.modes[0].weight >= 0.9
    assert pose_error(last.pose, truth[-1])[0] <= 0.1


def _corridor_run(beta: float, n: int, seed: int) -> tuple[np.ndarray, PoseEstimate]:
    tables = build_tables(rasterize(CORRIDOR), SensorConfig(max_range_m=4.5, beta=beta))
    odo = [(0.2, 0.0)] * 3 + [(0.2, 0.25)] * 4 + [(0.2, -0.25)] * 4
    truth = trajectory(np.array([1.2, 0.5, 0.0]), odo, DT)
    rng = np.random.default_rng(12)
    pf = ParticleFilter(tables, FilterConfig(n_particles=n), np.random.default_rng(seed))
    for k in range(len(truth)):
        v, w = odo[k - 1] if k else (0.2, 0.0)
        est = pf.step(synthetic_heatmap(CORRIDOR, truth[k], 0.2, rng), v, w, DT if k else 0.0)
    p = truth[-1]
    rot = float(wrap_angle(p[2] + np.pi))
    return np.array([p, [6.0 - p[0], 1.6 - p[1], rot], [p[0], 1.6 - p[1], -p[2]],
                     [6.0 - p[0], p[1], float(wrap_angle(-rot))]]), est


def test_symmetric_scene_reports_symmetric_modes() -> None:
    """Corridor (180 deg rotation symmetric), global start. With a tempered sensor
    (beta = 25) both rotation images are still reported as modes after 11 blocks, each
    holding >= 1 % of the weight (40 of 4000 particles), in at least 3 of 4 seeds, and the
    heaviest mode is within 10 cm of an image in all 4. Known limit: the PF's split between
    exactly symmetric modes is a random walk driven by resampling noise (measured over
    these seeds: 0.12-0.19 for the truth's image; seed 16 lost it), and at the default
    beta = 200 one image often dies (the grid filter holds 0.5/0.5, see test_grid_filter);
    the answer is then still right modulo the symmetry (within 15 cm / 10 deg of a rotation
    or mirror image: a nearly straight path in a corridor also keeps the mirror ambiguity
    about its centre line) in at least 3 of 4 seeds. Measured: seeds 13-15 within 2 cm /
    2.7 deg of an image; seed 16 ends 31 cm away in this feature-poor corridor (43 cm
    without the unconverged floor ``FilterConfig.z_rand_unconverged`` = 0.01, 16 cm with
    0.05: a sharper beta collapses a global start faster)."""
    both = 0
    for seed in (13, 14, 15, 16):
        images, est = _corridor_run(25.0, 4000, seed)
        weights = [max([m.weight for m in est.modes if pose_error(m.mean, im)[0] <= 0.1],
                       default=0.0) for im in images[:2]]
        both += min(weights) >= 0.01
        assert min(pose_error(est.pose, im)[0] for im in images) <= 0.1
    assert both >= 3
    right = 0
    for seed in (13, 14, 15, 16):
        images, est = _corridor_run(200.0, 2000, seed)
        right += (min(pose_error(est.pose, im)[0] for im in images) <= 0.15
                  and min(pose_error(est.pose, im)[1] for im in images) <= math.radians(10))
    assert right >= 3


@pytest.mark.parametrize("bias", [0.9, 1.1])
def test_odometry_speed_bias_does_not_diverge(tables: SensorTables,
                                              run: tuple[np.ndarray, list[HeatMap]],
                                              bias: float) -> None:
    """Speed off by +-10 %: stated degradation <= 6 cm RMSE (vs <= 3 cm), no divergence."""
    truth, hms = run
    pf = ParticleFilter(tables, FilterConfig(n_particles=1000), np.random.default_rng(14),
                        pose=truth[0], cov=TIGHT)
    errs = []
    for k in range(len(truth)):
        v, w, dt = _odometry(k)
        errs.append(pose_error(pf.step(hms[k], bias * v, w, dt).pose, truth[k])[0])
    assert math.sqrt(np.mean(np.square(errs))) <= 0.06
    assert errs[-1] <= 0.1


@pytest.mark.slow
def test_kidnapping_recovered(tables: SensorTables) -> None:
    """Teleport 2 m and -90 deg after 10 blocks: recovered (within 15 cm / 15 deg for the
    rest of the run) within 12 blocks in >= 18 of 20 seeds (typically 5-8 blocks)."""
    odo = [(0.2, 0.2 / 0.6)] * 26
    before = trajectory(np.array([1.2, 0.7, 0.0]), odo[:10], DT)
    p = before[-1]
    jump = np.array([p[0] + 1.9, p[1] - 0.62, float(wrap_angle(p[2] - np.pi / 2))])
    assert math.hypot(jump[0] - p[0], jump[1] - p[1]) == pytest.approx(2.0, abs=0.01)
    after = trajectory(jump, odo[10:], DT)
    truth = np.vstack([before, after[1:]])
    recovered = 0
    for seed in range(20):
        rng = np.random.default_rng(100 + seed)
        pf = ParticleFilter(tables, FilterConfig(n_particles=800), np.random.default_rng(seed),
                            pose=truth[0], cov=TIGHT)
        ok = []
        for k in range(len(truth)):
            v, w = odo[k - 1] if k else (0.2, 0.0)
            est = pf.step(synthetic_heatmap(ASYMMETRIC_ROOM, truth[k], 0.2, rng), v, w,
                          DT if k else 0.0)
            e_pos, e_head = pose_error(est.pose, truth[k])
            ok.append(e_pos <= 0.15 and e_head <= math.radians(15))
        first_bad_after = [k for k in range(10, len(truth)) if not ok[k]]
        if not first_bad_after or max(first_bad_after) < 10 + 12:
            recovered += 1
    assert recovered >= 18


def test_many_particles_sharp_beta_no_underflow(tables: SensorTables,
                                                run: tuple[np.ndarray, list[HeatMap]]) -> None:
    truth, hms = run
    sharp = dataclasses.replace(tables, config=dataclasses.replace(tables.config, beta=1e4))
    pf = ParticleFilter(sharp, FilterConfig(n_particles=100_000, global_oversample=1),
                        np.random.default_rng(15))
    for k in range(2):
        est = pf.step(hms[k], *_odometry(k))
        assert np.all(np.isfinite(pf.log_w))
        assert np.exp(pf.log_w).sum() == pytest.approx(1.0)
        assert est.ess >= 1.0 and np.all(np.isfinite(est.pose))


def test_kld_adapts_particle_count(tables: SensorTables,
                                   run: tuple[np.ndarray, list[HeatMap]]) -> None:
    truth, hms = run
    cfg = FilterConfig(n_particles=3000, kld=True, n_min=300, n_max=3000, augmented=False)
    pf = ParticleFilter(tables, cfg, np.random.default_rng(16), pose=truth[0], cov=TIGHT)
    counts = []
    for k in range(8):
        pf.step(hms[k], *_odometry(k))
        counts.append(pf.n_particles)
    assert min(counts) < 3000
    assert all(300 <= c <= 3000 for c in counts)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "issue 14: global start on the L-room. With the image-source engine's phantom echo from "
    "the reflex corner removed (issue 15 item 1, fixed with issue 13) the room is mirror "
    "symmetric to the sensor and the G-correlation filter never converges; the phantom echo "
    "had broken the symmetry"))
def test_end_to_end_on_simulated_runs(simulated: tuple[Any, Any]) -> None:
    """The real pipeline: image-source simulation (order 2) -> heat maps -> map G from a
    mapping run (L-room, curve, seed 0) -> localize a held-out run (same curve at 0.15 m/s,
    seed 1, odometry noise) from a global start. The L-room is mirror symmetric about its
    diagonal, and a mirror image is exactly what the sensor's left/right fold cannot see,
    so the mirror pose is as likely as the truth until the path turns (block ~14).
    Pass: within 10 cm / 10 deg by block 18 and staying there; RMSE after that <= 3 cm
    and <= 3 deg."""
    from localization.estimate import track_metrics
    from localization.particle_filter import run_filter
    from mapping.heatmap import heatmap_of_run

    wall_map, held = simulated
    tables = build_tables(wall_map, SensorConfig())
    pf = ParticleFilter(tables, FilterConfig(n_particles=3000), np.random.default_rng(2))
    ests = list(run_filter(pf, (heatmap_of_run(held, k) for k in range(held.n_blocks)),
                           held.speed_m_s, held.yaw_rate_rad_s, held.t_s,
                           held.config.block_s))
    m = track_metrics(np.array([e.pose for e in ests]), np.array([e.cov for e in ests]),
                      held.pose)
    assert m.blocks_to_converge is not None and m.blocks_to_converge <= 18
    assert m.position_rmse_m <= 0.03
    assert math.degrees(m.heading_rmse_rad) <= 3.0


# ---- honest covariance: tempering, the augmented-MCL statistic, the unconverged floor ------
@settings(max_examples=60, deadline=None)
@given(n=st.integers(2, 400), seed=st.integers(0, 2**31 - 1),
       sharp=st.floats(0.1, 500.0), frac=st.floats(0.01, 0.9))
def test_temper_to_ess_keeps_the_ess_floor(n: int, seed: int, sharp: float,
                                           frac: float) -> None:
    """``temper_to_ess`` returns 1 when the full update keeps the ESS floor; otherwise a
    scale in (0, 1) whose tempered update keeps it and is the largest that does (the ESS at
    a slightly larger scale falls below the floor)."""
    rng = np.random.default_rng(seed)
    log_w = rng.normal(0.0, 1.0, n)
    log_w -= np.logaddexp.reduce(log_w)
    ll = -sharp * rng.random(n)
    min_ess = frac * n

    def ess(s: float) -> float:
        a = log_w + s * ll
        return float(1.0 / np.sum(np.exp(2 * (a - np.logaddexp.reduce(a)))))

    s = temper_to_ess(log_w, ll, min_ess)
    assert 0 < s <= 1
    if ess(1.0) >= min_ess:
        assert s == 1.0
    elif ess(0.0) >= min_ess:
        assert ess(s) >= min_ess * (1 - 1e-9)
        assert ess(min(1.0, s + 1e-6)) <= min_ess * (1 + 1e-3)


def test_augmented_mcl_statistic_is_the_mean_log_likelihood(
        tables: SensorTables, run: tuple[np.ndarray, list[HeatMap]]) -> None:
    """``weigh``'s statistic is the prior-weighted mean of ``beta (rho - 1)`` (checked
    against ``score_poses`` directly), and a robot that keeps hearing the same block
    (standing still, so every block is the same measurement) never triggers injection:
    resampling only concentrates the set, so the short-term average stays at or above the
    long-term one. With Thrun's arithmetic
    mean of ``exp(beta (rho - 1))`` an average of values swinging by 10-25 nats is pinned
    to its largest term, and on the benchmark runs the short-term average fell 0.65 nats
    per block below the long-term one and injected poses mid-track."""
    import localization.particle_filter as pfm
    from localization.sensor import score_poses

    truth, hms = run
    rng = np.random.default_rng(2)
    poses = init_tracked(truth[3], TIGHT, 500, rng)
    log_w = np.log(rng.dirichlet(np.ones(500)))
    meas = prepare_measurement(hms[3], tables.config)
    _, stat, _ = weigh(log_w, poses, tables, meas)
    rho = score_poses(tables, meas, poses)
    ok = np.isfinite(rho)
    w = np.exp(log_w[ok]) / np.exp(log_w[ok]).sum()
    assert stat == pytest.approx(tables.config.beta * float(np.sum(w * (rho[ok] - 1))))

    injected = []
    original = pfm.inject

    def spy(poses: np.ndarray, n_inject: int, *args: Any, **kwargs: Any) -> np.ndarray:
        injected.append(n_inject)
        return original(poses, n_inject, *args, **kwargs)

    pfm.inject = spy
    try:
        pf = ParticleFilter(tables, FilterConfig(n_particles=1000, resample_ess_fraction=1.0),
                            np.random.default_rng(3), pose=truth[3], cov=TIGHT)
        for _ in range(15):
            pf.step(hms[3], 0.0, 0.0, DT)
    finally:
        pfm.inject = original
    assert sum(injected) == 0
    assert pf.log_w_fast >= pf.log_w_slow   # the set only concentrates on the better poses


def test_unconverged_floor_follows_convergence(tables: SensorTables,
                                               run: tuple[np.ndarray, list[HeatMap]]) -> None:
    """A global start is unconverged (the ``z_rand_unconverged`` floor applies) until one
    compact mode holds the weight; a tight tracked start is converged at once; the flag is
    part of the checkpoint; a config written before the threshold moved to correlation
    units still loads."""
    truth, hms = run
    pf = ParticleFilter(tables, FilterConfig(n_particles=3000), np.random.default_rng(4))
    assert not pf.converged
    flags = []
    for k in range(len(truth)):
        flags.append(pf.step(hms[k], *_odometry(k)).converged)
        assert pf.converged == flags[-1]
    assert not flags[0] and flags[-1]
    clone = ParticleFilter.from_state_dict(pf.state_dict(), tables)
    assert clone.converged and _state_bytes(clone) == _state_bytes(pf)
    assert ParticleFilter(tables, FilterConfig(n_particles=10), np.random.default_rng(0),
                          pose=truth[0], cov=TIGHT).converged
    assert not ParticleFilter(tables, FilterConfig(n_particles=10), np.random.default_rng(0),
                              pose=truth[0], cov=np.diag([1.0, 1.0, 1.0])).converged
    legacy = json.loads(FilterConfig().to_json())
    legacy["inject_threshold_nats"] = 1.0
    assert FilterConfig.from_json(json.dumps(legacy)) == FilterConfig()
    with pytest.raises(ValueError, match="z_rand_unconverged"):
        FilterConfig(z_rand_unconverged=1.5)
    with pytest.raises(ValueError, match="min_ess_fraction"):
        FilterConfig(min_ess_fraction=1.0)
    with pytest.raises(ValueError, match="inject_threshold_rho"):
        FilterConfig(inject_threshold_rho=-0.1)


def test_noisy_blocks_widen_the_estimate_and_do_not_derail_it(
        tables: SensorTables, run: tuple[np.ndarray, list[HeatMap]]) -> None:
    """Three blocks of pure noise mid-run (heat maps of |N(0, 1)|: no echo at all), 5 seeds:
    the filter never leaves 5 cm of the truth, and says it knows less: the reported position
    spread after the noisy stretch is >= 1.5x the one before it (only odometry moved the
    set), and it tightens again once echoes return. (Measured: within 2 cm throughout;
    spread 1.5 cm before, 4.5-4.7 cm after the three blocks, 1.4-1.7 cm three blocks later.)"""
    truth, hms = run
    for seed in range(5):
        rng = np.random.default_rng(100 + seed)
        pf = ParticleFilter(tables, FilterConfig(n_particles=1000), np.random.default_rng(seed),
                            pose=truth[0], cov=TIGHT)
        spread = []
        for k in range(len(truth)):
            hm = hms[k]
            if 8 <= k < 11:
                hm = dataclasses.replace(hm, H=np.abs(rng.standard_normal(hm.H.shape)))
            est = pf.step(hm, *_odometry(k))
            assert pose_error(est.pose, truth[k])[0] <= 0.05, (seed, k)
            spread.append(math.sqrt(est.cov[0, 0] + est.cov[1, 1]))
        assert spread[10] >= 1.5 * spread[7], (seed, spread[7], spread[10])
        assert spread[13] <= 0.75 * spread[10], (seed, spread[10], spread[13])
