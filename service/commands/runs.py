"""``omnisonar`` subcommands for runs and their inputs: signal, scenes, import-run, export-run.

Also the helpers the other subcommand modules share: :func:`_load_config` (SonarConfig
from a JSON file), :func:`resolve_scene` and :func:`resolve_path` (``builtin:NAME`` or a
scene file). An edge: parses, reads and writes files, prints; no computation.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mapping.files import atomic_write
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
def add_signal(sub: argparse._SubParsersAction) -> None:
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


def add_import_run(sub: argparse._SubParsersAction) -> None:
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
