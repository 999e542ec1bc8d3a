"""``rgtbus watch``: serve a cross-process run live to Foxglove, as an observer."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from rgtbus.cli import add_quiet_argument
from rgtbus.cli.arguments import (
    add_control_argument,
    add_key_argument,
    add_seconds_argument,
    add_tls_argument,
    add_zenoh_arguments,
    read_key,
    zenoh_options,
)
from rgtbus.cli.run_cmd import LIVE_ADDRESS

if TYPE_CHECKING:
    from rgtbus.cli import SubParsers
    from rgtbus.telemetry.control import Controller


def register(subparsers: SubParsers) -> None:
    """Add ``watch``."""
    w = subparsers.add_parser(
        "watch",
        help="watch a cross-process run live in Foxglove, as an observer (never a member)",
        description="Join a run's zenoh network as an observer and serve what every unit "
        "process logs over the Foxglove WebSocket protocol (the same topics and schemas as "
        "the MCAP log, as rgtbus run --live). The watcher only subscribes: the run neither "
        "waits for it nor notices it come or go. Ends with Ctrl-C, or --idle-exit.",
    )
    add_zenoh_arguments(w)
    w.add_argument("--run", default="*", metavar="RUN_ID", help="only this run (default: any)")
    w.add_argument(
        "--live",
        default=LIVE_ADDRESS,
        metavar="HOST:PORT",
        help=f"where to serve the live view (default {LIVE_ADDRESS}; port 0: any free port)",
    )
    add_key_argument(
        w,
        help="the run's shared secret (its --key-file): show only telemetry signed with it; "
        "without it, a keyed run's (signed) telemetry is not shown (docs/security.md)",
    )
    add_tls_argument(
        w,
        help="the run's directory of TLS identities (rgtbus certs): the watcher proves itself "
        "with DIR/run/watch.crt, on tls/ endpoints (needs --scenario)",
    )
    w.add_argument(
        "--scenario",
        metavar="SCENARIO",
        help="with --tls: the run's scenario, whose roster the access control is made from; "
        "with --control: what requests are checked against",
    )
    add_control_argument(
        w,
        "Foxglove clients may steer the run (a launch or units started with --control): "
        "the parameters and /control/* services of rgtbus run --control, each applied at the "
        "same sample in every process (needs --scenario; a keyed run's clients only after "
        "/control/auth; docs/foxglove.md)",
    )
    add_seconds_argument(
        w, "--idle-exit", help="end once S seconds pass without telemetry, after some came"
    )
    w.add_argument(
        "--json",
        action="store_true",
        help="at the end, one JSON object: messages received, runs, frames dropped and why",
    )
    add_quiet_argument(w)
    w.set_defaults(func=run_watch)


def run_watch(args: argparse.Namespace) -> int:
    """``rgtbus watch``: serve the runs' telemetry live until Ctrl-C or ``--idle-exit``; then
    say what was received and dropped."""
    from rgtbus.telemetry.live import LiveView, parse_address
    from rgtbus.telemetry.watch import Watcher

    host, port = parse_address(args.live)
    key = read_key(args)
    roster = _roster(args)
    say = _teller(quiet=args.quiet)
    control = _controller(args, key)
    with LiveView(host, port, name="rgtbus watch", linger=1.0, say=say, control=control) as live:
        live.advertise(_topics())
        with Watcher(
            live, run_id=args.run, key=key, tls=args.tls, roster=roster, **zenoh_options(args)
        ) as watcher:
            say(f"watch: serving {live.url} (listening for the telemetry of run {args.run})")
            if control is not None:
                watcher.steer(control)
                keyed = "; clients /control/auth first" if control.key is not None else ""
                say(f"watch: steering on (parameters and /control/* services{keyed})")
            subscribed = 0
            hinted = False
            try:
                while True:
                    time.sleep(0.1)
                    if watcher.drops["signed"] and not hinted:
                        hinted = True
                        say("watch: the run is keyed: its telemetry is shown with --key-file")
                    now = len(live.subscriptions.pairs)
                    settled = time.monotonic() - live.subscriptions.last_change > 0.3
                    if now != subscribed and settled:
                        subscribed = now
                        say(f"watch: {now} channel subscriptions")
                    idle = time.monotonic() - watcher.last_heard
                    waited = watcher.heard.is_set() and args.idle_exit is not None
                    if waited and idle >= args.idle_exit:
                        break
            except KeyboardInterrupt:
                pass
            drops = ", ".join(f"{n} {why}" for why, n in watcher.drops.items() if n)
            if args.json:
                print(
                    json.dumps(
                        {
                            "url": live.url,
                            "received": watcher.received,
                            "runs": sorted(watcher.runs),
                            "dropped": watcher.dropped,
                            "drops": {why: n for why, n in watcher.drops.items() if n},
                        }
                    ),
                    flush=True,
                )
            say(
                f"watch: {watcher.received} messages from run(s) "
                f"{', '.join(sorted(watcher.runs)) or '(none)'}"
                + (f"; {watcher.dropped} frames dropped ({drops})" if watcher.dropped else "")
            )
    return 0


def _controller(args: argparse.Namespace, key: bytes | None) -> Controller | None:
    """The steering ``--control`` asks for (None without it), checking requests against
    ``--scenario``. Who may steer: a client that proves it holds the run's key; on a TLS run
    without one, the watcher's own (its certificate's key file stands for it)."""
    from rgtbus.errors import BadInput

    if not args.control:
        return None
    if args.scenario is None:
        raise BadInput("watch: --control needs --scenario (what requests are checked against)")
    import hashlib

    from rgtbus.scenario import load_scenario
    from rgtbus.telemetry.control import Controller

    if key is None and args.tls is not None:
        from rgtbus.bus.certs import WATCH, check_tls

        key = hashlib.sha256(check_tls(args.tls, WATCH).key.read_bytes()).digest()
    return Controller(load_scenario(args.scenario), key=key, pace=None, paced=True)


def _roster(args: argparse.Namespace) -> tuple[str, ...]:
    """The roster of ``--scenario``, for ``--tls`` (its files checked here, before the live
    view opens); () without ``--tls``."""
    from rgtbus.errors import BadInput

    if args.tls is None:
        if args.scenario is not None and not args.control:
            raise BadInput("watch: --scenario is for --tls (its access control) or --control")
        return ()
    if args.scenario is None:
        raise BadInput("watch: --tls needs --scenario (the roster of the access control)")
    from rgtbus.bus.certs import WATCH, check_tls
    from rgtbus.scenario import load_scenario

    check_tls(args.tls, WATCH)
    return load_scenario(args.scenario).units


def _teller(quiet: bool) -> Callable[[str], None]:
    """What the watcher says: a line on stderr as it happens; nothing with ``--quiet``."""

    def say(line: str) -> None:
        if not quiet:
            print(line, file=sys.stderr, flush=True)

    return say


def _topics() -> list[tuple[str, str]]:
    from rgtbus.telemetry import topics

    return [(t, schema) for t, (schema, _) in topics.TOPICS.items()]
