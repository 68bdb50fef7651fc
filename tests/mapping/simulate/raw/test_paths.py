"""Floor and ceiling images, static paths and the 3-D lift of a plan, by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mapping.simulate.ism import plan_stretch, prepare_scene
from mapping.simulate.raw import (
    RawConfig,
    band_sos,
    static_paths,
    vertical_images,
    vertical_plan,
)
from tests.mapping.simulate.raw.helpers import CFG, ENGINE, driving, one_wall


def test_vertical_images_by_hand() -> None:
    """h = 0.3, H = 2.6. Up to two bounces: floor 2h = 0.6 m (rf), ceiling 2(H - h) = 4.6 m
    (rc), floor-ceiling and ceiling-floor 2H = 5.2 m (2 rf rc). Three bounces add
    floor-ceiling-floor 2H + 2h = 5.8 m (rf^2 rc) and ceiling-floor-ceiling 4H - 2h = 9.8 m
    (rf rc^2)."""
    rf, rc = 0.9, 0.7
    raw = RawConfig(sonar_height_m=0.3, ceiling_height_m=2.6, floor_reflection=rf,
                    ceiling_reflection=rc, vertical_bounces=2)
    dz, refl = vertical_images(raw)
    assert np.allclose(dz, [0.6, 4.6, 5.2])
    assert np.allclose(refl, [rf, rc, 2 * rf * rc])
    dz3, refl3 = vertical_images(RawConfig(sonar_height_m=0.3, ceiling_height_m=2.6,
                                           floor_reflection=rf, ceiling_reflection=rc,
                                           vertical_bounces=3))
    assert np.allclose(dz3, [0.6, 4.6, 5.2, 5.8, 9.8])
    assert np.allclose(refl3, [rf, rc, 2 * rf * rc, rf**2 * rc, rf * rc**2])


def test_floor_alone_and_no_floor() -> None:
    dz, refl = vertical_images(RawConfig(sonar_height_m=0.4, floor_reflection=0.5))
    assert np.allclose(dz, [0.8]) and np.allclose(refl, [0.5])
    assert vertical_images(RawConfig())[0].size == 0


def test_static_paths_direct_then_vertical() -> None:
    """Direct: d / c, 1 / d. Floor with the offset: sqrt(2h^2 + d^2) / c, r / length."""
    c, d, h = 343.0, 0.05, 0.3
    delays, gains = static_paths(RawConfig(transducer_offset_m=d, sonar_height_m=h,
                                           floor_reflection=0.9), c)
    length = math.hypot(2 * h, d)
    assert np.allclose(delays, [d / c, length / c])
    assert np.allclose(gains, [1 / d, 0.9 / length])


def test_vertical_plan_delay_and_its_derivative() -> None:
    """tau3 = sqrt(tau^2 + (dz/c)^2) at the nodes; its derivative matches a finite
    difference of the Hermite nodes (1e-6 relative); gains scaled."""
    prepared = prepare_scene(one_wall(), CFG, ENGINE)
    plan = plan_stretch(prepared, driving(), CFG, ENGINE, 0, 8000)
    lifted = vertical_plan(plan, 0.6, 0.9, CFG.sound_speed_m_s)
    a = 0.6 / CFG.sound_speed_m_s
    assert np.allclose(lifted.tau, np.sqrt(plan.tau**2 + a * a))
    step = ENGINE.delay_grid_s
    fd = np.gradient(lifted.tau, step, axis=1)[:, 1:-1]
    assert np.allclose(lifted.dtau[:, 1:-1], fd, rtol=1e-4, atol=1e-9)
    assert np.allclose(lifted.gain, 0.9 * plan.gain)


def test_band_above_the_sonar_nyquist_is_refused() -> None:
    with pytest.raises(ValueError, match="fs / 2 = 20000"):
        band_sos((1_000.0, 21_000.0), 2, CFG.fs_hz)
