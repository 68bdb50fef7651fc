"""The ``omnisonar`` command line: parses arguments, reads and writes files, prints.

Every subcommand is a thin edge over functions in ``mapping`` and ``localization``; no
computation lives here. Each subcommand is an ``add_<name>(subparsers)`` function that
registers its parser and sets ``func`` to a ``_cmd_<name>(args) -> int`` handler.

The subcommands live by topic in :mod:`service.commands`: ``runs`` (signal, scenes,
import-run, export-run, and the shared ``resolve_scene`` / ``resolve_path``), ``simulate``,
``maps`` (heatmap, build-map, evaluate-map), ``localize`` (localize, calibrate, posterior),
``serve`` (serve, demo-api, demo) and ``stream`` (the robot's side of the service). This
module holds the ``_COMMANDS`` registry (in ``--help`` order), the parser and the entry point.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

from service.commands.localize import add_calibrate, add_localize, add_posterior
from service.commands.maps import add_build_map, add_evaluate_map, add_heatmap
from service.commands.runs import (
    add_export_run,
    add_import_run,
    add_scenes,
    add_signal,
)
from service.commands.serve import add_demo, add_demo_api, add_serve
from service.commands.simulate import add_simulate
from service.commands.stream import add_stream

__all__ = ["DefaultsHelpFormatter", "build_parser", "main"]


_COMMANDS: list[Callable[[argparse._SubParsersAction], None]] = [
    add_scenes,
    add_import_run,
    add_export_run,
    add_signal,
    add_simulate,
    add_serve,
    add_demo_api,
    add_posterior,
    add_heatmap,
    add_demo,
    add_build_map,
    add_evaluate_map,
    add_localize,
    add_calibrate,
    add_stream,
]


class DefaultsHelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Appends ``(default: X)`` to every option's help, except where the help places
    ``%(default)s`` itself or the default is None or False (an unset option, an off flag:
    their help says what leaving them out means)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None or action.default is False:
            return action.help
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    """The ``omnisonar`` argument parser with every subcommand registered; every
    subcommand's help shows the defaults (:class:`DefaultsHelpFormatter`)."""
    parser = argparse.ArgumentParser(
        prog="omnisonar",
        description="Doppler direction-of-arrival sonar: simulate, map, localize, serve.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for add in _COMMANDS:
        add(sub)
    for subparser in sub.choices.values():
        subparser.formatter_class = DefaultsHelpFormatter
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
