"""Tests of mapping.quality on maps whose answers are known by construction."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mapping.quality import distance_to_walls, evaluate, strong_threshold, wall_samples
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
