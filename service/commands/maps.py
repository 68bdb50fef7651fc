"""``omnisonar`` subcommands for heat maps and wall maps: heatmap, build-map, evaluate-map.

Edges over :mod:`mapping.heatmap`, :mod:`mapping.build` and :mod:`mapping.quality`: they
read run and map files, write outputs and figures, print; no computation here.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mapping.files import atomic_savez
from service.commands.runs import resolve_scene

if TYPE_CHECKING:
    from mapping.scene import Scene


# ---- heatmap / demo (issue 2: the Doppler heat map, paper Sec. 2.1) ----------------------
def add_heatmap(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("heatmap", help="Doppler heat map of one block of a run file (eq. 1)")
    p.add_argument("run", help="run file (.npz)")
    p.add_argument("--block", type=int, required=True, help="block index K")
    p.add_argument("--bank", choices=("uniform_angle", "uniform_cos"), default="uniform_angle")
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


# ---- build-map / evaluate-map (issue 5) ---------------------------------------------------
def add_build_map(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("build-map", help="wall map G from tracked runs (paper Sec. 2.2)")
    p.add_argument("runs", nargs="+", metavar="RUN.npz", help="tracked run files")
    p.add_argument("--out", required=True, help="output map file (.npz, omnisonar-map-1)")
    p.add_argument("--method", choices=["paper", "inverse"], default="paper",
                   help="paper: eqs. 2-5 back-projection (default); inverse: NN-l1 inversion")
    p.add_argument("--literal", action="store_true",
                   help="paper method with eqs. 2-5 exactly as printed (reproduction)")
    p.add_argument("--resolution-m", type=float, default=0.05, help="cell size (m)")
    p.add_argument("--radius-m", type=float, default=6.0,
                   help="range used around each pose; the map grows by this around the runs")
    p.add_argument("--png", help="also write a PNG (true walls overlaid if the runs carry a scene)")
    p.add_argument("--pgm", help="also write ROS map_server PGM + YAML (FILE.pgm, FILE.yaml)")
    p.add_argument("--workers", type=int, default=1, help="worker processes")
    p.add_argument("--scheduler", help="dask.distributed scheduler address (extra 'cluster')")
    p.set_defaults(func=_cmd_build_map)


def _cmd_build_map(args: argparse.Namespace) -> int:
    import functools

    from tqdm import tqdm

    from mapping.build import BuildParams, RunSource, build_map
    from mapping.files import file_sha256, read_run, write_map, write_ros_map
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
          f" from {len(paths)} run(s); blocks used {prov['blocks_used']}, untracked skipped "
          f"{prov['blocks_untracked']}, unobservable skipped {prov['blocks_unobservable']}")
    if args.png:
        from service.plot import write_map_png

        scene = _scene_of_run(paths[0])
        write_map_png(Path(args.png), wm, segments=None if scene is None else scene.segments(),
                      title=f"{args.method} map from {len(paths)} run(s)")
        print(f"wrote {args.png}")
    if args.pgm:
        pgm, yaml = write_ros_map(Path(args.pgm), wm)
        print(f"wrote {pgm} and {yaml}")
    return 0


def _scene_of_run(path: Path) -> Scene | None:
    from mapping.scene import Scene

    with np.load(path, allow_pickle=False) as npz:
        return Scene.from_json(str(npz["scene"])) if "scene" in npz.files else None


def add_evaluate_map(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate-map", help="precision, recall, ghost energy of a map vs walls")
    p.add_argument("map", metavar="MAP.npz")
    p.add_argument("--scene", required=True, help="builtin:NAME or a scene JSON file")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--fractions", default="0.25,0.5,0.75",
                   help="strong-cell thresholds as fractions of the 99th percentile of G > 0")
    p.set_defaults(func=_cmd_evaluate_map)


def _cmd_evaluate_map(args: argparse.Namespace) -> int:
    import json

    from mapping.files import read_map
    from mapping.quality import evaluate

    try:
        fractions = tuple(float(f) for f in args.fractions.split(","))
    except ValueError:
        raise ValueError(f"--fractions must be comma-separated numbers, got {args.fractions!r}"
                         ) from None
    wm = read_map(args.map)
    q = evaluate(wm, resolve_scene(args.scene).segments(), fractions=fractions)
    if args.json:
        print(json.dumps({"map": str(args.map), "scene": args.scene, "method": wm.method,
                          **q.to_dict()}, indent=2))
        return 0
    print(f"{args.map} ({wm.method}) vs {args.scene}: ghost energy {q.ghost_energy:.3f} "
          f"(share of G farther than {q.ghost_m * 100:g} cm from any wall)")
    print(f"{'fraction':>8} {'threshold':>10} {'strong':>7} {'precision':>9} {'recall':>7} "
          f"{'chamfer_m':>9}")
    for a in q.at:
        print(f"{a.fraction:8.2f} {a.threshold:10.4g} {a.strong_cells:7d} {a.precision:9.3f} "
              f"{a.recall:7.3f} {a.chamfer_m:9.3f}")
    return 0
