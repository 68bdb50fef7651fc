"""WallMap v2 fields: defaults for old callers, validation naming the field, wall raster, the
ideal map of known walls."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from mapping.quality import distance_to_walls
from mapping.wallmap import WallMap, rasterize_walls, wallmap_from_walls


def test_defaults_keep_old_callers_working() -> None:
    wm = WallMap(G=np.zeros((3, 4)), origin_m=(0.0, 0.0), resolution_m=0.05)
    assert wm.walls_m.shape == (0, 4) and wm.n_walls == 0
    assert wm.wall_strength.shape == (0,) and wm.wall_sigma.shape == (0, 3)
    assert wm.wall_ambiguous.dtype == bool and wm.wall_pair.dtype == np.int64
    assert wm.coverage.shape == (3, 4) and wm.coverage.all()


def test_per_wall_defaults() -> None:
    wm = WallMap(G=np.zeros((3, 4)), origin_m=(0.0, 0.0), resolution_m=0.05,
                 walls_m=np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 1.0, 1.0, 1.0]]))
    np.testing.assert_array_equal(wm.wall_strength, [1.0, 1.0])
    assert np.isnan(wm.wall_sigma).all() and wm.wall_sigma.shape == (2, 3)
    np.testing.assert_array_equal(wm.wall_pair, [-1, -1])
    assert not wm.wall_ambiguous.any()


@pytest.mark.parametrize(("kwargs", "field"), [
    ({"walls_m": np.zeros((2, 3))}, "walls_m"),
    ({"walls_m": np.array([[0.0, np.nan, 1.0, 1.0]])}, "walls_m"),
    ({"walls_m": np.zeros((1, 4)), "wall_strength": np.ones(2)}, "wall_strength"),
    ({"walls_m": np.zeros((1, 4)), "wall_strength": np.array([-1.0])}, "wall_strength"),
    ({"walls_m": np.zeros((1, 4)), "wall_sigma": np.ones((1, 2))}, "wall_sigma"),
    ({"walls_m": np.zeros((1, 4)), "wall_sigma": np.array([[0.0, -1.0, 0.0]])}, "wall_sigma"),
    ({"walls_m": np.zeros((1, 4)), "wall_ambiguous": np.array([1])}, "wall_ambiguous"),
    ({"walls_m": np.zeros((1, 4)), "wall_pair": np.array([0])}, "wall_pair"),
    ({"walls_m": np.zeros((2, 4)), "wall_pair": np.array([1, -1]),
      "wall_ambiguous": np.array([True, True])}, "wall_pair"),
    ({"walls_m": np.zeros((2, 4)), "wall_pair": np.array([1, 0])}, "wall_ambiguous"),
    ({"walls_m": np.zeros((2, 4)), "wall_pair": np.array([0.5, 1.0])}, "wall_pair"),
    ({"coverage": np.ones((4, 3), dtype=bool)}, "coverage"),
    ({"coverage": np.ones((3, 4))}, "coverage"),
])
def test_validation_names_the_field(kwargs: dict[str, Any], field: str) -> None:
    with pytest.raises(ValueError, match=f"WallMap.{field}"):
        WallMap(G=np.zeros((3, 4)), origin_m=(0.0, 0.0), resolution_m=0.05, **kwargs)


def test_rasterize_walls_one_cell_wide() -> None:
    x = np.linspace(0.0, 1.9, 20)
    y = np.linspace(0.0, 0.9, 10)
    mask = rasterize_walls(np.array([[0.2, 0.3, 1.5, 0.3], [0.5, 0.0, 0.5, 5.0]]), x, y)
    np.testing.assert_array_equal(np.flatnonzero(mask[3]), np.arange(2, 16))
    assert mask[:, 5].all()  # vertical wall, clipped to the grid
    assert mask.sum() == 14 + 10 - 1
    diagonal = rasterize_walls(np.array([[0.0, 0.0, 0.9, 0.9]]), x, y)
    assert all(diagonal[i, i] for i in range(10)) and diagonal.sum(axis=1).max() <= 3
    assert not rasterize_walls(np.zeros((0, 4)), x, y).any()


#: A horizontal, a vertical and a diagonal wall (the diagonal at an awkward angle).
KNOWN_WALLS = np.array([[0.0, 0.0, 3.0, 0.0], [3.0, 0.0, 3.0, 2.0], [0.2, 0.5, 2.3, 1.9]])


@pytest.mark.parametrize("resolution", [0.05, 0.1, 0.037])
def test_wallmap_from_walls_puts_g_on_the_walls_only(resolution: float) -> None:
    wm = wallmap_from_walls(KNOWN_WALLS, resolution_m=resolution, margin_m=0.5)
    assert wm.resolution_m == resolution and wm.G.dtype == np.float64
    assert set(np.unique(wm.G)) == {0.0, 1.0}
    centres = np.stack(np.meshgrid(wm.x_m, wm.y_m), axis=-1)
    d = distance_to_walls(centres, KNOWN_WALLS.reshape(-1, 2, 2))
    assert np.all(wm.G[d <= 0.375 * resolution] == 1.0)      # a wall through the cell
    assert np.all(d[wm.G == 1.0] <= math.sqrt(0.5) * resolution + 1e-9)   # ... and only there
    assert np.all(wm.G[d > resolution] == 0.0)
    xmin, xmax, ymin, ymax = wm.extent_m                      # the walls plus the margin
    assert xmin <= -0.5 + 1e-9 and xmax >= 3.5 - 1e-9 and ymin <= -0.5 + 1e-9
    assert ymax >= 2.5 - 1e-9 and xmax <= 3.5 + 1.5 * resolution
    assert wm.coverage.all() and wm.coverage.shape == wm.shape


def test_wallmap_from_walls_keeps_the_vector_walls() -> None:
    wm = wallmap_from_walls(KNOWN_WALLS, strength=np.array([1.0, 0.3, 0.7]))
    np.testing.assert_array_equal(wm.walls_m, KNOWN_WALLS)
    np.testing.assert_array_equal(wm.wall_strength, [1.0, 0.3, 0.7])
    assert wm.n_walls == 3 and not wm.wall_ambiguous.any() and (wm.wall_pair == -1).all()
    np.testing.assert_array_equal(wallmap_from_walls(KNOWN_WALLS).wall_strength, np.ones(3))
    one = wallmap_from_walls(np.array([0.0, 0.0, 1.0, 1.0]))        # one row given flat
    assert one.walls_m.shape == (1, 4) and one.G.sum() >= 20


@pytest.mark.parametrize(("kwargs", "field"), [
    ({"walls_m": np.zeros((0, 4))}, "walls_m"),
    ({"walls_m": np.array([[0.0, 0.0, np.nan, 1.0]])}, "walls_m"),
    ({"walls_m": np.array([[0.0, 0.0, np.inf, 1.0]])}, "walls_m"),
    ({"resolution_m": 0.0}, "resolution_m"),
    ({"resolution_m": -0.05}, "resolution_m"),
    ({"resolution_m": math.nan}, "resolution_m"),
    ({"resolution_m": 1.5}, "resolution_m"),
    ({"margin_m": -1.0}, "margin_m"),
    ({"margin_m": math.inf}, "margin_m"),
    ({"strength": np.ones(2)}, "wall_strength"),
    ({"strength": np.array([1.0, -0.1, 1.0])}, "wall_strength"),
])
def test_wallmap_from_walls_refuses_bad_input(kwargs: dict[str, Any], field: str) -> None:
    args: dict[str, Any] = {"walls_m": KNOWN_WALLS, **kwargs}
    with pytest.raises(ValueError, match=field):
        wallmap_from_walls(**args)
