"""Command line: ``rgtbus SUBCOMMAND ...``.

Each subcommand lives in a module of this package that exposes ``register(subparsers)``; the
module adds its parser and sets ``func`` to a callable ``(args) -> int``.

Two rules hold for every command, here in ``main``: ``--quiet`` (``add_quiet_argument``) prints
nothing on stdout but the ``--json`` output if asked (errors go to stderr as ever), and a reader
that goes away (``rgtbus cat LOG | head -1``) ends the command quietly with exit code 0.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING, NoReturn

from rgtbus._version import __version__
from rgtbus.cli.arguments import check_arguments
from rgtbus.errors import RgtbusError

if TYPE_CHECKING:
    from typing import TypeAlias


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports usage errors in one line and exits 2."""

    def error(self, message: str) -> NoReturn:
        """The usage error ``message`` on one line of stderr; exit code 2."""
        self.exit(2, f"{self.prog}: error: {message}\n")


if TYPE_CHECKING:
    # What ``build_parser`` hands each command module's ``register``.
    SubParsers: TypeAlias = argparse._SubParsersAction[OneLineParser]


def add_quiet_argument(p: argparse.ArgumentParser) -> None:
    """``--quiet``: print nothing but errors (and the ``--json`` output if asked); ``main``
    holds stdout back, the command itself leaves out its progress and notes on stderr."""
    p.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="print nothing but errors (and the --json output if asked)",
    )
    p.set_defaults(quiet_holds_stdout=True)


@contextlib.contextmanager
def _held_stdout(hold: bool) -> Iterator[None]:
    if not hold:
        yield
        return
    with open(os.devnull, "w") as devnull, contextlib.redirect_stdout(devnull):
        yield


def _stdout_to_devnull() -> None:
    """After a BrokenPipeError: point stdout's file descriptor at /dev/null, so that what is
    still buffered is flushed there at exit, not reported as "Exception ignored" (the
    Python docs' recipe for SIGPIPE)."""
    with contextlib.suppress(AttributeError, OSError, ValueError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


# Each command's module, in the order ``rgtbus --help`` lists them. ``main`` imports and
# registers only the module of the command it runs (a command module imports what its
# command needs: ``rgtbus run`` must not pay for ``launch``'s sockets or ``cat``'s JSON);
# ``tests/test_cli_lazy.py`` holds this map equal to what the modules register.
COMMANDS: dict[str, str] = {
    "solve": "rgt_cmds",
    "control": "rgt_cmds",
    "run": "run_cmd",
    "scenarios": "scenarios_cmd",
    "sweeps": "scenarios_cmd",
    "resonate": "signal_cmds",
    "ser": "signal_cmds",
    "figures": "signal_cmds",
    "plan": "plan_cmd",
    "replay": "replay_cmds",
    "merge": "replay_cmds",
    "recover": "replay_cmds",
    "convert": "replay_cmds",
    "info": "log_cmds",
    "cat": "log_cmds",
    "scenario": "log_cmds",
    "unit": "proc_cmds",
    "launch": "proc_cmds",
    "router": "proc_cmds",
    "certs": "certs_cmd",
    "watch": "watch_cmd",
    "sweep": "sweep_cmds",
    "sweep-plot": "sweep_cmds",
    "study": "study_cmds",
    "study-plot": "study_cmds",
    "studies": "study_cmds",
    "completion": "completion_cmd",
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``rgtbus`` parser: every command's, or only ``command``'s module's when it names
    one (what ``main`` builds to run it; usage, help and errors of that command are the
    same)."""
    import importlib

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
    wanted = [COMMANDS[command]] if command in COMMANDS else COMMANDS.values()
    for name in dict.fromkeys(wanted):
        importlib.import_module(f"rgtbus.cli.{name}").register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """``rgtbus ARGV...``: parse, check the run options (``arguments.check_arguments``), run
    the command; its exit code (2 and one line on stderr for an ``RgtbusError``)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if "_ARGCOMPLETE" in os.environ:  # the shell asks for completions (rgtbus completion)
        import argcomplete

        argcomplete.autocomplete(build_parser())  # every command's parser; exits
    try:
        parser = build_parser(argv[0] if argv else None)
    except RgtbusError as exc:  # the environment a module reads as it loads (RGTBUS_WALK)
        print(f"rgtbus: error: {exc}", file=sys.stderr)
        return 2
    args = parser.parse_args(argv)
    hold = getattr(args, "quiet_holds_stdout", False) and args.quiet
    try:
        check_arguments(args)
        with _held_stdout(hold and not getattr(args, "json", False)):
            code = int(args.func(args) or 0)
            sys.stdout.flush()  # a reader that has gone: BrokenPipeError here, not at exit
        return code
    except RgtbusError as exc:
        # an error may quote what a file or a peer said: never a control character raw
        from rgtbus.telemetry.untrusted import printable

        print(f"rgtbus {args.command}: error: {printable(exc)}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # rgtbus cat LOG | head -1: the reader has what it wanted
        _stdout_to_devnull()
        return 0
