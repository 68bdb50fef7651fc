"""The Doppler direction-of-arrival heat map (paper Sec. 2.1, eq. 1).

One received block (M periods of the m-sequence, B = M P samples) and the odometry speed give
a polar heat map ``H[n_theta, n_tau]``: row n_theta is the envelope of the circular
cross-correlation of the transmitted period with the received block resampled by the Doppler
ratio alpha of eq. 1 for the direction ``theta = pi n_theta / N``.

The resampling (``method="spectral"`` or ``"direct"``, two implementations of the same eq. 1,
their numba kernels) lives in :mod:`mapping.heatmap._resampling`; this module
validates the input, builds the :class:`HeatMap` and reads its peak. Its public names
(``bank_angles``, ``doppler_ratios``, ``required_margin``, ``resample_about_centre``, ...) are
importable from here too. Kernels run in parallel over directions; the FFTs use ``scipy.fft``
batched over directions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mapping.heatmap._resampling import (
    DEFAULT_TAPS,
    SPECTRAL_TAPS,
    Bank,
    FloatArray,
    Method,
    bank_angles,
    bank_envelope,
    doppler_ratios,
    required_margin,
)
from mapping.run import Run
from mapping.signal import SonarConfig, checked_speed_m_s

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


# ---- public entry points ----------------------------------------------------------------------
def _validate(
    block: NDArray[np.floating], speed_m_s: float, config: SonarConfig,
    left: int | None, right: int | None,
) -> tuple[FloatArray, int, int, float]:
    v = checked_speed_m_s(speed_m_s, config)
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
        bad ``taps``/``bank``/``method``/``left``/``right``.

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
    env = bank_envelope(samples, lo, hi, unique, speed, config, method, int(k), workers)
    if env.shape[0] != angles.size:
        env = np.repeat(env, angles.size, axis=0)
    ranges = np.arange(config.period_samples, dtype=np.float64) * config.range_per_sample_m
    return HeatMap(
        H=env, angles_rad=angles, ranges_m=ranges, speed_m_s=v,
        direction_observable=bool(drift >= min_drift_samples),
    )


def heatmap_of_run(
    run: Run,
    k: int,
    *,
    method: Method = "spectral",
    taps: int | None = None,
    bank: Bank = "uniform_angle",
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
        bank=bank, workers=workers, min_drift_samples=min_drift_samples,
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
