"""Benchmark: accuracy vs cost of the wall-map methods on built-in and held-out scenes (issue 13).

Input: one curved run per scene, simulated with the image-source engine at SNR 10 dB with
odometry noise (5 mm/s on the recorded speed, seeded per path) and cached in
``benchmarks/results/cache/`` (simulation time is never counted):

* built-in scenes: ``paper-b`` and every ``<scene>-curve`` of :func:`mapping.path.builtin_path`;
* held-out scenes (``scenes/``, never used to tune a default): every ``<scene>-curve`` of
  ``scenes/paths.json``; those whose path has ``"group": "fresh"`` (written after the wall fit
  was developed, never looked at while tuning it) form their own group "fresh".

The engine keeps paths up to ``max_path_m`` = 12 m round trip (2 x the build radius of 6 m:
an echo from farther lands outside every back-projection disc). The automatic order without
that cap costs 3.5 s per block in ``office`` and 15 s in ``pillar`` (order 8-11, truncated),
with it 0.2 s and 0.8 s; the flutter echoes between parallel walls up to 12 m are kept.

Each method of ``--methods`` (``paper``, ``inverse``, ``walls``; a method that
:data:`mapping.build.METHODS` does not know yet is skipped with a note) builds a map of each run
with :func:`mapping.build.build_map` in this process, heat maps included; the build time is the
median of 3 builds when one takes under 2 s, else of one (after a warm-up build that pays
numba's compilation). The baseline is the paper method in the same process.

Scores (:func:`score_map`, with :func:`mapping.quality.evaluate_raster` and
:func:`mapping.quality.evaluate_walls`), all inside one coverage per run: cells within the 6 m
build radius of a pose and in its line of sight past the true walls. Raster precision/recall at
cells ``G >= 0.2 max(G)`` within 10 cm (also ``raster_in_range``: inside the 6 m range only,
so ghosts behind the true walls count against precision); for maps with fitted walls
(``walls_m``) wall-level precision/recall as issue 13 defines them (80 % within 10 cm), angle
and endpoint errors.

Writes ``benchmarks/results/wall_maps.json`` and ``wall_maps.png`` (``--quick``: 12 blocks per
run, one build each, ``wall_maps_quick.*``). Run: ``python -m benchmarks.wall_maps``.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import hashlib
import json
import os
import platform
import time
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from benchmarks._common import RESULTS
from benchmarks._heldout import heldout_path, heldout_scene, heldout_scene_names
from mapping.build import METHODS, BuildParams, RunSource, build_map, run_heatmaps
from mapping.coverage import coverage_mask
from mapping.files import read_run, write_run
from mapping.forward import ForwardParams, WallSet, echoes_batch
from mapping.path import Trajectory, builtin_path, builtin_path_names, builtin_path_scene
from mapping.quality import (
    evaluate_raster,
    evaluate_walls,
    observed_near_points,
    observed_wall_mask,
)
from mapping.run import Run
from mapping.scene import Scene, builtin_scene
from mapping.signal import SonarConfig
from mapping.simulate import simulate_run
from mapping.simulate.ism import IsmConfig
from mapping.wallmap import WallMap

FloatArray = NDArray[np.float64]
CACHE = RESULTS / "cache"
ALL_METHODS = ("paper", "inverse", "walls")
SNR_DB = 10.0
ODOMETRY_NOISE_M_S = 0.005
MAX_PATH_M = 12.0
FRACTION = 0.2  # raster threshold: G >= FRACTION * max(G)
TOL_M = 0.10  # 10 cm, raster and wall level
COVER = 0.8  # wall level: share of a wall that must lie within TOL_M
RADIUS_M = 6.0  # what a run could observe: the build radius (GridParams().radius_m)
SPACING_M = 0.01  # wall samples for the wall-level scores
QUICK_BLOCKS = 12


@dataclasses.dataclass(frozen=True)
class Case:
    """One scene and its curved path; ``group`` is "built-in", "held-out" or "fresh"."""

    path: str
    scene: Scene
    trajectory: Trajectory
    group: str


def cases(only: Sequence[str] = ()) -> list[Case]:
    """Every built-in and held-out curved path (only those named in ``only``, if given)."""
    out = [Case(p, builtin_scene(builtin_path_scene(p)), builtin_path(p), "built-in")
           for p in builtin_path_names() if p == "paper-b" or p.endswith("-curve")]
    for s in heldout_scene_names():
        spec = heldout_path(f"{s}-curve")
        out.append(Case(spec.name, heldout_scene(s), spec.trajectory(), spec.group))
    if only:
        unknown = set(only) - {c.path for c in out}
        if unknown:
            raise ValueError(f"--paths must name curved paths of {[c.path for c in out]}, "
                             f"got {sorted(unknown)}")
        out = [c for c in out if c.path in only]
    return out


# ---- simulation (cached) -----------------------------------------------------------------
def engine() -> IsmConfig:
    """The image-source configuration of every run."""
    return IsmConfig(snr_db=SNR_DB, odometry_noise_m_s=ODOMETRY_NOISE_M_S, max_path_m=MAX_PATH_M)


def simulated(case: Case, n_blocks: int | None = None, verbose: bool = True) -> Run:
    """The run of ``case`` (cached on disk, keyed by scene, path, engine and block count)."""
    config = SonarConfig()
    n = int(case.trajectory.duration_s / config.block_s)
    n = n if n_blocks is None else min(n, n_blocks)
    seed = zlib.crc32(case.path.encode())
    t = np.linspace(0.0, case.trajectory.duration_s, 64)
    key = json.dumps([case.scene.to_json(), case.trajectory.pose(t).round(6).tolist(),
                      engine().to_dict(), config.to_json(), n, seed])
    cached = CACHE / f"{case.path}_n{n}_{hashlib.sha1(key.encode()).hexdigest()[:10]}.npz"
    if cached.exists():
        return read_run(cached)
    start = time.perf_counter()
    run = simulate_run(case.scene, case.trajectory, config, n, engine(),
                       np.random.default_rng(seed), seed=seed)
    CACHE.mkdir(parents=True, exist_ok=True)
    write_run(cached, run)
    if verbose:
        print(f"simulated {case.path}: {n} blocks in {time.perf_counter() - start:.0f} s",
              flush=True)
    return run


# ---- scoring -----------------------------------------------------------------------------
def score_map(wallmap: WallMap, segments: FloatArray, poses: FloatArray,
              radius_m: float = RADIUS_M) -> dict[str, Any]:
    """Raster scores of ``wallmap`` and, if it has fitted walls, wall-level scores.

    Every method is scored inside the same coverage: the cells within ``radius_m`` of a pose of
    the run and in its line of sight past the *true* walls (:func:`mapping.coverage.coverage_mask`),
    not the map's own ``coverage``, so that no method sets its own denominator.

    Parameters
    ----------
    wallmap : WallMap
    segments : ndarray, shape (W, 2, 2)
        True walls (``Scene.segments()``), metres.
    poses : ndarray, shape (n, 3)
        Tracked poses of the run.
    radius_m : float
        Largest range the run could observe (the build radius).

    Returns
    -------
    dict
        ``raster``: :class:`mapping.quality.RasterQuality` fields plus ``f1``;
        ``raster_in_range``: the same inside range only, ignoring line of sight (so cells
        behind a true wall, where mirror ghosts land, count too); ``walls`` (only
        for a map with fitted walls): :class:`mapping.quality.WallQuality` fields plus ``f1``.
    """
    coverage = coverage_mask(poses, wallmap.x_m, wallmap.y_m, radius_m, segments.reshape(-1, 4))
    raster = evaluate_raster(wallmap, segments, FRACTION, TOL_M, coverage=coverage).to_dict()
    in_range = coverage_mask(poses, wallmap.x_m, wallmap.y_m, radius_m)
    whole = evaluate_raster(wallmap, segments, FRACTION, TOL_M, coverage=in_range).to_dict()
    out: dict[str, Any] = {
        "raster": raster | {"f1": _f1(raster["precision"], raster["recall"])},
        "raster_in_range": whole | {"f1": _f1(whole["precision"], whole["recall"])},
    }
    if wallmap.walls_m.shape[0] > 0:
        observed = observed_wall_mask(segments, coverage, wallmap.x_m, wallmap.y_m, SPACING_M)
        walls = evaluate_walls(wallmap.walls_m, segments, observed, TOL_M, COVER,
                               pair=wallmap.wall_pair, spacing_m=SPACING_M).to_dict()
        out["walls"] = walls | {"f1": _f1(walls["precision"], walls["recall"])}
        heard = observed_near_points(segments, heard_points(segments, poses, radius_m),
                                     SPACING_M, HEARD_RADIUS_M)
        spec = evaluate_walls(wallmap.walls_m, segments, heard, TOL_M, COVER,
                              pair=wallmap.wall_pair, spacing_m=SPACING_M).to_dict()
        out["walls_heard"] = spec | {"f1": _f1(spec["precision"], spec["recall"])}
    return out


#: A true-wall sample counts as heard within this of a specular point (the points of
#: consecutive blocks are up to ~0.1 m apart along a wall at 0.1 m/s).
HEARD_RADIUS_M = 0.15


def heard_points(segments: FloatArray, poses: FloatArray, radius_m: float) -> FloatArray:
    """Where a specular sonar on ``poses`` can hear the true walls: the first-order specular
    points (foot of the perpendicular on the segment, line of sight clear) and the vertices of
    the inside corners it hears, within ``radius_m`` (the forward model on the true walls)."""
    walls = WallSet(np.asarray(segments, dtype=np.float64), np.ones(len(segments)))
    tracked = poses[np.isfinite(poses).all(axis=1)]
    batch = echoes_batch(walls, tracked, 0.1, SonarConfig(),
                         ForwardParams(max_order=2, max_range_m=radius_m))
    pts = batch.points_m[..., 0, :][batch.order == 1]
    corner = (batch.order == 2)
    mid = batch.points_m[corner][:, :2].mean(axis=1)
    near = np.hypot(*(batch.points_m[corner][:, 0] - batch.points_m[corner][:, 1]).T) < 0.05
    return np.concatenate([pts.reshape(-1, 2), mid[near].reshape(-1, 2)])


def _f1(p: float | None, r: float | None) -> float:
    """Harmonic mean of precision and recall (0 when either is missing or both are 0)."""
    return 0.0 if p is None or r is None or not p + r > 0 else 2 * p * r / (p + r)


# ---- timing and the run of one case -------------------------------------------------------
def timed(fn: Callable[[], Any], cheap_s: float = 2.0, repeats: int = 3
          ) -> tuple[float, float, list[float], Any]:
    """Median wall-clock and CPU seconds of ``fn`` (``repeats`` calls if the first takes
    under ``cheap_s``), every wall-clock time, and the last result."""
    walls, cpus = [], []
    out = None
    for i in range(repeats):
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - w)
        cpus.append(time.process_time() - c)
        if i == 0 and walls[0] >= cheap_s:
            break
    return float(np.median(walls)), float(np.median(cpus)), walls, out


def bench_case(case: Case, run: Run, methods: Sequence[str], repeats: int) -> dict[str, Any]:
    """Build, time and score every method on the run of ``case``."""
    source = [RunSource.from_run(run, case.path)]
    hm_s, _, _, _ = timed(lambda: list(run_heatmaps(run)), repeats=1)
    row: dict[str, Any] = {"path": case.path, "scene": case.scene.name, "group": case.group,
                           "blocks": run.n_blocks, "walls": len(case.scene.walls),
                           "heatmaps_s": hm_s, "methods": {}}
    for m in methods:
        wall_s, cpu_s, all_s, wm = timed(
            functools.partial(build_map, source, BuildParams(method=m)), repeats=repeats)
        row["methods"][m] = {"build_s": wall_s, "cpu_s": cpu_s, "build_s_all": all_s,
                             **score_map(wm, case.scene.segments(), run.pose)}
    base = row["methods"].get("paper", {}).get("build_s")
    for r in row["methods"].values():
        r["cost_vs_paper"] = r["build_s"] / base if base else None
    return row


def warm_up(run: Run, methods: Sequence[str]) -> None:
    """One build per method on two blocks, so numba compilation is never timed."""
    short = dataclasses.replace(run, samples=run.samples[:2], t_s=run.t_s[:2],
                                speed_m_s=run.speed_m_s[:2],
                                yaw_rate_rad_s=run.yaw_rate_rad_s[:2], pose=run.pose[:2])
    for m in methods:
        try:
            build_map([RunSource.from_run(short, "warm-up")], BuildParams(method=m))
        except ValueError as exc:  # too little to map from 2 blocks: compiled anyway
            print(f"note: warm-up of {m!r} on 2 blocks: {exc}")


# ---- chart -------------------------------------------------------------------------------
def plot(rows: list[dict[str, Any]], methods: Sequence[str], path: Path) -> None:
    """Raster F1 (two coverages) and wall F1 vs build time, one marker per scene (hollow
    squares: held-out; hollow triangles: fresh)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FormatStrFormatter, NullFormatter

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.8), sharex=True)
    panels = ((axes[0], "raster", f"raster F1 in line of sight (G >= {FRACTION} max, 10 cm)"),
              (axes[1], "raster_in_range", "raster F1 in range (ghosts behind walls count)"),
              (axes[2], "walls", "wall-level F1 (80 % within 10 cm)"))
    for ax, key, label in panels:
        for k, m in enumerate(methods):
            for group, fill, marker in (("built-in", True, "o"), ("held-out", False, "s"),
                                        ("fresh", False, "^")):
                pts = [(r["methods"][m]["build_s"], r["methods"][m][key]["f1"], r["scene"])
                       for r in rows if r["group"] == group and key in r["methods"][m]]
                if not pts:
                    continue
                xs, ys, _ = zip(*pts, strict=True)
                color = f"C{k}"
                ax.scatter(xs, ys, s=40, marker=marker, label=f"{m}, {group}",
                           facecolors=color if fill else "none", edgecolors=color)
                for x, y, n in pts:
                    ax.annotate(n, (x, y), fontsize=6, xytext=(3, 2),
                                textcoords="offset points")
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_ylim(-0.03, 1.03)
        ax.set_xlabel("build time per run, s (log; heat maps included)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        if not ax.collections:
            ax.text(0.5, 0.5, "no method fitted walls", transform=ax.transAxes,
                    ha="center", color="0.5")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=8, loc="lower center", ncol=max(len(labels), 1))
    fig.suptitle(f"wall maps: accuracy vs cost, one curved run per scene "
                 f"(ISM, SNR {SNR_DB:g} dB, odometry noise {ODOMETRY_NOISE_M_S} m/s)",
                 fontsize=10)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def summary(rows: list[dict[str, Any]], methods: Sequence[str]) -> dict[str, Any]:
    """Mean raster P/R/F1 and build time per method and group (and over all scenes)."""
    out: dict[str, Any] = {}
    for m in methods:
        out[m] = {}
        for group in ("built-in", "held-out", "fresh", "all"):
            sel = [r["methods"][m] for r in rows if group in ("all", r["group"])]
            if sel:
                out[m][group] = {
                    k: float(np.nanmean([_num(s["raster"][k]) for s in sel]))
                    for k in ("precision", "recall", "f1")} | {
                    "build_s": float(np.mean([s["build_s"] for s in sel]))}
    return out


def _num(value: float | None) -> float:
    """A JSON figure as a float (null -> NaN)."""
    return float("nan") if value is None else float(value)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.wall_maps",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--methods", default=",".join(ALL_METHODS),
                        help="comma-separated build methods (default: %(default)s)")
    parser.add_argument("--paths", default="", help="comma-separated curved paths (default: "
                        "every built-in and held-out scene's)")
    parser.add_argument("--quick", action="store_true",
                        help=f"{QUICK_BLOCKS} blocks per run, one build per method")
    args = parser.parse_args(argv)
    methods = []
    for m in (s.strip() for s in args.methods.split(",") if s.strip()):
        if m in METHODS:
            methods.append(m)
        else:
            print(f"note: method {m!r} is not in mapping.build.METHODS {METHODS}: skipped")
    if not methods:
        raise SystemExit("no method to benchmark")
    chosen = cases([p for p in args.paths.split(",") if p])
    n_blocks = QUICK_BLOCKS if args.quick else None
    runs = [simulated(c, n_blocks) for c in chosen]
    warm_up(runs[0], methods)
    rows = []
    for case, run in zip(chosen, runs, strict=True):
        rows.append(bench_case(case, run, methods, repeats=1 if args.quick else 3))
        print(_line(rows[-1], methods), flush=True)
    name = "wall_maps_quick" if args.quick else "wall_maps"
    result = {
        "benchmark": "wall_maps",
        "machine": {"cpus": os.cpu_count(), "load_avg": os.getloadavg(),
                    "python": platform.python_version()},
        "input": {"engine": engine().to_dict(), "sonar": SonarConfig().to_dict(),
                  "quick": args.quick, "fraction_of_max": FRACTION, "tol_m": TOL_M,
                  "wall_cover": COVER, "observe_radius_m": RADIUS_M},
        "methods": methods,
        "skipped_methods": [m for m in args.methods.split(",") if m and m not in methods],
        "cases": rows,
        "summary": summary(rows, methods),
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps(result, indent=2))
    plot(rows, methods, RESULTS / f"{name}.png")
    print(json.dumps(result["summary"], indent=2))


def _line(row: dict[str, Any], methods: Sequence[str]) -> str:
    parts = [f"{row['path']:<22} {row['group']:<8} {row['blocks']:>3} blocks"]
    for m in methods:
        r = row["methods"][m]
        s = (f"{m}: P {_num(r['raster']['precision']):.2f} "
             f"R {_num(r['raster']['recall']):.2f} {r['build_s']:.2f} s")
        if "walls" in r:
            w = r["walls"]
            h = r["walls_heard"]
            s += (f" | walls P {_num(w['precision']):.2f} R {_num(w['recall']):.2f}"
                  f" heard-part R {_num(h['recall']):.2f}")
        parts.append(s)
    return "  ".join(parts)


if __name__ == "__main__":
    main()
