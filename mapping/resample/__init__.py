"""Band-limited resampling of a uniformly sampled stream at arbitrary output times.

A stream ``x`` sampled at ``fs_in_hz`` (sample ``n`` at time ``n / fs_in_hz``; samples outside
the array are zero) is evaluated at any times by a windowed-sinc low-pass interpolator,

    y(t) = sum_n x[n] h(t fs_in - n),
    h(u) = (2 f_cut / fs_in) sinc(2 f_cut u / fs_in) w(u / half_taps),   |u| <= half_taps,

with ``w`` the Kaiser window of shape ``kaiser_beta`` and ``2 half_taps`` taps per output.
``f_cut`` is the -6 dB point of the low-pass: below the output rate's Nyquist frequency when
going down in rate (anti-aliasing), at most the input's when going up. The response is flat
(ripple ~1e-4) below ``f_cut - width/2`` and attenuated by >= 60 dB (measured, tested) above
``f_cut + width/2``, ``width`` = :func:`transition_width_hz`. Used by the raw simulator
(:mod:`mapping.simulate.raw`) to go from the sonar clock to the sound card's, and by the raw
importer the other way.

Notes
-----
Private module: ``_kernels`` (the numba kernel; the kernel is tabulated 1024 times per
sample and linearly interpolated, error below 1e-6 of the input's amplitude per tap). Its
numpy twin, evaluating the window exactly, is ``tests/mapping/resample/naive.py``.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.resample._kernels import _resample

FloatArray = NDArray[np.float64]

#: Default half length of the windowed sinc (``2 * HALF_TAPS`` input samples per output).
HALF_TAPS = 64
#: Default Kaiser shape (about 80 dB of stop-band attenuation by Kaiser's formula).
KAISER_BETA = 8.0
#: Table points per input sample of the tabulated kernel.
OVERSAMPLE = 1024

__all__ = [
    "HALF_TAPS",
    "KAISER_BETA",
    "resample_at",
    "transition_width_hz",
]


def _kernel(u: ArrayLike, ratio: float, half_taps: int, kaiser_beta: float) -> FloatArray:
    """The interpolation kernel ``h(u)`` at distances ``u`` (input samples), exactly.

    Parameters
    ----------
    u : array_like
        Distances in input samples, any shape; zero where ``|u| > half_taps``.
    ratio : float
        ``2 f_cut / fs_in`` in (0, 1].
    half_taps, kaiser_beta : int, float
        Half length and Kaiser shape of the window.
    """
    u = np.asarray(u, dtype=np.float64)
    r = np.clip(u / half_taps, -1.0, 1.0)
    window = np.i0(kaiser_beta * np.sqrt(1.0 - r * r)) / np.i0(kaiser_beta)
    h = ratio * np.sinc(ratio * u) * window
    return np.where(np.abs(u) <= half_taps, h, 0.0)


@lru_cache(maxsize=32)
def _table(ratio: float, half_taps: int, kaiser_beta: float) -> FloatArray:
    """``_kernel`` at distances ``k / OVERSAMPLE`` for k = 0 .. half_taps * OVERSAMPLE, plus
    one trailing zero (so the kernel's linear interpolation never reads past the end)."""
    u = np.arange(half_taps * OVERSAMPLE + 1) / OVERSAMPLE
    table = np.concatenate([_kernel(u, ratio, half_taps, kaiser_beta), [0.0]])
    table.setflags(write=False)
    return table


def transition_width_hz(
    fs_in_hz: float, half_taps: int = HALF_TAPS, kaiser_beta: float = KAISER_BETA
) -> float:
    """Width of the transition band around ``cutoff_hz`` (Kaiser's design formula), Hz.

    The attenuation ``A = kaiser_beta / 0.1102 + 8.7`` dB is reached ``width / 2`` above the
    cutoff with ``width = fs_in (A - 7.95) / (2.285 * 2 pi * 2 half_taps)``.
    """
    attenuation_db = kaiser_beta / 0.1102 + 8.7
    return float(fs_in_hz * (attenuation_db - 7.95) / (2.285 * 2.0 * math.pi * 2 * half_taps))


def _check(fs_in_hz: float, cutoff_hz: float, half_taps: int, kaiser_beta: float) -> None:
    """Raise ``ValueError`` naming the first invalid scalar parameter of :func:`resample_at`."""
    if not (isinstance(fs_in_hz, int | float) and math.isfinite(fs_in_hz) and fs_in_hz > 0):
        raise ValueError(f"fs_in_hz must be a positive finite number, got {fs_in_hz!r}")
    if not (isinstance(cutoff_hz, int | float) and 0 < cutoff_hz <= fs_in_hz / 2):
        raise ValueError(
            f"cutoff_hz must lie in (0, fs_in_hz / 2 = {fs_in_hz / 2:g}] Hz, got {cutoff_hz!r}"
        )
    if not (isinstance(half_taps, int | np.integer) and 2 <= half_taps <= 1024):
        raise ValueError(f"half_taps must be an integer in 2..1024, got {half_taps!r}")
    if not (isinstance(kaiser_beta, int | float) and 0 <= kaiser_beta <= 30):
        raise ValueError(f"kaiser_beta must lie in [0, 30], got {kaiser_beta!r}")


def resample_at(
    x: ArrayLike,
    fs_in_hz: float,
    t_out_s: ArrayLike,
    cutoff_hz: float,
    half_taps: int = HALF_TAPS,
    kaiser_beta: float = KAISER_BETA,
) -> FloatArray:
    """Values of the low-passed stream ``x`` at times ``t_out_s``.

    Parameters
    ----------
    x : array_like, shape (n,)
        The input stream, sample ``n`` at time ``n / fs_in_hz`` s; zero outside the array.
    fs_in_hz : float
        Input sampling rate in Hz.
    t_out_s : array_like
        Output times in seconds, any shape, finite (time 0 = sample 0 of ``x``).
    cutoff_hz : float
        -6 dB frequency of the low-pass in Hz, in (0, fs_in_hz / 2]. With
        ``cutoff_hz = fs_in_hz / 2`` and output times on the input grid, the output is ``x``.
    half_taps : int
        Half length of the windowed sinc in input samples (2..1024).
    kaiser_beta : float
        Kaiser window shape in [0, 30]; larger: more stop-band attenuation, wider transition.

    Returns
    -------
    numpy.ndarray
        float64, the shape of ``t_out_s``.

    Raises
    ------
    ValueError
        Naming the parameter when ``x`` is not 1-D finite, ``t_out_s`` not finite, or a
        scalar is out of its range.
    """
    _check(fs_in_hz, cutoff_hz, half_taps, kaiser_beta)
    xs = np.ascontiguousarray(x, dtype=np.float64)
    if xs.ndim != 1:
        raise ValueError(f"x must be 1-D, got shape {xs.shape}")
    if not np.all(np.isfinite(xs)):
        raise ValueError("x must be finite (no NaN or inf)")
    t = np.asarray(t_out_s, dtype=np.float64)
    if not np.all(np.isfinite(t)):
        raise ValueError("t_out_s must be finite (no NaN or inf)")
    # positions in input samples; beyond the reach of the kernel the output is 0 anyway
    pos = np.clip(t.ravel() * fs_in_hz, -half_taps - 2.0, xs.size + half_taps + 2.0)
    out = np.zeros(pos.size)
    if xs.size:
        table = _table(2.0 * cutoff_hz / fs_in_hz, int(half_taps), float(kaiser_beta))
        _resample(xs, np.ascontiguousarray(pos), table, OVERSAMPLE, int(half_taps), out)
    return out.reshape(t.shape)
