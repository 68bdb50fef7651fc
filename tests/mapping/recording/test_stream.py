"""Raw recordings against clean runs (issue 16): the heat map of an imported raw recording has
its peaks where the clean run's are, and the streaming importer gives the batch import's
blocks."""

from __future__ import annotations

import dataclasses
from functools import cache

import numpy as np
import pytest

from mapping.forward import local_maxima
from mapping.heatmap import HeatMap, heatmap_of_run
from mapping.path import builtin_path
from mapping.recording import RawImportOptions, RawStreamer, import_raw
from mapping.run import Run
from mapping.scene import builtin_scene
from mapping.signal import SonarConfig
from mapping.simulate.ism import IsmConfig, simulate_stretch
from mapping.simulate.raw import RawConfig, RawRecording, simulate_raw

CFG = SonarConfig()
#: Every effect of issue 16 (floor / ceiling bounces alone, a body echo, band-passes, 22 C
#: air), 48 kHz.
ALL = RawConfig(fs_hz=48_000.0, latency_s=0.037, clock_offset_ppm=60.0,
                transducer_offset_m=0.05, sonar_height_m=0.3, ceiling_height_m=2.6,
                speaker_band_hz=(1_500.0, 18_000.0), mic_band_hz=(50.0, 19_000.0),
                temperature_c=22.0, body_echoes=((0.3, 0.3),))
OPTIONS = RawImportOptions(static_removal="gated", sonar_height_m=0.3, ceiling_height_m=2.6,
                           temperature_c=22.0)
ENGINE = IsmConfig(max_order=2, max_path_m=12.0)


@cache
def recording(raw: RawConfig = ALL, seconds: float = 7.0) -> RawRecording:
    return simulate_raw(builtin_scene("shoebox"), builtin_path("shoebox-straight"), CFG,
                        seconds, ENGINE, raw, np.random.default_rng(4))


def gated_ranges_m(options: RawImportOptions, c: float) -> np.ndarray:
    """One-way ranges (m) the ``gated`` removal clears at the floor / ceiling delays: a static
    clean echo there (a wall parallel to the path at that range) is removed with them."""
    from mapping.recording._static import vertical_delays_s

    d = vertical_delays_s(options.sonar_height_m, options.ceiling_height_m,
                          options.transducer_offset_m, c, CFG.period_s)
    return np.asarray(d * c / 2.0)


def strongest_peaks(hm: HeatMap, n: int) -> np.ndarray:
    """(angle row, range column) of the ``n`` strongest local maxima beyond 0.3 m."""
    H = np.where(local_maxima(hm) & (hm.ranges_m[None] > 0.3), hm.H, 0.0)
    flat = np.argsort(H.ravel())[::-1][:n]
    return np.column_stack(np.unravel_index(flat, H.shape))


def clean_block(run: Run, k: int, raw: RawConfig) -> Run:
    """The clean run of the sonar samples imported block ``k`` holds (same speed of sound).

    Located by the block's start on the recording clock (``run.t_s``) and the simulator's
    true clock: the importer's own sonar clock may be a whole number of periods off when
    the recording starts after the playback (no silence before the onset: which period is
    the first is unobservable and harmless, blocks and poses are both read at ``t_s``)."""
    tau = run.t_s[k] / (1.0 + raw.clock_offset_ppm * 1e-6) - raw.latency_s
    s0 = int(round(tau * run.config.fs_hz))
    x = simulate_stretch(builtin_scene("shoebox"), builtin_path("shoebox-straight"),
                         run.config, s0, run.config.block_samples, ENGINE)
    return dataclasses.replace(run, samples=x[None].astype(np.float32), t_s=run.t_s[k:k + 1],
                               speed_m_s=run.speed_m_s[k:k + 1],
                               yaw_rate_rad_s=run.yaw_rate_rad_s[k:k + 1],
                               pose=run.pose[k:k + 1])


@pytest.mark.parametrize("effect", ["all", "latency+clock", "direct", "floor+ceiling", "bands",
                                    "temperature", "body"])
def test_heat_map_peaks_of_a_raw_recording_are_the_clean_runs(effect: str) -> None:
    """Each effect alone and all together (no noise): the 6 strongest peaks of the clean
    block's heat map have a peak of the imported block within one range bin and one angle
    row (but those in a floor / ceiling gate of ``gated``: a parallel wall 3.0 m away sits in
    the 2.9 m gate of the floor-ceiling-floor bounce on this path)."""
    raw = ALL if effect == "all" else {
        "latency+clock": RawConfig(latency_s=0.037, clock_offset_ppm=60.0,
                                   transducer_offset_m=0.05),
        "direct": RawConfig(transducer_offset_m=0.05),
        "floor+ceiling": RawConfig(transducer_offset_m=0.05, sonar_height_m=0.3,
                                   ceiling_height_m=2.6),
        "bands": RawConfig(transducer_offset_m=0.05, speaker_band_hz=(1_500.0, 18_000.0),
                           mic_band_hz=(50.0, 19_000.0)),
        "temperature": RawConfig(transducer_offset_m=0.05, temperature_c=22.0),
        "body": RawConfig(transducer_offset_m=0.05, body_echoes=((0.3, 0.3),)),
    }[effect]
    opts = dataclasses.replace(OPTIONS, temperature_c=raw.temperature_c)
    if raw.sonar_height_m is None:
        opts = dataclasses.replace(opts, sonar_height_m=None, ceiling_height_m=None)
    rec = recording(raw)
    run, _ = import_raw(rec.samples, rec.fs_hz, rec.poses, CFG, opts)
    assert run.n_blocks >= 5
    for k in (1, 4):
        clean = clean_block(run, k, raw)
        got = strongest_peaks(heatmap_of_run(run, k), 12)
        hm_clean = heatmap_of_run(clean, 0)
        want = strongest_peaks(hm_clean, 6)
        gates = gated_ranges_m(opts, run.config.sound_speed_m_s)
        half = 32 * run.config.range_per_sample_m  # GATE_SAMPLES of range
        for row, col in want:
            if np.any(np.abs(hm_clean.ranges_m[col] - gates) <= half):
                continue  # inside a floor / ceiling gate: removed by design (the trap)
            near = (np.abs(got[:, 0] - row) <= 1) & (np.abs(got[:, 1] - col) <= 1)
            assert near.any(), (effect, k, row, col, got)


def test_streamer_gives_the_batch_imports_blocks() -> None:
    """Pushed in uneven chunks, the streamer's blocks are the batch import's (same clock to
    within its warm-up fit, same static removal): within -40 dB, and none before the warm-up."""
    rec = recording()
    run, report = import_raw(rec.samples, rec.fs_hz, rec.poses, CFG, OPTIONS)
    streamer = RawStreamer(rec.fs_hz, CFG, OPTIONS, warmup_s=3.0)
    blocks, sizes = [], np.random.default_rng(0).integers(100, 9000, size=10_000)
    pos = 0
    for size in sizes:
        if pos >= rec.samples.size:
            break
        out = streamer.push(rec.samples[pos:pos + size])
        if pos + size < 3.0 * rec.fs_hz:
            assert out == []
        blocks += out
        pos += size
    assert streamer.fit is not None  # fitted on 3 s, the batch on all 7: same clock
    assert abs(streamer.fit.latency_s - report.latency_s) * ALL.fs_hz < 0.01
    assert abs(streamer.fit.clock_offset_ppm - report.clock_offset_ppm) < 0.5
    n = min(len(blocks), run.n_blocks)
    assert n >= run.n_blocks - 1 >= 4
    errs = []
    for b in blocks[:n]:
        ref = run.samples[b.index].astype(np.float64)
        errs.append(np.sum((b.samples - ref) ** 2) / np.sum(ref**2))
        assert b.start_rec_s == pytest.approx(run.t_s[b.index], abs=1e-6)
    # the static template from the periods so far (30 at block 0) instead of all 68: -20 dB
    # at the first block, better as the mean fills
    assert max(errs) < 1e-2 and errs[-1] < errs[0], errs


def test_streamer_refuses_a_stream_without_a_direct_wave_at_the_warm_up() -> None:
    """An accelerating robot's echo and no direct wave (the timing test's stream): refused
    when the warm-up ends, nothing handed out before."""
    from tests.mapping.recording.test_timing import _echo_only

    fs = 48_000.0
    t = np.arange(int(5.0 * fs)) / fs
    x = _echo_only(2.0 - 0.02 * t**2, fs, CFG)
    streamer = RawStreamer(fs, CFG, OPTIONS, warmup_s=3.0)
    for i in range(0, int(2.9 * fs), 4800):
        assert streamer.push(x[i:i + 4800]) == []
    with pytest.raises(ValueError, match="no direct path"):
        for i in range(int(2.9 * fs) // 4800 * 4800 + 4800, x.size, 4800):
            streamer.push(x[i:i + 4800])


def test_streamer_checks_its_inputs() -> None:
    with pytest.raises(ValueError, match="warmup_s"):
        RawStreamer(48_000.0, CFG, warmup_s=1.0)
    with pytest.raises(ValueError, match="sample rate"):
        RawStreamer(32_000.0, CFG)
    with pytest.raises(ValueError, match="calibration"):
        RawStreamer(48_000.0, CFG, RawImportOptions(static_removal="calibration"))
    streamer = RawStreamer(48_000.0, CFG)
    with pytest.raises(ValueError, match="NaN"):
        streamer.push(np.array([0.0, np.nan]))
