"""Tests of mapping.signal against independent truths (m-sequence theory, the DFT)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.signal import (
    SonarConfig,
    mseq_chips,
    transmitted_at,
    transmitted_exact,
    tx_block,
    tx_period,
    tx_samples,
)


def test_table1_defaults_and_derived_values() -> None:
    cfg = SonarConfig()
    assert cfg.period_samples == 4092
    assert cfg.block_samples == 40920
    assert cfg.block_s == pytest.approx(1.023)
    assert cfg.range_per_sample_m == pytest.approx(340 / 80_000)
    assert cfg.max_range_m == pytest.approx(17.391, abs=1e-3)
    assert cfg.angles_rad.shape == (30,)
    assert cfg.angles_rad[-1] == pytest.approx(math.pi)


@pytest.mark.parametrize("nbits", [5, 7, 10])
def test_mseq_circular_autocorrelation_is_two_valued(nbits: int) -> None:
    cfg = SonarConfig(sequence_length=2**nbits - 1, carrier_hz=10_000.0)
    chips = mseq_chips(cfg)
    acf = np.array([np.dot(chips, np.roll(chips, k)) for k in range(chips.size)])
    assert acf[0] == chips.size
    np.testing.assert_allclose(acf[1:], -1.0)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("sequence_length", 1000),
        ("fs_hz", 45_000.0),
        ("carrier_hz", -1.0),
        ("repetitions", 0),
        ("directions", 0),
        ("sound_speed_m_s", float("nan")),
        ("carrier_hz", 25_000.0),
        ("mseq_state", (0,) * 10),
        ("mseq_taps", (2,)),
    ],
)
def test_invalid_config_names_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=field):
        SonarConfig(**{field: value})  # type: ignore[arg-type]


def test_config_json_round_trip_and_unknown_field() -> None:
    cfg = SonarConfig(repetitions=4, mseq_state=(1, 0, 1, 1, 0, 0, 1, 0, 1, 1))
    assert SonarConfig.from_json(cfg.to_json()) == cfg
    with pytest.raises(ValueError, match="bogus"):
        SonarConfig.from_dict({"bogus": 1})


def test_config_determines_waveform() -> None:
    a = tx_period(SonarConfig())
    b = tx_period(SonarConfig(mseq_state=(1, 0, 1, 1, 0, 0, 1, 0, 1, 1)))
    assert not np.allclose(a, b)
    np.testing.assert_array_equal(a, tx_period(SonarConfig()))


def test_default_carrier_phase_has_no_zero_samples() -> None:
    assert np.min(np.abs(tx_period(SonarConfig()))) > 0.7


def test_block_is_continuous_and_periodic() -> None:
    cfg = SonarConfig(repetitions=3)
    two = np.concatenate([tx_block(cfg, 0), tx_block(cfg, 1)])
    np.testing.assert_array_equal(two, tx_samples(cfg, 0, 2 * cfg.block_samples))
    p = cfg.period_samples
    np.testing.assert_array_equal(two[:p], two[p : 2 * p])


def test_transmitted_at_matches_samples_and_exact_interpolant() -> None:
    cfg = SonarConfig()
    n = np.arange(0, 200)
    np.testing.assert_allclose(transmitted_at(n / cfg.fs_hz, cfg), tx_period(cfg)[n], atol=1e-9)
    rng = np.random.default_rng(0)
    t = rng.uniform(-1.0, 3.0, size=64)
    exact = transmitted_exact(t, cfg)
    fast = transmitted_at(t, cfg)
    assert np.max(np.abs(fast - exact)) < 5e-6 * np.max(np.abs(exact))


@settings(max_examples=25, deadline=None)
@given(st.floats(-10.0, 10.0), st.integers(1, 3))
def test_transmitted_at_is_periodic(t: float, k: int) -> None:
    cfg = SonarConfig()
    a = transmitted_at(np.array([t]), cfg)
    b = transmitted_at(np.array([t + k * cfg.period_s]), cfg)
    np.testing.assert_allclose(a, b, atol=1e-6)
