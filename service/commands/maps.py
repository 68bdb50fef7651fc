"""``omnisonar`` subcommands for heat maps and wall maps: heatmap, build-map, evaluate-map.

Edges over :mod:`mapping.heatmap`, :mod:`mapping.build` and :mod:`mapping.quality`: they
read run and map files, write outputs (map, PNG, PGM/YAML, GeoJSON) and figures, print; no
computation here.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mapping.files import atomic_savez
from service.commands.runs import resolve_scene
from service.jsonout import strict_json

if TYPE_CHECKING:
    from mapping.quality import MapReport
    from mapping.scene import Scene
    from mapping.wallmap import WallMap


# ---- heatmap / demo (issue 2: the Doppler heat map, paper Sec. 2.1) ----------------------
def add_heatmap(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("heatmap", help="Doppler heat map of one block of a run file (eq. 1)")
    p.add_argument("run", help="run file (.npz)")
    p.add_argument("--block", type=int, required=True, help="block index K")
    p.add_argument("--bank", choices=("uniform_angle", "uniform_cos"), default="uniform_angle",
                   help="direction bank (default: %(default)s)")
    p.add_argument("--png", help="polar heat-map PNG")
    p.add_argument("--out", help="output .npz: H, angles_rad, ranges_m, speed_m_s, "
                                 "direction_observable")
    p.set_defaults(func=_cmd_heatmap)


def _cmd_heatmap(args: argparse.Namespace) -> int:
    from mapping.files import read_run
    from mapping.heatmap import find_peak, heatmap_of_run

    run = read_run(args.run)
    hm = heatmap_of_run(run, args.block, bank=args.bank)
    peak = find_peak(hm)
    print(f"block {args.block}: speed {hm.speed_m_s:.3f} m/s, strongest echo "
          f"{peak.range_m:.3f} m at {np.degrees(peak.angle_rad):.1f} deg from travel"
          + ("" if hm.direction_observable else " (direction NOT observable: speed too low)"))
    if args.out:
        atomic_savez(Path(args.out), {
            "H": hm.H, "angles_rad": hm.angles_rad, "ranges_m": hm.ranges_m,
            "speed_m_s": np.float64(hm.speed_m_s),
            "direction_observable": np.bool_(hm.direction_observable)})
        print(f"wrote {args.out}")
    if args.png:
        from service.plot import write_heatmap_png

        write_heatmap_png(Path(args.png), hm, title=f"{Path(args.run).name} block {args.block}")
        print(f"wrote {args.png}")
    return 0


# ---- build-map / evaluate-map (issues 5, 13) ------------------------------------------------
def add_build_map(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("build-map", help="wall map from tracked runs: fitted walls (default) or G "
                                         "(paper Sec. 2.2)")
    p.add_argument("runs", nargs="+", metavar="RUN.npz", help="tracked run files")
    p.add_argument("--out", required=True, help="output map file (.npz, omnisonar-map-2)")
    p.add_argument("--method", choices=["walls", "paper", "inverse"], default="walls",
                   help="walls: wall segments fitted with the specular forward model; paper: "
                        "eqs. 2-5 back-projection; inverse: NN-l1 inversion "
                        "(default: %(default)s)")
    p.add_argument("--literal", action="store_true",
                   help="paper method with eqs. 2-5 exactly as printed (reproduction)")
    p.add_argument("--resolution-m", type=float, default=0.05,
                   help="cell size in metres (default: %(default)s)")
    p.add_argument("--radius-m", type=float, default=6.0,
                   help="range used around each pose; the map grows by this around the runs "
                        "(default: %(default)s)")
    p.add_argument("--png", help="also write a PNG: G with the fitted walls, the coverage "
                                 "boundary and, if the runs carry a scene, the true walls")
    p.add_argument("--pgm", help="also write ROS map_server PGM + YAML (FILE.pgm, FILE.yaml); "
                                 "rasterized from the walls when the map has walls")
    p.add_argument("--geojson", help="also write the fitted walls as GeoJSON (map frame, metres)")
    p.add_argument("--workers", type=int, default=1,
                   help="worker processes (default: %(default)s)")
    p.add_argument("--scheduler", help="dask.distributed scheduler address (extra 'cluster')")
    p.set_defaults(func=_cmd_build_map)


def _cmd_build_map(args: argparse.Namespace) -> int:
    import functools

    from tqdm import tqdm

    from mapping.build import BuildParams, RunSource, build_map
    from mapping.files import file_sha256, read_run, write_geojson, write_map, write_ros_map
    from mapping.grid import GridParams

    paths = [Path(r) for r in args.runs]
    configs = {}
    for path in paths:  # refuse mixed configs before any work
        if not path.exists():
            raise FileNotFoundError(f"run file {path} not found")
        with np.load(path, allow_pickle=False) as npz:
            configs[path] = str(npz["sonar"]) if "sonar" in npz.files else ""
    first = paths[0]
    for path in paths[1:]:
        if configs[path] != configs[first]:
            raise ValueError(f"runs have different sonar configs and cannot share one map: "
                             f"{path} differs from {first}")
    sources = [RunSource(functools.partial(read_run, p), str(p), file_sha256(p)) for p in paths]
    grid = GridParams(resolution_m=args.resolution_m, radius_m=args.radius_m,
                      literal=args.literal)
    params = BuildParams(method=args.method, grid=grid)
    with tqdm(total=len(sources), unit="run", desc=f"build-map ({args.method})") as bar:
        wm = build_map(sources, params, workers=args.workers, scheduler=args.scheduler,
                       progress=lambda _r: bar.update(1))
    write_map(Path(args.out), wm)
    prov = wm.provenance
    print(f"wrote {args.out}: {wm.shape[1]} x {wm.shape[0]} cells of {wm.resolution_m * 1000:g} mm"
          f", {wm.n_walls} wall(s) ({int(wm.wall_ambiguous.sum())} ambiguous), "
          f"{wm.coverage.mean():.0%} of cells observed, from {len(paths)} run(s); blocks used "
          f"{prov['blocks_used']}, untracked skipped {prov['blocks_untracked']}, unobservable "
          f"skipped {prov['blocks_unobservable']}")
    fit = prov.get("fit", {})
    if fit:
        print(f"walls explain {fit['explained_share']:.0%} of the echo energy heard")
        es = wm.wall_end_sigma
        n_open = int(np.sum(es >= params.walls.open_end_sigma_m)) if np.isfinite(es).any() else 0
        if n_open:
            print(f"{n_open} wall end(s) open: the runs never looked past them, the wall may "
                  "go on (localization runs them on)")
        if fit.get("warning"):
            print(f"warning: {fit['warning']}", file=sys.stderr)
    if args.png:
        from service.plot import write_map_png

        scene = _scene_of_run(paths[0])
        write_map_png(Path(args.png), wm, segments=None if scene is None else scene.segments(),
                      title=f"{args.method} map from {len(paths)} run(s)")
        print(f"wrote {args.png}")
    if args.pgm:
        pgm, yaml = write_ros_map(Path(args.pgm), wm)
        print(f"wrote {pgm} and {yaml}")
    if args.geojson:
        print(f"wrote {write_geojson(Path(args.geojson), wm)}")
    return 0


def _scene_of_run(path: Path) -> Scene | None:
    """The scene embedded in a run file; None (with a warning on stderr) when it cannot be
    parsed, so a figure is still drawn, without the true walls."""
    from mapping.scene import Scene

    with np.load(path, allow_pickle=False) as npz:
        text = str(npz["scene"]) if "scene" in npz.files else None
    if text is None:
        return None
    try:
        return Scene.from_json(text)
    except ValueError as exc:
        print(f"omnisonar build-map: warning: {path}: cannot parse the embedded scene, the PNG "
              f"shows no true walls ({exc})", file=sys.stderr)
        return None


def add_evaluate_map(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate-map", help="wall-level and raster precision/recall of a map vs "
                                            "the true walls, scored on what the runs observed")
    p.add_argument("map", metavar="MAP.npz")
    p.add_argument("--scene", required=True, help="builtin:NAME or a scene JSON file")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.add_argument("--tol-m", type=float, default=0.10,
                   help="distance within which a point counts as on a wall (default: "
                        "%(default)s)")
    p.add_argument("--share", type=float, default=0.8,
                   help="share of a wall that must lie within --tol-m: of a true wall's observed "
                        "part to be found, of a fitted wall to be true (default: %(default)s)")
    p.add_argument("--fraction-of-max", type=float, default=0.2,
                   help="raster strong-cell threshold as a fraction of max(G) "
                        "(default: %(default)s)")
    p.add_argument("--p99-fractions", "--fractions", dest="p99_fractions",
                   default="0.25,0.5,0.75",
                   help="the older figures: strong-cell thresholds as fractions of the 99th "
                        "percentile of G > 0, whole map (default: %(default)s)")
    p.set_defaults(func=_cmd_evaluate_map)


def _cmd_evaluate_map(args: argparse.Namespace) -> int:

    from mapping.files import read_map
    from mapping.quality import evaluate_map

    try:
        fractions = tuple(float(f) for f in args.p99_fractions.split(","))
    except ValueError:
        raise ValueError(f"--p99-fractions must be comma-separated numbers, got "
                         f"{args.p99_fractions!r}") from None
    wm = read_map(args.map)
    report = evaluate_map(wm, resolve_scene(args.scene).segments(), tol_m=args.tol_m,
                          share=args.share, fraction_of_max=args.fraction_of_max,
                          p99_fractions=fractions)
    if args.json:
        print(strict_json({"map": str(args.map), "scene": args.scene, "method": wm.method,
                           **report.to_dict()}, indent=2))
        return 0
    for line in _report_lines(args, wm, report):
        print(line)
    return 0


def _report_lines(args: argparse.Namespace, wm: WallMap, report: MapReport) -> list[str]:
    w, r, p = report.walls, report.raster, report.fraction_of_p99
    tol_cm = w.tol_m * 100
    lines = [f"{args.map} ({wm.method}) vs {args.scene}: scored inside the map's coverage "
             f"({r.observed_cells} of {wm.G.size} cells observed, holding "
             f"{r.observed_wall_share:.0%} of the true wall length)"]
    if w.n_fitted == 0:
        lines.append("walls:  the map has no fitted walls (grid method): no wall-level figures")
    else:
        lines += [
            f"walls:  precision {_num(w.precision)} ({w.n_fitted - w.n_false - w.n_ambiguous} of "
            f"{w.n_fitted - w.n_ambiguous} fitted walls within {tol_cm:g} cm over "
            f">= {w.share:.0%} of their length; {w.n_ambiguous} ambiguous mirror(s) not "
            f"counted)",
            f"        recall {_num(w.recall)} ({w.n_found} of {w.n_true_observed} observed true "
            f"walls found; {len(w.unobserved)} never observed)",
            f"        angle error max {_num(w.angle_error_deg_max, '.2f')} deg, endpoint error "
            f"max {_num(w.endpoint_error_m_max)} m (ends the runs observed)",
            f"        missed true walls {list(w.missed)}, false fitted walls "
            f"{list(w.false_walls)}, ambiguous mirrors {list(w.ambiguous)}",
        ]
    lines += [
        f"raster: cells >= {r.fraction:g} x max(G) inside coverage: precision "
        f"{_num(r.precision)}, recall {_num(r.recall)} ({r.strong_cells} strong cells, "
        f"tolerance {r.tol_m * 100:g} cm)",
        f"fraction_of_p99 (thresholds relative to the 99th percentile of G > 0 over the whole "
        f"map, recall over all wall length: ranks maps, does not say how good one is); ghost "
        f"energy {p.ghost_energy:.3f} (share of G farther than {p.ghost_m * 100:g} cm from "
        f"any wall)",
        f"{'fraction':>8} {'threshold':>10} {'strong':>7} {'precision':>9} {'recall':>7} "
        f"{'chamfer_m':>9}",
    ]
    lines += [f"{a.fraction:8.2f} {a.threshold:10.4g} {a.strong_cells:7d} {a.precision:9.3f} "
              f"{a.recall:7.3f} {a.chamfer_m:9.3f}" for a in p.at]
    return lines


def _num(value: float, fmt: str = ".3f") -> str:
    return "n/a" if value != value else format(value, fmt)
