"""Doppler resampling of a sonar block for the heat map of paper eq. 1.

For each direction of the bank (:func:`bank_angles`) the received block is resampled by the
Doppler ratio alpha of eq. 1 (:func:`doppler_ratios`) about its centre, folded over its M
periods and correlated with the transmitted period; :func:`bank_envelope` returns the envelopes
that :func:`mapping.heatmap.doppler_heatmap` wraps in a :class:`~mapping.heatmap.HeatMap`.

Two implementations of the same eq. 1 (see :func:`mapping.heatmap.doppler_heatmap`, Notes):

* ``method="direct"``: resample in time about the block centre (Kaiser-windowed sinc,
  polyphase table), fold the M periods -> (N+1, P) -> rfft x conj(S), one-sided -> ifft -> |.|.
  Kernel ``_kernels._resample_fold``.
* ``method="spectral"`` (default): the folded spectrum of the resampled block is the DFT of the
  unresampled block at frequencies scaled by 1/alpha; one rfft of the block, Kaiser-Bessel
  gridding for all directions, window-edge corrections -> x conj(S) -> ifft -> |.|.
  Kernel ``_kernels._spectral_bank`` (+ ``_add_strip``).

The kernels' plain numpy twins live with the tests (``tests/mapping/heatmap/naive.py``).
This module is the only importer of :mod:`mapping.heatmap._kernels`; inputs are validated by
:func:`mapping.heatmap.doppler_heatmap` before they reach it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np
import scipy.fft
from numpy.typing import NDArray

from mapping.signal import SonarConfig, tx_period

FloatArray = NDArray[np.float64]
Bank = Literal["uniform_angle", "uniform_cos"]
Method = Literal["spectral", "direct"]

#: Number of fractional-delay phases of the polyphase interpolator table.
PHASES = 1024
#: Default interpolator length (taps) of the windowed-sinc resampler.
DEFAULT_TAPS = 16
#: Largest phase step (rad) across a window-correction strip between exactly evaluated
#: points (see ``_heatmap_kernels._add_strip``): error <= 0.1^2/8 of the strip's sum.
STRIP_STEP_RAD = 0.1
#: Default Kaiser-Bessel gridding kernel length of the spectral method.
SPECTRAL_TAPS = 8
#: Kaiser window shape and cutoff (fraction of Nyquist) of the interpolator.
KAISER_BETA = 3.0
CUTOFF = 1.0


# ---- direction bank -------------------------------------------------------------------------
def bank_angles(config: SonarConfig, bank: Bank = "uniform_angle") -> FloatArray:
    """Angles (rad from the direction of travel) of the direction bank.

    ``"uniform_angle"`` is eq. 1's ``pi n / N``, n = 0..N. ``"uniform_cos"`` spaces the N + 1
    directions uniformly in cos(theta) (``arccos(1 - 2 n / N)``), matching the Doppler
    resolution, which is fine broadside (~9.5 deg) and coarse along the track (~33 deg).
    """
    n = np.arange(config.directions + 1, dtype=np.float64)
    if bank == "uniform_angle":
        return np.pi * n / config.directions
    if bank == "uniform_cos":
        return np.arccos(np.clip(1.0 - 2.0 * n / config.directions, -1.0, 1.0))
    raise ValueError(f"bank must be 'uniform_angle' or 'uniform_cos', got {bank!r}")


def doppler_ratios(speed_m_s: float, angles_rad: FloatArray, sound_speed_m_s: float) -> FloatArray:
    """Resampling ratios of eq. 1: alpha = (c - v cos theta) / (c + v cos theta)."""
    vc = speed_m_s * np.cos(angles_rad)
    return np.asarray((sound_speed_m_s - vc) / (sound_speed_m_s + vc))


def required_margin(config: SonarConfig, speed_m_s: float, taps: int = DEFAULT_TAPS) -> int:
    """Neighbour samples needed on each side of the block: |1 - alpha|max * B / 2 + taps / 2.

    About 12 + 8 + 2 samples at 0.1 m/s with Table 1 and 16 taps. Pass this as ``margin`` to
    :meth:`mapping.runfile.Run.neighbourhood`.
    """
    a = abs(float(speed_m_s)) / config.sound_speed_m_s
    drift = 2.0 * a / (1.0 - a) * (config.block_samples / 2.0 + 1.0)
    return int(math.ceil(drift)) + taps // 2 + 2


# ---- interpolator -----------------------------------------------------------------------------
@lru_cache(maxsize=8)
def polyphase_table(taps: int, phases: int = PHASES) -> FloatArray:
    """Kaiser-windowed sinc interpolator, shape (phases + 1, taps), rows sum to 1.

    Row p interpolates at fraction ``p / phases`` past sample i from samples
    ``i - taps/2 + 1 .. i + taps/2``: weight of tap t is
    ``CUTOFF sinc(CUTOFF (t - taps/2 + 1 - p/phases)) * kaiser``.
    """
    if taps < 2 or taps % 2 or taps > 256:
        raise ValueError(f"taps must be an even integer in 2..256, got {taps}")
    frac = np.arange(phases + 1)[:, None] / phases
    dist = np.arange(taps)[None, :] - (taps // 2 - 1) - frac
    if taps == 2:  # linear interpolation (the baseline that loses ~3 dB at fc/fs = 1/4)
        table = np.maximum(0.0, 1.0 - np.abs(dist))
    else:
        u = np.clip(dist / (taps / 2.0), -1.0, 1.0)
        window = np.i0(KAISER_BETA * np.sqrt(1.0 - u * u)) / np.i0(KAISER_BETA)
        table = CUTOFF * np.sinc(CUTOFF * dist) * window
    table = table / table.sum(axis=1, keepdims=True)
    table.setflags(write=False)
    return np.asarray(table)


def _padded(
    samples: FloatArray, left: int, right: int, block: int, margin: int
) -> tuple[FloatArray, int]:
    """Zero-pad the extended samples so reads up to ``margin`` beyond the block are in bounds.

    Returns the padded array and the index of block sample 0 in it.
    """
    before = max(margin - left, 0) + 1
    after = max(margin - right, 0) + 1
    ext = np.zeros(before + samples.size + after)
    ext[before : before + samples.size] = samples
    return ext, before + left


def resample_about_centre(
    samples: FloatArray, alpha: float, n_out: int, *, left: int = 0, taps: int = DEFAULT_TAPS
) -> FloatArray:
    """Band-limited resampling ``r'[n] = r(c + alpha (n - c))``, c = n_out / 2, n = 0..n_out-1.

    ``samples`` holds ``left`` samples before sample 0 of the block and any number after;
    reads beyond them see zeros. The heat map's first stage for one ratio and no fold, in
    plain numpy (the same arithmetic as the kernel ``_resample_fold``, which sums in another
    order); used to test the interpolator against the exact band-limited signal.
    """
    samples = np.asarray(samples, dtype=np.float64)
    margin = int(math.ceil(abs(1.0 - alpha) * (n_out / 2.0 + 1.0))) + taps // 2 + 2
    ext, origin = _padded(samples, left, max(samples.size - left - n_out, 0), n_out, margin)
    table = polyphase_table(taps)
    q = table.shape[0] - 1
    n = np.arange(n_out, dtype=np.float64)
    x = float(origin) + n_out / 2.0 + alpha * (n - n_out / 2.0)
    i = np.floor(x)
    p = np.floor((x - i) * q + 0.5).astype(np.int64)
    idx = i.astype(np.int64)[:, None] - (taps // 2 - 1) + np.arange(taps)[None, :]
    return np.asarray(np.sum(ext[idx] * table[p], axis=1))


# ---- spectral method: resampling as a scaled-frequency DFT ----------------------------------
@dataclass(frozen=True)
class _SpectralPlan:
    """Kaiser-Bessel gridding plan for a block of ``n_block`` samples (type-2 NUFFT)."""

    nf: int
    icentre: int
    deapod: FloatArray
    table: FloatArray
    per_unit: int


@lru_cache(maxsize=8)
def _spectral_plan(n_block: int, taps: int, per_unit: int = 2048) -> _SpectralPlan:
    """Oversampling 2 (``nf`` = next fast length >= 2 B), Beatty et al. (2005) Kaiser-Bessel
    shape ``beta = pi sqrt((K / sigma)^2 (sigma - 1/2)^2 - 0.8)`` and its closed-form Fourier
    transform ``K sinh(z) / z``, ``z = sqrt(beta^2 - (pi K u / nf)^2)``, for deapodization."""
    if taps < 2 or taps % 2 or taps > 64:
        raise ValueError(f"taps (spectral method) must be an even integer in 2..64, got {taps}")
    nf = scipy.fft.next_fast_len(2 * n_block, real=True)
    while nf % 2:  # even, so the Hermitian extension mirrors about nf / 2
        nf = scipy.fft.next_fast_len(nf + 1, real=True)
    sigma = nf / n_block
    beta = math.pi * math.sqrt((taps / sigma) ** 2 * (sigma - 0.5) ** 2 - 0.8)
    icentre = n_block // 2
    u = np.arange(n_block) - icentre
    z = np.sqrt(beta**2 - (math.pi * taps * u / nf) ** 2)
    deapod = z / (taps * np.sinh(z))
    frac = np.arange(per_unit + 1)[:, None] / per_unit
    y = frac + taps // 2 - 1 - np.arange(taps)[None, :]
    table = np.i0(beta * np.sqrt(np.clip(1.0 - (2.0 * y / taps) ** 2, 0.0, None)))
    return _SpectralPlan(nf, icentre, deapod, table, per_unit)


def _block_spectrum(ext: FloatArray, origin: int, n_block: int, plan: _SpectralPlan) -> NDArray:
    """rfft (length nf) of the deapodized block, time origin at sample ``icentre``."""
    r = ext[origin : origin + n_block] * plan.deapod
    ci = plan.icentre
    buf = np.zeros(plan.nf)
    buf[: n_block - ci] = r[ci:]
    buf[plan.nf - ci :] = r[:ci]
    return np.asarray(scipy.fft.rfft(buf))


def _hermitian_extended(spec: NDArray, pad: int) -> tuple[FloatArray, FloatArray]:
    """Real and imaginary parts of ``G[j]``, j in [-pad, n + pad), index ``pad + j``, from the
    rfft ``spec`` (n = nf/2 + 1 bins, nf even) using ``G[-j] = G[nf - j] = conj G[j]``."""
    n = spec.size
    ext = np.empty(n + 2 * pad, dtype=np.complex128)
    ext[pad : pad + n] = spec
    ext[:pad] = np.conj(spec[pad:0:-1])
    ext[pad + n :] = np.conj(spec[n - 2 : n - 2 - pad : -1])
    return np.ascontiguousarray(ext.real), np.ascontiguousarray(ext.imag)


# ---- shared spectral stage --------------------------------------------------------------------
@lru_cache(maxsize=8)
def _tx_conj_spectrum(config: SonarConfig) -> NDArray[np.complex128]:
    """One-sided weights times conj(S) / (M sum s^2): the analytic-correlation filter.

    Weights 1 at DC and Nyquist, 2 between, so ``ifft`` of the product zero-extended over the
    negative frequencies is the analytic signal of the circular cross-correlation. Scaled so a
    unit-amplitude echo matched in direction gives an envelope peak of about 1.
    """
    s = tx_period(config)
    p = s.size
    spec = np.conj(np.fft.rfft(s)) / (config.repetitions * float(np.dot(s, s)))
    weights = np.full(spec.size, 2.0)
    weights[0] = 1.0
    if p % 2 == 0:
        weights[-1] = 1.0
    out = spec * weights
    out.setflags(write=False)
    return out


def _envelope(folded: FloatArray, config: SonarConfig, workers: int) -> FloatArray:
    """|analytic circular cross-correlation| of each folded row with the transmitted period."""
    p = config.period_samples
    spec = scipy.fft.rfft(folded, axis=1, workers=workers) * _tx_conj_spectrum(config)
    full = np.zeros((folded.shape[0], p), dtype=np.complex128)
    full[:, : spec.shape[1]] = spec
    return np.abs(scipy.fft.ifft(full, axis=1, workers=workers))


# ---- the bank of directions ------------------------------------------------------------------


def bank_envelope(
    samples: FloatArray, left: int, right: int, alphas: FloatArray, speed_m_s: float,
    config: SonarConfig, method: Method, taps: int, workers: int,
) -> FloatArray:
    """Envelopes (alphas.size, P) of eq. 1 for each resampling ratio in ``alphas``.

    ``samples`` are ``left + B + right`` validated samples (see
    :func:`mapping.heatmap.doppler_heatmap`, which checks every argument); reads beyond them
    see zeros. ``speed_m_s`` (>= 0) sets the padding through :func:`required_margin`.
    """
    ext, origin = _padded(samples, left, right, config.block_samples,
                          required_margin(config, speed_m_s, taps))
    if method == "direct":
        return _envelope(_fold(ext, float(origin), alphas, config, taps), config, workers)
    return _spectral_envelope(ext, origin, alphas, config, taps, workers)


def _fold(
    ext: FloatArray, origin: float, alphas: FloatArray, config: SonarConfig, taps: int
) -> FloatArray:
    table = polyphase_table(taps)
    centre = config.block_samples / 2.0
    p, m = config.period_samples, config.repetitions
    from mapping.heatmap._kernels import _resample_fold

    out = np.empty((alphas.size, p))
    _resample_fold(ext, origin, centre, np.ascontiguousarray(alphas), m, p, table, out)
    return out


def _spectral_envelope(
    ext: FloatArray, origin: int, alphas: FloatArray, config: SonarConfig, taps: int,
    workers: int,
) -> FloatArray:
    b, p = config.block_samples, config.period_samples
    plan = _spectral_plan(b, taps)
    spec = _block_spectrum(ext, origin, b, plan)
    from mapping.heatmap._kernels import _spectral_bank, _SpectralGrid, _Window

    # xi reaches q nf / (alpha P) <= nf / (2 alpha): beyond nf/2 when alpha < 1
    pad = taps + 2 + int(math.ceil(plan.nf / 2.0 * (1.0 / float(alphas.min()) - 1.0)))
    spec_re, spec_im = _hermitian_extended(spec, pad)
    grid = _SpectralGrid(spec_re, spec_im, pad, plan.nf, taps, plan.table, plan.per_unit)
    window = _Window(ext, origin, b, b / 2.0, plan.icentre, STRIP_STEP_RAD)
    full = np.empty((alphas.size, p), dtype=np.complex64)
    _spectral_bank(grid, window, np.ascontiguousarray(alphas), p, _tx_conj_spectrum(config), full)
    # single precision for the last FFT (relative error ~2e-7 of the peak, 2x faster)
    env = np.abs(scipy.fft.ifft(full, axis=1, workers=workers, overwrite_x=True))
    return np.asarray(env, dtype=np.float64)
