"""Parameters of the image-source engine and the signal one path is heard with.

:class:`IsmConfig` bundles the engine's parameters (order, limits, spreading, fractional
delay, grids, noise, reverberant tail). The spreading it names decides the signal an image
source is heard with (:func:`signal_period`: the transmitted period for ``3d``, the 2-D
line-source filtered period for ``2d``) and the exponent of its 1/r**p amplitude
(:func:`spreading_power`). Used by :mod:`mapping.simulate.ism` and its helpers.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping.signal import SonarConfig, periodic_table, tx_period

FloatArray = NDArray[np.float64]

#: Allowed values of ``IsmConfig.spreading`` and ``IsmConfig.fractional_delay``.
_SPREADINGS = ("2d", "3d")
_FRACTIONAL_DELAYS = ("table", "sinc")


@dataclass(frozen=True)
class IsmConfig:
    """Parameters of the image-source engine.

    Parameters
    ----------
    order : int or None
        Highest reflection order; None chooses it: the lowest order that captures every path
        no longer than ``max_path_m`` (whose amplitude is above ``energy_threshold_db``).
    max_order : int
        Cap for the automatic order.
    max_images : int
        Cap on candidate image sources per block: the automatic order stops at the last order
        completed below it (recorded as ``order_truncated`` in the block metadata); a fixed
        order raises ``ValueError``.
    max_path_m : float or None
        Longest path kept with the automatic order; None is one period's round trip,
        ``c P / fs`` (34.78 m for Table 1: one-way 17.39 m, the unambiguous range).
    energy_threshold_db : float
        Paths whose amplitude (reflection product times spreading, relative to a rigid path
        of 1 m) is below this are left out.
    spreading : {"3d", "2d"}
        ``3d``: 1/r, a point source (a real robot). ``2d``: the line source of a 2-D
        simulation (1/sqrt(r) with the -pi/4 phase and 1/sqrt(f) spectrum of the 2-D Green's
        function, normalised to 1/sqrt(r) at the carrier), to compare with a 2-D FDTD.
    fractional_delay : {"table", "sinc"}
        ``table``: the band-limited interpolant through a 32x table (error ~1e-6);
        ``sinc``: Blackman-windowed sinc of ``2 * sinc_half_taps`` taps.
    sinc_half_taps : int
        Half length of the windowed sinc.
    delay_grid_s : float
        Spacing of the Newton solutions of the retarded delay.
    validity_grid_s : float
        Spacing of the path validity (specular point on the segment, no occlusion) checks.
    fade_s : float
        Duration of the raised-cosine fade when a path appears or disappears; at most
        ``validity_grid_s``.
    newton_steps : int
        Newton iterations per delay node (2-3 suffice: v/c ~ 3e-4).
    snr_db : float or None
        White Gaussian noise at this per-sample SNR (against the block's echo power); None: none.
    odometry_noise_m_s : float
        Standard deviation of Gaussian noise on the recorded speed of each block.
    rt60_s : float or None
        Add a diffuse reverberant tail with this reverberation time; None: none.
    reverb_db : float
        Level of the tail relative to the first-order echoes at the start of the run.
    reverb_onset_s : float
        Delay where the tail starts (it fades in over 5 ms).
    diffraction_order : int
        Edge diffraction at free wall ends and outside corners (uniform theory of
        diffraction, :mod:`mapping.simulate.ism._diffraction`): 0 none (the default), 1 the
        edge alone (sonar -> edge -> sonar), 2 also with one specular reflection before or
        after the edge.
    """

    order: int | None = None
    max_order: int = 20
    max_images: int = 5000
    max_path_m: float | None = None
    energy_threshold_db: float = -60.0
    spreading: str = "3d"
    fractional_delay: str = "table"
    sinc_half_taps: int = 32
    delay_grid_s: float = 0.0025
    validity_grid_s: float = 0.01
    fade_s: float = 0.005
    newton_steps: int = 3
    snr_db: float | None = None
    odometry_noise_m_s: float = 0.0
    rt60_s: float | None = None
    reverb_db: float = -20.0
    reverb_onset_s: float = 0.02
    diffraction_order: int = 0

    def __post_init__(self) -> None:
        if self.order is not None and not 1 <= self.order <= 50:
            raise ValueError(f"IsmConfig.order must be None or in 1..50, got {self.order}")
        if not 1 <= self.max_images <= 1_000_000:
            raise ValueError(
                f"IsmConfig.max_images must be in 1..1000000, got {self.max_images}"
            )
        if not 1 <= self.max_order <= 50:
            raise ValueError(f"IsmConfig.max_order must be in 1..50, got {self.max_order}")
        if self.spreading not in _SPREADINGS:
            raise ValueError(
                f"IsmConfig.spreading must be one of {_SPREADINGS}, got {self.spreading!r}"
            )
        if self.fractional_delay not in _FRACTIONAL_DELAYS:
            raise ValueError(
                f"IsmConfig.fractional_delay must be one of {_FRACTIONAL_DELAYS}, "
                f"got {self.fractional_delay!r}"
            )
        if not 2 <= self.sinc_half_taps <= 512:
            raise ValueError(
                f"IsmConfig.sinc_half_taps must be in 2..512, got {self.sinc_half_taps}"
            )
        if not 1e-4 <= self.delay_grid_s <= 0.02:
            raise ValueError(
                f"IsmConfig.delay_grid_s must be in [1e-4, 0.02] s, got {self.delay_grid_s}"
            )
        if not 1e-3 <= self.validity_grid_s <= 0.1:
            raise ValueError(
                f"IsmConfig.validity_grid_s must be in [1e-3, 0.1] s, got {self.validity_grid_s}"
            )
        if not 0 < self.fade_s <= self.validity_grid_s:
            raise ValueError(
                f"IsmConfig.fade_s must be in (0, validity_grid_s={self.validity_grid_s}], "
                f"got {self.fade_s}"
            )
        if not 1 <= self.newton_steps <= 20:
            raise ValueError(f"IsmConfig.newton_steps must be in 1..20, got {self.newton_steps}")
        if self.max_path_m is not None and not self.max_path_m > 0:
            raise ValueError(f"IsmConfig.max_path_m must be None or > 0, got {self.max_path_m}")
        if self.snr_db is not None and not math.isfinite(self.snr_db):
            raise ValueError(f"IsmConfig.snr_db must be None or finite, got {self.snr_db}")
        if not (math.isfinite(self.odometry_noise_m_s) and self.odometry_noise_m_s >= 0):
            raise ValueError(
                f"IsmConfig.odometry_noise_m_s must be >= 0, got {self.odometry_noise_m_s}"
            )
        if self.rt60_s is not None and not 0.01 <= self.rt60_s <= 10:
            raise ValueError(f"IsmConfig.rt60_s must be None or in [0.01, 10] s, got {self.rt60_s}")
        if not 0 <= self.reverb_onset_s < 1:
            raise ValueError(
                f"IsmConfig.reverb_onset_s must be in [0, 1) s, got {self.reverb_onset_s}"
            )

        if self.diffraction_order not in (0, 1, 2):
            raise ValueError(
                f"IsmConfig.diffraction_order must be 0, 1 or 2, got {self.diffraction_order!r}"
            )

    def to_dict(self) -> dict[str, Any]:
        """Plain dictionary of the fields (for run metadata)."""
        return asdict(self)


# ---- the transmitted signal as heard through one path --------------------------------
@lru_cache(maxsize=8)
def signal_period(config: SonarConfig, spreading: str) -> FloatArray:
    """One period of the signal an image source is heard with (before the 1/r^p spreading).

    ``3d``: the transmitted period itself. ``2d``: the period filtered by the far field of
    the 2-D Green's function, ``G(w, r) = (-i/4) H0^(2)(k r) ~ e^{-i(kr + pi/4)} /
    sqrt(8 pi k r)``: each positive frequency is multiplied by ``sqrt(f_c / f) e^{-i pi/4}``
    (a half-order integrator: the 1/sqrt(t) tail of the 2-D impulse response), normalised
    so the carrier keeps its amplitude. So ``2d`` paths are ``sqrt(8 pi k_c)`` times the
    2-D Green's function response. DC is dropped (the BPSK spectrum has a null there).
    """
    period = np.asarray(tx_period(config), dtype=np.float64)
    if spreading == "3d":
        out = period.copy()
    elif spreading == "2d":
        out = np.fft.irfft(np.fft.rfft(period) * _half_integrator(config), n=period.size)
    else:
        raise ValueError(f"spreading must be one of {_SPREADINGS}, got {spreading!r}")
    out.setflags(write=False)
    return out


def _half_integrator(config: SonarConfig) -> NDArray[np.complex128]:
    """``sqrt(f_c / f) e^{-i pi/4}`` on the rfft bins of one period (0 at DC, the Nyquist
    bin kept real): the spectrum of the 2-D Green's function's far field, and of the
    diffraction coefficient of an edge, relative to the carrier."""
    p = config.period_samples
    f = np.fft.rfftfreq(p, 1.0 / config.fs_hz)
    filt = np.zeros(f.size, dtype=complex)
    filt[1:] = np.sqrt(config.carrier_hz / f[1:]) * np.exp(-1j * np.pi / 4)
    if p % 2 == 0:
        filt[-1] = filt[-1].real  # the Nyquist bin must stay real
    return filt


@lru_cache(maxsize=16)
def diffraction_period(config: SonarConfig, spreading: str, keller: bool = True,
                       quadrature: bool = False) -> FloatArray:
    """One period of a signal an edge-diffracted path is heard with.

    Far from shadow boundaries (Keller) an edge's diffraction coefficient falls as
    ``1/sqrt(k)`` with a ``-pi/4`` phase: the diffracted signal is :func:`signal_period`
    filtered once more by ``sqrt(f_c / f) e^{-i pi/4}`` (normalised at the carrier;
    ``keller=True``). At a shadow boundary the coefficient's spectrum is that of the path
    signal itself (``keller=False``); the engine mixes the two. ``quadrature``: every
    positive frequency multiplied by ``i``, so ``a * period + b * quadrature`` is the signal
    times the complex gain ``a + i b``.
    """
    spec = np.fft.rfft(signal_period(config, spreading))
    if keller:
        spec = spec * _half_integrator(config)
    if quadrature:
        spec = spec * 1j
    out = np.fft.irfft(spec, n=config.period_samples)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=8)
def _table(config: SonarConfig, spreading: str) -> FloatArray:
    """Periodic band-limited interpolant of :func:`signal_period` on a 32x finer grid."""
    period = signal_period(config, spreading)
    return periodic_table(np.fft.rfft(period), period.size)


@lru_cache(maxsize=16)
def _diffraction_table(config: SonarConfig, spreading: str, keller: bool,
                       quadrature: bool) -> FloatArray:
    """Periodic band-limited interpolant of :func:`diffraction_period` on a 32x finer grid."""
    period = diffraction_period(config, spreading, keller, quadrature)
    return periodic_table(np.fft.rfft(period), period.size)


def spreading_power(spreading: str) -> float:
    """Exponent p of the amplitude 1 / r**p: 1 for ``3d``, 1/2 for ``2d``."""
    if spreading not in _SPREADINGS:
        raise ValueError(f"spreading must be one of {_SPREADINGS}, got {spreading!r}")
    return 1.0 if spreading == "3d" else 0.5


def range_limit_m(config: SonarConfig) -> float:
    """Longest round-trip path inside one period, ``c P / fs`` (twice the max range)."""
    return 2.0 * config.max_range_m
