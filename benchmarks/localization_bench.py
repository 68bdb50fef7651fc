"""Localization benchmark: accuracy vs speed of the particle and grid filters (issue 6).

Data: for each scene, a mapping run (the scene's curve path, 0.1 m/s, seed 0) is simulated
with the image-source engine (reflection order 2 to keep the benchmark short) and turned
into a wall map G (paper back-projection); the filters then localize HELD-OUT runs: the
same curve at 0.15 m/s (seed 1) and the straight path at 0.15 m/s (seed 2), both with
0.005 m/s odometry speed noise.

Measured per configuration (filter x sensor model x particle count):
- tracking: tracked start (10 cm / 10 deg prior), position and heading RMSE over the run,
  mean NEES (3 when the reported covariance is honest);
- global localization: uniform start, over seeds (one seed at 10,000 particles); success =
  within 10 cm / 10 deg from block 8 on and staying there ("converged within 8 blocks"),
  reported for the curve runs (the straight runs keep a mirror ambiguity until they turn,
  and never turn);
- both raw and modulo the scenes' symmetries as this sensor sees them (pillar: 180 deg
  rotation and two mirror axes; L-room: mirror about its diagonal), per block against the
  image nearest to the estimate;
- time per update (median, p95), measured around ``step`` after a warm-up, as wall time
  and as process CPU time (the machine is shared: wall times carry other jobs' load, the
  load average is recorded);
The grid filter runs global on the first ``GRID_BLOCKS`` blocks of the curve runs.
A beta sweep calibrates the sensor sharpness against the NEES.

Writes benchmarks/results/localization.json and localization_pareto.png.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from localization.calibration import CalibrationRun, calibrate_beta
from localization.estimate import track_metrics
from localization.grid_filter import GridFilter
from localization.particle_filter import FilterConfig, ParticleFilter, Steppable, block_odometry
from localization.sensor import Model, SensorConfig, SensorTables, build_tables
from mapping.files import read_map, read_run
from mapping.heatmap import HeatMap, heatmap_of_run
from mapping.run import Run
from mapping.wallmap import WallMap
from service.cli import main as cli

ROOT = Path(__file__).resolve().parents[1]

RESULTS = ROOT / "benchmarks" / "results"
CACHE = ROOT / "out" / "localization_bench"
PARTICLES = (100, 300, 1000, 3000, 10000)
MODELS: tuple[Model, ...] = ("correlation", "range")
GRID_BLOCKS = 8
PRIOR = np.diag([0.1**2, 0.1**2, math.radians(10.0) ** 2])


def scene_data(scene: str) -> tuple[WallMap, dict[str, Run]]:
    """Map from the mapping run and the held-out runs (simulated once, cached on disk)."""
    CACHE.mkdir(parents=True, exist_ok=True)
    common = ["--snr-db", "20", "--order", "2"]
    specs = {
        "map": ["--path", f"{scene}-curve", "--seed", "0"],
        "curve": ["--path", f"{scene}-curve", "--speed", "0.15", "--seed", "1",
                  "--odometry-noise", "0.005"],
        "straight": ["--path", f"{scene}-straight", "--speed", "0.15", "--seed", "2",
                     "--odometry-noise", "0.005"],
    }
    for name, args in specs.items():
        out = CACHE / f"{scene}-{name}.npz"
        if not out.exists():
            cli(["simulate", "--scene", f"builtin:{scene}", *args, *common, "--out", str(out)])
    gmap = CACHE / f"{scene}-G.npz"
    if not gmap.exists():
        cli(["build-map", str(CACHE / f"{scene}-map.npz"), "--out", str(gmap), "--method", "paper"])
    return read_map(gmap), {k: read_run(CACHE / f"{scene}-{k}.npz") for k in ("curve",
                                                                           "straight")}


def images(scene: str, truth: np.ndarray) -> list[np.ndarray]:
    """The truth and its images under the scene's symmetries as this sensor sees them
    (rigid motions, and mirror images: the left/right fold cannot tell those apart)."""
    x, y, h = truth[:, 0], truth[:, 1], truth[:, 2]
    out = [truth]
    if scene == "l-room":        # mirror about the diagonal y = x
        out.append(np.column_stack([y, x, np.pi / 2 - h]))
    if scene == "pillar":        # 180 deg about (2.5, 2.0) and the two mirror axes
        out += [np.column_stack([5 - x, 4 - y, h + np.pi]),
                np.column_stack([5 - x, y, np.pi - h]), np.column_stack([x, 4 - y, -h])]
    for im in out:
        im[:, 2] = np.angle(np.exp(1j * im[:, 2]))
    return out


def modulo_symmetry(poses: np.ndarray, truth: np.ndarray, scene: str) -> np.ndarray:
    """Per block, the image of the truth nearest to the estimate."""
    ims = np.stack(images(scene, truth))                     # (n_images, n, 3)
    d = np.hypot(ims[:, :, 0] - poses[None, :, 0], ims[:, :, 1] - poses[None, :, 1])
    return ims[np.argmin(d, axis=0), np.arange(truth.shape[0])]


def run_blocks(run: Run) -> list[HeatMap]:
    return [heatmap_of_run(run, k) for k in range(run.n_blocks)]


def track(filt: Steppable, run: Run, hms: list[HeatMap], n_blocks: int | None = None,
          scene: str = "") -> dict[str, Any]:
    """Step through the run; metrics and per-update times."""
    v, w, dt = block_odometry(run.speed_m_s, run.yaw_rate_rad_s, run.t_s, run.config.block_s)
    n = run.n_blocks if n_blocks is None else min(n_blocks, run.n_blocks)
    poses, covs, times, cpu = [], [], [], []
    for k in range(n):
        t0, c0 = time.perf_counter(), time.process_time()
        est = filt.step(hms[k], float(v[k]), float(w[k]), float(dt[k]))
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        poses.append(est.pose)
        covs.append(est.cov)
    m = track_metrics(np.array(poses), np.array(covs), run.pose[:n])
    sym = track_metrics(np.array(poses), np.array(covs),
                        modulo_symmetry(np.array(poses), run.pose[:n], scene))
    return {"name": str(run.meta.get("path", scene)),
            "metrics": dataclasses.asdict(m), "metrics_mod_sym": dataclasses.asdict(sym),
            "times_s": times[1:], "cpu_s": cpu[1:]}


def pf_case(tables: SensorTables, n: int, run: Run, hms: list[HeatMap], seed: int,
            tracked: bool, scene: str = "") -> dict[str, Any]:
    pf = ParticleFilter(tables, FilterConfig(n_particles=n), np.random.default_rng(seed),
                        pose=run.pose[0] if tracked else None, cov=PRIOR if tracked else None)
    return track(pf, run, hms, scene=scene)


def summarize_cases(tracked: list[dict[str, Any]], global_: list[dict[str, Any]]
                    ) -> dict[str, Any]:
    def rmse(key: str) -> float:
        vals = [c["metrics"][key] for c in tracked if c["metrics"]["blocks_to_converge"] == 0]
        return float(np.sqrt(np.mean(np.square(vals)))) if vals else math.nan

    times = np.concatenate([c["times_s"] for c in tracked + global_])
    cpu = np.concatenate([c["cpu_s"] for c in tracked + global_])
    conv = [c["metrics"]["blocks_to_converge"] for c in global_]
    conv_sym = [c["metrics_mod_sym"]["blocks_to_converge"] for c in global_]
    return {
        "tracking_lost_runs_mod_sym": sum(c["metrics_mod_sym"]["blocks_to_converge"] != 0
                                          for c in tracked),
        "global_success_rate_8_blocks_mod_sym": float(np.mean(
            [b is not None and b <= 8 for b in conv_sym])) if conv_sym else math.nan,
        "tracking_position_rmse_m": rmse("position_rmse_m"),
        "tracking_heading_rmse_deg": math.degrees(rmse("heading_rmse_rad")),
        "tracking_lost_runs": sum(c["metrics"]["blocks_to_converge"] != 0 for c in tracked),
        "tracking_nees_mean": float(np.nanmean([c["metrics"]["nees_mean"] for c in tracked]))
        if tracked else math.nan,
        "tracking_nees_per_run": {c["name"]: c["metrics_mod_sym"]["nees_mean"] for c in tracked},
        "global_success_rate_8_blocks": float(np.mean([b is not None and b <= 8
                                                       for b in conv])) if conv else math.nan,
        "global_blocks_to_converge": conv,
        "update_ms_median": float(1e3 * np.median(times)),
        "update_ms_p95": float(1e3 * np.percentile(times, 95)),
        "update_cpu_ms_median": float(1e3 * np.median(cpu)),
        "update_cpu_ms_p95": float(1e3 * np.percentile(cpu, 95)),
    }


def kernel_baseline(tables: SensorTables, hm: HeatMap, n: int = 2000, reps: int = 30
                    ) -> dict[str, float]:
    """Sensor scoring of ``n`` poses: numba kernel vs its numpy twin, same process."""
    from localization.sensor import prepare_measurement, score_poses
    from tests.localization.sensor.naive import score_poses_numpy

    rng = np.random.default_rng(0)
    iy, ix = np.nonzero(tables.free_mask)
    pick = rng.integers(0, iy.size, n)
    poses = np.column_stack([tables.origin_m[0] + ix[pick] * tables.resolution_m,
                             tables.origin_m[1] + iy[pick] * tables.resolution_m,
                             rng.uniform(-np.pi, np.pi, n)])
    m = prepare_measurement(hm, tables.config)
    out = {}
    for name, fn in (("numba", score_poses), ("numpy_twin", score_poses_numpy)):
        fn(tables, m, poses)
        wall, cpu = [], []
        for _ in range(reps):
            t0, c0 = time.perf_counter(), time.process_time()
            fn(tables, m, poses)
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        out[f"{name}_ms_median"] = float(1e3 * np.median(wall))
        out[f"{name}_cpu_ms_median"] = float(1e3 * np.median(cpu))
    out["speedup_numba_vs_numpy"] = out["numpy_twin_ms_median"] / out["numba_ms_median"]
    out["particles"] = n
    return out


def warm_up(tables: SensorTables, run: Run, hms: list[HeatMap]) -> None:
    pf = ParticleFilter(tables, FilterConfig(n_particles=200), np.random.default_rng(0))
    track(pf, run, hms, n_blocks=3)


def beta_calibration(data: dict[str, tuple[WallMap, dict[str, Run], dict[str, list[HeatMap]]]],
                     betas: tuple[float, ...] = (25.0, 50.0, 100.0, 200.0, 400.0)
                     ) -> list[dict[str, Any]]:
    """``calibrate_beta`` per scene on its held-out curve run (the straight runs keep a mirror
    ambiguity, so raw truth would count them lost), 1000 particles, 2 filter seeds."""
    rows = []
    for s, (wall_map, runs, hms) in data.items():
        run = runs["curve"]
        cal_run = CalibrationRun(tuple(hms["curve"]), run.speed_m_s, run.yaw_rate_rad_s,
                                 run.t_s, run.config.block_s, run.pose)
        tables = build_tables(wall_map, SensorConfig())
        try:
            cal = calibrate_beta(tables, [cal_run], betas, FilterConfig(n_particles=1000),
                                 np.random.default_rng(0), n_seeds=2)
            row = {"scene": s, **dataclasses.asdict(cal)}
        except ValueError as err:          # every candidate lost a run
            row = {"scene": s, "beta": None, "error": str(err)}
        rows.append(row)
        print(json.dumps(row, default=float), flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["l-room", "pillar"])
    ap.add_argument("--seeds", type=int, default=2, help="global-init seeds per run")
    ap.add_argument("--calibrate-only", action="store_true",
                    help="only the beta calibration -> results/localization_calibration.json")
    args = ap.parse_args()
    t_start = time.perf_counter()
    data = {}
    for scene in args.scenes:
        wall_map, runs = scene_data(scene)
        hms = {k: run_blocks(r) for k, r in runs.items()}
        data[scene] = (wall_map, runs, hms)
    if args.calibrate_only:
        RESULTS.mkdir(parents=True, exist_ok=True)
        out = {"scenes": args.scenes, "particles": 1000, "calibration": beta_calibration(data),
               "runtime_s": time.perf_counter() - t_start}
        (RESULTS / "localization_calibration.json").write_text(
            json.dumps(out, indent=2, default=float))
        return 0
    results: dict[str, Any] = {"scenes": args.scenes, "seeds": args.seeds,
                               "particles": list(PARTICLES), "configs": [], "beta_sweep": [],
                               "load_average_start": os.getloadavg()}
    corr_tables: dict[str, SensorTables] = {}
    for model in MODELS:
        tables = {s: build_tables(d[0], SensorConfig(model=model)) for s, d in data.items()}
        if model == "correlation":
            corr_tables = tables
        first = args.scenes[0]
        warm_up(tables[first], data[first][1]["curve"], data[first][2]["curve"])
        for n in (*PARTICLES, 2000):
            tracked, global_ = [], []
            for s, (_, runs, hms) in data.items():
                for name, run in runs.items():
                    tracked.append(pf_case(tables[s], n, run, hms[name], 0, True, s))
                    if name == "curve" and n != 2000:
                        seeds = args.seeds if n <= 3000 else 1     # keep the runtime modest
                        global_ += [pf_case(tables[s], n, run, hms[name], 1 + seed, False,
                                            s) for seed in range(seeds)]
            row = {"filter": "pf", "model": model, "particles": n,
                   **summarize_cases(tracked, global_)}
            results["configs"].append(row)
            print(json.dumps(row), flush=True)
        grid = [track(GridFilter(tables[s]), d[1]["curve"], d[2]["curve"], GRID_BLOCKS, s)
                for s, d in data.items()]
        row = {"filter": "grid", "model": model, "particles": None,
               **summarize_cases([], grid)}
        row["grid_blocks"] = GRID_BLOCKS
        row["grid_rmse_after_convergence_m"] = [g["metrics"]["position_rmse_m"] for g in grid]
        results["configs"].append(row)
        print(json.dumps(row), flush=True)
    for beta in (25.0, 50.0, 100.0, 200.0, 400.0):
        cases = []
        for s, (_, runs, hms) in data.items():
            tab = corr_tables[s]
            tab = dataclasses.replace(tab, config=dataclasses.replace(tab.config, beta=beta))
            cases += [pf_case(tab, 1000, run, hms[name], 0, True, s)
                      for name, run in runs.items()]
        row = {"beta": beta, **summarize_cases(cases, [])}
        results["beta_sweep"].append(row)
        print(json.dumps(row), flush=True)
    results["beta_calibration"] = beta_calibration(data)
    results["kernel_baseline"] = kernel_baseline(corr_tables[args.scenes[0]],
                                                 data[args.scenes[0]][2]["curve"][5])
    print(json.dumps(results["kernel_baseline"]), flush=True)
    results["load_average_end"] = os.getloadavg()
    results["runtime_s"] = time.perf_counter() - t_start
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "localization.json").write_text(json.dumps(results, indent=2, default=float))
    plot(results, RESULTS / "localization_pareto.png")
    print(f"wrote {RESULTS / 'localization.json'} and localization_pareto.png "
          f"({results['runtime_s']:.0f} s)")
    return 0


def plot(results: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(17, 4.8))
    colors = {"correlation": "tab:blue", "range": "tab:orange"}
    for model in MODELS:
        rows = [r for r in results["configs"] if r["model"] == model and r["filter"] == "pf"
                and r["particles"] in PARTICLES]
        t = [r["update_ms_median"] for r in rows]
        axes[0].plot(t, [100 * r["tracking_position_rmse_m"] for r in rows], "o-",
                     color=colors[model], label=f"pf, {model}")
        axes[1].plot(t, [r["global_success_rate_8_blocks"] for r in rows], "o-",
                     color=colors[model], label=f"pf, {model}")
        axes[1].plot(t, [r["global_success_rate_8_blocks_mod_sym"] for r in rows], "o--",
                     color=colors[model], alpha=0.5, label=f"pf, {model}, modulo symmetry")
        for r, x in zip(rows, t, strict=True):
            lost = r["tracking_lost_runs"]
            axes[0].annotate(f"{r['particles']}" + (f" ({lost} lost)" if lost else ""),
                             (x, 100 * r["tracking_position_rmse_m"]), fontsize=7,
                             xytext=(3, 3), textcoords="offset points")
        for r in results["configs"]:
            if r["filter"] == "grid" and r["model"] == model:
                axes[1].plot([r["update_ms_median"]], [r["global_success_rate_8_blocks"]], "s",
                             color=colors[model], ms=9, label=f"grid, {model}")
    axes[0].axhline(3.0, color="grey", ls="--", lw=0.8, label="goal 3 cm")
    axes[0].set(xscale="log", xlabel="median time per update (ms)",
                ylabel="position RMSE (cm), runs that stayed within 10 cm",
                title="tracking (tracked start; 'lost': left 10 cm / 10 deg at some block)")
    axes[1].axvline(10.0, color="grey", ls=":", lw=0.8)
    axes[1].set(xscale="log", xlabel="median time per update (ms)", ylim=(-0.05, 1.05),
                ylabel="share converged within 8 blocks",
                title="global localization (curve runs)")
    sweep = results["beta_sweep"]
    names = sorted({k for r in sweep for k in r["tracking_nees_per_run"]})
    for name in names:
        axes[2].plot([r["beta"] for r in sweep],
                     [r["tracking_nees_per_run"].get(name, math.nan) for r in sweep], "o-",
                     label=name)
    axes[2].axhline(3.0, color="grey", ls="--", lw=0.8, label="honest (3 dof)")
    axes[2].axvline(200.0, color="k", ls=":", lw=0.8, label="default beta")
    betas = [r["beta"] for r in sweep]
    axes[2].set_xscale("log")
    axes[2].set_xticks(betas, [f"{b:g}" for b in betas])
    axes[2].minorticks_off()
    axes[2].set(yscale="log", xlabel="sensor sharpness beta",
                ylabel="mean NEES of the best mode (tracked, mod symmetry)",
                title="covariance honesty, 1000 particles")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"localization on simulated held-out runs ({', '.join(results['scenes'])})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    raise SystemExit(main())
