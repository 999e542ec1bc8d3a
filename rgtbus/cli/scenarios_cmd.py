"""``rgtbus scenarios`` and ``rgtbus sweeps``: the scenarios and sweeps shipped with rgtbus, run
by name (``rgtbus run gate``, ``rgtbus sweep noise``)."""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING

from rgtbus.errors import BadInput

if TYPE_CHECKING:
    from rgtbus.cli import SubParsers
    from rgtbus.scenario.shipped import ShippedScenario


def register(subparsers: SubParsers) -> None:
    """Add ``scenarios``."""
    p = subparsers.add_parser(
        "scenarios",
        help="list the shipped scenarios (rgtbus run NAME runs one)",
        description="List the scenarios shipped with rgtbus: name, units, schedule and file. "
        "Every command that takes a scenario file also takes one of these names (rgtbus run "
        "gate) when no file of that name exists; the sweeps in scenarios/sweeps/ are not "
        "scenarios: rgtbus sweeps lists them.",
    )
    p.add_argument("--json", action="store_true", help="print a JSON list, one object a scenario")
    p.set_defaults(func=list_scenarios)
    w = subparsers.add_parser(
        "sweeps",
        help="list the shipped sweeps (rgtbus sweep NAME runs one)",
        description="List the sweeps shipped with rgtbus: name, its base scenario's units and "
        "schedule, what it studies, and its file. rgtbus sweep takes one of these names when "
        "no file of that name exists.",
    )
    w.add_argument("--json", action="store_true", help="print a JSON list, one object a sweep")
    w.set_defaults(func=list_sweeps)


def list_scenarios(args: argparse.Namespace) -> int:
    """``rgtbus scenarios``: the shipped scenarios, a table or ``--json``."""
    from rgtbus.scenario import shipped_dir, shipped_scenarios

    if shipped_dir() is None:
        raise BadInput("no shipped scenarios found (neither rgtbus/scenarios/ nor scenarios/)")
    found = shipped_scenarios()
    _print_entries(found, args.json, "SCHEDULE", [s.schedule or "?" for s in found])
    return 0


def list_sweeps(args: argparse.Namespace) -> int:
    """``rgtbus sweeps``: the shipped sweeps, a table or ``--json``."""
    from rgtbus.scenario.shipped import shipped_sweeps

    found = shipped_sweeps()
    if not found:
        raise BadInput("no shipped sweeps found (neither rgtbus/scenarios/sweeps/ nor "
                          "scenarios/sweeps/)")  # fmt: skip
    _print_entries(found, args.json, "STUDIES", [s.description[:60] for s in found])
    return 0


def _print_entries(
    found: list[ShippedScenario], as_json: bool, third: str, column: list[str]
) -> None:
    """Shipped files as a JSON list, or a table: name, units, ``third`` (``column``), path."""
    if as_json:
        print(json.dumps([s.to_json() for s in found]))
        return
    from rgtbus.cli.tables import table_lines

    rows = [(s.name, "?" if s.units is None else str(s.units), c, str(s.path))
            for s, c in zip(found, column, strict=True)]  # fmt: skip
    headers = ("NAME", "UNITS", third, "PATH")
    for line in table_lines(rows, headers, align=("left", "right", "left", "left"), indent=""):
        print(line)
