"""Raw import: timing from the direct path, resampling onto the sonar clock, static removal,
refusals. Truth: synthetic streams written from the shared conventions (``synth.py``)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from mapping.recording import (
    PoseLog,
    RawImportOptions,
    block_odometry,
    find_clipping,
    fit_clock,
    import_raw,
)
from mapping.resample import resample_at, transition_width_hz
from mapping.signal import SonarConfig, sound_speed_at, transmitted_at, tx_period
from tests.mapping.recording.synth import Echo, RawScene, field_at, raw_stream, wall_echo

CFG = SonarConfig()
C = CFG.sound_speed_m_s
LOG = PoseLog(t_s=np.array([0.0, 60.0]), x_m=np.array([0.0, 6.0]), y_m=np.zeros(2),
              heading_rad=np.zeros(2), speed_m_s=np.full(2, 0.1))
MOVING = wall_echo(1.2, speed_m_s=0.1)
PARALLEL = wall_echo(1.5)  # a wall beside a straight path: constant range
BODY = wall_echo(0.1, gain=0.01)  # the robot's body, 10 cm away


@pytest.mark.parametrize(("fs", "latency_s", "ppm", "noise"), [
    (44_100.0, 0.0371, 0.0, 0.0),      # latency alone
    (40_000.0, 0.0, 93.0, 0.0),        # clock offset alone, at the sonar rate
    (48_000.0, 0.3123, -87.0, 0.002),  # latency > a period, slow clock, noise
    (96_000.0, 0.9, 100.0, 0.005),     # ~1 s latency, fast clock, more noise
])
def test_latency_and_clock_offset_recovered(fs: float, latency_s: float, ppm: float,
                                            noise: float) -> None:
    scene = RawScene(fs_rec_hz=fs, latency_s=latency_s, clock_offset_ppm=ppm, noise_std=noise,
                     duration_s=5.0, echoes=(MOVING, PARALLEL, BODY))
    x = raw_stream(scene, CFG, np.random.default_rng(3))
    fit = fit_clock(x, fs, CFG, scene.offset_m, C)
    assert abs(fit.latency_s - latency_s) * fs < 0.05  # issue 16: 0.05 samples
    assert abs(fit.clock_offset_ppm - ppm) < 2.0  # issue 16: 2 ppm
    arrival = (latency_s + scene.offset_m / C) * (1 + ppm * 1e-6)
    assert fit.onset_s == pytest.approx(arrival, abs=0.1 / fs)
    assert fit.residual_samples < 0.01


def test_transducer_offset_sets_the_latency() -> None:
    """The same stream read with a wrong offset: the latency moves by the path difference."""
    scene = RawScene(offset_m=0.08, duration_s=3.0)
    x = raw_stream(scene, CFG)
    right = fit_clock(x, scene.fs_rec_hz, CFG, 0.08, C)
    wrong = fit_clock(x, scene.fs_rec_hz, CFG, 0.03, C)
    assert wrong.latency_s - right.latency_s == pytest.approx(0.05 / C, abs=1e-7)


def _lowpassed(truth_at, first: int, n: int, fs_rec: float) -> np.ndarray:
    """``truth_at(tau)`` on sonar samples first .. first + n - 1, through the importer's
    low-pass (the resampler as a filter at the sonar rate, 200 samples of margin)."""
    margin = 200
    tau = (first - margin + np.arange(n + 2 * margin)) / CFG.fs_hz
    cutoff = 0.5 * min(CFG.fs_hz, fs_rec) - 0.5 * transition_width_hz(fs_rec)
    out_t = (margin + np.arange(n)) / CFG.fs_hz
    return resample_at(truth_at(tau), CFG.fs_hz, out_t, cutoff)


def _project(y: np.ndarray, ref: np.ndarray) -> float:
    return float(y @ ref / (ref @ ref))


@pytest.mark.parametrize("fs", [44_100.0, 48_000.0])
def test_run_removal_leaves_the_moving_echo_on_the_sonar_clock(fs: float) -> None:
    """Output = the moving echo minus its periodic mean, sample for sample (the clean
    simulation of the same samples is the block's ground truth)."""
    scene = RawScene(fs_rec_hz=fs, latency_s=0.151, clock_offset_ppm=-41.0, duration_s=7.0,
                     echoes=(MOVING, PARALLEL, BODY))
    run, report = import_raw(raw_stream(scene, CFG), fs, LOG, CFG,
                             RawImportOptions(static_removal="run"))
    y = run.samples.reshape(-1).astype(np.float64)
    assert report.first_sample % CFG.period_samples == 0 and report.first_sample > 0
    moving = _lowpassed(lambda tau: field_at(RawScene(echoes=(MOVING,), direct=False), tau, CFG),
                        report.first_sample, y.size, fs)
    periods = moving.reshape(-1, CFG.period_samples)
    expected = (periods - periods.mean(axis=0)).reshape(-1)
    err_db = 10 * np.log10(np.sum((y - expected) ** 2) / np.sum(expected ** 2))
    assert err_db < -35.0
    assert report.direct_suppression_db >= 40.0
    assert report.blocks == run.n_blocks == 6  # (7 - 0.151 - 0.102) s
    # direct 0.2 (and the body, 0.01, inside its gate) over the two walls' 0.002 each
    assert report.direct_to_echo_db == pytest.approx(10 * np.log10(0.0401 / 8e-6), abs=0.5)


def test_run_removes_a_parallel_wall_and_gated_keeps_it() -> None:
    """The trap of issue 16: a wall at constant range is static too."""
    scene = RawScene(latency_s=0.05, clock_offset_ppm=20.0, duration_s=6.0,
                     echoes=(MOVING, PARALLEL, BODY), noise_std=0.0005)
    x = raw_stream(scene, CFG, np.random.default_rng(5))
    kept = {}
    for method in ("run", "gated"):
        run, report = import_raw(x, scene.fs_rec_hz, LOG, CFG,
                                 RawImportOptions(static_removal=method))
        y = run.samples.reshape(-1).astype(np.float64)
        wall = _lowpassed(lambda tau: field_at(RawScene(echoes=(PARALLEL,), direct=False),
                                               tau, CFG), report.first_sample, y.size, 44_100.0)
        body = _lowpassed(lambda tau: field_at(RawScene(echoes=(BODY,), direct=False),
                                               tau, CFG), report.first_sample, y.size, 44_100.0)
        kept[method] = (_project(y, wall), _project(y, body))
        assert report.direct_suppression_db >= 40.0, method
        assert report.method == method
    assert abs(kept["run"][0]) < 0.02 and kept["gated"][0] == pytest.approx(1.0, abs=0.03)
    assert abs(kept["run"][1]) < 0.02 and abs(kept["gated"][1]) < 0.02  # body gone in both


def test_gated_removes_floor_and_ceiling_only_given_heights() -> None:
    h, big_h, offset = 0.6, 2.5, 0.05  # floor beyond the near gate (0.2 m)
    floor = Echo(0.005, lambda tau: np.full(tau.shape, math.hypot(2 * h, offset) / C))
    ceiling = Echo(0.002, lambda tau: np.full(tau.shape, math.hypot(2 * (big_h - h), offset) / C))
    scene = RawScene(duration_s=5.0, echoes=(MOVING, PARALLEL, floor, ceiling))
    x = raw_stream(scene, CFG)
    gains = {}
    for heights in ((None, None), (h, big_h)):
        run, report = import_raw(x, scene.fs_rec_hz, LOG, CFG, RawImportOptions(
            static_removal="gated", sonar_height_m=heights[0], ceiling_height_m=heights[1]))
        y = run.samples.reshape(-1).astype(np.float64)
        refs = [_lowpassed(lambda tau, e=e: field_at(RawScene(echoes=(e,), direct=False), tau,
                                                     CFG), report.first_sample, y.size, 44_100.0)
                for e in (floor, ceiling, PARALLEL)]
        gains[heights[0]] = [_project(y, r) for r in refs]
        assert any("floor/ceiling" in w for w in report.warnings) == (heights[0] is None)
    assert gains[None] == pytest.approx([1.0, 1.0, 1.0], abs=0.03)
    assert gains[h][:2] == pytest.approx([0.0, 0.0], abs=0.02)
    assert gains[h][2] == pytest.approx(1.0, abs=0.03)


def test_calibration_removes_what_it_heard_and_keeps_walls() -> None:
    """A calibration in the open (direct + body) at another latency, clock and volume."""
    cal_scene = RawScene(fs_rec_hz=48_000.0, latency_s=0.2137, clock_offset_ppm=-30.0,
                         duration_s=4.0, echoes=(Echo(0.01, BODY.delay_s),))
    cal = raw_stream(cal_scene, CFG)
    cal = cal * 0.8  # the volume was lower: the fitted gain is 1 / 0.8
    scene = RawScene(latency_s=0.071, clock_offset_ppm=55.0, duration_s=6.0,
                     echoes=(MOVING, PARALLEL, Echo(0.01, BODY.delay_s)))
    run, report = import_raw(raw_stream(scene, CFG), scene.fs_rec_hz, LOG, CFG,
                             RawImportOptions(static_removal="calibration"),
                             calibration=(cal, 48_000.0))
    y = run.samples.reshape(-1).astype(np.float64)
    wall = _lowpassed(lambda tau: field_at(RawScene(echoes=(PARALLEL,), direct=False), tau, CFG),
                      report.first_sample, y.size, 44_100.0)
    assert _project(y, wall) == pytest.approx(1.0, abs=0.03)
    assert report.direct_suppression_db >= 40.0
    assert report.calibration is not None
    assert report.calibration.gain == pytest.approx(0.2 / (0.8 * 0.2), rel=0.01)
    assert report.calibration.latency_s == pytest.approx(0.2137, abs=0.05 / 48_000)


def test_run_times_and_odometry_on_the_recording_clock() -> None:
    latency, ppm = 0.4321, 80.0
    scene = RawScene(latency_s=latency, clock_offset_ppm=ppm, duration_s=6.5)
    t = np.linspace(0.0, 7.0, 71)
    log = PoseLog(t_s=t, x_m=0.1 * t, y_m=np.zeros(t.size), heading_rad=0.2 * t,
                  speed_m_s=0.1 + 0.01 * t)
    run, report = import_raw(raw_stream(scene, CFG), scene.fs_rec_hz, log, CFG)
    k = np.arange(run.n_blocks)
    tau0 = (report.first_sample + k * CFG.block_samples) / CFG.fs_hz
    scale = 1 + ppm * 1e-6
    np.testing.assert_allclose(run.t_s, (tau0 + latency) * scale, atol=2e-6)
    mid = run.t_s + 0.5 * CFG.block_s * scale
    np.testing.assert_allclose(run.pose[:, 0], 0.1 * mid, atol=1e-9)
    np.testing.assert_allclose(run.speed_m_s, 0.1 + 0.01 * mid, atol=1e-9)
    np.testing.assert_allclose(run.yaw_rate_rad_s, 0.2, atol=1e-9)
    assert run.meta["raw_import"] == json.loads(json.dumps(report.to_dict()))


def test_blocks_outside_the_pose_log_are_dropped_and_reported() -> None:
    scene = RawScene(duration_s=6.0)
    log = PoseLog(t_s=np.array([2.0, 4.5]), x_m=np.zeros(2), y_m=np.zeros(2),
                  heading_rad=np.zeros(2), speed_m_s=np.zeros(2))
    x = raw_stream(scene, CFG)
    run, report = import_raw(x, scene.fs_rec_hz, log, CFG)
    mid = run.t_s + 0.5 * CFG.block_s
    assert np.all((mid >= 2.0) & (mid <= 4.5)) and run.n_blocks == 2
    assert report.first_sample == CFG.period_samples + 2 * CFG.block_samples  # mid 2.69 s
    assert any("outside the pose log" in w for w in report.warnings)
    late = PoseLog(t_s=np.array([100.0, 200.0]), x_m=np.zeros(2), y_m=np.zeros(2),
                   heading_rad=np.zeros(2), speed_m_s=np.zeros(2))
    with pytest.raises(ValueError, match="no block lies inside the pose log"):
        import_raw(x, scene.fs_rec_hz, late, CFG)


def test_refusals_say_what_and_how_much() -> None:
    scene = RawScene(duration_s=3.0)
    x = raw_stream(scene, CFG)
    with pytest.raises(ValueError, match="unsupported sample rate 32000 Hz"):
        import_raw(x, 32_000.0, LOG, CFG)
    clipped = np.clip(x * 10.0, -1.0, 1.0)
    with pytest.raises(ValueError, match=r"clipping: \d+ samples .* from 0\.0\d\d s"):
        import_raw(clipped, scene.fs_rec_hz, LOG, CFG)
    noise = np.random.default_rng(0).standard_normal(x.size) * 0.01
    with pytest.raises(ValueError, match="no direct path found"):
        import_raw(noise, scene.fs_rec_hz, LOG, CFG)
    short = raw_stream(RawScene(duration_s=1.1), CFG)
    with pytest.raises(ValueError, match=r"too short: needs at least 1\.1\d s"):
        import_raw(short, scene.fs_rec_hz, LOG, CFG)
    with pytest.raises(ValueError, match="needs a calibration recording"):
        import_raw(x, scene.fs_rec_hz, LOG, CFG, RawImportOptions(static_removal="calibration"))


@pytest.mark.parametrize(("kwargs", "fragment"), [
    ({"transducer_offset_m": 0.0}, "transducer_offset_m"),
    ({"static_removal": "all"}, "static_removal"),
    ({"ceiling_height_m": 2.5}, "ceiling_height_m needs sonar_height_m"),
    ({"sonar_height_m": 3.0, "ceiling_height_m": 2.5}, "below it"),
    ({"temperature_c": 20.0, "sound_speed_m_s": 343.0}, "not both"),
    ({"startup_periods": 0}, "startup_periods"),
])
def test_options_validation(kwargs: dict[str, object], fragment: str) -> None:
    with pytest.raises(ValueError, match=fragment):
        RawImportOptions(**kwargs)  # type: ignore[arg-type]


def test_temperature_sets_the_run_speed_of_sound() -> None:
    assert sound_speed_at(20.0) == pytest.approx(343.2, abs=0.1)
    assert sound_speed_at(0.0) == pytest.approx(331.3)
    scene = RawScene(duration_s=3.0, sound_speed_m_s=sound_speed_at(30.0))
    run, report = import_raw(raw_stream(scene, CFG), scene.fs_rec_hz, LOG, CFG,
                             RawImportOptions(temperature_c=30.0))
    assert run.config.sound_speed_m_s == report.sound_speed_m_s == scene.sound_speed_m_s
    assert abs(report.latency_s - scene.latency_s) * scene.fs_rec_hz < 0.05


def test_find_clipping() -> None:
    x = np.sin(np.linspace(0, 20, 1000))
    assert find_clipping(x) == (0, -1, -1)  # a clean peak is one sample
    y = np.clip(1.2 * x, -1.0, 1.0)
    count, first, last = find_clipping(y)
    assert count == np.sum(np.abs(1.2 * x) >= 1.0) and first == int(np.argmax(np.abs(y) >= 1.0))
    pcm = np.array([0.1, 32767 / 32768, 0.2, -1.0, 0.0])
    assert find_clipping(pcm, full_scale=32767 / 32768) == (2, 1, 3)


def test_block_odometry_with_start_times_matches_the_old_call() -> None:
    t = np.arange(0.0, 5.01, 0.1)
    log = PoseLog(t_s=t, x_m=np.cos(t), y_m=np.sin(t), heading_rad=0.3 * t,
                  speed_m_s=0.1 + 0.02 * t)
    old = block_odometry(log, 4, 1.0)
    new = block_odometry(log, 4, 1.0, start_s=np.arange(4.0))
    for name in ("t_s", "pose", "speed_m_s", "yaw_rate_rad_s"):
        np.testing.assert_array_equal(getattr(old, name), getattr(new, name))
    shifted = block_odometry(log, 3, 1.0, start_s=np.array([0.25, 1.3, 2.9]))
    np.testing.assert_allclose(shifted.speed_m_s, 0.1 + 0.02 * np.array([0.75, 1.8, 3.4]))
    with pytest.raises(ValueError, match="start_s must be 3 finite"):
        block_odometry(log, 3, 1.0, start_s=np.zeros(2))


def test_transmitted_reference_is_what_the_synth_plays() -> None:
    """Guard on the test's own truth: the synthetic direct wave is the transmitted signal."""
    scene = RawScene(latency_s=0.0, duration_s=0.2)
    x = raw_stream(scene, CFG)
    n = np.arange(x.size)
    expected = scene.direct_gain() * transmitted_at(n / scene.fs_rec_hz - 0.05 / C, CFG)
    np.testing.assert_allclose(x, np.where(n / scene.fs_rec_hz >= 0, expected, 0.0))


def test_simulated_raw_recording_all_effects() -> None:
    """The raw simulator (mapping.simulate.raw), every effect but the band-passes on, at 48 kHz
    and SNR 10 dB: timing within the issue's targets, direct wave and floor/ceiling gone."""
    from mapping.path import builtin_path
    from mapping.scene import builtin_scene
    from mapping.simulate.ism import IsmConfig
    from mapping.simulate.raw import RawConfig, simulate_raw

    raw = RawConfig(fs_hz=48_000.0, latency_s=0.0837, clock_offset_ppm=-62.0,
                    transducer_offset_m=0.05, sonar_height_m=0.3, ceiling_height_m=2.4,
                    temperature_c=25.0, snr_db=10.0)
    rec = simulate_raw(builtin_scene("paper"), builtin_path("paper-a"), CFG, 5.0, IsmConfig(),
                       raw, np.random.default_rng(1))
    residual = {}
    for heights in ((None, None), (0.3, 2.4)):
        run, report = import_raw(rec.samples, rec.fs_hz, rec.poses, CFG, RawImportOptions(
            static_removal="gated", sonar_height_m=heights[0], ceiling_height_m=heights[1],
            temperature_c=25.0))
        assert abs(report.latency_s - raw.latency_s) * raw.fs_hz < 0.05
        assert abs(report.clock_offset_ppm - raw.clock_offset_ppm) < 2.0
        assert report.direct_suppression_db >= 40.0
        assert report.sound_speed_m_s == pytest.approx(rec.truth.sound_speed_m_s)
        # matched-filter output averaged over the periods: what stayed static, per lag
        y = run.samples.reshape(-1, CFG.period_samples).astype(np.float64)
        lag = np.fft.irfft(np.fft.rfft(y) * np.conj(np.fft.rfft(tx_period(CFG))),
                           CFG.period_samples)
        static = np.abs(lag.mean(axis=0))
        residual[heights[0]] = [static[int(round(d * CFG.fs_hz)) - 2:][:5].max()
                                for d in rec.truth.static_delay_s[2:]]  # ceiling, floor+ceiling
    # without heights the ceiling stays; with them it drops by > 20 dB
    assert all(a > 10.0 * b for a, b in zip(residual[None], residual[0.3], strict=True))
