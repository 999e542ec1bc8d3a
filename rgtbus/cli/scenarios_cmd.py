"""``rgtbus scenarios``: the scenarios shipped with rgtbus, run by name (``rgtbus run gate``)."""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING

from rgtbus.errors import RgtbusError

if TYPE_CHECKING:
    from rgtbus.cli import SubParsers


def register(subparsers: SubParsers) -> None:
    """Add ``scenarios``."""
    p = subparsers.add_parser(
        "scenarios",
        help="list the shipped scenarios (rgtbus run NAME runs one)",
        description="List the scenarios shipped with rgtbus: name, units, schedule and file. "
        "Every command that takes a scenario file also takes one of these names (rgtbus run "
        "gate) when no file of that name exists; the sweeps in scenarios/sweeps/ are not "
        "scenarios and are not listed.",
    )
    p.add_argument("--json", action="store_true", help="print a JSON list, one object a scenario")
    p.set_defaults(func=list_scenarios)


def list_scenarios(args: argparse.Namespace) -> int:
    """``rgtbus scenarios``: the shipped scenarios, a table or ``--json``."""
    from rgtbus.scenario import shipped_dir, shipped_scenarios

    if shipped_dir() is None:
        raise RgtbusError("no shipped scenarios found (neither rgtbus/scenarios/ nor scenarios/)")
    found = shipped_scenarios()
    if args.json:
        print(json.dumps([s.to_json() for s in found]))
        return 0
    from rgtbus.cli.tables import table_lines

    rows = [
        (s.name, "?" if s.units is None else str(s.units), s.schedule or "?", str(s.path))
        for s in found
    ]
    headers = ("NAME", "UNITS", "SCHEDULE", "PATH")
    for line in table_lines(rows, headers, align=("left", "right", "left", "left"), indent=""):
        print(line)
    return 0
