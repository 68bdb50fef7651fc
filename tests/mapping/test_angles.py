"""Tests of mapping.angles: wrapping, circular statistics and pose errors against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.angles import (
    circular_mean,
    circular_std,
    circular_std_of_resultant,
    mean_resultant,
    pose_difference,
    pose_error,
    wrap_angle,
)


@given(st.floats(-100.0, 100.0))
def test_wrap_angle_range_and_equivalence(a: float) -> None:
    w = float(wrap_angle(a))
    assert -math.pi < w <= math.pi
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9)
    assert math.isclose(math.sin(w), math.sin(a), abs_tol=1e-9)


def test_wrap_angle_maps_minus_pi_to_pi() -> None:
    assert float(wrap_angle(-math.pi)) == pytest.approx(math.pi)


def test_circular_mean_across_pi() -> None:
    a = np.array([math.pi - 0.1, -math.pi + 0.1])
    assert abs(wrap_angle(circular_mean(a) - math.pi)) < 1e-12
    assert -math.pi < circular_mean(a) <= math.pi


@settings(max_examples=50, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(0.01, 0.5))
def test_circular_statistics_of_wrapped_normal(mu: float, sigma: float) -> None:
    """Samples of a wrapped normal: circular mean -> mu, circular std -> sigma."""
    rng = np.random.default_rng(0)
    a = wrap_angle(mu + sigma * rng.standard_normal(20000))
    assert abs(wrap_angle(circular_mean(a) - mu)) < 0.02
    assert circular_std(a) == pytest.approx(sigma, rel=0.05)


def test_mean_resultant_agrees_with_circular_mean_and_std() -> None:
    """The normalized pair (mean, R) gives the same mean (to rounding) and, through
    circular_std_of_resultant, the same spread as the weighted one-number functions."""
    rng = np.random.default_rng(4)
    a = 2.5 + 0.3 * rng.standard_normal(500)
    w = rng.uniform(0.1, 1.0, 500)
    mean, r = mean_resultant(a, w)
    assert wrap_angle(mean - circular_mean(a, w)) == pytest.approx(0.0, abs=1e-12)
    assert circular_std_of_resultant(r) == pytest.approx(circular_std(a, w), rel=1e-9)
    assert circular_std_of_resultant(0.0) == math.inf


def test_pose_error_and_difference_wrap_the_heading() -> None:
    a = np.array([1.0, 2.0, math.pi - 0.1])
    b = np.array([4.0, 6.0, -math.pi + 0.1])
    assert pose_error(a, b) == pytest.approx((5.0, 0.2))
    np.testing.assert_allclose(pose_difference(a, b), [-3.0, -4.0, -0.2], atol=1e-12)
    many = pose_difference(np.tile(a, (3, 1)), b)
    assert many.shape == (3, 3) and np.allclose(many[:, 2], -0.2)
