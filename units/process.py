"""Units in an OS process of their own, synchronised with the other processes over zenoh.

The process holds its ``AutonomousUnit``s (one, or several: ``rgtbus launch --procs P``) and the
run's zenoh bus with those units local. It joins the run (a barrier: every member up, on the
same scenario and seed), then runs the same ``World`` as a single-process run: it advances to
the smallest promise of all members (conservative synchronisation, docs/engine.md), or window
by window with ``engine="dense"``. The decisions and the log content equal the single-process
run of the same scenario and seed. ``open_router`` opens the zenoh router that units on several
machines can meet at.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from rgtbus.units.group import (
    auth_name,
    default_run_id,
    write_metadata,
)
from rgtbus.units.unit import AutonomousUnit

from rgtbus.bus import drop_summary, open_bus
from rgtbus.bus.hello import join_seconds
from rgtbus.bus.registry import cross_process_kind
from rgtbus.bus.steer_link import SteerLink
from rgtbus.bus.zenoh import ZenohBus
from rgtbus.engine.sim import World, WorldResult
from rgtbus.engine.steering import Steering
from rgtbus.errors import BadInput, IOFailure, RgtbusError
from rgtbus.scenario import Scenario
from rgtbus.telemetry import McapRecorder, Recorder
from rgtbus.telemetry.topics import UNIT_DONE, UNIT_ENDED_EARLY, unit_end_record
from rgtbus.timebase import ns


class PauseWatch:
    """The longest time this process did not run while the watch was on: a thread ticks a few
    times a second; a process stopped (SIGSTOP, a suspended machine) or starved of CPU sees a
    gap between two ticks as long as it was away."""

    TICK = 0.2  # seconds between ticks

    def __init__(self) -> None:
        self.longest = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._tick, name="rgtbus-pause-watch", daemon=True)

    def __enter__(self) -> PauseWatch:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()

    def _tick(self) -> None:
        last = time.monotonic()
        while not self._stop.wait(self.TICK):
            now = time.monotonic()
            self.longest = max(self.longest, now - last - self.TICK)
            last = now


def lateness(
    names: Sequence[str], sc: Scenario, silent: Sequence[str], paused: float, timeout: float
) -> str | None:
    """Why the units ``names`` of this process, not the members they heard nothing from,
    are the late ones when a run gave up on ``silent``: this process did not run for at
    least half the timeout (``paused`` s: stopped, or starved), or it heard nothing from any
    other member (it is cut off, or it came back after the others had gone on without it).
    None when the silent members are the cause."""
    if not silent:
        return None
    label = f"unit{'s' if len(names) > 1 else ''} {', '.join(names)}"
    if paused >= timeout / 2:
        return (
            f"{label}: its process did not run for {paused:.1f} s (stopped, or starved of CPU), "
            f"half the {timeout:g} s timeout or more: the others gave up on it; it is the late one"
        )
    others = [u for u in sc.units if u not in names]
    if len(others) > 1 and set(silent) >= set(others):
        return (
            f"{label}: no news from any other member for {timeout:g} s: its process is cut off "
            "from the run (its link?) or came back after the others had gone on without it"
        )
    return None


def scenario_digest(sc: Scenario) -> str:
    """What every process of one run must share: the scenario text and the seed."""
    return hashlib.sha256(f"{sc.text}\0seed={sc.seed}".encode()).hexdigest()


def _write_end(recorder: Recorder, name: str, status: str, detail: str, sim: float) -> None:
    """How this unit's process ended, as a metadata record (never raises: a log that cannot be
    written has said so already)."""
    if getattr(recorder, "failed", None) or getattr(recorder, "closed", False):
        return
    with contextlib.suppress(RgtbusError):
        recorder.metadata(
            unit_end_record(name),
            {"status": status, "detail": detail, "sim_seconds": repr(round(sim, 6))},
        )


def unit_names(text: str, sc: Scenario) -> list[str]:
    """``a`` or ``a,b,c``: the units one process runs (each a unit of the scenario, once)."""
    names = [n.strip() for n in text.split(",")]
    for name in names:
        if name not in sc.units:
            raise BadInput(f"unknown unit {name!r} (units of {sc.name}: {', '.join(sc.units)})")
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise BadInput(f"unit {dup!r} named twice in {text!r}")
    return names


def run_unit(sc: Scenario, name: str, recorder: Recorder, **options: Any) -> dict[str, Any]:
    """Run unit ``name`` of ``sc`` in this process (``run_units`` with one unit); returns its
    part of the run summary."""
    return run_units(sc, [name], recorder, **options)[name]


def run_logged_units(
    sc: Scenario, names: Sequence[str], log: Path, **options: Any
) -> dict[str, dict[str, Any]]:
    """``run_units`` with its own MCAP log at ``log``: opened here and always closed (a run
    that fails still closes a readable log); an interrupt (SIGINT, or SIGTERM under
    ``interrupted_by``) is written to the log, one line a unit, before it is raised again.
    Each unit's output names its ``log``. A bad TLS identity (``tls``) is refused before the
    log is opened."""
    from rgtbus.bus.certs import process_tls
    from rgtbus.telemetry.logfile import close_log, open_log

    if options.get("tls") is not None:
        process_tls(options["tls"], names)

    stream, recorder = open_log(log)
    try:
        outs = run_units(sc, names, recorder, **options)
    except KeyboardInterrupt:
        if not recorder.failed:
            for name in names:
                recorder.log("error", f"{name}: interrupted", 0, name=name)
        raise
    finally:
        close_log(stream, recorder)
    for out in outs.values():
        out["log"] = str(log)
    return outs


def run_units(
    sc: Scenario,
    names: Sequence[str],
    recorder: Recorder,
    *,
    zenoh_options: dict[str, Any] | None = None,
    run_id: str | None = None,
    timeout: float = 10.0,
    join_timeout: float | None = None,
    traces: bool = False,
    progress: Callable[[float, int], None] | None = None,
    engine: str = "event",
    realtime: float | None = None,
    on_open: Callable[[], None] | None = None,
    on_result: Callable[[dict[str, dict[str, Any]]], None] | None = None,
    key: bytes | None = None,
    tls: str | os.PathLike[str] | None = None,
    control: bool = False,
) -> dict[str, dict[str, Any]]:
    """Run the units ``names`` of ``sc`` in this process, one world and one zenoh session for
    all of them (their ears advanced together, one frame per unit and step); returns each
    unit's part of the run summary, by name. ``on_open``: called once the zenoh session is
    open (listening), before the join (``join_timeout``: how long it may take; by default
    ``join_seconds``); ``on_result``: called with the parts as soon as the
    run is over and the units' reports are on disk, before the session closes (closing can
    wait seconds for a peer that died). ``key``: the run's shared secret (every frame and
    hello signed and checked); ``tls``: the run's directory of TLS identities (the process
    proves itself with its one unit's certificate: rgtbus.bus.certs). A failed join is written
    to the log before it is raised. When the run gives up on silent members, the units of this
    process say whether they are the late ones themselves (``lateness``: their part's
    ``late``). ``control``: the run is steered (``rgtbus watch --control``): the process
    that runs the roster's first unit takes the watcher's requests and places them, every
    process applies them at the same sample (``rgtbus.bus.steer_link``)."""
    names = _checked_names(sc, names)
    first = names[0]
    run_id = run_id or default_run_id(sc)
    t0 = time.perf_counter()
    hosted = {"units": ",".join(names)} if len(names) > 1 else {}
    kind = cross_process_kind()
    if control:
        hosted["steered"] = "yes"
    write_metadata(
        recorder, sc, kind, run_id, process=first, engine=engine, auth=auth_name(key), **hosted
    )
    units = [
        AutonomousUnit(name, sc, recorder, traces=traces, realtime=realtime, steerable=control)
        for name in names
    ]
    opts = dict(zenoh_options or {})
    # a peer starved of CPU keeps its links as long as the run would wait for it
    opts.setdefault("send_patience", timeout)
    world_options = {"engine": engine, "timeout": timeout, "progress": progress,
                     "realtime": realtime, "write_medium": sc.units[0] == first}  # fmt: skip
    sim_seconds = 0.0
    told = False  # the parts are out (``on_result``): being stopped then loses nothing
    try:
        with open_bus(
            kind,
            run_id,
            sc.units,
            sc.timing.sample_rate,
            local=names,
            key=key,
            tls=tls,
            **opts,
        ) as bus:
            if (
                isinstance(bus, ZenohBus)
                and isinstance(recorder, McapRecorder)
                and (recorder.live is None)
            ):
                recorder.live = bus.telemetry_feed(first)  # what `rgtbus watch` serves
            if on_open is not None:  # e.g. a launcher starting the peers that connect here
                on_open()
            allowance = join_seconds(len(sc.units)) if join_timeout is None else join_timeout
            link = _steer_link(bus, sc, names, key) if control else None
            if link is not None:
                steering = Steering(sc, sc.timing.window_samples, source=link, pace=realtime)
                steering.settle_timeout = timeout  # a process that lags: as long as the run waits
                world_options["steering"] = steering
            try:
                _join(bus, sc, names, recorder, allowance)
                result, outs = _run_world(sc, units, bus, recorder, world_options, run_id, t0)
            finally:
                if link is not None:
                    link.close()
                    link.undeclare()
            sim_seconds = result.sim_seconds
            if on_result is not None:
                flush = getattr(recorder, "flush", None)
                if flush is not None:  # the reports on disk before anyone is told
                    flush()
                on_result(outs)
                told = True
            if not result.failure and isinstance(bus, ZenohBus):
                bus.linger(timeout)  # its last frames may be asked for again
        if bus.close_problem:
            recorder.log("warning", bus.close_problem, ns(result.sim_seconds), name=first)
    except BaseException as exc:
        # a launcher reaping a process that told its parts and lingers (or closes its
        # session) loses nothing: the run is whole, its log the same however long that took
        if not (told and isinstance(exc, KeyboardInterrupt)):
            for name in names:
                _write_end(
                    recorder, name, UNIT_ENDED_EARLY, str(exc) or type(exc).__name__, sim_seconds
                )
            raise
    for unit in units:
        if result.failure:  # the others went silent: the rest of this run never happened
            _write_end(recorder, unit.name, UNIT_ENDED_EARLY, result.failure, sim_seconds)
        else:
            _write_end(recorder, unit.name, UNIT_DONE, unit.failure or "", sim_seconds)
    return outs


def _steer_link(bus: Any, sc: Scenario, names: list[str], key: bytes | None) -> SteerLink:
    """This process's side of steering the run (``--control``), on the bus's zenoh session."""
    if not isinstance(bus, ZenohBus):
        raise BadInput("--control across processes needs the zenoh bus")
    return SteerLink(bus.session, bus.run_id, names, sc.units, key)


def _checked_names(sc: Scenario, names: Sequence[str]) -> list[str]:
    """``names``, each a unit of ``sc`` and given once, in the scenario's order (one world,
    whatever the layout of processes)."""
    names = list(names)
    if not names:
        raise BadInput("no unit to run")
    for name in names:
        if name not in sc.units:
            raise BadInput(f"unknown unit {name!r} (units of {sc.name}: {', '.join(sc.units)})")
    if len(set(names)) != len(names):
        raise BadInput(f"a unit named twice: {', '.join(names)}")
    return [u for u in sc.units if u in names]


def _join(
    bus: Any, sc: Scenario, names: list[str], recorder: Recorder, join_timeout: float
) -> None:
    """The join: every member up, on this scenario and seed; a failure is logged, then
    raised."""
    try:
        bus.join(names, scenario_digest(sc), timeout=join_timeout)
    except RgtbusError as exc:
        for note in bus.drop_notes():  # e.g. the hellos that did not authenticate
            recorder.log("warning", f"dropped: {note}", 0, name=names[0])
        for name in names:
            recorder.log("error", f"{name}: join failed: {exc}", 0, name=name)
        raise


def _run_world(
    sc: Scenario,
    units: list[AutonomousUnit],
    bus: Any,
    recorder: Recorder,
    options: dict[str, Any],
    run_id: str,
    t0: float,
) -> tuple[WorldResult, dict[str, dict[str, Any]]]:
    """The world of these units over the bus, to its end (a member gone or stalled ends it
    with ``failure``; so does a request to stop; when it gave up on silent members, this
    process may be the late one: ``lateness``), their reports written; how it ended, and each
    unit's part of the summary."""
    names = [u.name for u in units]
    world = World.for_scenario(sc, units, bus, recorder, **options)
    with PauseWatch() as paused:
        result = world.run(interruptible=True)
    late = lateness(names, sc, result.silent, paused.longest, options["timeout"])
    if late is not None:
        result = dataclasses.replace(result, failure=late)
    stats = _reported(units, bus, recorder, result.sim_seconds)
    if result.failure:  # a unit's own failure is in its log already
        recorder.log("error", result.failure, ns(result.sim_seconds), name=names[0])
    wall = round(time.perf_counter() - t0, 3)
    return result, {u.name: _output(u, run_id, result, wall, stats, late) for u in units}


def _reported(
    units: list[AutonomousUnit], bus: Any, recorder: Recorder, sim_seconds: float
) -> dict[str, Any]:
    """Each unit's report written (while the watch feed is open) and what the bus dropped;
    returns the bus's statistics."""
    for unit in units:
        unit.write_report(sim_seconds)
    for note in bus.drop_notes():
        recorder.log("warning", f"dropped: {note}", ns(sim_seconds), name=units[0].name)
    stats = dict(bus.stats())
    dropped = drop_summary(stats)
    if dropped:  # once, with the counts: a flood is a number, not a stream of lines
        recorder.log("warning", f"dropped: {dropped}", ns(sim_seconds), name=units[0].name)
    return stats


def _output(
    unit: AutonomousUnit,
    run_id: str,
    result: WorldResult,
    wall: float,
    stats: dict[str, Any],
    late: str | None,
) -> dict[str, Any]:
    """A unit's part of the run summary, as its process reports it (``late``: why its process
    is the late one, when the run gave up on others for want of it)."""
    return {
        "unit": unit.name,
        "run_id": run_id,
        "report": unit.report(),
        "sim_seconds": round(result.sim_seconds, 6),
        "steps": result.steps,
        "world_failure": result.failure,
        "wall_seconds": wall,
        "error": result.failure or unit.failure,
        "late": late,
        "bus": stats,
        "sync": result.sync,  # the cost of the clock to this unit's process (SyncCost)
    }


ROUTER_PATIENCE = 60.0  # s: a router waits this long on a client that does not read


def open_router(
    listen: Sequence[str] | None,
    config: str | None = None,
    multicast: bool | None = None,
    send_patience: float = ROUTER_PATIENCE,
    *,
    tls: str | os.PathLike[str] | None = None,
    roster: Sequence[str] = (),
    run_id: str | None = None,
) -> Any:
    """A zenoh session in router mode on the ``listen`` endpoints (or as ``config`` says), for
    units on several machines to meet at; the caller closes it. ``send_patience``: how long
    it waits on a client that does not read before it closes that client's link (a client
    starved of CPU, on a loaded host: its frames are never dropped, so a closed link would
    stall the run). Over TLS (``tls``: the run's directory of identities) it proves itself
    with the router's certificate and holds each client to the access control of the run's
    ``roster`` (of run ``run_id``; None: any run). One line (``RgtbusError``) when it cannot
    open."""
    import zenoh

    from rgtbus.bus.base import check_name
    from rgtbus.bus.certs import ROUTER, check_tls
    from rgtbus.bus.config import TlsRun, make_config, zenoh_reason

    tls_run = None
    if tls is not None:
        if not roster:
            raise BadInput("--tls: a router needs the run's roster (give --scenario)")
        if run_id is not None:
            check_name("run id", run_id)
        tls_run = TlsRun(check_tls(tls, ROUTER), tuple(roster), run_id)
    cfg = make_config(
        mode="router",
        listen=listen,
        config=config,
        multicast=multicast,
        tls=tls_run,
        send_patience=send_patience,
    )
    try:
        return zenoh.open(cfg)
    except Exception as exc:
        raise IOFailure(
            f"router: cannot open a zenoh router on {list(listen or [])}: {zenoh_reason(exc)}"
        ) from None
