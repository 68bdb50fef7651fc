"""Tests of :mod:`mapping.resample` against independent truths: analytic sines, a known
fractional delay, the measured stop band, the exact numpy twin, linearity and shape."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from mapping.resample import HALF_TAPS, KAISER_BETA, resample_at, transition_width_hz
from tests.mapping.resample.naive import resample_numpy


def _sine_amplitude(y: np.ndarray, f_hz: float, t_s: np.ndarray) -> float:
    """Least-squares amplitude of a sine of frequency ``f_hz`` in ``y(t_s)``."""
    basis = np.stack([np.cos(2 * np.pi * f_hz * t_s), np.sin(2 * np.pi * f_hz * t_s)], axis=1)
    coef = np.linalg.lstsq(basis, y, rcond=None)[0]
    return float(np.hypot(*coef))


def _interior(fs_in: float, n_in: int, fs_out: float) -> np.ndarray:
    """Output times at ``fs_out`` at least 2 half_taps away from both ends of the input."""
    margin = 2 * HALF_TAPS / fs_in
    return np.arange(int(margin * fs_out), int((n_in / fs_in - margin) * fs_out)) / fs_out


@pytest.mark.parametrize(
    ("fs_in", "fs_out", "cutoff", "freqs"),
    [
        (48_000.0, 40_000.0, 18_500.0, (3_000.0, 10_000.0, 16_000.0)),
        (40_000.0, 44_100.0, 20_000.0, (1_000.0, 10_000.0, 18_000.0)),
    ],
)
def test_sines_match_the_analytic_sine(fs_in: float, fs_out: float, cutoff: float,
                                       freqs: tuple[float, ...]) -> None:
    """Each sine in the pass band comes out as the analytic sine at the new times: max error
    below 2e-4 of the amplitude (measured ~1e-4 at cutoff - width/2, the pass-band ripple)."""
    n = np.arange(8000)
    for f in freqs:
        assert f < cutoff - transition_width_hz(fs_in) / 2
        x = np.sin(2 * np.pi * f * n / fs_in + 0.3)
        t = _interior(fs_in, n.size, fs_out)
        y = resample_at(x, fs_in, t, cutoff)
        err = np.max(np.abs(y - np.sin(2 * np.pi * f * t + 0.3)))
        assert err < 2e-4, (f, err)


def test_fractional_delay_is_recovered() -> None:
    """A multi-sine read 0.37 samples late: the delay read back from each component's phase
    (joint least-squares fit against the original sample grid) is 0.37 samples within 1e-5."""
    fs, delay = 40_000.0, 0.37
    freqs = np.array([700.0, 4_300.0, 9_100.0, 15_700.0])
    n = np.arange(6000)
    x = np.sum(np.cos(2 * np.pi * freqs[:, None] * n / fs), axis=0)
    grid = _interior(fs, n.size, fs)
    y = resample_at(x, fs, grid - delay / fs, fs / 2 * 0.95)
    arg = 2 * np.pi * freqs[None, :] * grid[:, None]
    coef = np.linalg.lstsq(np.hstack([np.cos(arg), np.sin(arg)]), y, rcond=None)[0]
    a, b = coef[: freqs.size], coef[freqs.size:]
    # cos(w (t - d)) = cos(w t) cos(w d) + sin(w t) sin(w d)
    recovered = np.arctan2(b, a) / (2 * np.pi * freqs) * fs
    assert np.allclose(recovered, delay, atol=1e-5), recovered


def test_output_is_the_input_delayed_band_limited() -> None:
    """Band-limited noise (FFT-synthesised below 15 kHz at 40 kHz) shifted by 0.37 samples:
    the resampled stream matches the exact band-limited (FFT) shift within 1e-4 of its RMS."""
    rng = np.random.default_rng(3)
    fs, n, delay = 40_000.0, 8192, 0.37
    spec = rng.standard_normal(n // 2 + 1) + 1j * rng.standard_normal(n // 2 + 1)
    f = np.fft.rfftfreq(n, 1 / fs)
    spec[f > 15_000.0] = 0.0
    spec[0] = 0.0
    x = np.fft.irfft(spec, n)
    truth = np.fft.irfft(spec * np.exp(-2j * np.pi * f * delay / fs), n)  # x(t - delay)
    t = np.arange(n) / fs - delay / fs
    y = resample_at(np.tile(x, 3), fs, t + n / fs, fs / 2 * 0.95)  # periodic: middle copy
    err = np.max(np.abs(y - truth)) / np.std(x)
    assert err < 1e-4, err


@pytest.mark.parametrize("fs_in", [40_000.0, 48_000.0, 96_000.0])
def test_stop_band_attenuation_of_the_defaults(fs_in: float) -> None:
    """Measured on sines: >= 60 dB of attenuation from cutoff + width/2 to fs/2 (~80 dB
    measured), and less than 0.01 dB of loss below cutoff - width/2, at 10 fractional
    offsets of the output grid."""
    cutoff = 0.4 * fs_in
    width = transition_width_hz(fs_in, HALF_TAPS, KAISER_BETA)
    n = np.arange(4000)
    stop = np.linspace(cutoff + width / 2, fs_in / 2 * 0.999, 6)
    passing = np.linspace(fs_in * 0.01, cutoff - width / 2, 4)
    for f in np.concatenate([stop, passing]):
        x = np.cos(2 * np.pi * f * n / fs_in)
        gains = []
        for frac in np.linspace(0.0, 0.9, 10):
            t = (np.arange(600, 3400) + frac) / fs_in
            gains.append(_sine_amplitude(resample_at(x, fs_in, t, cutoff), f, t))
        if f > cutoff:
            assert 20 * np.log10(max(gains)) < -60.0, (f, gains)
        else:
            assert np.all(np.abs(20 * np.log10(gains)) < 0.01), (f, gains)


def test_identity_on_the_input_grid_at_nyquist_cutoff() -> None:
    """``cutoff = fs / 2`` and integer times: the sinc is 1 at 0 and 0 at other integers."""
    x = np.random.default_rng(1).standard_normal(500)
    y = resample_at(x, 40_000.0, np.arange(500) / 40_000.0, 20_000.0)
    assert np.allclose(y, x, atol=1e-12)


def test_kernel_matches_the_exact_twin_on_random_inputs() -> None:
    """Table kernel vs exact windowed sinc: within 2e-6 of the input scale, at random times
    inside, at the edges and beyond them (zeros), for several widths."""
    rng = np.random.default_rng(7)
    for half_taps, beta, fs, ratio in ((64, 8.0, 48_000.0, 0.8), (8, 5.0, 40_000.0, 1.0),
                                       (3, 0.0, 44_100.0, 0.3)):
        x = rng.standard_normal(257)
        t = rng.uniform(-(half_taps + 3) / fs, (257 + half_taps + 3) / fs, 700)
        t[:3] = [0.0, 256 / fs, 1e3]
        got = resample_at(x, fs, t, ratio * fs / 2, half_taps, beta)
        want = resample_numpy(x, fs, t, ratio * fs / 2, half_taps, beta)
        assert np.max(np.abs(got - want)) < 2e-6
        assert got[2] == 0.0


@settings(max_examples=40, deadline=None)
@given(
    x=arrays(np.float64, st.integers(0, 60), elements=st.floats(-1e3, 1e3)),
    y_scale=st.floats(-5, 5),
    shape=st.lists(st.integers(0, 4), min_size=0, max_size=3),
    seed=st.integers(0, 2**31),
)
def test_shape_and_linearity(x: np.ndarray, y_scale: float, shape: list[int], seed: int) -> None:
    """Output has the shape of ``t_out_s``; resampling is linear in ``x``."""
    rng = np.random.default_rng(seed)
    fs = 48_000.0
    t = rng.uniform(-0.001, 0.002, size=tuple(shape))
    other = rng.standard_normal(x.size)
    a = resample_at(x, fs, t, 18_000.0)
    b = resample_at(other, fs, t, 18_000.0)
    both = resample_at(x + y_scale * other, fs, t, 18_000.0)
    assert a.shape == t.shape and a.dtype == np.float64
    scale = 1.0 + np.max(np.abs(x), initial=0.0) + abs(y_scale)
    assert np.allclose(both, a + y_scale * b, atol=1e-9 * scale * HALF_TAPS)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        (dict(fs_in_hz=0.0), "fs_in_hz"),
        (dict(fs_in_hz=float("nan")), "fs_in_hz"),
        (dict(cutoff_hz=30_000.0), "cutoff_hz"),
        (dict(cutoff_hz=0.0), "cutoff_hz"),
        (dict(half_taps=1), "half_taps"),
        (dict(half_taps=2.5), "half_taps"),
        (dict(kaiser_beta=-1.0), "kaiser_beta"),
        (dict(x=np.zeros((2, 3))), "x must be 1-D"),
        (dict(x=np.array([1.0, np.nan])), "x must be finite"),
        (dict(t_out_s=np.array([np.inf])), "t_out_s"),
    ],
)
def test_bad_inputs_name_the_parameter(kwargs: dict[str, Any], name: str) -> None:
    args: dict[str, Any] = dict(x=np.ones(10), fs_in_hz=48_000.0, t_out_s=np.zeros(3),
                                cutoff_hz=18_000.0)
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        resample_at(**args)
