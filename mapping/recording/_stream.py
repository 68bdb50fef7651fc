"""Raw import while recording: sound-card chunks in, sonar blocks out (issue 16, item 4).

:func:`~mapping.recording.import_raw` needs the whole recording; a robot streaming to the
localization service has only what it has heard so far. :class:`RawStreamer` holds the raw
samples as they arrive (``push``) and hands out each sonar block as soon as the samples its
resampling needs are in:

1. **warm-up**: until ``warmup_s`` of playback are recorded, nothing comes out; then the
   clock (latency, rate offset) is fitted on the direct path of what is there
   (:func:`~mapping.recording.fit_clock`), once - the offset of a sound card does not change
   within a run (a drifting one shows in the final report's fit, not here);
2. **blocks**: block k covers sonar samples ``first_sample + k B ..`` (period-aligned, one
   start-up period after the onset, as the batch import), resampled onto the sonar clock;
3. **static removal**: the periodic mean of every period resampled so far (warm-up
   included) stands in for the whole run's: ``run`` subtracts it, ``gated`` only its part at
   the direct path / robot body and the floor and ceiling delays, ``calibration`` the
   calibration recording's (fitted once at the first block). The first blocks of ``run``
   remove less cleanly than the batch import (fewer periods in the mean); ``gated`` and
   ``calibration`` do not depend on that.

Memory: raw samples no longer needed by any later block are dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.recording._raw import (
    RawImportOptions,
    _calibration_template,
    _check_stream,
    _half_taps,
    _resample_periods,
    _sound_speed,
    _static_template,
)
from mapping.recording._timing import ClockFit, fit_clock
from mapping.signal import SonarConfig

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class StreamBlock:
    """One sonar block cut from the stream.

    Attributes
    ----------
    index : int
        Block number k (0 = the first after the start-up period).
    samples : ndarray, float64 (B,)
        The block on the sonar clock, static part removed.
    start_rec_s, duration_rec_s : float
        Its start and length on the recording clock (where the pose log is read).
    """

    index: int
    samples: FloatArray
    start_rec_s: float
    duration_rec_s: float


class RawStreamer:
    """Cut a raw recording into sonar blocks as it arrives (see the module docstring).

    Parameters
    ----------
    fs_hz : float
        The recording's rate (>= the sonar rate).
    config : SonarConfig
    options : RawImportOptions, optional
    calibration : (samples, fs_hz), optional
        For ``static_removal="calibration"``.
    warmup_s : float
        Seconds of recording before the clock is fitted (>= 2; 3 s hold ~30 periods).
    """

    def __init__(self, fs_hz: float, config: SonarConfig,
                 options: RawImportOptions | None = None,
                 calibration: tuple[ArrayLike, float] | None = None,
                 warmup_s: float = 3.0) -> None:
        if not (math.isfinite(warmup_s) and 2.0 <= warmup_s <= 60.0):
            raise ValueError(f"warmup_s must be in [2, 60] s, got {warmup_s!r}")
        self.options = RawImportOptions() if options is None else options
        c = _sound_speed(config, self.options)
        self.config = replace(config, sound_speed_m_s=c)
        self.fs_hz = float(fs_hz)
        _check_stream(np.zeros(1), self.fs_hz, self.config, None, "stream")
        self.warmup_s = float(warmup_s)
        self.fit: ClockFit | None = None
        self._cal: FloatArray | None = None
        if self.options.static_removal == "calibration":
            if calibration is None:
                raise ValueError("static_removal 'calibration' needs a calibration recording")
            self._cal = _calibration_template(calibration, self.config, self.options, c,
                                              None)[0]
        self._buf = np.zeros(0)
        self._buf_start = 0          # recording index of self._buf[0]
        self._next = 0               # next block index
        self._first_sample = self.options.startup_periods * self.config.period_samples
        self._period_sum = np.zeros(self.config.period_samples)
        self._periods = 0
        self._warm_count = 0

    @property
    def received(self) -> int:
        """Recording samples pushed so far."""
        return self._buf_start + self._buf.size

    def push(self, chunk: ArrayLike) -> list[StreamBlock]:
        """Add recorded samples; return the blocks that became complete (maybe none).

        Raises
        ------
        ValueError
            Non-finite samples; at the end of the warm-up: no direct path (see
            :func:`~mapping.recording.fit_clock`).
        """
        x = np.asarray(chunk, dtype=np.float64).ravel()
        if not np.all(np.isfinite(x)):
            raise ValueError("chunk contains NaN or inf")
        self._buf = np.concatenate([self._buf, x])
        if self.fit is None:
            if self.received < self.warmup_s * self.fs_hz:
                return []
            self.fit = fit_clock(self._buf, self.fs_hz, self.config,
                                 self.options.transducer_offset_m,
                                 self.config.sound_speed_m_s, self.options.min_peak_score)
            self._warm_periods()
        out = []
        while self._ready(self._next):
            out.append(self._block(self._next))
            self._next += 1
        self._trim()
        return out

    # ---- internals ---------------------------------------------------------------------
    def _rec_index(self, sonar_sample: float) -> float:
        """Recording index (fractional) of sonar sample ``sonar_sample``."""
        assert self.fit is not None
        e = self.fit.clock_offset_ppm * 1e-6
        return (sonar_sample / self.config.fs_hz + self.fit.latency_s) * (1 + e) * self.fs_hz

    def _ready(self, k: int) -> bool:
        end = self._first_sample + (k + 1) * self.config.block_samples
        need = self._rec_index(end) + _half_taps(self.fs_hz, self.config) + 1
        return self.received >= need

    def _resampled(self, first: int, n: int) -> FloatArray:
        """Sonar samples ``first .. first + n - 1`` from the buffer."""
        assert self.fit is not None
        shifted = replace(self.fit, latency_s=self.fit.latency_s
                          - self._buf_start / self.fs_hz / (1 + self.fit.clock_offset_ppm * 1e-6))
        return _resample_periods(self._buf, self.fs_hz, self.config, shifted, first, n)

    def _warm_periods(self) -> None:
        """Fold the whole periods of the warm-up into the periodic mean."""
        p = self.config.period_samples
        n = 0
        while self.received >= self._rec_index(self._first_sample + (n + 1) * p) \
                + _half_taps(self.fs_hz, self.config) + 1:
            n += 1
        if n:
            y = self._resampled(self._first_sample, n * p).reshape(n, p)
            self._period_sum += y.sum(axis=0)
            self._periods += n
        self._warm_count = n

    def _block(self, k: int) -> StreamBlock:
        cfg = self.config
        p, b = cfg.period_samples, cfg.block_samples
        first = self._first_sample + k * b
        y = self._resampled(first, b).reshape(-1, p)
        # periods of this block not yet in the mean (the warm-up folded in the first ones)
        done = max(self._warm_count - k * cfg.repetitions, 0)
        new = y[min(done, y.shape[0]):]
        self._period_sum += new.sum(axis=0)
        self._periods += new.shape[0]
        template, _ = _static_template(self._period_sum[None] / self._periods, cfg,
                                       self.options, cfg.sound_speed_m_s, self._cal)
        assert self.fit is not None
        scale = 1.0 + self.fit.clock_offset_ppm * 1e-6
        start = (first / cfg.fs_hz + self.fit.latency_s) * scale
        return StreamBlock(index=k, samples=(y - template).reshape(-1), start_rec_s=start,
                           duration_rec_s=cfg.block_s * scale)

    def _trim(self) -> None:
        """Drop raw samples no later block needs."""
        if self.fit is None:
            return
        start = self._first_sample + self._next * self.config.block_samples
        keep_from = int(self._rec_index(start)) - _half_taps(self.fs_hz, self.config) - 2
        drop = keep_from - self._buf_start
        if drop > 0:
            self._buf = self._buf[drop:]
            self._buf_start += drop
