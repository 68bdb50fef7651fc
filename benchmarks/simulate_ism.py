"""Speed of the image-source engine: seconds per simulated 1.023 s block.

For built-in scenes of 3 to 8 walls and reflection orders 1-3 (and the automatic order), the
median wall time of one block from :func:`mapping.simulate.ism.iter_ism_blocks` (validity
trace, retarded-delay Newton on the coarse grid, numba render, path table), against the
straightforward per-sample reference loop (`render_reference` in
`tests/mapping/simulate/ism/naive.py`:
trace, Newton to convergence and signal evaluation at every sample) timed on a short stretch
in the same process and scaled to a block. The two outputs are compared on that stretch.

Goal (issue 3): <= 50 ms per block for the paper scene at order 2 on 2 cores.

Writes ``benchmarks/results/simulate_ism.json`` and ``simulate_ism.png``.
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from mapping.path import builtin_path
from mapping.scene import builtin_scene
from mapping.signal import SonarConfig
from mapping.simulate.ism import (
    IsmConfig,
    iter_ism_blocks,
    plan_stretch,
    prepare_scene,
    render_stretch,
)
from tests.mapping.simulate.ism.naive import render_reference

RESULTS = Path(__file__).resolve().parent / "results"
SCENES = {"paper": "paper-b", "shoebox": "shoebox-curve", "l-room": "l-room-curve",
          "pillar": "pillar-curve"}
ORDERS: list[int | None] = [1, 2, 3, None]
N_BLOCKS = 5  # timed blocks per case (after one warm-up block)
REFERENCE_SAMPLES = 200
GOAL_S = 0.050


def time_blocks(scene_name: str, order: int | None, config: SonarConfig) -> dict:
    """Median seconds per block over ``N_BLOCKS`` blocks (the first, warm-up, excluded)."""
    scene, traj = builtin_scene(scene_name), builtin_path(SCENES[scene_name])
    engine = IsmConfig(order=order)
    gen = iter_ism_blocks(scene, traj, config, N_BLOCKS + 1, engine, np.random.default_rng(0), 3)
    first = next(gen)
    times, paths = [], []
    for _ in range(N_BLOCKS):
        t0 = time.perf_counter()
        block = next(gen)
        times.append(time.perf_counter() - t0)
        paths.append(block.paths.n)
    return {
        "walls": int(scene.segments().shape[0]),
        "order": order if order is not None else "auto",
        "order_used": first.meta["order"],
        "candidate_images": first.meta["n_images"],
        "paths_per_block": float(np.mean(paths)),
        "median_s_per_block": float(np.median(times)),
        "min_s_per_block": float(np.min(times)),
    }


def time_reference(config: SonarConfig) -> dict:
    """The per-sample reference loop on a short stretch, scaled to a block; accuracy."""
    scene, traj = builtin_scene("paper"), builtin_path("paper-b")
    engine = IsmConfig(order=2)
    start = 5 * config.block_samples + 1000
    prepared = prepare_scene(scene, config, engine)
    t0 = time.perf_counter()
    slow = render_reference(prepared, traj, config, engine, start, REFERENCE_SAMPLES)
    per_sample = (time.perf_counter() - t0) / REFERENCE_SAMPLES
    plan = plan_stretch(prepared, traj, config, engine, start, REFERENCE_SAMPLES)
    fast = render_stretch(plan, config, engine)
    return {
        "scene": "paper",
        "order": 2,
        "samples": REFERENCE_SAMPLES,
        "s_per_sample": per_sample,
        "s_per_block_extrapolated": per_sample * config.block_samples,
        "max_abs_error_fast_vs_reference": float(np.max(np.abs(fast - slow))),
        "max_abs_reference": float(np.max(np.abs(slow))),
    }


def plot(cases: list[dict], reference: dict, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name in SCENES:
        rows = [c for c in cases if c["scene"] == name and c["order"] != "auto"]
        ax.plot([c["order"] for c in rows], [1e3 * c["median_s_per_block"] for c in rows],
                "o-", label=f"{name} ({rows[0]['walls']} walls)")
        auto = [c for c in cases if c["scene"] == name and c["order"] == "auto"]
        if auto:
            ax.plot([3.3], [1e3 * auto[0]["median_s_per_block"]], "x", color="k")
            ax.annotate(f"auto (order {auto[0]['order_used']})", (3.33,
                        1e3 * auto[0]["median_s_per_block"]), fontsize=7)
    ax.axhline(1e3 * GOAL_S, ls="--", color="r", label="goal 50 ms (paper, order 2)")
    ax.axhline(1e3 * reference["s_per_block_extrapolated"], ls=":", color="gray",
               label="per-sample reference loop (paper, order 2)")
    ax.set_yscale("log")
    ax.set_xlabel("reflection order (x: automatic order)")
    ax.set_ylabel("ms per 1.023 s block")
    ax.set_xticks([1, 2, 3])
    ax.set_title("Image-source engine: time per simulated block")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    config = SonarConfig()
    time_blocks("paper", 2, config)  # compile / warm caches
    cases = []
    for name in SCENES:
        for order in ORDERS:
            if order is None and name == "pillar":
                continue  # ~600 beams per image: tens of seconds per block (see README)
            case = {"scene": name, **time_blocks(name, order, config)}
            cases.append(case)
            print(f"{name:8s} order {case['order']!s:4s} ({case['order_used']:2d}) "
                  f"{case['paths_per_block']:6.1f} paths  "
                  f"{1e3 * case['median_s_per_block']:8.1f} ms/block")
    reference = time_reference(config)
    paper2 = next(c for c in cases if c["scene"] == "paper" and c["order"] == 2)
    summary = {
        "paper_order2_ms_per_block": 1e3 * paper2["median_s_per_block"],
        "goal_ms_per_block": 1e3 * GOAL_S,
        "meets_goal": paper2["median_s_per_block"] <= GOAL_S,
        "speedup_vs_reference": reference["s_per_block_extrapolated"]
        / paper2["median_s_per_block"],
    }
    print(f"reference loop: {reference['s_per_block_extrapolated']:.1f} s/block "
          f"(extrapolated from {REFERENCE_SAMPLES} samples); speed-up "
          f"{summary['speedup_vs_reference']:.0f}x; max |fast - reference| = "
          f"{reference['max_abs_error_fast_vs_reference']:.2e} "
          f"(of {reference['max_abs_reference']:.3f})")
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = {
        "benchmark": "simulate_ism",
        "block_s": config.block_s,
        "cases": cases,
        "reference": reference,
        "summary": summary,
        "machine": {"cpus": os.cpu_count(), "load_average": list(os.getloadavg()),
                    "python": platform.python_version(),
                    "numba_threads": int(os.environ.get("NUMBA_NUM_THREADS", os.cpu_count() or 1))},
    }
    (RESULTS / "simulate_ism.json").write_text(json.dumps(out, indent=2))
    plot(cases, reference, RESULTS / "simulate_ism.png")
    print(f"wrote {RESULTS / 'simulate_ism.json'} and .png")


if __name__ == "__main__":
    main()
