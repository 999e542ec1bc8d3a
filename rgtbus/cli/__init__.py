"""Command line: ``rgtbus SUBCOMMAND ...``.

Each subcommand lives in a module of this package that exposes ``register(subparsers)``; the
module adds its parser and sets ``func`` to a callable ``(args) -> int``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from rgtbus import __version__
from rgtbus.errors import RgtbusError


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports usage errors in one line and exits 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    from rgtbus.cli import (
        log_cmds,
        plan_cmd,
        proc_cmds,
        replay_cmds,
        rgt_cmds,
        run_cmd,
        signal_cmds,
        sweep_cmds,
        watch_cmd,
    )

    parser = OneLineParser(
        prog="rgtbus",
        description="Socialised autonomous units: Reflexive Game Theory over a shared medium "
        "of resonate-and-fire receivers.",
    )
    parser.add_argument("--version", action="version", version=f"rgtbus {__version__}")
    subparsers = parser.add_subparsers(
        dest="command", metavar="COMMAND", parser_class=OneLineParser
    )
    subparsers.required = True
    for module in (
        rgt_cmds,
        run_cmd,
        signal_cmds,
        plan_cmd,
        replay_cmds,
        log_cmds,
        proc_cmds,
        watch_cmd,
        sweep_cmds,
    ):
        module.register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except RgtbusError as exc:
        print(f"rgtbus {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 1
