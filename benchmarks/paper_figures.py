"""Reproduce the paper's Figs. 5-7 with numbers (image-source simulations of the paper scene).

* Fig. 5 analogue: single-block Cartesian heat maps (eqs. 2-4) at point (a) = (2, 2) on path A
  and at two points of path B, scaled to a maximum of 1 as in the paper;
* Fig. 6 analogue: the map G from path A and from path B (M = 10);
* Fig. 7 analogue: path B with M = 4, 6, 8, 10;
* every map also with the inverse reconstruction (``--method inverse``), same runs;
* ``--extra``: the other built-in scenes' curved paths and path B at -20 dB per-sample SNR.

Writes ``benchmarks/results/paper_fig5.png``, ``paper_fig6.png``, ``paper_fig7.png``,
``paper_extra.png`` and the quality table ``paper_figures.json`` (precision / recall / Chamfer at
strong-cell thresholds 0.25, 0.5, 0.75 of the 99th percentile of G > 0, ghost energy; see
:mod:`mapping.quality`). Runs are simulated once and cached in ``out/bench_runs/``.
Run: ``python -m benchmarks.paper_figures [--extra]``.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from benchmarks._common import CACHE, RESULTS, simulated_run
from mapping.build import run_heatmaps
from mapping.grid import GridExtent, GridParams, accumulate, cartesian_heatmap
from mapping.quality import evaluate
from mapping.reconstruct import (
    InverseParams,
    observations_from_heatmaps,
    prune_speckle,
    reconstruct_inverse,
)
from mapping.run import Run
from mapping.scene import Scene
from mapping.wallmap import WallMap

VIEW = (-1.0, 7.0, -1.0, 6.0)
BASE = ["path A, M=10", "path B, M=10", "path B, M=4", "path B, M=6", "path B, M=8"]


def maps_for(run: Run) -> tuple[list[Any], WallMap, WallMap, WallMap, dict[str, float]]:
    """Heat maps, the paper's map, the inverse map (defaults) and the inverse map with speckle
    pruning at 5 % of p99 of one run, with timings."""
    grid, inv = GridParams(), InverseParams()
    t0 = time.perf_counter()
    hms = list(run_heatmaps(run))
    t1 = time.perf_counter()
    G, extent, _ = accumulate(hms, run.pose, grid)
    t2 = time.perf_counter()
    obs, _ = observations_from_heatmaps(hms, run.pose, grid, inv, config=run.config)
    Gi, _ = reconstruct_inverse(obs, extent, grid, inv)
    t3 = time.perf_counter()
    paper = WallMap(G, extent.origin_m, extent.resolution_m, method="paper")
    inverse = WallMap(Gi, extent.origin_m, extent.resolution_m, method="inverse")
    pruned, _ = prune_speckle(Gi, 0.05)
    pruned_map = WallMap(pruned, extent.origin_m, extent.resolution_m, method="inverse_pruned")
    return hms, paper, inverse, pruned_map, {"heatmaps_s": t1 - t0, "paper_s": t2 - t1,
                                             "inverse_s": t3 - t2}


def quality_row(wm: WallMap, segments: np.ndarray) -> dict[str, Any]:
    """Quality numbers of a map as a plain dict."""
    q = evaluate(wm, segments)
    return {"ghost_energy": q.ghost_energy,
            **{f"at_{a.fraction:g}": {"precision": a.precision, "recall": a.recall,
                                      "chamfer_m": a.chamfer_m, "strong_cells": a.strong_cells}
               for a in q.at}}


def draw(ax: Any, G: np.ndarray, extent_m: tuple[float, float, float, float],
         segments: np.ndarray, poses: np.ndarray | None, title: str, scale: float) -> None:
    ax.imshow(G / scale, origin="lower", extent=extent_m, vmin=0, vmax=1, cmap="magma",
              interpolation="nearest")
    for a, b in segments:
        ax.plot([a[0], b[0]], [a[1], b[1]], "-", color="cyan", lw=0.6, alpha=0.7)
    if poses is not None:
        ax.plot(poses[:, 0], poses[:, 1], ".", color="white", ms=1.5)
    lo, hi = segments.reshape(-1, 2).min(axis=0), segments.reshape(-1, 2).max(axis=0)
    ax.set_xlim(min(VIEW[0], lo[0] - 1.0), max(VIEW[1], hi[0] + 1.0))
    ax.set_ylim(min(VIEW[2], lo[1] - 1.0), max(VIEW[3], hi[1] + 1.0))
    ax.set_title(title, fontsize=8)
    ax.tick_params(labelsize=6)


def p99(G: np.ndarray) -> float:
    pos = G[G > 0]
    return float(np.percentile(pos, 99)) if pos.size else 1.0


def short(row: dict[str, Any]) -> str:
    a = row["at_0.5"]
    return f"P {a['precision']:.2f} R {a['recall']:.2f} ghost {row['ghost_energy']:.2f}"


def fig5(run_a: Run, hms_a: list[Any], run_b: Run, hms_b: list[Any],
         segments: np.ndarray) -> None:
    ext = GridExtent((VIEW[0], VIEW[2]), (141, 161), 0.05)
    k_a = int(np.argmin(np.hypot(run_a.pose[:, 0] - 2.0, run_a.pose[:, 1] - 2.0)))
    picks = [("(a) path A", run_a, hms_a, k_a), ("(b) path B", run_b, hms_b, run_b.n_blocks // 3),
             ("(c) path B", run_b, hms_b, 2 * run_b.n_blocks // 3)]
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.2))
    for ax, (label, run, hms, k) in zip(axes, picks, strict=True):
        G = cartesian_heatmap(hms[k], run.pose[k], ext, GridParams(floor="none"))
        wm = WallMap(G, ext.origin_m, ext.resolution_m)
        x, y, h = run.pose[k]
        draw(ax, G, wm.extent_m, segments, None,
             f"{label}: block {k} at ({x:.2f}, {y:.2f}), heading {np.degrees(h):.0f} deg",
             float(G.max()))
        ax.arrow(x, y, 0.4 * np.cos(h), 0.4 * np.sin(h), color="lime", width=0.03)
    fig.suptitle("Fig. 5 analogue: one block's heat map in Cartesian coordinates (max = 1)",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(RESULTS / "paper_fig5.png", dpi=110)
    plt.close(fig)


def grid_figure(name: str, title: str, entries: list[tuple[str, Run, WallMap, WallMap]],
                segments_of: dict[str, np.ndarray], table: dict[str, Any]) -> None:
    fig, axes = plt.subplots(2, len(entries), figsize=(3.6 * len(entries), 7.2), squeeze=False)
    for j, (label, run, paper, inverse) in enumerate(entries):
        for i, wm in enumerate((paper, inverse)):
            row = table[label][wm.method]
            draw(axes[i, j], wm.G, wm.extent_m, segments_of[label], run.pose,
                 f"{label} {wm.method}\n{short(row)}", p99(wm.G))
    fig.suptitle(title + " (top: paper eqs. 2-5, bottom: inverse; scale p99 of G > 0; "
                 "P/R at 0.5 x p99, 10 cm)", fontsize=9)
    fig.tight_layout()
    fig.savefig(RESULTS / name, dpi=100)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--extra", action="store_true",
                        help="also the other scenes' curved paths and path B at -20 dB SNR "
                             "(those already simulated into out/bench_runs/ unless "
                             "--simulate-missing)")
    parser.add_argument("--simulate-missing", action="store_true",
                        help="with --extra, simulate runs not yet cached (slow)")
    args = parser.parse_args()
    RESULTS.mkdir(parents=True, exist_ok=True)
    specs = [("path A, M=10", "paper-a", 10, None), ("path B, M=10", "paper-b", 10, None),
             ("path B, M=4", "paper-b", 4, None), ("path B, M=6", "paper-b", 6, None),
             ("path B, M=8", "paper-b", 8, None)]
    assert [s[0] for s in specs] == BASE
    if args.extra:
        specs += [("path B, M=10, -20 dB", "paper-b", 10, -20.0)]
        specs += [(f"{s}-curve, M=10", f"{s}-curve", 10, None)
                  for s in ("shoebox", "l-room", "corridor", "pillar")]
    table: dict[str, Any] = {}
    entries: dict[str, tuple[str, Run, WallMap, WallMap]] = {}
    segments_of: dict[str, np.ndarray] = {}
    heatmaps: dict[str, list[Any]] = {}
    for label, path_name, m, snr in specs:
        tag = f"{path_name}_M{m}" + ("" if snr is None else f"_snr{snr:g}")
        if label not in BASE and not args.simulate_missing and not (CACHE / f"{tag}.npz").exists():
            print(f"skipping {label}: {tag} not simulated yet (use --simulate-missing)")
            continue
        run = simulated_run(path_name, m, snr, verbose=True)
        assert run.scene is not None
        segments = Scene.from_json(run.scene).segments()
        hms, paper, inverse, pruned, times = maps_for(run)
        heatmaps[label] = hms
        segments_of[label] = segments
        entries[label] = (label, run, paper, inverse)
        table[label] = {"run": {"path": path_name, "M": m, "snr_db": snr,
                                "blocks": run.n_blocks},
                        "paper": quality_row(paper, segments),
                        "inverse": quality_row(inverse, segments),
                        "inverse_pruned_0.05": quality_row(pruned, segments),
                        "timing_s": times}
        table[label]["ghost_ratio_paper_over_inverse"] = (
            table[label]["paper"]["ghost_energy"]
            / max(table[label]["inverse"]["ghost_energy"], 1e-12))
        print(f"{label}: paper {short(table[label]['paper'])} | "
              f"inverse {short(table[label]['inverse'])} | {times}", flush=True)
    paper_scene = segments_of["path A, M=10"]
    fig5(entries["path A, M=10"][1], heatmaps["path A, M=10"], entries["path B, M=10"][1],
         heatmaps["path B, M=10"], paper_scene)
    grid_figure("paper_fig6.png", "Fig. 6 analogue: path A vs path B",
                [entries["path A, M=10"], entries["path B, M=10"]], segments_of, table)
    grid_figure("paper_fig7.png", "Fig. 7 analogue: path B, M = 4, 6, 8, 10",
                [entries[f"path B, M={m}"] for m in (4, 6, 8, 10)], segments_of, table)
    if args.extra:
        extra = [entries[s[0]] for s in specs[5:] if s[0] in entries]
        if extra:
            grid_figure("paper_extra.png", "other scenes (curved paths) and -20 dB SNR", extra,
                        segments_of, table)
    ghost = {lbl: table[lbl]["paper"]["ghost_energy"] for lbl in table}
    claims = {
        "path_B_less_ghost_than_A": ghost["path B, M=10"] < ghost["path A, M=10"],
        "ghost_falls_with_M": [ghost[f"path B, M={m}"] for m in (4, 6, 8, 10)],
    }
    out = {"definitions": "see mapping/quality.py; thresholds are fractions of the 99th "
                          "percentile of the positive cells; tolerance 10 cm, ghost 20 cm",
           "claims_paper_method": claims, "maps": table}
    (RESULTS / "paper_figures.json").write_text(json.dumps(out, indent=2))
    print(json.dumps(claims, indent=2))


if __name__ == "__main__":
    main()
