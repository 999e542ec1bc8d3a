"""``rgtbus certs``: a run's TLS identities (thin: ``rgtbus.bus.certs.make_certs``, then what it
wrote)."""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING

from rgtbus.cli import add_quiet_argument

if TYPE_CHECKING:
    from rgtbus.cli import SubParsers


def register(subparsers: SubParsers) -> None:
    """Add ``certs``."""
    from rgtbus.bus.certs import DEFAULT_DAYS

    c = subparsers.add_parser(
        "certs",
        help="make a run's CA and a key and certificate per unit, for --tls",
        description="Make the TLS identities of a run of SCENARIO in DIR: a CA of the run's own "
        "(DIR/run/ca.crt, ca.key), and a key and certificate, signed by it, for each unit "
        "(DIR/<unit>.crt, <unit>.key; the unit's name is the certificate's common name), the "
        "router (DIR/run/router.*) and a watcher (DIR/run/watch.*). Give DIR to unit, launch, "
        "router and watch as --tls DIR. Copy to each host DIR/run/ca.crt and its own pair only; "
        "keep DIR/run/ca.key off the hosts (docs/hosts.md).",
    )
    c.add_argument("scenario", metavar="SCENARIO", help="the scenario whose units get identities")
    c.add_argument("--out", required=True, metavar="DIR", help="where to write them")
    c.add_argument(
        "--days",
        type=float,
        default=DEFAULT_DAYS,
        metavar="N",
        help=f"how long the certificates are valid, from now (default {DEFAULT_DAYS})",
    )
    c.add_argument(
        "--force", action="store_true", help="replace the files of an earlier rgtbus certs in DIR"
    )
    c.add_argument("--json", action="store_true", help="print one JSON object: the files written")
    add_quiet_argument(c)
    c.set_defaults(func=run_certs)


def run_certs(args: argparse.Namespace) -> int:
    """``rgtbus certs``: ``make_certs`` for the scenario's units; one line a file written."""
    from rgtbus.bus.certs import describe, make_certs
    from rgtbus.scenario import load_scenario

    sc = load_scenario(args.scenario)
    made = make_certs(sc.units, args.out, days=args.days, label=sc.name, force=args.force)
    if args.json:
        pairs = {who: {"crt": str(crt), "key": str(key)} for who, (crt, key) in made.pairs.items()}
        out = {"directory": str(made.directory), "ca": str(made.ca), "ca_key": str(made.ca_key),
               "days": args.days, "identities": pairs}  # fmt: skip
        print(json.dumps(out))
        return 0
    print(f"certs: the TLS identities of {sc.name} in {made.directory} (valid {args.days:g} days)")
    print(f"  {made.ca}  the run's CA ({made.ca_key}: keep it off the hosts)")
    for identity, (crt, key) in made.pairs.items():
        print(f"  {crt}  {key}  {describe(identity)}")
    return 0
