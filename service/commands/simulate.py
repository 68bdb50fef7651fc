"""``omnisonar simulate``: a run of the sonar along a path in a scene (image sources or FDTD).

The FDTD engine gets a set-up report, a progress bar with ETA, atomic checkpoints and
``--resume``. ``--raw-wav`` / ``--raw-poses`` write what a real robot's sound card would record
instead (:mod:`mapping.simulate.raw`: sound-card rate, latency, clock offset, direct wave,
floor and ceiling, band-passes, temperature). An edge over :mod:`mapping.simulate`; no
computation here.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from mapping.files import atomic_savez
from mapping.signal import SonarConfig
from mapping.simulate import SceneLike, TrajectoryLike
from mapping.simulate.raw import RawConfig
from service.commands.runs import _load_config, resolve_path, resolve_scene


# ---- simulate (issue 3) ----------------------------------------------------------------
def add_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="simulate a run of the sonar along a path in a scene")
    p.add_argument("--scene", required=True, help="builtin:NAME or a scene JSON file")
    p.add_argument("--path", required=True, help="built-in path NAME (or builtin:NAME)")
    p.add_argument("--engine", default="ism", help="forward model: ism (image sources) or fdtd")
    length = p.add_mutually_exclusive_group()
    length.add_argument("--blocks", type=int, help="number of 1.023 s blocks")
    length.add_argument("--duration", type=float, help="seconds to simulate (whole blocks)")
    p.add_argument("--snr-db", type=float, help="add white noise at this per-sample SNR")
    p.add_argument("--seed", type=int, default=0, help="random seed (noise, tail)")
    p.add_argument("--order", type=int, help="reflection order (default: automatic)")
    p.add_argument("--spreading", choices=["3d", "2d"], default="3d",
                   help="3d: 1/r point source; 2d: line source, as a 2-D FDTD")
    p.add_argument("--rt60", type=float, help="add a diffuse reverberant tail (seconds)")
    p.add_argument("--odometry-noise", type=float, default=0.0,
                   help="std of the recorded speed noise in m/s")
    p.add_argument("--speed", type=float, default=0.1, help="path speed in m/s")
    p.add_argument("--config", help="SonarConfig JSON file (default: paper Table 1)")
    p.add_argument("--out", help="output run file (.npz); with --raw-wav optional: the clean run "
                   "of the same drive, for comparison")
    fd = p.add_argument_group("--engine fdtd (issue 4)")
    fd.add_argument("--grid-step", type=float, default=0.005, help="FDTD dx in m (Table 2)")
    fd.add_argument("--time-step", type=float, default=1 / 120_000, help="FDTD dt in s")
    fd.add_argument("--float64", action="store_true", help="float64 fields (default float32)")
    fd.add_argument("--checkpoint-minutes", type=float, default=5.0,
                    help="write OUT.checkpoint.npz this often")
    fd.add_argument("--resume", action="store_true", help="continue from OUT.checkpoint.npz")
    _add_raw_options(p)
    p.set_defaults(func=_cmd_simulate)


#: ``--raw-all``: realistic values for every effect (each option given explicitly wins).
RAW_ALL = dict(rate=48_000.0, latency=0.037, clock_ppm=60.0, offset=0.05, sonar_height=0.3,
               ceiling_height=2.6, vertical_order=2, band=True, temperature=22.0,
               body_echo=[[0.3, 0.3]])


def _add_raw_options(p: argparse.ArgumentParser) -> None:
    raw = p.add_argument_group("raw recording (issue 16): what a sound card records")
    raw.add_argument("--raw-wav", help="write the raw microphone recording (float32 WAV)")
    raw.add_argument("--raw-poses", help="write its pose log CSV (times on the recording clock)")
    raw.add_argument("--raw-all", action="store_true",
                     help="every effect on at realistic values: 48 kHz, 37 ms latency, +60 ppm, "
                          "5 cm offset, sonar 0.3 m, ceiling 2.6 m with wall combinations, "
                          "speaker 1.5-18 kHz and mic 50 Hz-19 kHz, 22 C, a body echo "
                          "(0.3 m path, 0.3)")
    raw.add_argument("--rate", type=float, help="sound-card rate in Hz (default 48000)")
    raw.add_argument("--latency", type=float, help="recording start to playback start, s")
    raw.add_argument("--clock-ppm", type=float, help="recording clock rate offset, ppm")
    raw.add_argument("--offset", type=float, help="loudspeaker-microphone distance in m "
                     "(the direct wave)")
    raw.add_argument("--sonar-height", type=float, help="sonar height above the floor, m")
    raw.add_argument("--ceiling-height", type=float, help="ceiling height, m")
    raw.add_argument("--vertical-order", type=int, choices=[1, 2],
                     help="1: floor/ceiling bounces alone; 2: also combined with wall paths")
    raw.add_argument("--band", action="store_true",
                     help="speaker 1.5-18 kHz and microphone 50 Hz-19 kHz band-passes")
    raw.add_argument("--temperature", type=float,
                     help="air temperature in C (sound speed 331.3 sqrt(1 + T/273.15) m/s)")
    raw.add_argument("--full-scale", type=float, help="clip the recording at +-this")
    raw.add_argument("--body-echo", type=float, nargs=2, action="append",
                     metavar=("PATH_M", "REFLECTION"),
                     help="an echo off the robot's body: loudspeaker-body-microphone path and "
                     "reflection (repeat for more)")


def raw_config(args: argparse.Namespace) -> RawConfig:
    """The :class:`~mapping.simulate.raw.RawConfig` of the command line (``--raw-all``
    supplies every option not given)."""
    opt: dict[str, Any] = dict(RAW_ALL) if args.raw_all else {}
    opt.update({k: getattr(args, k) for k in RAW_ALL if getattr(args, k) not in (None, False)})
    bands = bool(opt.get("band", False))
    return RawConfig(
        fs_hz=float(opt.get("rate", 48_000.0)),
        latency_s=float(opt.get("latency", 0.0)),
        clock_offset_ppm=float(opt.get("clock_ppm", 0.0)),
        transducer_offset_m=opt.get("offset"),
        sonar_height_m=opt.get("sonar_height"),
        ceiling_height_m=opt.get("ceiling_height"),
        vertical_order=int(opt.get("vertical_order", 1)),
        speaker_band_hz=(1_500.0, 18_000.0) if bands else None,
        mic_band_hz=(50.0, 19_000.0) if bands else None,
        temperature_c=opt.get("temperature"),
        snr_db=args.snr_db,
        full_scale=args.full_scale,
        body_echoes=tuple((float(p), float(r)) for p, r in opt.get("body_echo") or ()),
    )


def _engine_config(args: argparse.Namespace) -> object:
    """Engine parameters from the command line (only the ISM has options here)."""
    from mapping.simulate import ENGINES
    from mapping.simulate.ism import IsmConfig

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

    from mapping.files import write_run
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
    if args.raw_wav is None and args.raw_poses is None and args.out is None:
        raise ValueError("give --out RUN.npz, or --raw-wav and --raw-poses")
    if (args.raw_wav is None) != (args.raw_poses is None):
        raise ValueError("--raw-wav and --raw-poses go together")
    if args.raw_wav is not None:
        return _simulate_raw(args, scene, trajectory, config, n_blocks * config.block_s)
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


def _simulate_raw(args: argparse.Namespace, scene: SceneLike, trajectory: TrajectoryLike,
                  config: SonarConfig, sonar_s: float) -> int:
    """``simulate --raw-wav W --raw-poses P``: the raw recording of ``sonar_s`` seconds of the
    drive (plus the latency), its pose log, and with ``--out`` the clean run for comparison."""
    import dataclasses
    import math
    import time

    from tqdm import tqdm

    from mapping.files import write_pose_csv, write_wav
    from mapping.simulate.ism import IsmConfig
    from mapping.simulate.raw import assemble_raw, iter_raw_chunks

    if args.engine != "ism":
        raise ValueError("--raw-wav needs --engine ism")
    raw = raw_config(args)
    engine = IsmConfig(order=args.order, rt60_s=args.rt60)
    start = time.perf_counter()
    duration = (sonar_s + raw.latency_s) * (1 + raw.clock_offset_ppm * 1e-6)
    stream = iter_raw_chunks(scene, trajectory, config, duration, engine, raw,
                             np.random.default_rng(args.seed))
    chunks = list(tqdm(stream, total=math.ceil(duration), unit="s", desc="simulate raw"))
    rec = assemble_raw(chunks, trajectory, config, duration, raw)
    write_wav(args.raw_wav, rec.samples, rec.fs_hz)
    write_pose_csv(args.raw_poses, rec.poses)
    t = rec.truth
    direct = "none" if t.direct_delay_s is None else f"{t.direct_delay_s * 1e3:.3f} ms"
    print(f"wrote {args.raw_wav} ({rec.samples.size} samples at {rec.fs_hz:g} Hz, "
          f"{rec.samples.size / rec.fs_hz:.2f} s) and {args.raw_poses} ({rec.poses.t_s.size} rows)")
    print(f"truth: latency {t.latency_s * 1e3:.3f} ms (onset sample {t.onset_sample}), clock "
          f"{t.clock_offset_ppm:+g} ppm, sound speed {t.sound_speed_m_s:.2f} m/s (config "
          f"{config.sound_speed_m_s:g}), direct wave {direct}, clipped {t.clipped_samples}; "
          f"{time.perf_counter() - start:.1f} s")
    if args.out is not None:
        from mapping.files import write_run
        from mapping.simulate import simulate_run

        n_blocks = max(1, round(sonar_s / config.block_s))
        clean_engine = dataclasses.replace(engine, snr_db=args.snr_db)
        run = simulate_run(scene, trajectory, config, n_blocks, clean_engine,
                           np.random.default_rng(args.seed))
        print(f"wrote {write_run(args.out, run)}: the clean run ({n_blocks} blocks)")
    return 0


def _simulate_fdtd(args: argparse.Namespace, scene: object, trajectory: object,
                   config: SonarConfig, n_blocks: int) -> int:
    """``simulate --engine fdtd``: set-up report, progress with ETA, atomic checkpoints every
    ``--checkpoint-minutes`` (and on Ctrl-C), ``--resume``; the run file is written last."""
    import time

    from tqdm import tqdm

    from mapping.files import write_run
    from mapping.simulate import assemble_run
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
