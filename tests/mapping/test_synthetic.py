"""Tests of mapping.synthetic against closed-form geometry (not against its own solver)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.signal import SonarConfig, transmitted_at, transmitted_exact
from mapping.synthetic import (
    Motion,
    PointReflector,
    Wall,
    echo_delay_s,
    echo_samples,
    echo_truth,
    run_motion,
    run_target,
    run_truth,
    synthetic_run,
)

C = 340.0
CFG = SonarConfig()


@pytest.mark.parametrize("d", [0.5, 2.0, 8.0])
def test_static_delays_are_twice_the_distance(d: float) -> None:
    t = np.linspace(0.0, 2.0, 7)
    still = Motion(0.0)
    np.testing.assert_allclose(echo_delay_s(t, still, Wall(d, 0.7), C), 2 * d / C, rtol=1e-13)
    np.testing.assert_allclose(
        echo_delay_s(t, still, PointReflector(d, -1.1), C), 2 * d / C, rtol=1e-13
    )


@pytest.mark.parametrize("theta_deg,sign", [(0.0, 1.0), (180.0, -1.0)])
def test_head_on_wall_delay_and_doppler_closed_form(theta_deg: float, sign: float) -> None:
    # Wall straight ahead (theta = 0): d(t) = d0 - v t, c tau = d(t_e) + d(t) gives
    # tau = 2 d(t) / (c - v); behind (180 deg) c + v. The echo is s(beta t - 2 d0 / (c -+ v))
    # with beta = (c + v)/(c - v) (compressed ahead), i.e. the inverse of eq. 1's alpha.
    v, d0 = 0.1, 3.0
    motion = Motion(v)
    wall = Wall(d0, math.radians(theta_deg))
    t = np.linspace(-0.5, 0.5, 11)
    d_t = d0 - sign * v * t
    np.testing.assert_allclose(echo_delay_s(t, motion, wall, C), 2 * d_t / (C - sign * v),
                               rtol=1e-12)
    beta = (C + sign * v) / (C - sign * v)
    ts = np.arange(2000) / CFG.fs_hz
    echo = echo_samples(ts, CFG, motion, wall, spreading=False)
    expected = transmitted_at(beta * ts - 2 * d0 / (C - sign * v), CFG)
    np.testing.assert_allclose(echo, expected, atol=1e-9)


def test_wall_delay_satisfies_image_source_geometry_at_oblique_motion() -> None:
    # Independent check: the emission point p(t - tau), mirrored in the wall, lies exactly
    # c * tau from the receiving point (here written out by hand for a wall at y = 2 m).
    motion = Motion(0.1, heading_rad=0.0)
    wall = Wall(2.0, math.radians(90.0))  # wall y = 2, travelling parallel to it
    t = np.linspace(-1, 1, 5)
    tau = echo_delay_s(t, motion, wall, C)
    x_rx, x_tx = 0.1 * t, 0.1 * (t - tau)
    path = np.hypot(x_rx - x_tx, 4.0)  # image of (x_tx, 0) is (x_tx, 4)
    np.testing.assert_allclose(C * tau, path, rtol=1e-13)


def test_point_delay_two_legs_by_hand() -> None:
    motion = Motion(0.2, heading_rad=0.3)
    point = PointReflector(1.5, math.radians(35))
    t = np.array([0.0, 0.7])
    tau = echo_delay_s(t, motion, point, C)
    q = 1.5 * np.array([math.cos(0.3 + math.radians(35)), math.sin(0.3 + math.radians(35))])
    for ti, taui in zip(t, tau, strict=True):
        rx = motion.position(np.array(ti))
        back = np.linalg.norm(rx - q) / C
        tx = motion.position(np.array(ti - taui))
        assert np.linalg.norm(q - tx) / C + back == pytest.approx(taui, rel=1e-13)


def test_static_echo_correlation_peak_is_the_geometric_delay() -> None:
    # Band-limited echo: its correlation with the delayed transmission s(t - D) is largest
    # at D = 2 d / c (autocorrelation maximum), found on a fine grid + parabola; this does not
    # use the delay solver.
    d = 1.234
    ts = np.arange(CFG.period_samples) / CFG.fs_hz
    echo = echo_samples(ts, CFG, Motion(0.0), Wall(d, 0.0), spreading=False)
    step = 0.02 / CFG.fs_hz
    grid = 2 * d / C + step * np.arange(-50, 51) + 0.37 * step
    corr = np.array([np.dot(echo, transmitted_at(ts - g, CFG)) for g in grid])
    k = int(np.argmax(corr))
    ym, y0, yp = corr[k - 1], corr[k], corr[k + 1]
    best = grid[k] + step * 0.5 * (ym - yp) / (ym - 2 * y0 + yp)
    assert best * CFG.fs_hz == pytest.approx(2 * d / C * CFG.fs_hz, abs=1e-3)


def test_echo_is_band_limited_transmission_at_retarded_time() -> None:
    motion = Motion(0.1)
    wall = Wall(2.0, 0.9, reflection=-0.7)
    t = np.array([0.013, 0.5117, 0.77])
    tau = echo_delay_s(t, motion, wall, C)
    expected = -0.7 / (C * tau) * transmitted_exact(t - tau, CFG)
    np.testing.assert_allclose(echo_samples(t, CFG, motion, wall), expected, rtol=1e-5,
                               atol=1e-7)


def test_synthetic_run_layout_pose_and_truth() -> None:
    cfg = SonarConfig(sequence_length=63, repetitions=4)
    run = synthetic_run(cfg, Wall(2.0, math.radians(50)), 0.1, n_blocks=3)
    assert run.samples.shape == (3, cfg.block_samples) and run.samples.dtype == np.float32
    np.testing.assert_allclose(run.t_s, np.arange(3) * cfg.block_s)
    # pose at block midpoints; the middle block is the reference (sonar at the origin)
    np.testing.assert_allclose(run.pose[:, 0], 0.1 * (np.arange(3) - 1) * cfg.block_s)
    truth = run_truth(run, 1)
    assert truth.distance_m == pytest.approx(2.0)
    assert truth.angle_rad == pytest.approx(math.radians(50))
    # block 0 is earlier: farther from the wall by v T cos(theta)
    assert run_truth(run, 0).distance_m == pytest.approx(
        2.0 + 0.1 * cfg.block_s * math.cos(math.radians(50)))
    assert run_target(run) == Wall(2.0, math.radians(50))
    # samples of block k are the echo at (k B + n) / fs
    t = (2 * cfg.block_samples + np.arange(5)) / cfg.fs_hz
    np.testing.assert_allclose(
        run.samples[2, :5], echo_samples(t, cfg, run_motion(run), run_target(run)), rtol=1e-6)


@settings(max_examples=25, deadline=None)
@given(
    bearing=st.floats(-math.pi, math.pi),
    rng_m=st.floats(0.3, 10.0),
    speed=st.floats(0.0, 1.0),
)
def test_point_truth_is_geometry(bearing: float, rng_m: float, speed: float) -> None:
    motion = Motion(speed)
    truth = echo_truth(0.0, motion, PointReflector(rng_m, bearing), C)
    assert truth.distance_m == pytest.approx(rng_m)
    assert truth.angle_rad == pytest.approx(abs(bearing), abs=1e-9)
    # moving: the echo path is longer/shorter by at most v/c of itself
    assert truth.range_m == pytest.approx(rng_m, rel=2 * speed / C + 1e-12)


def test_bad_inputs_raise() -> None:
    with pytest.raises(ValueError, match="distance_m"):
        Wall(-1.0, 0.0)
    with pytest.raises(ValueError, match="range_m"):
        PointReflector(0.0, 0.0)
    with pytest.raises(ValueError, match="speed_m_s"):
        Motion(float("nan"))
    with pytest.raises(ValueError, match="n_blocks"):
        synthetic_run(CFG, Wall(1.0, 0.0), 0.1, n_blocks=0)
    with pytest.raises(ValueError, match="ref_block"):
        synthetic_run(CFG, Wall(1.0, 0.0), 0.1, n_blocks=2, ref_block=5)


@pytest.mark.parametrize("bearing", [5.960464477539063e-08, -1e-9, math.pi - 1e-8, 0.0, math.pi])
def test_point_truth_angle_is_exact_near_0_and_pi(bearing: float) -> None:
    """Regression: the angle came from acos(dot), which loses half the digits near 0 and pi
    (hypothesis: 6.14e-8 rad for a 5.96e-8 rad bearing)."""
    truth = echo_truth(0.0, Motion(0.3), PointReflector(2.0, bearing), C)
    assert truth.angle_rad == pytest.approx(abs(bearing), abs=1e-12)
