"""Direct-path timing (``mapping.recording._timing``): refusals at its edge."""

from __future__ import annotations

import numpy as np
import pytest

from mapping.recording import fit_clock
from mapping.signal import SonarConfig, transmitted_at


def _echo_only(range_m: np.ndarray, fs: float, config: SonarConfig) -> np.ndarray:
    """A stream holding one echo at one-way range ``range_m`` (per sample), no direct wave."""
    t = np.arange(range_m.size) / fs
    x = transmitted_at(t - 2.0 * range_m / config.sound_speed_m_s, config) / (2.0 * range_m)
    return np.asarray(x + 1e-4 * np.random.default_rng(0).standard_normal(t.size))


@pytest.mark.parametrize("how", ["accelerating", "constant speed"])
def test_a_moving_echo_without_a_direct_wave_is_refused(how: str) -> None:
    """Regression: without a direct wave the strongest arrival of each period is an echo; on a
    moving robot it drifts, and the import used to take it as the clock reference (on the
    simulated shoebox-straight run: latency 535 samples off, only a warning). An accelerating
    robot's echo scatters about any clock line; one at constant speed drifts like a clock
    hundreds of ppm off (0.1 m/s: 588 ppm). Both are refused."""
    config, fs = SonarConfig(), 48_000.0
    t = np.arange(int(8.0 * fs)) / fs
    rng_m = 2.0 - 0.02 * t**2 if how == "accelerating" else 2.0 - 0.1 * t
    with pytest.raises(ValueError, match="no direct path"):
        fit_clock(_echo_only(rng_m, fs, config), fs, config, 0.05, config.sound_speed_m_s)


def test_a_static_direct_wave_with_an_echo_is_accepted() -> None:
    """The same stream with a direct wave 5 cm away (40 dB above) passes: the refusals above
    are about the missing direct wave, not the echo."""
    config, fs = SonarConfig(), 48_000.0
    t = np.arange(int(8.0 * fs)) / fs
    x = _echo_only(2.0 - 0.1 * t, fs, config)
    x = x + 20.0 * transmitted_at(t - 0.05 / config.sound_speed_m_s - 0.011, config)
    fit = fit_clock(x, fs, config, 0.05, config.sound_speed_m_s)
    assert abs(fit.clock_offset_ppm) < 2.0 and fit.residual_samples < 0.05
