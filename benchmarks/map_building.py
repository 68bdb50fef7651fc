"""Benchmark: blocks per second into the wall map G, paper method and inverse, and the batch
builder's throughput with 1 and 2 worker processes.

Input: the paper scene's path B simulated with the image-source engine (M = 10, 59 blocks),
cached in ``out/bench_runs/``; simulation time is never counted. Measured in one process:

* heat maps: time per block of ``mapping.heatmap.heatmap_of_run`` (reported separately, since
  the goal "a 100-block run mapped in <= 1 s" excludes simulation but a user also pays this);
* paper: :func:`mapping.grid.accumulate` of 100 blocks (the 59 heat maps cycled with their
  poses) on the extent of the run, numba kernel; the numpy twin on 10 blocks as the baseline;
* inverse: :func:`mapping.reconstruct.reconstruct_inverse` on the 59 blocks;
* batch: :func:`mapping.build.build_map` over 4 runs (the run cut into 4 x 14 blocks), heat maps
  included, with 1 and 2 spawned worker processes (process start-up included: that is what a
  user waits for: "cold") and in a pool whose workers have already started ("warm").

Wall-clock medians and CPU times are recorded with the load average (the machine is shared).
Writes ``benchmarks/results/map_building.json`` and ``map_building.png``. Run:
``python -m benchmarks.map_building``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import time
from collections.abc import Callable
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from benchmarks._common import RESULTS, simulated_run
from mapping.build import BuildParams, RunSource, build_map, process_pool, run_heatmaps
from mapping.grid import GridParams, accumulate, map_extent
from mapping.reconstruct import InverseParams, observations_from_heatmaps, reconstruct_inverse
from mapping.run import Run
from tests.mapping.grid.naive import backproject_numpy


def timed(fn: Callable[[], Any], repeats: int) -> tuple[float, float, Any]:
    """Median wall-clock and CPU seconds of ``fn`` over ``repeats`` calls, and its result."""
    walls, cpus, out = [], [], None
    for _ in range(repeats):
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - w)
        cpus.append(time.process_time() - c)
    return float(np.median(walls)), float(np.median(cpus)), out


def cut(run: Run, a: int, b: int) -> Run:
    """Blocks a..b-1 of ``run``."""
    return dataclasses.replace(run, samples=run.samples[a:b], t_s=run.t_s[a:b],
                               speed_m_s=run.speed_m_s[a:b],
                               yaw_rate_rad_s=run.yaw_rate_rad_s[a:b], pose=run.pose[a:b])


def main() -> None:
    run = simulated_run("paper-b")
    n = run.n_blocks
    grid = GridParams()
    hm_wall, hm_cpu, hms = timed(lambda: list(run_heatmaps(run)), 1)
    idx = np.arange(100) % n
    hms100 = [hms[i] for i in idx]
    poses100 = run.pose[idx]
    extent = map_extent(run.pose, grid.radius_m, grid.resolution_m)
    accumulate(hms[:2], run.pose[:2], grid, extent)  # warm up (numba cache / compile)
    paper_wall, paper_cpu, _ = timed(lambda: accumulate(hms100, poses100, grid, extent), 5)

    def numpy_twin() -> None:
        for hm, p in zip(hms[:10], run.pose[:10], strict=True):
            backproject_numpy(extent.shape, *extent.origin_m, extent.resolution_m, hm.H,
                              float(hm.ranges_m[0]), float(hm.ranges_m[1] - hm.ranges_m[0]),
                              *p, grid.radius_m, False)

    twin_wall, _, _ = timed(numpy_twin, 1)
    inv = InverseParams()
    obs, _ = observations_from_heatmaps(hms, run.pose, grid, inv, config=run.config)
    inv_wall, inv_cpu, (_, info) = timed(lambda: reconstruct_inverse(obs, extent, grid, inv), 1)

    parts = [cut(run, 14 * i, 14 * (i + 1)) for i in range(4)]
    sources = [RunSource.from_run(r, f"part{i}") for i, r in enumerate(parts)]
    batch: dict[int, dict[str, float]] = {}
    warm_src = [RunSource.from_run(cut(run, 0, 1), "warm-up")]
    for workers in (1, 2):
        w, c, wm = timed(lambda workers=workers: build_map(sources, BuildParams(),
                                                           workers=workers), 1)
        batch[workers] = {"cold_wall_s": w, "cpu_s_main": c, "checksum": float(wm.G.sum())}
        if workers == 1:
            batch[1].update(wall_s=w, runs_per_s=4 / w, blocks_per_s=56 / w)
            continue
        with process_pool(workers) as pool:  # steady state: workers already started
            for _ in range(workers):
                build_map(warm_src, BuildParams(), executor=pool)
            w, _, wm2 = timed(lambda pool=pool: build_map(sources, BuildParams(),
                                                          executor=pool), 1)
        batch[workers].update(wall_s=w, runs_per_s=4 / w, blocks_per_s=56 / w,
                              warm_checksum=float(wm2.G.sum()))
    result = {
        "machine": {"cpus": os.cpu_count(), "load_avg": os.getloadavg(),
                    "python": platform.python_version()},
        "input": {"run": "paper-b, image-source, M=10", "blocks": n,
                  "map_cells": extent.shape[0] * extent.shape[1], "radius_m": grid.radius_m},
        "heatmap_s_per_block": hm_wall / n,
        "paper": {"blocks": 100, "wall_s": paper_wall, "cpu_s": paper_cpu,
                  "blocks_per_s": 100 / paper_wall,
                  "numpy_twin_s_per_block": twin_wall / 10,
                  "speedup_vs_numpy_twin": (twin_wall / 10) / (paper_wall / 100),
                  "100_blocks_with_heatmaps_s": paper_wall + 100 * hm_wall / n},
        "inverse": {"blocks": n, "wall_s": inv_wall, "cpu_s": inv_cpu,
                    "blocks_per_s": n / inv_wall, "solver": info},
        "batch": {"runs": 4, "blocks": 56, **{f"workers_{k}": v for k, v in batch.items()},
                  "speedup_2_vs_1_warm": batch[1]["wall_s"] / batch[2]["wall_s"],
                  "speedup_2_vs_1_cold": batch[1]["cold_wall_s"] / batch[2]["cold_wall_s"],
                  "bit_identical": batch[1]["checksum"] == batch[2]["checksum"]
                  == batch[2]["warm_checksum"]},
        "goal": "100-block run mapped (paper method, excluding simulation) <= 1 s",
        "goal_met_excluding_heatmaps": paper_wall <= 1.0,
        "goal_met_excluding_heatmaps_cpu_time": paper_cpu <= 1.0,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "map_building.json").write_text(json.dumps(result, indent=2))
    fig, ax = plt.subplots(figsize=(7, 4))
    labels = ["paper\n(G only)", "paper\nnumpy twin", "inverse\n(solve)", "heat maps",
              "batch\n1 worker", "batch\n2 workers\n(warm)"]
    rates = [100 / paper_wall, 1 / (twin_wall / 10), n / inv_wall, n / hm_wall,
             batch[1]["blocks_per_s"], batch[2]["blocks_per_s"]]
    ax.bar(labels, rates, color=["C0", "C7", "C1", "C2", "C3", "C3"])
    ax.set_yscale("log")
    ax.set_ylabel("blocks per second (log)")
    ax.set_title(f"wall-map throughput (paper-b, {extent.shape[1]}x{extent.shape[0]} cells)",
                 fontsize=10)
    for i, r in enumerate(rates):
        ax.text(i, r, f"{r:.3g}", ha="center", va="bottom", fontsize=8)
    fig.tight_layout()
    fig.savefig(RESULTS / "map_building.png", dpi=110)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
