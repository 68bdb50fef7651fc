"""Right corners of fitted maps heard at the vertex (``ForwardParams.right_corner_tol_deg``).

Truths: on an exactly square room the exact image-source paths (the kernel, itself checked
against pyroomacoustics) are the reference, and the regularized list must equal them; on a
room whose corners are a fraction of a degree off square (as every fitted map is) the exact
paths split in two or vanish, and the regularized list must hold one echo per corner at the
vertex distance, with the Doppler cosine of the direction to the vertex. The kernel hears the
corners itself; its numpy twin (``naive.regularize_corners`` over ``naive.echoes_numpy``)
must give the same list on random skewed rectangles and L-shaped rooms.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from mapping.forward import (
    ForwardParams,
    WallSet,
    echoes,
    echoes_batch,
    right_corners,
    shared_vertices,
)
from mapping.signal import SonarConfig
from tests.mapping.forward.naive import echoes_numpy, padded, regularize_corners

SONAR = SonarConfig()
C = SONAR.sound_speed_m_s
SQUARE = np.array([[0.0, 0.0, 4.0, 0.0], [4.0, 0.0, 4.0, 3.0],
                   [4.0, 3.0, 0.0, 3.0], [0.0, 3.0, 0.0, 0.0]])
EXACT = ForwardParams(max_order=2)
RIGHT = ForwardParams(max_order=2, right_corner_tol_deg=3.0)
CORNERS = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]])


def _skewed(eps_m: float) -> np.ndarray:
    """The square room with its corners moved by up to ``eps_m`` (angles off 90 by a
    fraction of a degree); walls still share their ends, as a fitted map's do."""
    c = CORNERS + eps_m * np.array([[0.3, -0.8], [1.0, 0.6], [-0.9, 0.8], [-0.4, -1.0]])
    return np.array([[*c[k], *c[(k + 1) % 4]] for k in range(4)])


@pytest.mark.parametrize("speed", [0.0, 0.15, -0.1])
def test_square_room_regularized_equals_exact_paths(speed: float) -> None:
    walls = WallSet.from_array(SQUARE, [0.9, 0.8, 0.95, 0.7])
    rng = np.random.default_rng(3)
    poses = np.column_stack([rng.uniform(0.2, 3.8, 40), rng.uniform(0.2, 2.8, 40),
                             rng.uniform(-np.pi, np.pi, 40)])
    a = echoes_batch(walls, poses, speed, SONAR, EXACT)
    b = echoes_batch(walls, poses, speed, SONAR, RIGHT)
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_allclose(a.range_m, b.range_m, atol=1e-9, equal_nan=True)
    np.testing.assert_allclose(a.cos_doppler, b.cos_doppler, atol=1e-9, equal_nan=True)
    np.testing.assert_allclose(a.amplitude, b.amplitude, rtol=1e-9, equal_nan=True)
    np.testing.assert_array_equal(a.order, b.order)


def test_skewed_corners_split_or_vanish_exactly_but_are_heard_once_regularized() -> None:
    walls = WallSet.from_array(_skewed(0.004))
    pose = np.array([1.84, 1.43, 0.44])
    exact = echoes(walls, pose, 0.12, SONAR, EXACT)
    right = echoes(walls, pose, 0.12, SONAR, RIGHT)
    vertices = _skewed(0.004)[:, :2]
    d_true = np.hypot(*(vertices - pose[:2]).T)
    seen_exact = [int(np.sum((exact.order == 2) & (np.abs(exact.range_m - d) < 0.01)))
                  for d in d_true]
    seen_right = [int(np.sum((right.order == 2) & (np.abs(right.range_m - d) < 0.003)))
                  for d in d_true]
    assert seen_exact != [1, 1, 1, 1]            # the artefact this fixes (split or lost)
    assert seen_right == [1, 1, 1, 1]
    for v, d in zip(vertices, d_true, strict=True):
        k = int(np.argmin(np.abs(right.range_m - d) + 10 * (right.order != 2)))
        to_vertex = math.atan2(v[1] - pose[1], v[0] - pose[0])
        assert right.cos_doppler[k] == pytest.approx(math.cos(to_vertex - pose[2]), abs=1e-3)
    # first-order echoes are untouched
    np.testing.assert_allclose(np.sort(exact.range_m[exact.order == 1]),
                               np.sort(right.range_m[right.order == 1]))


def test_shared_vertices_and_right_corners_of_a_skewed_room() -> None:
    rows = _skewed(0.004)
    segments = rows.reshape(-1, 2, 2)
    shared = shared_vertices(segments)
    assert [(i, j) for i, j, _ in shared] == [(0, 1), (0, 3), (1, 2), (2, 3)]
    for i, j, v in shared:  # the midpoint of the two touching ends
        assert np.allclose(v, rows[i, 2:] if j == i + 1 else rows[i, :2])
    assert [(i, j) for i, j, _ in right_corners(segments, 3.0)] == [(0, 1), (0, 3), (1, 2),
                                                                    (2, 3)]
    assert right_corners(segments, 0.01) == []  # each a fraction of a degree off square
    assert shared_vertices(segments[:1]) == [] and right_corners(segments[:0], 3.0) == []


def test_corners_outside_the_tolerance_keep_their_exact_paths() -> None:
    """A 120 deg corner is no retro-reflector: the regularization leaves it alone."""
    hexagon = np.array([[2 * math.cos(a), 2 * math.sin(a)]
                        for a in np.linspace(0, 2 * np.pi, 7)[:-1]])
    walls = WallSet.from_array(np.array([[*hexagon[k], *hexagon[(k + 1) % 6]]
                                         for k in range(6)]))
    poses = np.array([[0.3, -0.2, 0.4], [-0.5, 0.6, 2.0]])
    a = echoes_batch(walls, poses, 0.1, SONAR, EXACT)
    b = echoes_batch(walls, poses, 0.1, SONAR, RIGHT)
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_allclose(a.range_m, b.range_m, equal_nan=True)


def test_a_wall_between_the_sonar_and_the_vertex_hides_the_corner_echo() -> None:
    partition = np.vstack([_skewed(0.003), [[2.5, 2.0, 3.5, 1.0]]])
    walls = WallSet.from_array(partition)
    pose = np.array([2.0, 1.0, 0.0])
    right = echoes(walls, pose, 0.1, SONAR, RIGHT)
    d_ne = math.hypot(4.0 - 2.0, 3.0 - 1.0)
    assert not np.any((right.order == 2) & (np.abs(right.range_m - d_ne) < 0.01)
                      & np.all(right.walls[:, :2] >= 1, axis=1)
                      & np.all(right.walls[:, :2] <= 2, axis=1))


@settings(max_examples=25, deadline=None)
@given(eps=st.floats(0.0, 0.01), x=st.floats(0.3, 3.7), y=st.floats(0.3, 2.7),
       h=st.floats(-math.pi, math.pi), v=st.floats(-0.3, 0.3))
def test_regularized_rows_are_sorted_padded_and_counted(eps: float, x: float, y: float,
                                                        h: float, v: float) -> None:
    walls = WallSet.from_array(_skewed(eps))
    b = echoes_batch(walls, np.array([[x, y, h], [y, x, -h]]), v, SONAR, RIGHT)
    for i in range(2):
        k = int(b.count[i])
        r = b.range_m[i]
        assert np.all(np.isfinite(r[:k])) and np.all(np.isnan(r[k:]))
        assert np.all(np.diff(r[:k]) >= 0)
        assert np.all(b.order[i, k:] == 0) and np.all(b.walls[i, k:] == -1)
        # one echo per corner (adjacent walls) at most; parallel walls keep both orders
        second = [tuple(sorted(w[:2])) for w in b.walls[i, :k][b.order[i, :k] == 2]]
        for pair in ((0, 1), (1, 2), (2, 3), (0, 3)):
            assert second.count(pair) <= 1


@st.composite
def _cornered_rooms(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, int,
                                              float]:
    """A rectangle or an L-shaped room, its corners moved by up to 6 cm (a few degrees off
    square, some beyond the 3 deg tolerance) and its wall ends by up to 2 cm (still one
    vertex), turned and shifted; wall strengths, three poses (some outside), a speed, an
    order 2-3 and an amplitude floor."""
    w, h = draw(st.floats(2.0, 6.0)), draw(st.floats(2.0, 5.0))
    if draw(st.booleans()):
        corners = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)]
    else:
        a, b = draw(st.floats(0.3, 0.7)), draw(st.floats(0.3, 0.7))
        corners = [(0.0, 0.0), (w, 0.0), (w, b * h), (a * w, b * h), (a * w, h), (0.0, h)]
    n = len(corners)
    unit = st.floats(-1.0, 1.0)
    skew, gap = draw(st.floats(0.0, 0.06)), draw(st.sampled_from([0.0, 0.02]))
    v = np.array(corners) + skew * np.array([[draw(unit), draw(unit)] for _ in range(n)])
    ends = np.roll(v, -1, axis=0) + gap * np.array([[draw(unit), draw(unit)] for _ in range(n)])
    turn, shift = draw(st.floats(-math.pi, math.pi)), np.array([draw(unit), draw(unit)])
    rot = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])
    rows = np.hstack([v @ rot.T + shift, ends @ rot.T + shift])
    strength = np.array([draw(st.floats(-1.0, 1.0)) for _ in range(n)])
    local = np.array([[draw(st.floats(-0.5, w + 0.5)), draw(st.floats(-0.5, h + 0.5))]
                      for _ in range(3)])
    poses = np.column_stack([local @ rot.T + shift,
                             [draw(st.floats(-math.pi, math.pi)) for _ in range(3)]])
    # a sonar on a wall's line is degenerate (tangent legs, zero-length first order): the
    # kernel and the twin may decide it differently in the last bit, as for exact paths
    # (hypothesis favours the bounds, which put poses on lines: step such a pose 5 cm along
    # the line's normal, a few times, so that few examples are filtered out)
    d = rows[:, 2:] - rows[:, :2]
    normal = np.column_stack([-d[:, 1], d[:, 0]]) / np.hypot(d[:, 0], d[:, 1])[:, None]
    for _ in range(4):
        off = poses[:, None, :2] - rows[None, :, :2]
        dist = np.abs(np.sum(off * normal[None], axis=2))
        close = dist <= 0.01
        if not close.any():
            break
        for i, j in zip(*np.nonzero(close), strict=True):
            poses[i, :2] += 0.05 * normal[j]
    assume(bool(np.all(dist > 0.01)))
    return (rows, strength, poses, draw(st.floats(-0.3, 0.3)), draw(st.integers(2, 3)),
            draw(st.sampled_from([0.0, 0.05])))


@settings(max_examples=40, deadline=None)
@given(_cornered_rooms())
def test_kernel_matches_numpy_twin_on_skewed_rooms(
        case: tuple[np.ndarray, np.ndarray, np.ndarray, float, int, float]) -> None:
    rows, strength, poses, speed, order, floor = case
    walls = WallSet.from_array(rows, strength)
    seg = walls.segments_m
    params = ForwardParams(max_order=order, max_range_m=8.0, min_amplitude=floor,
                           right_corner_tol_deg=3.0)
    corners = right_corners(seg, 3.0)
    batch = echoes_batch(walls, poses, speed, SONAR, params)
    for i, pose in enumerate(poses):
        got = batch.echoes_of(i)
        exact = padded(echoes_numpy(seg, walls.strength, pose, speed, C, order, 16.0, 1.0,
                                    floor), order)
        want = regularize_corners(exact, seg, walls.strength, pose[None], corners, speed, C,
                                  1.0, 16.0, floor)
        assert got.k == int(want["count"][0])
        # a path and its reverse can tie in length: pair each twin echo with the kernel
        # echo of its walls (as test_forward.test_kernel_matches_numpy_twin)
        used: set[int] = set()
        for col in range(got.k):
            walls_want = want["walls"][0, col]
            ties = [j for j in range(got.k) if j not in used
                    and abs(got.range_m[j] - want["path_m"][0, col] / 2) < 1e-9
                    and np.array_equal(got.walls[j], walls_want)]
            assert ties, f"no kernel echo for walls {walls_want}"
            j = ties[0]
            used.add(j)
            assert got.order[j] == want["order"][0, col]
            assert got.cos_doppler[j] == pytest.approx(want["cos_doppler"][0, col], abs=1e-9)
            assert got.amplitude[j] == pytest.approx(want["amplitude"][0, col], rel=1e-9)
            np.testing.assert_allclose(got.points_m[j], want["points"][0, col], atol=1e-9,
                                       equal_nan=True)
            turn = got.arrival_bearing_rad[j] - want["bearing"][0, col]
            assert abs(math.remainder(turn, 2 * math.pi)) < 1e-9


def test_no_corners_when_the_order_is_one() -> None:
    """Order 1 has no two-bounce paths to replace: the tolerance changes nothing."""
    walls = WallSet.from_array(_skewed(0.004))
    poses = np.array([[1.84, 1.43, 0.44], [0.5, 2.5, -2.0]])
    a = echoes_batch(walls, poses, 0.1, SONAR, ForwardParams(max_order=1))
    b = echoes_batch(walls, poses, 0.1, SONAR, ForwardParams(max_order=1,
                                                             right_corner_tol_deg=3.0))
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_array_equal(a.range_m, b.range_m)


def test_bad_parameters_name_the_field() -> None:
    with pytest.raises(ValueError, match="right_corner_tol_deg"):
        ForwardParams(right_corner_tol_deg=-1.0)
    with pytest.raises(ValueError, match="corner_join_m"):
        ForwardParams(corner_join_m=float("nan"))
