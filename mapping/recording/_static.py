"""Removing the direct wave and the static echoes of an aligned stream (issue 16).

Input: the stream at the sonar rate on the sonar clock, cut into whole transmission periods
``y`` (n_periods, P). What does not move with respect to the robot (the direct wave, the
robot's body, the floor and ceiling, and - the trap - a wall parallel to the path, at constant
range) repeats every period; its periodic mean ``T`` (P,) is the transmitted period circularly
convolved with a static impulse response ``h``. Three ways to remove it:

- ``run``: subtract ``T`` of the whole run: everything static goes, parallel walls too;
- ``calibration``: subtract ``T`` of a calibration recording (standing still, or in the open),
  aligned to the run's ``T`` in gain and sub-sample delay (two recordings' latencies differ);
  what the calibration did not hear (walls) stays;
- ``gated``: subtract only the part of ``T`` whose delay cannot be a wall's: ``h`` is estimated
  by regularized deconvolution; what it holds outside the near region (direct path and robot
  body, up to ``near_range_m``) and the floor / ceiling delays (when their heights are known)
  is convolved back with the transmitted period and kept, the rest of ``T`` is removed.

The direct wave's suppression is measured the same way for every method: the energy of the
per-period impulse responses inside the direct-path gate before and after removal.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

#: Regularization of the deconvolution, relative to the peak of |S|^2.
_REGULARIZATION = 1e-3
#: Half width in sonar samples of a gate around a delay. The signal fills the band up to the
#: sonar Nyquist frequency, so a reflector's impulse response is sinc-like with tails falling
#: as 1/lag: +-32 samples (0.8 ms, 13.6 cm of range at 40 kHz) hold all but -66 dB of a
#: direct wave's energy (+-8: -50 dB; measured on the resampled signal).
GATE_SAMPLES = 32


def deconvolve(periods: FloatArray, tx_period: FloatArray) -> FloatArray:
    """Impulse responses ``h`` (..., P) with ``periods ~= h (*) tx_period`` (circular),
    by regularized spectral division (Tikhonov, ``1e-3`` of the peak of |S|^2)."""
    s = np.fft.rfft(tx_period)
    power = np.abs(s) ** 2
    inverse = np.conj(s) / (power + _REGULARIZATION * power.max())
    return np.fft.irfft(np.fft.rfft(periods, axis=-1) * inverse, n=tx_period.size, axis=-1)


def convolve(h: FloatArray, tx_period: FloatArray) -> FloatArray:
    """Circular convolution ``h (*) tx_period`` (..., P)."""
    return np.fft.irfft(np.fft.rfft(h, axis=-1) * np.fft.rfft(tx_period), n=tx_period.size,
                        axis=-1)


def gate_mask(n: int, delays_samples: FloatArray, half_width: float,
              near_samples: float = 0.0) -> NDArray[np.bool_]:
    """Boolean mask (n,) of circular lags within ``half_width`` of any of ``delays_samples``,
    plus the near region ``[-half_width, near_samples + half_width]``."""
    lag = np.arange(n, dtype=np.float64)
    signed = (lag + n / 2) % n - n / 2
    mask = (signed >= -half_width) & (signed <= near_samples + half_width)
    for d in np.atleast_1d(delays_samples):
        mask |= np.abs((lag - d + n / 2) % n - n / 2) <= half_width
    return mask


def vertical_delays_s(sonar_height_m: float | None, ceiling_height_m: float | None,
                      transducer_offset_m: float, c: float, max_delay_s: float) -> FloatArray:
    """Delays of the pure vertical bounces below ``max_delay_s``: ``sqrt(dz^2 + offset^2) / c``
    for the vertical image offsets ``dz`` of a sonar at ``h`` between a floor at 0 and a
    ceiling at ``H`` with up to three bounces (2h, 2(H - h), 2H, 2h + 2H, 2(H - h) + 2H, 4H);
    only 2h without a ceiling."""
    h, big_h = sonar_height_m, ceiling_height_m
    dz: list[float] = []
    if h is not None and big_h is None:
        dz = [2.0 * h]
    elif big_h is not None:
        if h is None:
            raise ValueError("ceiling_height_m needs sonar_height_m (the sonar's height)")
        for m in range(2):  # up to two vertical bounces; higher orders are weak
            dz += [2.0 * h + 2.0 * m * big_h, 2.0 * (big_h - h) + 2.0 * m * big_h,
                   2.0 * (m + 1) * big_h]
    d = np.sqrt(np.asarray(dz) ** 2 + transducer_offset_m ** 2) / c
    return np.unique(d[d < max_delay_s])


def gated_template(template: FloatArray, tx_period: FloatArray,
                   mask: NDArray[np.bool_]) -> FloatArray:
    """The part of a periodic template to remove: all of it but what its impulse response
    holds outside ``mask`` (so the band edges the deconvolution cannot see go too)."""
    outside = convolve(deconvolve(template, tx_period) * ~mask, tx_period)
    return np.asarray(template - outside)


def align_template(reference: FloatArray, template: FloatArray) -> tuple[FloatArray, float, float]:
    """``template`` circularly shifted by a sub-sample delay and scaled to best match
    ``reference`` (least squares); returns ``(aligned, gain, shift_samples)``.

    The shift maximizes the band-limited cross-correlation (integer peak, then Newton steps
    on its phase-ramp form); the gain is then the least-squares scale.
    """
    n = reference.size
    r, t = np.fft.rfft(reference), np.fft.rfft(template)
    cross = r * np.conj(t)
    shift = float(np.argmax(np.fft.irfft(cross, n)))
    shift = shift - n if shift > n / 2 else shift
    w = 2.0 * np.pi * np.arange(r.size) / n
    weight = np.where((np.arange(r.size) == 0) | ((n % 2 == 0) & (np.arange(r.size) == r.size
                                                                    - 1)), 1.0, 2.0)
    for _ in range(8):
        phase = np.exp(-1j * w * shift)
        d1 = float(np.sum(weight * (cross * phase * (-1j * w)).real))
        d2 = float(np.sum(weight * (cross * phase * (-(w ** 2))).real))
        if d2 >= 0:
            break
        step = -d1 / d2
        shift += float(np.clip(step, -0.5, 0.5))
        if abs(step) < 1e-9:
            break
    shifted = shift_periodic(template, shift)
    energy = float(shifted @ shifted)
    gain = float(reference @ shifted) / energy if energy > 0 else 0.0
    return gain * shifted, gain, shift


def shift_periodic(x: FloatArray, shift_samples: float) -> FloatArray:
    """Band-limited circular delay of one period by ``shift_samples`` (may be fractional)."""
    n = x.size
    w = 2.0 * np.pi * np.arange(n // 2 + 1) / n
    return np.fft.irfft(np.fft.rfft(x) * np.exp(-1j * w * shift_samples), n)


def gated_energy(periods: FloatArray, tx_period: FloatArray, mask: NDArray[np.bool_]) -> float:
    """Total energy of the per-period impulse responses inside ``mask``."""
    h = deconvolve(periods, tx_period)
    return float(np.sum(h[..., mask] ** 2))


def suppression_db(before: FloatArray, after: FloatArray, tx_period: FloatArray,
                   direct_mask: NDArray[np.bool_]) -> float:
    """Direct-wave suppression in dB: impulse-response energy inside the direct-path gate,
    before over after removal (a lower bound: noise and echoes in the gate stay)."""
    e_before = gated_energy(before, tx_period, direct_mask)
    e_after = gated_energy(after, tx_period, direct_mask)
    if e_after <= 0:
        return math.inf
    return float(10.0 * np.log10(e_before / e_after))


def direct_to_echo_db(periods: FloatArray, tx_period: FloatArray,
                      direct_mask: NDArray[np.bool_]) -> float:
    """Power of the direct wave over the power of everything else (echoes, noise), dB.

    The direct wave is the periodic mean's part inside the direct-path gate.
    """
    direct = gated_template(periods.mean(axis=0), tx_period, direct_mask)
    p_direct = float(np.mean(direct ** 2))
    p_rest = float(np.mean((periods - direct) ** 2))
    if p_rest <= 0:
        return math.inf
    return float(10.0 * np.log10(max(p_direct, 1e-300) / p_rest))
