"""The ``omnisonar`` command line: parses arguments, reads and writes files, prints.

Every subcommand is a thin edge over functions in ``mapping`` and ``localization``; no
computation lives here. Each subcommand is an ``_add_<name>(subparsers)`` function that
registers its parser and sets ``func`` to a ``_cmd_<name>(args) -> int`` handler.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mapping.atomicfile import atomic_savez, atomic_write
from mapping.signal import SonarConfig, tx_block

if TYPE_CHECKING:
    from mapping.path import Trajectory
    from mapping.scene import Scene


def _load_config(path: str | None) -> SonarConfig:
    """SonarConfig from a JSON file of fields, or the Table 1 defaults."""
    if path is None:
        return SonarConfig()
    return SonarConfig.from_json(Path(path).read_text())


# ---- signal ---------------------------------------------------------------------------
def _add_signal(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("signal", help="write one block of the transmitted signal as a WAV")
    p.add_argument("--config", help="SonarConfig JSON file (default: paper Table 1)")
    p.add_argument("--out", required=True, help="output WAV (float32, mono, at fs)")
    p.set_defaults(func=_cmd_signal)


def _cmd_signal(args: argparse.Namespace) -> int:
    from scipy.io import wavfile

    config = _load_config(args.config)
    block = tx_block(config).astype(np.float32)
    out = Path(args.out)
    atomic_write(out, lambda fh: wavfile.write(fh, int(config.fs_hz), block), private=False)
    print(
        f"wrote {out}: {block.size} samples at {config.fs_hz:g} Hz "
        f"({config.block_s:.4f} s, M={config.repetitions}, L={config.sequence_length})"
    )
    return 0


# ---- scenes, paths, recordings (issue 3) ------------------------------------------------
def resolve_scene(spec: str) -> Scene:
    """Scene from ``builtin:NAME`` or from the path of a scene JSON file."""
    from mapping.scene import Scene, builtin_scene

    if spec.startswith("builtin:"):
        return builtin_scene(spec.removeprefix("builtin:"))
    path = Path(spec)
    if not path.exists():
        raise FileNotFoundError(f"scene file {spec!r} not found (or use builtin:NAME)")
    try:
        return Scene.from_json(path.read_text())
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def resolve_path(spec: str, speed_m_s: float = 0.1) -> Trajectory:
    """Trajectory from ``builtin:NAME`` (see ``omnisonar scenes``)."""
    from mapping.path import builtin_path

    if not spec.startswith("builtin:"):
        raise ValueError(f"path must be builtin:NAME (see `omnisonar scenes`), got {spec!r}")
    return builtin_path(spec.removeprefix("builtin:"), speed_m_s=speed_m_s)


def _add_scenes(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("scenes", help="list the built-in scenes and paths")
    p.add_argument("--show", metavar="NAME", help="print the JSON of built-in scene NAME")
    p.set_defaults(func=_cmd_scenes)


def _cmd_scenes(args: argparse.Namespace) -> int:
    from mapping.path import (
        builtin_path,
        builtin_path_description,
        builtin_path_names,
        builtin_path_scene,
    )
    from mapping.scene import builtin_scene, builtin_scene_names

    if args.show:
        print(builtin_scene(args.show).to_json())
        return 0
    print("scenes (use as --scene builtin:NAME):")
    for name in builtin_scene_names():
        scene = builtin_scene(name)
        desc = scene.description if len(scene.description) < 90 else \
            scene.description[:87] + "..."
        print(f"  {name:10s} {len(scene.walls)} walls  {desc}")
    print("paths (use as --path builtin:NAME; 0.1 m/s, 1.023 s blocks):")
    for name in builtin_path_names():
        tr = builtin_path(name)
        print(f"  {name:18s} in {builtin_path_scene(name):9s} {tr.length_m:5.2f} m "
              f"{tr.duration_s:6.1f} s  {builtin_path_description(name)}")
    return 0


def _add_import_run(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import-run", help="real recording (WAV + pose CSV) -> run file")
    p.add_argument("--wav", required=True, help="mono WAV at the sonar rate, starting on a "
                   "transmission period boundary")
    p.add_argument("--poses", required=True,
                   help="CSV with columns t_s,x_m,y_m,heading_rad,speed_m_s")
    p.add_argument("--out", required=True, help="output run file (.npz)")
    p.add_argument("--config", help="SonarConfig JSON file (default: paper Table 1)")
    p.add_argument("--blocks", type=int, help="use only the first N blocks")
    p.set_defaults(func=_cmd_import_run)


def _cmd_import_run(args: argparse.Namespace) -> int:
    from mapping.recording import block_odometry, split_blocks
    from mapping.recordingfile import read_pose_csv, read_wav_mono
    from mapping.runfile import Run, write_run

    config = _load_config(args.config)
    samples = read_wav_mono(args.wav, config.fs_hz)
    try:
        blocks = split_blocks(samples, config.block_samples)
    except ValueError as exc:
        raise ValueError(f"{args.wav}: {exc}") from None
    if args.blocks is not None:
        if not 1 <= args.blocks <= blocks.shape[0]:
            raise ValueError(f"--blocks must be in 1..{blocks.shape[0]}, got {args.blocks}")
        blocks = blocks[: args.blocks]
    log = read_pose_csv(args.poses)
    try:
        odo = block_odometry(log, blocks.shape[0], config.block_s)
    except ValueError as exc:
        raise ValueError(f"{args.poses}: {exc} (shorten with --blocks)") from None
    run = Run(config=config, samples=blocks, t_s=odo.t_s, speed_m_s=odo.speed_m_s,
              yaw_rate_rad_s=odo.yaw_rate_rad_s, pose=odo.pose,
              meta={"source": "import-run", "wav": Path(args.wav).name,
                    "poses": Path(args.poses).name})
    out = write_run(args.out, run)
    dropped = samples.size - blocks.size
    print(f"wrote {out}: {run.n_blocks} blocks of {config.block_samples} samples "
          f"({dropped} trailing samples unused)")
    return 0


def _add_export_run(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export-run", help="run file -> WAV + pose CSV (block midpoints)")
    p.add_argument("run", help="run file (.npz)")
    p.add_argument("--wav", required=True, help="output WAV (float32, mono, at fs)")
    p.add_argument("--poses", required=True, help="output pose CSV, one row per tracked block")
    p.set_defaults(func=_cmd_export_run)


def _cmd_export_run(args: argparse.Namespace) -> int:
    from mapping.recording import join_blocks, pose_log_from_blocks
    from mapping.recordingfile import write_pose_csv, write_wav
    from mapping.runfile import read_run

    run = read_run(args.run)
    wav = write_wav(args.wav, join_blocks(run.samples), run.config.fs_hz)
    log = pose_log_from_blocks(run.t_s, run.pose, run.speed_m_s, run.config.block_s)
    csv_path = write_pose_csv(args.poses, log)
    print(f"wrote {wav} ({run.n_blocks} blocks) and {csv_path} ({log.t_s.size} poses)")
    return 0


# ---- posterior (issue 8: offline emcee study of the pose posterior) -----------------------
def _add_posterior(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("posterior", help="sample the pose posterior of a block window (emcee)")
    p.add_argument("run", help="run file (.npz)")
    p.add_argument("--map", required=True, help="wall map file (.npz)")
    p.add_argument("--blocks", required=True, help="A:B, blocks A..B-1 tied by odometry")
    p.add_argument("--walkers", type=int, default=32, help="walkers per mode (>= 6)")
    p.add_argument("--steps", type=int, default=1000, help="first batch of steps per mode")
    p.add_argument("--max-steps", type=int, default=20000, help="cap while reaching 50 tau")
    p.add_argument("--model", choices=("correlation", "range"), default="correlation")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True, help="output .npz (samples and diagnostics)")
    p.add_argument("--png", help="corner plot PNG")
    p.set_defaults(func=_cmd_posterior)


def _cmd_posterior(args: argparse.Namespace) -> int:
    import json

    from tqdm import tqdm

    from localization import posterior as post
    from localization.sensor import SensorConfig, build_tables
    from mapping.mapfile import read_map
    from mapping.runfile import read_run

    try:
        a, b = (int(v) for v in args.blocks.split(":"))
    except ValueError:
        raise ValueError(f"--blocks must be A:B with integers A < B, got {args.blocks!r}") from None
    settings = post.PosteriorSettings(n_walkers=args.walkers, n_steps=args.steps,
                                      max_steps=max(args.max_steps, args.steps))
    run = read_run(args.run)
    post.check_block_range(a, b, run.n_blocks)
    tables = build_tables(read_map(args.map), SensorConfig(model=args.model))
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
            f"{np.degrees(post.wrap_angle(m.mean[2] - truth[2])):+.1f} deg")
        print(f"mode {k}: mass {m.mass:.3f} at ({m.mean[0]:.3f}, {m.mean[1]:.3f}) m, "
              f"{np.degrees(m.mean[2]):.1f} deg; sd {np.sqrt(m.cov[0, 0]) * 100:.1f} / "
              f"{np.sqrt(m.cov[1, 1]) * 100:.1f} cm, {np.degrees(m.heading_circular_std_rad):.1f}"
              f" deg; tau {np.max(m.tau):.1f}, acceptance {m.acceptance_fraction:.2f}, "
              f"{m.n_steps} steps, {'converged' if m.converged else 'NOT converged'}{err}")
    print(f"wrote {args.out}" + (f" and {args.png}" if args.png else ""))
    return 0


# ---- serve / demo-api (the HTTP service: service/app.py) ----------------------------------
def _add_serve(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("serve", help="run the localization HTTP service (uvicorn)")
    p.add_argument("--maps", help="maps directory (default: $OMNISONAR_MAPS_DIR or var/maps)")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--log-level", default="info")
    p.set_defaults(func=_cmd_serve)


def _cmd_serve(args: argparse.Namespace) -> int:
    from service.server import serve

    serve(None if args.maps is None else Path(args.maps), args.host, args.port, args.log_level)
    return 0


def _add_demo_api(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo-api", help="start the service, stream a held-out run, stop it")
    p.add_argument("--out", default="out/demo-api", help="work directory (maps, sessions)")
    p.add_argument("--blocks", type=int, default=None, help="stream only the first N blocks")
    p.add_argument("--particles", type=int, default=2000)
    p.add_argument("--global", dest="global_init", action="store_true",
                   help="start the filter globally instead of from the first true pose")
    p.set_defaults(func=_cmd_demo_api)


def _cmd_demo_api(args: argparse.Namespace) -> int:
    from service.demo_client import run_demo

    run_demo(Path(args.out), args.blocks, args.particles, args.global_init)
    return 0


# ---- simulate (issue 3) ----------------------------------------------------------------
def _add_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="simulate a run of the sonar along a path in a scene")
    p.add_argument("--scene", required=True, help="builtin:NAME or a scene JSON file")
    p.add_argument("--path", required=True, help="built-in path NAME (or builtin:NAME)")
    p.add_argument("--engine", default="ism", help="forward model (default ism: image sources)")
    length = p.add_mutually_exclusive_group()
    length.add_argument("--blocks", type=int, help="number of 1.023 s blocks")
    length.add_argument("--duration", type=float, help="seconds to simulate (whole blocks)")
    p.add_argument("--snr-db", type=float, help="add white noise at this per-sample SNR")
    p.add_argument("--seed", type=int, default=0, help="random seed (noise, tail; default 0)")
    p.add_argument("--order", type=int, help="reflection order (default: automatic)")
    p.add_argument("--spreading", choices=["3d", "2d"], default="3d",
                   help="3d: 1/r point source (default); 2d: line source, as a 2-D FDTD")
    p.add_argument("--rt60", type=float, help="add a diffuse reverberant tail (seconds)")
    p.add_argument("--odometry-noise", type=float, default=0.0,
                   help="std of the recorded speed noise in m/s")
    p.add_argument("--speed", type=float, default=0.1, help="path speed in m/s (default 0.1)")
    p.add_argument("--config", help="SonarConfig JSON file (default: paper Table 1)")
    p.add_argument("--out", required=True, help="output run file (.npz)")
    fd = p.add_argument_group("--engine fdtd (issue 4)")
    fd.add_argument("--grid-step", type=float, default=0.005, help="FDTD dx in m (Table 2)")
    fd.add_argument("--time-step", type=float, default=1 / 120_000, help="FDTD dt in s")
    fd.add_argument("--float64", action="store_true", help="float64 fields (default float32)")
    fd.add_argument("--checkpoint-minutes", type=float, default=5.0,
                    help="write OUT.checkpoint.npz this often (default 5)")
    fd.add_argument("--resume", action="store_true", help="continue from OUT.checkpoint.npz")
    p.set_defaults(func=_cmd_simulate)


def _engine_config(args: argparse.Namespace) -> object:
    """Engine parameters from the command line (only the ISM has options here)."""
    from mapping.simulate import ENGINES, IsmConfig

    if args.engine not in ENGINES:
        raise ValueError(f"--engine must be one of {sorted(ENGINES)}, got {args.engine!r}")
    if args.engine == "ism":
        return IsmConfig(order=args.order, spreading=args.spreading, snr_db=args.snr_db,
                         odometry_noise_m_s=args.odometry_noise, rt60_s=args.rt60)
    return ENGINES[args.engine][0]()


def _cmd_simulate(args: argparse.Namespace) -> int:
    import math
    import time

    from tqdm import tqdm

    from mapping.runfile import write_run
    from mapping.simulate import assemble_run, iter_blocks, run_meta

    config = _load_config(args.config)
    scene = resolve_scene(args.scene)
    spec = args.path if args.path.startswith("builtin:") else f"builtin:{args.path}"
    trajectory = resolve_path(spec, speed_m_s=args.speed)
    if args.blocks is not None:
        n_blocks = args.blocks
    else:
        seconds = trajectory.duration_s if args.duration is None else args.duration
        n_blocks = max(1, math.ceil(seconds / config.block_s - 1e-9))
    if n_blocks < 1:
        raise ValueError(f"--blocks must be >= 1, got {n_blocks}")
    if args.engine == "fdtd":
        return _simulate_fdtd(args, scene, trajectory, config, n_blocks)
    engine = _engine_config(args)
    rng = np.random.default_rng(args.seed)
    start = time.perf_counter()
    blocks = []
    stream = iter_blocks(scene, trajectory, config, n_blocks, engine, rng)
    try:
        for block in tqdm(stream, total=n_blocks, unit="block", desc="simulate"):
            blocks.append(block)
    except KeyboardInterrupt:
        print(f"interrupted after {len(blocks)} blocks; nothing written", file=sys.stderr)
        return 130
    meta = run_meta(scene, trajectory, engine, args.seed, blocks)
    run = assemble_run(blocks, config, scene.to_json(), meta)
    out = write_run(args.out, run)
    elapsed = time.perf_counter() - start
    print(f"wrote {out}: {n_blocks} blocks ({n_blocks * config.block_s:.1f} s) of "
          f"{trajectory.name} in {scene.name}, engine {meta['engine']}, order "
          f"{meta.get('order')}, {elapsed:.1f} s")
    return 0


def _simulate_fdtd(args: argparse.Namespace, scene: object, trajectory: object,
                   config: SonarConfig, n_blocks: int) -> int:
    """``simulate --engine fdtd``: set-up report, progress with ETA, atomic checkpoints every
    ``--checkpoint-minutes`` (and on Ctrl-C), ``--resume``; the run file is written last."""
    import time

    from tqdm import tqdm

    from mapping.runfile import write_run
    from mapping.simulate.base import assemble_run
    from mapping.simulate.fdtd import (
        FdtdConfig,
        default_chunk_steps,
        finished_blocks,
        iter_fdtd,
        new_state,
        restore_state,
        run_meta,
        setup_fingerprint,
        setup_for_scene,
    )

    fdtd = FdtdConfig(grid_step_m=args.grid_step, time_step_s=args.time_step,
                      dtype="float64" if args.float64 else "float32")
    setup = setup_for_scene(scene, trajectory, config, fdtd, n_blocks)  # type: ignore[arg-type]
    for line in setup.report.lines():
        print(line)
    out = Path(args.out)
    ckpt = out.with_name(out.name + ".checkpoint.npz")
    tag = setup_fingerprint(setup)
    state = new_state(setup)
    if args.resume and ckpt.exists():
        with np.load(ckpt, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
        if str(arrays.get("fingerprint")) != tag:
            raise ValueError(f"{ckpt} belongs to a different set-up; delete it or drop --resume")
        state = restore_state(setup, arrays)
        print(f"resumed at step {state.step} of {setup.n_steps}")

    def save() -> None:
        atomic_savez(ckpt, {**state.to_arrays(), "fingerprint": np.array(tag)})

    last = time.monotonic()
    try:
        with tqdm(total=setup.n_steps, initial=state.step, unit="step", desc="fdtd") as bar:
            for progress in iter_fdtd(setup, state, default_chunk_steps(setup)):
                bar.update(progress.steps_done - bar.n)
                if time.monotonic() - last > 60 * args.checkpoint_minutes:
                    save()
                    last = time.monotonic()
    except KeyboardInterrupt:
        save()
        print(f"interrupted at step {state.step}; checkpoint {ckpt}; rerun with --resume",
              file=sys.stderr)
        return 130
    run = assemble_run(finished_blocks(setup, state), config,
                       scene.to_json(), run_meta(setup))  # type: ignore[attr-defined]
    written = write_run(out, run)
    ckpt.unlink(missing_ok=True)
    print(f"wrote {written}: {n_blocks} blocks, engine fdtd, grid {setup.grid.shape}")
    return 0


# ---- heatmap / demo (issue 2: the Doppler heat map, paper Sec. 2.1) ----------------------
def _add_heatmap(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("heatmap", help="Doppler heat map of one block of a run file (eq. 1)")
    p.add_argument("run", help="run file (.npz)")
    p.add_argument("--block", type=int, required=True, help="block index K")
    p.add_argument("--bank", choices=("uniform_angle", "uniform_cos"), default="uniform_angle")
    p.add_argument("--png", help="polar heat-map PNG")
    p.add_argument("--out", help="output .npz: H, angles_rad, ranges_m, speed_m_s, "
                                 "direction_observable")
    p.set_defaults(func=_cmd_heatmap)


def _cmd_heatmap(args: argparse.Namespace) -> int:
    from mapping.heatmap import find_peak, heatmap_of_run
    from mapping.runfile import read_run

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


def _add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="the main job end to end: a heat map next to one wall, then the paper scene's "
        "default map and a held-out run localized through the HTTP API",
    )
    p.add_argument("--out", default="out/demo", help="output directory (default out/demo)")
    p.add_argument("--heatmap-only", action="store_true", help="stop after the heat-map part")
    p.add_argument("--blocks", type=int, help="stream only the first N blocks of the run")
    p.add_argument("--particles", type=int, default=2000, help="particles (default 2000)")
    p.add_argument("--global", dest="global_init", action="store_true",
                   help="start the filter globally instead of from the first true pose")
    p.set_defaults(func=_cmd_demo)


def _cmd_demo(args: argparse.Namespace) -> int:
    import math

    from mapping.heatmap import find_peak, heatmap_of_run
    from mapping.runfile import write_run
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


# ---- build-map / evaluate-map (issue 5) ---------------------------------------------------
def _add_build_map(sub: argparse._SubParsersAction) -> None:
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
    from mapping.grid import GridParams
    from mapping.mapfile import file_sha256, write_map, write_ros_map
    from mapping.runfile import read_run

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


def _add_evaluate_map(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate-map", help="precision, recall, ghost energy of a map vs walls")
    p.add_argument("map", metavar="MAP.npz")
    p.add_argument("--scene", required=True, help="builtin:NAME or a scene JSON file")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--fractions", default="0.25,0.5,0.75",
                   help="strong-cell thresholds as fractions of the 99th percentile of G > 0")
    p.set_defaults(func=_cmd_evaluate_map)


def _cmd_evaluate_map(args: argparse.Namespace) -> int:
    import json

    from mapping.mapfile import read_map
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


# ---- localize (issue 6) ---------------------------------------------------------------
def _add_localize(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("localize", help="localize a run on a wall map (paper Fig. 1(b))")
    p.add_argument("run", metavar="RUN.npz", help="run file to localize")
    p.add_argument("--map", required=True, metavar="MAP.npz", help="wall map (omnisonar-map-1)")
    p.add_argument("--filter", choices=("pf", "grid"), default="pf",
                   help="particle filter (default) or exact grid filter")
    p.add_argument("--particles", type=int, default=2000, help="particle count (pf)")
    p.add_argument("--init", choices=("global", "tracked"), default="global",
                   help="global (uniform over free space) or the run's first tracked pose")
    p.add_argument("--model", choices=("correlation", "range"), default="correlation",
                   help="sensor model")
    p.add_argument("--seed", type=int, default=0, help="random seed (pf)")
    p.add_argument("--out", help="write the track as CSV")
    p.add_argument("--json", action="store_true", help="print a JSON summary instead of a table")
    p.set_defaults(func=_cmd_localize)


def _cmd_localize(args: argparse.Namespace) -> int:
    import dataclasses
    import json
    import math

    from localization.estimate import pose_error, track_metrics
    from localization.grid_filter import GridFilter
    from localization.particle_filter import FilterConfig, ParticleFilter, Steppable, run_filter
    from localization.sensor import SensorConfig, build_tables, validate_block
    from mapping.heatmap import heatmap_of_run
    from mapping.mapfile import read_map
    from mapping.runfile import read_run

    if args.particles < 1:
        raise ValueError(f"--particles must be >= 1, got {args.particles}")
    wall_map, run = read_map(args.map), read_run(args.run)
    tables = build_tables(wall_map, SensorConfig(model=args.model))
    tracked = np.asarray(np.isfinite(run.pose).all(axis=1), dtype=bool)
    if args.init == "tracked" and not tracked[0]:
        raise ValueError("--init tracked needs a tracked pose in the run's first block")
    pose0 = run.pose[0] if args.init == "tracked" else None
    cov0 = np.diag([0.1**2, 0.1**2, math.radians(10.0) ** 2])
    filt: Steppable
    if args.filter == "grid":
        filt = GridFilter(tables, pose=pose0, cov=cov0)
    else:
        filt = ParticleFilter(tables, FilterConfig(n_particles=args.particles),
                              np.random.default_rng(args.seed), pose=pose0, cov=cov0)

    def heat_maps():  # type: ignore[no-untyped-def]
        for k in range(run.n_blocks):
            try:
                validate_block(run.samples[k], run.config.block_samples)
            except ValueError as exc:
                print(f"block {k}: {exc}; predicting only", file=sys.stderr)
                yield None
                continue
            yield heatmap_of_run(run, k)

    rows, poses, covs = [], [], []
    if not args.json:
        print("block      x_m      y_m  yaw_deg  sx_m  sy_m syaw_deg    ess conv modes"
              "  err_m err_deg")
    for k, est in enumerate(run_filter(filt, heat_maps(), run.speed_m_s, run.yaw_rate_rad_s,
                                       run.t_s, run.config.block_s)):
        sd = np.sqrt(np.clip(np.diag(est.cov), 0.0, None))
        err = pose_error(est.pose, run.pose[k]) if tracked[k] else (math.nan, math.nan)
        rows.append([k, *est.pose, *sd, est.ess, int(est.converged), len(est.modes),
                     int(est.direction_observable), *err])
        poses.append(est.pose)
        covs.append(est.cov)
        if not args.json:
            print(f"{k:5d} {est.pose[0]:8.3f} {est.pose[1]:8.3f} {math.degrees(est.pose[2]):8.1f}"
                  f" {sd[0]:5.3f} {sd[1]:5.3f} {math.degrees(sd[2]):8.1f} {est.ess:6.0f}"
                  f" {int(est.converged):4d} {len(est.modes):5d} {err[0]:6.3f}"
                  f" {math.degrees(err[1]):7.1f}")
    summary: dict[str, Any] = {"run": args.run, "map": args.map, "filter": args.filter,
                                  "init": args.init, "model": args.model,
                                  "n_blocks": run.n_blocks}
    if tracked.any():
        m = track_metrics(np.array(poses), np.array(covs), run.pose)
        summary.update(dataclasses.asdict(m))
        summary["heading_rmse_deg"] = math.degrees(m.heading_rmse_rad)
    if args.out:
        header = ("block,x_m,y_m,yaw_rad,std_x_m,std_y_m,std_yaw_rad,ess,converged,n_modes,"
                  "direction_observable,err_m,err_rad")
        atomic_write(Path(args.out), lambda fh: np.savetxt(
            fh, np.array(rows, dtype=np.float64), delimiter=",", header=header, comments="",
            fmt="%.6g"), private=False)
    if args.json:
        print(json.dumps(summary, indent=2, default=float))
    elif tracked.any():
        print(f"blocks to converge: {summary['blocks_to_converge']}; after convergence "
              f"position RMSE {float(summary['position_rmse_m']) * 100:.1f} cm, heading RMSE "
              f"{float(summary['heading_rmse_deg']):.1f} deg; within 10 cm: "
              f"{float(summary['share_within_tol']) * 100:.0f} % of blocks")
    if args.out:
        print(f"wrote {args.out}", file=sys.stderr if args.json else sys.stdout)
    return 0


_COMMANDS: list[Callable[[argparse._SubParsersAction], None]] = [
    _add_scenes,
    _add_import_run,
    _add_export_run,
    _add_signal,
    _add_simulate,
    _add_serve,
    _add_demo_api,
    _add_posterior,
    _add_heatmap,
    _add_demo,
    _add_build_map,
    _add_evaluate_map,
    _add_localize,
]


def build_parser() -> argparse.ArgumentParser:
    """The ``omnisonar`` argument parser with every subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="omnisonar",
        description="Doppler direction-of-arrival sonar: simulate, map, localize, serve.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for add in _COMMANDS:
        add(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``omnisonar`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (ValueError, FileNotFoundError) as exc:
        print(f"omnisonar {args.command}: error: {exc}", file=sys.stderr)
        return 2
