"""``rgtbus info LOG``, ``rgtbus cat LOG`` and ``rgtbus scenario LOG``: the log tools users of
``mcap`` and ``ros2 bag`` expect (rgtbus/telemetry/logtools.py)."""

from __future__ import annotations

import argparse
import json
import sys

from rgtbus.cli import add_quiet_argument


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "info",
        help="a log at a glance: duration, messages per topic, scenario, seed, outcome",
        description="What a run's MCAP log holds, read from its summary section (fast on large "
        "logs; a log cut short is read record by record and says so): duration, messages "
        "per topic with their schemas, compression, scenario, seed, rgtbus version, units, "
        "outcome.",
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
        help="only this topic (repeat for several), e.g. /rx/decode",
    )
    c.add_argument("--unit", metavar="NAME", help="only messages about this unit")
    c.add_argument("--from", dest="t_from", type=float, metavar="S", help="from S simulated s")
    c.add_argument("--to", dest="t_to", type=float, metavar="S", help="up to S simulated s")
    c.set_defaults(func=cat)

    s = subparsers.add_parser(
        "scenario",
        help="print the scenario a log was run with (runnable as is)",
        description="Print the scenario TOML stored in a run's log, its seed set to the "
        "run's: rgtbus scenario LOG > again.toml && rgtbus run again.toml repeats the run.",
    )
    s.add_argument("log", metavar="LOG", help="an MCAP log written by rgtbus")
    s.set_defaults(func=scenario)


def info(args: argparse.Namespace) -> int:
    from rgtbus.telemetry.logtools import info_text, log_info

    data = log_info(args.log)
    print(json.dumps(data) if args.json else info_text(data))
    return 0


def cat(args: argparse.Namespace) -> int:
    from rgtbus.telemetry.logtools import cat_messages

    out = sys.stdout
    for msg in cat_messages(
        args.log, topics=args.topic, unit=args.unit, t_from=args.t_from, t_to=args.t_to
    ):
        out.write(json.dumps(msg) + "\n")
    return 0


def scenario(args: argparse.Namespace) -> int:
    from rgtbus.telemetry.logtools import stored_scenario

    text = stored_scenario(args.log)
    sys.stdout.write(text if text.endswith("\n") else text + "\n")
    return 0
