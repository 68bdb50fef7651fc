"""Image-source engine: analytic echo, Doppler from the waveform, statics, continuity, 2-D."""

from __future__ import annotations

import json
import math
from typing import Any, cast

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import hankel2

from mapping import synthetic
from mapping.path import builtin_path, polyline_path, stationary_path
from mapping.scene import Scene, builtin_scene
from mapping.signal import SonarConfig, transmitted_at, tx_period
from mapping.simulate import TrajectoryLike, iter_blocks, simulate_run
from mapping.simulate.ism import (
    IsmConfig,
    iter_ism_blocks,
    path_table,
    plan_stretch,
    prepare_scene,
    render_stretch,
    retarded_delay_scalar,
    simulate_stretch,
)
from tests.mapping.simulate.ism.naive import delay_at_samples, render_numpy, render_reference

CFG1 = SonarConfig(repetitions=1)  # B = P = 4092: fast tests
CFG2 = SonarConfig(repetitions=2)
C = 340.0


def _scene(segments: list, reflection: list[float] | None = None, name: str = "test") -> Scene:
    walls = []
    for i, (a, b) in enumerate(segments):
        wall: dict[str, object] = {"name": f"w{i}", "start": list(a), "end": list(b)}
        if reflection is not None:
            wall["reflection"] = reflection[i]
        walls.append(wall)
    return Scene.from_json(json.dumps({"name": name, "walls": walls}))


def _line(start: tuple[float, float], heading: float, speed: float, length: float = 40.0):
    end = (start[0] + length * math.cos(heading), start[1] + length * math.sin(heading))
    return polyline_path([start, end], speed_m_s=speed, name="line")


def _fine_delay(
    window: np.ndarray, start: int, config: SonarConfig, up: int = 32
) -> tuple[np.ndarray, np.ndarray]:
    """Envelope of the circular cross-correlation of one received period against the
    transmitted period, upsampled ``up`` times; returns (lags in samples, envelope).

    The envelope (not the carrier-rate correlation) is used because the delay drifts by a
    few samples within a window when moving, which smears the carrier phase."""
    p = config.period_samples
    s = tx_period(config)
    s_rot = np.roll(s, -(start % p))  # transmitted samples aligned with the window start
    spec = np.fft.rfft(window) * np.conj(np.fft.rfft(s_rot))
    analytic = np.zeros(p * up, dtype=complex)
    analytic[: spec.size] = 2 * spec
    analytic[0] = spec[0]
    xc = np.abs(np.fft.ifft(analytic)) * up
    return np.arange(p * up) / up, xc


def _measured_delay(
    signal: np.ndarray, start: int, config: SonarConfig, around_s: float, half_s: float = 2e-4
) -> float:
    """Delay (s) of the strongest correlation peak within +-half_s of around_s."""
    lags, xc = _fine_delay(signal[start : start + config.period_samples], start, config)
    lag_s = lags / config.fs_hz
    sel = np.abs(lag_s - around_s) < half_s
    i = np.flatnonzero(sel)[np.argmax(np.abs(xc[sel]))]
    # parabolic refinement on the fine grid
    y0, y1, y2 = xc[i - 1], xc[i], xc[i + 1]
    frac = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
    return float((lags[i] + frac / 32) / config.fs_hz)


# ---- agreement with the analytic single-wall echo ----------------------------------------
@pytest.mark.parametrize("normal_angle", [0.3, 1.2, 2.5])
def test_single_wall_matches_analytic_echo(normal_angle):
    speed, heading, distance = 0.5, 0.4, 2.0
    motion = synthetic.Motion(speed, heading, t_ref_s=0.0)
    wall = synthetic.Wall(distance, normal_angle)
    phi = heading + normal_angle
    n = np.array([math.cos(phi), math.sin(phi)])
    tangent = np.array([-n[1], n[0]])
    seg = [tuple(distance * n - 300 * tangent), tuple(distance * n + 300 * tangent)]
    traj = _line((0.0, 0.0), heading, speed)
    engine = IsmConfig(order=1)
    got = simulate_stretch(_scene([seg]), traj, CFG2, 0, CFG2.block_samples, engine)
    t = np.arange(CFG2.block_samples) / CFG2.fs_hz
    want = synthetic.echo_samples(t, CFG2, motion, wall)
    corr = np.dot(got, want) / np.linalg.norm(got) / np.linalg.norm(want)
    assert corr >= 0.999
    assert np.max(np.abs(got - want)) < 1e-5 * np.max(np.abs(want))


# ---- Doppler measured from the waveform ------------------------------------------------------
def test_first_order_time_compression_from_the_waveform():
    speed, theta = 0.1, math.radians(60)  # angle between velocity and the wall normal
    u = speed * math.cos(theta)
    traj = _line((0.0, 0.0), math.pi / 2 - theta, speed)  # wall y = 3, normal +y
    scene = _scene([((-300.0, 3.0), (300.0, 3.0))])
    cfg = CFG1
    n = int(4.0 * cfg.fs_hz)
    x = simulate_stretch(scene, traj, cfg, 0, n, IsmConfig(order=1))
    p = cfg.period_samples
    starts = [0, n - p]
    delays = []
    for s0 in starts:
        t_mid = (s0 + p / 2) / cfg.fs_hz
        y = 3.0 - u * t_mid
        delays.append(_measured_delay(x, s0, cfg, 2 * y / C, half_s=5e-4))
    dt = (starts[1] - starts[0]) / cfg.fs_hz
    factor = 1.0 - (delays[1] - delays[0]) / dt
    expected = (C + u) / (C - u)
    assert abs((factor - 1) - (expected - 1)) < 0.01 * (expected - 1)


def _corner_delay(traj, t: float, corner: np.ndarray) -> float:
    """Retarded delay of the corner (point-reflected) image: |x(t) + x(t - tau) - 2c| = c tau,
    by fixed-point iteration (independent of the engine)."""
    x = traj.position(np.array([t]))[0]
    tau = 2 * np.linalg.norm(x - corner) / C
    for _ in range(50):
        tau = np.linalg.norm(x + traj.position(np.array([t - tau]))[0] - 2 * corner) / C
    return float(tau)


def test_second_order_corner_echo_matches_its_geometry():
    corner = np.array([4.5, 4.0])
    scene = _scene([((-3.0, 4.0), (4.5, 4.0)), ((4.5, 4.0), (4.5, -3.0))])
    speed = 0.1
    traj = _line((1.5, 2.0), 0.2, speed)
    cfg = CFG1
    n = int(4.0 * cfg.fs_hz)
    x = simulate_stretch(scene, traj, cfg, 0, n, IsmConfig(order=2))
    p = cfg.period_samples
    starts = np.linspace(0, n - p, 4).astype(int)
    measured, predicted = [], []
    for s0 in starts:
        t_mid = (s0 + p / 2) / cfg.fs_hz
        predicted.append(_corner_delay(traj, t_mid, corner))
        measured.append(_measured_delay(x, s0, cfg, predicted[-1]))
    measured_arr, predicted_arr = np.array(measured), np.array(predicted)
    assert np.max(np.abs(measured_arr - predicted_arr)) < 0.5 / cfg.fs_hz  # half a sample
    dt = (starts[-1] - starts[0]) / cfg.fs_hz
    f_meas = 1 - (measured_arr[-1] - measured_arr[0]) / dt
    f_geom = 1 - (predicted_arr[-1] - predicted_arr[0]) / dt
    assert abs(f_meas - f_geom) < 0.01 * abs(f_geom - 1)
    # the corner echo approaches at v cos(phi) both ways, like a point reflector
    mid = 0.5 * (starts[0] + starts[-1] + p) / cfg.fs_hz
    xm = traj.position(np.array([mid]))[0]
    direction = (corner - xm) / np.linalg.norm(corner - xm)
    cosphi = float(np.dot(traj.velocity(np.array([mid]))[0], direction)) / speed
    expected = (C + speed * cosphi) / (C - speed * cosphi)
    assert abs(f_meas - expected) < 0.02 * (expected - 1)


def test_path_table_doppler_and_angle_match_the_analytic_truth():
    speed, heading = 0.5, 0.4
    motion = synthetic.Motion(speed, heading, t_ref_s=0.0)
    wall = synthetic.Wall(2.0, 0.9)
    phi = heading + 0.9
    n = np.array([math.cos(phi), math.sin(phi)])
    tangent = np.array([-n[1], n[0]])
    scene = _scene([(tuple(2 * n - 300 * tangent), tuple(2 * n + 300 * tangent))])
    traj = _line((0.0, 0.0), heading, speed)
    engine = IsmConfig(order=1)
    prepared = prepare_scene(scene, CFG1, engine)
    plan = plan_stretch(prepared, traj, CFG1, engine, 0, CFG1.block_samples)
    table = path_table(plan, prepared, traj, CFG1, engine)
    t_mid = CFG1.block_s / 2
    truth = synthetic.echo_truth(t_mid, motion, wall, C)
    u = speed * math.cos(truth.angle_rad)
    assert table.n == 1 and table.order[0] == 1 and table.walls == ((0,),)
    assert abs(table.delay_s[0] - truth.delay_s) < 1e-12
    assert abs(table.doppler_factor[0] - (C + u) / (C - u)) < 1e-8
    assert abs(table.angle_to_velocity_rad[0] - truth.angle_rad) < 1e-3


def test_path_table_walls_are_in_the_order_the_sound_hits_them():
    """Two walls at 60 degrees (A along the x axis, B at 60 degrees from the apex), robot at
    1 m/s along y = 0.4. The sound that hits A first and then B comes back from the image
    ``R(+120) x(t - tau)`` (M_B M_A, a rotation about the apex), its reverse from
    ``R(-120) x(t - tau)``; for a moving sonar their retarded delays differ (microseconds).
    The table row labelled (A, B) carries the delay of the A-first path, solved by hand by
    fixed-point iteration. Regression: the labels of a path and its reverse were swapped."""
    speed, y0 = 1.0, 0.4
    scene = _scene([((0.0, 0.0), (4.0, 0.0)), ((0.0, 0.0), (2.0, 2.0 * math.sqrt(3.0)))])
    traj = _line((1.0, y0), 0.0, speed)
    engine = IsmConfig(order=2)
    prepared = prepare_scene(scene, CFG1, engine)
    plan = plan_stretch(prepared, traj, CFG1, engine, 0, CFG1.block_samples)
    table = path_table(plan, prepared, traj, CFG1, engine)
    t_mid = CFG1.block_s / 2

    def x_at(t: float) -> np.ndarray:
        return np.array([1.0 + speed * t, y0])

    def hand_delay(deg: float) -> float:
        a = math.radians(deg)
        R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        tau = 0.0
        for _ in range(50):
            tau = float(np.linalg.norm(x_at(t_mid) - R @ x_at(t_mid - tau))) / C
        return tau

    rows = {w: i for i, w in enumerate(table.walls) if len(w) == 2}
    assert set(rows) == {(0, 1), (1, 0)}
    a_first, b_first = hand_delay(120.0), hand_delay(-120.0)
    assert abs(a_first - b_first) > 1e-6  # the test can tell the two apart
    assert abs(table.delay_s[rows[(0, 1)]] - a_first) < 1e-10
    assert abs(table.delay_s[rows[(1, 0)]] - b_first) < 1e-10


# ---- statics, interpolation, continuity --------------------------------------------------------
def test_speed_zero_reduces_to_the_static_image_response():
    scene = builtin_scene("paper")
    xy = np.array([2.0, 2.0])
    traj = stationary_path(xy, math.pi / 4, 30.0)
    engine = IsmConfig(order=2)
    prepared = prepare_scene(scene, CFG1, engine)
    plan = plan_stretch(prepared, traj, CFG1, engine, 0, CFG1.block_samples)
    table = path_table(plan, prepared, traj, CFG1, engine)
    # by hand (paper scene, from (2, 2)): walls 1 and 2, their corner, and the corner of
    # walls 2 and 3 at (4.5, 1.36); wall 3 itself ends at x = 2.3 (no foot point)
    images = np.array([[2.0, 6.0], [7.0, 2.0], [7.0, 6.0], [7.0, 0.72]])
    lengths = np.sort(np.linalg.norm(images - xy, axis=1))
    assert np.allclose(np.sort(table.delay_s), lengths / C, atol=1e-9, rtol=0)
    assert np.all(table.doppler_factor == pytest.approx(1.0, abs=1e-12))
    t = np.arange(CFG1.block_samples) / CFG1.fs_hz
    want = sum(transmitted_at(t - L / C, CFG1) / L for L in lengths)
    got = render_stretch(plan, CFG1, engine)
    assert np.max(np.abs(got - want)) < 1e-9 * np.max(np.abs(want))


def test_hermite_delays_match_per_sample_newton_on_a_curve():
    scene = builtin_scene("paper")
    traj = builtin_path("paper-b")
    engine = IsmConfig(order=2)
    cfg = CFG1
    start = 7 * cfg.block_samples
    prepared = prepare_scene(scene, cfg, engine)
    plan = plan_stretch(prepared, traj, cfg, engine, start, cfg.block_samples)
    taus = delay_at_samples(plan, cfg, engine)
    rng = np.random.default_rng(1)
    idx = rng.choice(cfg.block_samples, 40, replace=False)
    worst = 0.0
    for i, img in enumerate(plan.active):
        A, b = plan.images.A[img], plan.images.b[img]
        for n in idx:
            ref = retarded_delay_scalar(A, b, traj, (start + n) / cfg.fs_hz, C)
            worst = max(worst, abs(taus[i, n] - ref))
    assert plan.active.size >= 3
    assert worst < 1e-9


def test_ten_blocks_equal_one_ten_block_stretch():
    scene = builtin_scene("paper")
    traj = builtin_path("paper-b")
    engine = IsmConfig(order=2)
    cfg = CFG1
    blocks = list(iter_ism_blocks(scene, traj, cfg, 10, engine, np.random.default_rng(0), 20))
    joined = np.concatenate([b.samples for b in blocks])
    stretch = simulate_stretch(scene, traj, cfg, 20 * cfg.block_samples, 10 * cfg.block_samples,
                               engine)
    assert np.max(np.abs(joined - stretch)) < 1e-12 * np.max(np.abs(stretch))
    assert [b.index for b in blocks] == list(range(20, 30))


@pytest.mark.parametrize("spreading", ["3d", "2d"])
@pytest.mark.parametrize("fractional_delay", ["table", "sinc"])
def test_kernel_matches_numpy_twin_across_a_path_appearing(spreading, fractional_delay):
    # the robot walks past the end of a finite wall: its echo fades out inside the stretch
    scene = _scene([((0.0, 2.0), (1.0, 2.0)), ((3.0, -1.0), (3.0, 4.0))])
    traj = _line((0.99, 0.0), 0.0, 0.5)
    engine = IsmConfig(order=2, spreading=spreading, fractional_delay=fractional_delay,
                       sinc_half_taps=8)
    cfg = CFG1
    prepared = prepare_scene(scene, cfg, engine)
    plan = plan_stretch(prepared, traj, cfg, engine, 0, 2000)
    assert np.any(np.diff(plan.gain, axis=1) != 0)  # a path does disappear here
    got = render_stretch(plan, cfg, engine)
    want = render_numpy(plan, cfg, engine)
    assert np.max(np.abs(got - want)) < 1e-10 * np.max(np.abs(want))


def test_windowed_sinc_converges_to_the_band_limited_table():
    scene = builtin_scene("paper")
    traj = builtin_path("paper-a")
    a = simulate_stretch(scene, traj, CFG1, 50_000, 3000, IsmConfig(order=2))
    errors = []
    for half_taps in (16, 64, 128):
        b = simulate_stretch(scene, traj, CFG1, 50_000, 3000,
                             IsmConfig(order=2, fractional_delay="sinc", sinc_half_taps=half_taps))
        errors.append(np.sqrt(np.mean((a - b) ** 2) / np.mean(a**2)))
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-3


def test_wall_end_echo_vanishes_without_a_click():
    scene = _scene([((0.0, 2.0), (1.0, 2.0))])
    traj = _line((0.5, 0.0), 0.0, 0.5)  # foot point leaves the wall at t = 1 s
    cfg = CFG1
    x = simulate_stretch(scene, traj, cfg, 0, int(2 * cfg.fs_hz), IsmConfig(order=1))
    before, after = x[: int(0.9 * cfg.fs_hz)], x[int(1.1 * cfg.fs_hz):]
    assert np.max(np.abs(before)) > 0.1
    assert np.max(np.abs(after)) == 0.0
    jump = np.max(np.abs(np.diff(x)))
    assert jump <= 1.05 * np.max(np.abs(np.diff(before)))


# ---- 2-D spreading against the exact 2-D Green's function --------------------------------------
def test_2d_spreading_matches_the_exact_hankel_response():
    cfg = CFG1
    distance = 2.0
    scene = _scene([((-300.0, distance), (300.0, distance))])
    traj = stationary_path(np.zeros(2), 0.0, 10.0)
    got = simulate_stretch(scene, traj, cfg, 0, cfg.period_samples,
                           IsmConfig(order=1, spreading="2d"))
    p = cfg.period_samples
    f = np.fft.rfftfreq(p, 1 / cfg.fs_hz)
    k = 2 * np.pi * f / C
    green = np.zeros(f.size, dtype=complex)
    green[1:] = -0.25j * hankel2(0, k[1:] * 2 * distance)  # e^{+i w t} convention
    k_c = 2 * np.pi * cfg.carrier_hz / C
    want = np.fft.irfft(np.fft.rfft(tx_period(cfg)) * green, n=p) * math.sqrt(8 * math.pi * k_c)
    corr = np.dot(got, want) / np.linalg.norm(got) / np.linalg.norm(want)
    assert corr >= 0.999
    assert np.linalg.norm(got) / np.linalg.norm(want) == pytest.approx(1.0, rel=0.02)
    # and 3-D spreading is clearly not the 2-D response
    got3 = simulate_stretch(scene, traj, cfg, 0, p, IsmConfig(order=1, spreading="3d"))
    assert np.dot(got3, want) / np.linalg.norm(got3) / np.linalg.norm(want) < 0.9


# ---- automatic order, noise, odometry, reverberation -----------------------------------------
def test_automatic_order_captures_every_shoebox_path_within_one_period():
    scene = builtin_scene("shoebox")  # 4 m x 3 m
    xy = np.array([1.0, 1.2])
    traj = stationary_path(xy, 0.0, 10.0)
    engine = IsmConfig()
    prepared = prepare_scene(scene, CFG1, engine)
    plan = plan_stretch(prepared, traj, CFG1, engine, 0, CFG1.block_samples)
    table = path_table(plan, prepared, traj, CFG1, engine)
    limit = C * CFG1.period_samples / CFG1.fs_hz
    count = 0
    for m in range(-10, 11):
        for n in range(-10, 11):
            for sx in (1, -1):
                for sy in (1, -1):
                    img = np.array([sx * xy[0] + 8 * m, sy * xy[1] + 6 * n])
                    if 1e-9 < np.linalg.norm(img - xy) <= limit:
                        count += 1
    assert table.n == count
    assert np.max(table.delay_s) <= limit / C


def test_white_noise_at_the_requested_snr_and_seeded():
    scene, traj = builtin_scene("paper"), builtin_path("paper-a")
    clean = simulate_run(scene, traj, CFG1, 2, IsmConfig(order=2), np.random.default_rng(0))
    noisy = simulate_run(scene, traj, CFG1, 2, IsmConfig(order=2, snr_db=10.0),
                         np.random.default_rng(5))
    again = simulate_run(scene, traj, CFG1, 2, IsmConfig(order=2, snr_db=10.0),
                         np.random.default_rng(5))
    noise = noisy.samples.astype(float) - clean.samples
    snr = 10 * np.log10(np.mean(clean.samples.astype(float) ** 2) / np.mean(noise**2))
    assert snr == pytest.approx(10.0, abs=0.3)
    assert np.array_equal(noisy.samples, again.samples)


def test_odometry_noise_on_the_recorded_speed_only():
    scene = builtin_scene("paper")
    traj = builtin_path("paper-a")
    run = simulate_run(scene, traj, CFG1, 60, IsmConfig(order=1, odometry_noise_m_s=0.01),
                       np.random.default_rng(3))
    err = run.speed_m_s - 0.1
    assert abs(np.std(err) - 0.01) < 0.003 and abs(np.mean(err)) < 0.004
    mids = (np.arange(60) + 0.5) * CFG1.block_s
    assert np.allclose(run.pose, traj.pose(mids))


def test_reverberant_tail_decays_at_rt60():
    cfg = CFG1
    scene = builtin_scene("paper")
    traj = stationary_path(np.array([2.0, 2.0]), 0.0, 30.0)
    rt60 = 0.04
    base = IsmConfig(order=1)
    wet = IsmConfig(order=1, rt60_s=rt60, reverb_db=-10.0, reverb_onset_s=0.005)
    dry_run = simulate_run(scene, traj, cfg, 2, base, np.random.default_rng(0))
    wet_run = simulate_run(scene, traj, cfg, 2, wet, np.random.default_rng(0))
    tail = wet_run.samples.astype(float) - dry_run.samples
    assert np.allclose(tail[0], tail[1], atol=1e-6)  # steady state: periodic
    first = np.array([1 / 4.0, 1 / 5.0])  # first-order amplitudes from (2, 2)
    level = np.sqrt(np.mean(tail[0] ** 2)) / (np.sqrt(np.sum(first**2)) * np.std(tx_period(cfg)))
    assert 20 * np.log10(level) == pytest.approx(-10.0, abs=0.2)
    # impulse response by circular cross-correlation with the m-sequence signal
    s = tx_period(cfg)
    h = np.fft.irfft(np.fft.rfft(tail[0]) * np.conj(np.fft.rfft(s)), n=s.size)
    win = int(0.002 * cfg.fs_hz)
    # fit from 7 ms after the onset to 30 ms (~37 dB of decay, above the sidelobe floor)
    edges = np.arange(int(0.012 * cfg.fs_hz), int(0.03 * cfg.fs_hz), win)
    energy_db = np.array([10 * np.log10(np.mean(h[e: e + win] ** 2)) for e in edges])
    slope = np.polyfit(edges / cfg.fs_hz, energy_db, 1)[0]
    assert slope == pytest.approx(-60.0 / rt60, rel=0.15)


def test_run_fields_and_metadata():
    scene, traj = builtin_scene("paper"), builtin_path("paper-b")
    run = simulate_run(scene, traj, CFG1, 3, IsmConfig(order=2), np.random.default_rng(0),
                       seed=0)
    mids = (np.arange(3) + 0.5) * CFG1.block_s
    assert run.samples.dtype == np.float32 and run.samples.shape == (3, CFG1.block_samples)
    assert np.allclose(run.t_s, np.arange(3) * CFG1.block_s)
    assert np.allclose(run.pose, traj.pose(mids))
    assert np.allclose(run.speed_m_s, traj.speed_m_s(mids))
    heading = np.unwrap(traj.pose(np.arange(4) * CFG1.block_s)[:, 2])
    assert np.allclose(run.yaw_rate_rad_s, np.diff(heading) / CFG1.block_s)   # block means
    assert run.scene is not None
    assert Scene.from_json(run.scene).segments().shape == scene.segments().shape
    assert run.meta["engine"] == "ism" and run.meta["path"] == "paper-b"
    assert run.meta["order"] == 2 and run.meta["spreading"] == "3d" and run.meta["seed"] == 0
    blocks = list(iter_blocks(scene, traj, CFG1, 2, IsmConfig(order=2), np.random.default_rng(0)))
    assert np.array_equal(blocks[1].samples.astype(np.float32), run.samples[1])


@pytest.mark.parametrize(
    ("field", "value"),
    [("order", 0), ("spreading", "4d"), ("fractional_delay", "linear"), ("fade_s", 0.5),
     ("delay_grid_s", 1.0), ("snr_db", float("nan")), ("rt60_s", -1.0),
     ("odometry_noise_m_s", -0.1), ("newton_steps", 0)],
)
def test_bad_engine_config_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        IsmConfig(**{field: value})


def test_bad_block_count_raises():
    with pytest.raises(ValueError, match="n_blocks"):
        next(iter_ism_blocks(builtin_scene("paper"), builtin_path("paper-a"), CFG1, 0,
                             IsmConfig(), np.random.default_rng(0)))


# ---- the paper's Fig. 5(a): heat map of a simulated block at point (a) --------------------------
def test_heat_map_at_point_a_peaks_at_the_paper_walls_and_corner():
    from mapping.heatmap import doppler_heatmap, required_margin

    cfg = SonarConfig()
    scene, traj = builtin_scene("paper"), builtin_path("paper-a")
    k = 13  # block midpoint at 13.8 s: the robot is at (1.98, 1.98), the paper's point (a)
    blocks = list(iter_ism_blocks(scene, traj, cfg, 3, IsmConfig(order=2),
                                  np.random.default_rng(0), k - 1))
    margin = required_margin(cfg, 0.1)
    ext = np.concatenate([blocks[0].samples[-margin:], blocks[1].samples,
                          blocks[2].samples[:margin]])
    hm = doppler_heatmap(ext, blocks[1].speed_m_s, cfg, left=margin, right=margin)
    x, y, heading = blocks[1].pose
    assert np.hypot(x - 2, y - 2) < 0.05

    def level(px: float, py: float) -> float:
        d = np.array([px - x, py - y])
        theta = abs(math.remainder(math.atan2(d[1], d[0]) - heading, 2 * math.pi))
        n = int(np.argmin(np.abs(hm.angles_rad - theta)))
        j = int(np.argmin(np.abs(hm.ranges_m - np.linalg.norm(d))))
        return float(hm.H[max(n - 1, 0): n + 2, max(j - 12, 0): j + 13].max() / hm.H.max())

    # Sec. 5: peaks at (2, 4) (Wall 1) and (4.5, 2) (Wall 2), and the corner (4.5, 4)
    assert level(2.0, 4.0) > 0.5 and level(4.5, 2.0) > 0.5 and level(4.5, 4.0) > 0.3
    # nothing where there is no wall: straight ahead at 1.5 m, sideways at 1.4 m
    assert level(x + 1.06, y + 1.06) < 0.1 and level(1.0, 3.0) < 0.1


@pytest.mark.parametrize("spreading", ["3d", "2d"])
def test_fast_engine_equals_the_per_sample_reference_loop(spreading):
    scene, traj = builtin_scene("paper"), builtin_path("paper-b")
    engine = IsmConfig(order=2, spreading=spreading)
    start, n = 9 * CFG1.block_samples + 123, 300
    prepared = prepare_scene(scene, CFG1, engine)
    plan = plan_stretch(prepared, traj, CFG1, engine, start, n)
    assert np.all(plan.gain == plan.gain[:, :1])  # no path appears here (no fades)
    fast = render_stretch(plan, CFG1, engine)
    slow = render_reference(prepared, traj, CFG1, engine, start, n)
    assert np.max(np.abs(fast - slow)) < 1e-8 * np.max(np.abs(slow))


def test_cli_simulate_writes_a_run_file(tmp_path):
    from mapping.files import read_run
    from service.cli import main

    config = tmp_path / "sonar.json"
    config.write_text(json.dumps({"repetitions": 1}))
    out = tmp_path / "run.npz"
    code = main(["simulate", "--scene", "builtin:paper", "--path", "paper-a", "--blocks", "3",
                 "--order", "2", "--snr-db", "30", "--seed", "4", "--config", str(config),
                 "--out", str(out)])
    assert code == 0
    run = read_run(out)
    assert run.n_blocks == 3 and run.meta["engine"] == "ism" and run.meta["seed"] == 4
    mids = (np.arange(3) + 0.5) * CFG1.block_s
    assert np.allclose(run.pose, builtin_path("paper-a").pose(mids))
    assert Scene.from_json(run.scene or "").name == "paper"
    assert main(["simulate", "--scene", "builtin:paper", "--path", "paper-a", "--engine", "nope",
                 "--out", str(out)]) == 2
    assert main(["simulate", "--scene", "builtin:paper", "--path", "paper-a", "--blocks", "0",
                 "--out", str(out)]) == 2


class _Line:
    """Stand-in trajectory: x(t) = p0 + v t (any time)."""

    name = "line"
    duration_s = 1.0

    def __init__(self, p0: np.ndarray, v: np.ndarray) -> None:
        self.p0, self.v = p0, v

    def position(self, t_s: Any) -> np.ndarray:
        return np.asarray(self.p0[None] + np.atleast_1d(np.asarray(t_s, float))[:, None]
                          * self.v[None], dtype=np.float64)

    def velocity(self, t_s: Any) -> np.ndarray:
        return np.broadcast_to(self.v, (np.size(t_s), 2)).copy()


@settings(max_examples=40, deadline=None)
@given(
    st.floats(-3, 3), st.floats(-3, 3), st.floats(0, 2 * math.pi), st.floats(0.0, 2.0),
    st.floats(0, 2 * math.pi), st.floats(2.5, 5.0),  # the robot stays in front of the wall
)
def test_retarded_delay_solves_its_equation(px, py, heading, speed, wall_angle, wall_dist):
    from mapping.simulate.ism import mirror_maps, retarded_delay

    n = np.array([math.cos(wall_angle), math.sin(wall_angle)])
    p0 = np.array([px, py])
    foot = p0 + wall_dist * n
    seg = np.array([[foot - 5 * np.array([-n[1], n[0]]), foot + 5 * np.array([-n[1], n[0]])]])
    A, b = mirror_maps(seg)
    line = _Line(p0, speed * np.array([math.cos(heading), math.sin(heading)]))
    traj = cast("TrajectoryLike", line)  # retarded_delay needs position() only
    t = np.linspace(-1.0, 1.0, 7)
    tau, dtau = retarded_delay(A, b, traj, t, C, 3)
    assert tau.shape == dtau.shape == (1, 7) and np.all(tau > 0)
    x, xe = traj.position(t), traj.position(t - tau[0])
    residual = np.linalg.norm(x - (xe @ A[0].T + b[0]), axis=1) - C * tau[0]
    assert np.max(np.abs(residual)) < 1e-9
    h = 1e-4
    fd = (retarded_delay(A, b, traj, t + h, C, 3)[0] - retarded_delay(A, b, traj, t - h, C, 3)[0])
    assert np.allclose(dtau, fd / (2 * h), atol=1e-9)
    # a wall: exactly (c + u) / (c - u) with u the approach speed
    u = float(line.v @ n)
    assert np.allclose(1 - dtau, (C + u) / (C - u), atol=1e-10)
