"""The wall-map figure: fitted walls over G, ambiguous ones dashed, coverage boundary."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from mapping.wallmap import WallMap
from service.plot import draw_map, write_map_png


def _map() -> WallMap:
    coverage = np.zeros((40, 60), dtype=bool)
    coverage[5:35, 5:55] = True
    return WallMap(
        G=np.random.default_rng(0).random((40, 60)), origin_m=(0.0, 0.0), resolution_m=0.05,
        method="walls",
        walls_m=np.array([[0.5, 0.5, 2.5, 0.5], [0.5, 1.5, 2.5, 1.5], [0.5, -0.5, 2.5, -0.5]]),
        wall_strength=np.array([2.0, 1.0, 0.5]), wall_ambiguous=np.array([True, False, True]),
        wall_pair=np.array([2, -1, 0]), coverage=coverage)


def test_walls_drawn_by_strength_ambiguous_dashed() -> None:
    wm = _map()
    fig, ax = plt.subplots()
    segments = np.array([[[0.5, 0.5], [2.5, 0.5]]])
    draw_map(ax, wm, segments, None)
    fitted = [ln for ln in ax.get_lines() if ln.get_linewidth() > 0.6]
    assert len(fitted) == 3
    widths = [ln.get_linewidth() for ln in fitted]
    assert widths[0] > widths[1] > widths[2]  # by strength
    assert [ln.get_linestyle() for ln in fitted] == ["--", "-", "--"]
    true = [ln for ln in ax.get_lines() if ln.get_linewidth() <= 0.6]
    assert len(true) == 1  # the true wall, thin
    assert len(ax.collections) >= 1  # the coverage boundary (contour)
    plt.close(fig)


def test_write_map_png(tmp_path: Path) -> None:
    path = write_map_png(tmp_path / "m.png", _map(), title="t")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    grid_only = WallMap(G=np.zeros((4, 4)), origin_m=(0.0, 0.0), resolution_m=0.05)
    assert write_map_png(tmp_path / "g.png", grid_only).stat().st_size > 0
