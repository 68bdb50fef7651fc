"""What the FDTD grid carries and injects: numerical dispersion, the source signal, resampling.

The dispersion relation of the staggered scheme (paper eqs. 9-11) gives the grid's wavenumber
and group velocity (:class:`FdtdReport` quotes their error), the injected mass source is the
transmitted signal filtered to the 2-D free-field convention and band-limited to the grid
(:func:`source_filter`, :func:`source_signal`), and the per-step receiver series is resampled to
the sonar rate by a Kaiser-windowed sinc (:func:`resample_to_rate`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq

from mapping.signal import (
    TABLE_UPSAMPLE,
    SonarConfig,
    periodic_table,
    periodic_table_at,
    tx_period,
)
from mapping.simulate.fdtd._config import FdtdConfig, injected_band
from mapping.simulate.fdtd._grid import FdtdGrid

FloatArray = NDArray[np.float64]

_RESAMPLE_HALF_WIDTH = 96


# ---- numerical dispersion -----------------------------------------------------------------
def numerical_wavenumber(freq_hz: float, angle_rad: float, grid_step_m: float,
                         time_step_s: float, c: float) -> float:
    """Wavenumber |k| of the staggered scheme at ``freq_hz`` along ``angle_rad``.

    Solves the dispersion relation of eqs. 9-11,
    ``sin^2(w dt / 2) / (c dt)^2 = [sin^2(kx dx / 2) + sin^2(ky dx / 2)] / dx^2``.
    """
    w, dx, dt = 2 * math.pi * freq_hz, grid_step_m, time_step_s
    ca, sa = abs(math.cos(angle_rad)), abs(math.sin(angle_rad))
    rhs = (math.sin(w * dt / 2) * dx / (c * dt)) ** 2

    def g(k: float) -> float:
        return math.sin(k * ca * dx / 2) ** 2 + math.sin(k * sa * dx / 2) ** 2 - rhs

    k_hi = math.pi / (dx * max(ca, sa))
    if g(k_hi) < 0:
        raise ValueError(f"freq_hz={freq_hz:g} is above the grid's cut-off along {angle_rad} rad")
    return float(brentq(g, 1e-12, k_hi, xtol=1e-12, rtol=1e-14))


def numerical_group_velocity(freq_hz: float, angle_rad: float, grid_step_m: float,
                             time_step_s: float, c: float) -> float:
    """Group velocity dw/d|k| of the grid at ``freq_hz`` along ``angle_rad`` (m/s)."""
    df = 1e-4 * freq_hz
    k1 = numerical_wavenumber(freq_hz - df, angle_rad, grid_step_m, time_step_s, c)
    k2 = numerical_wavenumber(freq_hz + df, angle_rad, grid_step_m, time_step_s, c)
    return 2 * math.pi * 2 * df / (k2 - k1)


@dataclass(frozen=True)
class FdtdReport:
    """Set-up numbers of an FDTD run (printed by the CLI).

    ``group_velocity_error_*`` are ``v_g / c - 1`` along the grid axis and the diagonal
    (negative = slow).
    """

    shape: tuple[int, int]
    origin_m: tuple[float, float]
    grid_step_m: float
    time_step_s: float
    courant: float
    signal_band_edge_hz: float
    injected_max_hz: float
    points_per_wavelength_signal_edge: float
    points_per_wavelength_injected_edge: float
    group_velocity_error_carrier: tuple[float, float]
    group_velocity_error_injected_edge: tuple[float, float]
    n_steps: int
    warmup_steps: int
    field_bytes: int

    def lines(self) -> list[str]:
        """Human-readable summary, one item per line."""
        gc, ge = self.group_velocity_error_carrier, self.group_velocity_error_injected_edge
        return [
            f"grid {self.shape[0]} x {self.shape[1]} cells of {self.grid_step_m * 1e3:g} mm, "
            f"dt {self.time_step_s * 1e6:.4g} us, Courant {self.courant:.3f}",
            f"points per wavelength: {self.points_per_wavelength_signal_edge:.2f} at the signal "
            f"band edge {self.signal_band_edge_hz / 1e3:g} kHz, "
            f"{self.points_per_wavelength_injected_edge:.2f} at the injected edge "
            f"{self.injected_max_hz / 1e3:.3g} kHz",
            f"group-velocity error at the carrier: {gc[0] * 100:+.2f} % (axis) "
            f"{gc[1] * 100:+.2f} % (diagonal); at the injected edge {ge[0] * 100:+.2f} % / "
            f"{ge[1] * 100:+.2f} %",
            f"{self.n_steps} steps ({self.warmup_steps} warm-up), "
            f"{self.field_bytes / 1e6:.1f} MB of fields",
        ]


def _report(grid: FdtdGrid, sonar: SonarConfig, fdtd: FdtdConfig, c: float, courant: float,
            n_steps: int, warmup_steps: int) -> FdtdReport:
    edge, fmax = injected_band(sonar, fdtd)
    dx, dt = fdtd.grid_step_m, fdtd.time_step_s

    def one(f: float, a: float) -> float:
        try:
            return numerical_group_velocity(f, a, dx, dt, c) / c - 1
        except ValueError:  # above the grid's cut-off: the grid does not carry it at all
            return float("nan")

    def err(f: float) -> tuple[float, float]:
        return one(f, 0.0), one(f, math.pi / 4)

    nx, ny = grid.shape
    nbytes = 2 * (4 * nx * ny + nx + ny) * np.dtype(fdtd.dtype).itemsize
    return FdtdReport(
        shape=grid.shape, origin_m=grid.origin_m, grid_step_m=dx, time_step_s=dt,
        courant=courant, signal_band_edge_hz=edge, injected_max_hz=fmax,
        points_per_wavelength_signal_edge=c / (edge * dx),
        points_per_wavelength_injected_edge=c / (fmax * dx),
        group_velocity_error_carrier=err(sonar.carrier_hz),
        group_velocity_error_injected_edge=err(fmax),
        n_steps=n_steps, warmup_steps=warmup_steps, field_bytes=nbytes,
    )


# ---- the injected source signal -----------------------------------------------------------
def source_filter(freq_hz: ArrayLike, sonar: SonarConfig, fdtd: FdtdConfig) -> NDArray[Any]:
    """Complex gain from the transmitted signal to the per-step pressure increment.

    The injected volume velocity (per unit depth) is ``Q = sqrt(8 pi k_c) s / (i w rho)``,
    ``k_c = 2 pi f_c / c``, so that the field is ``sqrt(8 pi k_c)`` times the 2-D Green's
    function ``G = (-i/4) H0^(2)(k r)`` convolved with ``s`` -- the convention of the
    image-source engine's ``2d`` spreading (far field ``s(t - r/c)`` half-integrated, with
    ``1/sqrt(r)`` decay and unit gain at the carrier). The per-step increment is
    ``rho c^2 dt / dx^2 * Q``; raised-cosine tapers 0 -> 0.1 f_c (high-pass) and
    0.8 f_max -> f_max (low-pass, band limit of the grid) multiply it. Numpy FFT sign
    convention (``e^{+i w t}``).
    """
    c = fdtd.speed(sonar)
    _, fmax = injected_band(sonar, fdtd)
    fs = np.asarray(freq_hz, dtype=np.float64)
    f = np.abs(fs)
    f_lo = 0.1 * sonar.carrier_hz
    hp = np.where(f >= f_lo, 1.0, 0.5 - 0.5 * np.cos(np.pi * np.clip(f / f_lo, 0, 1)))
    x = np.clip((f - 0.8 * fmax) / (0.2 * fmax), 0, 1)
    lp = 0.5 + 0.5 * np.cos(np.pi * x)
    k_c = 2 * np.pi * sonar.carrier_hz / c
    w = 2 * np.pi * np.where(fs == 0, 1.0, fs)
    gain = c * c * fdtd.time_step_s / fdtd.grid_step_m**2 * math.sqrt(8 * np.pi * k_c)
    return np.asarray(np.where(fs == 0, 0.0, gain * hp * lp / (1j * w)))


@lru_cache(maxsize=8)
def _source_table(sonar: SonarConfig, fdtd: FdtdConfig, filtered: bool) -> FloatArray:
    period = tx_period(sonar)
    p = period.size
    spec = np.fft.rfft(period)
    if filtered:
        spec = spec * source_filter(np.fft.rfftfreq(p, 1 / sonar.fs_hz), sonar, fdtd)
    return periodic_table(spec, p)


def source_signal(t_s: ArrayLike, sonar: SonarConfig, fdtd: FdtdConfig,
                  filtered: bool = True) -> FloatArray:
    """Injected per-step pressure increment g(t) (``filtered=False``: the plain band-limited
    transmitted signal, equal to ``mapping.signal.transmitted_at``).

    Periodic band-limited interpolation (cubic Lagrange on a 32x table) of the filtered
    period spectrum.
    """
    u = np.asarray(t_s, dtype=np.float64) * (sonar.fs_hz * TABLE_UPSAMPLE)
    return periodic_table_at(_source_table(sonar, fdtd, filtered), u)


def resample_to_rate(series: FloatArray, t_first_s: float, step_s: float, fs_hz: float,
                     first_sample: int, n_samples: int) -> FloatArray:
    """Band-limited resampling of a step series (sample m at ``t_first_s + m step_s``) to the
    sonar samples ``first_sample ..`` at ``k / fs_hz``; Kaiser-windowed sinc, cut-off fs / 2.

    Needs the series to cover ``_RESAMPLE_HALF_WIDTH`` steps beyond each output time.
    """
    series = np.asarray(series, dtype=np.float64)
    t = (first_sample + np.arange(n_samples)) / fs_hz
    pos = (t - t_first_s) / step_s
    base = np.floor(pos).astype(np.int64)
    h = _RESAMPLE_HALF_WIDTH
    if n_samples and (base[0] - h + 1 < 0 or base[-1] + h >= series.size):
        raise ValueError("series does not cover the requested samples plus the filter length")
    out = np.zeros(n_samples)
    fc = min(0.5 * fs_hz, 0.5 / step_s)
    beta = 8.0
    norm = np.i0(beta)
    for m in range(-h + 1, h + 1):
        tau = (pos - (base + m)) * step_s
        x = np.clip(tau / (h * step_s), -1, 1)
        win = np.i0(beta * np.sqrt(1 - x * x)) / norm
        out += series[base + m] * (2 * fc * step_s) * np.sinc(2 * fc * tau) * win
    return out
