"""The raw simulator, one effect at a time, against independent truths.

Rates: at ``fs_hz = 40 kHz`` with no latency or clock offset the resampling reads the sonar
stream on its own grid (identity), so an effect alone can be compared with its analytic
signal to ~1e-6 (the engine's table interpolation); at 48 kHz the truth is the exact
band-limited (periodic) interpolant of a standing robot's stream, which the 20 kHz low-pass
of the resampling matches to the stated tolerances.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.signal import sosfreqz

from mapping.signal import playback_signal, sound_speed_at, transmitted_exact, tx_samples
from mapping.simulate.ism import IsmConfig, simulate_stretch
from mapping.simulate.raw import (
    RawConfig,
    band_sos,
    iter_raw_chunks,
    recording_times,
    simulate_raw,
)
from tests.mapping.simulate.raw.helpers import (
    CFG,
    ENGINE,
    REFLECTION,
    WALL_X_M,
    driving,
    echo,
    one_wall,
    standing,
)

RNG = np.random.default_rng
C = CFG.sound_speed_m_s
P = CFG.period_samples


def _raw(duration_s: float, trajectory=None, **fields) -> np.ndarray:  # noqa: ANN001
    rec = simulate_raw(one_wall(), trajectory or standing(), CFG, duration_s, ENGINE,
                       RawConfig(**fields), RNG(0))
    return rec.samples


def _wall_echo(tau: np.ndarray, c: float = C) -> np.ndarray:
    """The standing robot's wall echo: R / (2 r) s(tau - 2 r / c)."""
    return echo(2 * WALL_X_M / c, REFLECTION / (2 * WALL_X_M), tau)


def test_all_effects_off_at_the_sonar_rate_is_the_clean_stream() -> None:
    """fs = 40 kHz, nothing on: the clean image-source stream of a driving robot to 1e-9
    (measured 3e-12: rounding of the output times)."""
    got = _raw(0.5, driving(), fs_hz=40_000.0)
    clean = simulate_stretch(one_wall(), driving(), CFG, 0, got.size, ENGINE)
    assert np.max(np.abs(got - clean)) < 1e-9 * np.max(np.abs(clean))


def test_all_effects_off_at_48k_is_the_band_limited_stream() -> None:
    """48 kHz: the standing robot's echo (exact band-limited interpolant) within 3e-3 of its
    peak, away from the onset (measured 2.2e-3: the sonar stream has energy up to 20 kHz,
    where the resampling's low-pass rolls off)."""
    got = _raw(0.4, fs_hz=48_000.0)
    tau = recording_times(RawConfig(fs_hz=48_000.0), 0, got.size)
    truth = _wall_echo(tau)
    keep = (tau > 0.002) & (tau < tau[-1] - 0.002)
    err = np.max(np.abs(got - truth)[keep]) / np.max(np.abs(truth))
    assert err < 3e-3, err


def test_latency_shifts_the_stream_by_exactly_the_latency() -> None:
    """Latency of 777 recording samples: the stream moves by 777 samples (1e-9; measured
    2e-12, rounding of the output times) with zeros before; a driving robot, so the stream
    is not periodic."""
    lat = 777 / 48_000.0
    base = _raw(0.3, driving(), fs_hz=48_000.0)
    late = _raw(0.3, driving(), fs_hz=48_000.0, latency_s=lat)
    assert np.all(late[:777] == 0.0)
    assert np.max(np.abs(late[777:] - base[: base.size - 777])) < 1e-9


def test_fractional_latency_and_clock_offset_follow_the_conventions() -> None:
    """Latency 12.345 ms and +300 ppm: sample n holds the standing robot's echo at
    tau_n = n / (fs (1 + ppm 1e-6)) - latency (3e-3 of the peak, as without them)."""
    raw = RawConfig(fs_hz=44_100.0, latency_s=0.012345, clock_offset_ppm=300.0)
    rec = simulate_raw(one_wall(), standing(), CFG, 0.4, ENGINE, raw, RNG(0))
    n = np.arange(rec.samples.size)
    tau = n / (44_100.0 * (1 + 300e-6)) - 0.012345
    assert rec.truth.onset_sample == int(np.argmax(tau >= 0))
    truth = np.where(tau >= 0, _wall_echo(tau), 0.0)
    keep = (tau < -0.002) | ((tau > 0.002) & (tau < tau[-1] - 0.002))
    err = np.max(np.abs(rec.samples - truth)[keep]) / np.max(np.abs(truth))
    assert err < 3e-3, err


def _peak_sample(x: np.ndarray, template: np.ndarray, around: float) -> float:
    """Position of the cross-correlation peak of ``template`` in ``x`` within 20 samples of
    ``around``, refined by a parabola through the three highest samples."""
    lo = int(around) - 20
    corr = np.array([x[lo + k: lo + k + template.size] @ template for k in range(41)])
    k = int(np.argmax(corr))
    a, b, c = corr[k - 1], corr[k], corr[k + 1]
    return lo + k + 0.5 * (a - c) / (a - 2 * b + c)


def test_clock_offset_drifts_the_direct_wave_by_p_ppm_per_period() -> None:
    """+100 ppm at 48 kHz: the direct wave's arrival (correlation peak against the playback
    signal) moves P_rec * 1e-4 = 0.491 recording samples per period more than the nominal
    P_rec = 4910.4 (slope of a line through 12 periods, within 0.01 samples/period)."""
    fs_rec, ppm = 48_000.0, 100.0
    x = _raw(1.3, fs_hz=fs_rec, clock_offset_ppm=ppm, transducer_offset_m=0.05)
    template = playback_signal(CFG, fs_rec, 1500)
    p_rec = P / CFG.fs_hz * fs_rec
    delay = 0.05 / C * fs_rec
    peaks = [_peak_sample(x, template, k * p_rec * (1 + ppm * 1e-6) + delay) for k in range(1, 13)]
    slope = np.polyfit(np.arange(1, 13), peaks, 1)[0]
    assert abs(slope - p_rec - p_rec * ppm * 1e-6) < 0.01, slope - p_rec


def test_direct_wave_delay_and_amplitude() -> None:
    """Offset 5 cm: the recording minus the one without it is s(t - d / c) / d (1e-5 of its
    peak, 20 above the 2 m wall's echo)."""
    with_direct = _raw(0.25, fs_hz=40_000.0, transducer_offset_m=0.05)
    without = _raw(0.25, fs_hz=40_000.0)
    tau = np.arange(with_direct.size) / CFG.fs_hz
    truth = echo(0.05 / C, 1 / 0.05, tau)
    assert np.max(np.abs(with_direct - without - truth)) < 1e-5 * 20


def test_body_echo_constant_delay_no_doppler() -> None:
    """A bumper echo (path 0.3 m, reflection 0.4) on a driving robot: the extra signal is
    0.4 / 0.3 s(t - 0.3 / c), constant delay, to 1e-5 of its peak."""
    on = _raw(0.3, driving(), fs_hz=40_000.0, body_echoes=((0.3, 0.4),))
    off = _raw(0.3, driving(), fs_hz=40_000.0)
    tau = np.arange(on.size) / CFG.fs_hz
    truth = echo(0.3 / C, 0.4 / 0.3, tau)
    assert np.max(np.abs(on - off - truth)) < 1e-5 * 1.4


@pytest.mark.parametrize("bad", [((0.0, 0.5),), ((2.5, 0.5),), ((0.3, 1.5),), ((0.3,),)])
def test_body_echoes_are_checked(bad: tuple[tuple[float, ...], ...]) -> None:
    with pytest.raises(ValueError, match=r"body_echoes\[0\]"):
        RawConfig(body_echoes=bad)  # type: ignore[arg-type]


def test_floor_echo_constant_delay_no_doppler_one_over_r() -> None:
    """Sonar 0.3 m up, floor 0.9, a DRIVING robot: the extra signal is 0.9 / 0.6 s(t - 0.6 / c)
    (constant delay, zero Doppler) to 1e-5 of its peak."""
    on = _raw(0.3, driving(), fs_hz=40_000.0, sonar_height_m=0.3, floor_reflection=0.9)
    off = _raw(0.3, driving(), fs_hz=40_000.0)
    tau = np.arange(on.size) / CFG.fs_hz
    truth = echo(0.6 / C, 0.9 / 0.6, tau)
    assert np.max(np.abs(on - off - truth)) < 1e-5 * 1.5


def test_floor_plus_wall_path_delay_and_amplitude() -> None:
    """vertical_order 2, standing 2 m from the wall 0.3 m up: the combined path has delay
    sqrt(4^2 + 0.6^2) / c and amplitude R rf / sqrt(4^2 + 0.6^2) (1e-5 of its peak)."""
    kw = dict(fs_hz=40_000.0, sonar_height_m=0.3, floor_reflection=0.9)
    two = _raw(0.25, **kw, vertical_order=2)
    one = _raw(0.25, **kw, vertical_order=1)
    tau = np.arange(two.size) / CFG.fs_hz
    length = math.hypot(2 * WALL_X_M, 0.6)
    gain = REFLECTION * 0.9 / length
    truth = echo(length / C, gain, tau)
    assert np.max(np.abs(two - one - truth)) < 1e-5 * gain


def test_temperature_scales_the_echo_delay() -> None:
    """22 C: the wall echo is R / (2r) s(t - 2r / c(22 C)), c = 344.4 m/s while the config
    says 340 (its delay shorter by the ratio 340 / 344.4), to 1e-5 of its peak."""
    c22 = sound_speed_at(22.0)
    rec = simulate_raw(one_wall(), standing(), CFG, 0.25, ENGINE,
                       RawConfig(fs_hz=40_000.0, temperature_c=22.0), RNG(0))
    assert rec.truth.sound_speed_m_s == pytest.approx(c22)
    tau = np.arange(rec.samples.size) / CFG.fs_hz
    peak = REFLECTION / (2 * WALL_X_M)
    assert np.max(np.abs(rec.samples - _wall_echo(tau, c22))) < 1e-5 * peak
    # the same recording is far from the echo at the config's speed (26 um of delay: 0.9 samples)
    assert np.max(np.abs(rec.samples - _wall_echo(tau, C))) > 0.3 * peak


def test_band_passes_apply_the_butterworth_response() -> None:
    """Speaker 1.5-18 kHz and mic 0.05-19 kHz on a standing robot's direct wave: in steady
    state, each DFT bin over 4 whole periods is the unfiltered one times |H_s H_m| (1e-3),
    and the energy below 1 kHz drops by > 6 dB."""
    kw = dict(fs_hz=40_000.0, transducer_offset_m=0.05)
    flat = _raw(0.6, **kw)
    banded = _raw(0.6, **kw, speaker_band_hz=(1_500.0, 18_000.0), mic_band_hz=(50.0, 19_000.0))
    seg = slice(P, 5 * P)  # after the filters' start-up
    f_flat, f_band = np.fft.rfft(flat[seg]), np.fft.rfft(banded[seg])
    freqs = np.fft.rfftfreq(4 * P, 1 / CFG.fs_hz)
    h = np.ones(freqs.size, dtype=complex)
    for band in ((1_500.0, 18_000.0), (50.0, 19_000.0)):
        h *= sosfreqz(band_sos(band, 2, CFG.fs_hz), worN=freqs, fs=CFG.fs_hz)[1]
    strong = np.abs(f_flat) > 1e-3 * np.max(np.abs(f_flat))
    assert np.allclose(f_band[strong], (h * f_flat)[strong], rtol=1e-3,
                       atol=1e-6 * np.max(np.abs(f_flat)))
    low = freqs < 1_000.0
    assert np.sum(np.abs(f_band[low]) ** 2) < 0.25 * np.sum(np.abs(f_flat[low]) ** 2)


def test_chunks_join_into_one_stream() -> None:
    """Band-passes on, latency, clock offset: 13 ms chunks give the 1 s chunks' samples."""
    raw = RawConfig(fs_hz=48_000.0, latency_s=0.01, clock_offset_ppm=-40.0,
                    speaker_band_hz=(1_500.0, 18_000.0), transducer_offset_m=0.05)
    args = (one_wall(), driving(), CFG, 0.3, ENGINE, raw, RNG(0))
    small = np.concatenate([c.samples for c in iter_raw_chunks(*args, chunk_s=0.013)])
    large = np.concatenate([c.samples for c in iter_raw_chunks(*args, chunk_s=1.0)])
    assert np.max(np.abs(small - large)) < 1e-9


def test_noise_level_is_the_clean_runs_snr_in_the_sonar_band() -> None:
    """SNR 10 dB at 48 kHz: sigma^2 = P_echo / 10 * 48 / 40 (1 %), P_echo the clean wall
    echo's power; measured noise std within 3 %; before the onset noise only."""
    raw = RawConfig(fs_hz=48_000.0, snr_db=10.0, latency_s=0.05)
    noisy = simulate_raw(one_wall(), standing(), CFG, 0.5, ENGINE, raw, RNG(5))
    clean = _raw(0.5, fs_hz=48_000.0, latency_s=0.05)
    echo_power = np.mean(_wall_echo(np.arange(P) / CFG.fs_hz) ** 2)
    sigma = math.sqrt(echo_power / 10 * 48 / 40)
    assert np.allclose(noisy.truth.noise_sigma, sigma, rtol=0.01)
    assert np.std(noisy.samples - clean) == pytest.approx(sigma, rel=0.03)
    assert np.std(noisy.samples[:2000]) == pytest.approx(sigma, rel=0.1)


def test_full_scale_clips_and_counts() -> None:
    rec = simulate_raw(one_wall(), standing(), CFG, 0.2, ENGINE,
                       RawConfig(transducer_offset_m=0.05, full_scale=10.0), RNG(0))
    assert np.max(np.abs(rec.samples)) == 10.0
    assert rec.truth.clipped_samples == np.count_nonzero(np.abs(rec.samples) == 10.0) > 0


def test_pose_log_is_on_the_recording_clock() -> None:
    """A row at t_rec holds the pose at tau = t_rec / (1 + ppm 1e-6) - latency, so the pose
    at tau = 1 s is logged at (1 + latency) (1 + ppm 1e-6); rows cover the recording."""
    raw = RawConfig(latency_s=0.2, clock_offset_ppm=500.0, pose_step_s=0.05)
    traj = driving()
    rec = simulate_raw(one_wall(), traj, CFG, 2.0, ENGINE, raw, RNG(0))
    log = rec.poses
    assert log.t_s[0] == 0.0 and log.t_s[-1] >= 2.0
    t_log = (1.0 + 0.2) * (1 + 500e-6)
    x = np.interp(t_log, log.t_s, log.x_m)
    assert x == pytest.approx(traj.position(np.array([1.0]))[0, 0], abs=1e-9)
    assert np.allclose(log.speed_m_s, 0.3)


def test_playback_signal_is_the_transmitted_signal_at_the_card_rate() -> None:
    """At 48 kHz: the exact band-limited interpolant (1e-5); at 40 kHz: the samples."""
    got = playback_signal(CFG, 48_000.0, 300)
    assert np.max(np.abs(got - transmitted_exact(np.arange(300) / 48_000.0, CFG))) < 1e-5
    assert np.allclose(playback_signal(CFG, 40_000.0, 300), tx_samples(CFG, 0, 300), atol=1e-5)
    with pytest.raises(ValueError, match="fs_hz"):
        playback_signal(CFG, 32_000.0, 10)


@pytest.mark.parametrize(
    ("engine", "message"),
    [
        (replace(ENGINE, spreading="2d"), "spreading must be '3d'"),
        (IsmConfig(snr_db=10.0), "RawConfig.snr_db"),
        (IsmConfig(rt60_s=0.3), "rt60_s"),
        (IsmConfig(odometry_noise_m_s=0.01), "odometry_noise_m_s"),
    ],
)
def test_unmodelled_engine_settings_are_refused(engine: IsmConfig, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        simulate_raw(one_wall(), standing(), CFG, 0.1, engine, RawConfig(), RNG(0))


def test_bad_run_arguments() -> None:
    with pytest.raises(ValueError, match="duration_s"):
        simulate_raw(one_wall(), standing(), CFG, 0.0, ENGINE, RawConfig(), RNG(0))
    with pytest.raises(ValueError, match="fs / 2"):
        simulate_raw(one_wall(), standing(), CFG, 0.1, ENGINE,
                     RawConfig(mic_band_hz=(50.0, 22_000.0)), RNG(0))
