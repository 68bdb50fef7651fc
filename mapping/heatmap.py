"""The Doppler direction-of-arrival heat map (paper Sec. 2.1, eq. 1).

One received block (M periods of the m-sequence, B = M P samples) and the odometry speed give
a polar heat map ``H[n_theta, n_tau]``: row n_theta is the envelope of the circular
cross-correlation of the transmitted period with the received block resampled by the Doppler
ratio alpha of eq. 1 for the direction ``theta = pi n_theta / N``.

Two implementations of the same eq. 1 (see :func:`doppler_heatmap`, Notes):

* ``method="direct"``: resample in time about the block centre (Kaiser-windowed sinc,
  polyphase table), fold the M periods -> (N+1, P) -> rfft x conj(S), one-sided -> ifft -> |.|.
  Kernel ``_heatmap_kernels._resample_fold``, numpy twin ``_resample_fold_numpy``.
* ``method="spectral"`` (default): the folded spectrum of the resampled block is the DFT of the
  unresampled block at frequencies scaled by 1/alpha; one rfft of the block, Kaiser-Bessel
  gridding for all directions, window-edge corrections -> x conj(S) -> ifft -> |.|.
  Kernel ``_heatmap_kernels._spectral_bank`` (+ ``_add_strip``), numpy twin
  ``_spectral_bank_numpy`` (+ ``_strip_numpy``).

Kernels run in parallel over directions; the FFTs use ``scipy.fft`` batched over directions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np
import scipy.fft
from numpy.typing import NDArray

from mapping.runfile import Run
from mapping.signal import SonarConfig, tx_period

FloatArray = NDArray[np.float64]
Bank = Literal["uniform_angle", "uniform_cos"]
Engine = Literal["numba", "numpy"]
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
#: Direction is declared observable when the largest Doppler time drift over the block
#: (|1 - alpha_0| * B / 2, samples) reaches this many samples.
MIN_DRIFT_SAMPLES = 0.5


@dataclass(frozen=True)
class HeatMap:
    """Polar heat map H[n_theta, n_tau] of one sonar block (paper Fig. 2).

    Attributes
    ----------
    H : ndarray, shape (n_dirs, P)
        Envelope of the Doppler-compensated circular cross-correlation; row n_theta is the
        direction ``angles_rad[n_theta]``, column n_tau the range ``ranges_m[n_tau]``.
    angles_rad : ndarray, shape (n_dirs,)
        Angle of arrival measured from the direction of travel, in [0, pi]; the sensor cannot
        tell +theta from -theta (left/right mirror).
    ranges_m : ndarray, shape (P,)
        One-way range c * n_tau / (2 fs) of each lag.
    speed_m_s : float
        Speed used for the Doppler bank (odometry).
    direction_observable : bool
        False when |speed| is too small for the Doppler bank to separate directions; every
        row is then the same and no bearing may be read from it.
    """

    H: NDArray[np.float64]
    angles_rad: NDArray[np.float64]
    ranges_m: NDArray[np.float64]
    speed_m_s: float
    direction_observable: bool


@dataclass(frozen=True)
class Peak:
    """Strongest echo of a heat map, refined to sub-bin precision by parabolas.

    ``range_m`` and ``angle_rad`` are refined; ``n_theta``/``n_tau`` are the integer bins.
    """

    range_m: float
    angle_rad: float
    value: float
    n_theta: int
    n_tau: int


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


def _resample_fold_numpy(
    ext: FloatArray, origin: float, centre: float, alphas: FloatArray, n_periods: int,
    period: int, table: FloatArray,
) -> FloatArray:
    """Plain numpy twin of ``_heatmap_kernels._resample_fold`` (same arithmetic)."""
    taps = table.shape[1]
    q = table.shape[0] - 1
    half = taps // 2 - 1
    n = np.arange(n_periods * period, dtype=np.float64)
    out = np.empty((alphas.size, period))
    for d, a in enumerate(alphas):
        x = origin + centre + a * (n - centre)
        i = np.floor(x)
        p = np.floor((x - i) * q + 0.5).astype(np.int64)
        idx = i.astype(np.int64)[:, None] - half + np.arange(taps)[None, :]
        values = np.sum(ext[idx] * table[p], axis=1)
        out[d] = values.reshape(n_periods, period).sum(axis=0)
    return out


def resample_about_centre(
    samples: FloatArray, alpha: float, n_out: int, *, left: int = 0, taps: int = DEFAULT_TAPS
) -> FloatArray:
    """Band-limited resampling ``r'[n] = r(c + alpha (n - c))``, c = n_out / 2, n = 0..n_out-1.

    ``samples`` holds ``left`` samples before sample 0 of the block and any number after;
    reads beyond them see zeros. The plain numpy path of the heat map's first stage (without
    the fold); used to test the interpolator against the exact band-limited signal.
    """
    samples = np.asarray(samples, dtype=np.float64)
    margin = int(math.ceil(abs(1.0 - alpha) * (n_out / 2.0 + 1.0))) + taps // 2 + 2
    ext, origin = _padded(samples, left, max(samples.size - left - n_out, 0), n_out, margin)
    return _resample_fold_numpy(
        ext, float(origin), n_out / 2.0, np.array([alpha]), 1, n_out, polyphase_table(taps)
    )[0]


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


def _spectral_bank_numpy(
    spec: NDArray, nf: int, ext: FloatArray, origin: int, n_block: int, centre: float,
    icentre: int, alphas: FloatArray, period: int, taps: int, table: FloatArray,
    per_unit: int, conj_tx: NDArray,
) -> NDArray[np.complex128]:
    """Plain numpy twin of ``_heatmap_kernels._spectral_bank`` (same algorithm)."""
    n_q = period // 2 + 1
    q = np.arange(n_q, dtype=np.float64)
    grid = np.arange(table.shape[0]) / per_unit
    out = np.zeros((alphas.size, period), dtype=np.complex128)
    for d, a in enumerate(alphas):
        xi = q * (nf / (a * period))
        fl = np.floor(xi)
        j = (fl.astype(np.int64) - taps // 2 + 1)[:, None] + np.arange(taps)[None, :]
        w = np.stack([np.interp(xi - fl, grid, table[:, t]) for t in range(taps)], axis=1)
        jm = j % nf
        low = jm < spec.size
        g = np.where(low, spec[np.where(low, jm, 0)], np.conj(spec[np.where(low, 0, nf - jm)]))
        acc = np.sum(w * g, axis=1)
        lo = math.ceil(centre - a * (centre + 0.5))
        hi = math.ceil(centre + a * (n_block - 0.5 - centre))
        strips = [(lo, 0, 1.0) if lo < 0 else (0, lo, -1.0),
                  (n_block, hi, 1.0) if hi > n_block else (hi, n_block, -1.0)]
        delta = 2.0 * np.pi / (a * period)
        for start, stop, sign in strips:
            acc = acc + _strip_numpy(ext, origin, start, stop, sign, icentre, delta, n_q)
        phase = -2.0 * np.pi / period * (centre * (1.0 - 1.0 / a) + icentre / a) * q
        out[d, :n_q] = acc * np.exp(1j * phase) * conj_tx / a
    return out


def _strip_numpy(
    ext: FloatArray, origin: int, start: int, stop: int, sign: float, icentre: int,
    delta: float, n_q: int,
) -> NDArray[np.complex128]:
    """Plain numpy twin of ``_heatmap_kernels._add_strip`` (returns the added term)."""
    q = np.arange(n_q, dtype=np.float64)
    n_s = stop - start
    if n_s <= 0:
        return np.zeros(n_q, dtype=np.complex128)
    k = origin + np.arange(start, stop)
    ok = (k >= 0) & (k < ext.size)
    vals = np.where(ok, sign * ext[np.clip(k, 0, ext.size - 1)], 0.0)
    coarse = max(1, int(STRIP_STEP_RAD / (delta * n_s)))
    qg = np.arange((n_q - 1) // coarse + 2) * coarse
    t = np.exp(-1j * delta * np.outer(qg, np.arange(n_s))) @ vals
    smooth = np.interp(q, qg, t.real) + 1j * np.interp(q, qg, t.imag)
    return np.asarray(smooth * np.exp(-1j * delta * (start - icentre) * q))


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


# ---- public entry points ----------------------------------------------------------------------
def _validate(
    block: NDArray[np.floating], speed_m_s: float, config: SonarConfig,
    left: int | None, right: int | None,
) -> tuple[FloatArray, int, int, float]:
    if not isinstance(config, SonarConfig):
        raise ValueError(f"config must be a SonarConfig, got {type(config).__name__}")
    try:
        v = float(speed_m_s)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"speed_m_s must be a real number, got {speed_m_s!r}") from exc
    c = config.sound_speed_m_s
    if not math.isfinite(v) or abs(v) >= c / 10.0:
        raise ValueError(f"speed_m_s must be finite with |speed_m_s| < c/10 = {c / 10:g}, got {v}")
    arr = np.asarray(block)
    if arr.ndim != 1 or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"block must be a 1-D numeric array, got shape {arr.shape}")
    lo = 0 if left is None else left
    hi = 0 if right is None else right
    for name, value in (("left", lo), ("right", hi)):
        if not isinstance(value, int | np.integer) or value < 0:
            raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
    expected = int(lo) + config.block_samples + int(hi)
    if arr.size != expected:
        raise ValueError(
            f"block must have left + B + right = {lo} + {config.block_samples} + {hi} = "
            f"{expected} samples, got {arr.size}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError("block contains NaN or inf")
    return arr.astype(np.float64, copy=False), int(lo), int(hi), v


def doppler_heatmap(
    block: NDArray[np.floating],
    speed_m_s: float,
    config: SonarConfig,
    *,
    left: int | None = None,
    right: int | None = None,
    method: Method = "spectral",
    taps: int | None = None,
    bank: Bank = "uniform_angle",
    engine: Engine = "numba",
    workers: int = 2,
    min_drift_samples: float = MIN_DRIFT_SAMPLES,
) -> HeatMap:
    """Doppler direction-of-arrival heat map of one received block (paper eq. 1, Fig. 2).

    Parameters
    ----------
    block : ndarray, shape (left + B + right,)
        Received samples of the block (direct wave removed), optionally with ``left`` samples
        of the previous block before it and ``right`` samples of the next block after it
        (exactly what :meth:`mapping.runfile.Run.neighbourhood` returns; ask it for
        :func:`required_margin` samples). Sample m of the block is taken at ``t_s + m / fs``.
    speed_m_s : float
        Odometry speed over the block, m/s; finite, ``|v| < c / 10``. Negative (reversing) is
        handled by flipping: the bank is built for ``|v|`` and angles are measured from the
        direction of travel, which then points backwards (heading + pi). Equivalently, row n
        for ``-v`` is row N - n of eq. 1 evaluated with the signed speed.
    config : SonarConfig
    left, right : int or None
        Neighbour samples included before / after the block (None = 0).
    method : {"spectral", "direct"}
        How the block is resampled (both band-limited, both eq. 1):
        ``"direct"`` resamples in time with a Kaiser-windowed sinc polyphase interpolator of
        ``taps`` taps (default 16) and folds the M periods; ``"spectral"`` (default, ~5x
        faster, more accurate) evaluates the same folded spectrum as a DFT at scaled
        frequencies with a Kaiser-Bessel gridding kernel of ``taps`` taps (default 8) (see
        Notes).
    taps : int or None
        Interpolator length (even); None picks the method's default. ``method="direct",
        taps=2`` is linear interpolation (for comparison only: it loses ~3 dB at fc/fs = 1/4).
    bank : {"uniform_angle", "uniform_cos"}
        Direction bank: eq. 1's ``pi n / N`` or uniform in cos(theta) (see :func:`bank_angles`).
    engine : {"numba", "numpy"}
        The numba kernel or its plain numpy twin (same algorithm, for tests).
    workers : int
        Threads for ``scipy.fft``.
    min_drift_samples : float
        ``direction_observable`` is True when the largest Doppler drift over the block,
        ``|1 - alpha_0| B / 2`` samples, reaches this (default 0.5 sample, i.e.
        |v| >= ~4 mm/s for Table 1). At v = 0 every row is identical.

    Returns
    -------
    HeatMap
        ``H`` of shape (N + 1, P), scaled so a unit-amplitude echo matched in direction peaks
        at about 1. The map refers to the block-centre pose (``Run.pose``).

    Raises
    ------
    ValueError
        Naming the parameter: wrong length, NaN/inf samples, non-finite or too large speed,
        bad ``taps``/``bank``/``method``/``engine``/``left``/``right``.

    Notes
    -----
    **Direction of the resampling.** The sonar moves with speed v; an echo arriving from
    angle theta to the direction of travel has its path shortened at the rate
    ``2 v cos(theta)`` (transmitter and receiver both approach the reflector, eq. 1's
    assumption), so with ``v_r = v cos(theta)`` the echo is ``r(t) = s(beta t - t0)`` with
    ``beta = (c + v_r) / (c - v_r) = 1 / alpha``: an echo from ahead (theta = 0) is
    *compressed* (higher pitch, beta > 1). Reading the received block at the stretched times
    ``r'(t) = r(t_c + alpha (t - t_c))`` gives
    ``s(beta t_c + beta alpha (t - t_c) - t0) = s(t - tau_c)`` with ``tau_c`` the echo delay
    at ``t_c``: the compression is undone exactly in the row whose alpha matches, and the echo
    becomes a pure delay there, so M periods add coherently. (Resampling by beta instead
    would map theta to pi - theta; the tests check 40 deg, which is not symmetric.)

    **Block centre.** ``t_c`` is the block midpoint (sample B / 2, the time of ``Run.pose``);
    the lag of the peak is then ``tau(t_c) fs``, the delay of the echo received at the
    midpoint. Resampling about the block start instead would bias every range by
    ``v T / 2 cos(theta)`` (5 cm at theta = 0).

    **Neighbour samples and run ends.** ``r'`` over n = 0..B-1 reads ``r`` from
    ``B/2 (1 - alpha)`` to ``B/2 (1 + alpha)``, i.e. up to ``|1 - alpha| B / 2`` samples
    (~12 at 0.1 m/s) beyond each block edge (plus ``taps / 2`` samples of interpolator
    support for ``"direct"``). Those are taken from ``left``/``right`` when given; any read
    beyond the samples supplied (first/last block of a run, or a bare block) sees **zeros**.
    That removes at most ~20 of 40,920 samples from the correlation (< 0.1 % of the peak)
    and does not bias range or angle.

    **Linearity and the envelope.** The M resampled periods are summed (folded) before one
    circular correlation per direction (the correlation is linear). The envelope is
    ``|ifft(2 X conj(S))|`` over the non-negative frequencies only (DC and Nyquist weight 1):
    the analytic signal of the correlation, i.e. the Hilbert envelope of eq. 1's pipeline.

    **Spectral method.** The folded spectrum is ``X[q] = sum_{n<B} r(c + alpha (n - c))
    exp(-2 pi i q n / P)``. For a band-limited r, sum and integral coincide (Poisson), so
    ``X[q] = exp(-2 pi i q c / P) / alpha * sum_{u in W} r[u] exp(-i Omega_q (u - c))`` with
    ``Omega_q = 2 pi q / (alpha P)`` and W the stretched read window: the resampling becomes
    a DFT of the *unresampled* block at slightly scaled frequencies. It is evaluated for all
    directions from one rfft of the deapodized block (length 2B) by Kaiser-Bessel gridding
    (a type-2 non-uniform FFT, oversampling 2), plus sums over the ~|1 - alpha| B / 2
    samples by which W differs from the block at each end (``_add_strip``). No interpolation
    in time, so no per-sample filter: O(B log B + N P taps). Against eq. 1 applied to the
    exactly resampled analytic echo the map differs by ~5e-5 of its peak (tested; the
    16-tap direct method by ~6e-3). The final inverse FFT runs in single precision
    (~2e-7 of the peak).

    **Range wrap.** The circular correlation repeats every P lags: the range axis spans
    ``[0, c L T_c / 2)`` = [0, 17.39 m) and an echo at range ``R`` appears at
    ``R mod 17.39 m`` (18 m -> 0.61 m).
    """
    samples, lo, hi, v = _validate(block, speed_m_s, config, left, right)
    if bank not in ("uniform_angle", "uniform_cos"):
        raise ValueError(f"bank must be 'uniform_angle' or 'uniform_cos', got {bank!r}")
    if engine not in ("numba", "numpy"):
        raise ValueError(f"engine must be 'numba' or 'numpy', got {engine!r}")
    if method not in ("spectral", "direct"):
        raise ValueError(f"method must be 'spectral' or 'direct', got {method!r}")
    k = (DEFAULT_TAPS if method == "direct" else SPECTRAL_TAPS) if taps is None else taps
    if not isinstance(k, int | np.integer) or k < 2 or k % 2 or k > 64:
        raise ValueError(f"taps must be an even integer in 2..64, got {taps!r}")
    angles = bank_angles(config, bank)
    speed = abs(v)  # reversing: angles are from the (backward) direction of travel
    alphas = doppler_ratios(speed, angles, config.sound_speed_m_s)
    b = config.block_samples
    drift = abs(1.0 - alphas[0]) * b / 2.0
    unique = np.array([1.0]) if speed == 0.0 else alphas
    ext, origin = _padded(samples, lo, hi, b, required_margin(config, speed, int(k)))
    if method == "direct":
        env = _envelope(_fold(ext, float(origin), unique, config, int(k), engine), config, workers)
    else:
        env = _spectral_envelope(ext, origin, unique, config, int(k), engine, workers)
    if env.shape[0] != angles.size:
        env = np.repeat(env, angles.size, axis=0)
    ranges = np.arange(config.period_samples, dtype=np.float64) * config.range_per_sample_m
    return HeatMap(
        H=env, angles_rad=angles, ranges_m=ranges, speed_m_s=v,
        direction_observable=bool(drift >= min_drift_samples),
    )


def _fold(
    ext: FloatArray, origin: float, alphas: FloatArray, config: SonarConfig, taps: int,
    engine: Engine,
) -> FloatArray:
    table = polyphase_table(taps)
    centre = config.block_samples / 2.0
    p, m = config.period_samples, config.repetitions
    if engine == "numpy":
        return _resample_fold_numpy(ext, origin, centre, alphas, m, p, table)
    from mapping._heatmap_kernels import _resample_fold

    out = np.empty((alphas.size, p))
    _resample_fold(ext, origin, centre, np.ascontiguousarray(alphas), m, p, table, out)
    return out


def _spectral_envelope(
    ext: FloatArray, origin: int, alphas: FloatArray, config: SonarConfig, taps: int,
    engine: Engine, workers: int,
) -> FloatArray:
    b, p = config.block_samples, config.period_samples
    plan = _spectral_plan(b, taps)
    spec = _block_spectrum(ext, origin, b, plan)
    tail = (ext, origin, b, b / 2.0, plan.icentre, np.ascontiguousarray(alphas), p, taps,
            plan.table, plan.per_unit, _tx_conj_spectrum(config))
    if engine == "numpy":
        full = _spectral_bank_numpy(spec, plan.nf, *tail).astype(np.complex64)
    else:
        from mapping._heatmap_kernels import _spectral_bank

        # xi reaches q nf / (alpha P) <= nf / (2 alpha): beyond nf/2 when alpha < 1
        pad = taps + 2 + int(math.ceil(plan.nf / 2.0 * (1.0 / float(alphas.min()) - 1.0)))
        spec_re, spec_im = _hermitian_extended(spec, pad)
        full = np.empty((alphas.size, p), dtype=np.complex64)
        _spectral_bank(spec_re, spec_im, pad, plan.nf, *tail, STRIP_STEP_RAD, full)
    # single precision for the last FFT (relative error ~2e-7 of the peak, 2x faster)
    env = np.abs(scipy.fft.ifft(full, axis=1, workers=workers, overwrite_x=True))
    return np.asarray(env, dtype=np.float64)


def heatmap_of_run(
    run: Run,
    k: int,
    *,
    method: Method = "spectral",
    taps: int | None = None,
    bank: Bank = "uniform_angle",
    engine: Engine = "numba",
    workers: int = 2,
    min_drift_samples: float = MIN_DRIFT_SAMPLES,
) -> HeatMap:
    """Heat map of block ``k`` of ``run`` using its neighbours' samples (see doppler_heatmap).

    Uses ``run.speed_m_s[k]`` and :meth:`Run.neighbourhood` with :func:`required_margin`
    samples; the first/last block of the run sees zeros beyond its outer edge.
    """
    if not isinstance(k, int | np.integer) or not 0 <= k < run.n_blocks:
        raise ValueError(f"block index k must be in 0..{run.n_blocks - 1}, got {k!r}")
    speed = float(run.speed_m_s[k])
    margin = required_margin(run.config, speed, max(taps or DEFAULT_TAPS, DEFAULT_TAPS))
    samples, left, right = run.neighbourhood(int(k), margin)
    return doppler_heatmap(
        samples, speed, run.config, left=left, right=right, method=method, taps=taps,
        bank=bank, engine=engine, workers=workers, min_drift_samples=min_drift_samples,
    )


def find_peak(hm: HeatMap) -> Peak:
    """Strongest cell of ``hm``, refined by a parabola through the neighbours on each axis.

    Range: circular parabola over n_tau at the peak row. Angle: parabola over n_theta of the
    peak column in bin index (at the ends of the bank the mirror symmetry of the Doppler
    pattern about 0 and pi is used), mapped to an angle by interpolating ``angles_rad``.
    """
    n_theta, n_tau = np.unravel_index(int(np.argmax(hm.H)), hm.H.shape)
    row = hm.H[n_theta]
    p = row.size
    d_tau = _parabola(row[(n_tau - 1) % p], row[n_tau], row[(n_tau + 1) % p])
    col = hm.H[:, n_tau]
    last = col.size - 1
    below = col[n_theta - 1] if n_theta > 0 else col[1]
    above = col[n_theta + 1] if n_theta < last else col[last - 1]
    d_theta = _parabola(below, col[n_theta], above) if hm.direction_observable else 0.0
    idx = np.arange(col.size, dtype=np.float64)
    angle = float(np.interp(n_theta + d_theta, idx, hm.angles_rad))
    step = float(hm.ranges_m[1] - hm.ranges_m[0])
    return Peak(
        range_m=float(((n_tau + d_tau) % p) * step), angle_rad=angle,
        value=float(hm.H[n_theta, n_tau]), n_theta=int(n_theta), n_tau=int(n_tau),
    )


def _parabola(ym: float, y0: float, yp: float) -> float:
    """Offset in (-0.5, 0.5) of the vertex of the parabola through (-1, ym), (0, y0), (1, yp)."""
    den = ym - 2.0 * y0 + yp
    if den >= 0.0:
        return 0.0
    return float(np.clip(0.5 * (ym - yp) / den, -0.5, 0.5))
