"""Cross-process runs: ``rgtbus unit``, ``rgtbus launch`` and ``rgtbus router`` (thin: parse,
call ``rgtbus.units.process`` or ``rgtbus.launch``, print)."""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rgtbus.cli import add_quiet_argument
from rgtbus.cli.arguments import (
    add_control_argument,
    add_engine_argument,
    add_join_timeout_argument,
    add_key_argument,
    add_realtime_argument,
    add_seed_argument,
    add_timeout_argument,
    add_tls_argument,
    add_zenoh_arguments,
    read_key,
    zenoh_options,
)
from rgtbus.errors import BadInput
from rgtbus.interrupts import interrupted_by
from rgtbus.pairs import PairTexts

if TYPE_CHECKING:
    from rgtbus.cli import SubParsers
    from rgtbus.scenario import Scenario


def register(subparsers: SubParsers) -> None:
    """The ``unit``, ``launch`` and ``router`` commands."""
    _add_unit(subparsers)
    _add_launch(subparsers)
    _add_router(subparsers)


def _add_unit(subparsers: SubParsers) -> None:
    u = subparsers.add_parser(
        "unit",
        help="run units of a scenario in this process, over zenoh",
        description="Run unit NAME (or units NAME,NAME,...) of SCENARIO in this process. Every "
        "unit of the scenario must be started (on this machine or others) and reachable through "
        "zenoh; they join, then advance together, each to the smallest promise of all "
        "(conservative synchronisation).",
    )
    u.add_argument(
        "name", metavar="NAME", help="the unit to run, e.g. a; several: a,b,c (one process)"
    )
    u.add_argument("scenario", metavar="SCENARIO", help="the scenario file (same on every unit)")
    add_zenoh_arguments(u)
    u.add_argument("--log", metavar="PATH", help="this process's MCAP log (default logs/...)")
    add_timeout_argument(u)
    add_join_timeout_argument(u)
    u.add_argument("--run-id", help="the run's id on the bus (default <scenario>-<seed>)")
    add_seed_argument(u, help="override the scenario's seed (same on every unit)")
    u.add_argument("--traces", action="store_true", help="log resonator traces")
    add_realtime_argument(u)
    add_engine_argument(
        u,
        help="the same on every unit of a run (event: the default; dense: the time-stepped "
        "reference)",
    )
    add_key_argument(u)
    add_tls_argument(u)
    _add_control(u)
    u.add_argument("--json", action="store_true", help="print one JSON object")
    add_quiet_argument(u)
    u.set_defaults(func=run_unit_cmd)


def _add_control(p: argparse.ArgumentParser) -> None:
    add_control_argument(
        p,
        "the run may be steered from Foxglove through rgtbus watch --control (the same "
        "flag on every unit of a run): each change applied at the same sample in every "
        "process (docs/foxglove.md)",
    )


def _add_launch(subparsers: SubParsers) -> None:
    la = subparsers.add_parser(
        "launch",
        help="run the units of a scenario as OS processes (one per unit, or --procs P)",
        description="Start the units of SCENARIO as separate processes (zenoh on loopback, free "
        "ports; or the zenoh options given, the same for every process), wait for all, merge "
        "their logs into one, and print the run's summary.",
    )
    la.add_argument("scenario", metavar="SCENARIO")
    la.add_argument(
        "--procs",
        type=int,
        metavar="P",
        help="run the units in P processes, as even groups in the scenario's order (default: "
        "one process per unit); the results and log content are the same",
    )
    la.add_argument("--traces", action="store_true", help="log resonator traces")
    add_zenoh_arguments(la)
    la.add_argument(
        "--log-dir",
        metavar="DIR",
        help="per-unit logs and the merged run.mcap (default logs/<scenario>-<time>/)",
    )
    la.add_argument(
        "--router",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="connect the units through a zenoh router process (--no-router: a full mesh; "
        "default: a mesh up to 16 processes, a router above)",
    )
    add_timeout_argument(
        la,
        "give up when no member has news for S seconds (default 10, stretched when the "
        "processes outnumber the cores: 10 x processes / cores)",
        default=None,
    )
    add_seed_argument(la)
    add_engine_argument(la, help="as for rgtbus run")
    add_realtime_argument(la)
    add_key_argument(la)
    add_tls_argument(
        la,
        help="the run's directory of TLS identities (rgtbus certs SCENARIO --out DIR): each "
        "unit's process proves itself with its own certificate (one unit a process), the mesh "
        "or --router on tls/ endpoints, under the run's access control (docs/hosts.md)",
    )
    _add_control(la)
    la.add_argument("--json", action="store_true", help="print one JSON object (as rgtbus run)")
    add_quiet_argument(la)
    la.set_defaults(func=run_launch)


def _add_router(subparsers: SubParsers) -> None:
    r = subparsers.add_parser(
        "router",
        help="a zenoh router for units on several machines",
        description="Open a zenoh session in router mode and route between client units until "
        "interrupted (Ctrl-C or SIGTERM).",
    )
    r.add_argument(
        "-l",
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (tls/... with --tls; repeatable)",
    )
    r.add_argument(
        "-c",
        "--config",
        dest="zenoh_config",
        metavar="FILE",
        help="a zenoh JSON5 config file (default: the file $ZENOH_CONFIG names, if set)",
    )
    add_tls_argument(
        r,
        help="the run's directory of TLS identities (rgtbus certs): the router proves itself "
        "with DIR/run/router.crt and holds every unit to its own keys (needs --scenario)",
    )
    r.add_argument(
        "--scenario",
        metavar="SCENARIO",
        help="with --tls: the run's scenario, whose roster the access control is made from",
    )
    r.add_argument(
        "--run-id",
        metavar="RUN_ID",
        help="with --tls: only this run's keys (default: any run of the roster)",
    )
    add_quiet_argument(r)
    r.add_argument(
        "--json",
        action="store_true",
        help="say it is listening as one JSON object (its endpoints), once it is",
    )
    r.set_defaults(func=run_router)


def _load(path: str, seed: int | None) -> Scenario:
    from rgtbus.scenario import load_scenario

    sc = load_scenario(path)
    return sc if seed is None else sc.with_seed(seed, "--seed")


def run_unit_cmd(args: argparse.Namespace) -> int:
    """``rgtbus unit``: ``run_logged_units`` of the units named, then a line or two each."""
    from rgtbus.cli.run_cmd import default_log_path
    from rgtbus.units.process import run_logged_units, unit_names

    sc = _load(args.scenario, args.seed)
    names = unit_names(args.name, sc)
    key = read_key(args)
    label = "+".join(names)
    log_path = Path(args.log) if args.log else default_log_path(f"{sc.name}-{label}")
    # SIGTERM (a launcher giving up) ends the run like Ctrl-C: the log is still finished.
    with interrupted_by(signal.SIGTERM, signal.SIGINT):
        try:
            outs = run_logged_units(
                sc, names, log_path, zenoh_options=zenoh_options(args), run_id=args.run_id,
                timeout=args.timeout, join_timeout=args.join_timeout, traces=args.traces,
                engine=args.engine, realtime=args.realtime, key=key, tls=args.tls,
                control=args.control,
            )  # fmt: skip
        except KeyboardInterrupt:
            print(f"rgtbus unit: {label}: interrupted", file=sys.stderr)
            return 130
    if args.json:  # one unit: its object, as ever; several: one object per unit, by name
        shown = outs[names[0]] if len(names) == 1 else outs
        print(json.dumps(shown, default=_columns_as_lists))
    else:
        _print_units(sc, outs, log_path)
    errors = list(dict.fromkeys(out["error"] for out in outs.values() if out["error"]))
    for error in errors:
        print(f"rgtbus unit: {error}", file=sys.stderr)
    return 1 if errors else 0


def _print_units(sc: Scenario, outs: dict[str, dict[str, Any]], log_path: Path) -> None:
    """Each unit's decision line and polynomial, as ``rgtbus run`` words them."""
    from rgtbus.cli.run_cmd import decision_text
    from rgtbus.summary import not_decomposable_text

    for name, out in outs.items():
        rep = out["report"]
        res = rep["result"]
        canonical = f"{res['canonical']}   " if res["decided"] else ""
        print(f"unit {name}: {canonical}{decision_text(sc.universe, name, res)}")
        poly = (
            f"(none): {not_decomposable_text(rep['p4'])}"
            if rep.get("p4")
            else rep["polynomial"] or "(none)"
        )
        print(
            f"  polynomial {poly}; {out['steps']} steps, {out['sim_seconds']:.1f} s "
            f"simulated in {out['wall_seconds']:.2f} s; log {log_path}"
        )


def _columns_as_lists(obj: Any) -> Any:
    """JSON for what a unit's output holds as columns (its decodes: rows as lists) or as a
    view of its tables (``PairTexts``: the dict)."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, PairTexts):
        return obj.to_dict()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def run_launch(args: argparse.Namespace) -> int:
    """``rgtbus launch``: ``rgtbus.launch``, then the summary and every failure; exit 130 when
    a SIGINT or SIGTERM stopped it, 1 when it failed."""
    from rgtbus.cli.run_cmd import print_summary
    from rgtbus.summary import summary_json
    from rgtbus.units.launch import launch

    result = launch(
        args.scenario, procs=args.procs, seed=args.seed, log_dir=args.log_dir,
        zenoh=zenoh_options(args), key_file=args.key_file, realtime=args.realtime,
        timeout=args.timeout, engine=args.engine, traces=args.traces, router=args.router,
        tls=args.tls, control=args.control,
    )  # fmt: skip
    if args.json:
        print(json.dumps(summary_json(result.details)))
    elif not args.quiet:  # held and thrown away
        print_summary(result.scenario, result.details)
    for msg in result.failures:
        print(f"launch: {msg}", file=sys.stderr)
    if result.interrupted:
        return 130
    return 1 if result.failures else 0


def run_router(args: argparse.Namespace) -> int:
    """``rgtbus router``: a zenoh router until SIGINT or SIGTERM."""
    from rgtbus.bus.config import ENV
    from rgtbus.units.process import open_router

    if not args.listen and not args.zenoh_config and not os.environ.get(ENV):
        raise BadInput(f"router: give at least one --listen ENDPOINT (or a --config, or {ENV})")
    roster: tuple[str, ...] = ()
    if args.tls is None and (args.scenario or args.run_id):
        raise BadInput("router: --scenario and --run-id are for --tls (its access control)")
    if args.tls is not None:
        if args.scenario is None:
            raise BadInput("router: --tls needs --scenario (the roster of the access control)")
        roster = _load(args.scenario, None).units
    session = open_router(
        args.listen or None, args.zenoh_config, tls=args.tls, roster=roster, run_id=args.run_id
    )
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.json:
        print(json.dumps({"router": "listening", "listen": list(args.listen or [])}), flush=True)
    else:
        print(f"router listening on {', '.join(args.listen) or '(config)'}", flush=True)
    try:
        while not stop.wait(0.5):
            pass
    finally:
        session.close()
    return 0
