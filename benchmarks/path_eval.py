"""Benchmark: trajectory position + velocity evaluation, numba kernel vs the numpy twin.

The image-source engine evaluates the trajectory at every output sample for every echo path
and Newton step, so this is on its hot path. Writes ``benchmarks/results/path_eval.json`` and
``path_eval.png`` (medians over repeats, kernel/numpy ratio, both in this process).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from mapping.path import builtin_path
from tests.mapping.path.naive import position_velocity_numpy

RESULTS = Path(__file__).resolve().parent / "results"


def _times_s(fn, repeats: int) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """Median and minimum wall time of ``fn()`` over ``repeats`` calls after a warm-up."""
    fn()  # warm-up (and numba compile / cache load)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), float(np.min(times))


def main() -> None:
    traj = builtin_path("paper-b")  # ~300 line/arc primitives
    rng = np.random.default_rng(0)
    sizes = [1_000, 10_000, 40_920, 100_000, 1_000_000]
    rows = []
    for n in sizes:
        t = np.sort(rng.uniform(-1.0, traj.duration_s + 1.0, n))
        repeats = 30 if n <= 100_000 else 7
        k, k_min = _times_s(lambda t=t: traj.position_velocity(t), repeats)
        p, p_min = _times_s(lambda t=t: position_velocity_numpy(traj, t), repeats)
        rows.append({"n_times": n, "kernel_s": k, "numpy_s": p, "speedup": p / k,
                     "kernel_min_s": k_min, "numpy_min_s": p_min})
        print(f"n={n:>8d}  median: kernel {k * 1e3:8.3f} ms  numpy {p * 1e3:8.3f} ms  "
              f"x{p / k:5.1f}   min: {k_min * 1e3:8.3f} / {p_min * 1e3:8.3f} ms")
    RESULTS.mkdir(parents=True, exist_ok=True)
    info = {
        "benchmark": "path_eval",
        "what": "Trajectory.position_velocity (numba) vs position_velocity_numpy, paper-b path",
        "primitives": int(traj.s0_m.size),
        "cpu_count": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0],
        "numba_parallel": os.environ.get("OMNISONAR_NUMBA_PARALLEL", "1") != "0",
        "rows": rows,
    }
    (RESULTS / "path_eval.json").write_text(json.dumps(info, indent=2))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    ax.loglog(sizes, [r["kernel_s"] * 1e3 for r in rows], "o-", label="numba kernel")
    ax.loglog(sizes, [r["numpy_s"] * 1e3 for r in rows], "s--", label="numpy twin")
    ax.set_xlabel("number of times evaluated")
    ax.set_ylabel("median time for position + velocity (ms)")
    ax.set_title(f"trajectory evaluation, paper-b ({traj.s0_m.size} primitives)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(RESULTS / "path_eval.png", dpi=120)


if __name__ == "__main__":
    main()
