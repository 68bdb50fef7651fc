"""The ``omnisonar`` command line: parses arguments, reads and writes files, prints.

Every subcommand is a thin edge over functions in ``mapping`` and ``localization``; no
computation lives here. Each subcommand is an ``_add_<name>(subparsers)`` function that
registers its parser and sets ``func`` to a ``_cmd_<name>(args) -> int`` handler.

The subcommands live by topic in ``service/cli_<group>.py``: ``cli_runs`` (signal, scenes,
import-run, export-run, and the shared ``resolve_scene`` / ``resolve_path``),
``cli_simulate``, ``cli_maps`` (heatmap, build-map, evaluate-map), ``cli_localize``
(localize, calibrate, posterior) and ``cli_service`` (serve, demo-api, demo). This module holds the
``_COMMANDS`` registry (in ``--help`` order), the parser and the entry point.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

from service.commands.localize import _add_calibrate, _add_localize, _add_posterior
from service.commands.maps import _add_build_map, _add_evaluate_map, _add_heatmap
from service.commands.runs import (
    _add_export_run,
    _add_import_run,
    _add_scenes,
    _add_signal,
    resolve_path,
    resolve_scene,
)
from service.commands.serve import _add_demo, _add_demo_api, _add_serve
from service.commands.simulate import _add_simulate

__all__ = ["build_parser", "main", "resolve_path", "resolve_scene"]


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
    _add_calibrate,
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
