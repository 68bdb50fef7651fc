"""Heat-map bookkeeping and the FDTD's band and dispersion applied to image-source paths
(:func:`render_paths`); part of :mod:`mapping.simulate.fdtd_compare`, which re-exports it."""

from __future__ import annotations

import itertools
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.signal import SonarConfig
from mapping.simulate import PathTable
from mapping.simulate.fdtd import (
    FdtdConfig,
    injected_band,
    numerical_group_velocity,
    numerical_wavenumber,
    source_filter,
)
from mapping.simulate.ism import signal_period

FloatArray = NDArray[np.float64]


# ---- heat-map bookkeeping -------------------------------------------------------------------
def heatmap_angle_rad(doppler_factor: ArrayLike, speed_m_s: float, c: float) -> FloatArray:
    """Angle a path shows in the Doppler heat map (paper eq. 1), from its Doppler factor.

    The bank of eq. 1 compensates ``D = 1 + 2 v cos(theta) / c``; a path with Doppler factor
    ``D`` peaks at ``theta = arccos((D - 1) c / (2 v))``. For a path that leaves at angle
    ``a`` and returns from angle ``b`` (both from the velocity) ``D - 1 = v (cos a + cos b) /
    c``, so ``cos theta`` is the mean of the two cosines.

    Raises
    ------
    ValueError
        ``speed_m_s`` zero or not finite, ``c`` not positive.
    """
    if not (math.isfinite(speed_m_s) and speed_m_s != 0):
        raise ValueError(f"speed_m_s must be finite and non-zero, got {speed_m_s}")
    if not c > 0:
        raise ValueError(f"c must be > 0, got {c}")
    d = np.asarray(doppler_factor, dtype=np.float64)
    out: FloatArray = np.arccos(np.clip((d - 1.0) * c / (2.0 * speed_m_s), -1.0, 1.0))
    return out


def local_maxima(H: ArrayLike, n: int, n_range: int | None = None) -> list[tuple[int, int, float]]:
    """The ``n`` strongest strict local maxima of a heat map (3 x 3 neighbourhood).

    Parameters
    ----------
    H : array, shape (n_dirs, P)
        Heat map (rows: angles, columns: range lags).
    n : int
        How many to return (fewer if the map has fewer), >= 1.
    n_range : int or None
        Only columns ``< n_range`` count (None: all). Ranges are circular (the correlation is),
        the angle axis is mirrored at its ends (the Doppler pattern is symmetric about 0 and
        pi), as in :func:`mapping.heatmap.find_peak`.

    Returns
    -------
    list of (n_theta, n_tau, value)
        Strongest first.
    """
    A = np.asarray(H, dtype=np.float64)
    if A.ndim != 2 or A.shape[0] < 2 or A.shape[1] < 3:
        raise ValueError(f"H must be 2-D with >= 2 rows and >= 3 columns, got {A.shape}")
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    m = A.shape[1] if n_range is None else int(n_range)
    if not 1 <= m <= A.shape[1]:
        raise ValueError(f"n_range must be in 1..{A.shape[1]}, got {n_range}")
    pad = np.pad(A, ((1, 1), (0, 0)), mode="reflect")
    neighbours = np.stack([np.roll(pad, (di, dj), axis=(0, 1))[1:-1]
                           for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)])
    is_max = A > neighbours.max(axis=0)
    is_max[:, m:] = False
    idx = np.argwhere(is_max)
    vals = A[is_max]
    order = np.argsort(-vals, kind="stable")[:n]
    return [(int(idx[j, 0]), int(idx[j, 1]), float(vals[j])) for j in order]


def window_peak(H: ArrayLike, n_theta: int, n_tau: int, half_theta: int,
                half_tau: int) -> tuple[int, int, float]:
    """Strongest cell of ``H`` within ``+-half_theta`` rows and ``+-half_tau`` columns of a cell.

    The window is clipped at the angle axis' ends and wraps around in range (circular lags).
    Returns ``(n_theta, n_tau, value)``.
    """
    A = np.asarray(H, dtype=np.float64)
    if A.ndim != 2:
        raise ValueError(f"H must be 2-D, got shape {A.shape}")
    if half_theta < 0 or half_tau < 0:
        raise ValueError(f"half_theta and half_tau must be >= 0, got {half_theta}, {half_tau}")
    if not 0 <= n_theta < A.shape[0]:
        raise ValueError(f"n_theta must be in 0..{A.shape[0] - 1}, got {n_theta}")
    rows = np.arange(max(n_theta - half_theta, 0), min(n_theta + half_theta, A.shape[0] - 1) + 1)
    cols = np.arange(n_tau - half_tau, n_tau + half_tau + 1) % A.shape[1]
    sub = A[np.ix_(rows, cols)]
    i, j = np.unravel_index(int(np.argmax(sub)), sub.shape)
    return int(rows[i]), int(cols[j]), float(sub[i, j])


# ---- band and dispersion of the FDTD --------------------------------------------------------
def grid_band(f_hz: ArrayLike, sonar: SonarConfig, fdtd: FdtdConfig) -> FloatArray:
    """Magnitude response of the FDTD's injection tapers (high-pass below 0.1 f_c,
    raised-cosine low-pass to the injected band edge), normalised to a peak of 1: the
    :func:`~mapping.simulate.fdtd_dispersion.source_filter` without its ``1/(i w)`` and gain."""
    f = np.asarray(f_hz, dtype=np.float64)
    g = np.abs(source_filter(f, sonar, fdtd) * 2 * np.pi * f)
    peak = float(g.max()) if g.size else 0.0
    if not peak > 0:
        raise ValueError("f_hz must contain at least one frequency inside the injected band")
    out: FloatArray = g / peak
    return out


def dispersion_phase(f_hz: ArrayLike, length_m: float, direction_rad: float,
                     sonar: SonarConfig, fdtd: FdtdConfig) -> NDArray[np.complex128]:
    """Phase the grid adds over a straight path: ``exp(-i (k_num(f, phi) - k) L)``.

    ``k_num`` is the staggered scheme's wavenumber along ``direction_rad``
    (:func:`~mapping.simulate.fdtd_dispersion.numerical_wavenumber`); numpy's
    ``e^{+i w t}`` convention, so a slower grid delays. Outside the injected band
    ``(0, f_max)`` the phase is 1 (nothing was injected there).
    """
    c = fdtd.speed(sonar)
    f = np.asarray(f_hz, dtype=np.float64)
    _, f_max = injected_band(sonar, fdtd)
    k = 2 * np.pi * f / c
    kn = np.array([numerical_wavenumber(float(fi), direction_rad, fdtd.grid_step_m,
                                        fdtd.time_step_s, c) if 0 < fi < f_max else float(ki)
                   for fi, ki in zip(f.ravel(), k.ravel(), strict=True)]).reshape(f.shape)
    out: NDArray[np.complex128] = np.exp(-1j * (kn - k) * length_m)
    return out


def fdtd_length_m(points_m: ArrayLike, freq_hz: float, fdtd: FdtdConfig, c: float) -> float:
    """Length a polyline path appears to have in the FDTD: each leg scaled by
    ``c / v_g(freq_hz, leg direction)``, the grid's group velocity at ``freq_hz``.

    An envelope at ``freq_hz`` along the path arrives at ``fdtd_length_m / c`` instead of
    ``length / c``.
    """
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    if p.shape[0] < 2:
        raise ValueError(f"points_m must hold >= 2 points, got {p.shape[0]}")
    total = 0.0
    for a, b in itertools.pairwise(p):
        d = b - a
        length = float(np.hypot(d[0], d[1]))
        if length == 0:
            continue
        vg = numerical_group_velocity(freq_hz, math.atan2(d[1], d[0]), fdtd.grid_step_m,
                                      fdtd.time_step_s, c)
        total += length * c / vg
    return total


def render_paths(paths: PathTable, direction_rad: ArrayLike | None, sonar: SonarConfig,
                 fdtd: FdtdConfig, block_index: int, oversample: int = 32) -> FloatArray:
    """Image-source block ``block_index`` rebuilt path by path, as the FDTD grid would carry it.

    Path i contributes ``a_i s2d(t - tau_i(t))`` with ``tau_i(t) = tau_i + (1 - D_i)(t -
    t_mid)`` (delay and Doppler factor at the block midpoint ``t_mid``, as in the path
    table), ``s2d`` the 2-D signal period (:func:`mapping.simulate.ism.signal_period`,
    spreading ``"2d"``) band-limited by :func:`grid_band` and read off an ``oversample``-times
    finer periodic grid by linear interpolation.

    Parameters
    ----------
    paths : PathTable
        The image-source engine's ground truth for the block (``spreading="2d"``).
    direction_rad : array (n_paths,) or None
        Direction of each path in the grid (e.g. of its image seen from the receiver); the
        grid-dispersion phase of its length ``c tau_i`` along that direction is applied
        (:func:`dispersion_phase`). One direction per path is exact when every leg has the
        same dispersion, i.e. walls parallel to the grid axes or its diagonals (mirroring in
        them keeps ``|cos|`` and ``|sin|`` of a direction, or swaps them). None: no dispersion.
    sonar, fdtd : SonarConfig, FdtdConfig
    block_index : int
        Block k spans samples ``k B .. (k + 1) B - 1``.
    oversample : int
        Fineness of the interpolation grid (>= 1).
    """
    if oversample < 1:
        raise ValueError(f"oversample must be >= 1, got {oversample}")
    if block_index < 0:
        raise ValueError(f"block_index must be >= 0, got {block_index}")
    n_paths = int(paths.delay_s.size)
    dirs = None if direction_rad is None else np.asarray(direction_rad, dtype=np.float64)
    if dirs is not None and dirs.shape != (n_paths,):
        raise ValueError(f"direction_rad must have shape ({n_paths},), got {dirs.shape}")
    c = fdtd.speed(sonar)
    period = signal_period(sonar, "2d")
    p = period.size
    fs = sonar.fs_hz
    f: FloatArray = np.fft.rfftfreq(p, 1.0 / fs).astype(np.float64)
    spec = np.fft.rfft(period) * grid_band(f, sonar, fdtd)
    B = sonar.block_samples
    t = (block_index * B + np.arange(B)) / fs
    t_mid = (block_index + 0.5) * B / fs
    fine_n = p * oversample
    out = np.zeros(B)
    for i in range(n_paths):
        s = spec
        if dirs is not None:
            s = spec * dispersion_phase(f, c * float(paths.delay_s[i]), float(dirs[i]), sonar,
                                        fdtd)
        fine = np.fft.irfft(s, n=fine_n) * oversample
        tau = paths.delay_s[i] + (1.0 - paths.doppler_factor[i]) * (t - t_mid)
        pos = ((t - tau) * fs * oversample) % fine_n
        i0 = np.floor(pos).astype(np.int64)
        w = pos - i0
        out += paths.amplitude[i] * ((1 - w) * fine[i0 % fine_n] + w * fine[(i0 + 1) % fine_n])
    return out


# ---- waveform agreement ----------------------------------------------------------------------
def band_limited(samples: ArrayLike, sonar: SonarConfig, fdtd: FdtdConfig) -> FloatArray:
    """A waveform filtered by :func:`grid_band` (what the FDTD injects), circularly."""
    x = np.asarray(samples, dtype=np.float64)
    f = np.fft.rfftfreq(x.size, 1.0 / sonar.fs_hz)
    out: FloatArray = np.fft.irfft(np.fft.rfft(x) * grid_band(f, sonar, fdtd), x.size)
    return out


def residual_energy(reference: ArrayLike, model: ArrayLike) -> float:
    """``|reference - model|^2 / |reference|^2``: the share of the reference's energy a model
    leaves unexplained (1 for a silent model)."""
    r, m = np.asarray(reference, dtype=np.float64), np.asarray(model, dtype=np.float64)
    den = float(r @ r)
    if r.shape != m.shape or not den > 0:
        raise ValueError("reference and model must have the same shape, reference non-zero")
    return float((r - m) @ (r - m)) / den


def lag_s(reference: ArrayLike, model: ArrayLike, fs_hz: float, max_lag_s: float) -> float:
    """Delay (s) of ``reference`` relative to ``model`` at the largest circular
    cross-correlation within ``+-max_lag_s`` (parabolic refinement; positive: the reference
    arrives later)."""
    r, m = np.asarray(reference, dtype=np.float64), np.asarray(model, dtype=np.float64)
    if r.shape != m.shape or r.ndim != 1:
        raise ValueError("reference and model must be 1-D of the same length")
    xc = np.fft.irfft(np.fft.rfft(r) * np.conj(np.fft.rfft(m)), r.size)
    half = max(1, int(round(max_lag_s * fs_hz)))
    lags = np.arange(-half, half + 1)
    vals = xc[lags % r.size]
    i = int(np.clip(np.argmax(vals), 1, lags.size - 2))
    y0, y1, y2 = vals[i - 1], vals[i], vals[i + 1]
    den = y0 - 2 * y1 + y2
    frac = 0.5 * (y0 - y2) / den if den != 0 else 0.0
    return float((lags[i] + frac) / fs_hz)
