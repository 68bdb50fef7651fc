"""``omnisonar`` subcommands for the HTTP service and the demos: serve, demo-api, demo.

``serve`` runs the localization service (:mod:`service.app` under uvicorn); ``demo-api``
streams a held-out run through it; ``demo`` is the main job end to end (a heat map next to
one wall, then the map and localization through the API). Edges; no computation here.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mapping.signal import SonarConfig


# ---- serve / demo-api (the HTTP service: service/app.py) ----------------------------------
def add_serve(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("serve", help="run the localization HTTP service (uvicorn)")
    p.add_argument("--maps", help="maps directory (default: $OMNISONAR_MAPS_DIR or var/maps)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on")
    p.add_argument("--port", type=int, default=8000, help="TCP port")
    p.add_argument("--log-level", default="info", help="uvicorn log level")
    p.add_argument("--insecure", action="store_true",
                   help="serve a non-loopback address without API keys (trusted networks "
                   "only; default: refuse)")
    p.set_defaults(func=_cmd_serve)


def _cmd_serve(args: argparse.Namespace) -> int:
    from service.server import serve

    try:
        serve(None if args.maps is None else Path(args.maps), args.host, args.port,
              args.log_level, args.insecure)
    except RuntimeError as exc:
        print(f"omnisonar serve: {exc}")
        return 2
    return 0


def add_demo_api(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo-api", help="start the service, stream a held-out run, stop it")
    p.add_argument("--out", default="out/demo-api", help="work directory (maps, sessions)")
    p.add_argument("--blocks", type=int, default=None, help="stream only the first N blocks")
    p.add_argument("--particles", type=int, default=2000, help="particles")
    p.add_argument("--global", dest="global_init", action="store_true",
                   help="start the filter globally instead of from the first true pose")
    p.set_defaults(func=_cmd_demo_api)


def _cmd_demo_api(args: argparse.Namespace) -> int:
    from service.demo_client import run_demo

    run_demo(Path(args.out), args.blocks, args.particles, args.global_init)
    return 0


def add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="the main job end to end: a heat map next to one wall, then the paper scene's "
        "default map and a held-out run localized through the HTTP API",
    )
    p.add_argument("--out", default="out/demo", help="output directory")
    p.add_argument("--heatmap-only", action="store_true", help="stop after the heat-map part")
    p.add_argument("--blocks", type=int, help="stream only the first N blocks of the run")
    p.add_argument("--particles", type=int, default=2000, help="particles")
    p.add_argument("--global", dest="global_init", action="store_true",
                   help="start the filter globally instead of from the first true pose")
    p.set_defaults(func=_cmd_demo)


def _cmd_demo(args: argparse.Namespace) -> int:
    import math

    from mapping.files import write_run
    from mapping.heatmap import find_peak, heatmap_of_run
    from mapping.synthetic import Wall, run_truth, synthetic_run
    from service.plot import write_heatmap_png

    out = Path(args.out)
    config = SonarConfig()
    wall, speed = Wall(distance_m=2.0, normal_angle_rad=math.radians(50.0)), 0.1
    print(f"demo: wall 2.00 m away, its normal 50.0 deg from travel, {speed} m/s, Table 1 "
          f"(M={config.repetitions}, N={config.directions}); analytic echo, 3 blocks")
    run = synthetic_run(config, wall, speed, n_blocks=3)
    hm = heatmap_of_run(run, 1)
    peak, truth = find_peak(hm), run_truth(run, 1)
    print(f"  detected: range {peak.range_m:.4f} m, angle {math.degrees(peak.angle_rad):.2f} deg")
    print(f"  truth:    range {truth.range_m:.4f} m, angle {math.degrees(truth.angle_rad):.2f} deg"
          f" (c tau / 2 at the block midpoint)")
    print(f"  error:    {1e3 * (peak.range_m - truth.range_m):+.2f} mm "
          f"(1 range sample = {1e3 * config.range_per_sample_m:.2f} mm), "
          f"{math.degrees(peak.angle_rad - truth.angle_rad):+.2f} deg "
          f"(half a bin = {90.0 / config.directions:.2f} deg)")
    png = write_heatmap_png(out / "heatmap.png", hm, title="demo: wall at 2 m, 50 deg, 0.1 m/s",
                            max_range_m=4.0, truth=(truth.range_m, truth.angle_rad))
    write_run(out / "demo_run.npz", run)
    print(f"wrote {png} and {out / 'demo_run.npz'}")
    if args.heatmap_only:
        return 0
    from service.demo_client import run_demo

    print("\ndemo, part 2: the main job through the HTTP API (map -> live localization)")
    run_demo(out / "api", args.blocks, args.particles, args.global_init)
    return 0
