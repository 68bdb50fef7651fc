"""Coverage: cells within range of a tracked pose and in its line of sight."""

from __future__ import annotations

import time

import numpy as np
import pytest

from mapping.coverage import coverage_mask
from mapping.wallmap import rasterize_walls

X = np.linspace(0.0, 3.9, 40)  # 10 cm cells
Y = np.linspace(0.0, 2.9, 30)


def _crosses(p: np.ndarray, c: np.ndarray, a: np.ndarray, b: np.ndarray) -> bool:
    """Does the segment p-c cross a-b (ends of a-b included) strictly between p and c? (solved
    for the parameters of the intersection, independently of the module's orientation tests)"""
    d, e = c - p, b - a
    den = d[0] * e[1] - d[1] * e[0]
    if den == 0:
        return False
    t = ((a[0] - p[0]) * e[1] - (a[1] - p[1]) * e[0]) / den
    u = ((a[0] - p[0]) * d[1] - (a[1] - p[1]) * d[0]) / den
    return bool(0 < t < 1 and 0 <= u <= 1)


def _naive(poses: np.ndarray, x: np.ndarray, y: np.ndarray, r: float,
           walls: np.ndarray) -> np.ndarray:
    on_wall = [rasterize_walls(w[None], x, y) for w in walls]
    out = np.zeros((y.size, x.size), dtype=bool)
    for p in poses:
        if not np.all(np.isfinite(p[:2])):
            continue
        for iy, yy in enumerate(y):
            for ix, xx in enumerate(x):
                c = np.array([xx, yy])
                if np.hypot(*(c - p[:2])) > r:
                    continue
                hidden = any(_crosses(p[:2], c, w[:2], w[2:]) and not ow[iy, ix]
                             for w, ow in zip(walls, on_wall, strict=True))
                out[iy, ix] |= not hidden
    return out


def test_range_only() -> None:
    poses = np.array([[1.0, 1.0, 0.0], [np.nan, np.nan, np.nan], [3.0, 2.0, 1.0]])
    got = coverage_mask(poses, X, Y, 0.75)
    cx, cy = np.meshgrid(X, Y)
    want = (np.hypot(cx - 1, cy - 1) <= 0.75) | (np.hypot(cx - 3, cy - 2) <= 0.75)
    np.testing.assert_array_equal(got, want)
    assert not coverage_mask(np.full((3, 3), np.nan), X, Y, 1.0).any()
    assert coverage_mask(np.array([[1.0, 1.0]]), X, Y, 0.75).sum() == np.sum(
        np.hypot(cx - 1, cy - 1) <= 0.75)  # (n, 2) poses accepted


def test_wall_hides_what_is_behind_it_but_not_itself() -> None:
    """A pose left of a vertical wall x = 2 m (y in 0.5 .. 2.5 m) sees the wall's cells, not the
    cells behind it; cells beside the wall's end stay visible."""
    wall = np.array([[2.0, 0.5, 2.0, 2.5]])
    seen = coverage_mask(np.array([[1.0, 1.5, 0.0]]), X, Y, 10.0, wall)
    assert seen[5:26, 20].all()  # the wall column (x = 2.0 m), y 0.5 .. 2.5
    assert not seen[10:21, 21:].any()  # straight behind it
    assert seen[15, :20].all()  # in front
    assert seen[0, 23] and seen[29, 23]  # sight lines passing the wall's ends
    assert not seen[0, 39] and not seen[29, 39]  # sight lines through the wall
    both = coverage_mask(np.array([[1.0, 1.5, 0.0], [3.0, 1.5, 0.0]]), X, Y, 10.0, wall)
    assert both.all()


def test_no_leak_through_a_corner() -> None:
    """Sight lines through the shared end point of two walls are blocked (regression: cells
    on the diagonal through a room corner read as observed)."""
    walls = np.array([[1.0, 1.0, 3.0, 1.0], [1.0, 1.0, 1.0, 2.5]])
    seen = coverage_mask(np.array([[2.0, 2.0, 0.0]]), X, Y, 10.0, walls)
    assert not seen[:10, :10].any()  # the quadrant behind the corner (1, 1)
    assert seen[10, 10]  # the corner cell itself


def test_matches_naive_twin_on_random_scenes() -> None:
    rng = np.random.default_rng(7)
    for _ in range(4):
        poses = np.c_[rng.uniform(0, 3.9, (5, 2)), np.zeros(5)]
        poses[rng.integers(5)] = np.nan
        walls = np.c_[rng.uniform(0, 3.9, (3, 1)), rng.uniform(0, 2.9, (3, 1)),
                      rng.uniform(0, 3.9, (3, 1)), rng.uniform(0, 2.9, (3, 1))]
        r = float(rng.uniform(0.5, 3.0))
        np.testing.assert_array_equal(coverage_mask(poses, X, Y, r, walls),
                                      _naive(poses, X, Y, r, walls))


def test_fast_on_200_by_200_and_100_poses() -> None:
    rng = np.random.default_rng(1)
    x = y = np.linspace(0.0, 9.95, 200)
    poses = np.c_[rng.uniform(1, 9, (100, 2)), np.zeros(100)]
    walls = np.array([[0.5, 0.5, 9.5, 0.5], [9.5, 0.5, 9.5, 9.5], [9.5, 9.5, 0.5, 9.5],
                      [0.5, 9.5, 0.5, 0.5], [4.0, 3.0, 4.0, 7.0], [6.0, 2.0, 7.0, 5.0]])
    coverage_mask(poses[:2], x, y, 6.0, walls)
    t0 = time.perf_counter()
    seen = coverage_mask(poses, x, y, 6.0, walls)
    assert time.perf_counter() - t0 < 1.0
    assert seen[20:180, 20:180].mean() > 0.9 and not seen[:5].any()  # nothing beyond the room


@pytest.mark.parametrize(("args", "name"), [
    ((np.zeros(3), X, Y, 1.0), "poses"),
    ((np.zeros((1, 3)), X[::-1], Y, 1.0), "x_m"),
    ((np.zeros((1, 3)), X, np.zeros((2, 2)), 1.0), "y_m"),
    ((np.zeros((1, 3)), X, Y, 0.0), "max_range_m"),
    ((np.zeros((1, 3)), X, Y, 1.0, np.zeros((1, 3))), "walls_m"),
])
def test_bad_arguments_named(args: tuple[object, ...], name: str) -> None:
    with pytest.raises(ValueError, match=name):
        coverage_mask(*args)  # type: ignore[arg-type]
