"""Unit and property tests of mapping.simulate.fdtd_compare against independent truths: the
law of reflection, the image-source engine's own beam tracing, brute-force maxima, the
grid's group velocity, and the image-source engine's rendered block."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.compare import (
    dispersion_phase,
    edge_diffraction_paths,
    fdtd_length_m,
    grid_band,
    heatmap_angle_rad,
    image_point,
    local_maxima,
    path_angles_rad,
    path_length_m,
    render_paths,
    retarded,
    specular_path,
    valid_wall_sequences,
    window_peak,
)
from mapping.signal import SonarConfig
from mapping.simulate.fdtd import FdtdConfig, numerical_group_velocity
from mapping.simulate.ism import candidate_images, trace_images

C = 340.0
L_CORNERS = [(0, 0), (6, 0), (6, 3), (3, 3), (3, 6), (0, 6)]
L_ROOM = np.array([[L_CORNERS[i], L_CORNERS[(i + 1) % 6]] for i in range(6)], float)
ONE_WALL = np.array([[[0.0, 2.0], [3.0, 2.0]]])
SCALED = SonarConfig(sequence_length=31, carrier_hz=2500.0, chip_rate_hz=2500.0, fs_hz=10_000.0,
                     repetitions=4)


# ---- geometry ---------------------------------------------------------------------------------
@settings(max_examples=60, deadline=None)
@given(st.floats(0.2, 2.8), st.floats(0.1, 1.9), st.floats(0.2, 2.8), st.floats(0.1, 1.9))
def test_one_wall_specular_path_obeys_the_law_of_reflection(xs: float, ys: float, xr: float,
                                                            yr: float) -> None:
    src, rcv = np.array([xs, ys]), np.array([xr, yr])
    pts = specular_path(src, rcv, (0,), ONE_WALL)
    # specular point on y = 2 where the angles to the normal are equal: x by similar triangles
    x = xs + (xr - xs) * (2 - ys) / ((2 - ys) + (2 - yr))
    if not 0 <= x <= 3:
        assert pts is None
        return
    assert pts is not None
    assert np.allclose(pts[1], [x, 2.0], atol=1e-9)
    assert path_length_m(pts) == pytest.approx(np.hypot(xs - xr, 4 - ys - yr), abs=1e-9)
    assert path_length_m(pts) == pytest.approx(
        float(np.hypot(*(rcv - image_point(src, (0,), ONE_WALL)))), abs=1e-9)


def test_specular_path_refuses_blocked_and_repeated_walls() -> None:
    two = np.array([[[0.0, 2.0], [3.0, 2.0]], [[1.0, 0.5], [2.0, 0.5]]])  # a screen below
    assert specular_path([1.5, 0.2], [1.5, 0.2], (0,), two) is None   # the screen is in the way
    assert specular_path([0.5, 1.0], [0.5, 1.0], (0,), two) is not None
    assert specular_path([0.5, 1.0], [0.5, 1.0], (0, 0), two) is None
    with pytest.raises(ValueError, match="walls"):
        specular_path([0.5, 1.0], [0.5, 1.0], (2,), two)


@settings(max_examples=15, deadline=None)
@given(st.floats(0.3, 5.7), st.floats(0.3, 2.7))
def test_brute_force_paths_equal_the_beam_tracer_in_an_l_room(x: float, y: float) -> None:
    """Two independent methods: brute-force wall sequences with :func:`specular_path` and the
    image-source engine's pruned beam tracing (mapping.simulate.images); the same images."""
    pos = np.array([[x, y]])
    order = 3
    brute = {tuple(np.round(image_point(pos[0], w, L_ROOM), 6))
             for w in valid_wall_sequences(L_ROOM, pos[0], order, np.inf)}
    imgs = candidate_images(L_ROOM, pos, order)
    tr = trace_images(imgs, L_ROOM, np.ones(6), pos)
    beam = {tuple(np.round(p, 6)) for p in imgs.positions(pos)[tr.valid[:, 0], 0]}
    assert brute == beam


def test_edge_paths_in_front_of_one_wall() -> None:
    """Sonar below a wall, moving along +x: the direct edge paths are 2 |p - e| long, at the
    angle of the end from the velocity; with one reflection, sonar -> wall -> edge is refused
    (the specular point would be the end itself), so only the two direct paths exist."""
    p = np.array([1.0, 1.0])
    paths = edge_diffraction_paths(ONE_WALL, p, p, [1.0, 0.0], max_reflections=1)
    assert len(paths) == 2
    for e in paths:
        d = np.array(e.edge_m) - p
        assert e.length_m == pytest.approx(2 * np.hypot(*d))
        assert e.range_m == pytest.approx(np.hypot(*d))
        assert e.heatmap_angle_rad == pytest.approx(math.atan2(abs(d[1]), d[0]))
        assert e.walls_in == e.walls_out == ()
    assert [e.edge_m for e in paths] == [(0.0, 2.0), (3.0, 2.0)]  # sorted by length


def test_edge_paths_with_a_reflection_via_a_second_wall() -> None:
    """A mirror wall at x = 4 (vertical): sonar -> mirror -> free end (0, 2) has the length of
    the straight line from the sonar's image (7, 1) to the end."""
    seg = np.array([[[0.0, 2.0], [3.0, 2.0]], [[4.0, -1.0], [4.0, 3.5]]])
    p = np.array([1.0, 1.0])
    paths = edge_diffraction_paths(seg, p, p, [0.0, 1.0], max_reflections=1)
    via = [e for e in paths if e.edge_m == (0.0, 2.0) and e.walls_in == (1,) and not e.walls_out]
    assert len(via) == 1
    assert via[0].length_m == pytest.approx(np.hypot(7.0, 1.0) + np.hypot(1.0, 1.0))


def test_path_angles_and_heatmap_angle_agree() -> None:
    pts = np.array([[0.0, 0.0], [1.0, 1.0], [0.0, 2.0], [0.0, 0.0]])
    dep, arr, hm = path_angles_rad(pts, [1.0, 0.0])
    assert dep == pytest.approx(math.pi / 4)
    assert arr == pytest.approx(math.pi / 2)
    assert math.cos(hm) == pytest.approx((math.cos(dep) + math.cos(arr)) / 2)
    v = 1.5
    d = 1 + v * (math.cos(dep) + math.cos(arr)) / C
    assert float(heatmap_angle_rad(d, v, C)) == pytest.approx(hm)
    with pytest.raises(ValueError, match="speed_m_s"):
        heatmap_angle_rad(d, 0.0, C)


def test_retarded_length_of_a_receding_sonar() -> None:
    """Sonar moving away from a wall at speed v, distance d(t): the retarded path
    L = d(t) + d(t - L/c) solves to L = 2 d(t) / (1 + v/c) (exact, linear motion)."""
    v, t = 5.0, 0.3

    def pos(s: float) -> np.ndarray:
        return np.array([1.0, 1.5 - v * s])

    def length(a: np.ndarray, b: np.ndarray) -> float | None:
        pts = specular_path(a, b, (0,), ONE_WALL)
        return None if pts is None else path_length_m(pts)

    sol = retarded(length, pos, t, C)
    assert sol is not None
    # d(t) = 2 - y(t); d(t - L/c) = d(t) - v L / c
    d = 2 - pos(t)[1]
    assert sol[0] == pytest.approx(2 * d / (1 + v / C), rel=1e-10)


# ---- heat-map peaks ----------------------------------------------------------------------------
@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_local_maxima_are_strict_and_sorted(seed: int) -> None:
    rng = np.random.default_rng(seed)
    H = rng.random((7, 40))
    out = local_maxima(H, 5)
    vals = [v for _, _, v in out]
    assert vals == sorted(vals, reverse=True)
    for a, j, v in out:
        assert H[a, j] == v
        for da in (-1, 0, 1):
            for dj in (-1, 0, 1):
                b = a + da
                b = 1 if b < 0 else (H.shape[0] - 2 if b >= H.shape[0] else b)  # mirrored
                if (da, dj) != (0, 0) and (b, (j + dj) % 40) != (a, j):
                    assert H[b, (j + dj) % 40] < v
    # the global maximum is always the first local maximum
    assert out[0][:2] == tuple(np.unravel_index(int(np.argmax(H)), H.shape))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(0, 6), st.integers(0, 39), st.integers(0, 3),
       st.integers(0, 5))
def test_window_peak_is_the_brute_force_maximum(seed: int, a: int, j: int, ha: int,
                                               hj: int) -> None:
    H = np.random.default_rng(seed).random((7, 40))
    b, k, v = window_peak(H, a, j, ha, hj)
    cells = [(x, y % 40) for x in range(max(a - ha, 0), min(a + ha, 6) + 1)
             for y in range(j - hj, j + hj + 1)]
    assert (b, k) in cells
    assert v == max(H[x, y] for x, y in cells) == H[b, k]


# ---- dispersion and rendering -----------------------------------------------------------------
def test_dispersion_phase_delays_the_envelope_by_the_group_velocity() -> None:
    """The phase's frequency derivative at the carrier is the extra group delay
    ``L (1/v_g - 1/c)``, the same the polyline length :func:`fdtd_length_m` predicts."""
    fdtd = FdtdConfig(grid_step_m=0.01, time_step_s=1.6667e-5)
    length, phi = 3.0, 0.3
    f0, df = SCALED.carrier_hz, 0.5
    ph = dispersion_phase(np.array([f0 - df, f0 + df]), length, phi, SCALED, fdtd)
    assert np.allclose(np.abs(ph), 1.0)
    group_delay = -np.angle(ph[1] / ph[0]) / (2 * np.pi * 2 * df)
    vg = numerical_group_velocity(f0, phi, 0.01, 1.6667e-5, C)
    assert group_delay == pytest.approx(length * (1 / vg - 1 / C), rel=1e-3)
    pts = np.array([[0.0, 0.0], [length * math.cos(phi), length * math.sin(phi)]])
    assert fdtd_length_m(pts, f0, fdtd, C) / C - length / C == pytest.approx(group_delay,
                                                                              rel=1e-3)
    assert np.allclose(dispersion_phase(np.array([f0]), 0.0, phi, SCALED, fdtd), 1.0)


def test_grid_band_is_one_in_band_and_zero_beyond_the_injected_edge() -> None:
    fdtd = FdtdConfig(grid_step_m=0.01, time_step_s=1.6667e-5)
    f = np.linspace(0, 5000, 501)
    g = grid_band(f, SCALED, fdtd)
    assert g.max() == pytest.approx(1.0)
    assert g[0] == 0 and np.all(g[f >= 5000] == 0)
    assert np.allclose(g[(f > 300) & (f < 3900)], 1.0)


def test_render_without_dispersion_reproduces_the_image_source_block() -> None:
    """Rebuilt from the path table alone (delay, Doppler factor, amplitude at the midpoint),
    band-limited to a band wider than the signal's, the block equals the engine's rendering
    to a correlation > 0.999 and energy within 1 %."""
    from mapping.path import polyline_path
    from mapping.scene import Scene, Wall
    from mapping.simulate.ism import IsmConfig, iter_ism_blocks

    scene = Scene(name="w", walls=[Wall(start=(-1.0, 2.0), end=(4.0, 2.0))])
    traj = polyline_path([[0.0, 0.0], [2.0, 1.0]], speed_m_s=2.0)
    block = next(iter(iter_ism_blocks(scene, traj, SCALED, 1, IsmConfig(spreading="2d"),
                                      np.random.default_rng(0), first_block=1)))
    fdtd = FdtdConfig(grid_step_m=0.002, time_step_s=3e-6, max_frequency_hz=9000.0)
    x = render_paths(block.paths, None, SCALED, fdtd, 1)
    y = np.asarray(block.samples, dtype=float)
    corr = float(np.dot(x, y) / np.linalg.norm(x) / np.linalg.norm(y))
    assert corr > 0.999
    assert np.sum(x**2) / np.sum(y**2) == pytest.approx(1.0, abs=0.01)
    with pytest.raises(ValueError, match="direction_rad"):
        render_paths(block.paths, np.zeros(block.paths.n + 1), SCALED, fdtd, 1)


def test_edge_echo_range_of_a_static_sonar_is_half_the_path_and_nearest_prediction() -> None:
    from mapping.compare import edge_echo_range_m, nearest_prediction

    seg = np.array([[[0.0, 2.0], [3.0, 2.0]], [[4.0, -1.0], [4.0, 3.5]]])
    p = np.array([1.0, 1.0])
    fdtd = FdtdConfig(grid_step_m=0.01, time_step_s=1.6667e-5)
    for e in edge_diffraction_paths(seg, p, p, [0.0, 1.0], max_reflections=1):
        r = edge_echo_range_m(seg, e, lambda t: p, 0.1, SCALED, fdtd)
        assert r is not None
        assert r[0] == pytest.approx(e.range_m, abs=1e-12)
        assert r[1] == pytest.approx(fdtd_length_m(e.points_m, SCALED.carrier_hz, fdtd, C) / 2)
        assert r[1] > r[0]  # the grid is slow
    assert nearest_prediction(3, 10, [(0.0, 0.0), (3.5, 9.0), (3.0, 12.0)]) == (1, -0.5, 1.0)
    with pytest.raises(ValueError, match="predicted"):
        nearest_prediction(0, 0, [])
