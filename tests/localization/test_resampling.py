"""Tests of log-weight normalization and systematic resampling (kernel vs numpy twin)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.special import logsumexp

from localization.resampling import (
    effective_sample_size,
    log_sum_exp,
    normalize_log_weights,
    systematic_resample,
    systematic_resample_u0,
)
from tests.localization.naive import systematic_resample_numpy

weights_st = arrays(np.float64, st.integers(1, 60), elements=st.floats(0.0, 1.0)).filter(
    lambda w: w.sum() > 1e-6)


@settings(max_examples=60, deadline=None)
@given(weights_st, st.floats(0.0, 0.999999), st.integers(1, 80))
def test_kernel_matches_numpy_twin(w: np.ndarray, u0: float, n_out: int) -> None:
    np.testing.assert_array_equal(systematic_resample_u0(w, u0, n_out),
                                  systematic_resample_numpy(w, u0, n_out))


@settings(max_examples=60, deadline=None)
@given(weights_st, st.floats(0.0, 0.999999))
def test_counts_are_floor_or_ceil_of_n_w(w: np.ndarray, u0: float) -> None:
    """Systematic resampling copies particle i floor(n w_i) or ceil(n w_i) times."""
    n = w.size
    counts = np.bincount(systematic_resample_u0(w, u0, n), minlength=n)
    expected = n * w / w.sum()
    assert counts.sum() == n
    assert np.all(counts >= np.floor(expected - 1e-9))
    assert np.all(counts <= np.ceil(expected + 1e-9))


def test_counts_match_n_w_in_expectation() -> None:
    """Averaged over u0 the counts equal n w_i (the filterpy issue 290 check), within 1 %."""
    rng = np.random.default_rng(0)
    w = rng.dirichlet(np.full(37, 0.5))
    n = 1000
    total = np.zeros(w.size)
    reps = 2000
    for _ in range(reps):
        total += np.bincount(systematic_resample(w, rng, n), minlength=w.size)
    np.testing.assert_allclose(total / reps, n * w, atol=0.01 * n * w.max() + 0.02)


def test_zero_weight_never_drawn() -> None:
    w = np.array([0.0, 0.5, 0.0, 0.5, 0.0])
    idx = systematic_resample(w, np.random.default_rng(1))
    assert set(idx.tolist()) <= {1, 3}


def test_normalize_1e5_particles_sharp_no_underflow() -> None:
    """Log-likelihoods spread over 1e4 nats: exp would underflow; log-sum-exp does not."""
    rng = np.random.default_rng(2)
    log_w = -1e4 * rng.random(100_000) - 800.0
    norm, lse = normalize_log_weights(log_w)
    assert math.isfinite(lse)
    assert np.exp(norm).sum() == pytest.approx(1.0, abs=1e-12)
    assert 1.0 <= effective_sample_size(norm) <= 100_000
    idx = systematic_resample(np.exp(norm - norm.max()), rng)
    assert idx.shape == (100_000,)


def test_ess_bounds() -> None:
    n = 10
    uniform, _ = normalize_log_weights(np.zeros(n))
    assert effective_sample_size(uniform) == pytest.approx(n)
    one = np.full(n, -np.inf)
    one[3] = 0.0
    assert effective_sample_size(one) == pytest.approx(1.0)


def test_bad_weights_raise() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="all -inf"):
        normalize_log_weights(np.full(4, -np.inf))
    with pytest.raises(ValueError, match="NaN"):
        normalize_log_weights(np.array([0.0, np.nan]))
    with pytest.raises(ValueError, match="sum to zero"):
        systematic_resample(np.zeros(3), rng)
    with pytest.raises(ValueError, match=">= 0"):
        systematic_resample(np.array([0.5, -0.1]), rng)
    with pytest.raises(ValueError, match="u0"):
        systematic_resample_u0(np.ones(3), 1.0, 3)


@settings(max_examples=80, deadline=None)
@given(arrays(np.float64, st.integers(1, 300),
              elements=st.floats(-1e4, 1e4) | st.just(-math.inf)))
def test_log_sum_exp_matches_scipy(a: np.ndarray) -> None:
    """The filter's own log-sum-exp against scipy's (an independent implementation), with
    spreads far beyond exp's range and -inf entries (zero weights)."""
    want = float(logsumexp(a))
    got = log_sum_exp(a)
    if math.isinf(want):
        assert got == want
    else:
        assert got == pytest.approx(want, rel=1e-12, abs=1e-12)


def test_log_sum_exp_edges() -> None:
    """All -inf is -inf (no NaN from inf - inf); NaN or +inf propagate."""
    assert log_sum_exp(np.full(4, -math.inf)) == -math.inf
    assert log_sum_exp(np.array([0.0, math.inf])) == math.inf
    assert math.isnan(log_sum_exp(np.array([0.0, math.nan])))
