"""Raw recordings -> a run: timing, resampling, static removal, blocks (issue 16, item 1).

A raw recording is what a sound card gives: a mono stream at its own rate and clock, starting
an unknown time before playback, with the loudspeaker's direct wave and the static echoes in
it. :func:`import_raw` estimates the latency and clock offset from the direct path
(:mod:`mapping.recording._timing`), resamples the stream onto the sonar clock at the sonar rate
(:func:`mapping.resample.resample_at`), period-aligned as the shared conventions fix it
(block ``k`` starts at sonar time ``first_sample / fs + k B / fs``, ``first_sample`` a whole
number of periods after playback starts), removes the static part
(:mod:`mapping.recording._static`) and attaches odometry from the pose log at the blocks'
recording-clock times.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.recording._poses import PoseLog, block_odometry
from mapping.recording._static import (
    GATE_SAMPLES,
    align_template,
    direct_to_echo_db,
    gate_mask,
    gated_template,
    shift_periodic,
    suppression_db,
    vertical_delays_s,
)
from mapping.recording._timing import ON_SCORE, ClockFit, fit_clock
from mapping.resample import HALF_TAPS, resample_at, transition_width_hz
from mapping.run import Run
from mapping.signal import SonarConfig, sound_speed_at, tx_period

FloatArray = NDArray[np.float64]
StaticRemoval = Literal["run", "calibration", "gated"]

#: The static-removal methods, in the order the docs list them.
STATIC_REMOVAL_METHODS: tuple[str, ...] = ("run", "calibration", "gated")
#: Default loudspeaker-microphone distance in m (a small robot's transducers side by side).
DEFAULT_TRANSDUCER_OFFSET_M = 0.05
#: Suppression of the direct wave below which the report warns, dB.
MIN_SUPPRESSION_DB = 40.0


@dataclass(frozen=True)
class RawImportOptions:
    """How to import a raw recording.

    Parameters
    ----------
    transducer_offset_m : float
        Loudspeaker-microphone distance in m (> 0, < 1); the direct path takes ``offset / c``,
        so it sets the latency. Default 5 cm.
    static_removal : {"run", "calibration", "gated"}
        ``run``: subtract the whole run's periodic mean (everything static: also walls
        parallel to the path); ``calibration``: subtract the calibration recording's
        (needs one); ``gated``: only the direct path, the robot body (``near_range_m``) and,
        with heights, the floor/ceiling delays. Default ``gated``: it loses least
        (``benchmarks/raw_recordings.py``, 5 built-in scenes, every effect on, heights given:
        wall F1 0.92 and tracking 0.6 cm against the clean runs' 0.90 and 0.4 cm, where
        ``run`` lost the corridor's and the pillar room's straight runs, 1.6-2.1 m off, with
        their walls parallel to the path; ``calibration`` did best, 0.97 and 0.4 cm, but
        needs the extra recording).
    sonar_height_m, ceiling_height_m : float or None
        Heights above the floor of the sonar and of the ceiling (``gated``).
    near_range_m : float
        ``gated``: static echoes closer than this (robot body) are removed. Default 0.2 m.
    sound_speed_m_s, temperature_c : float or None
        Override the configuration's speed of sound, directly or from the air temperature
        (``331.3 sqrt(1 + T / 273.15)`` m/s); at most one.
    startup_periods : int
        Whole periods after playback starts that are dropped (>= 1; the start-up transient
        lasts one round trip). Default 1.
    min_peak_score : float
        A period carries the direct path when its correlation peak is at least this many RMS
        of its other lags. Default 10.
    """

    transducer_offset_m: float = DEFAULT_TRANSDUCER_OFFSET_M
    static_removal: StaticRemoval = "gated"
    sonar_height_m: float | None = None
    ceiling_height_m: float | None = None
    near_range_m: float = 0.2
    sound_speed_m_s: float | None = None
    temperature_c: float | None = None
    startup_periods: int = 1
    min_peak_score: float = ON_SCORE

    def __post_init__(self) -> None:
        _check_options(self)


def _check_options(o: RawImportOptions) -> None:
    """Raise ``ValueError`` naming the first invalid option."""
    if not 0 < o.transducer_offset_m < 1:
        raise ValueError(f"transducer_offset_m must lie in (0, 1) m, got {o.transducer_offset_m}")
    if o.static_removal not in STATIC_REMOVAL_METHODS:
        raise ValueError(f"static_removal must be one of {STATIC_REMOVAL_METHODS}, "
                         f"got {o.static_removal!r}")
    for name in ("sonar_height_m", "ceiling_height_m", "sound_speed_m_s"):
        v = getattr(o, name)
        if v is not None and not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a positive finite number, got {v}")
    if o.ceiling_height_m is not None and (o.sonar_height_m is None
                                           or o.sonar_height_m >= o.ceiling_height_m):
        raise ValueError("ceiling_height_m needs sonar_height_m below it, got "
                         f"sonar_height_m={o.sonar_height_m}, "
                         f"ceiling_height_m={o.ceiling_height_m}")
    if not 0 <= o.near_range_m < 5:
        raise ValueError(f"near_range_m must lie in [0, 5) m, got {o.near_range_m}")
    if o.temperature_c is not None and not -50 <= o.temperature_c <= 60:
        raise ValueError(f"temperature_c must lie in [-50, 60] deg C, got {o.temperature_c}")
    if o.temperature_c is not None and o.sound_speed_m_s is not None:
        raise ValueError("give sound_speed_m_s or temperature_c, not both")
    if not (isinstance(o.startup_periods, int) and o.startup_periods >= 1):
        raise ValueError(f"startup_periods must be an integer >= 1, got {o.startup_periods!r}")
    if not o.min_peak_score > 0:
        raise ValueError(f"min_peak_score must be > 0, got {o.min_peak_score}")


@dataclass(frozen=True)
class CalibrationFit:
    """How the calibration recording was matched to the run: its own timing, the gain and
    sub-sample shift (sonar samples) that align its static template to the run's."""

    latency_s: float
    clock_offset_ppm: float
    gain: float
    shift_samples: float
    periods: int


@dataclass(frozen=True)
class RawImportReport:
    """What :func:`import_raw` estimated and did (times on the recording clock unless said).

    ``latency_s`` / ``latency_samples``: first recorded sample to playback start (seconds of
    sonar time, recording samples); ``clock_offset_ppm``: recording clock rate error (> 0:
    fast); ``fit_residual_samples``: RMS of the per-period direct-path delays about the fitted
    line (recording samples); ``direct_to_echo_db``: direct wave power over everything else;
    ``direct_suppression_db``: direct wave energy before / after the static removal (a lower
    bound); ``onset_s``: arrival of the first direct wave; ``first_sample``: sonar sample of the
    first block's start (whole periods); ``blocks``; ``dropped_samples``: recording samples
    outside the blocks; ``method``: the static removal used.
    """

    fs_rec_hz: float
    latency_s: float
    latency_samples: float
    clock_offset_ppm: float
    fit_residual_samples: float
    periods_fitted: int
    direct_peak_db: float
    direct_to_echo_db: float
    direct_suppression_db: float
    onset_s: float
    first_sample: int
    blocks: int
    dropped_samples: int
    method: str
    sound_speed_m_s: float
    transducer_offset_m: float
    calibration: CalibrationFit | None
    warnings: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dictionary (infinities as None)."""
        d = asdict(self)
        d["warnings"] = list(self.warnings)
        for key, value in d.items():
            if isinstance(value, float) and not math.isfinite(value):
                d[key] = None
        return d


def find_clipping(x: FloatArray, full_scale: float | None = None) -> tuple[int, int, int]:
    """Clipped samples of a stream: ``(count, first, last)`` sample indices (count 0: none).

    With ``full_scale`` (the format's largest magnitude, e.g. 32767/32768 for 16-bit PCM), a
    sample at or above it is clipped; without, a run of 3 or more consecutive samples at the
    stream's largest magnitude is (a clean signal peaks in one sample).
    """
    mag = np.abs(x)
    if mag.size == 0:
        return 0, -1, -1
    level = float(mag.max()) if full_scale is None else float(full_scale)
    at = mag >= level * (1.0 - 1e-6)
    if full_scale is None:
        edges = np.diff(np.concatenate([[0], at.astype(np.int8), [0]]))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        long = (ends - starts) >= 3
        at = np.zeros_like(at)
        for s, e in zip(starts[long], ends[long], strict=True):
            at[s:e] = True
    idx = np.flatnonzero(at)
    if idx.size == 0:
        return 0, -1, -1
    return int(idx.size), int(idx[0]), int(idx[-1])


def _check_stream(x: FloatArray, fs_rec_hz: float, config: SonarConfig,
                  full_scale: float | None, what: str) -> None:
    """Refuse a stream that cannot be imported: rate, shape, non-finite, clipping, length."""
    if not (math.isfinite(fs_rec_hz) and config.fs_hz <= fs_rec_hz <= 768_000):
        raise ValueError(
            f"{what}: unsupported sample rate {fs_rec_hz:g} Hz: it must be at least the sonar "
            f"rate {config.fs_hz:g} Hz (the signal reaches "
            f"{config.carrier_hz + config.chip_rate_hz:g} Hz) and at most 768 kHz; record at "
            "44.1, 48 or 96 kHz"
        )
    if x.ndim != 1:
        raise ValueError(f"{what}: samples must be a 1-D (mono) stream, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{what}: samples contain NaN or inf")
    count, first, last = find_clipping(x, full_scale)
    if count:
        raise ValueError(
            f"{what}: clipping: {count} samples ({100.0 * count / x.size:.3g} %) at full scale, "
            f"from {first / fs_rec_hz:.3f} s to {last / fs_rec_hz:.3f} s; lower the playback "
            "volume or the microphone gain and record again"
        )


def _half_taps(fs_rec_hz: float, config: SonarConfig) -> int:
    """Resampler half length scaled with the input rate, so its transition band (and so the
    low-pass every rate goes through) is the same in Hz for every recording rate: a
    calibration at 48 kHz then matches a run at 44.1 kHz to the band edge."""
    return int(round(HALF_TAPS * fs_rec_hz / config.fs_hz))


def _resample_periods(x: FloatArray, fs_rec_hz: float, config: SonarConfig, fit: ClockFit,
                      first_sample: int, n_samples: int) -> FloatArray:
    """Sonar samples ``first_sample ..`` of the stream on the sonar clock (at recording time
    ``(j / fs + latency) (1 + e)``), band-limited below the sonar Nyquist frequency (the
    transition band ends there)."""
    e = fit.clock_offset_ppm * 1e-6
    j = first_sample + np.arange(n_samples, dtype=np.float64)
    t_rec = (j / config.fs_hz + fit.latency_s) * (1.0 + e)
    taps = _half_taps(fs_rec_hz, config)
    cutoff = 0.5 * config.fs_hz - 0.5 * transition_width_hz(fs_rec_hz, taps)
    return resample_at(x, fs_rec_hz, t_rec, cutoff, half_taps=taps)


def _usable_sonar_samples(x_size: int, fs_rec_hz: float, config: SonarConfig,
                          fit: ClockFit, chunk_end: int, first_sample: int) -> int:
    """Sonar samples from ``first_sample`` whose interpolation stays inside the stream (and
    before the end of playback, recording sample ``chunk_end``)."""
    e = fit.clock_offset_ppm * 1e-6
    n_end = min(x_size, chunk_end) - _half_taps(fs_rec_hz, config) - 1
    tau_end = n_end / (fs_rec_hz * (1.0 + e)) - fit.latency_s
    return max(int(math.floor(tau_end * config.fs_hz)) - first_sample, 0)


def aligned_stream(x: FloatArray, fs_rec_hz: float, config: SonarConfig,
                   options: RawImportOptions, sound_speed_m_s: float,
                   whole: int) -> tuple[ClockFit, int, FloatArray]:
    """Timing fit and the stream on the sonar clock, ``whole`` samples at a time.

    Returns ``(fit, first_sample, y)``: ``y`` starts at sonar sample ``first_sample``
    (``startup_periods`` periods after playback starts) and holds whole multiples of
    ``whole`` samples (a block for a run, a period for a calibration).

    Raises
    ------
    ValueError
        If no direct path is found or fewer than ``whole`` samples are usable (too short).
    """
    fit = fit_clock(x, fs_rec_hz, config, options.transducer_offset_m, sound_speed_m_s,
                    min_score=options.min_peak_score)
    first_sample = options.startup_periods * config.period_samples
    n = _usable_sonar_samples(x.size, fs_rec_hz, config, fit, fit.end_sample, first_sample)
    n_whole = n // whole
    if n_whole < 1:
        need_s = (first_sample + whole) / config.fs_hz + 2.0 * HALF_TAPS / config.fs_hz
        have_s = max(min(x.size, fit.end_sample) / fs_rec_hz - fit.onset_s, 0.0)
        raise ValueError(
            f"too short: needs at least {need_s:.2f} s of playback after it starts "
            f"({options.startup_periods} start-up period(s) + {whole / config.fs_hz:.3f} s), "
            f"the recording has {have_s:.2f} s after the onset at {fit.onset_s:.3f} s"
        )
    y = _resample_periods(x, fs_rec_hz, config, fit, first_sample, n_whole * whole)
    return fit, first_sample, y


def _static_template(periods: FloatArray, config: SonarConfig, options: RawImportOptions,
                     c: float, calibration: FloatArray | None
                     ) -> tuple[FloatArray, tuple[float, float] | None]:
    """The periodic part to subtract, and the calibration's (gain, shift) when used."""
    template = periods.mean(axis=0)
    s = tx_period(config)
    if options.static_removal == "run":
        return template, None
    if options.static_removal == "calibration":
        if calibration is None:
            raise ValueError("static_removal 'calibration' needs a calibration recording")
        direct = gate_mask(config.period_samples, np.zeros(0), GATE_SAMPLES,
                           options.transducer_offset_m / c * config.fs_hz)
        _, gain, shift = align_template(gated_template(template, s, direct),
                                        gated_template(calibration, s, direct))
        return gain * shift_periodic(calibration, shift), (gain, shift)
    near = (options.transducer_offset_m + 2.0 * options.near_range_m) / c * config.fs_hz
    vertical = vertical_delays_s(options.sonar_height_m, options.ceiling_height_m,
                                 options.transducer_offset_m, c, config.period_s)
    mask = gate_mask(config.period_samples, vertical * config.fs_hz, GATE_SAMPLES, near)
    return gated_template(template, s, mask), None


def _calibration_template(calibration: tuple[ArrayLike, float], config: SonarConfig,
                          options: RawImportOptions, c: float,
                          full_scale: float | None) -> tuple[FloatArray, ClockFit, int]:
    """Periodic mean of a calibration recording on the sonar clock, its fit, its periods."""
    xc = np.asarray(calibration[0], dtype=np.float64)
    fs_c = float(calibration[1])
    _check_stream(xc, fs_c, config, full_scale, "calibration")
    fit, _, y = aligned_stream(xc, fs_c, config, options, c, config.period_samples)
    periods = y.reshape(-1, config.period_samples)
    return periods.mean(axis=0), fit, periods.shape[0]


def import_raw(samples: ArrayLike, fs_hz: float, log: PoseLog, config: SonarConfig,
               options: RawImportOptions | None = None,
               calibration: tuple[ArrayLike, float] | None = None,
               full_scale: float | None = None) -> tuple[Run, RawImportReport]:
    """A run from a raw recording and its pose log (see the module docstring).

    Parameters
    ----------
    samples : array_like, shape (n,)
        The raw microphone stream, sample n at ``n / fs_hz`` on the recording clock.
    fs_hz : float
        Its rate in Hz (>= the sonar rate; 44.1, 48 or 96 kHz typically).
    log : PoseLog
        Poses with times on the recording clock (sample 0 at 0 s).
    config : SonarConfig
        The transmitted signal; its speed of sound unless ``options`` overrides it.
    options : RawImportOptions, optional
        Defaults: 5 cm transducer offset, ``run`` static removal.
    calibration : (samples, fs_hz), optional
        A calibration recording (standing still, or in the open), for
        ``static_removal="calibration"``.
    full_scale : float, optional
        The format's largest magnitude (from the WAV reader) for clipping detection; without
        it, flat runs at the stream's peak count as clipping.

    Returns
    -------
    (Run, RawImportReport)
        The run (``t_s``: block starts on the recording clock; ``meta["raw_import"]``: the
        report) and the report.

    Raises
    ------
    ValueError
        Unsupported rate, clipping (where, how much), no direct path, too short (how many
        seconds are needed), no block inside the pose log, invalid options.
    """
    opts = RawImportOptions() if options is None else options
    x = np.asarray(samples, dtype=np.float64)
    _check_stream(x, float(fs_hz), config, full_scale, "recording")
    c = _sound_speed(config, opts)
    cfg = replace(config, sound_speed_m_s=c)
    cal = None
    if opts.static_removal == "calibration":
        if calibration is None:
            raise ValueError("static_removal 'calibration' needs a calibration recording")
        cal = _calibration_template(calibration, cfg, opts, c, full_scale)
    fit, first_sample, y = aligned_stream(x, float(fs_hz), cfg, opts, c, cfg.block_samples)
    periods = y.reshape(-1, cfg.period_samples)
    template, cal_match = _static_template(periods, cfg, opts, c,
                                           None if cal is None else cal[0])
    cleaned = periods - template
    direct = gate_mask(cfg.period_samples, np.zeros(0), GATE_SAMPLES,
                       opts.transducer_offset_m / c * cfg.fs_hz)
    s = tx_period(cfg)
    blocks = cleaned.reshape(-1, cfg.block_samples)
    run, kept = _run_from_blocks(blocks, cfg, fit, first_sample, log, float(fs_hz))
    calibration_fit = None if cal is None or cal_match is None else CalibrationFit(
        latency_s=cal[1].latency_s, clock_offset_ppm=cal[1].clock_offset_ppm,
        gain=cal_match[0], shift_samples=cal_match[1], periods=cal[2])
    report = RawImportReport(
        fs_rec_hz=float(fs_hz), latency_s=fit.latency_s,
        latency_samples=fit.latency_s * fs_hz,
        clock_offset_ppm=fit.clock_offset_ppm, fit_residual_samples=fit.residual_samples,
        periods_fitted=fit.n_fitted, direct_peak_db=fit.score_db,
        direct_to_echo_db=direct_to_echo_db(periods, s, direct),
        direct_suppression_db=suppression_db(periods, cleaned, s, direct),
        onset_s=fit.onset_s, first_sample=int(first_sample + kept[0] * cfg.block_samples),
        blocks=run.n_blocks,
        dropped_samples=int(x.size - round(run.n_blocks * cfg.block_s * fs_hz
                                           * (1 + fit.clock_offset_ppm * 1e-6))),
        method=opts.static_removal, sound_speed_m_s=c,
        transducer_offset_m=opts.transducer_offset_m, calibration=calibration_fit,
        warnings=(),
    )
    report = replace(report, warnings=_warnings(report, opts, blocks.shape[0]))
    return replace(run, meta={**run.meta, "raw_import": report.to_dict(),
                              "raw_import_options": asdict(opts)}), report


def _sound_speed(config: SonarConfig, options: RawImportOptions) -> float:
    """The speed of sound to use: an override, from the temperature, or the config's."""
    if options.sound_speed_m_s is not None:
        return options.sound_speed_m_s
    if options.temperature_c is not None:
        return sound_speed_at(options.temperature_c)
    return config.sound_speed_m_s


def _run_from_blocks(blocks: FloatArray, config: SonarConfig, fit: ClockFit,
                     first_sample: int, log: PoseLog,
                     fs_rec_hz: float) -> tuple[Run, NDArray[np.int64]]:
    """The run of the blocks whose midpoints lie inside the pose log (recording clock)."""
    scale = 1.0 + fit.clock_offset_ppm * 1e-6
    k = np.arange(blocks.shape[0])
    start_tau = (first_sample + k * config.block_samples) / config.fs_hz
    start_rec = (start_tau + fit.latency_s) * scale
    block_rec = config.block_s * scale
    mid = start_rec + 0.5 * block_rec
    inside = np.flatnonzero((mid >= log.t_s[0]) & (mid <= log.t_s[-1]))
    if inside.size == 0:
        raise ValueError(
            f"no block lies inside the pose log: blocks span {start_rec[0]:.2f} .. "
            f"{start_rec[-1] + block_rec:.2f} s on the recording clock, the log "
            f"{log.t_s[0]:.2f} .. {log.t_s[-1]:.2f} s (pose times must be on the recording's "
            "clock, first sample = 0 s)"
        )
    kept = np.arange(inside[0], inside[-1] + 1)
    odo = block_odometry(log, kept.size, block_rec, start_rec[kept])
    run = Run(config=config, samples=blocks[kept].astype(np.float32), t_s=odo.t_s,
              speed_m_s=odo.speed_m_s, yaw_rate_rad_s=odo.yaw_rate_rad_s, pose=odo.pose,
              meta={"source": "import-run --raw"})
    return run, kept


def _warnings(report: RawImportReport, options: RawImportOptions,
              n_aligned_blocks: int) -> tuple[str, ...]:
    """Plain-language warnings about a report's numbers."""
    out = []
    if report.direct_suppression_db < MIN_SUPPRESSION_DB:
        out.append(f"the direct wave is suppressed by only {report.direct_suppression_db:.1f} dB "
                   f"(< {MIN_SUPPRESSION_DB:g} dB): it may show as a false echo near range 0")
    if report.fit_residual_samples > 0.05:
        out.append(f"the direct-path delays scatter by {report.fit_residual_samples:.3f} samples "
                   "about the fitted clock (> 0.05): a drifting clock or a moving microphone?")
    if abs(report.clock_offset_ppm) > 100:
        out.append(f"clock offset {report.clock_offset_ppm:.1f} ppm is unusually large")
    if report.blocks < n_aligned_blocks:
        out.append(f"{n_aligned_blocks - report.blocks} block(s) outside the pose log dropped")
    if options.static_removal == "gated" and options.sonar_height_m is None:
        out.append("gated removal without --sonar-height: floor/ceiling echoes are kept and may "
                   "show as walls at the sonar's height to each side")
    if options.static_removal == "run":
        out.append("static removal 'run' also removes walls at constant range (parallel to a "
                   "straight path); use 'gated' with heights, or 'calibration', to keep them")
    cal = report.calibration
    if cal is not None and not 0.5 <= cal.gain <= 2.0:
        out.append(f"the calibration's direct wave is {cal.gain:.2f} x the run's: was the volume "
                   "changed between the recordings?")
    return tuple(out)
