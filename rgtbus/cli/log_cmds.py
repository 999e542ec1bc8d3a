"""``rgtbus info LOG``, ``rgtbus cat LOG`` and ``rgtbus scenario LOG``: the log tools users of
``mcap`` and ``ros2 bag`` expect (rgtbus/telemetry/logtools.py, log_cat.py).

Each opens its log with ``check_log``, which checks it whole before anything is printed. Exit
codes, as ``rgtbus replay``'s: 0 read; 2 unreadable, not MCAP, corrupt (a chunk, data-section
or summary CRC mismatch, a damaged record), only a header, or not an rgtbus run log: one line,
nothing on stdout; 3 truncated (a killed run): what is there is printed, and one line on stderr
says where the log ends and the last log time read."""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING

from rgtbus.cli import add_quiet_argument

if TYPE_CHECKING:
    from rgtbus.cli import SubParsers

EXIT_TRUNCATED = 3  # as rgtbus replay's (rgtbus.telemetry.verify.EXIT_TRUNCATED)


def register(subparsers: SubParsers) -> None:
    """Add ``info``, ``cat`` and ``scenario``."""
    p = subparsers.add_parser(
        "info",
        help="a log at a glance: duration, messages per topic, scenario, seed, outcome",
        description="What a run's MCAP log holds, read from its summary section once its CRCs "
        "have checked the whole file (fast on large logs; a log cut short is read record by "
        "record and says so): duration, messages per topic with their schemas, compression, "
        "scenario, seed, rgtbus version, units, outcome. Exit 0: read; 2: unreadable, "
        "corrupt, header-only or not an rgtbus log; 3: truncated.",
    )
    p.add_argument("log", metavar="LOG", help="an MCAP log written by rgtbus")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_quiet_argument(p)
    p.set_defaults(func=info)

    c = subparsers.add_parser(
        "cat",
        help="a log's messages as JSON lines, by topic, unit and time",
        description="Print a log's messages in log-time order, one JSON object a line: "
        '{"topic", "t" (simulated s), "log_time" (ns), "message"}.',
    )
    c.add_argument("log", metavar="LOG", help="an MCAP log written by rgtbus")
    c.add_argument(
        "--topic",
        action="append",
        default=[],
        metavar="TOPIC",
        help="only this topic (repeat for several), e.g. /rx/decodes",
    )
    c.add_argument("--unit", metavar="NAME", help="only messages about this unit")
    c.add_argument("--from", dest="t_from", type=float, metavar="S", help="from S simulated s")
    c.add_argument("--to", dest="t_to", type=float, metavar="S", help="up to S simulated s")
    c.add_argument(
        "--blocks",
        action="store_true",
        help="/rx/decodes as stored (a unit's decodes of a block as columns, at the block's "
        "last decode's time); by default one decode a line, at its own time",
    )
    c.set_defaults(func=cat)

    s = subparsers.add_parser(
        "scenario",
        help="print the scenario a log was run with (runnable as is)",
        description="Print the scenario TOML stored in a run's log, its seed set to the "
        "run's: rgtbus scenario LOG > again.toml && rgtbus run again.toml repeats the run.",
    )
    s.add_argument("log", metavar="LOG", help="an MCAP log written by rgtbus")
    s.set_defaults(func=scenario)


def _ended(note: str) -> int:
    """A log that ends early was read as far as it goes: one line saying so, exit 3 (as
    ``rgtbus replay``)."""
    if not note:
        return 0
    from rgtbus.telemetry.untrusted import printable

    sys.stdout.flush()
    print(f"note: {printable(note)}", file=sys.stderr)
    return EXIT_TRUNCATED


def info(args: argparse.Namespace) -> int:
    """``rgtbus info LOG``: what the log holds, as text or ``--json``."""
    from rgtbus.telemetry.log_check import check_log
    from rgtbus.telemetry.logtools import info_text, log_info
    from rgtbus.telemetry.untrusted import printable_errors

    with printable_errors(), check_log(args.log) as log:
        data = log_info(log)
    print(json.dumps(data) if args.json else info_text(data))
    return _ended(log.note)


def cat(args: argparse.Namespace) -> int:
    """``rgtbus cat LOG``: its messages as JSON lines, filtered by topic, unit and time."""
    from rgtbus.telemetry.log_cat import cat_messages
    from rgtbus.telemetry.log_check import check_log
    from rgtbus.telemetry.untrusted import printable_errors

    out = sys.stdout
    # a line is JSON, which escapes every control character (json.dumps: ASCII only)
    with printable_errors(), check_log(args.log) as log:
        for msg in cat_messages(
            log,
            topics=args.topic,
            unit=args.unit,
            t_from=args.t_from,
            t_to=args.t_to,
            blocks=args.blocks,
        ):
            out.write(json.dumps(msg) + "\n")
    return _ended(log.note)


def scenario(args: argparse.Namespace) -> int:
    """``rgtbus scenario LOG``: the scenario TOML the run was made with, its seed the run's."""
    from rgtbus.telemetry.log_check import check_log
    from rgtbus.telemetry.logtools import stored_scenario
    from rgtbus.telemetry.untrusted import printable_errors

    with printable_errors(), check_log(args.log) as log:
        text = stored_scenario(log)  # printable: its control characters escaped
    sys.stdout.write(text if text.endswith("\n") else text + "\n")
    return _ended(log.note)
