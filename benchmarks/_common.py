"""Shared by the mapping benchmarks: paths and the cached image-source simulation of a
built-in path (simulation time is never part of a measurement)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from mapping.files import read_run, write_run
from mapping.run import Run

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
CACHE = ROOT / "out" / "bench_runs"


def simulated_run(path_name: str, repetitions: int = 10, snr_db: float | None = None,
                  verbose: bool = False) -> Run:
    """The built-in path simulated with the image-source engine (cached on disk in
    ``out/bench_runs/``; ``verbose`` prints the simulation time of a cache miss)."""
    from mapping.path import builtin_path, builtin_path_scene
    from mapping.scene import builtin_scene
    from mapping.signal import SonarConfig
    from mapping.simulate import simulate_run
    from mapping.simulate.ism import IsmConfig

    tag = f"{path_name}_M{repetitions}" + ("" if snr_db is None else f"_snr{snr_db:g}")
    cached = CACHE / f"{tag}.npz"
    if cached.exists():
        return read_run(cached)
    config = SonarConfig(repetitions=repetitions)
    trajectory = builtin_path(path_name)
    n_blocks = int(trajectory.duration_s / config.block_s)
    t = time.perf_counter()
    run = simulate_run(builtin_scene(builtin_path_scene(path_name)), trajectory, config,
                       n_blocks, IsmConfig(snr_db=snr_db), np.random.default_rng(1), seed=1)
    write_run(cached, run)
    if verbose:
        print(f"simulated {tag}: {n_blocks} blocks in {time.perf_counter() - t:.0f} s",
              flush=True)
    return run
