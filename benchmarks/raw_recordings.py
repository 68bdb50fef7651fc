"""Benchmark (issue 16): maps and localization from raw recordings against clean runs.

For every built-in scene, the mapped path (``<scene>-curve``, paper: ``paper-b``) and the
localized path (``<scene>-straight``, paper: ``paper-a``) are simulated twice with the same
image-source engine as ``benchmarks.localization_echo`` (order <= 3, paths <= 12 m, SNR 10 dB):

* **clean**: the run file the heat map wants (sonar rate, period-aligned, no direct wave);
* **raw**: :func:`mapping.simulate.raw.simulate_raw` with every effect on (48 kHz, 37 ms latency,
  +60 ppm clock, 5 cm transducer offset, sonar 0.3 m above the floor under a 2.6 m ceiling with
  its floor and ceiling bounces (zero Doppler, constant range), a body echo (0.3 m path,
  reflection 0.3), speaker 1.5-18 kHz and
  microphone 50 Hz-19 kHz band-passes, 22 C air), then imported with
  :func:`mapping.recording.import_raw` told the temperature (a thermometer), once per static
  removal method: ``run``, ``gated`` (given the sonar and ceiling heights) and ``calibration``
  (a 10 s recording standing still in an empty hall of the same height).

Per scene and variant: the wall map built from the mapped run (``walls`` method) scored against
the true walls (:func:`benchmarks.wall_maps.score_map`: wall precision / recall, raster F1),
the false walls within 0.6 m of the floor/ceiling ranges, the tracking RMSE and the global-start
success of the localized run (2000 particles, echo sensor model, odometry noise) on that map,
the importer's latency and clock errors against the simulator's truth, and the cost of
simulating and importing (seconds per minute of recording). Then three harder cases, each with
``gated`` removal: no heights given (floor and ceiling echoes kept), the wrong temperature
(imported with 12 C while the air is at 22 C: a 10 K error, 1.7 % of the speed of sound) and
``wallvia``: the wall paths heard via the floor and the ceiling as well (``vertical_order=2``:
each wall echo gets a copy 2-4 cm behind it off the floor and one up to metres behind it off
the ceiling), localized with the echo model told the heights (it predicts the copies) and,
``wallvia-2d``, without (the copies are clutter to it). Wherever the import was given the
heights, the localization is too (``omnisonar localize`` takes them from the run file).

Writes ``benchmarks/results/raw_recordings.json`` and ``raw_recordings.png``. Run:
``python -m benchmarks.raw_recordings [--scenes paper l-room ...] [--seeds 2]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from tqdm import tqdm

from benchmarks._common import RESULTS
from benchmarks._heldout import heldout_path, heldout_path_names, heldout_scene
from benchmarks.localization_echo import (
    ODO_SPEED_SD_M_S,
    Feed,
    Images,
    engine,
    environment,
    global_trial,
    tracking_trial,
    with_odometry_noise,
    write_json,
)
from benchmarks.wall_maps import score_map
from localization.particle_filter import block_odometry
from localization.sensor import SensorConfig, build_tables, heatmap_run
from mapping.build import BuildParams, RunSource, build_map
from mapping.heatmap import heatmap_of_run
from mapping.path import (
    Trajectory,
    builtin_path,
    builtin_path_names,
    builtin_path_scene,
    stationary_path,
)
from mapping.quality import distance_to_walls
from mapping.recording import RawImportOptions, RawImportReport, import_raw
from mapping.run import Run
from mapping.scene import Scene, Wall, builtin_scene, builtin_scene_names
from mapping.signal import SonarConfig
from mapping.simulate import simulate_run
from mapping.simulate.raw import RawConfig, simulate_raw
from mapping.wallmap import WallMap

SNR_DB = 10.0
SPEED_M_S = 0.1
N_PARTICLES = 2000
TEMPERATURE_C = 22.0
WRONG_TEMPERATURE_C = 12.0
SONAR_HEIGHT_M, CEILING_HEIGHT_M = 0.3, 2.6
METHODS = ("run", "gated", "calibration")
#: A false wall this close to the range of a floor / ceiling bounce counts as one of theirs.
VERTICAL_GHOST_M = 0.6


def raw_config(vertical_order: int = 1) -> RawConfig:
    """Every effect of issue 16 on, at the values of ``omnisonar simulate --raw-all``;
    ``vertical_order`` 1: the floor / ceiling bounces alone (the issue's "zero Doppler,
    constant range"), 2: also the wall paths via the floor and ceiling (ghost walls)."""
    return RawConfig(fs_hz=48_000.0, latency_s=0.037, clock_offset_ppm=60.0,
                     transducer_offset_m=0.05, sonar_height_m=SONAR_HEIGHT_M,
                     ceiling_height_m=CEILING_HEIGHT_M, vertical_order=vertical_order,
                     speaker_band_hz=(1_500.0, 18_000.0), mic_band_hz=(50.0, 19_000.0),
                     temperature_c=TEMPERATURE_C, snr_db=SNR_DB, body_echoes=((0.3, 0.3),))


def paths_of(scene: str) -> tuple[str, str]:
    """(mapped path, localized path) of a built-in scene."""
    names = [p for p in builtin_path_names() if builtin_path_scene(p) == scene]
    curve = [p for p in names if p.endswith("-curve") or p == "paper-b"]
    other = [p for p in names if p not in curve]
    return curve[0], other[0]


def clean_run(scene: Scene, traj: Trajectory, seed: int) -> Run:
    config = SonarConfig()
    n = int(traj.duration_s / config.block_s)
    return simulate_run(scene, traj, config, n, engine(SNR_DB), np.random.default_rng(seed),
                        seed=seed)


def raw_recording(scene: Scene, traj: Trajectory, seed: int, raw: RawConfig) -> tuple[Any, float]:
    """The raw recording of ``traj`` (as long as the clean run) and its simulation seconds."""
    config = SonarConfig()
    n = int(traj.duration_s / config.block_s)
    duration = (n * config.block_s + raw.latency_s + 2 * config.period_s) * (
        1 + raw.clock_offset_ppm * 1e-6)
    t0 = time.perf_counter()
    rec = simulate_raw(scene, traj, config, duration, engine(None), raw,
                       np.random.default_rng(seed))
    return rec, time.perf_counter() - t0


def calibration_recording(raw: RawConfig, seed: int) -> tuple[Any, float]:
    """10 s standing still in an empty hall (one wall 40 m away: beyond every kept path)."""
    hall = Scene(name="empty-hall", description="calibration: no wall within range",
                 walls=[Wall(name="far", start=(40.0, -20.0), end=(40.0, 20.0))])
    traj = stationary_path((0.0, 0.0), 0.0, 12.0)
    t0 = time.perf_counter()
    rec = simulate_raw(hall, traj, SonarConfig(), 10.0, engine(None), raw,
                       np.random.default_rng(seed))
    return rec, time.perf_counter() - t0


def imported(rec: Any, method: str, temperature_c: float, calibration: Any,
             heights: bool = True) -> tuple[Run, RawImportReport, float]:
    opts = RawImportOptions(transducer_offset_m=0.05, static_removal=method,  # type: ignore[arg-type]
                            sonar_height_m=SONAR_HEIGHT_M if heights else None,
                            ceiling_height_m=CEILING_HEIGHT_M if heights else None,
                            temperature_c=temperature_c)
    cal = None if method != "calibration" else (calibration.samples, calibration.fs_hz)
    t0 = time.perf_counter()
    run, report = import_raw(rec.samples, rec.fs_hz, rec.poses, SonarConfig(), opts, cal)
    return run, report, time.perf_counter() - t0


def vertical_ranges_m() -> list[float]:
    """Ranges at which a floor / ceiling bounce would appear (half the vertical path)."""
    h, hc = SONAR_HEIGHT_M, CEILING_HEIGHT_M
    return [h, hc - h, hc]


def map_scores(wm: WallMap | str, scene: Scene, poses: np.ndarray) -> dict[str, Any]:
    """Wall P/R, raster F1 and false walls at the floor / ceiling ranges."""
    if isinstance(wm, str):
        return {"ok": False, "error": wm}
    s = score_map(wm, scene.segments(), poses)
    out: dict[str, Any] = {"ok": True, "walls_found": wm.n_walls,
                           "raster_f1": s["raster"]["f1"]}
    if "walls" in s:
        out |= {"wall_precision": s["walls"]["precision"], "wall_recall": s["walls"]["recall"],
                "wall_f1": s["walls"]["f1"]}
    out["vertical_ghosts"] = vertical_ghosts(wm, scene, poses)
    return out


def vertical_ghosts(wm: WallMap, scene: Scene, poses: np.ndarray) -> int:
    """Fitted walls far (> 0.3 m) from every true wall whose midpoint lies at a floor/ceiling
    range (within 0.6 m) from the nearest pose: false walls the vertical echoes would make."""
    if wm.walls_m is None or len(wm.walls_m) == 0:
        return 0
    mids = 0.5 * (wm.walls_m[:, :2] + wm.walls_m[:, 2:])
    far = distance_to_walls(mids, scene.segments()) > 0.3
    d_pose = np.min(np.linalg.norm(mids[:, None] - poses[None, :, :2], axis=2), axis=1)
    near_vertical = np.min(np.abs(d_pose[:, None] - np.array(vertical_ranges_m())[None]),
                           axis=1) < VERTICAL_GHOST_M
    return int(np.sum(far & near_vertical))


def build(run: Run, name: str) -> WallMap | str:
    try:
        return build_map([RunSource.from_run(run, name)], BuildParams(method="walls"))
    except Exception as exc:  # noqa: BLE001 - a refused fit is a result
        return f"{type(exc).__name__}: {exc}"


def feed_of(run: Run, truth_speed: np.ndarray, seed: int) -> Feed:
    noisy = with_odometry_noise(run, seed)
    heard = heatmap_run(noisy, SensorConfig(model="echo"))  # the echo model's bank, its only reader
    hms = [heatmap_of_run(heard, k) for k in range(noisy.n_blocks)]
    v, w, dt = block_odometry(noisy.speed_m_s, noisy.yaw_rate_rad_s, noisy.t_s,
                              noisy.config.block_s)
    return Feed(hms, v, w, dt, run.pose.copy(), truth_speed)


def localization(wm: WallMap | str, run: Run, scene: Scene, seeds: int, seed: int,
                 heights: bool = False) -> dict[str, Any]:
    """Tracking and global starts of ``run`` on ``wm`` with the echo model; ``heights``: the
    model told the sonar and ceiling heights (floor / ceiling copies of every echo), as
    ``omnisonar localize`` is for a run imported with them."""
    if isinstance(wm, str):
        return {"ok": False, "error": f"map build failed: {wm}"}
    sensor = SensorConfig(model="echo")
    if heights:
        sensor = dataclasses.replace(sensor, sonar_height_m=SONAR_HEIGHT_M,
                                     ceiling_height_m=CEILING_HEIGHT_M)
    tables = build_tables(wm, sensor, sonar=run.config)
    feed = feed_of(run, run.speed_m_s.copy(), seed)
    images = Images(scene, run.config)
    track, _ = tracking_trial(tables, feed, N_PARTICLES, images)
    glob = [global_trial(tables, feed, N_PARTICLES, s, images)[0] for s in range(seeds)]
    return {"ok": True, "position_rmse_m": track["position_rmse_m"],
            "heading_rmse_deg": track["heading_rmse_deg"], "nees_mean": track["nees_mean"],
            "converged_share": track["status"].get("converged", 0) / feed.n,
            "confidently_wrong": track["confidently_wrong"]["wrong"],
            "global_success_mod_sym": float(np.mean([g["success_mod_sym"] for g in glob])),
            "blocks": feed.n}


def report_errors(report: RawImportReport, raw: RawConfig, offset_m: float) -> dict[str, Any]:
    return {"latency_error_samples": (report.latency_s - raw.latency_s) * raw.fs_hz,
            "clock_error_ppm": report.clock_offset_ppm - raw.clock_offset_ppm,
            "direct_suppression_db": report.direct_suppression_db,
            "direct_to_echo_db": report.direct_to_echo_db,
            "fit_residual_samples": report.fit_residual_samples, "blocks": report.blocks,
            "warnings": list(report.warnings), "offset_m": offset_m}


def scene_and_paths(name: str) -> tuple[Scene, str, str, Trajectory, Trajectory]:
    """A built-in scene (its curved and straight paths) or a held-out one of ``scenes/``
    (its ``-curve`` path mapped, its first other path localized)."""
    if name in builtin_scene_names():
        map_path, loc_path = paths_of(name)
        return (builtin_scene(name), map_path, loc_path, builtin_path(map_path, SPEED_M_S),
                builtin_path(loc_path, SPEED_M_S))
    map_path = f"{name}-curve"
    loc_path = next(p for p in heldout_path_names(name) if p != map_path)
    return (heldout_scene(name), map_path, loc_path,
            heldout_path(map_path).trajectory(SPEED_M_S),
            heldout_path(loc_path).trajectory(SPEED_M_S))


def scene_case(name: str, seeds: int) -> dict[str, Any]:
    scene, map_path, loc_path, tr_map, tr_loc = scene_and_paths(name)
    out: dict[str, Any] = {"scene": name, "map_path": map_path, "loc_path": loc_path,
                           "variants": {}}
    seed_map, seed_loc = zlib.crc32(map_path.encode()), zlib.crc32(loc_path.encode())
    t0 = time.perf_counter()
    clean_map, clean_loc = clean_run(scene, tr_map, seed_map), clean_run(scene, tr_loc, seed_loc)
    clean_s = time.perf_counter() - t0
    wm = build(clean_map, map_path)
    out["variants"]["clean"] = {"map": map_scores(wm, scene, clean_map.pose),
                                "localization": localization(wm, clean_loc, scene, seeds, 7)}
    raw = raw_config()
    rec_map, sim_map_s = raw_recording(scene, tr_map, seed_map, raw)
    rec_loc, sim_loc_s = raw_recording(scene, tr_loc, seed_loc, raw)
    cal, _ = calibration_recording(raw, 99)
    minutes = (rec_map.samples.size + rec_loc.samples.size) / raw.fs_hz / 60.0
    out["cost"] = {"recording_minutes": minutes, "clean_sim_s_per_min": clean_s / minutes,
                   "raw_sim_s_per_min": (sim_map_s + sim_loc_s) / minutes}
    for method in METHODS:
        out["variants"][f"raw-{method}"] = raw_variant(scene, rec_map, rec_loc, cal, method,
                                                       TEMPERATURE_C, map_path, seeds, minutes)
    out["variants"]["raw-gated-noheights"] = raw_variant(
        scene, rec_map, rec_loc, cal, "gated", TEMPERATURE_C, map_path, seeds, minutes,
        heights=False)
    out["variants"]["raw-gated-12C"] = raw_variant(scene, rec_map, rec_loc, cal, "gated",
                                                   WRONG_TEMPERATURE_C, map_path, seeds, minutes)
    raw3 = raw_config(vertical_order=2)
    rec_map3, _ = raw_recording(scene, tr_map, seed_map, raw3)
    rec_loc3, _ = raw_recording(scene, tr_loc, seed_loc, raw3)
    out["variants"]["raw-gated-wallvia"] = raw_variant(scene, rec_map3, rec_loc3, cal, "gated",
                                                       TEMPERATURE_C, map_path, seeds, minutes)
    out["variants"]["raw-gated-wallvia-2d"] = raw_variant(
        scene, rec_map3, rec_loc3, cal, "gated", TEMPERATURE_C, map_path, seeds, minutes,
        sensor_heights=False)
    return out


def raw_variant(scene: Scene, rec_map: Any, rec_loc: Any, cal: Any, method: str,
                temperature_c: float, map_path: str, seeds: int, minutes: float,
                heights: bool = True, sensor_heights: bool | None = None) -> dict[str, Any]:
    """Import (``heights``: the import told the heights), map, localize (``sensor_heights``,
    default ``heights``: the echo model told them too)."""
    try:
        run_map, rep_map, s1 = imported(rec_map, method, temperature_c, cal, heights)
        run_loc, rep_loc, s2 = imported(rec_loc, method, temperature_c, cal, heights)
    except ValueError as exc:
        return {"error": str(exc)}
    wm = build(run_map, map_path)
    return {"map": map_scores(wm, scene, run_map.pose),
            "localization": localization(wm, run_loc, scene, seeds, 7,
                                         heights if sensor_heights is None else sensor_heights),
            "import": report_errors(rep_map, rec_map.raw, 0.05),
            "import_loc": report_errors(rep_loc, rec_loc.raw, 0.05),
            "import_s_per_min": (s1 + s2) / minutes,
            "sound_speed_m_s": rep_map.sound_speed_m_s}


def ratio_rows(scenes: Sequence[dict[str, Any]]) -> list[str]:
    """Text lines: per scene and variant the figures beside the clean run's."""
    lines = []
    for sc in scenes:
        for v, e in sc["variants"].items():
            if "error" in e:
                lines.append(f"{sc['scene']:9s} {v:16s} import refused: {e['error']}")
                continue
            m, loc = e["map"], e["localization"]
            wall = (f"wall P/R {m.get('wall_precision', math.nan):.2f}/"
                    f"{m.get('wall_recall', math.nan):.2f} F1 {m.get('wall_f1', math.nan):.2f}"
                    if m.get("ok") else f"map failed: {m.get('error')}")
            locs = (f"rmse {100 * loc['position_rmse_m']:5.1f} cm "
                    f"{loc['heading_rmse_deg']:4.1f} deg glob {loc['global_success_mod_sym']:.2f}"
                    f" conv {loc['converged_share']:.2f} cw {loc['confidently_wrong']}"
                    if loc.get("ok") else f"loc failed: {loc.get('error')}")
            extra = ""
            if "import" in e:
                i = e["import"]
                extra = (f" | lat {i['latency_error_samples']:+.3f} smp clock "
                         f"{i['clock_error_ppm']:+.2f} ppm supp "
                         f"{i['direct_suppression_db']:.0f} dB")
            lines.append(f"{sc['scene']:9s} {v:16s} {wall} raster F1 "
                         f"{m.get('raster_f1', math.nan):.2f} ghosts "
                         f"{m.get('vertical_ghosts', '-')} | {locs}{extra}")
    return lines


def plot(scenes: Sequence[dict[str, Any]], path: Path) -> None:
    """Wall F1, raster F1 and tracking RMSE per scene and variant, and accuracy against cost:
    each raw variant's mean tracking RMSE against its import seconds per minute of recording
    (the clean run at the clean simulation's cost, for scale)."""
    variants = list(scenes[0]["variants"])
    fig, axes = plt.subplots(1, 4, figsize=(19, 4.6),
                             gridspec_kw={"width_ratios": [1.2, 1.2, 1.2, 1.0]})
    width = 0.8 / len(variants)
    x = np.arange(len(scenes))
    panels = (("map", "wall_f1", "wall F1 (map from the curved run)"),
              ("map", "raster_f1", "raster F1"),
              ("localization", "position_rmse_m", "tracking RMSE (m), log"))
    for ax, (part, key, title) in zip(axes[:3], panels, strict=True):
        for i, v in enumerate(variants):
            vals = [sc["variants"][v].get(part, {}).get(key, math.nan) for sc in scenes]
            ax.bar(x + (i - len(variants) / 2 + 0.5) * width, vals, width, label=v)
        ax.set_xticks(x, [sc["scene"] for sc in scenes])
        ax.set_title(title, fontsize=10)
        if key == "position_rmse_m":
            ax.set_yscale("log")
    ax = axes[3]
    for i, v in enumerate(variants):
        rmse = np.nanmean([sc["variants"][v].get("localization", {}).get(
            "position_rmse_m", math.nan) for sc in scenes])
        cost = np.mean([sc["cost"]["clean_sim_s_per_min"] if v == "clean" else
                        sc["variants"][v].get("import_s_per_min", math.nan) for sc in scenes])
        ax.scatter(cost, rmse, s=60, color=f"C{i}")
        ax.annotate(v, (cost, rmse), fontsize=7, xytext=(4, 3), textcoords="offset points")
    ax.set_yscale("log")
    ax.set_xlabel("s per minute of recording (import; clean: its simulation)")
    ax.set_ylabel("mean tracking RMSE (m)")
    ax.set_title("accuracy vs cost", fontsize=10)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="lower center", ncol=len(variants),
               fontsize=8, frameon=False)
    fig.suptitle("raw recordings (48 kHz, every effect, SNR 10 dB) against clean runs",
                 fontsize=11)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)


def summarize(scenes: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Means over scenes per variant, and each raw variant's ratio to the clean figures."""
    out: dict[str, Any] = {}
    keys = (("map", "wall_f1"), ("map", "raster_f1"), ("map", "vertical_ghosts"),
            ("localization", "position_rmse_m"), ("localization", "global_success_mod_sym"),
            ("localization", "converged_share"), ("localization", "confidently_wrong"))
    for v in scenes[0]["variants"]:
        row = {}
        for part, key in keys:
            vals = [float(sc["variants"][v].get(part, {}).get(key, math.nan)) for sc in scenes]
            row[key] = float(np.nanmean(vals)) if np.isfinite(vals).any() else math.nan
        if v != "clean":
            imp = [sc["variants"][v].get("import", {}) for sc in scenes]
            row["latency_error_samples_max"] = max(abs(i.get("latency_error_samples", math.nan))
                                                   for i in imp)
            row["clock_error_ppm_max"] = max(abs(i.get("clock_error_ppm", math.nan)) for i in imp)
            row["direct_suppression_db_min"] = min(i.get("direct_suppression_db", math.nan)
                                                   for i in imp)
        out[v] = row
    for v, row in out.items():
        if v != "clean":
            row["ratio_to_clean"] = {k: row[k] / out["clean"][k] if out["clean"][k] else math.nan
                                     for k in ("wall_f1", "raster_f1", "position_rmse_m",
                                               "global_success_mod_sym")}
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.raw_recordings",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="+", default=builtin_scene_names())
    ap.add_argument("--seeds", type=int, default=2, help="global starts per localized run")
    ap.add_argument("--plot-only", action="store_true",
                    help="redraw raw_recordings.png from raw_recordings.json")
    ap.add_argument("--tag", default="", help="write raw_recordings_TAG.json/.png (with "
                    "--scenes: a subset beside the built-in scenes' results)")
    args = ap.parse_args(argv)
    stem = f"raw_recordings_{args.tag}" if args.tag else "raw_recordings"
    if args.plot_only:
        plot(json.loads((RESULTS / f"{stem}.json").read_text())["scenes"],
             RESULTS / f"{stem}.png")
        return 0
    t0 = time.perf_counter()
    env = environment()
    scenes = [scene_case(s, args.seeds) for s in tqdm(args.scenes, desc="scenes")]
    result = {"settings": {"snr_db": SNR_DB, "speed_m_s": SPEED_M_S, "particles": N_PARTICLES,
                           "raw": dataclasses.asdict(raw_config()), "methods": list(METHODS),
                           "wallvia_vertical_order": 2,
                           "odometry_speed_sd_m_s": ODO_SPEED_SD_M_S,
                           "wrong_temperature_c": WRONG_TEMPERATURE_C, "seeds": args.seeds},
              "environment_start": env, "environment_end": environment(),
              "scenes": scenes, "summary": summarize(scenes),
              "runtime_s": time.perf_counter() - t0}
    write_json(RESULTS / f"{stem}.json", result)
    plot(scenes, RESULTS / f"{stem}.png")
    for line in ratio_rows(scenes):
        print(line)
    summary: dict[str, Any] = result["summary"]  # type: ignore[assignment]
    for v, row in summary.items():
        print(v, {k: (round(x, 3) if isinstance(x, float) else x) for k, x in row.items()})
    print(f"wrote {RESULTS / (stem + '.json')} ({result['runtime_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
