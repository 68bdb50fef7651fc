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

import numpy as np

from mapping.signal import SonarConfig, tx_block


def _load_config(path: str | None) -> SonarConfig:
    """SonarConfig from a JSON file of fields, or the Table 1 defaults."""
    if path is None:
        return SonarConfig()
    return SonarConfig.from_json(Path(path).read_text())


def _atomic_write_bytes(path: Path, write: Callable[[Path], None]) -> None:
    """Call ``write(tmp)`` on a temporary name beside ``path``, then rename into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        write(tmp)
        tmp.replace(path)
    finally:
        if tmp.exists():
            tmp.unlink()


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
    _atomic_write_bytes(out, lambda tmp: wavfile.write(tmp, int(config.fs_hz), block))
    print(
        f"wrote {out}: {block.size} samples at {config.fs_hz:g} Hz "
        f"({config.block_s:.4f} s, M={config.repetitions}, L={config.sequence_length})"
    )
    return 0


_COMMANDS: list[Callable[[argparse._SubParsersAction], None]] = [
    _add_signal,
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
