"""Tests of mapping.grid (paper eqs. 2-5) against ground-truth geometry and the numpy twin."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.grid import (
    GridExtent,
    GridParams,
    accumulate,
    backproject,
    map_extent,
    remove_floor,
    union_extent,
)
from mapping.heatmap import HeatMap
from tests.mapping.grid.naive import backproject_numpy
from tests.mapping.ideal import ideal_heatmap

RES = 0.05


def _random_heatmap(rng: np.random.Generator, n_dirs: int = 8, n_samples: int = 500) -> HeatMap:
    return HeatMap(H=rng.random((n_dirs, n_samples)),
                   angles_rad=np.pi * np.arange(n_dirs) / (n_dirs - 1),
                   ranges_m=0.00425 * np.arange(n_samples, dtype=np.float64), speed_m_s=0.1,
                   direction_observable=True)


def _straight_pass(n: int = 41) -> np.ndarray:
    x = np.linspace(0.0, 4.0, n)
    return np.column_stack([x, np.zeros(n), np.zeros(n)])


# an oblique wall: through (0, 1.5) at 20 degrees to the path (the x axis)
WALL = np.array([[[-2.0, 1.5 - 2.0 * math.tan(0.35)], [6.0, 1.5 + 6.0 * math.tan(0.35)]]])


def _line_distance(x: np.ndarray, y: np.ndarray, seg: np.ndarray) -> np.ndarray:
    a, b = seg
    u = (b - a) / np.linalg.norm(b - a)
    return np.abs((x - a[0]) * u[1] - (y - a[1]) * u[0])


def test_single_wall_ridge_on_wall_and_mirror_ghost_where_predicted() -> None:
    poses = _straight_pass()
    params = GridParams(radius_m=4.0)
    G, ext, counts = accumulate((ideal_heatmap(p, WALL) for p in poses), poses, params)
    assert counts["blocks_used"] == poses.shape[0]
    xs = ext.origin_m[0] + RES * np.arange(G.shape[1])
    ys = ext.origin_m[1] + RES * np.arange(G.shape[0])
    mirror = WALL[0] * np.array([1.0, -1.0])  # reflection about the path line y = 0
    # specular points of the wall from x in [0, 4] have x in about [-0.45, 3.6]
    for x in (0.5, 1.5, 2.5):
        ix = int(np.argmin(np.abs(xs - x)))
        col = G[:, ix]
        up, down = ys > 0.3, ys < -0.3
        y_true = ys[up][np.argmax(col[up])]
        y_ghost = ys[down][np.argmax(col[down])]
        assert _line_distance(np.array(x), np.array(y_true), WALL[0]) <= RES
        assert _line_distance(np.array(x), np.array(y_ghost), mirror) <= RES
        # the ghost is as strong as the wall: the mirror the method cannot resolve
        assert col[down].max() == pytest.approx(col[up].max(), rel=0.05)


def test_interval_max_gives_continuous_wall_unlike_centre_sample() -> None:
    """A +-8 mm peak read at 50 mm cell centres leaves gaps; the interval maximum does not."""
    pose = np.array([0.0, 0.0, 0.0])
    ranges = 0.00425 * np.arange(600, dtype=np.float64)
    ring = np.exp(-0.5 * ((ranges - 1.0) / 0.004) ** 2)  # same echo in every row: a ring
    hm = HeatMap(H=np.tile(ring, (30, 1)), angles_rad=np.pi * np.arange(30) / 29,
                 ranges_m=ranges, speed_m_s=0.1, direction_observable=True)
    ext = map_extent(pose[None], 1.5, RES)
    G = ext.zeros()
    backproject(G, ext, hm, pose, GridParams(radius_m=1.5, floor="none"))
    lit = ext.zeros()
    backproject(lit, ext, hm, pose, GridParams(radius_m=1.5, floor="none", literal=True))
    ring_max = G.max()
    # every direction: the maximum along a ray from the pose reaches the ring peak
    iy, ix = np.mgrid[0:G.shape[0], 0:G.shape[1]]
    x = ext.origin_m[0] + RES * ix
    y = ext.origin_m[1] + RES * iy
    bearing = np.arctan2(y, x)
    r = np.hypot(x, y)
    near = np.abs(r - 1.0) < 0.1
    sectors = np.digitize(bearing[near], np.linspace(-np.pi, np.pi, 37))
    per_sector_G = np.array([G[near][sectors == s].max() for s in np.unique(sectors)])
    per_sector_lit = np.array([lit[near][sectors == s].max() for s in np.unique(sectors)])
    assert per_sector_G.min() > 0.9 * ring_max
    assert per_sector_lit.min() < 0.5 * ring_max  # the dotted ring of the centre sample


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), literal=st.booleans())
def test_numba_equals_numpy_twin(seed: int, literal: bool) -> None:
    rng = np.random.default_rng(seed)
    hm = _random_heatmap(rng)
    pose = np.array([*rng.uniform(-1, 1, 2), rng.uniform(-7, 7)])
    params = GridParams(radius_m=float(rng.uniform(0.3, 2.0)), literal=literal, floor="none")
    ext = map_extent(pose[None], 1.0, RES)
    G = ext.zeros()
    backproject(G, ext, hm, pose, params)
    ref = backproject_numpy(ext.shape, ext.origin_m[0], ext.origin_m[1], RES, hm.H, 0.0,
                            0.00425, float(pose[0]), float(pose[1]), float(pose[2]),
                            params.radius_m, literal)
    np.testing.assert_allclose(G, ref, rtol=0, atol=1e-12)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_mirror_symmetry_about_travel_line(seed: int) -> None:
    """A cell at +theta and its mirror at -theta read the same heat-map row (paper Sec. 5)."""
    rng = np.random.default_rng(seed)
    hm = _random_heatmap(rng)
    ext = GridExtent((-1.25, -1.25), (41, 41), 0.0625)  # symmetric about y = 0, exact floats
    G = ext.zeros()
    backproject(G, ext, hm, np.array([0.0, 0.0, 0.0]), GridParams(radius_m=1.0, floor="none"))
    np.testing.assert_array_equal(G, G[::-1, :])
    assert np.all(G >= 0)


def test_literal_form_loses_quadrant_and_indexes_past_n() -> None:
    """Behind the robot (x < 0) arctan(m_y/m_x) returns the wrong angle (the printed trap)."""
    n_dirs = 30
    H = np.zeros((n_dirs, 800))
    H[n_dirs - 1, :] = 1.0  # only straight behind (angle pi) is lit
    hm = HeatMap(H=H, angles_rad=np.pi * np.arange(n_dirs) / (n_dirs - 1),
                 ranges_m=0.00425 * np.arange(800, dtype=np.float64), speed_m_s=0.1,
                 direction_observable=True)
    ext = GridExtent((-1.5, -1.5), (61, 61), RES)
    pose = np.array([0.0, 0.0, 0.0])
    intended, literal = ext.zeros(), ext.zeros()
    backproject(intended, ext, hm, pose, GridParams(radius_m=1.4, floor="none"))
    backproject(literal, ext, hm, pose, GridParams(radius_m=1.4, floor="none", literal=True))
    behind = (slice(30, 31), slice(2, 29))  # y = 0, x < 0
    assert intended[behind].min() == 1.0
    assert literal[behind].max() == 0.0  # arctan gives 0 there: row 0, which is dark
    # heading 3 pi / 2: the unwrapped |arctan - phi| * N / pi is past N for every cell but
    # those straight ahead/behind (x = 0), so the literal form drops them all
    lit2 = ext.zeros()
    backproject(lit2, ext, hm, np.array([0.0, 0.0, 1.5 * np.pi]),
                GridParams(radius_m=1.4, floor="none", literal=True))
    assert set(np.nonzero(lit2)[1].tolist()) <= {29, 30, 31}


def test_exact_pose_vs_rounded_pose() -> None:
    """Intended geometry places the echo from the exact pose; eq. 5 rounds the pose to the grid."""
    wall = np.array([[[-3.0, 1.0], [3.0, 1.0]]])
    res = 0.025
    ext = GridExtent((-1.0, -0.5), (81, 81), res)
    pose = np.array([0.0, 0.012, 0.0])  # rounds to the grid point y = 0 (0.48 cells)
    hm = ideal_heatmap(pose, wall, sigma_m=0.03)
    ys = ext.origin_m[1] + res * np.arange(ext.shape[0])
    near = np.abs(ys - 1.0) < 0.15
    centroids = {}
    for literal in (False, True):
        G = ext.zeros()
        backproject(G, ext, hm, pose, GridParams(radius_m=1.4, floor="none", literal=literal))
        col = G[near, 40]  # x = 0
        centroids[literal] = float(np.sum(ys[near] * col) / np.sum(col))
    assert centroids[False] == pytest.approx(1.0, abs=0.004)
    assert centroids[True] == pytest.approx(1.0 - 0.012, abs=0.004)


def test_remove_floor_and_skips() -> None:
    H = np.full((4, 10), 2.0)
    H[1, 3] = 5.0
    out = remove_floor(H)
    assert out[1, 3] == 3.0 and out.sum() == 3.0
    with pytest.raises(ValueError, match="floor"):
        remove_floor(H, "mean")
    rng = np.random.default_rng(0)
    hm = _random_heatmap(rng)
    blind = HeatMap(hm.H, hm.angles_rad, hm.ranges_m, 0.0, False)
    poses = np.array([[0, 0, 0], [np.nan] * 3, [0.1, 0, 0]], dtype=float)
    G, _, counts = accumulate([hm, hm, blind], poses, GridParams(radius_m=1.0))
    assert counts == {"blocks_used": 1, "blocks_untracked": 1, "blocks_unobservable": 1}
    assert G.max() > 0


def test_extent_grows_and_is_aligned() -> None:
    poses = np.array([[0.013, 0.0, 0.0], [3.0, -1.02, 1.0]])
    ext = map_extent(poses, 2.0, RES)
    o = np.array(ext.origin_m) / RES
    np.testing.assert_allclose(o, np.round(o), atol=1e-9)
    assert ext.origin_m[0] <= -2.0 + 0.013 and ext.origin_m[1] <= -3.02
    xmax = ext.origin_m[0] + RES * (ext.shape[1] - 1)
    assert xmax >= 5.0
    u = union_extent([ext, map_extent(poses + 10.0, 2.0, RES)])
    assert u.origin_m == ext.origin_m and u.shape[1] > ext.shape[1]
    with pytest.raises(ValueError, match="poses"):
        map_extent(np.full((2, 3), np.nan), 1.0, RES)
    with pytest.raises(ValueError, match="resolution_m"):
        GridParams(resolution_m=0.0)


def test_percentile_floor() -> None:
    H = np.arange(100.0).reshape(4, 25)
    np.testing.assert_allclose(remove_floor(H, "p90"), np.maximum(H - np.percentile(H, 90), 0))
    with pytest.raises(ValueError, match="floor"):
        GridParams(floor="p100")
