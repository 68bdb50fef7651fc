"""Figures of the core results (matplotlib, Agg): the edge where plots live.

``write_heatmap_png`` draws a :class:`~mapping.heatmap.HeatMap` as the paper's polar heat map
(Fig. 2): angle from the direction of travel (up) mirrored to both sides, since the sensor
cannot tell left from right, range outwards; the peak and, optionally, the truth are marked.
``write_map_png`` (``draw_map`` on given axes) draws a wall map: G, the fitted walls (colour and
width by strength, ambiguous mirror hypotheses dashed), the coverage boundary, the true walls.
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.projections.polar import PolarAxes  # noqa: E402

from mapping.heatmap import HeatMap, find_peak
from mapping.wallmap import WallMap


def write_heatmap_png(
    path: Path,
    hm: HeatMap,
    *,
    title: str = "",
    max_range_m: float | None = None,
    truth: tuple[float, float] | None = None,
) -> Path:
    """Write ``hm`` as a polar PNG; ``truth`` = (range_m, angle_rad) to mark. Returns path."""
    peak = find_peak(hm)
    r_max = max_range_m or min(float(hm.ranges_m[-1]), max(2.0 * peak.range_m, 1.0))
    n_r = int(np.searchsorted(hm.ranges_m, r_max)) + 1
    pool = max(1, n_r // 120)  # max-pool range bins so 4 mm echoes stay visible
    n_r -= n_r % pool
    h = hm.H[:, :n_r].reshape(hm.H.shape[0], -1, pool).max(axis=2)
    db = 20 * np.log10(np.maximum(h / max(float(hm.H.max()), 1e-300), 1e-3))
    fig = plt.figure(figsize=(6.5, 6))
    ax = fig.add_subplot(projection="polar")
    assert isinstance(ax, PolarAxes)
    ax.set_theta_zero_location("N")
    edges_r = np.r_[hm.ranges_m[:n_r:pool], hm.ranges_m[1] * n_r]
    mid = 0.5 * (hm.angles_rad[1:] + hm.angles_rad[:-1])
    edges_a = np.r_[0.0, mid, math.pi]
    for sign in (1.0, -1.0):  # left/right mirror
        mesh = ax.pcolormesh(sign * edges_a, edges_r, db.T, vmin=-30, vmax=0, cmap="magma",
                             shading="flat")
    ax.plot([peak.angle_rad, -peak.angle_rad], [peak.range_m] * 2, "o", mfc="none",
            mec="cyan", ms=16, mew=1.5,
            label=f"peak {peak.range_m:.3f} m, {math.degrees(peak.angle_rad):.1f} deg")
    if truth is not None:
        ax.plot([truth[1], -truth[1]], [truth[0]] * 2, "s", mfc="none", mec="lime", ms=22, mew=1.2,
                label=f"truth {truth[0]:.3f} m, {math.degrees(truth[1]):.1f} deg")
    ax.set_rmax(r_max)
    ticks = np.arange(0, 360, 45)
    ax.set_thetagrids(ticks, [f"{t if t <= 180 else t - 360:d}" for t in ticks])
    ax.set_title(title or "Doppler heat map (0 deg = direction of travel)", fontsize=10)
    fig.colorbar(mesh, ax=ax, label="dB re peak (range bins max-pooled for display)",
                 shrink=0.7, pad=0.1)
    ax.legend(loc="lower left", bbox_to_anchor=(-0.15, -0.15), fontsize=8)
    if not hm.direction_observable:
        ax.text(0.5, -0.12, "speed too low: direction not observable", transform=ax.transAxes,
                ha="center", color="red")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def write_map_png(
    path: Path,
    wallmap: WallMap,
    *,
    segments: np.ndarray | None = None,
    poses: np.ndarray | None = None,
    title: str = "",
    scale_percentile: float = 99.0,
) -> Path:
    """Write a wall map as a PNG: G (scaled to its ``scale_percentile`` of the positive cells,
    so retro-reflecting corners do not black out the walls), the fitted walls (colour and width
    by strength, ambiguous mirror hypotheses dashed), the coverage boundary (faint), and the true
    walls (thin) and tracked poses when given. Returns ``path``."""
    fig, ax = plt.subplots(figsize=(6.5, 6))
    draw_map(ax, wallmap, segments, poses, scale_percentile)
    ax.set_title(title or f"wall map ({wallmap.method})", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def draw_map(ax: plt.Axes, wallmap: WallMap, segments: np.ndarray | None,
             poses: np.ndarray | None, scale_percentile: float = 99.0) -> None:
    """Draw ``wallmap`` on ``ax`` (see :func:`write_map_png`); ``segments`` (W, 2, 2) are the
    true walls, ``poses`` (n, 3) the tracked poses."""
    G = wallmap.G
    pos = G[G > 0]
    scale = float(np.percentile(pos, scale_percentile)) if pos.size else 1.0
    im = ax.imshow(G / scale, origin="lower", extent=wallmap.extent_m, vmin=0, vmax=1,
                   cmap="magma", interpolation="nearest")
    if not wallmap.coverage.all():
        ax.contour(wallmap.x_m, wallmap.y_m, wallmap.coverage.astype(float), levels=[0.5],
                   colors="white", linewidths=0.6, alpha=0.35)
    if segments is not None:
        for k, (a, b) in enumerate(np.asarray(segments)):
            ax.plot([a[0], b[0]], [a[1], b[1]], "-", color="cyan", lw=0.6, alpha=0.9, zorder=3,
                    label="true walls" if k == 0 else None)
    _draw_walls(ax, wallmap)
    if poses is not None:
        ok = np.isfinite(np.asarray(poses)).all(axis=1)
        ax.plot(poses[ok, 0], poses[ok, 1], ".", color="white", ms=2, zorder=4)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    plt.colorbar(im, ax=ax, shrink=0.8, label=f"G / p{scale_percentile:g}(G > 0)")
    if segments is not None or wallmap.n_walls:
        ax.legend(loc="upper right", fontsize=7, framealpha=0.6)


def _draw_walls(ax: plt.Axes, wallmap: WallMap) -> None:
    """Fitted walls: colour and width by strength (relative to the strongest), mirrors dashed."""
    if not wallmap.n_walls:
        return
    strength = wallmap.wall_strength
    rel = strength / strength.max() if strength.max() > 0 else np.ones_like(strength)
    cmap = plt.get_cmap("viridis")
    labelled = {False: False, True: False}
    for (x0, y0, x1, y1), s, ambiguous in zip(wallmap.walls_m, rel, wallmap.wall_ambiguous,
                                              strict=True):
        amb = bool(ambiguous)
        label = None
        if not labelled[amb]:
            label = "fitted walls, ambiguous (mirror kept)" if amb else "fitted walls"
            labelled[amb] = True
        ax.plot([x0, x1], [y0, y1], "--" if amb else "-", color=cmap(0.45 + 0.55 * float(s)),
                lw=1.0 + 2.5 * float(s), solid_capstyle="round", label=label)
