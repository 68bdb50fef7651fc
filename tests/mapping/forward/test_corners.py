"""Right corners of fitted maps heard at the vertex (``ForwardParams.right_corner_tol_deg``).

Truths: on an exactly square room the exact image-source paths (the kernel, itself checked
against pyroomacoustics) are the reference, and the regularized list must equal them; on a
room whose corners are a fraction of a degree off square (as every fitted map is) the exact
paths split in two or vanish, and the regularized list must hold one echo per corner at the
vertex distance, with the Doppler cosine of the direction to the vertex.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.forward import ForwardParams, WallSet, echoes, echoes_batch
from mapping.signal import SonarConfig

SONAR = SonarConfig()
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


def test_bad_parameters_name_the_field() -> None:
    with pytest.raises(ValueError, match="right_corner_tol_deg"):
        ForwardParams(right_corner_tol_deg=-1.0)
    with pytest.raises(ValueError, match="corner_join_m"):
        ForwardParams(corner_join_m=float("nan"))
