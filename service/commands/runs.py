"""``omnisonar`` subcommands for runs and their inputs: signal, scenes, import-run, export-run.

``import-run --raw`` imports what a sound card recorded (:func:`mapping.recording.import_raw`)
and prints its report as text or ``--json``; its options are shared with ``stream``
(:func:`add_raw_import_options`, :func:`raw_import_options`).

Also the helpers the other subcommand modules share: :func:`_load_config` (SonarConfig
from a JSON file), :func:`resolve_scene` and :func:`resolve_path` (``builtin:NAME`` or a
scene file). An edge: parses, reads and writes files, prints; no computation.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mapping.files import atomic_write
from mapping.signal import SonarConfig, tx_block

if TYPE_CHECKING:
    from mapping.path import Trajectory
    from mapping.recording import RawImportOptions
    from mapping.scene import Scene


def _load_config(path: str | None) -> SonarConfig:
    """SonarConfig from a JSON file of fields, or the Table 1 defaults."""
    if path is None:
        return SonarConfig()
    return SonarConfig.from_json(Path(path).read_text())


# ---- signal ---------------------------------------------------------------------------
def add_signal(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("signal", help="write the transmitted signal as a WAV: one block at the "
                       "sonar rate, or with --rate what a loudspeaker plays")
    p.add_argument("--config", help="SonarConfig JSON file (default: paper Table 1)")
    p.add_argument("--out", required=True, help="output WAV (float32, mono)")
    p.add_argument("--rate", type=int, metavar="HZ",
                   help="write the playback signal at this sound-card rate (e.g. 48000), "
                   "scaled to a peak of 0.5; play it once, not looped")
    p.add_argument("--seconds", type=float, default=120.0,
                   help="duration of the playback signal (with --rate)")
    p.set_defaults(func=_cmd_signal)


def _cmd_signal(args: argparse.Namespace) -> int:
    from scipy.io import wavfile

    config = _load_config(args.config)
    if args.rate is None:
        block = tx_block(config).astype(np.float32)
        rate = int(config.fs_hz)
        what = (f"({config.block_s:.4f} s, M={config.repetitions}, "
                f"L={config.sequence_length})")
    else:
        from mapping.signal import playback_signal

        if not 0 < args.seconds <= 3600:
            raise ValueError(f"--seconds must lie in (0, 3600], got {args.seconds}")
        x = playback_signal(config, float(args.rate), int(round(args.seconds * args.rate)))
        block = (0.5 * x / np.max(np.abs(x))).astype(np.float32)
        rate = args.rate
        what = f"({args.seconds:g} s of playback, peak 0.5)"
    out = Path(args.out)
    atomic_write(out, lambda fh: wavfile.write(fh, rate, block), private=False)
    print(f"wrote {out}: {block.size} samples at {rate:g} Hz {what}")
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


def add_scenes(sub: argparse._SubParsersAction) -> None:
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


def add_raw_import_options(raw: argparse._ArgumentGroup) -> None:
    """The raw-import options ``import-run --raw`` and ``stream`` share."""
    from mapping.recording import DEFAULT_TRANSDUCER_OFFSET_M, STATIC_REMOVAL_METHODS

    raw.add_argument("--calibration", metavar="CAL.wav",
                     help="a raw recording made standing still (or in the open) for "
                     "--static calibration")
    raw.add_argument("--static", choices=STATIC_REMOVAL_METHODS,
                     help="static removal: run = everything static (also walls parallel to a "
                     "straight path), calibration = what CAL.wav heard, gated = direct path, "
                     "body and (with heights) floor/ceiling only (default: calibration with "
                     "--calibration, else gated; give the heights)")
    raw.add_argument("--offset", type=float, default=DEFAULT_TRANSDUCER_OFFSET_M, metavar="M",
                     help="loudspeaker-microphone distance in m")
    raw.add_argument("--sonar-height", type=float, metavar="M",
                     help="sonar height above the floor in m (gated: removes floor echoes)")
    raw.add_argument("--ceiling-height", type=float, metavar="M",
                     help="ceiling height in m (gated, with --sonar-height)")
    raw.add_argument("--temperature", type=float, metavar="C",
                     help="air temperature in deg C: sets the speed of sound (default: the "
                     "config's)")


def raw_import_options(args: argparse.Namespace
                       ) -> tuple[RawImportOptions, tuple[NDArray[np.float64], float] | None]:
    """Options and the calibration recording (samples, rate) of the shared raw options."""
    from mapping.files import read_wav_raw
    from mapping.recording import RawImportOptions, StaticRemoval

    method: StaticRemoval = args.static or ("calibration" if args.calibration else "gated")
    if method == "calibration" and not args.calibration:
        raise ValueError("--static calibration needs --calibration CAL.wav")
    options = RawImportOptions(
        transducer_offset_m=args.offset, static_removal=method,
        sonar_height_m=args.sonar_height, ceiling_height_m=args.ceiling_height,
        temperature_c=args.temperature)
    cal = read_wav_raw(args.calibration) if args.calibration else None
    return options, None if cal is None else (cal.samples, cal.fs_hz)


def add_import_run(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import-run", help="real recording (WAV + pose CSV) -> run file")
    p.add_argument("--wav", required=True, help="mono WAV: with --raw, what the sound card "
                   "recorded (any rate >= the sonar rate); without, a stream at the sonar rate "
                   "starting on a transmission period boundary, direct wave removed")
    p.add_argument("--poses", required=True,
                   help="CSV with columns t_s,x_m,y_m,heading_rad,speed_m_s (times on the "
                   "WAV's clock, first sample = 0 s)")
    p.add_argument("--out", required=True, help="output run file (.npz)")
    p.add_argument("--config", help="SonarConfig JSON file (default: paper Table 1)")
    p.add_argument("--blocks", type=int, help="use only the first N blocks")
    raw = p.add_argument_group("raw recordings (--raw)")
    raw.add_argument("--raw", action="store_true",
                     help="the WAV is a raw recording: estimate latency and clock offset from "
                     "the direct path, resample, remove the direct wave and static echoes")
    add_raw_import_options(raw)
    raw.add_argument("--json", action="store_true",
                     help="print the import report as one JSON object")
    p.set_defaults(func=_cmd_import_run)


def _cmd_import_run(args: argparse.Namespace) -> int:
    if args.raw:
        return _cmd_import_raw(args)
    given = [f"--{n.replace('_', '-')}" for n in ("calibration", "static", "sonar_height",
                                                  "ceiling_height", "temperature", "json")
             if getattr(args, n) not in (None, False)]
    if given:
        raise ValueError(f"{', '.join(given)} only apply to raw recordings: add --raw")
    from mapping.files import read_pose_csv, read_wav_mono, write_run
    from mapping.recording import block_odometry, split_blocks
    from mapping.run import Run

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


def _cmd_import_raw(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from mapping.files import read_pose_csv, read_wav_raw, write_run
    from mapping.recording import import_raw
    from service.jsonout import strict_json

    config = _load_config(args.config)
    options, calibration = raw_import_options(args)
    wav = read_wav_raw(args.wav)
    log = read_pose_csv(args.poses)
    try:
        run, report = import_raw(wav.samples, wav.fs_hz, log, config, options,
                                 calibration=calibration, full_scale=wav.full_scale)
    except ValueError as exc:
        raise ValueError(f"{args.wav}: {exc}") from None
    if args.blocks is not None:
        if not 1 <= args.blocks <= run.n_blocks:
            raise ValueError(f"--blocks must be in 1..{run.n_blocks}, got {args.blocks}")
        run = replace(run, samples=run.samples[: args.blocks], t_s=run.t_s[: args.blocks],
                      speed_m_s=run.speed_m_s[: args.blocks],
                      yaw_rate_rad_s=run.yaw_rate_rad_s[: args.blocks],
                      pose=run.pose[: args.blocks])
    run = replace(run, meta={**run.meta, "wav": Path(args.wav).name,
                             "poses": Path(args.poses).name})
    out = write_run(args.out, run)
    if args.json:
        print(strict_json({"out": str(out), "blocks_written": run.n_blocks,
                           **report.to_dict()}))
        return 0
    for line in _report_lines(report.to_dict()):
        print(line)
    print(f"wrote {out}: {run.n_blocks} blocks")
    return 0


def _report_lines(r: dict[str, Any]) -> list[str]:
    """The import report as text, one estimate per line."""
    lines = [
        f"recording        {r['fs_rec_hz']:g} Hz; playback heard from {r['onset_s']:.4f} s",
        f"latency          {r['latency_s'] * 1e3:.4f} ms ({r['latency_samples']:.3f} samples)",
        f"clock offset     {r['clock_offset_ppm']:+.3f} ppm (residual "
        f"{r['fit_residual_samples']:.4f} samples over {r['periods_fitted']} periods)",
        f"direct path      peak {r['direct_peak_db']:.1f} dB over the other lags; "
        f"{r['direct_to_echo_db']:.1f} dB above everything else",
        f"static removal   {r['method']}: direct wave suppressed by "
        f"{_db(r['direct_suppression_db'])}",
        f"blocks           {r['blocks']} from sonar sample {r['first_sample']} "
        f"(c = {r['sound_speed_m_s']:.1f} m/s, offset {r['transducer_offset_m']:g} m)",
    ]
    cal = r["calibration"]
    if cal is not None:
        lines.append(f"calibration      latency {cal['latency_s'] * 1e3:.4f} ms, clock "
                     f"{cal['clock_offset_ppm']:+.3f} ppm, gain {cal['gain']:.3f}, shift "
                     f"{cal['shift_samples']:+.4f} samples")
    lines += [f"warning: {w}" for w in r["warnings"]]
    return lines


def _db(value: float | None) -> str:
    return ">= noise floor (inf)" if value is None else f"{value:.1f} dB"


def add_export_run(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export-run", help="run file -> WAV + pose CSV (block midpoints)")
    p.add_argument("run", help="run file (.npz)")
    p.add_argument("--wav", required=True, help="output WAV (float32, mono, at fs)")
    p.add_argument("--poses", required=True, help="output pose CSV, one row per tracked block")
    p.set_defaults(func=_cmd_export_run)


def _cmd_export_run(args: argparse.Namespace) -> int:
    from mapping.files import read_run, write_pose_csv, write_wav
    from mapping.recording import join_blocks, pose_log_from_blocks

    run = read_run(args.run)
    wav = write_wav(args.wav, join_blocks(run.samples), run.config.fs_hz)
    log = pose_log_from_blocks(run.t_s, run.pose, run.speed_m_s, run.config.block_s)
    csv_path = write_pose_csv(args.poses, log)
    print(f"wrote {wav} ({run.n_blocks} blocks) and {csv_path} ({log.t_s.size} poses)")
    return 0
