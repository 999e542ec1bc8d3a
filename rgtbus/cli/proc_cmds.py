"""Cross-process runs: ``rgtbus unit``, ``rgtbus launch`` and ``rgtbus router``."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Collection, Mapping, Sequence
from pathlib import Path
from typing import Any

from rgtbus.cli import add_quiet_argument
from rgtbus.cli.arguments import add_key_argument, read_key
from rgtbus.cli.interrupts import interrupted_by
from rgtbus.errors import RgtbusError


def _zenoh_arguments(p: argparse.ArgumentParser) -> None:
    # zenoh's own spelling: -m/--mode, -e/--connect, -l/--listen, -c/--config. No defaults
    # here (None = not given): a --config file's own values must survive what was not typed.
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
        help="zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    p.add_argument(
        "-l",
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="zenoh endpoint to listen on, e.g. tcp/127.0.0.1:7448 (repeatable)",
    )
    p.add_argument(
        "-c",
        "--config",
        "--zenoh-config",
        dest="zenoh_config",
        metavar="FILE",
        help="a zenoh JSON5 config file (the options above, where given, override it)",
    )
    p.add_argument(
        "--multicast",
        action="store_true",
        default=None,
        help="turn zenoh's multicast scouting on (off unless asked or set in --config)",
    )


def register(subparsers: argparse._SubParsersAction) -> None:
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
    _zenoh_arguments(u)
    u.add_argument("--log", metavar="PATH", help="this process's MCAP log (default logs/...)")
    u.add_argument(
        "--timeout",
        type=float,
        default=10.0,
        metavar="S",
        help="give up when no member has news for S seconds (default 10)",
    )
    u.add_argument(
        "--join-timeout",
        type=float,
        default=30.0,
        metavar="S",
        help="give up when not every unit has joined within S seconds (default 30)",
    )
    u.add_argument("--run-id", help="the run's id on the bus (default <scenario>-<seed>)")
    u.add_argument("--seed", type=int, help="override the scenario's seed (same on every unit)")
    u.add_argument("--traces", action="store_true", help="log resonator traces")
    u.add_argument(
        "--realtime",
        type=float,
        metavar="FACTOR",
        help="pace the run: FACTOR simulated seconds per wall second",
    )
    u.add_argument(
        "--engine",
        choices=("event", "dense"),
        default="event",
        help="the same on every unit of a run (event: the default; dense: the time-stepped "
        "reference)",
    )
    add_key_argument(u)
    u.add_argument("--json", action="store_true", help="print one JSON object")
    add_quiet_argument(u)
    u.set_defaults(func=run_unit_cmd)

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
    _zenoh_arguments(la)
    la.add_argument(
        "--log-dir",
        metavar="DIR",
        help="per-unit logs and the merged run.mcap (default logs/<scenario>-<time>/)",
    )
    la.add_argument(
        "--router",
        action="store_true",
        help="connect the units through a zenoh router process instead of a mesh",
    )
    la.add_argument(
        "--timeout",
        type=float,
        default=10.0,
        metavar="S",
        help="give up when no member has news for S seconds (default 10)",
    )
    la.add_argument("--seed", type=int, help="override the scenario's seed")
    la.add_argument(
        "--engine", choices=("event", "dense"), default="event", help="as for rgtbus run"
    )
    la.add_argument(
        "--realtime",
        type=float,
        metavar="FACTOR",
        help="pace the run: FACTOR simulated seconds per wall second",
    )
    add_key_argument(la)
    la.add_argument("--json", action="store_true", help="print one JSON object (as rgtbus run)")
    add_quiet_argument(la)
    la.set_defaults(func=run_launch)

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
        help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)",
    )
    r.add_argument(
        "-c", "--config", dest="zenoh_config", metavar="FILE", help="a zenoh JSON5 config file"
    )
    add_quiet_argument(r)
    r.set_defaults(func=run_router)


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


def _load(path: str, seed: int | None):
    from rgtbus.scenario import load_scenario

    sc = load_scenario(path)
    if seed is not None:
        if seed < 0:
            raise RgtbusError(f"--seed {seed}: must be a non-negative integer")
        sc = sc.with_seed(seed)
    return sc


def run_unit_cmd(args: argparse.Namespace) -> int:
    from rgtbus.cli.run_cmd import decision_text, default_log_path
    from rgtbus.summary import not_decomposable_text
    from rgtbus.telemetry.logfile import close_log, open_log
    from rgtbus.units.process import run_units

    sc = _load(args.scenario, args.seed)
    names = unit_names(args.name, sc)
    for what in ("timeout", "join_timeout"):
        if not getattr(args, what) > 0:
            raise RgtbusError(f"--{what.replace('_', '-')} must be positive seconds")
    if args.realtime is not None and not args.realtime > 0:
        raise RgtbusError(f"--realtime {args.realtime}: must be a positive factor")
    key = read_key(args)
    label = "+".join(names)
    log_path = Path(args.log) if args.log else default_log_path(f"{sc.name}-{label}")
    stream, recorder = open_log(log_path)
    # SIGTERM (a launcher giving up) ends the run like Ctrl-C: the log is still finished.
    with interrupted_by(signal.SIGTERM, signal.SIGINT):
        try:
            outs = run_units(
                sc,
                names,
                recorder,
                zenoh_options=zenoh_options(args),
                run_id=args.run_id,
                timeout=args.timeout,
                join_timeout=args.join_timeout,
                traces=args.traces,
                engine=args.engine,
                realtime=args.realtime,
                key=key,
            )
        except KeyboardInterrupt:
            if not recorder.failed:
                for name in names:
                    recorder.log("error", f"{name}: interrupted", 0, name=name)
            print(f"rgtbus unit: {label}: interrupted", file=sys.stderr)
            return 130
        finally:
            close_log(stream, recorder)
    for out in outs.values():
        out["log"] = str(log_path)
    if args.json:  # one unit: its object, as ever; several: one object per unit, by name
        shown = outs[names[0]] if len(names) == 1 else outs
        print(json.dumps(shown, default=_columns_as_lists))
    else:
        for name, out in outs.items():
            rep = out["report"]
            res = rep["result"]
            # The decision line and polynomial of ``rgtbus run``: one formatting rule for both.
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
    errors = list(dict.fromkeys(out["error"] for out in outs.values() if out["error"]))
    for error in errors:
        print(f"rgtbus unit: {error}", file=sys.stderr)
    return 1 if errors else 0


def _columns_as_lists(obj: Any) -> Any:
    """JSON for what a unit's output holds as columns (its decodes): rows as lists."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def unit_names(text: str, sc: Any) -> list[str]:
    """``a`` or ``a,b,c``: the units one process runs (each a unit of the scenario, once)."""
    names = [n.strip() for n in text.split(",")]
    for name in names:
        if name not in sc.units:
            raise RgtbusError(f"unknown unit {name!r} (units of {sc.name}: {', '.join(sc.units)})")
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise RgtbusError(f"unit {dup!r} named twice in {text!r}")
    return names


def free_ports(n: int) -> list[int]:
    """n distinct free TCP ports on loopback (held open together, so no two are the same)."""
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def _die_with_parent() -> None:
    """In a child: ask Linux for SIGTERM when the launcher dies, so no unit is left behind even
    if the launcher is killed outright (best effort elsewhere)."""
    with contextlib.suppress(Exception):
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def _unit_child(
    conn: Any,
    sc: Any,
    names: list[str],
    log: Path,
    net: dict[str, Any],
    after: list[Any],
    listening: Any,
    **opts: Any,
) -> None:
    """The units ``names`` of a launch, in their own forked process: what ``rgtbus unit``
    does, the result (``{"units": {name: output}}``, or ``{"crash": why}``) sent back on
    ``conn``. It opens its session once the peers it connects to listen (``after``), and
    says when it listens itself (``listening``)."""
    from rgtbus.telemetry.logfile import close_log, open_log
    from rgtbus.units.process import run_units

    _die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the launcher's to handle
    out: dict[str, Any]
    with interrupted_by(signal.SIGTERM):  # a launcher stopping its units
        try:
            for ev in after:  # bounded: a peer that never listens is named by the join
                ev.wait(10.0)
            stream, recorder = open_log(log)
            try:
                outs = run_units(
                    sc,
                    names,
                    recorder,
                    zenoh_options=net,
                    join_timeout=30.0,
                    on_open=listening.set,
                    **opts,
                )
                for o in outs.values():
                    o["log"] = str(log)
                out = {"units": outs}
            except KeyboardInterrupt:
                if not recorder.failed:
                    for name in names:
                        recorder.log("error", f"{name}: interrupted", 0, name=name)
                out = {"crash": "interrupted"}
            finally:
                close_log(stream, recorder)
        except RgtbusError as exc:
            out = {"crash": str(exc)}
        except BaseException as exc:  # a bug: say what, not a traceback on the launcher's terminal
            out = {"crash": f"{type(exc).__name__}: {exc}"}
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # done: being stopped now loses nothing
    conn.send(out)
    conn.close()


def _router_child(conn: Any, endpoint: str) -> None:
    import zenoh

    from rgtbus.bus.zenoh import make_config

    _die_with_parent()
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    session = zenoh.open(make_config(mode="router", listen=[endpoint], multicast=False))
    try:
        conn.send("listening")
        while not stop.wait(0.5):
            pass
    finally:
        session.close()


_FEW_SECONDS = 5.0  # for the other units to report once one has said a member went silent


def _size(path: Path | None) -> int:
    """A log's size so far (-1: none yet): a unit that still writes is still running."""
    try:
        return -1 if path is None else os.stat(path).st_size
    except OSError:
        return -1


class Launch:
    """The processes of a launch, forked from the launcher once it has loaded everything (so
    a unit starts in milliseconds), always reaped: terminate, then kill what is left."""

    def __init__(self) -> None:
        import multiprocessing

        self._mp = multiprocessing.get_context("fork")
        self.procs: dict[str, Any] = {}
        self._results: dict[str, Any] = {}
        self._listening: dict[str, Any] = {}
        self._logs: dict[str, Path] = {}

    def start_process(
        self,
        name: str,
        units: list[str],
        sc: Any,
        log: Path,
        net: dict[str, Any],
        after: list[str],
        **opts: Any,
    ) -> None:
        """Fork process ``name`` running ``units``; it opens its session once the processes
        ``after`` listen."""
        reader, writer = self._mp.Pipe(duplex=False)
        self._listening[name] = self._mp.Event()
        waits = [self._listening[p] for p in after]
        proc = self._mp.Process(
            target=_unit_child,
            args=(writer, sc, units, log, net, waits, self._listening[name]),
            kwargs=opts,
            name=name,
        )
        proc.start()
        writer.close()
        self.procs[name] = proc
        self._results[name] = reader
        self._logs[name] = log

    def start_router(self, endpoint: str, timeout: float) -> None:
        reader, writer = self._mp.Pipe(duplex=False)
        proc = self._mp.Process(target=_router_child, args=(writer, endpoint), name="router")
        proc.start()
        writer.close()
        self.procs["router"] = proc
        if not reader.poll(timeout):
            raise RgtbusError(f"router did not start within {timeout:g} s")
        reader.recv()

    def collect(self, limit: float, timeout: float) -> dict[str, dict[str, Any]]:
        """Every process's result as it comes, at most ``limit`` seconds in all. Once one has
        died or crashed, the others notice within their ``timeout`` (no news): a process gets
        that and a few seconds more since its log last grew (a paced one may still be running
        up to where the dead one had promised, seconds of wall time); once one reports that a
        member went silent, the rest get a few seconds since theirs did. A process that is
        still quiet then is stalled (absent from the result). A process that dies without a
        result gets ``{"died": exit code}``."""
        from multiprocessing.connection import wait

        out: dict[str, dict[str, Any]] = {}
        waiting = dict(self._results)
        end = time.monotonic() + limit
        quiet: float | None = None  # once a run has failed: how long a process may not write
        grew: dict[str, tuple[int, float]] = {}  # its log's size, and when it was last seen
        while waiting:
            now = time.monotonic()
            if quiet is not None:
                for name in list(waiting):
                    size = _size(self._logs.get(name))
                    if name not in grew or size != grew[name][0]:
                        grew[name] = (size, now)
                    elif now - grew[name][1] > quiet:  # no record for that long: stalled
                        del waiting[name]
                if not waiting:
                    break
            step = end - now if quiet is None else min(end - now, 0.25)
            ready = wait(list(waiting.values()), timeout=max(0.0, step))
            if not ready:
                if time.monotonic() >= end:
                    break
                continue
            for name, conn in list(waiting.items()):
                if conn not in ready:
                    continue
                try:
                    out[name] = conn.recv()
                except (EOFError, OSError):  # the process ended without a word
                    proc = self.procs[name]
                    proc.join(timeout=5.0)
                    out[name] = {"died": proc.exitcode}
                del waiting[name]
                said = out[name]
                grace = None
                if "died" in said or said.get("crash"):
                    grace = timeout + _FEW_SECONDS
                elif any(o.get("world_failure") for o in said.get("units", {}).values()):
                    grace = _FEW_SECONDS
                if grace is not None:
                    quiet = grace if quiet is None else min(quiet, grace)
        return out

    def late_results(self, names: list[str], timeout: float) -> dict[str, dict[str, Any]]:
        """What processes that were asked to stop still said (within ``timeout`` s in all)."""
        out: dict[str, dict[str, Any]] = {}
        end = time.monotonic() + timeout
        for name in names:
            conn = self._results[name]
            with contextlib.suppress(EOFError, OSError):
                if conn.poll(max(0.0, end - time.monotonic())):
                    out[name] = conn.recv()
        return out

    def stop(self, names: list[str]) -> None:
        """Ask processes to stop: SIGTERM (its units then finish the log and say so), and
        SIGCONT so that a stopped (SIGSTOP) one can."""
        for name in names:
            p = self.procs[name]
            if p.is_alive() and p.pid is not None:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(p.pid, signal.SIGTERM)
                    os.kill(p.pid, signal.SIGCONT)

    def reap(self) -> None:
        """Every process ended: given a moment to leave on its own (a unit that has sent its
        result is closing its session), then asked to stop, then killed."""
        grace = time.monotonic() + 1.0
        for name, p in self.procs.items():
            if name != "router":
                p.join(timeout=max(0.0, grace - time.monotonic()))
        self.stop([n for n in self.procs if n != "router"])
        router = self.procs.get("router")
        if router is not None and router.is_alive():
            router.terminate()
        deadline = time.monotonic() + 5
        for p in self.procs.values():
            p.join(timeout=max(0.1, deadline - time.monotonic()))
            if p.is_alive():
                p.kill()
                p.join()


def _signal_name(code: int | None) -> str:
    if code is None:
        return "no exit code"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


def _where(log: Path, window: float) -> str:
    """Where a unit's log ends: its last message's time and window (logs are flushed as the
    run goes, so this is at most about a second of simulated time before the unit stopped)."""
    from rgtbus.telemetry.scan import scan_log
    from rgtbus.timebase import seconds

    if not log.exists():
        return "before it opened its log"
    try:
        raw = scan_log(log)
    except RgtbusError:
        return "(its log is unreadable)"
    last = max((m[1] for m in raw.messages), default=None)
    if last is None:
        return "before it logged a message"
    t = seconds(last)
    return f"in window {int(t / window)} (its log ends at t = {t:.3f} s)"


def unit_failures(
    units: list[str],
    results: dict[str, dict[str, Any]],
    logs: Mapping[str, Path],
    window: float,
    stopped: Collection[str] = (),
) -> tuple[list[str], dict[str, dict[str, Any]]]:
    """The failures of a launch, root causes first (a unit that died or crashed; then one that
    stalled; then the units that failed for want of them), and the outputs of every unit that
    reported (its share of the summary), those the launcher had to stop (``stopped``)
    included: a healthy unit stopped after another died keeps what it knew."""
    died: list[str] = []
    stalled: list[str] = []
    knock_on: list[str] = []
    outputs: dict[str, dict[str, Any]] = {}
    for name in units:
        out = results.get(name)
        log = logs[name]
        if out is None:
            stalled.append(f"unit {name} stalled {_where(log, window)}: no result, stopped")
        elif "died" in out:
            died.append(f"unit {name} died ({_signal_name(out['died'])}) {_where(log, window)}")
        elif "crash" in out:
            died.append(f"unit {name}: {out['crash']}")
        else:
            outputs[name] = out
            if name in stopped:
                stalled.append(f"unit {name} stalled {_where(log, window)}: stopped")
            elif out["error"]:
                knock_on.append(f"unit {name}: {out['error']}")
    if died:  # the units the launcher stopped were waiting for the dead one: not a cause
        knock_on = [
            f"unit {n}: stopped while waiting for the others" for n in units if n in stopped
        ] + knock_on
        stalled = [x for x in stalled if not x.endswith(": stopped")]
    return died + stalled + knock_on, outputs


def run_launch(args: argparse.Namespace) -> int:
    """Fork every unit, collect their results, and always end with a merged ``run.mcap``
    whose ``/run`` record names the first failure; SIGINT and SIGTERM stop the units (their
    logs finished) and still merge."""
    from rgtbus.units.group import default_run_id

    t0 = time.perf_counter()
    sc = _load(args.scenario, args.seed)
    if not args.timeout > 0:
        raise RgtbusError("--timeout must be positive seconds")
    if args.realtime is not None and not args.realtime > 0:
        raise RgtbusError(f"--realtime {args.realtime}: must be a positive factor")
    key = read_key(args)
    groups = process_groups(sc.units, args.procs)
    net_given = {k: v for k, v in zenoh_options(args).items() if v is not None}
    if net_given.get("listen") and len(groups) > 1:
        raise RgtbusError(
            f"-l/--listen with {len(groups)} processes: each would listen on the same "
            "endpoint (give --procs 1, or -e/--connect to a router, or no endpoint at all)"
        )
    stamp = time.strftime("%Y%m%d-%H%M%S")
    log_dir = Path(args.log_dir) if args.log_dir else Path("logs") / f"{sc.name}-{stamp}"
    try:
        log_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RgtbusError(f"cannot create log dir {str(log_dir)!r}: {exc.strerror}") from None
    # one process per unit: its log is <unit>.mcap; several units a process: proc-<i>.mcap
    logs = {p: log_dir / f"{p}.mcap" for p in groups}
    stale = [log_dir / f"{u}.mcap" for u in sc.units] + [log_dir / "launch.mcap"]
    for path in [*stale, *(log_dir.glob("proc-*.mcap"))]:
        with contextlib.suppress(FileNotFoundError):  # never merge an earlier launch's log
            path.unlink()
    run_id = f"{default_run_id(sc)}-{os.getpid()}"  # never mixes with another launch's traffic
    # Loaded once here, before the units are forked (numpy loads numpy.random lazily).
    import numpy.random  # noqa: F401

    import rgtbus.bus.zenoh
    import rgtbus.units.process  # noqa: F401

    launch = Launch()
    results: dict[str, dict[str, Any]] = {}  # by process
    interrupted: str | None = None
    procs = list(groups)
    with interrupted_by(signal.SIGTERM, signal.SIGINT):  # SIGTERM ends a launch like Ctrl-C
        try:
            try:
                ports = free_ports(len(procs) + 1)
                if args.router:
                    router_ep = f"tcp/127.0.0.1:{ports[-1]}"
                    launch.start_router(router_ep, timeout=10.0)
                for i, name in enumerate(procs):
                    if net_given:  # the user's zenoh options, the same for every process
                        net = dict(zenoh_options(args))
                        after: list[str] = []
                    elif args.router:
                        net = {"mode": "client", "connect": [router_ep]}
                        after = []
                    else:  # a full mesh: each listens on its port and connects to those before it
                        net = {
                            "listen": [f"tcp/127.0.0.1:{ports[i]}"],
                            "connect": [f"tcp/127.0.0.1:{p}" for p in ports[:i]],
                        }
                        after = procs[:i]
                    launch.start_process(
                        name,
                        groups[name],
                        sc,
                        logs[name],
                        net,
                        after,
                        run_id=run_id,
                        timeout=args.timeout,
                        engine=args.engine,
                        realtime=args.realtime,
                        key=key,
                        traces=args.traces,
                    )
                # A run ends by itself within its simulated length (paced: at the realtime factor)
                # plus the join; after a failure the others end within their --timeout.
                paced = sc.timing.max_seconds / args.realtime if args.realtime else 0.0
                limit = paced + 60 + sc.timing.max_seconds / 10 + 2 * args.timeout
                results = launch.collect(limit, timeout=args.timeout)
            except KeyboardInterrupt:
                interrupted = "launch interrupted (SIGINT or SIGTERM): units stopped"
            running = [p for p in procs if p not in results and p in launch.procs]
            launch.stop(running)
            late = launch.late_results(running, timeout=10.0)
            # a process asked to stop reports what its units knew (their share of the summary);
            # one that could not say even that is named as stalled
            results.update({p: out for p, out in late.items() if "units" in out})
        finally:
            launch.reap()
    by_unit: dict[str, dict[str, Any]] = {}
    for p, said in results.items():
        for u in groups[p]:
            by_unit[u] = said["units"][u] if "units" in said else said
    stopped = set() if interrupted is not None else {u for p in running for u in groups[p]}
    unit_logs = {u: logs[p] for p, us in groups.items() for u in us}
    failures, outputs = unit_failures(
        list(sc.units), by_unit, unit_logs, sc.timing.window, stopped=stopped
    )
    if interrupted is not None:
        failures.insert(0, interrupted)
    return _finish_launch(args, sc, run_id, log_dir, outputs, failures, t0, interrupted, logs)


def process_groups(units: Sequence[str], procs: int | None) -> dict[str, list[str]]:
    """The units of each process of a launch, by process name: one process per unit (named
    by its unit) by default; with ``procs`` P, P even groups in the scenario's order, named
    ``proc-<i>``."""
    if procs is None:
        return {u: [u] for u in units}
    if isinstance(procs, bool) or not isinstance(procs, int) or not 1 <= procs <= len(units):
        raise RgtbusError(f"--procs {procs}: must be 1 to {len(units)} (the number of units)")
    size, extra = divmod(len(units), procs)
    out: dict[str, list[str]] = {}
    at = 0
    for i in range(procs):
        n = size + (i < extra)
        out[f"proc-{i}"] = list(units[at : at + n])
        at += n
    return out


def _finish_launch(
    args: argparse.Namespace,
    sc: Any,
    run_id: str,
    log_dir: Path,
    outputs: dict[str, dict[str, Any]],
    failures: list[str],
    t0: float,
    interrupted: str | None,
    process_logs: Mapping[str, Path],
) -> int:
    """Write ``launch.mcap`` (metadata, the run's summary, every failure) and merge it with
    every process log that has anything in it into ``run.mcap``; print the summary."""
    from rgtbus.cli.run_cmd import print_summary
    from rgtbus.engine.sim import WorldResult
    from rgtbus.summary import summarise, summary_json
    from rgtbus.telemetry.logfile import close_log, open_log
    from rgtbus.telemetry.merge import merge_logs
    from rgtbus.telemetry.scan import scan_log
    from rgtbus.timebase import ns
    from rgtbus.units.group import auth_name, write_metadata, write_run_summary

    reports = [outputs[u]["report"] for u in sc.units if u in outputs]
    first = next((outputs[u] for u in sc.units if u in outputs), None)
    result = WorldResult(
        steps=first["steps"] if first else 0,
        sim_seconds=max((o["sim_seconds"] for o in outputs.values()), default=0.0),
        wall_seconds=time.perf_counter() - t0,
        failure=failures[0] if failures else None,
        bus_stats={u: o["bus"] for u, o in outputs.items()},
    )
    summary = summarise(sc, reports, result, engine=args.engine)
    merged = log_dir / "run.mcap"
    f, rec = open_log(log_dir / "launch.mcap")
    try:
        write_metadata(rec, sc, "zenoh", run_id, process="launch", auth=auth_name(read_key(args)))
        for msg in failures:
            rec.log("error", msg, ns(result.sim_seconds), name="launch")
        write_run_summary(rec, summary)
    finally:
        close_log(f, rec)
    logs = []
    for path in [*process_logs.values(), log_dir / "launch.mcap"]:
        if not path.exists() or path.stat().st_size == 0:
            continue  # a unit that died before its log's first byte: named in the failures
        try:
            logs.append(scan_log(path))
        except RgtbusError as exc:
            failures.append(f"log {path.name} left out of run.mcap: {exc}")
    try:
        with open(merged, "wb") as out:
            merge_logs(logs, out)
    except OSError as exc:
        raise RgtbusError(f"cannot write log {str(merged)!r}: {exc.strerror}") from None
    summary["log"] = str(merged)
    if args.json:
        print(json.dumps(summary_json(summary)))
    elif not args.quiet:  # held and thrown away
        print_summary(sc, summary)
    for msg in failures:
        print(f"launch: {msg}", file=sys.stderr)
    if interrupted is not None:
        return 130
    return 1 if failures else 0


def run_router(args: argparse.Namespace) -> int:
    import zenoh

    from rgtbus.bus.zenoh import make_config, zenoh_reason

    if not args.listen and not args.zenoh_config:
        raise RgtbusError("router: give at least one --listen ENDPOINT (or a --config)")
    cfg = make_config(
        mode="router",
        listen=args.listen or None,
        config=args.zenoh_config,
        multicast=None if args.zenoh_config else False,
    )
    try:
        session = zenoh.open(cfg)
    except Exception as exc:
        raise RgtbusError(
            f"router: cannot open a zenoh router on {args.listen}: {zenoh_reason(exc)}"
        ) from None
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    print(f"router listening on {', '.join(args.listen) or '(config)'}", flush=True)
    try:
        while not stop.wait(0.5):
            pass
    finally:
        session.close()
    return 0
