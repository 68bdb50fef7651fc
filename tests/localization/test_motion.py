"""Tests of the odometry motion model against analytic arcs and the noise formulas."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from localization.motion import (
    MotionNoise,
    apply_increment,
    motion_std,
    odometry_increment,
    predict,
    predict_mean,
)
from mapping.angles import wrap_angle

QUIET = MotionNoise(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@given(st.floats(-1.0, 1.0), st.floats(-2.0, 2.0), st.floats(0.0, 3.0), st.floats(-3.0, 3.0))
def test_arc_endpoint_matches_circle_geometry(v: float, w: float, dt: float, h0: float) -> None:
    """The chord decomposition lands on the exact circular arc x = R(sin(h0+wt) - sin h0)."""
    end = predict_mean(np.array([1.0, 2.0, h0]), v, w, dt)
    if abs(w) < 1e-6:
        ex, ey = 1.0 + v * dt * math.cos(h0), 2.0 + v * dt * math.sin(h0)
    else:
        r = v / w
        ex = 1.0 + r * (math.sin(h0 + w * dt) - math.sin(h0))
        ey = 2.0 - r * (math.cos(h0 + w * dt) - math.cos(h0))
    assert end[0] == pytest.approx(ex, abs=1e-6)
    assert end[1] == pytest.approx(ey, abs=1e-6)
    assert math.cos(end[2] - h0 - w * dt) == pytest.approx(1.0, abs=1e-9)


def test_noise_free_predict_equals_dead_reckoning() -> None:
    rng = np.random.default_rng(0)
    poses = rng.uniform(-1, 1, (50, 3))
    out = predict(poses, 0.2, 0.3, 1.023, QUIET, rng)
    for p, q in zip(poses, out, strict=True):
        np.testing.assert_allclose(q, predict_mean(p, 0.2, 0.3, 1.023), atol=1e-12)


def test_no_motion_adds_no_uncertainty() -> None:
    """AMCL-style: noise scales with the motion, so a robot at rest stays put."""
    rng = np.random.default_rng(1)
    poses = rng.uniform(-1, 1, (100, 3))
    poses[:, 2] = wrap_angle(poses[:, 2])
    out = predict(poses, 0.0, 0.0, 1.0, MotionNoise(), rng)
    np.testing.assert_allclose(out, poses, atol=1e-12)


def test_translation_noise_matches_alpha3() -> None:
    """Straight motion: std of the travelled distance = sqrt(alpha3) * trans (seeded, 3 %)."""
    noise = MotionNoise(alpha1=0.0, alpha2=0.0, alpha3=0.04, alpha4=0.0,
                        min_trans_std_m=0.0, min_rot_std_rad=0.0)
    rng = np.random.default_rng(2)
    out = predict(np.zeros((40000, 3)), 0.5, 0.0, 2.0, noise, rng)
    assert out[:, 0].mean() == pytest.approx(1.0, abs=0.005)
    assert out[:, 0].std() == pytest.approx(0.2, rel=0.03)
    np.testing.assert_allclose(out[:, 1:], 0.0, atol=1e-12)


def test_rotation_noise_matches_alpha1_alpha2() -> None:
    noise = MotionNoise(alpha1=0.1, alpha2=0.2, alpha3=0.0, alpha4=0.0,
                        min_trans_std_m=0.0, min_rot_std_rad=0.0)
    rot1, trans, rot2 = odometry_increment(0.2, 0.4, 1.0)
    s1, _, s2 = motion_std(rot1, trans, rot2, noise)
    assert s1 == pytest.approx(math.sqrt(0.1 * rot1**2 + 0.2 * trans**2))
    rng = np.random.default_rng(3)
    out = predict(np.zeros((40000, 3)), 0.2, 0.4, 1.0, noise, rng)
    assert np.std(wrap_angle(out[:, 2] - 0.4)) == pytest.approx(math.hypot(s1, s2), rel=0.03)


def test_apply_increment_does_not_mutate() -> None:
    poses = np.zeros((3, 3))
    apply_increment(poses, 0.1, 1.0, 0.1)
    assert not poses.any()


@pytest.mark.parametrize("args", [(math.nan, 0.0, 1.0), (0.1, math.inf, 1.0), (0.1, 0.0, -1.0),
                                  (50.0, 0.0, 1.0), (0.1, 0.0, 100.0)])
def test_bad_odometry_raises(args: tuple[float, float, float]) -> None:
    with pytest.raises(ValueError, match="speed_m_s|yaw_rate_rad_s|dt_s"):
        predict(np.zeros((2, 3)), *args, MotionNoise(), np.random.default_rng(0))


def test_bad_inputs_raise() -> None:
    with pytest.raises(ValueError, match="poses"):
        predict(np.zeros((2, 2)), 0.1, 0.0, 1.0, MotionNoise(), np.random.default_rng(0))
    with pytest.raises(ValueError, match="alpha3"):
        MotionNoise(alpha3=-1.0)
