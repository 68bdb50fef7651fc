"""Timing of a raw recording from its direct path: latency and clock offset (issue 16).

Conventions (shared with :mod:`mapping.simulate.raw`): recording sample ``n`` (rate
``fs_rec``) is taken at sonar time ``tau_n = n / (fs_rec (1 + e)) - latency_s`` with
``e = clock_offset_ppm * 1e-6``; the loudspeaker is silent before ``tau = 0``; the direct wave
reaches the microphone ``offset / c`` later, without Doppler. So at recording time
``t = n / fs_rec`` the direct wave is the transmitted signal delayed by

    D(t) = latency_s + offset / c + t e / (1 + e),

a straight line in ``t``. Each transmission period of the stream (``P / fs`` s, cut on the
recording's nominal grid) is correlated with the transmitted signal evaluated at the
recording's sample times (:func:`mapping.signal.transmitted_at`); the correlation peak gives
``D`` modulo one period, refined below a sample by evaluating the correlation at fractional
lags. Periods whose peak stands out of the correlation's other lags are "on"; a line fitted
to their unwrapped peaks gives the slope ``e / (1 + e)`` and ``D`` modulo the period; the
playback onset (silence before, signal after) picks the whole number of periods.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mapping.signal import SonarConfig, transmitted_at

FloatArray = NDArray[np.float64]

#: A period is "on" when its correlation peak exceeds this many RMS of its other lags (noise
#: alone gives about 4 over the ~4500 lags of a period).
ON_SCORE = 10.0
#: Largest RMS scatter (recording samples) of the per-period direct-path delays about the
#: clock line before the stream is refused as having no direct path. A direct wave scatters by
#: ~0.001-0.02 samples (noise, band-passes); the strongest echo of a moving robot, mistaken
#: for it, by hundreds (measured: 288 samples on shoebox-straight without a direct wave).
MAX_SCATTER_SAMPLES = 2.0
#: Largest clock offset (ppm) taken as a sound card's (they are within +-100 ppm); a larger
#: drift of the strongest arrival is an echo of a moving robot (0.1 m/s towards a wall drifts
#: like 588 ppm, at 70 deg off the wall's normal like 200).
MAX_CLOCK_PPM = 200.0
#: Periods of the stream correlated per FFT batch (memory bound).
_BATCH = 32


@dataclass(frozen=True)
class PeriodPeaks:
    """Direct-path peaks per period of the raw stream (all arrays (n_periods,)).

    ``center_s``: chunk centres on the recording's clock; ``lag_samples``: peak lag in
    recording samples (modulo one period, sub-sample); ``score``: peak over the RMS of the
    other lags; ``chunk_samples``: recording samples per chunk.
    """

    center_s: FloatArray
    lag_samples: FloatArray
    score: FloatArray
    chunk_samples: int


@dataclass(frozen=True)
class ClockFit:
    """Latency and clock offset of a raw recording (see the module docstring).

    ``latency_s``: first recorded sample to playback start; ``clock_offset_ppm``: positive
    when the recording clock runs fast; ``residual_samples``: RMS of the fitted periods'
    peaks about the line (recording samples); ``onset_s``: the direct wave's arrival on the
    recording clock; ``first_period``/``last_period``: the chunk range that was fitted;
    ``n_fitted``: periods kept by the fit; ``score_db``: median peak score of the fitted
    periods in dB; ``end_sample``: recording sample up to which playback is certain (the
    stream's end, or the start of the last period that still carries the direct path).
    """

    latency_s: float
    clock_offset_ppm: float
    residual_samples: float
    onset_s: float
    first_period: int
    last_period: int
    n_fitted: int
    score_db: float
    end_sample: int


def _reference(start: int, n: int, fs_rec_hz: float, config: SonarConfig) -> FloatArray:
    """The transmitted signal at recording samples ``start .. start + n - 1`` (nominal clock)."""
    return transmitted_at((start + np.arange(n)) / fs_rec_hz, config)


def _corr_at(x: FloatArray, start: int, lag: FloatArray, fs_rec_hz: float,
             config: SonarConfig) -> FloatArray:
    """Correlation ``sum_n x[n] s((start + n - lag) / fs_rec)`` at fractional lags (samples)."""
    n = start + np.arange(x.size)
    t = (n[None, :] - np.asarray(lag)[:, None]) / fs_rec_hz
    return np.asarray(transmitted_at(t, config) @ x)


def _refine(x: FloatArray, start: int, lag0: float, fs_rec_hz: float,
            config: SonarConfig) -> float:
    """Sub-sample peak of the correlation near integer lag ``lag0``: two parabolic steps
    through fractional lags (+-0.5, then +-0.05 samples)."""
    lag = float(lag0)
    for h in (0.5, 0.05):
        c = _corr_at(x, start, np.array([lag - h, lag, lag + h]), fs_rec_hz, config)
        curv = c[0] - 2.0 * c[1] + c[2]
        if curv < 0:
            lag += float(np.clip(0.5 * h * (c[0] - c[2]) / curv, -h, h))
    return lag


def period_peaks(x: FloatArray, fs_rec_hz: float, config: SonarConfig) -> PeriodPeaks:
    """Direct-path correlation peak of every whole transmission period of ``x``.

    Parameters
    ----------
    x : numpy.ndarray, shape (n,)
        The raw stream at ``fs_rec_hz``, polarity as recorded.
    fs_rec_hz : float
        Recording rate in Hz.
    config : SonarConfig
        The transmitted signal.

    Returns
    -------
    PeriodPeaks
        One row per chunk of ``floor(P fs_rec / fs)`` samples.
    """
    period_rec = config.period_s * fs_rec_hz
    n_chunk = int(math.floor(period_rec))
    n_lag = int(math.ceil(period_rec)) + 2
    n_periods = x.size // n_chunk
    nfft = 1 << int(math.ceil(math.log2(n_chunk + n_lag)))
    lag = np.empty(n_periods)
    score = np.empty(n_periods)
    for b0 in range(0, n_periods, _BATCH):
        ks = np.arange(b0, min(b0 + _BATCH, n_periods))
        starts = ks * n_chunk
        chunks = np.stack([x[s:s + n_chunk] for s in starts])
        refs = np.stack([_reference(int(s) - n_lag, n_chunk + n_lag, fs_rec_hz, config)
                         for s in starts])
        # corr[m] = sum_n ref[n + m] chunk[n]; lag l = n_lag - m
        spec = np.fft.rfft(refs, nfft) * np.conj(np.fft.rfft(chunks, nfft))
        corr = np.fft.irfft(spec, nfft)[:, : n_lag + 1][:, ::-1]  # index = lag l
        valid = corr[:, : int(math.floor(period_rec)) + 1]
        peak = np.argmax(valid, axis=1)
        for i, k in enumerate(ks):
            score[k] = _peak_score(valid[i], int(peak[i]))
            lag[k] = _refine(chunks[i], int(starts[i]), float(peak[i]), fs_rec_hz, config)
    centers = np.asarray((np.arange(n_periods) * n_chunk + 0.5 * (n_chunk - 1)) / fs_rec_hz,
                         dtype=np.float64)
    return PeriodPeaks(center_s=centers, lag_samples=lag, score=score, chunk_samples=n_chunk)


def _peak_score(corr: FloatArray, peak: int, guard: int = 16) -> float:
    """Peak value over the RMS of the correlation away from the peak (circular guard)."""
    idx = np.arange(corr.size)
    far = np.abs((idx - peak + corr.size // 2) % corr.size - corr.size // 2) > guard
    rms = math.sqrt(float(np.mean(corr[far] ** 2))) if far.any() else 0.0
    return float(corr[peak] / rms) if rms > 0 else 0.0


def on_span(score: FloatArray, min_score: float = ON_SCORE) -> tuple[int, int]:
    """First and last period (inclusive) of the first contiguous run of "on" periods.

    Raises
    ------
    ValueError
        If no period's direct-path peak stands out (no direct path found).
    """
    on = score >= min_score
    if not on.any():
        best = float(score.max()) if score.size else 0.0
        raise ValueError(
            "no direct path found: no transmission period's correlation peak stands out of "
            f"the noise (best peak {best:.1f} x the RMS of the other lags, need {min_score:g}); "
            "is the loudspeaker audible to the microphone and the signal the configured one?"
        )
    first = int(np.argmax(on))
    off = np.flatnonzero(~on[first:])
    last = first + (int(off[0]) - 1 if off.size else int(on.size - first - 1))
    return first, last


def fit_line(t_s: FloatArray, d_samples: FloatArray) -> tuple[float, float, FloatArray]:
    """Least-squares line ``d = a + b t`` with two passes of outlier rejection (> 5 robust
    sigma); returns ``(a, b, kept)`` with ``kept`` a boolean mask."""
    kept = np.ones(t_s.size, dtype=bool)
    a = b = 0.0
    for _ in range(3):
        b, a = np.polyfit(t_s[kept], d_samples[kept], 1)
        r = d_samples - (a + b * t_s)
        sigma = max(1.4826 * float(np.median(np.abs(r[kept]))), 1e-4)
        new = np.abs(r) <= 5.0 * sigma
        if new.sum() < 2 or np.array_equal(new, kept):
            break
        kept = new
    return float(a), float(b), kept


def onset_periods(x: FloatArray, onset_candidates: FloatArray, window: int) -> int:
    """Index of the candidate onset sample with the largest power ratio after/before it.

    Candidates are the direct wave's arrival for successive whole numbers of periods; only
    the true one has silence (noise) before it and signal after.
    """
    best, best_ratio = 0, -1.0
    for i, n in enumerate(np.round(onset_candidates).astype(np.int64)):
        before = x[max(n - window, 0):max(n, 0)]
        after = x[max(n, 0):n + window]
        if after.size < window // 2:
            continue
        p_before = float(np.mean(before ** 2)) if before.size else 0.0
        ratio = float(np.mean(after ** 2)) / max(p_before, 1e-300)
        if ratio > best_ratio:
            best, best_ratio = i, ratio
    return best


def fit_clock(x: FloatArray, fs_rec_hz: float, config: SonarConfig,
              transducer_offset_m: float, sound_speed_m_s: float,
              min_score: float = ON_SCORE) -> ClockFit:
    """Latency and clock offset of raw stream ``x`` from its direct path.

    Parameters
    ----------
    x : numpy.ndarray, shape (n,)
        The raw stream, sample n at ``n / fs_rec_hz`` on the recording clock.
    fs_rec_hz : float
        Recording rate in Hz.
    config : SonarConfig
        The transmitted signal.
    transducer_offset_m : float
        Loudspeaker-microphone distance (the direct path takes ``offset / c``).
    sound_speed_m_s : float
        Speed of sound c in m/s.
    min_score : float
        A period carries the direct path when its peak is this many RMS of its other lags.

    Returns
    -------
    ClockFit

    Raises
    ------
    ValueError
        If no direct path is found, or fewer than 3 periods carry it.
    """
    peaks = period_peaks(x, fs_rec_hz, config)
    first, last = on_span(peaks.score, min_score)
    # leave out the periods straddling the onset and the end of playback
    lo, hi = first + 1, last - 1 if last + 1 < peaks.score.size else last
    if hi - lo + 1 < 3:
        raise ValueError(
            f"the direct path is heard in only {last - first + 1} transmission period(s) "
            f"({(last - first + 1) * config.period_s:.2f} s); need at least 5"
        )
    period_rec = config.period_s * fs_rec_hz
    d = np.unwrap(peaks.lag_samples[lo:hi + 1], period=period_rec)
    t = peaks.center_s[lo:hi + 1]
    a, b, kept = fit_line(t, d)
    resid = d - (a + b * t)
    scatter = float(np.sqrt(np.mean(resid[kept] ** 2)))
    if scatter > MAX_SCATTER_SAMPLES or kept.sum() < 0.5 * kept.size:
        raise ValueError(
            f"no direct path: the strongest arrival of each period is not on one clock line "
            f"(RMS {scatter:.2f} samples about the best fit, {int(kept.sum())} of "
            f"{kept.size} periods on it; a direct wave rides with the robot and stays within "
            f"~0.05 samples) - the microphone must hear the loudspeaker directly (both on "
            f"the robot, a few cm apart); an echo of a moving robot is not a clock reference"
        )
    e = b / fs_rec_hz / (1.0 - b / fs_rec_hz)  # slope in s/s = e / (1 + e)
    if abs(e) * 1e6 > MAX_CLOCK_PPM:
        raise ValueError(
            f"no direct path: the strongest arrival drifts as a clock {e * 1e6:+.0f} ppm off, "
            f"beyond any sound card (+-{MAX_CLOCK_PPM:.0f} ppm) - an echo of a robot moving "
            f"at {abs(e) * sound_speed_m_s / 2:.3f} m/s, not the direct wave?"
        )
    # the true intercept (latency + offset / c) is a / fs_rec + m periods, m >= 0
    m0 = math.ceil(-a / period_rec)  # the first whole period with a non-negative arrival
    m = m0 + np.arange(int((first + 2) * peaks.chunk_samples / period_rec) + 2)
    arrival = (a / fs_rec_hz + m * config.period_s) * (1.0 + e)  # recording clock, s
    window = max(int(0.5 * period_rec), 8)
    i = onset_periods(x, np.asarray(arrival * fs_rec_hz, dtype=np.float64), window)
    latency = arrival[i] / (1.0 + e) - transducer_offset_m / sound_speed_m_s
    return ClockFit(
        latency_s=float(latency), clock_offset_ppm=float(e * 1e6),
        residual_samples=scatter,
        onset_s=float(arrival[i]), first_period=lo, last_period=hi,
        n_fitted=int(kept.sum()),
        score_db=float(20.0 * np.log10(np.median(peaks.score[lo:hi + 1]))),
        end_sample=x.size if last + 1 == peaks.score.size else last * peaks.chunk_samples,
    )
