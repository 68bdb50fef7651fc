"""``omnisonar`` subcommands for localization: localize (paper Fig. 1(b)) and posterior.

``localize`` runs the particle or grid filter over a run on a wall map; ``posterior`` samples
the pose posterior of a block window with emcee (issue 8). Edges over :mod:`localization`;
no computation here.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mapping.files import atomic_savez, atomic_write
from service.jsonout import strict_json

if TYPE_CHECKING:
    from localization.calibration import BetaCalibration
    from localization.estimate import PoseEstimate


# ---- localize (issue 6) ---------------------------------------------------------------
def add_localize(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("localize", help="localize a run on a wall map (paper Fig. 1(b))")
    p.add_argument("run", metavar="RUN.npz", help="run file to localize")
    p.add_argument("--map", required=True, metavar="MAP.npz",
                   help="map file (omnisonar-map-2; omnisonar-map-1 is read too)")
    p.add_argument("--filter", choices=("pf", "grid"), default="pf",
                   help="pf: particle filter; grid: exact grid filter")
    p.add_argument("--particles", type=int, default=2000, help="particle count (pf)")
    p.add_argument("--init", choices=("global", "tracked"), default="global",
                   help="global: uniform over the free space; tracked: the run's first tracked "
                        "pose (10 cm / 10 deg)")
    p.add_argument("--model", choices=("auto", "echo", "correlation", "range"), default="auto",
                   help="sensor model: echo (physical, needs a map with walls), correlation or "
                   "range (against G, the baseline); auto = echo when the map has walls")
    p.add_argument("--seed", type=int, default=0, help="random seed (pf)")
    p.add_argument("--open-map", choices=("uncertain", "confirm"), default="uncertain",
                   help="a global start (or a filter that lost its track and found a place "
                   "again) on a map built from runs with an open wall end (free space the "
                   "map knows nothing of): never reported converged "
                   "('uncertain'), or as on a closed map ('confirm': the robot is known to "
                   "be in the mapped part)")
    p.add_argument("--beta", type=float, default=None,
                   help="sensor sharpness (default 200; `omnisonar calibrate` picks one per map)")
    p.add_argument("--sonar-height", type=float, metavar="M",
                   help="sonar height above the floor: the echo model also predicts the "
                   "floor / ceiling copies of every wall echo (default: the height the run was "
                   "imported with, `import-run --raw --sonar-height`, else none)")
    p.add_argument("--ceiling-height", type=float, metavar="M",
                   help="ceiling height (with the sonar height; default as --sonar-height)")
    p.add_argument("--out", metavar="TRACK.csv",
                   help="write the track as CSV: pose, full covariance, status per block")
    p.add_argument("--json", action="store_true", help="print a JSON summary instead of a table")
    p.set_defaults(func=_cmd_localize)


def _cmd_localize(args: argparse.Namespace) -> int:
    import dataclasses

    from localization.estimate import default_start_cov, track_metrics
    from localization.grid_filter import GridFilter
    from localization.particle_filter import FilterConfig, ParticleFilter, Steppable, run_filter
    from localization.sensor import (
        SensorConfig,
        build_tables,
        heatmap_run,
        resolve_model,
        validate_block,
    )
    from mapping.angles import pose_error
    from mapping.files import read_map, read_run
    from mapping.heatmap import heatmap_of_run

    if args.particles < 1:
        raise ValueError(f"--particles must be >= 1, got {args.particles}")
    wall_map, run = read_map(args.map), read_run(args.run)
    sensor = SensorConfig(model=resolve_model(wall_map, args.model))
    if args.beta is not None:
        sensor = dataclasses.replace(sensor, beta=args.beta)   # validated by SensorConfig
    imported = run.meta.get("raw_import_options", {})
    h = args.sonar_height if args.sonar_height is not None else imported.get("sonar_height_m")
    top = (args.ceiling_height if args.ceiling_height is not None
           else imported.get("ceiling_height_m"))
    if h is not None or top is not None:
        sensor = dataclasses.replace(sensor, sonar_height_m=h, ceiling_height_m=top)
    tables = build_tables(wall_map, sensor, sonar=run.config)
    tracked = np.asarray(np.isfinite(run.pose).all(axis=1), dtype=bool)
    if args.init == "tracked" and not tracked[0]:
        raise ValueError("--init tracked needs a tracked pose in the run's first block")
    pose0 = run.pose[0] if args.init == "tracked" else None
    cov0 = default_start_cov()
    filt: Steppable
    if args.filter == "grid":
        filt = GridFilter(tables, pose=pose0, cov=cov0)
    else:
        filt = ParticleFilter(tables, FilterConfig(n_particles=args.particles,
                                                   open_map_global=args.open_map),
                              np.random.default_rng(args.seed), pose=pose0, cov=cov0)

    heard = heatmap_run(run, tables.config)   # the echo model reads a denser bank

    def heat_maps():  # type: ignore[no-untyped-def]
        for k in range(run.n_blocks):
            try:
                validate_block(run.samples[k], run.config.block_samples)
            except ValueError as exc:
                print(f"block {k}: {exc}; predicting only", file=sys.stderr)
                yield None
                continue
            yield heatmap_of_run(heard, k)

    rows, poses, covs = [], [], []
    if not args.json:
        print("block      x_m      y_m  yaw_deg  sx_m  sy_m syaw_deg    ess conv modes"
              "  err_m err_deg")
    for k, est in enumerate(run_filter(filt, heat_maps(), run.speed_m_s, run.yaw_rate_rad_s,
                                       run.t_s, run.config.block_s)):
        sd = np.sqrt(np.clip(np.diag(est.cov), 0.0, None))
        err = pose_error(est.pose, run.pose[k]) if tracked[k] else (math.nan, math.nan)
        rows.append(_track_row(k, est, err))
        poses.append(est.pose)
        covs.append(est.cov)
        if not args.json:
            print(f"{k:5d} {est.pose[0]:8.3f} {est.pose[1]:8.3f} {math.degrees(est.pose[2]):8.1f}"
                  f" {sd[0]:5.3f} {sd[1]:5.3f} {math.degrees(sd[2]):8.1f} {est.ess:6.0f}"
                  f" {int(est.converged):4d} {len(est.modes):5d} {err[0]:6.3f}"
                  f" {math.degrees(err[1]):7.1f}")
    summary: dict[str, Any] = {"run": args.run, "map": args.map, "filter": args.filter,
                                  "init": args.init, "model": sensor.model,
                                  "n_blocks": run.n_blocks}
    if tracked.any():
        m = track_metrics(np.array(poses), np.array(covs), run.pose)
        summary.update(dataclasses.asdict(m))
        summary["heading_rmse_deg"] = math.degrees(m.heading_rmse_rad)
        summary["heading_rmse_all_deg"] = math.degrees(m.heading_rmse_all_rad)
    if args.out:
        atomic_write(Path(args.out), lambda fh: fh.write(_track_csv(rows).encode()),
                     private=False)
    if args.json:
        print(strict_json(summary, indent=2))
    elif tracked.any():
        print(_metrics_text(summary))
    if args.out:
        print(f"wrote {args.out}", file=sys.stderr if args.json else sys.stdout)
    return 0


TRACK_CSV_COLUMNS = (
    "block", "x_m", "y_m", "yaw_rad", "std_x_m", "std_y_m", "std_yaw_rad", "ess", "converged",
    "n_modes", "direction_observable", "err_m", "err_rad",
    "cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw", "status", "refined",
    "reckoned", "reason",
)
"""Columns of the ``localize --out`` track CSV (documented in docs/formats.md)."""


def _track_row(k: int, est: PoseEstimate, err: tuple[float, float]) -> list[Any]:
    """One row of the track CSV (:data:`TRACK_CSV_COLUMNS`): the best mode's pose, standard
    deviations and upper-triangle covariance, the filter's flags, the error and the status."""
    from localization.estimate import track_status

    sd = np.sqrt(np.clip(np.diag(est.cov), 0.0, None))
    upper = est.cov[np.triu_indices(3)]          # xx, xy, xyaw, yy, yyaw, yawyaw
    return [k, *est.pose, *sd, est.ess, int(est.converged), len(est.modes),
            int(est.direction_observable), *err, *upper, track_status(est), int(est.refined),
            int(est.reckoned), est.reason]


def _track_csv(rows: list[list[Any]]) -> str:
    """The track CSV text: a header of :data:`TRACK_CSV_COLUMNS`, floats as ``%.6g``."""
    lines = [",".join(TRACK_CSV_COLUMNS)]
    for row in rows:
        lines.append(",".join(v if isinstance(v, str) else str(v) if isinstance(v, int)
                              else f"{float(v):.6g}" for v in row))
    return "\n".join(lines) + "\n"


def _metrics_text(summary: dict[str, Any]) -> str:
    """The closing line of ``localize`` on a tracked run: RMSE after convergence (when it
    converged) and over all blocks, and the share within 10 cm."""
    def cm_deg(position_m: float, heading_deg: float) -> str:
        return f"position RMSE {position_m * 100:.1f} cm, heading RMSE {heading_deg:.1f} deg"

    if summary["blocks_to_converge"] is None:
        after = "never converged (no block from which the error stays within 10 cm / 10 deg)"
    else:
        after = (f"blocks to converge: {summary['blocks_to_converge']}; after convergence "
                 + cm_deg(summary["position_rmse_m"], summary["heading_rmse_deg"]))
    return (f"{after}; over all blocks "
            f"{cm_deg(summary['position_rmse_all_m'], summary['heading_rmse_all_deg'])}; "
            f"within 10 cm: {summary['share_within_tol'] * 100:.0f} % of blocks")


# ---- calibrate (issue 6: the sensor sharpness that makes the covariance honest) -----------
def add_calibrate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate",
                       help="pick the sensor sharpness beta of a map by NEES on tracked runs")
    p.add_argument("runs", nargs="+", metavar="RUN.npz",
                   help="tracked runs on the map (held out from its mapping runs)")
    p.add_argument("--map", required=True, metavar="MAP.npz",
                   help="map file (omnisonar-map-2; omnisonar-map-1 is read too)")
    p.add_argument("--betas", default="50,100,200,400",
                   help="comma-separated candidates")
    p.add_argument("--particles", type=int, default=1000, help="particle count per filter run")
    p.add_argument("--seeds", type=int, default=2, help="filter runs per run and candidate")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--widen", type=int, default=4, metavar="N",
                   help="when no candidate brackets mean NEES 3, try up to N more beyond the "
                        "ends, doubling the largest or halving the smallest; 0: off")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(func=_cmd_calibrate)


def _calibration_warning(cal: BetaCalibration, max_widen: int,
                         target_nees: float = 3.0) -> str | None:
    """The stderr warning of ``calibrate`` when the given candidates did not bracket the
    target NEES (what was tried, whether widening found a crossing), else None."""
    if cal.bracketed and not cal.widened:
        return None

    def entry(b: float) -> str:
        i = cal.betas.index(b)
        lost = f" ({cal.lost_runs[i]} lost)" if cal.lost_runs[i] else ""
        return f"{b:g}: {cal.nees_mean[i]:.2f}{lost}"

    table = ", ".join(entry(b) for b in cal.betas if b not in cal.widened)
    text = (f"warning: no candidate beta brackets the target mean NEES {target_nees:g} "
            f"(mean NEES per beta {table})")
    if cal.widened:
        text += f"; widened the search, tried beta {', '.join(map(entry, cal.widened))}"
    if cal.bracketed:
        return text + f"; the crossing lies at beta {cal.beta:.1f}"
    if len(cal.widened) >= max_widen:
        why = ("--widen 0 turns widening off" if max_widen == 0
               else f"stopped at the cap of {max_widen} (--widen)")
    else:
        why = ("cannot widen further: the end candidate lost a run, or NEES crosses "
               f"{target_nees:g} only downward")
    return (text + f"; {why}. Picked the nearest, beta = {cal.beta:.1f}: its covariance is "
            "not honest; try other --betas or more runs")


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from localization.calibration import CalibrationRun, calibrate_beta
    from localization.particle_filter import FilterConfig
    from localization.sensor import SensorConfig, build_tables
    from mapping.files import read_map, read_run

    try:
        betas = [float(b) for b in args.betas.split(",") if b.strip()]
    except ValueError:
        raise ValueError(f"--betas must be comma-separated numbers, got {args.betas!r}") from None
    config = FilterConfig(n_particles=args.particles)          # validates --particles
    tables = build_tables(read_map(args.map), SensorConfig())
    runs = []
    for path in args.runs:
        try:
            runs.append(CalibrationRun.from_run(read_run(path), tables.config))
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None
    if args.widen < 0:
        raise ValueError(f"--widen must be >= 0, got {args.widen}")
    cal = calibrate_beta(tables, runs, betas, config, np.random.default_rng(args.seed),
                         n_seeds=args.seeds, max_widen=args.widen)
    warning = _calibration_warning(cal, args.widen)
    if warning is not None:
        print(warning, file=sys.stderr)
    if args.json:
        print(strict_json({"beta": cal.beta, "betas": list(cal.betas),
                           "nees_mean": list(cal.nees_mean), "lost_runs": list(cal.lost_runs),
                           "bracketed": cal.bracketed, "widened": list(cal.widened)}))
        return 0
    print("   beta  mean NEES  lost runs")
    for b, q, lost in zip(cal.betas, cal.nees_mean, cal.lost_runs, strict=True):
        print(f"{b:7.1f}  {q:9.2f}  {lost:9d}")
    how = ("mean NEES 3 = honest covariance" if cal.bracketed
           else "the nearest candidate: no crossing of mean NEES 3, see the warning")
    print(f"beta = {cal.beta:.1f} ({how}); use it with "
          f"`omnisonar localize --beta {cal.beta:.0f}`")
    return 0


# ---- posterior (issue 8: offline emcee study of the pose posterior) -----------------------
def add_posterior(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("posterior", help="sample the pose posterior of a block window (emcee)")
    p.add_argument("run", help="run file (.npz)")
    p.add_argument("--map", required=True, help="wall map file (.npz)")
    p.add_argument("--blocks", required=True, help="A:B, blocks A..B-1 tied by odometry")
    p.add_argument("--walkers", type=int, default=32, help="walkers per mode (>= 6)")
    p.add_argument("--steps", type=int, default=1000, help="first batch of steps per mode")
    p.add_argument("--max-steps", type=int, default=20000, help="cap while reaching 50 tau")
    p.add_argument("--model", choices=("auto", "echo", "correlation", "range"), default="auto",
                   help="sensor model: echo (physical, needs a map with walls), correlation or "
                   "range (against G, the baseline); auto = echo when the map has walls")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--out", required=True, help="output .npz (samples and diagnostics)")
    p.add_argument("--png", help="corner plot PNG")
    p.set_defaults(func=_cmd_posterior)


def _cmd_posterior(args: argparse.Namespace) -> int:
    import json

    from tqdm import tqdm

    from localization import posterior as post
    from localization.sensor import SensorConfig, build_tables, resolve_model
    from mapping.angles import wrap_angle
    from mapping.files import read_map, read_run

    try:
        a, b = (int(v) for v in args.blocks.split(":"))
    except ValueError:
        raise ValueError(f"--blocks must be A:B with integers A < B, got {args.blocks!r}") from None
    settings = post.PosteriorSettings(n_walkers=args.walkers, n_steps=args.steps,
                                      max_steps=max(args.max_steps, args.steps))
    run = read_run(args.run)
    post.check_block_range(a, b, run.n_blocks)
    wall_map = read_map(args.map)
    tables = build_tables(wall_map, SensorConfig(
        model=resolve_model(wall_map, args.model)), sonar=run.config)
    loglik, truth = post.window_from_run(run, a, b, tables)
    result = None
    with tqdm(total=0, unit="step", desc="grid posterior") as bar:
        for ev in post.iter_posterior(loglik, post.prior_from_tables(tables),
                                      np.random.default_rng(args.seed), settings):
            if ev.stage == "sample":
                if ev.step == 1:
                    bar.reset(total=ev.planned_steps)
                    bar.set_description(f"mode {ev.mode + 1}/{ev.n_modes}")
                bar.total = ev.planned_steps
                bar.update(ev.step - bar.n)
            result = ev.result if ev.result is not None else result
    assert result is not None
    arrays = post.result_arrays(result)
    arrays["truth"] = truth
    arrays["blocks"] = np.array([a, b], dtype=np.float64)
    arrays["meta"] = np.array(json.dumps({"run": str(args.run), "map": str(args.map),
                                          "seed": args.seed, "model": args.model}))
    atomic_savez(Path(args.out), arrays)
    if args.png:
        from service.posterior_plot import write_corner_png

        write_corner_png(Path(args.png), result, truth, f"{Path(args.run).name} blocks {a}:{b}")
    for k, m in enumerate(result.modes):
        err = "" if not np.all(np.isfinite(truth)) else (
            f", error {np.hypot(*(m.mean[:2] - truth[:2])) * 100:.1f} cm "
            f"{np.degrees(wrap_angle(m.mean[2] - truth[2])):+.1f} deg")
        print(f"mode {k}: mass {m.mass:.3f} at ({m.mean[0]:.3f}, {m.mean[1]:.3f}) m, "
              f"{np.degrees(m.mean[2]):.1f} deg; sd {np.sqrt(m.cov[0, 0]) * 100:.1f} / "
              f"{np.sqrt(m.cov[1, 1]) * 100:.1f} cm, {np.degrees(m.heading_circular_std_rad):.1f}"
              f" deg; tau {np.max(m.tau):.1f}, acceptance {m.acceptance_fraction:.2f}, "
              f"{m.n_steps} steps, {'converged' if m.converged else 'NOT converged'}{err}")
    print(f"wrote {args.out}" + (f" and {args.png}" if args.png else ""))
    return 0
