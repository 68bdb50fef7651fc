"""Trajectories: exact constant speed, C1 joints, heading wrap, arc length, extrapolation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.angles import wrap_angle
from mapping.path import (
    Trajectory,
    builtin_path,
    builtin_path_names,
    builtin_path_scene,
    curve_path,
    min_wall_distance_m,
    path_inside,
    polyline_path,
    stationary_path,
)
from mapping.scene import builtin_scene
from tests.mapping.path.naive import position_velocity_numpy


def _joint_times(tr: Trajectory) -> np.ndarray:
    return tr.s0_m[1:] / tr.cruise_speed_m_s


def _dense(tr: Trajectory, n: int = 20001, margin_s: float = 0.0) -> np.ndarray:
    return np.linspace(-margin_s, tr.duration_s + margin_s, n)


def _polyline_length(points: np.ndarray, r: float) -> float:
    """Independent arc length: segments minus 2 r tan(phi/2) plus r phi per corner."""
    d = np.diff(points, axis=0)
    total = float(np.linalg.norm(d, axis=1).sum())
    h = np.arctan2(d[:, 1], d[:, 0])
    phi = np.abs(wrap_angle(np.diff(h)))
    return total - float(np.sum(2 * r * np.tan(phi / 2))) + float(np.sum(r * phi))


def _arc_length_numeric(tr: Trajectory, n: int = 200001) -> float:
    p = tr.position(np.linspace(0.0, tr.duration_s, n))
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


SQUARE = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])


def test_polyline_constant_speed_and_length() -> None:
    tr = polyline_path(SQUARE, speed_m_s=0.1, corner_radius_m=0.3)
    t = _dense(tr, margin_s=5.0)
    speed = np.linalg.norm(tr.velocity(t), axis=1)
    np.testing.assert_allclose(speed, 0.1, atol=1e-9)
    np.testing.assert_array_equal(tr.speed_m_s(t), 0.1)
    expected = _polyline_length(SQUARE, 0.3)  # 6 - 4*0.3 + pi*0.3
    assert tr.length_m == pytest.approx(6 - 1.2 + math.pi * 0.3, rel=1e-12)
    assert tr.length_m == pytest.approx(expected, rel=1e-12)
    assert tr.duration_s * 0.1 == pytest.approx(tr.length_m, rel=1e-12)
    assert _arc_length_numeric(tr) == pytest.approx(tr.length_m, rel=1e-7)


def test_polyline_start_end_and_arcs_tangent() -> None:
    tr = polyline_path(SQUARE, corner_radius_m=0.5)
    np.testing.assert_allclose(tr.position(np.array([0.0, tr.duration_s])), SQUARE[[0, -1]],
                               atol=1e-12)
    # the first arc is the quarter circle centred (1.5, 0.5): every point 0.5 m from it
    t_arc = (1.5 + np.linspace(0, math.pi * 0.5 / 2, 50)) / tr.cruise_speed_m_s
    d = np.linalg.norm(tr.position(t_arc) - [1.5, 0.5], axis=1)
    np.testing.assert_allclose(d, 0.5, atol=1e-12)
    # yaw rate there is v / r, left turn
    np.testing.assert_allclose(tr.yaw_rate_rad_s(t_arc[1:-1]), 0.1 / 0.5, rtol=1e-12)
    np.testing.assert_allclose(tr.yaw_rate_rad_s(np.array([0.5 / 0.1])), 0.0)


@pytest.mark.parametrize("name", builtin_path_names())
def test_c1_at_every_joint(name: str) -> None:
    tr = builtin_path(name)
    tj = np.concatenate([[0.0], _joint_times(tr), [tr.duration_s]])
    eps = 1e-9
    for f in (tr.position, tr.velocity):
        left, right = f(tj - eps), f(tj + eps)
        np.testing.assert_allclose(left, right, atol=1e-9)
    # velocity is the derivative of position (central difference) everywhere
    t = _dense(tr, 4001, margin_s=3.0)
    h = 1e-3
    fd = (tr.position(t + h) - tr.position(t - h)) / (2 * h)
    np.testing.assert_allclose(fd, tr.velocity(t), atol=1e-6)


@pytest.mark.parametrize("name", builtin_path_names())
def test_builtin_paths_keep_clearance(name: str) -> None:
    tr = builtin_path(name)
    scene = builtin_scene(builtin_path_scene(name))
    assert path_inside(scene, tr, clearance_m=0.3)
    # and start inside the room: a ray to +x from the start crosses an odd number of walls
    # (the paper scene is open, so there the start must be inside its bounding box)
    p0 = tr.position(np.array([0.0]))[0]
    xmin, ymin, xmax, ymax = scene.bounds_m()
    if name.startswith("paper"):
        assert xmin - 1 <= p0[0] <= xmax and ymin - 1 <= p0[1] <= ymax
    else:
        seg = scene.segments()
        (x0, y0), (x1, y1) = seg[:, 0].T, seg[:, 1].T
        straddle = (y0 > p0[1]) != (y1 > p0[1])
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = x0 + (p0[1] - y0) * (x1 - x0) / (y1 - y0)
        assert int(np.sum(straddle & (xc > p0[0]))) % 2 == 1
    assert 2.0 <= tr.length_m <= 6.5  # 20-60 blocks at 0.1 m/s


def test_path_inside_detects_a_crossing() -> None:
    scene = builtin_scene("shoebox")
    tr = polyline_path([[1.0, 1.0], [5.0, 1.0]])
    assert min_wall_distance_m(scene, tr) == pytest.approx(0.0, abs=0.006)
    assert not path_inside(scene, tr, 0.3)


def test_paper_path_a() -> None:
    tr = builtin_path("paper-a")
    h = tr.heading_rad(_dense(tr, 101))
    np.testing.assert_allclose(h, math.pi / 4, atol=1e-12)
    # passes point (a) = (2, 2)
    t_a = math.hypot(1, 1) / 0.1
    np.testing.assert_allclose(tr.position(np.array([t_a]))[0], [2.0, 2.0], atol=1e-12)
    assert tr.length_m >= 20 * 0.1023


def test_paper_path_b_faces_many_directions() -> None:
    tr = builtin_path("paper-b")
    h = np.unwrap(tr.heading_rad(_dense(tr, 2001)))
    assert np.ptp(h) > math.pi  # sweeps more than half a turn


def test_extrapolation_outside_the_path() -> None:
    tr = curve_path([[0.0, 0.0], [1.0, 1.0], [2.0, 0.5]], speed_m_s=0.2)
    t_end = tr.duration_s
    dt = np.array([0.5, 2.0, 10.0])
    p_start, p_end = tr.position(np.array([0.0, t_end]))
    v_start, v_end = tr.velocity(np.array([0.0, t_end]))
    np.testing.assert_allclose(tr.position(-dt), p_start - dt[:, None] * v_start, atol=1e-12)
    np.testing.assert_allclose(tr.position(t_end + dt), p_end + dt[:, None] * v_end, atol=1e-12)
    np.testing.assert_allclose(tr.velocity(-dt), np.tile(v_start, (3, 1)), atol=1e-15)
    np.testing.assert_allclose(tr.velocity(t_end + dt), np.tile(v_end, (3, 1)), atol=1e-15)
    np.testing.assert_array_equal(tr.yaw_rate_rad_s(np.concatenate([-dt, t_end + dt])), 0.0)


def test_heading_wraps_to_half_open_interval() -> None:
    # a closed loop turns through 2 pi: headings must stay in (-pi, pi]
    tr = curve_path([[0, 0], [1, 0], [1, 1], [0, 1]], closed=True)
    h = tr.heading_rad(_dense(tr, 5001, margin_s=2.0))
    assert np.all(h > -math.pi) and np.all(h <= math.pi)
    np.testing.assert_array_equal(wrap_angle(np.array([-math.pi, math.pi, 3 * math.pi])),
                                  [math.pi, math.pi, math.pi])
    # heading matches the velocity direction
    t = _dense(tr, 301)
    v = tr.velocity(t)
    diff = wrap_angle(tr.heading_rad(t) - np.arctan2(v[:, 1], v[:, 0]))
    np.testing.assert_allclose(diff, 0.0, atol=1e-12)
    pose = tr.pose(t)
    assert pose.shape == (t.size, 3)
    np.testing.assert_allclose(pose[:, :2], tr.position(t))


def test_closed_curve_returns_with_matching_tangent() -> None:
    tr = curve_path([[0, 0], [2, 0], [2, 1], [0, 1]], closed=True)
    p = tr.position(np.array([0.0, tr.duration_s]))
    np.testing.assert_allclose(p[0], p[1], atol=1e-12)
    v = tr.velocity(np.array([0.0, tr.duration_s]))
    np.testing.assert_allclose(v[0], v[1], atol=1e-9)


def test_curve_passes_through_points_at_constant_speed() -> None:
    pts = np.array([[0.0, 0.0], [1.0, 0.7], [2.0, 0.2], [3.1, 1.0]])
    tr = curve_path(pts, speed_m_s=0.1)
    t = _dense(tr, 50001)
    p = tr.position(t)
    for q in pts:
        assert np.min(np.linalg.norm(p - q, axis=1)) < 1e-3  # sampled 1e-4 m apart
    np.testing.assert_allclose(np.linalg.norm(tr.velocity(t), axis=1), 0.1, atol=1e-12)
    assert _arc_length_numeric(tr) == pytest.approx(tr.length_m, rel=1e-7)
    # the arc spline follows the cubic spline's length within a tiny fraction
    from scipy.interpolate import CubicSpline
    u = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    cs = CubicSpline(u, pts, bc_type="natural")
    uu = np.linspace(0, u[-1], 200001)
    spline_len = np.linalg.norm(np.diff(cs(uu), axis=0), axis=1).sum()
    assert tr.length_m == pytest.approx(spline_len, rel=1e-5)


def test_stationary_path() -> None:
    tr = stationary_path([1.0, 2.0], heading_rad=3 * math.pi / 2, duration_s=4.0)
    t = np.linspace(-1, 5, 13)
    assert tr.duration_s == 4.0 and tr.length_m == 0.0
    np.testing.assert_array_equal(tr.position(t), np.tile([1.0, 2.0], (13, 1)))
    np.testing.assert_array_equal(tr.velocity(t), 0.0)
    np.testing.assert_allclose(tr.heading_rad(t), -math.pi / 2)
    np.testing.assert_array_equal(tr.speed_m_s(t), 0.0)
    np.testing.assert_array_equal(tr.yaw_rate_rad_s(t), 0.0)


@pytest.mark.parametrize(
    ("kwargs", "param"),
    [
        ({"points_m": [[0, 0]]}, "points_m"),
        ({"points_m": [[0, 0], [0, 0], [1, 0]]}, "points_m"),
        ({"points_m": [[0, 0], [1, 0], [0, 0]]}, "points_m"),
        ({"points_m": [[0, 0], [np.nan, 0]]}, "points_m"),
        ({"points_m": [[0, 0], [0.2, 0], [0.2, 0.2]], "corner_radius_m": 0.3}, "corner_radius_m"),
        ({"points_m": [[0, 0], [1, 0]], "corner_radius_m": 0.0}, "corner_radius_m"),
        ({"points_m": [[0, 0], [1, 0]], "speed_m_s": 0.0}, "speed_m_s"),
    ],
)
def test_polyline_validation(kwargs: dict, param: str) -> None:
    with pytest.raises(ValueError, match=param):
        polyline_path(**kwargs)


def test_validation_of_other_constructors() -> None:
    with pytest.raises(ValueError, match="points_m"):
        curve_path([[0, 0], [1, 0]], closed=True)
    with pytest.raises(ValueError, match="duration_s"):
        stationary_path([0, 0], 0.0, duration_s=0.0)
    with pytest.raises(ValueError, match="t_s"):
        polyline_path([[0, 0], [1, 0]]).position(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="paper-a"):
        builtin_path("nope")


def test_radius_error_states_the_largest_radius() -> None:
    with pytest.raises(ValueError, match=r"<= 0\.2 m"):
        polyline_path([[0.0, 0.0], [0.2, 0.0], [0.2, 0.2]], corner_radius_m=0.3)
    polyline_path([[0.0, 0.0], [0.2, 0.0], [0.2, 0.2]], corner_radius_m=0.2)  # exactly fits


@st.composite
def _polylines(draw: st.DrawFn) -> tuple[np.ndarray, float]:
    n = draw(st.integers(2, 6))
    lengths = draw(st.lists(st.floats(0.5, 3.0), min_size=n - 1, max_size=n - 1))
    turns = draw(st.lists(st.floats(-2.6, 2.6), min_size=n - 2, max_size=n - 2))
    heading = draw(st.floats(-math.pi, math.pi))
    pts = [np.zeros(2)]
    for i, length in enumerate(lengths):
        if i:
            heading += turns[i - 1]
        pts.append(pts[-1] + length * np.array([math.cos(heading), math.sin(heading)]))
    pts_a = np.array(pts)
    t = np.tan(np.abs(np.array(turns)) / 2) if turns else np.zeros(0)
    per_r = np.concatenate([[0.0], t]) + np.concatenate([t, [0.0]])
    with np.errstate(divide="ignore", over="ignore"):
        r_max = float(np.min(np.where(per_r > 0, np.array(lengths) / per_r, 10.0)))
    r = draw(st.floats(0.01, 0.99)) * min(r_max, 10.0)
    return pts_a, r


@settings(max_examples=60, deadline=None)
@given(_polylines(), st.floats(0.01, 2.0))
def test_property_random_polylines(case: tuple[np.ndarray, float], speed: float) -> None:
    pts, r = case
    tr = polyline_path(pts, speed_m_s=speed, corner_radius_m=r)
    t = _dense(tr, 3001, margin_s=1.0)
    np.testing.assert_allclose(np.linalg.norm(tr.velocity(t), axis=1), speed, atol=1e-9)
    np.testing.assert_allclose(tr.position(np.array([0.0, tr.duration_s])), pts[[0, -1]],
                               atol=1e-9)
    assert tr.length_m == pytest.approx(_polyline_length(pts, r), rel=1e-9)
    # position continuous: steps never exceed speed * dt (straight-line bound)
    p = tr.position(t)
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    assert np.all(step <= speed * np.diff(t) * (1 + 1e-9) + 1e-12)
    tj = _joint_times(tr)
    eps = 1e-12 / speed  # 1e-12 m of arc length either side of each joint
    np.testing.assert_allclose(tr.velocity(tj - eps), tr.velocity(tj + eps), atol=1e-9 * speed)
    np.testing.assert_allclose(tr.position(tj - eps), tr.position(tj + eps), atol=1e-9)


@pytest.mark.parametrize("name", builtin_path_names())
def test_kernel_matches_numpy_twin(name: str) -> None:
    tr = builtin_path(name)
    rng = np.random.default_rng(5)
    t = np.concatenate([
        rng.uniform(-20.0, tr.duration_s + 20.0, 3000),
        [0.0, tr.duration_s, -1e-12, tr.duration_s + 1e-12],
        _joint_times(tr),
    ])
    pos, vel = tr.position_velocity(t)
    pos_np, vel_np = position_velocity_numpy(tr, t)
    np.testing.assert_allclose(pos, pos_np, rtol=0, atol=1e-12)
    np.testing.assert_allclose(vel, vel_np, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(tr.position(t), pos)
    np.testing.assert_array_equal(tr.velocity(t), vel)


def test_parallel_kernel_matches_numpy_twin() -> None:
    tr = builtin_path("pillar-curve")
    t = np.random.default_rng(6).uniform(-10.0, tr.duration_s + 10.0, 250_000)  # >= threshold
    pos, vel = tr.position_velocity(t)
    pos_np, vel_np = position_velocity_numpy(tr, t)
    np.testing.assert_allclose(pos, pos_np, rtol=0, atol=1e-12)
    np.testing.assert_allclose(vel, vel_np, rtol=0, atol=1e-15)


def test_kernel_matches_numpy_twin_when_stationary() -> None:
    tr = stationary_path([0.5, -1.0], heading_rad=1.0, duration_s=3.0)
    t = np.linspace(-2.0, 5.0, 29)
    for got, want in zip(tr.position_velocity(t), position_velocity_numpy(tr, t), strict=True):
        np.testing.assert_array_equal(got, want)


def test_trajectory_arrays_are_read_only() -> None:
    tr = builtin_path("paper-b")
    with pytest.raises(ValueError, match="read-only"):
        tr.kappa_1_m[0] = 1.0
    with pytest.raises(ValueError, match="share a shape"):
        Trajectory(s0_m=np.zeros(2), x0_m=np.zeros(1), y0_m=np.zeros(2), theta0_rad=np.zeros(2),
                   kappa_1_m=np.zeros(2), total_length_m=1.0, cruise_speed_m_s=0.1)


def test_wrap_angle_boundaries_and_exactness() -> None:
    """(-pi, pi]: pi stays pi, -pi becomes pi, the float just above pi never gives -pi,
    and in-range angles come back bit for bit (regression: 0.1 -> 0.10000000000000009)."""
    import math

    from mapping.angles import wrap_angle

    above_pi = np.nextafter(np.pi, 4.0)
    out = wrap_angle(np.array([np.pi, -np.pi, above_pi, 3 * np.pi, -3 * np.pi, 0.1, 1e-20]))
    assert out[0] == np.pi and out[1] == np.pi and out[3] == np.pi and out[4] == np.pi
    assert -np.pi < out[2] < -np.pi + 1e-12
    assert out[5] == 0.1 and out[6] == 1e-20
    rng = np.random.default_rng(3)
    a = rng.uniform(-40.0, 40.0, 10_000)
    w = wrap_angle(a)
    assert np.all((w > -np.pi) & (w <= np.pi))
    exact = np.array([math.remainder(v, 2 * math.pi) for v in a])
    np.testing.assert_allclose(w, np.where(exact <= -np.pi, np.pi, exact), atol=1e-14)
