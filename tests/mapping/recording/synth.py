"""Synthetic raw recordings for the importer's tests, written from the conventions alone.

Recording sample n is taken at sonar time ``tau_n = n / (fs_rec (1 + e)) - latency``; from
``tau = 0`` the microphone hears the steady-state field: the direct wave (gain 1/offset,
delay offset/c) plus echoes ``gain * s(tau - delay(tau))``, before it noise only. Every
value comes from :func:`mapping.signal.transmitted_at`, independent of the importer.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from mapping.signal import SonarConfig, transmitted_at

Delay = Callable[[NDArray[np.float64]], NDArray[np.float64]]


@dataclass(frozen=True)
class Echo:
    """One echo: amplitude and delay (s) as a function of sonar time (s)."""

    gain: float
    delay_s: Delay


@dataclass(frozen=True)
class RawScene:
    fs_rec_hz: float = 44_100.0
    latency_s: float = 0.0371
    clock_offset_ppm: float = 0.0
    offset_m: float = 0.05
    sound_speed_m_s: float = 340.0
    duration_s: float = 6.0
    echoes: tuple[Echo, ...] = field(default_factory=tuple)
    noise_std: float = 0.0
    direct: bool = True

    def direct_gain(self) -> float:
        return 0.01 / self.offset_m  # 0.2 at 5 cm: loud but far from full scale

    def sonar_time(self, n: NDArray[np.float64]) -> NDArray[np.float64]:
        e = self.clock_offset_ppm * 1e-6
        return n / (self.fs_rec_hz * (1.0 + e)) - self.latency_s


def field_at(scene: RawScene, tau: NDArray[np.float64], config: SonarConfig,
             with_direct: bool = True) -> NDArray[np.float64]:
    """The noise-free microphone signal at sonar times ``tau`` (>= 0: steady state)."""
    out = np.zeros(tau.shape)
    if scene.direct and with_direct:
        out += scene.direct_gain() * transmitted_at(
            tau - scene.offset_m / scene.sound_speed_m_s, config)
    for echo in scene.echoes:
        out += echo.gain * transmitted_at(tau - echo.delay_s(tau), config)
    return np.where(tau >= 0.0, out, 0.0)


def raw_stream(scene: RawScene, config: SonarConfig,
               rng: np.random.Generator | None = None) -> NDArray[np.float64]:
    """The raw recording at ``scene.fs_rec_hz``."""
    n = np.arange(int(scene.duration_s * scene.fs_rec_hz), dtype=np.float64)
    x = field_at(scene, scene.sonar_time(n), config)
    if scene.noise_std > 0:
        assert rng is not None
        x = x + scene.noise_std * rng.standard_normal(x.size)
    return x


def wall_echo(range_m: float, speed_m_s: float = 0.0, gain: float = 0.002,
              c: float = 340.0) -> Echo:
    """A wall approached head-on at ``speed_m_s`` (range at tau = 0: ``range_m``); speed 0:
    constant range (a wall parallel to the path, or any static reflector)."""
    return Echo(gain, lambda tau: 2.0 * (range_m - speed_m_s * tau) / (c + speed_m_s))
