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
import hashlib
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

from rgtbus.bus import open_bus
from rgtbus.bus.zenoh import ZenohBus
from rgtbus.engine.sim import World, WorldResult
from rgtbus.errors import RgtbusError
from rgtbus.scenario import Scenario
from rgtbus.telemetry import McapRecorder, Recorder
from rgtbus.telemetry.topics import UNIT_DONE, UNIT_ENDED_EARLY, unit_end_record
from rgtbus.timebase import ns


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
            raise RgtbusError(f"unknown unit {name!r} (units of {sc.name}: {', '.join(sc.units)})")
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise RgtbusError(f"unit {dup!r} named twice in {text!r}")
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
    Each unit's output names its ``log``."""
    from rgtbus.telemetry.logfile import close_log, open_log

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
    join_timeout: float = 20.0,
    traces: bool = False,
    progress: Callable[[float, int], None] | None = None,
    engine: str = "event",
    realtime: float | None = None,
    on_open: Callable[[], None] | None = None,
    key: bytes | None = None,
) -> dict[str, dict[str, Any]]:
    """Run the units ``names`` of ``sc`` in this process, one world and one zenoh session for
    all of them (their ears advanced together, one frame per unit and step); returns each
    unit's part of the run summary, by name. ``on_open``: called once the zenoh session is
    open (listening), before the join. ``key``: the run's shared secret (every frame and hello
    signed and checked). A failed join is written to the log before it is raised."""
    names = _checked_names(sc, names)
    first = names[0]
    run_id = run_id or default_run_id(sc)
    t0 = time.perf_counter()
    hosted = {"units": ",".join(names)} if len(names) > 1 else {}
    write_metadata(
        recorder, sc, "zenoh", run_id, process=first, engine=engine, auth=auth_name(key), **hosted
    )
    units = [AutonomousUnit(name, sc, recorder, traces=traces) for name in names]
    opts = dict(zenoh_options or {})
    world_options = {"engine": engine, "timeout": timeout, "progress": progress,
                     "realtime": realtime, "write_medium": sc.units[0] == first}  # fmt: skip
    sim_seconds = 0.0
    try:
        with open_bus(
            "zenoh", run_id, sc.units, sc.timing.sample_rate, local=names, key=key, **opts
        ) as bus:
            if (
                isinstance(bus, ZenohBus)
                and isinstance(recorder, McapRecorder)
                and (recorder.live is None)
            ):
                recorder.live = bus.telemetry_feed(first)  # what `rgtbus watch` serves
            if on_open is not None:  # e.g. a launcher starting the peers that connect here
                on_open()
            _join(bus, sc, names, recorder, join_timeout)
            # a member gone or stalled ends it with result.failure; so does a request to stop
            world = World.for_scenario(sc, units, bus, recorder, **world_options)
            result = world.run(interruptible=True)
            sim_seconds = result.sim_seconds
            stats = _reported(units, bus, recorder, result.sim_seconds)
        if bus.close_problem:
            recorder.log("warning", bus.close_problem, ns(result.sim_seconds), name=first)
        if result.failure:  # a unit's own failure is in its log already
            recorder.log("error", result.failure, ns(result.sim_seconds), name=first)
    except BaseException as exc:
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
    wall = round(time.perf_counter() - t0, 3)
    return {unit.name: _output(unit, run_id, result, wall, stats) for unit in units}


def _checked_names(sc: Scenario, names: Sequence[str]) -> list[str]:
    """``names``, each a unit of ``sc`` and given once, in the scenario's order (one world,
    whatever the layout of processes)."""
    names = list(names)
    if not names:
        raise RgtbusError("no unit to run")
    for name in names:
        if name not in sc.units:
            raise RgtbusError(f"unknown unit {name!r} (units of {sc.name}: {', '.join(sc.units)})")
    if len(set(names)) != len(names):
        raise RgtbusError(f"a unit named twice: {', '.join(names)}")
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


def _reported(
    units: list[AutonomousUnit], bus: Any, recorder: Recorder, sim_seconds: float
) -> dict[str, Any]:
    """Each unit's report written (while the watch feed is open) and what the bus dropped;
    returns the bus's statistics."""
    for unit in units:
        unit.write_report(sim_seconds)
    for note in bus.drop_notes():
        recorder.log("warning", f"dropped: {note}", ns(sim_seconds), name=units[0].name)
    return dict(bus.stats())


def _output(
    unit: AutonomousUnit, run_id: str, result: WorldResult, wall: float, stats: dict[str, Any]
) -> dict[str, Any]:
    """A unit's part of the run summary, as its process reports it."""
    return {
        "unit": unit.name,
        "run_id": run_id,
        "report": unit.report(),
        "sim_seconds": round(result.sim_seconds, 6),
        "steps": result.steps,
        "world_failure": result.failure,
        "wall_seconds": wall,
        "error": result.failure or unit.failure,
        "bus": stats,
    }


def open_router(
    listen: Sequence[str] | None,
    config: str | None = None,
    multicast: bool | None = None,
) -> Any:
    """A zenoh session in router mode on the ``listen`` endpoints (or as ``config`` says), for
    units on several machines to meet at; the caller closes it. One line (``RgtbusError``)
    when it cannot open."""
    import zenoh

    from rgtbus.bus.zenoh import make_config, zenoh_reason

    cfg = make_config(mode="router", listen=listen, config=config, multicast=multicast)
    try:
        return zenoh.open(cfg)
    except Exception as exc:
        raise RgtbusError(
            f"router: cannot open a zenoh router on {list(listen or [])}: {zenoh_reason(exc)}"
        ) from None
