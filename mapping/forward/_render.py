"""Rendering an echo list as the heat map eq. 1 would give: the point-spread function.

Row n of eq. 1 resamples the block with the ratio alpha_n of direction theta_n. An echo whose
Doppler cosine is ``cos_e`` is compressed by ``beta_e = (c + v cos_e) / (c - v cos_e)``; after
the resampling a residual time scaling ``eps = beta_e alpha_n - 1`` is left, so about the
block centre the echo sits at lag ``x + eps (t - t_c) fs``: it drifts by ``D = eps B``
samples over the block while its carrier phase turns by ``2 pi f_c D / f_s``. Over any stretch
of the block the correlation with the transmitted period is the analytic correlation C of one
period shifted by the local drift, and the folded block integrates those stretches, so the
row's analytic correlation is the box average

    h(x; D) = (1 / D) int_{-D/2}^{D/2} C(x + d) dd ,

C being the (band-limited, -1/L floor included) analytic circular cross-correlation of the
heard period with the transmitted one, scaled as :func:`mapping.heatmap.doppler_heatmap`
scales it (a matched unit echo peaks at 1). With G the periodic primitive of C the box
average is ``(G(x + D/2) - G(x - D/2)) / D`` (plus the mean of C): tabulated once per
configuration (:func:`psf_tables`, lru_cache) on a grid 16x finer than the lags, read by
cubic interpolation. No blur parameter: M, L, the chip shape, f_c, f_s and v fix it.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from mapping.forward._echoes import DEFAULT_PARAMS, Echoes, ForwardParams, WallSet, echoes
from mapping.forward._kernels import _Psf, _psf_at, _render_rows
from mapping.heatmap import MIN_DRIFT_SAMPLES, Bank, HeatMap, bank_angles, doppler_ratios
from mapping.signal import SonarConfig, tx_period
from mapping.simulate.ism import signal_period

FloatArray = NDArray[np.float64]

#: Fine-grid points per lag sample of the PSF tables.
PSF_UPSAMPLE = 16
#: Each echo is rendered over ``|lag - lag_e| <= |D| / 2 + PSF_HALF_WIDTH`` samples; beyond
#: that its envelope is below ~1e-3 of its peak (the m-sequence floor is 1/L ~ 1e-3).
PSF_HALF_WIDTH = 40.0


#: Echoes closer than this fraction of a carrier wavelength in range ...
COINCIDENT_RANGE = 0.125
#: ... and this in Doppler cosine arrive together (see ``render_heatmap``).
COINCIDENT_COS = 1e-3


@lru_cache(maxsize=8)
def psf_tables(config: SonarConfig, spreading: str = "3d") -> _Psf:
    """Analytic correlation C and its primitive G on a grid ``PSF_UPSAMPLE`` finer.

    ``C(x) = (1/P) sum_q w_q X_q conj(S_q) e^{2 pi i q x / P} / sum s^2`` over q = 0..P/2
    (w = 1 at DC and Nyquist, 2 between): the envelope filter of the heat map applied to one
    period of the heard signal (:func:`mapping.simulate.ism.signal_period`: the transmitted
    period for ``3d``, the 2-D line-source filtered one for ``2d``).
    """
    s = np.asarray(tx_period(config), dtype=np.float64)
    heard = np.asarray(signal_period(config, spreading), dtype=np.float64)
    p = s.size
    spec = np.fft.rfft(heard) * np.conj(np.fft.rfft(s)) / float(np.dot(s, s))
    weights = np.full(spec.size, 2.0)
    weights[0] = 1.0
    if p % 2 == 0:
        weights[-1] = 1.0
    spec = spec * weights
    n_fine = p * PSF_UPSAMPLE
    full = np.zeros(n_fine, dtype=np.complex128)
    full[: spec.size] = spec
    corr = np.fft.ifft(full) * PSF_UPSAMPLE
    q = np.arange(spec.size, dtype=np.float64)
    prim_spec = np.zeros(n_fine, dtype=np.complex128)
    prim_spec[1: spec.size] = spec[1:] * p / (2j * np.pi * q[1:])
    prim = np.fft.ifft(prim_spec) * PSF_UPSAMPLE
    mean = spec[0] / p
    return _Psf(np.ascontiguousarray(corr.real), np.ascontiguousarray(corr.imag),
                np.ascontiguousarray(prim.real), np.ascontiguousarray(prim.imag),
                float(mean.real), float(mean.imag), PSF_UPSAMPLE)


def point_spread(
    offset_samples: NDArray[np.floating], drift_samples: float, config: SonarConfig,
    spreading: str = "3d",
) -> NDArray[np.complex128]:
    """Analytic heat-map response ``h(x; D)`` of a unit echo at lag offsets ``x`` (samples)
    for a drift of ``D`` samples over the block (0: matched row); ``|h|`` is the envelope."""
    psf = psf_tables(config, spreading)
    x = np.asarray(offset_samples, dtype=np.float64)
    out = np.array([_psf_at(psf, float(v), float(drift_samples)) for v in x.ravel()])
    return out.reshape(x.shape)


def drift_samples(
    cos_doppler: NDArray[np.floating], angles_rad: NDArray[np.floating], speed_m_s: float,
    config: SonarConfig,
) -> FloatArray:
    """Drift ``D[n, k] = (beta_k alpha_n - 1) B`` (samples over the block) of echo k in row n.

    ``alpha_n`` is eq. 1's ratio of direction ``angles_rad[n]``; ``beta_k = (c + |v| cos_k) /
    (c - |v| cos_k)`` the compression of an echo with Doppler cosine ``cos_k``.
    """
    c = config.sound_speed_m_s
    v = abs(float(speed_m_s))
    alphas = doppler_ratios(v, np.asarray(angles_rad, dtype=np.float64), c)
    cos = np.asarray(cos_doppler, dtype=np.float64)
    beta = (c + v * cos) / (c - v * cos)
    return np.asarray((alphas[:, None] * beta[None, :] - 1.0) * config.block_samples)


def render_heatmap(
    echoes: Echoes,
    speed_m_s: float,
    config: SonarConfig,
    *,
    bank: Bank = "uniform_angle",
    coherent: bool = False,
) -> HeatMap:
    """The heat map eq. 1 gives for ``echoes`` (same axes as ``doppler_heatmap``).

    Parameters
    ----------
    echoes : Echoes
        From :func:`mapping.forward.echoes` (any speed; ``cos_doppler`` and ``range_m`` are
        used, with ``spreading`` deciding the heard waveform).
    speed_m_s : float
        Odometry speed the bank is built for (signed; only |v| matters, as in eq. 1).
    config : SonarConfig
    bank : {"uniform_angle", "uniform_cos"}
        Direction bank, as :func:`mapping.heatmap.doppler_heatmap`.
    coherent : bool
        False (default): ``sqrt(sum_k |a_k h_k|^2)``, the expected envelope of echoes with
        unknown relative carrier phase (a range error of lambda / 4 ~ 8.5 mm turns it by pi);
        exact wherever echoes do not overlap. Echoes arriving together (a path and its
        reverse, mirror-symmetric paths: within lambda / 8 in range and 1e-3 in Doppler
        cosine) are one arrival: their amplitudes add with their carrier phases first.
        True: ``|sum_k a_k h_k|``, the complex sum with the phases of the modelled delays
        (signed strengths included).

    Returns
    -------
    HeatMap
        ``H`` (N + 1, P); ``direction_observable`` as ``doppler_heatmap`` sets it. Ranges
        beyond the unambiguous range wrap (``range mod c P / (2 fs)``) as in eq. 1.

    Notes
    -----
    Point-spread: see :mod:`mapping.forward` (``h(x; D)``, the drift-averaged analytic
    correlation). At speed 0 every drift is 0 and every row is the same, as in eq. 1.
    """
    if not isinstance(echoes, Echoes):
        raise ValueError(f"echoes must be an Echoes, got {type(echoes).__name__}")
    if not isinstance(config, SonarConfig):
        raise ValueError(f"config must be a SonarConfig, got {type(config).__name__}")
    if bank not in ("uniform_angle", "uniform_cos"):
        raise ValueError(f"bank must be 'uniform_angle' or 'uniform_cos', got {bank!r}")
    v = float(speed_m_s)
    if not np.isfinite(v) or abs(v) >= config.sound_speed_m_s / 10.0:
        raise ValueError(f"speed_m_s must be finite with |speed_m_s| < c/10, got {speed_m_s!r}")
    angles = bank_angles(config, bank)
    p = config.period_samples
    rng, cos, amp = (echoes.range_m, echoes.cos_doppler, echoes.amplitude) if coherent else (
        _merge_coincident(echoes, config.carrier_hz, config.sound_speed_m_s))
    drift = np.ascontiguousarray(drift_samples(cos, angles, v, config))
    lag = np.ascontiguousarray(np.mod(rng / config.range_per_sample_m, p))
    amp = np.ascontiguousarray(amp, dtype=np.float64)
    out = np.zeros((angles.size, p))
    if amp.size:
        _render_rows(psf_tables(config, echoes.spreading), drift, lag, amp, PSF_HALF_WIDTH,
                     bool(coherent), out)
    alpha0 = doppler_ratios(abs(v), angles[:1], config.sound_speed_m_s)[0]
    observable = abs(1.0 - alpha0) * config.block_samples / 2.0 >= MIN_DRIFT_SAMPLES
    ranges = np.arange(p, dtype=np.float64) * config.range_per_sample_m
    return HeatMap(H=out, angles_rad=angles, ranges_m=ranges, speed_m_s=v,
                   direction_observable=bool(observable))


def _merge_coincident(
    echoes: Echoes, carrier_hz: float, sound_speed_m_s: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Echoes that arrive together are one arrival: a path and its reverse (walls in the
    opposite order, e.g. (i, j) and (j, i) between parallel walls; equal up to the mm of
    retardation) or mirror-symmetric paths (a robot on a corridor's centre line). Echoes
    within ``COINCIDENT_RANGE`` of a carrier wavelength in range and ``COINCIDENT_COS`` in
    Doppler cosine add their amplitudes with the carrier phase of their range difference
    before the incoherent sum. Returns (range_m, cos_doppler, amplitude), merged."""
    rng, cos, amp = echoes.range_m, echoes.cos_doppler, echoes.amplitude
    if echoes.k < 2:
        return rng, cos, amp
    tol = COINCIDENT_RANGE * sound_speed_m_s / carrier_hz
    close = np.flatnonzero(np.diff(rng) <= tol)
    if close.size == 0:
        return rng, cos, amp
    keep = np.ones(echoes.k, dtype=bool)
    out_a = amp.astype(np.complex128)
    for i in range(echoes.k):  # echoes are sorted by range
        j = i + 1
        while keep[i] and j < echoes.k and rng[j] - rng[i] <= tol:
            if keep[j] and abs(cos[j] - cos[i]) <= COINCIDENT_COS:
                phase = 4.0 * np.pi * carrier_hz * (rng[j] - rng[i]) / sound_speed_m_s
                out_a[i] += amp[j] * np.exp(1j * phase)
                keep[j] = False
            j += 1
    merged = np.abs(out_a) * np.where(out_a.real < 0, -1.0, 1.0)
    return rng[keep], cos[keep], merged[keep]


def predicted_heatmap(
    walls: WallSet,
    pose: NDArray[np.floating] | list[float] | tuple[float, ...],
    speed_m_s: float,
    config: SonarConfig,
    params: ForwardParams = DEFAULT_PARAMS,
    *,
    bank: Bank = "uniform_angle",
    coherent: bool = False,
) -> HeatMap:
    """``render_heatmap(echoes(walls, pose, speed_m_s, config, params), speed_m_s, config)``."""
    found = echoes(walls, pose, speed_m_s, config, params)
    return render_heatmap(found, speed_m_s, config, bank=bank, coherent=coherent)
