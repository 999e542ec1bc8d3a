"""``rgtbus run SCENARIO``: the timed protocol simulation, logged to MCAP."""

from __future__ import annotations

import argparse
import json
import signal
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rgtbus.bus.registry import BUS_KINDS, bus_kinds
from rgtbus.cli import add_quiet_argument
from rgtbus.cli.arguments import (
    add_control_argument,
    add_engine_argument,
    add_key_argument,
    add_realtime_argument,
    add_seed_argument,
    read_key,
)
from rgtbus.cli.tables import fitted_table_lines, relations_lines, wrapped_table_lines
from rgtbus.errors import BadInput
from rgtbus.interrupts import interrupted_by, last_signal
from rgtbus.mind import goal_text
from rgtbus.misreads import decode_errors_line
from rgtbus.scenario import Scenario
from rgtbus.summary import not_decomposable_text

if TYPE_CHECKING:
    from rgtbus.cli import SubParsers
    from rgtbus.rgt.algebra import Universe
    from rgtbus.telemetry.control import Controller
    from rgtbus.telemetry.live import LiveView


def register(subparsers: SubParsers) -> None:
    """Add ``run``."""
    p = subparsers.add_parser(
        "run",
        help="run a scenario: units socialising over the medium, logged to MCAP",
        description="Run a scenario: every unit a SimPy process exchanging sampled waveforms over "
        "the bus, decoding with its own resonators and deciding by its own RGT inference.",
    )
    p.add_argument("scenario", metavar="SCENARIO", help="a scenario file, e.g. scenarios/gate.toml")
    p.add_argument(
        "--bus",
        choices=bus_kinds(),
        default=bus_kinds()[0],
        help="; ".join(f"{k.name}: {k.about}" for k in BUS_KINDS.values())
        + f" (default {bus_kinds()[0]}: an in-process session, no network)",
    )
    logs = p.add_mutually_exclusive_group()
    logs.add_argument(
        "--log", metavar="PATH", help="MCAP log (default logs/<scenario>-<time>.mcap)"
    )
    logs.add_argument(
        "--no-log",
        action="store_true",
        help="no log at all (speed runs; the summary is the same, nothing is written)",
    )
    add_seed_argument(p)
    add_realtime_argument(p)
    p.add_argument("--traces", action="store_true", help="log resonator y/x traces too")
    add_engine_argument(
        p,
        help="event: jump from event to event (the default); dense: the time-stepped "
        "reference, every window (same results)",
    )
    p.add_argument(
        "--check",
        action="store_true",
        help="verify the scenario's [expect] table; exit 1 if anything differs",
    )
    add_key_argument(p)
    add_live_arguments(p)
    _add_control(p)
    add_quiet_argument(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


LIVE_ADDRESS = "127.0.0.1:8765"  # Foxglove's own default for a WebSocket connection


def add_live_arguments(p: argparse.ArgumentParser) -> None:
    """``--live [HOST:PORT]`` and ``--live-wait SECONDS`` (``open_live`` reads them)."""
    p.add_argument(
        "--live",
        nargs="?",
        const=LIVE_ADDRESS,
        metavar="HOST:PORT",
        help=f"serve the run live to Foxglove over its WebSocket protocol (default "
        f"{LIVE_ADDRESS}; port 0: any free port); paced by --realtime (docs/foxglove.md)",
    )
    p.add_argument(
        "--live-wait",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="with --live: wait up to SECONDS for a client to subscribe before starting",
    )


def _add_control(p: argparse.ArgumentParser) -> None:
    add_control_argument(
        p,
        "with --live and --realtime: Foxglove clients may steer the run (parameters: "
        "channel.noise, channel.gains.a>b, channel.clock.drift.U, repair.budget, pace; "
        "services: pause, resume, "
        "step, relation, influence, mark), each change logged on /control/*; a keyed run's "
        "clients only after /control/auth (docs/foxglove.md)",
    )


def open_controller(
    args: argparse.Namespace, scenario: Scenario, key: bytes | None
) -> Controller | None:
    """The steering ``--control`` asks for (None without it); ``--live`` and ``--realtime``
    must come with it."""
    if not getattr(args, "control", False):
        return None
    if args.live is None:
        raise BadInput("--control goes with --live (clients steer the run through the live view)")
    if args.realtime is None:
        raise BadInput("--control goes with --realtime FACTOR (a run steered as it goes is paced)")
    from rgtbus.telemetry.control import Controller

    return Controller(scenario, key=key, pace=args.realtime)


def open_live(
    args: argparse.Namespace,
    advertise: list[tuple[str, str]],
    control: Controller | None = None,
) -> LiveView | None:
    """The live view ``--live`` asks for (None without it): listening, channels advertised,
    waited for a client if ``--live-wait``; its address on stderr. ``control``: it serves
    the run's steering too (``--control``)."""
    if args.live is None:
        if args.live_wait:
            raise BadInput("--live-wait goes with --live")
        return None
    if not args.live_wait >= 0:
        raise BadInput(f"--live-wait {args.live_wait}: must be 0 or more seconds")
    from rgtbus.telemetry.live import LiveView, parse_address

    host, port = parse_address(args.live)
    live = LiveView(host, port, realtime=args.realtime, control=control)
    live.advertise(advertise)
    print(f"live: {live.url} (Foxglove: Open connection, Foxglove WebSocket)", file=sys.stderr)
    if control is not None:
        keyed = "; keyed: /control/auth first" if control.key is not None else ""
        print(f"live: steering on (parameters and /control/* services{keyed})", file=sys.stderr)
    sys.stderr.flush()
    if args.live_wait and not live.wait_for_client(args.live_wait):
        print(f"live: no client after {args.live_wait:g} s; starting", file=sys.stderr)
    return live


def live_topics(units: Iterable[str], traces: bool) -> list[tuple[str, str]]:
    """Every (topic, schema) a run logs: advertised before it starts."""
    from rgtbus.telemetry import records, topics

    out = [(t, schema) for t, (schema, _) in topics.TOPICS.items()]
    if traces:
        traced = [records.trace_topic(u) for u in units]
        out += [(topic, topics.schema_for(topic)) for topic in traced]
    return out


def default_log_path(name: str) -> Path:
    """``logs/<name>-<date>-<time>.mcap``: the log of a run not given ``--log``."""
    from datetime import datetime  # imported here: only a log named by the time needs it

    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path("logs") / f"{name}-{stamp}.mcap"


class Progress:
    """The run's progress on stderr, a tqdm counter of simulated seconds (``t = 120.5 s
    simulated, step 3400``), drawn from 2 s of wall time on (a short run shows none) and at
    most twice a second; pacing is the world's (``--realtime``). ``show`` False: nothing."""

    def __init__(self, show: bool) -> None:
        self.bar: Any = None
        if not show:  # no tqdm import for a run that shows nothing (start-up time)
            return
        from tqdm import tqdm

        self.bar = tqdm(
            file=sys.stderr,
            delay=2.0,
            mininterval=0.5,
            leave=True,
            unit=" s",
            bar_format="  t = {n:.1f} s simulated{postfix}, {elapsed} wall",
        )
        self.bar.set_postfix_str("step 0", refresh=False)

    def __call__(self, sim_now: float, step: int) -> None:
        """The run is at ``sim_now`` simulated seconds, step ``step``."""
        if self.bar is None:
            return
        self.bar.set_postfix_str(f"step {step}", refresh=False)
        self.bar.update(sim_now - self.bar.n)  # tqdm draws it when mininterval has passed

    def done(self) -> None:
        """The run is over: the counter's last line stays."""
        if self.bar is not None:
            self.bar.close()


def run(args: argparse.Namespace) -> int:
    """``rgtbus run``: ``rgtbus.run`` with a log (and a live view), then the summary."""
    from rgtbus.api import run as run_scenario
    from rgtbus.scenario import load_scenario
    from rgtbus.summary import check_expectations, summary_json

    scenario = load_scenario(args.scenario)
    key = read_key(args)
    if args.no_log and (args.live is not None or args.traces):
        what = "--live" if args.live is not None else "--traces"
        raise BadInput(f"--no-log with {what}: {what} needs a log (it serves what is logged)")
    log_path = (
        None if args.no_log else Path(args.log) if args.log else default_log_path(scenario.name)
    )
    control = open_controller(args, scenario, key)
    live = open_live(args, live_topics(scenario.units, args.traces), control)
    progress = Progress(not (args.quiet or args.json) and sys.stderr.isatty())
    try:
        with interrupted_by(signal.SIGINT, signal.SIGTERM):  # SIGTERM ends it like Ctrl-C
            result = run_scenario(
                scenario,
                seed=args.seed,
                bus=args.bus,
                engine=args.engine,
                log=log_path,
                traces=args.traces,
                key=key,
                realtime=args.realtime,
                progress=progress,
                live=live,
                control=control,
            )
    except KeyboardInterrupt:
        progress.done()
        signum = last_signal() or signal.SIGINT
        name = signal.Signals(signum).name
        where = f"its log is cut there: {log_path} (replay --verify checks it that far)"
        print(f"rgtbus run: interrupted by {name}; " + (where if log_path else "no log"),
              file=sys.stderr)  # fmt: skip
        return 128 + int(signum)
    finally:
        progress.done()
    summary = result.details
    scenario = result.scenario

    checks = (
        judged_checks(check_expectations(scenario, summary), summary["error"]) if args.check else []
    )
    if args.json:
        out_json = summary_json(summary)
        if args.check:
            out_json["checks"] = [{"what": w, "ok": ok, "detail": d} for w, ok, d in checks]
        print(json.dumps(out_json))
    else:
        if not args.quiet:  # held and thrown away: a large group's summary is slow to lay out
            print_summary(scenario, summary)
        if args.check:
            print_checks(checks, summary["error"], quiet=args.quiet)
    if summary["error"]:
        if not args.json:
            print(f"run failed: {summary['error']}", file=sys.stderr)
        return 1
    if any(ok is False for _, ok, _ in checks):
        return 1
    return 0


NOT_JUDGED = "not judged: the run failed"


def judged_checks(
    checks: list[tuple[str, bool | None, str]], error: str | None
) -> list[tuple[str, bool | None, str]]:
    """The ``[expect]`` checks as ``run --check`` reports them: after a failed run none is
    judged (``ok`` None: what the failed run held is no result to pass or fail on; the run's
    exit code is 1 already)."""
    if error:
        return [(what, None, NOT_JUDGED) for what, _, _ in checks]
    return list(checks)


def print_checks(
    checks: list[tuple[str, bool | None, str]], error: str | None, *, quiet: bool = False
) -> None:
    """``checks:`` and one line a check (``ok``/``FAIL``); after a failed run one line saying
    they were not judged. ``quiet``: only the failed checks, on stderr."""
    if quiet:
        for what, ok, detail in checks:
            if ok is False:
                print(f"check failed: {what}: {detail}", file=sys.stderr)
        return
    if error:
        print(f"checks: {NOT_JUDGED} ({error})")
        return
    print("checks:")
    for what, ok, detail in checks:
        mark = "ok  " if ok else "skip" if ok is None else "FAIL"  # skip: left out, said why
        print(f"  {mark} {what}{'' if ok else ': ' + detail}")


def decision_cells(universe: Universe, name: str, v: dict[str, Any]) -> tuple[str, str]:
    """Unit ``name``'s decision as every command prints it (one rule: ``rgtbus run``,
    ``launch`` and ``unit``), as (verdict, choice): ``no decision`` or ``frustrated: no
    decision`` with no choice, or its interval [B, A] (``a = {beta}`` when B = A, else
    ``1 ⊇ a ⊇ {beta}``) and ``choice X``, alternatives in set notation. ``v``: the decision's
    fields (``rgtbus.mind.result_fields``)."""
    if not v["decided"]:
        return "no decision", ""
    if v["frustrated"]:
        return "frustrated: no decision", ""
    lo, hi = (universe.format(universe.from_list(x)) for x in v["interval"])
    interval = f"{name} = {lo}" if lo == hi else f"{hi} ⊇ {name} ⊇ {lo}"
    return interval, f"choice {universe.format(universe.from_list(v['choice']))}"


def decision_text(universe: Universe, name: str, v: dict[str, Any]) -> str:
    """``decision_cells`` on one line (``rgtbus unit``; ``run`` puts them in columns)."""
    return "  ".join(c for c in decision_cells(universe, name, v) if c)


def goal_line(universe: Universe, g: dict[str, Any]) -> str:
    """One judged goal (``summary["goals"]``) as ``run`` prints it."""
    lo, hi = (universe.from_list(x) for x in g["want"])
    verdict = {True: "reached", False: "NOT reached", None: "no decision"}[g["reached"]]
    could = {True: "reachable", False: "unreachable", None: "?"}[g["reachable"]]
    share = "" if g["share"] is None else f", steerable for {g['share']:.0%} of influences"
    what = goal_text(g["target"], lo, hi, g["mode"], universe)
    return f"{g['unit']} wants {what}: {verdict} ({could}{share})"


def print_summary(scenario: Scenario, s: dict[str, Any]) -> None:
    """The run's summary ``s`` as ``rgtbus run`` (and ``launch``) print it: relations,
    polynomial, influences, decisions, rounds, goals, outcome, decode errors, time, log."""
    u = scenario.universe
    units = scenario.units
    print(
        f"scenario {s['scenario']} (seed {s['seed']}): {', '.join(units)}; "
        f"actions {', '.join(u.actions)}"
    )
    print("relationships decoded by each unit:")
    for line in relations_lines(units, s["unit_relations"], missing="no report: the unit failed"):
        print(line)
    print(f"  all units agree: {'yes' if s['agree'] else 'NO'}")
    if s.get("p4"):  # a random group can install one: a result, the run still succeeds
        print(f"polynomial: (none): {not_decomposable_text(s['p4'])}")
    else:
        print(f"polynomial: {s['polynomial'] or '(none)'}")
    if s["influences"]:
        print("influences (row influences column):")
        rows = []
        for src in units:
            row = [src]
            for dst in units:
                v = s["influences"].get(f"{src}>{dst}")
                row.append(
                    dst if src == dst else (u.format(u.from_list(v)) if v is not None else "?")
                )
            rows.append(row)
        for line in wrapped_table_lines(rows, ["", *units]):
            print(line)
    print("decisions:")
    decided = [
        [v["canonical"], *decision_cells(u, name, v)]
        for name in units
        if (v := s["units"].get(name)) is not None and v["decided"]
    ]
    table = iter(fitted_table_lines(decided))
    for name in units:
        v = s["units"].get(name)
        if v is None:
            print(f"  {name}: no report (the unit failed)")
        elif not v["decided"]:
            print(f"  {name}: {decision_text(u, name, v)}")
        else:
            print(next(table))
    rounds = s.get("rounds") or {}
    if rounds.get("count", 1) > 1:
        state = rounds.get("state")
        since = f" from round {rounds['since']}" if rounds.get("since") else ""
        length = f" of length {rounds['length']}" if state == "cycle" else ""
        print(f"influence rounds: {rounds['count']}; influences: {state}{length}{since}")
    for g in s.get("goals") or []:
        print(f"goal: {goal_line(u, g)}")
    if s["outcome"] is not None:
        print(f"outcome: {s['outcome']}")
    steered = s.get("steered")
    if steered is not None:  # --control: what the truth it was judged against accounts for
        print(
            f"steered: {steered['influences']} influences injected, {steered['relations']} "
            "relations edited (judged against the forward task with them; the log's /control/*)"
        )
    print(decode_errors_line(s["decode_errors"]))
    print(
        f"time: {s['sim_seconds']:.1f} s simulated in {s['wall_seconds']:.2f} s wall "
        f"({s['engine']} engine, {s['steps']} steps)"
    )
    print(f"log: {s.get('log') or 'none (--no-log)'}")
