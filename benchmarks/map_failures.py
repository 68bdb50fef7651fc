"""Why tracked runs are lost on built maps: the map's faults at the block the filter leaves.

``localization_echo`` finds the echo model tracking every run on ideal maps and losing 36 of
86 on the walls maps built from one mapping run (its "Read" paragraph blames the maps). This
script measures that blame, run by run, without tuning anything. For every localized run of
every scene it runs the benchmark's tracked trial (2000 particles, seed 0, the same feed) on
the built walls map; for a run that is lost (a block more than 10 cm or 10 deg off) it takes
the first such block and the three before it and asks, at the robot's *true* pose:

- **ghost echoes**: echoes the built map predicts there that were not heard (no measured
  peak within 3 sigma in range and Doppler cosine) and that the room's true walls do not give
  either (no echo of the ideal map within 3 sigma): the built map holds a wall, or a piece of
  one, that is not there (a ghost, a corner joined too far, a wall on the wrong side);
- **missing walls**: measured peaks that no echo of the built map explains but an echo of the
  true walls does: the built map lacks a wall the robot hears;
- and, at the first lost block, whether the built map explains the block better at the
  filter's estimate than at the truth (the map prefers the wrong pose: no filter can keep the
  truth there) and whether the ideal map prefers the truth; then the same comparison on
  counterfactual maps: the built map without the walls blamed for ghost echoes, with the true
  walls blamed for missing peaks added (as exact walls), and both - which repair would have
  kept the truth ahead at that block.

A ghost echo is blamed on the built walls where it bounces more than 10 cm from every true
wall (a ghost, or a piece joined on beyond a real wall's end); one whose bounces all lie on
true walls is a path the true walls block or that needs a wall the map lacks (counted apart).
Each blamed wall gets its *support*, the share of its length within 10 cm of a true wall (a
ghost has none; a real wall joined on too far keeps some). A run's faults are ghosts,
missing walls, both, or neither; its *repair* is the counterfactual map that first makes the
lost block prefer the truth (:data:`REPAIRS`; "the map prefers the truth": it already does,
the filter drifted).

Writes ``benchmarks/results/map_failures.json`` and ``map_failures.png`` (per group of
scenes, the lost runs by the repair that makes their first lost block prefer the truth).
Run: ``python -m benchmarks.map_failures [--only SCENE ...]`` (about 8 min on two cores; the
simulated runs and built maps come from ``localization_echo``'s cache, built there when
missing).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from benchmarks._common import RESULTS
from benchmarks.localization_echo import (
    N_PARTICLES,
    TOL_M,
    TOL_RAD,
    Images,
    LocRun,
    loc_run,
    make_tables,
    scene_cases,
    scene_maps,
    tracking_trial,
    write_json,
)
from localization.sensor import (
    Measurement,
    SensorTables,
    cos_sigma,
    explanation,
    predicted_echoes,
    prepare_measurement,
)
from mapping.heatmap import HeatMap
from mapping.quality import distance_to_walls
from mapping.wallmap import WallMap

FloatArray = NDArray[np.float64]

#: Blocks before the first lost one that are examined with it.
LOOK_BACK = 3
#: A predicted echo and a measured peak match within this many sigma in range and cosine.
MATCH_SIGMA = 3.0
#: A built wall's point within this distance of a true wall is supported by it.
SUPPORT_TOL_M = 0.10
#: Points per metre along a built wall for its support.
SUPPORT_SAMPLES_PER_M = 20


def wall_support(built: FloatArray, true: FloatArray) -> FloatArray:
    """Share of each built wall (n, 2, 2) lying within :data:`SUPPORT_TOL_M` of a true wall."""
    out = np.zeros(built.shape[0])
    for i, (a, b) in enumerate(built):
        k = max(2, int(math.ceil(float(np.hypot(*(b - a))) * SUPPORT_SAMPLES_PER_M)) + 1)
        pts = a + np.linspace(0.0, 1.0, k)[:, None] * (b - a)
        out[i] = float(np.mean(distance_to_walls(pts, true) <= SUPPORT_TOL_M))
    return out


def _matched(r: FloatArray, c: FloatArray, to_r: FloatArray, to_c: FloatArray,
             sig_r: float, sig_c: float | None) -> NDArray[np.bool_]:
    """Whether each (r, c) lies within MATCH_SIGMA of some (to_r, to_c) (cosine ignored when
    ``sig_c`` is None: a block without direction)."""
    if r.size == 0:
        return np.zeros(0, dtype=bool)
    if to_r.size == 0:
        return np.zeros(r.size, dtype=bool)
    d = ((r[:, None] - to_r[None, :]) / sig_r) ** 2
    if sig_c is not None:
        d = d + ((c[:, None] - to_c[None, :]) / sig_c) ** 2
    return np.asarray(np.min(d, axis=1) <= MATCH_SIGMA**2)


def _echoes_at(tables: SensorTables, meas: Measurement, pose: FloatArray
               ) -> tuple[FloatArray, FloatArray, list[list[int]], list[FloatArray]]:
    """Range, cosine, walls and bounce points (k, 2) of each echo the map predicts at
    ``pose`` within the sensor's range window."""
    b, _ = predicted_echoes(tables, meas.speed_m_s, pose[None, :])
    k = int(b.count[0])
    r, c = b.range_m[0, :k], b.cos_doppler[0, :k]
    cfg = tables.config
    keep = np.flatnonzero((r >= cfg.min_range_m) & (r <= cfg.max_range_m))
    walls = [[int(w) for w in b.walls[0, j] if w >= 0] for j in keep]
    points = [b.points_m[0, j][b.walls[0, j] >= 0] for j in keep]
    return r[keep], c[keep], walls, points


def block_faults(built: SensorTables, ideal: SensorTables, meas: Measurement,
                 truth: FloatArray) -> dict[str, Any]:
    """Ghost echoes and missing walls of one block at the true pose (see the module
    docstring): built-map walls of each ghost echo, ideal-map walls of each missing peak."""
    pk = meas.peaks
    assert pk is not None
    sig_r = float(built.config.range_sigma_m)
    sig_c = cos_sigma(built, meas) if pk.use_cos else None
    br, bc, bw, bp = _echoes_at(built, meas, truth)
    ir, ic, iw, _ = _echoes_at(ideal, meas, truth)
    heard = _matched(br, bc, pk.r, pk.c, sig_r, sig_c)
    real = _matched(br, bc, ir, ic, sig_r, sig_c)
    true_seg = np.asarray(ideal.walls.segments_m, dtype=np.float64).reshape(-1, 2, 2)
    ghosts = []
    for j in np.flatnonzero(~heard & ~real):
        off = distance_to_walls(bp[j], true_seg) > SUPPORT_TOL_M
        # the culprit: a bounce off the true walls (a ghost, a piece joined on), or none
        # (every bounce on a true wall: a path the true walls block or that misses a bounce)
        ghosts.append({"walls": bw[j], "off_true_walls": [bw[j][m] for m in np.flatnonzero(off)],
                       "range_m": float(br[j])})
    by_built = _matched(pk.r, pk.c, br, bc, sig_r, sig_c)
    by_ideal = _matched(pk.r, pk.c, ir, ic, sig_r, sig_c)
    missing = []
    for j in np.flatnonzero(~by_built & by_ideal):
        d = ((ir - pk.r[j]) / sig_r) ** 2
        if sig_c is not None:
            d = d + ((ic - pk.c[j]) / sig_c) ** 2
        missing.append(iw[int(np.argmin(d))])
    return {"peaks": int(pk.r.size), "predicted": int(br.size), "ghost_echoes": ghosts,
            "missing_peaks": missing,
            "unexplained_by_either": int(np.sum(~by_built & ~by_ideal))}


def edited_map(wm: WallMap, drop: Sequence[int], add: FloatArray) -> WallMap:
    """``wm`` without the walls ``drop`` and with the segments ``add`` (k, 4) as exact walls
    (the map's median strength, no uncertainty, joined ends): a counterfactual map."""
    n = wm.n_walls
    keep = np.array([i for i in range(n) if i not in set(drop)], dtype=np.int64)
    new_index = np.full(n, -1, dtype=np.int64)
    new_index[keep] = np.arange(keep.size)
    k = add.shape[0]
    pair = wm.wall_pair[keep]
    pair = np.where(pair >= 0, new_index[np.maximum(pair, 0)], -1)
    strength = np.asarray(wm.wall_strength, dtype=np.float64)
    fit = dict(wm.provenance.get("fit", {}))
    ends = wm.wall_end_sigma[keep]
    fit["end_sigma_m"] = np.vstack([ends, np.zeros((k, 2))]).tolist()
    return dataclasses.replace(
        wm, walls_m=np.vstack([wm.walls_m[keep], add.reshape(-1, 4)]),
        wall_strength=np.concatenate([strength[keep],
                                      np.full(k, float(np.median(strength)) if n else 1.0)]),
        wall_sigma=np.vstack([wm.wall_sigma[keep], np.zeros((k, 3))]),
        wall_ambiguous=np.concatenate([pair >= 0, np.zeros(k, dtype=bool)]),
        wall_pair=np.concatenate([pair, np.full(k, -1, dtype=np.int64)]),
        provenance={**wm.provenance, "fit": fit})


def estimate_gap(tables: SensorTables, hm: HeatMap, truth: FloatArray, est: FloatArray
                 ) -> float:
    """How much better ``est`` explains the block ``hm`` than ``truth`` on ``tables``'s map
    (echo log-likelihood, nats; > 0: the map prefers the estimate)."""
    ll = explanation(tables, prepare_measurement(hm, tables.config),
                     np.vstack([truth, est])).log_likelihood
    return float(ll[1] - ll[0])


def counterfactual_gaps(wm: WallMap, ideal: SensorTables, lr: LocRun, hm: HeatMap,
                        truth: FloatArray, est: FloatArray, ghost_walls: Sequence[int],
                        missing_walls: Sequence[int]) -> dict[str, float | None]:
    """:func:`estimate_gap` of the block ``hm`` on the built map ``wm`` without its blamed
    ghost walls, with the true walls it misses added, and both (None where a map's tables
    cannot be built)."""
    true_seg = np.asarray(ideal.walls.segments_m, dtype=np.float64).reshape(-1, 4)
    add = true_seg[list(missing_walls)] if missing_walls else np.zeros((0, 4))
    out: dict[str, float | None] = {}
    for name, drop, extra in (("without_ghosts", ghost_walls, np.zeros((0, 4))),
                              ("with_missing", [], add), ("both", ghost_walls, add)):
        tab = make_tables(edited_map(wm, drop, extra), "echo", lr.sonar)
        out[name] = None if isinstance(tab, str) else estimate_gap(tab, hm, truth, est)
    return out


#: What a lost run's first lost block needs for the map to prefer the truth again.
REPAIRS = ("map prefers the truth", "removing the ghosts", "adding the missing walls",
           "either", "both", "neither", "no heat map at that block")


def repair_class(gaps: dict[str, float | None]) -> str:
    """Which counterfactual map (:func:`counterfactual_gaps`) prefers the truth: none needed
    (the built map already does: the filter drifted), removing the ghost walls, adding the
    missing walls, either one alone, only both together, or neither; a first lost block
    without a heat map says so instead of being counted as any of these."""
    def truth(name: str) -> bool:
        g = gaps.get(name)
        return g is not None and g <= 0.0

    if gaps.get("built") is None:
        return REPAIRS[6]   # a silent block: nothing to compare
    if truth("built"):
        return REPAIRS[0]
    a, b = truth("without_ghosts"), truth("with_missing")
    return (REPAIRS[3] if a and b else REPAIRS[1] if a else REPAIRS[2] if b
            else REPAIRS[4] if truth("both") else REPAIRS[5])


def run_faults(built: SensorTables, ideal: SensorTables, lr: LocRun, images: Images,
               support: FloatArray, wm: WallMap) -> dict[str, Any]:
    """The tracked trial on the built map and, if it is lost, the faults at its first lost
    block and the :data:`LOOK_BACK` blocks before."""
    track, tr = tracking_trial(built, lr.feed, N_PARTICLES, images)
    pos, head = tr.err
    bad = np.flatnonzero((pos > TOL_M) | (head > TOL_RAD))
    out: dict[str, Any] = {"run": lr.name, "lost": bool(bad.size),
                           "position_rmse_m": track["position_rmse_m"]}
    if not bad.size:
        return out
    k = int(bad[0])
    truth, est = lr.feed.truth[k], tr.poses[k]
    blocks = []
    for j in range(max(0, k - LOOK_BACK), k + 1):
        hm = lr.feed.hms[j]
        if hm is None:
            continue
        meas = prepare_measurement(hm, built.config)
        f = block_faults(built, ideal, meas, lr.feed.truth[j])
        f["block"] = j
        blocks.append(f)
    hm = lr.feed.hms[k]
    gaps: dict[str, float | None] = {}
    ideal_gap: float | None = None
    if hm is not None:
        gaps["built"] = estimate_gap(built, hm, truth, est)
        ideal_gap = estimate_gap(ideal, hm, truth, est)
    ghost_walls = sorted({w for b in blocks for e in b["ghost_echoes"]
                          for w in e["off_true_walls"]})
    occluded = sum(not e["off_true_walls"] for b in blocks for e in b["ghost_echoes"])
    missing_walls = sorted({w for b in blocks for e in b["missing_peaks"] for w in e})
    ghosts = sum(len(b["ghost_echoes"]) for b in blocks)
    missing = sum(len(b["missing_peaks"]) for b in blocks)
    cause = ("ghost and missing" if ghosts and missing else "ghost" if ghosts
             else "missing" if missing else "neither")
    built_gap = gaps.get("built")
    if hm is not None:
        gaps |= counterfactual_gaps(wm, ideal, lr, hm, truth, est, ghost_walls, missing_walls)
    repair = repair_class(gaps)
    out.update({
        "first_lost_block": k, "blocks": lr.feed.n,
        "error_m": float(pos[k]), "error_deg": math.degrees(float(head[k])),
        "built_map_prefers_estimate": None if built_gap is None else bool(built_gap > 0.0),
        "ideal_map_prefers_estimate": None if ideal_gap is None else bool(ideal_gap > 0.0),
        "ghost_echoes": ghosts, "ghost_echoes_on_true_walls": occluded,
        "missing_peaks": missing, "cause": cause,
        "ghost_walls": [{"wall": w, "support": float(support[w])} for w in ghost_walls],
        "missing_true_walls": missing_walls, "estimate_minus_truth_nats": gaps,
        "repair": repair,
        "per_block": blocks})
    return out


def summarize(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    lost = [r for r in rows if r.get("lost")]
    ghost_support = [g["support"] for r in lost for g in r.get("ghost_walls", [])]
    return {
        "runs": len(rows), "lost": len(lost),
        "causes": dict(Counter(r["cause"] for r in lost)),
        "repairs": dict(Counter(r["repair"] for r in lost)),
        "built_map_prefers_estimate": sum(bool(r["built_map_prefers_estimate"]) for r in lost),
        "ideal_map_prefers_estimate": sum(bool(r["ideal_map_prefers_estimate"]) for r in lost),
        "ghost_echoes": sum(r["ghost_echoes"] for r in lost),
        "ghost_echoes_on_true_walls": sum(r["ghost_echoes_on_true_walls"] for r in lost),
        "missing_peaks": sum(r["missing_peaks"] for r in lost),
        "map_prefers_estimate_after_edit": {
            name: sum(1 for r in lost
                      if (r.get("estimate_minus_truth_nats", {}).get(name) or 0.0) > 0.0)
            for name in ("built", "without_ghosts", "with_missing", "both")},
        "ghost_walls_blamed": len(ghost_support),
        "ghost_walls_blamed_support_below_half": int(sum(s < 0.5 for s in ghost_support)),
        "ghost_walls_blamed_support_median": (float(np.median(ghost_support))
                                              if ghost_support else math.nan),
    }


def plot(by_group: dict[str, dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = sorted(by_group)
    fig, ax = plt.subplots(figsize=(8, 0.4 * len(groups) + 1.5))
    left = np.zeros(len(groups))
    for repair in REPAIRS:
        n = np.array([by_group[g]["repairs"].get(repair, 0) for g in groups], dtype=float)
        ax.barh(groups, n, left=left, label=f"repaired by {repair}" if repair != REPAIRS[0]
                else repair)
        left += n
    ax.plot([by_group[g]["runs"] for g in groups], groups, "k|", markersize=12,
            label="runs in the group")
    ax.set_xlabel("tracked runs lost on the built walls map")
    ax.set_title("Tracked runs lost on built maps: which map edit makes the first lost block\n"
                 "prefer the truth (without the ghost walls / with the missing true walls)",
                 fontsize=10)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.map_failures",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="+", default=(), metavar="SCENE", help="scenes to run")
    args = ap.parse_args(argv)
    start = time.perf_counter()
    rows: list[dict[str, Any]] = []
    groups: dict[str, str] = {}
    for case in tqdm(scene_cases(args.only), desc="scenes", unit="scene"):
        maps = scene_maps(case)
        runs = [loc_run(case, p) for p in case.loc_paths]
        if not runs:
            continue
        built = make_tables(maps["walls"], "echo", runs[0].sonar)
        ideal = make_tables(maps["ideal"], "echo", runs[0].sonar)
        if isinstance(built, str) or isinstance(ideal, str):
            rows += [{"run": lr.name, "scene": case.name, "group": case.group,
                      "error": built if isinstance(built, str) else ideal} for lr in runs]
            continue
        seg_b = np.asarray(built.walls.segments_m, dtype=np.float64).reshape(-1, 2, 2)
        seg_i = np.asarray(ideal.walls.segments_m, dtype=np.float64).reshape(-1, 2, 2)
        support = wall_support(seg_b, seg_i)
        images = Images(case.scene, runs[0].sonar)
        for lr in runs:
            wm = maps["walls"]
            assert not isinstance(wm, str)
            r = run_faults(built, ideal, lr, images, support, wm)
            r |= {"scene": case.name, "group": case.group,
                  "built_walls": int(seg_b.shape[0]),
                  "built_walls_support_below_half": int(np.sum(support < 0.5))}
            groups[lr.name] = case.group
            rows.append(r)
            tqdm.write(f"{lr.name:24s} " + (f"lost at block {r['first_lost_block']:3d}: "
                                            f"{r['cause']:17s} ghost echoes "
                                            f"{r['ghost_echoes']:2d}, missing peaks "
                                            f"{r['missing_peaks']:2d}, built map prefers the "
                                            f"estimate: {r['built_map_prefers_estimate']}"
                                            if r["lost"] else "tracked"))
    ok = [r for r in rows if "error" not in r]
    by_group = {g: summarize([r for r in ok if r["group"] == g])
                for g in sorted({r["group"] for r in ok})}
    result = {"benchmark": "map_failures", "summary": summarize(ok), "by_group": by_group,
              "settings": {"particles": N_PARTICLES, "tol_m": TOL_M,
                           "tol_deg": math.degrees(TOL_RAD), "look_back": LOOK_BACK,
                           "match_sigma": MATCH_SIGMA, "support_tol_m": SUPPORT_TOL_M},
              "runs": rows, "runtime_s": time.perf_counter() - start}
    stem = "map_failures" if not args.only else "map_failures_only"
    write_json(RESULTS / f"{stem}.json", result)
    if by_group:
        plot(by_group, RESULTS / f"{stem}.png")
    print(result["summary"])
    print(f"wrote {RESULTS / (stem + '.json')} and .png ({result['runtime_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
