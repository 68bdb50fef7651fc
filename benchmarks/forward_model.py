"""Benchmark: the forward model of the heat map (mapping.forward) - speed and fidelity.

* Speed: median microseconds per pose of the echo list (numba kernel, batch of poses, after
  warm-up; and one ``echoes`` call including the Python wrapper) for orders 1 and 2 on rooms
  of 4, 10 and 20 walls; milliseconds per ``echoes_batch`` call on 2000 poses in the shoebox
  with exact corners (``right_corner_tol_deg`` 0) and with right corners heard at their
  vertex (3 deg, the localization sensor's setting); rendering time of one heat map.
* Point-spread: ``render_heatmap`` of one unit echo against ``doppler_heatmap`` of the exact
  synthetic echo (``mapping.synthetic``) at several speeds and wall angles: error at the peak,
  in the PSF window of rows the bank nearly matches (|D| < 20 samples), and anywhere.
* Scenes: every built-in path, three blocks each (1/4, 1/2, 3/4 of the path), simulated with
  the image-source engine (order 3 fixed; ``ism_auto`` runs: automatic order on one block) + eq. 1
  against the model at orders 1, 2, 3: correlation of rendered vs simulated map, share of the
  predicted echoes above 0.1 x the strongest that sit on a local maximum within one range and
  one angle bin, and the order ``required_order`` picks.

Writes ``benchmarks/results/forward_model.json`` and ``forward_model.png``.
Run: ``python -m benchmarks.forward_model``.
"""

from __future__ import annotations

import json
import math
import platform
import time
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from mapping import synthetic
from mapping.forward import (
    PSF_HALF_WIDTH,
    Echoes,
    ForwardParams,
    WallSet,
    drift_samples,
    echoes,
    echoes_batch,
    heatmap_correlation,
    match_echoes,
    render_heatmap,
    required_order,
)
from mapping.heatmap import doppler_heatmap, heatmap_of_run, required_margin
from mapping.path import builtin_path, builtin_path_names, builtin_path_scene
from mapping.scene import builtin_scene
from mapping.signal import SonarConfig
from mapping.simulate.ism import IsmConfig, iter_ism_blocks

RESULTS = Path(__file__).resolve().parent / "results"
CFG = SonarConfig()


def _room(n_walls: int, rng: np.random.Generator) -> WallSet:
    """A closed room of n walls: a random star-shaped polygon of radius 3-6 m."""
    ang = np.sort(rng.uniform(0, 2 * np.pi, n_walls))
    rad = rng.uniform(3.0, 6.0, n_walls)
    pts = np.column_stack([rad * np.cos(ang), rad * np.sin(ang)])
    return WallSet.from_array(np.hstack([pts, np.roll(pts, -1, axis=0)]))


def speed_table() -> list[dict[str, Any]]:
    rng = np.random.default_rng(0)
    rows = []
    for n_walls in (4, 10, 20):
        walls = _room(n_walls, rng)
        poses = np.column_stack([rng.uniform(-1.5, 1.5, (2000, 2)), rng.uniform(-3, 3, 2000)])
        for order in (1, 2):
            params = ForwardParams(max_order=order)
            echoes_batch(walls, poses[:10], 0.1, CFG, params)  # warm-up
            batch = []
            for _ in range(7):
                t = time.perf_counter()
                out = echoes_batch(walls, poses, 0.1, CFG, params)
                batch.append((time.perf_counter() - t) / poses.shape[0] * 1e6)
            single = []
            for pose in poses[:300]:
                t = time.perf_counter()
                echoes(walls, pose, 0.1, CFG, params)
                single.append((time.perf_counter() - t) * 1e6)
            rows.append(dict(walls=n_walls, order=order,
                             batch_us_per_pose=float(np.median(batch)),
                             single_call_us=float(np.median(single)),
                             mean_echoes=float(out.count.mean())))
    walls = WallSet.from_scene(builtin_scene("shoebox"))
    rows.extend(corner_speed(walls, rng))
    e = echoes(walls, [1.0, 1.0, 0.3], 0.1, CFG, ForwardParams(max_order=3))
    render_heatmap(e, 0.1, CFG)
    times = []
    for _ in range(10):
        t = time.perf_counter()
        render_heatmap(e, 0.1, CFG)
        times.append((time.perf_counter() - t) * 1e3)
    rows.append(dict(render_ms=float(np.median(times)), render_echoes=e.k))
    return rows


def corner_speed(walls: WallSet, rng: np.random.Generator) -> list[dict[str, Any]]:
    """Milliseconds per ``echoes_batch`` call (2000 poses, order 2, 5 m) with right corners
    off (0) and heard at their vertex (3 deg)."""
    ends = walls.segments_m.reshape(-1, 2)
    lo, hi = ends.min(axis=0), ends.max(axis=0)
    poses = np.column_stack([rng.uniform(lo + 0.2, hi - 0.2, (2000, 2)),
                             rng.uniform(-np.pi, np.pi, 2000)])
    rows = []
    for tol in (0.0, 3.0):
        params = ForwardParams(max_order=2, right_corner_tol_deg=tol, max_range_m=5.0)
        echoes_batch(walls, poses, 0.12, CFG, params)  # warm-up
        times = []
        for _ in range(21):
            t = time.perf_counter()
            echoes_batch(walls, poses, 0.12, CFG, params)
            times.append((time.perf_counter() - t) * 1e3)
        rows.append(dict(corner_tol_deg=tol, poses=2000, batch_ms=float(np.median(times))))
    return rows


def psf_table() -> list[dict[str, Any]]:
    rows = []
    for speed in (0.05, 0.1, 0.2):
        for normal_deg in (0.0, 40.0, 90.0, 137.0, 180.0):
            phi = math.radians(normal_deg)
            run = synthetic.synthetic_run(CFG, synthetic.Wall(3.0, phi), speed, n_blocks=3,
                                          spreading=False)
            measured = heatmap_of_run(run, 1)
            pose = run.pose[1]
            n = np.array([math.cos(pose[2] + phi), math.sin(pose[2] + phi)])
            foot, t = pose[:2] + 3.0 * n, np.array([-n[1], n[0]])
            e = echoes(WallSet.from_array([[*(foot - 50 * t), *(foot + 50 * t)]]), pose, speed,
                       CFG)
            unit = Echoes(e.range_m, e.cos_doppler, e.angle_rad, np.ones(1), e.order, e.walls,
                          e.points_m, e.arrival_bearing_rad)
            rendered = render_heatmap(unit, speed, CFG)
            peak = float(measured.H.max())
            drift = drift_samples(e.cos_doppler, CFG.angles_rad, speed, CFG)[:, 0]
            cols = np.arange(CFG.period_samples)
            lag = e.range_m[0] / CFG.range_per_sample_m
            near = 0.0
            for row in np.flatnonzero(np.abs(drift) < 20):
                win = np.abs(cols - lag) <= abs(drift[row]) / 2 + PSF_HALF_WIDTH
                near = max(near, float(np.abs(rendered.H[row, win] - measured.H[row, win]).max()))
            rows.append(dict(speed_m_s=speed, normal_deg=normal_deg, peak=peak,
                             peak_error=float(abs(rendered.H.max() - peak) / peak),
                             window_error=near / peak,
                             max_error=float(np.abs(rendered.H - measured.H).max() / peak)))
    return rows


def _block_heatmap(scene: Any, trajectory: Any, k: int, engine: IsmConfig) -> tuple[Any, Any]:
    """Heat map of block k (with its neighbours' samples) and its SimBlock."""
    blocks = list(iter_ism_blocks(scene, trajectory, CFG, 3, engine, np.random.default_rng(0),
                                  first_block=k - 1))
    margin = required_margin(CFG, blocks[1].speed_m_s)
    samples = np.concatenate([blocks[0].samples[-margin:], blocks[1].samples,
                              blocks[2].samples[:margin]])
    hm = doppler_heatmap(samples, blocks[1].speed_m_s, CFG, left=margin, right=margin)
    return hm, blocks[1]


def _compare(walls: WallSet, hm: Any, block: Any, order: int) -> dict[str, Any]:
    e = echoes(walls, block.pose, block.speed_m_s, CFG, ForwardParams(max_order=order))
    rendered = render_heatmap(e, block.speed_m_s, CFG)
    strong = e.amplitude >= 0.1 * e.amplitude.max()
    drift = 0.5 * CFG.fs_hz / (2 * math.pi * CFG.carrier_hz)
    cos_tol = drift * CFG.sound_speed_m_s / (2 * abs(block.speed_m_s) * CFG.block_samples)
    matched = match_echoes(e, hm, cos_tolerance=cos_tol)
    return dict(order=order, correlation=heatmap_correlation(rendered, hm),
                matched=int(matched[strong].sum()), predicted=int(strong.sum()),
                echoes=e.k)


def scene_table() -> list[dict[str, Any]]:
    rows = []
    for name in builtin_path_names():
        scene = builtin_scene(builtin_path_scene(name))
        trajectory = builtin_path(name)
        walls = WallSet.from_scene(scene)
        nb = int(trajectory.duration_s / CFG.block_s)
        ks = [max(1, nb // 4), nb // 2, min(3 * nb // 4, nb - 2)]
        for k in ks:
            hm, block = _block_heatmap(scene, trajectory, k, IsmConfig(order=3))
            need = required_order(walls, block.pose[None], block.speed_m_s, CFG)
            for order in (1, 2, 3):
                rows.append(dict(path=name, scene=scene.name, block=k, ism="order 3",
                                 required_order=need, **_compare(walls, hm, block, order)))
        hm, block = _block_heatmap(scene, trajectory, ks[1], IsmConfig())
        for order in (1, 2, 3):
            rows.append(dict(path=name, scene=scene.name, block=ks[1], ism="auto",
                             **_compare(walls, hm, block, order)))
    return rows


def _plot(result: dict[str, Any], path: Path) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    sp = [r for r in result["speed"] if "walls" in r]
    for order, marker in ((1, "o"), (2, "s")):
        sel = [r for r in sp if r["order"] == order]
        axes[0].plot([r["walls"] for r in sel], [r["batch_us_per_pose"] for r in sel],
                     marker=marker, label=f"order {order}, batch")
        axes[0].plot([r["walls"] for r in sel], [r["single_call_us"] for r in sel],
                     marker=marker, ls="--", label=f"order {order}, one call")
    axes[0].set(xlabel="walls", ylabel="us per pose", yscale="log", title="echo list")
    axes[0].legend(fontsize=8)
    ps = result["psf"]
    for speed in sorted({r["speed_m_s"] for r in ps}):
        sel = [r for r in ps if r["speed_m_s"] == speed]
        axes[1].plot([r["normal_deg"] for r in sel], [r["window_error"] for r in sel], "o-",
                     label=f"{speed} m/s, PSF window")
        axes[1].plot([r["normal_deg"] for r in sel], [r["max_error"] for r in sel], "x:",
                     label=f"{speed} m/s, anywhere")
    axes[1].set(xlabel="wall normal from travel (deg)", ylabel="|rendered - eq. 1| / peak",
                yscale="log", title="point-spread vs eq. 1")
    axes[1].legend(fontsize=7)
    sc = [r for r in result["scenes"] if r["ism"] == "order 3"]
    paths = list(dict.fromkeys(r["path"] for r in sc))
    for order in (1, 2, 3):
        vals = [np.mean([r["correlation"] for r in sc if r["path"] == p and r["order"] == order])
                for p in paths]
        axes[2].plot(range(len(paths)), vals, "o-", label=f"model order {order}")
    axes[2].set_xticks(range(len(paths)), paths, rotation=60, fontsize=7)
    axes[2].set(ylabel="correlation with ISM (order 3) + eq. 1", title="scenes")
    axes[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    result: dict[str, Any] = dict(platform=platform.platform(), speed=speed_table(),
                                  psf=psf_table(), scenes=scene_table())
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "forward_model.json").write_text(json.dumps(result, indent=1))
    _plot(result, RESULTS / "forward_model.png")
    for r in result["speed"]:
        print(r)
    for r in result["psf"]:
        print({k: round(v, 4) if isinstance(v, float) else v for k, v in r.items()})
    for r in result["scenes"]:
        print(r)


if __name__ == "__main__":
    main()
