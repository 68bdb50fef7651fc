"""The shape of the pose posterior (issue 8): width against M, path, speed, scene symmetry,
and whether the particle filter's covariance is honest.

Blocks are simulated with the image-source engine (``mapping.simulate``), heat maps come from
``mapping.heatmap`` (paper eq. 1) and the likelihood is issue 6's sensor model
(``localization.sensor``, beta * rho, unfloored) against an *ideal* wall map (the scene's
walls rasterized, 50 mm) so that the study measures the sensor, not the map builder.
Posteriors are sampled by ``localization.posterior`` (grid modes + one emcee ensemble each).

With ``--model echo`` (the default since issue 14) the likelihood is the echo model on the
scene's true walls; ``--model correlation`` is issue 8's G model on the rasterized walls.

Writes ``benchmarks/results/posterior_study.json`` and ``posterior_study.png`` (+ a corner
plot of the symmetric-room case; ``posterior_study_correlation.*`` for the G model).
Runtime: a few minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import matplotlib

from mapping.angles import pose_difference, wrap_angle

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from localization import posterior as post
from localization.estimate import nees
from localization.particle_filter import FilterConfig, ParticleFilter
from localization.sensor import SensorConfig, SensorTables, build_tables, heatmap_run
from mapping.heatmap import heatmap_of_run
from mapping.path import curve_path, polyline_path, stationary_path
from mapping.run import Run
from mapping.scene import builtin_scene
from mapping.signal import SonarConfig
from mapping.simulate import simulate_run
from mapping.simulate.ism import IsmConfig
from mapping.wallmap import WallMap, wallmap_from_walls
from service.posterior_plot import write_corner_png

OUT = Path(__file__).resolve().parent / "results"
OUT_NAME = "posterior_study"
ISM = IsmConfig(max_path_m=12.0)
SETTINGS = post.PosteriorSettings(n_walkers=16, n_steps=300, max_steps=1500, grid_step_m=0.05,
                                  grid_heading_step_rad=math.radians(10), local_grid_cells=15,
                                  min_mode_mass=0.05)
GLOBAL = post.PosteriorSettings(n_walkers=16, n_steps=300, max_steps=1500, grid_step_m=0.1,
                                grid_heading_step_rad=math.radians(15), local_grid_cells=15,
                                min_mode_mass=0.05)
A = (2.0, 2.0)          # the paper's point (a)
HEADING = math.pi / 4   # paper path A


def rasterize(segments: np.ndarray, resolution_m: float = 0.05, margin_m: float = 0.5,
              width_cells: float = 0.7) -> WallMap:
    """Ideal wall map: a Gaussian ridge along every wall segment."""
    lo = segments.reshape(-1, 2).min(axis=0) - margin_m
    hi = segments.reshape(-1, 2).max(axis=0) + margin_m
    nx, ny = (np.ceil((hi - lo) / resolution_m).astype(int) + 1)
    px, py = np.meshgrid(lo[0] + resolution_m * np.arange(nx), lo[1] + resolution_m * np.arange(ny))
    d = np.full(px.shape, np.inf)
    for a, b in segments:
        ab = b - a
        t = np.clip(((px - a[0]) * ab[0] + (py - a[1]) * ab[1]) / (ab @ ab), 0, 1)
        d = np.minimum(d, np.hypot(px - a[0] - t * ab[0], py - a[1] - t * ab[1]))
    return WallMap(G=np.exp(-0.5 * (d / (width_cells * resolution_m)) ** 2),
                   origin_m=(float(lo[0]), float(lo[1])), resolution_m=resolution_m)


#: Sensor model of the study: "echo" (the product's default on a map with walls: the scene's
#: true walls, ``wallmap_from_walls``) or "correlation" (issue 8's G model on the rasterized
#: walls); ``--model`` picks it, the results carry it.
MODEL = "echo"


def scene_tables(name: str, model: str = MODEL) -> tuple[Any, SensorTables]:
    scene = builtin_scene(name)
    seg = np.array([[w.start, w.end] for w in scene.walls], dtype=float)
    if model == "echo":
        return scene, build_tables(wallmap_from_walls(seg.reshape(-1, 4)),
                                   SensorConfig(model="echo"))
    return scene, build_tables(rasterize(seg), SensorConfig())


def straight_from(xy: tuple[float, float], heading: float, length_m: float = 1.0) -> Any:
    """A straight path whose first block midpoint is near ``xy`` (starts 5 cm before it)."""
    u = np.array([math.cos(heading), math.sin(heading)])
    p0 = np.asarray(xy) - 0.05 * u
    return polyline_path([tuple(p0), tuple(p0 + length_m * u)], speed_m_s=0.1, name="straight")


def local_prior(truth: np.ndarray, half_m: float = 0.6) -> post.PosePrior:
    return post.PosePrior(truth[0] - half_m, truth[0] + half_m, truth[1] - half_m,
                          truth[1] + half_m)


def summary(res: post.PosteriorResult, truth: np.ndarray, seconds: float) -> dict[str, Any]:
    """Numbers of one posterior: modes, widths, chain health, error of the best mode."""
    best = res.modes[0]
    err = pose_difference(best.mean, truth)
    # the mode in the strict sense: the highest-posterior sample of the heaviest mode (its
    # mean, above, sits off the peak when the posterior is wide and skewed)
    own = np.flatnonzero(res.mode_index == 0)
    peak = res.samples[own[np.argmax(res.log_prob[own])]]
    peak_err = pose_difference(peak, truth)
    return {
        "n_modes": len(res.modes),
        "mode_mass": [round(m.mass, 4) for m in res.modes],
        "mode_mean": [np.round(m.mean, 4).tolist() for m in res.modes],
        "sd_x_cm": 100 * math.sqrt(best.cov[0, 0]), "sd_y_cm": 100 * math.sqrt(best.cov[1, 1]),
        "sd_pos_cm": 100 * math.sqrt(0.5 * (best.cov[0, 0] + best.cov[1, 1])),
        "heading_circ_std_deg": math.degrees(best.heading_circular_std_rad),
        "hpd95_volume_cm2_deg": res.hpd_volume[1] * 1e4 * math.degrees(1.0),
        "error_cm": 100 * float(np.hypot(err[0], err[1])),
        "error_deg": math.degrees(float(err[2])),
        "peak": np.round(peak, 4).tolist(),
        "peak_error_cm": 100 * float(np.hypot(peak_err[0], peak_err[1])),
        "peak_error_deg": math.degrees(float(peak_err[2])),
        "tau_max": [round(float(np.max(m.tau)), 1) for m in res.modes],
        "acceptance": [round(m.acceptance_fraction, 3) for m in res.modes],
        "steps": [m.n_steps for m in res.modes],
        "converged": [m.converged for m in res.modes],
        "hellinger": [round(m.comparison.hellinger, 3) for m in res.modes],
        "hellinger_iid": [round(m.comparison.hellinger_iid, 3) for m in res.modes],
        "coverage68": [round(m.comparison.coverage68, 3) for m in res.modes],
        "coverage95": [round(m.comparison.coverage95, 3) for m in res.modes],
        "seconds": round(seconds, 1),
    }


def sample(run: Run, tables: SensorTables, k: int, prior: post.PosePrior | None,
           settings: post.PosteriorSettings, seed: int) -> tuple[post.PosteriorResult,
                                                                 np.ndarray, float]:
    """Posterior of blocks 0..k-1 parametrized by the last block's pose."""
    ll, truth = post.window_from_run(run, 0, k, tables, anchor=k - 1)
    pr = local_prior(truth) if prior is None else prior
    t0 = time.perf_counter()
    res = post.sample_posterior(ll, pr, np.random.default_rng(seed), settings)
    return res, truth, time.perf_counter() - t0


def pf_calibration(run: Run, tables: SensorTables, res: post.PosteriorResult,
                   truth: np.ndarray, seed: int) -> dict[str, Any]:
    """Tracked particle filter over the same blocks; its final cloud against the posterior."""
    pf = ParticleFilter(tables, FilterConfig(n_particles=2000), np.random.default_rng(seed),
                        pose=run.pose[0], cov=np.diag([0.1**2, 0.1**2, math.radians(10) ** 2]))
    heard = heatmap_run(run, tables.config)     # the bank the sensor model reads
    for k in range(run.n_blocks):
        est = pf.step(heatmap_of_run(heard, k), float(run.speed_m_s[k]),
                      float(run.yaw_rate_rad_s[k]), 0.0 if k == 0 else run.config.block_s)
    cal = post.compare_cloud(res, pf.poses, np.exp(pf.log_w - pf.log_w.max()), truth)
    return {"pf_mean": np.round(est.pose, 4).tolist(),
            "pf_sd": np.round(np.sqrt(np.diag(cal.cloud_cov)), 4).tolist(),
            "posterior_sd": np.round(np.sqrt(np.diag(res.modes[cal.mode].cov)), 4).tolist(),
            "covariance_ratio_eigs": np.round(cal.covariance_ratio, 3).tolist(),
            "nees_truth_pf": cal.nees_truth, "nees_truth_posterior": cal.nees_truth_posterior,
            "kl_posterior_to_pf": cal.kl_posterior_to_cloud,
            # what the filter reports: the refined Gaussian of its converged mode
            # (localization.refine), its own noise measured from the residuals
            "reported_refined": bool(est.refined),
            "reported_sd": np.round(np.sqrt(np.diag(est.cov)), 5).tolist(),
            "nees_truth_reported": nees(est.pose, est.cov, truth)}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.posterior_study")
    ap.add_argument("--model", choices=("echo", "correlation"), default=MODEL,
                    help="sensor model (default %(default)s); correlation writes "
                         "posterior_study_correlation.*")
    model = ap.parse_args(argv).model
    global OUT_NAME
    OUT_NAME = "posterior_study" if model == "echo" else "posterior_study_correlation"
    t_start = time.perf_counter()
    out: dict[str, Any] = {
        "settings": {"local": SETTINGS.__dict__, "global": GLOBAL.__dict__}, "model": model,
        "map": ("ideal (the scene's walls, wallmap_from_walls)" if model == "echo"
                else "ideal (rasterized scene walls, 50 mm)"),
        "sensor": "echo model, rho = 1 + ll / 200, beta 200" if model == "echo"
        else "beta*rho"}
    scene, tables = scene_tables("paper", model)
    rng = np.random.default_rng(0)
    # 1. width against M: one block at point (a), heading pi/4
    sweep = {}
    for m in (4, 6, 8, 10):
        cfg = SonarConfig(repetitions=m)
        run = simulate_run(scene, straight_from(A, HEADING), cfg, 1, ISM, rng)
        res, truth, sec = sample(run, tables, 1, None, SETTINGS, m)
        sweep[m] = summary(res, truth, sec)
        print(f"M={m}: {sweep[m]}", flush=True)
        if m == 10:
            moving = sweep[m]
    out["width_vs_M"] = sweep
    # 2. moving vs stationary (one block, M = 10)
    run = simulate_run(scene, stationary_path(A, HEADING, 3.0), SonarConfig(), 1, ISM, rng)
    res, truth, sec = sample(run, tables, 1, None, SETTINGS, 20)
    out["moving_vs_stationary"] = {"moving": moving, "stationary": summary(res, truth, sec)}
    print("stationary:", out["moving_vs_stationary"]["stationary"], flush=True)
    # 3. straight vs curved (three blocks, M = 10) + 5. particle filter calibration
    paths = {"straight": straight_from((1.9, 1.9), HEADING),
             "curved": curve_path([(1.85, 1.85), (2.1, 1.9), (2.3, 2.1), (2.35, 2.4)],
                                  speed_m_s=0.1, name="curved")}
    out["straight_vs_curved"], out["pf_calibration"] = {}, {}
    for name, path in paths.items():
        run = simulate_run(scene, path, SonarConfig(), 3, ISM, rng)
        res, truth, sec = sample(run, tables, 3, None, SETTINGS, 30)
        out["straight_vs_curved"][name] = summary(res, truth, sec)
        out["straight_vs_curved"][name]["turn_deg"] = math.degrees(
            float(wrap_angle(run.pose[-1, 2] - run.pose[0, 2])))
        out["pf_calibration"][name] = pf_calibration(run, tables, res, truth, 40)
        print(name, out["straight_vs_curved"][name], out["pf_calibration"][name], flush=True)
        if name == "straight":
            asym_run = run
    # 4. asymmetric vs symmetric scene: whole-map prior, three straight blocks
    sym_scene, sym_tables = scene_tables("l-room", model)
    sym_run = simulate_run(sym_scene, straight_from((1.35, 0.9), 0.0), SonarConfig(), 3, ISM,
                           rng)
    out["symmetry"] = {}
    for name, run, tab in (("asymmetric (paper)", asym_run, tables),
                           ("symmetric (l-room)", sym_run, sym_tables)):
        res, truth, sec = sample(run, tab, 3, post.prior_from_tables(tab), GLOBAL, 50)
        s = summary(res, truth, sec)
        s["truth_mode_mass"] = float(sum(m.mass for m in res.modes
                                         if np.linalg.norm(pose_difference(m.mean, truth)[:2])
                                         < 0.15))
        out["symmetry"][name] = s
        print(name, s, flush=True)
        if "l-room" in name:
            write_corner_png(OUT / f"{OUT_NAME}_corner.png", res, truth,
                             "L-room, 3 straight blocks, whole-map prior")
    out["total_seconds"] = round(time.perf_counter() - t_start, 1)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / f"{OUT_NAME}.json").write_text(json.dumps(out, indent=1, default=float))
    plot(out)
    print(f"wrote {OUT / (OUT_NAME + '.json')} in {out['total_seconds']} s")


def plot(out: dict[str, Any]) -> None:
    fig, ax = plt.subplots(1, 3, figsize=(14, 4))
    ms = sorted(out["width_vs_M"])
    ax[0].plot(ms, [out["width_vs_M"][m]["sd_pos_cm"] for m in ms], "o-", label="position sd (cm)")
    ax[0].plot(ms, [out["width_vs_M"][m]["heading_circ_std_deg"] for m in ms], "s-",
               label="heading circular sd (deg)")
    ax[0].set_xlabel("M (repetitions per block)")
    ax[0].set_title("one block at point (a)")
    ax[0].legend()
    cases = {"moving 1 blk": out["moving_vs_stationary"]["moving"],
             "stationary 1 blk": out["moving_vs_stationary"]["stationary"],
             "straight 3 blk": out["straight_vs_curved"]["straight"],
             "curved 3 blk": out["straight_vs_curved"]["curved"]}
    x = np.arange(len(cases))
    ax[1].bar(x - 0.2, [c["sd_pos_cm"] for c in cases.values()], 0.4, label="position sd (cm)")
    ax[1].bar(x + 0.2, [c["heading_circ_std_deg"] for c in cases.values()], 0.4,
              label="heading sd (deg)")
    ax[1].set_xticks(x, list(cases), rotation=15)
    ax[1].set_yscale("log")
    ax[1].legend()
    ax[1].set_title("posterior width (best mode)")
    sym = out["symmetry"]
    for i, s in enumerate(sym.values()):
        ax[2].bar(i + 0.4 * np.arange(len(s["mode_mass"])) / max(1, len(s["mode_mass"])),
                  s["mode_mass"], 0.35 / max(1, len(s["mode_mass"])))
    ax[2].set_xticks(range(len(sym)), list(sym))
    ax[2].set_ylabel("mode masses (whole-map prior)")
    ax[2].set_title("scene symmetry: modes of 3 straight blocks")
    fig.tight_layout()
    fig.savefig(OUT / f"{OUT_NAME}.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
