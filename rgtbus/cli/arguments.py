"""The options of a run, declared once for every command that takes them: ``--seed``,
``--realtime``, ``--engine``, the ``--timeout`` and ``--join-timeout`` of a cross-process run,
``--key-file``, zenoh's options and ``--tls``.

Each option with a rule is checked by ``rgtbus.checks`` (the library's own rules) once the
command line is parsed: ``rgtbus.cli.main`` calls ``check_arguments`` before the command runs,
so a bad value is one line naming the flag and the value (``--realtime 0.0: must be a positive
factor``), exit code 2, whichever command it was given to."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import rgtbus.checks as checks

# A rule of rgtbus.checks: (value, flag) -> the value, or RgtbusError naming the flag
Rule = Callable[[Any, str], Any]

# The namespace attribute that holds a command's (dest, flag, rule) triples: a parser default,
# so the command's own parser says which of its options are checked.
_CHECKED = "checked_options"


def add_checked_argument(
    p: argparse.ArgumentParser, flag: str, rule: Rule, **kwargs: Any
) -> argparse.Action:
    """``p.add_argument(flag, **kwargs)``, its value (when given, or a default other than
    None) checked by ``rule`` after parsing (``check_arguments``)."""
    action = p.add_argument(flag, **kwargs)
    checked = p.get_default(_CHECKED) or ()
    p.set_defaults(**{_CHECKED: (*checked, (action.dest, flag, rule))})
    return action


def check_arguments(args: argparse.Namespace) -> None:
    """Check every option its command declared with a rule, and keep the value the rule
    gives; the first bad one raises ``RgtbusError`` (one line naming the flag and value)."""
    for dest, flag, rule in getattr(args, _CHECKED, ()):
        value = getattr(args, dest)
        if value is not None:
            setattr(args, dest, rule(value, flag))


def add_seed_argument(
    p: argparse.ArgumentParser,
    help: str | None = "override the scenario's seed",
    default: int | None = None,
) -> None:
    """``--seed``: a non-negative integer (``checks.seed``)."""
    add_checked_argument(p, "--seed", checks.seed, type=int, default=default, help=help)


def add_realtime_argument(p: argparse.ArgumentParser) -> None:
    """``--realtime FACTOR``: pace the run, a positive finite factor (``checks.realtime``)."""
    add_checked_argument(
        p,
        "--realtime",
        checks.realtime,
        type=float,
        metavar="FACTOR",
        help="pace the run: FACTOR simulated seconds per wall second",
    )


def add_engine_argument(p: argparse.ArgumentParser, help: str) -> None:
    """``--engine``: one of the library's engines (``rgtbus.checks.ENGINES``), event by
    default."""
    p.add_argument("--engine", choices=checks.ENGINES, default="event", help=help)


def add_seconds_argument(
    p: argparse.ArgumentParser,
    flag: str,
    help: str,
    default: float | None = None,
) -> None:
    """A wall-clock limit ``flag S``: positive finite seconds (``checks.seconds``)."""
    add_checked_argument(
        p, flag, checks.seconds, type=float, default=default, metavar="S", help=help
    )


def add_timeout_argument(
    p: argparse.ArgumentParser,
    help: str = "give up when no member has news for S seconds (default 10)",
    default: float | None = 10.0,
) -> None:
    """``--timeout S`` of a cross-process run: how long no member may have news."""
    add_seconds_argument(p, "--timeout", help, default=default)


def add_join_timeout_argument(p: argparse.ArgumentParser) -> None:
    """``--join-timeout S`` of a cross-process run: how long every unit has to join."""
    add_seconds_argument(
        p,
        "--join-timeout",
        "give up when not every unit has joined within S seconds (default 20 and 1 a unit)",
    )


KEY_FILE_HELP = (
    "a shared secret (>= 16 bytes, e.g. head -c 32 /dev/urandom | base64 > FILE): every "
    "frame and hello is signed with it and anything unsigned is dropped; without it anyone "
    "who reaches the zenoh endpoints can join the run. For loopback runs: across machines use "
    "--tls (docs/security.md)"
)


def add_key_argument(
    p: argparse.ArgumentParser,
    help: str = KEY_FILE_HELP,
) -> None:
    """``--key-file FILE``: the run's shared secret (``read_key`` loads it)."""
    p.add_argument("--key-file", metavar="FILE", help=help)


def add_control_argument(p: argparse.ArgumentParser, help: str) -> None:
    """``--control``: the run may be steered from Foxglove (docs/foxglove.md, "Steer a live
    run"); ``help`` says how, for the command at hand."""
    p.add_argument("--control", action="store_true", help=help)


def read_key(args: argparse.Namespace) -> bytes | None:
    """The shared secret ``--key-file`` names (None without it), checked by
    ``rgtbus.bus.auth.load_key``."""
    from rgtbus.bus.auth import load_key

    return None if args.key_file is None else load_key(args.key_file)


def add_zenoh_arguments(p: argparse.ArgumentParser) -> None:
    """zenoh's options, in zenoh's own spelling: -m/--mode, -e/--connect, -l/--listen,
    -c/--config, --multicast. No defaults here (None = not given): a --config file's own
    values must survive what was not typed (``zenoh_options``)."""
    p.add_argument(
        "-m",
        "--mode",
        choices=("peer", "client"),
        help="zenoh mode (default peer; client to go through a router)",
    )
    p.add_argument(
        "-e",
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (tls/... with --tls; "
        "repeatable)",
    )
    p.add_argument(
        "-l",
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="zenoh endpoint to listen on, e.g. tcp/127.0.0.1:7448 (tls/... with --tls; "
        "repeatable)",
    )
    p.add_argument(
        "-c",
        "--config",
        "--zenoh-config",
        dest="zenoh_config",
        metavar="FILE",
        help="a zenoh JSON5 config file (the options above, where given, override it; "
        "default: the file $ZENOH_CONFIG names, if set)",
    )
    p.add_argument(
        "--multicast",
        action="store_true",
        default=None,
        help="turn zenoh's multicast scouting on (off unless asked or set in --config)",
    )


TLS_HELP = (
    "the run's directory of TLS identities (rgtbus certs SCENARIO --out DIR): this process "
    "proves who it is with its own certificate there, over mutual TLS on tls/ endpoints, under "
    "an access control made from the roster (docs/hosts.md)"
)


def add_tls_argument(p: argparse.ArgumentParser, help: str = TLS_HELP) -> None:
    """``--tls DIR``: the run's directory of TLS identities (rgtbus.bus.certs)."""
    p.add_argument("--tls", metavar="DIR", help=help)


def zenoh_options(args: argparse.Namespace) -> dict[str, Any]:
    """Only what the user typed (None: not given), so ``make_config`` keeps the rest of a
    ``--config`` file; without a file, ``make_config`` supplies the defaults."""
    return {
        "mode": args.mode,
        "connect": None if args.connect is None else list(args.connect),
        "listen": None if args.listen is None else list(args.listen),
        "multicast": args.multicast,
        "config": args.zenoh_config,
    }
