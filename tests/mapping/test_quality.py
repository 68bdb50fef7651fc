"""Tests of mapping.quality on maps whose answers are known by construction."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from mapping.quality import (
    distance_to_walls,
    evaluate,
    evaluate_map,
    evaluate_raster,
    evaluate_walls,
    observed_near_points,
    observed_wall_mask,
    strong_threshold,
    wall_sample_index,
    wall_samples,
)
from mapping.wallmap import WallMap

RES = 0.05
WALL = np.array([[[0.0, 1.0], [2.0, 1.0]]])  # 2 m long, y = 1


def _empty() -> WallMap:
    return WallMap(G=np.zeros((61, 61)), origin_m=(-0.5, -0.5), resolution_m=RES)


def _cells(wm: WallMap, x: float, y: float) -> tuple[int, int]:
    ix, iy = np.round(wm.world_to_cell(np.array([x, y]))).astype(int)
    return int(iy), int(ix)


def test_perfect_map() -> None:
    wm = _empty()
    for x in np.arange(0.0, 2.0 + 1e-9, RES):
        wm.G[_cells(wm, x, 1.0)] = 1.0
    q = evaluate(wm, WALL)
    for a in q.at:
        assert a.precision == 1.0 and a.recall == 1.0
        assert a.chamfer_m < 0.02
    assert q.ghost_energy == 0.0


def test_ghost_line_and_half_wall() -> None:
    """Half the wall mapped (weight 1) plus a ghost line 0.5 m away (weight 1, same length)."""
    wm = _empty()
    xs = np.arange(0.0, 1.0 - 1e-9, RES)  # 20 cells covering x in [0, 0.95]
    for x in xs:
        wm.G[_cells(wm, x, 1.0)] = 1.0
        wm.G[_cells(wm, x, 0.5)] = 1.0
    q = evaluate(wm, WALL, fractions=(0.5,))
    a = q.get(0.5)
    assert a.strong_cells == 40
    assert a.precision == pytest.approx(0.5)
    # wall points within 10 cm of a strong cell: x <= 0.95 + 0.1
    assert a.recall == pytest.approx(1.05 / 2.0, abs=0.02)
    assert q.ghost_energy == pytest.approx(0.5)
    with pytest.raises(ValueError, match="fraction"):
        q.get(0.9)
    json.dumps(q.to_dict())


def test_threshold_uses_high_percentile_of_positive_cells() -> None:
    G = np.zeros((10, 10))
    G[0, :] = 1.0
    G[1, 0] = 1000.0  # a corner-like spike
    thr = strong_threshold(G, 0.5)
    assert thr == pytest.approx(0.5 * np.percentile(G[G > 0], 99))
    assert strong_threshold(np.zeros((2, 2)), 0.5) == np.inf


def test_distance_and_samples() -> None:
    pts = np.array([[1.0, 0.0], [3.0, 1.0], [-1.0, 1.0]])
    np.testing.assert_allclose(distance_to_walls(pts, WALL), [1.0, 1.0, 1.0])
    s = wall_samples(WALL, 0.1)
    assert s.shape == (20, 2) and np.all(s[:, 1] == 1.0)
    with pytest.raises(ValueError, match="segments"):
        distance_to_walls(pts, np.zeros((2, 2)))


# ---- wall level, raster inside coverage, evaluate_map ----------------------------------------
ROOM = np.array([[[0.0, 0.0], [4.0, 0.0]], [[4.0, 0.0], [4.0, 3.0]],
                 [[4.0, 3.0], [0.0, 3.0]], [[0.0, 3.0], [0.0, 0.0]]])  # 4 m x 3 m, CCW


def _fitted(*extra: list[float]) -> np.ndarray:
    return np.vstack([ROOM.reshape(-1, 4), *(np.array(e, ndmin=2) for e in extra)])


def test_walls_perfect_map_scores_one() -> None:
    q = evaluate_walls(_fitted(), ROOM)
    assert (q.precision, q.recall) == (1.0, 1.0)
    assert (q.n_true, q.n_true_observed, q.n_fitted, q.n_found) == (4, 4, 4, 4)
    assert q.missed == () and q.false_walls == () and q.ambiguous == ()
    assert [(m.true_index, m.fitted_index) for m in q.matches] == [(i, i) for i in range(4)]
    assert q.angle_error_deg_max == pytest.approx(0.0, abs=1e-9)
    assert q.endpoint_error_m_max == pytest.approx(0.0, abs=1e-12)


def test_walls_shifted_15_cm_is_missed_and_false() -> None:
    fitted = _fitted()
    fitted[0, [1, 3]] += 0.15
    q = evaluate_walls(fitted, ROOM)
    assert q.missed == (0,) and q.false_walls == (0,)
    assert q.recall == pytest.approx(0.75) and q.precision == pytest.approx(0.75)
    fitted[0, [1, 3]] -= 0.06  # 9 cm off: within the 10 cm tolerance
    assert evaluate_walls(fitted, ROOM).recall == 1.0


def test_walls_ghost_is_false() -> None:
    """A ghost one corridor width beyond the bottom wall (flutter-echo image)."""
    q = evaluate_walls(_fitted([0.0, -3.0, 4.0, -3.0]), ROOM)
    assert q.false_walls == (4,) and q.n_false == 1
    assert q.precision == pytest.approx(0.8) and q.recall == 1.0


def test_walls_angle_and_endpoint_errors() -> None:
    fitted = _fitted()
    c, half, a = np.array([2.0, 0.0]), 1.95, np.radians(1.0)  # rotated 1 deg, 5 cm short
    d = half * np.array([np.cos(a), np.sin(a)])
    fitted[0] = [*(c - d), *(c + d)]
    q = evaluate_walls(fitted, ROOM)
    m = q.matches[0]
    assert m.fitted_index == 0 and m.angle_error_deg == pytest.approx(1.0)
    assert m.endpoint_error_m[0] == pytest.approx(np.hypot(2 - d[0], d[1]))
    assert q.angle_error_deg_max == pytest.approx(1.0)


def test_walls_partial_observation() -> None:
    """The runs observed only x <= 2 m of the bottom wall and nothing of the left wall; the
    fitted bottom wall covers x in [0, 2.1]: found, with only the observed end scored."""
    fitted = _fitted()
    fitted[0] = [0.0, 0.0, 2.1, 0.0]
    samples, index = wall_samples(ROOM, 0.01), wall_sample_index(ROOM, 0.01)
    observed = ~((index == 0) & (samples[:, 0] > 2.0)) & (index != 3)
    q = evaluate_walls(fitted, ROOM, observed)
    assert q.found == (0, 1, 2) and q.unobserved == (3,) and q.recall == 1.0
    assert q.n_true_observed == 3
    assert q.matches[0].endpoint_error_m == (0.0, None)
    assert q.precision == 1.0  # the fitted left wall lies on a true wall: not false
    assert evaluate_walls(fitted, ROOM).missed == (0,)  # judged on the whole wall: 52 %
    glimpse = observed | ((index == 3) & (samples[:, 1] < 0.05))  # 5 cm of the left wall
    assert evaluate_walls(fitted, ROOM, glimpse).unobserved == (3,)


def test_walls_ambiguous_mirror_reported_not_false() -> None:
    """A straight path along y = -0.5 hears the bottom wall and keeps its mirror at y = -1."""
    fitted = _fitted([0.0, -1.0, 4.0, -1.0])
    pair = np.array([4, -1, -1, -1, 0])
    q = evaluate_walls(fitted, ROOM, pair=pair)
    assert q.ambiguous == (4,) and q.false_walls == () and q.precision == 1.0
    assert q.n_ambiguous == 1 and q.recall == 1.0
    assert evaluate_walls(fitted, ROOM).false_walls == (4,)  # without the pair: a false wall
    both_wrong = fitted.copy()
    both_wrong[0, [1, 3]] = 0.5  # the kept hypothesis is wrong too: both are false
    assert evaluate_walls(both_wrong, ROOM, pair=pair).false_walls == (0, 4)


def test_walls_no_fitted_walls_and_bad_input() -> None:
    q = evaluate_walls(np.zeros((0, 4)), ROOM)
    assert q.recall == 0.0 and np.isnan(q.precision) and q.missed == (0, 1, 2, 3)
    json.dumps(q.to_dict(), allow_nan=False)
    with pytest.raises(ValueError, match="observed"):
        evaluate_walls(_fitted(), ROOM, np.ones(3, bool))
    with pytest.raises(ValueError, match="walls_m"):
        evaluate_walls(np.zeros((2, 3)), ROOM)
    with pytest.raises(ValueError, match="pair"):
        evaluate_walls(_fitted(), ROOM, pair=np.zeros(2, np.int64))


def _room_map(coverage: np.ndarray | None = None) -> WallMap:
    G = np.zeros((81, 101))
    kwargs: dict[str, Any] = {} if coverage is None else {"coverage": coverage}
    wm = WallMap(G=G, origin_m=(-0.5, -0.5), resolution_m=RES, walls_m=_fitted(), **kwargs)
    for a, b in ROOM:
        for p in np.linspace(a, b, 200):
            wm.G[_cells(wm, *p)] = 1.0
    return wm


def test_observed_wall_mask_from_coverage() -> None:
    cov = np.zeros((81, 101), dtype=bool)
    cov[:, :51] = True  # x <= 2.0 m
    wm = _room_map(cov)
    obs = observed_wall_mask(ROOM, cov, wm.x_m, wm.y_m, 0.01)
    samples = wall_samples(ROOM, 0.01)
    np.testing.assert_array_equal(obs, samples[:, 0] < 2.025)
    outside = observed_wall_mask(ROOM + 100.0, cov, wm.x_m, wm.y_m, 0.01)
    assert not outside.any()
    near = observed_near_points(ROOM, np.array([[2.0, 0.0]]), 0.01, 0.5)
    assert near.sum() == pytest.approx(100, abs=1)
    with pytest.raises(ValueError, match="coverage"):
        observed_wall_mask(ROOM, cov[:, :5], wm.x_m, wm.y_m, 0.01)


def test_raster_relative_to_max_inside_coverage() -> None:
    wm = _room_map()
    r = evaluate_raster(wm, ROOM)
    assert (r.precision, r.recall) == (1.0, 1.0) and r.threshold == pytest.approx(0.2)
    wm.G[_cells(wm, 2.0, 1.5)] = 0.5  # a ghost in the middle of the room
    assert evaluate_raster(wm, ROOM).precision < 1.0
    cov = np.ones(wm.shape, dtype=bool)
    cov[_cells(wm, 2.0, 1.5)] = False  # ... that the runs did not observe: not scored
    assert evaluate_raster(wm, ROOM, coverage=cov).precision == 1.0
    wm.G[_cells(wm, 2.0, 1.5)] = 100.0  # ... nor sets the scale
    assert evaluate_raster(wm, ROOM, coverage=cov).recall == 1.0
    wm.G[_cells(wm, 2.0, 1.5)] = 0.0
    wm.G[_cells(wm, 0.0, 0.0)] = 10.0  # a retro-reflecting corner: only it is strong
    r = evaluate_raster(wm, ROOM)
    assert r.strong_cells == 1 and r.recall < 0.1
    half = np.zeros(wm.shape, dtype=bool)
    half[:, :51] = True  # recall over the observed half only
    wm.G[_cells(wm, 0.0, 0.0)] = 1.0
    wm.G[:, 51:] = 0.0
    r = evaluate_raster(wm, ROOM, coverage=half)
    assert r.recall == 1.0 and 0.4 < r.observed_wall_share < 0.6


def test_evaluate_map_combines_all_three() -> None:
    cov = np.ones((81, 101), dtype=bool)
    wm = _room_map(cov)
    report = evaluate_map(wm, ROOM)
    assert report.walls.recall == 1.0 and report.raster.precision == 1.0
    assert report.fraction_of_p99.get(0.5).precision == 1.0
    d = report.to_dict()
    assert set(d) == {"walls", "raster", "fraction_of_p99"}
    json.dumps(d, allow_nan=False)
