"""The paths a real robot hears besides the 2-D wall echoes, and the transducers' filters.

- :func:`vertical_images`: the images of the sonar in the floor and ceiling (a 1-D cavity of
  height H with the sonar at h): images at ``z = 2 m H + h`` (m != 0: |m| floor and |m|
  ceiling bounces, vertical path ``dz = 2 |m| H``) and ``z = 2 m H - h`` (``2m - 1`` bounces:
  m >= 1: m on the ceiling and m - 1 on the floor; m <= 0: 1 - m on the floor and -m on the
  ceiling; ``dz = |2 m H - 2 h|``); equal ``dz`` are merged (their coefficients add).
- :func:`static_paths`: direct wave and pure vertical bounces, constant delays, no Doppler.
- :func:`vertical_plan`: a planned stretch of wall paths lifted to 3-D through one vertical
  image (delay ``sqrt(tau2^2 + (dz / c)^2)``, its exact time derivative, gain times the
  image's coefficient; the kernel's 1/(c tau) is then the 3-D spreading).
- :func:`band_sos`: a transducer's Butterworth band-pass as second-order sections.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray
from scipy.signal import butter

from mapping.forward import vertical_images as forward_vertical_images
from mapping.simulate.ism import StretchPlan
from mapping.simulate.raw._config import RawConfig

FloatArray = NDArray[np.float64]


def vertical_images(raw: RawConfig) -> tuple[FloatArray, FloatArray]:
    """Vertical path lengths ``dz`` (m, increasing) and reflection products of the floor and
    ceiling images with at most ``raw.vertical_bounces`` bounces (empty without a floor):
    :func:`mapping.forward.vertical_images`, the one the echo sensor model predicts with."""
    return forward_vertical_images(raw.sonar_height_m, raw.ceiling_height_m,
                                   raw.floor_reflection, raw.ceiling_reflection,
                                   raw.vertical_bounces)


def static_paths(raw: RawConfig, c: float) -> tuple[FloatArray, FloatArray]:
    """Delays (s) and amplitudes of the paths that ride with the robot (no Doppler).

    The direct wave (``transducer_offset_m`` = d: delay d / c, amplitude 1 / d), the pure
    vertical bounces (delay ``sqrt(dz^2 + d^2) / c``, amplitude ``r / (c delay)``) and the
    robot's body echoes (``body_echoes``: delay ``path / c``, amplitude ``r / path``).
    """
    d = raw.transducer_offset_m
    delays, gains = [], []
    if d is not None:
        delays.append(d / c)
        gains.append(1.0 / d)
    dz_m, refl = vertical_images(raw)
    for dz, r in zip(dz_m, refl, strict=True):
        length = math.hypot(dz, d or 0.0)
        delays.append(length / c)
        gains.append(r / length)
    for path, r in raw.body_echoes:
        delays.append(path / c)
        gains.append(r / path)
    return np.array(delays), np.array(gains)


def vertical_plan(plan: StretchPlan, dz_m: float, reflection: float, c: float) -> StretchPlan:
    """The specular wall paths of ``plan`` after an extra vertical path ``dz_m`` (no edges).

    ``tau3 = sqrt(tau^2 + a^2)``, ``a = dz / c``; ``d tau3 / dt = tau / tau3 * d tau / dt``
    (only the horizontal part of the path changes); gains times ``reflection``.
    """
    a = dz_m / c
    tau3 = np.sqrt(plan.tau**2 + a * a)
    return replace(
        plan,
        tau=tau3,
        dtau=plan.tau / tau3 * plan.dtau,
        gain=plan.gain * reflection,
        edge_active=np.zeros(0, np.int64),
    )


def band_sos(band_hz: tuple[float, float], order: int, fs_hz: float) -> FloatArray:
    """Second-order sections of a Butterworth band-pass ``band_hz`` at rate ``fs_hz``.

    Raises ``ValueError`` when the band's top reaches ``fs_hz / 2``.
    """
    lo, hi = band_hz
    if not 0 < lo < hi < fs_hz / 2:
        raise ValueError(
            f"band {band_hz} Hz must satisfy 0 < lo < hi < fs / 2 = {fs_hz / 2:g} Hz of the sonar"
        )
    return np.asarray(butter(order, [lo, hi], btype="bandpass", fs=fs_hz, output="sos"))
