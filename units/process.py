"""Units in an OS process of their own, synchronised with the other processes over zenoh.

The process holds its ``AutonomousUnit``s (one, or several: ``rgtbus launch --procs P``) and the
run's zenoh bus with those units local. It joins the run (a barrier: every member up, on the
same scenario and seed), then runs the same
``World`` as a single-process run: it advances to the smallest promise of all members
(conservative synchronisation, docs/engine.md), or window by window with ``engine="dense"``.
The decisions and the log content equal the single-process run of the same scenario and seed.
"""

from __future__ import annotations

import contextlib
import hashlib
import time
from collections.abc import Callable, Sequence
from typing import Any

from rgtbus.units.group import (
    auth_name,
    default_run_id,
    scenario_world,
    write_metadata,
    write_unit_report,
)
from rgtbus.units.unit import AutonomousUnit

from rgtbus.bus import open_bus
from rgtbus.bus.zenoh import ZenohBus
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


def run_unit(sc: Scenario, name: str, recorder: Recorder, **options: Any) -> dict[str, Any]:
    """Run unit ``name`` of ``sc`` in this process (``run_units`` with one unit); returns its
    part of the run summary."""
    return run_units(sc, [name], recorder, **options)[name]


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
    names = list(names)
    if not names:
        raise RgtbusError("no unit to run")
    for name in names:
        if name not in sc.units:
            raise RgtbusError(f"unknown unit {name!r} (units of {sc.name}: {', '.join(sc.units)})")
    if len(set(names)) != len(names):
        raise RgtbusError(f"a unit named twice: {', '.join(names)}")
    names = [u for u in sc.units if u in names]  # the scenario's order: one world, any layout
    first = names[0]
    run_id = run_id or default_run_id(sc)
    t0 = time.perf_counter()
    hosted = {"units": ",".join(names)} if len(names) > 1 else {}
    write_metadata(
        recorder, sc, "zenoh", run_id, process=first, engine=engine, auth=auth_name(key), **hosted
    )
    units = [AutonomousUnit(name, sc, recorder, traces=traces) for name in names]
    opts = dict(zenoh_options or {})
    rate = sc.timing.sample_rate
    sim_seconds = 0.0
    try:
        with open_bus("zenoh", run_id, sc.units, rate, local=names, key=key, **opts) as bus:
            if (
                isinstance(bus, ZenohBus)
                and isinstance(recorder, McapRecorder)
                and recorder.live is None
            ):
                recorder.live = bus.telemetry_feed(first)  # what `rgtbus watch` serves
            if on_open is not None:  # e.g. a launcher starting the peers that connect here
                on_open()
            try:
                bus.join(names, scenario_digest(sc), timeout=join_timeout)
            except RgtbusError as exc:
                for note in bus.drop_notes():  # e.g. the hellos that did not authenticate
                    recorder.log("warning", f"dropped: {note}", 0, name=first)
                for name in names:
                    recorder.log("error", f"{name}: join failed: {exc}", 0, name=name)
                raise
            world = scenario_world(
                sc,
                units,
                bus,
                recorder,
                engine=engine,
                timeout=timeout,
                progress=progress,
                realtime=realtime,
                write_medium=sc.units[0] in names,  # one medium in the merged log
            )
            # a member gone or stalled ends it with result.failure; so does a request to stop
            result = world.run(interruptible=True)
            sim_seconds = result.sim_seconds
            for unit in units:
                write_unit_report(recorder, unit, sim_seconds)  # while the watch feed is open
            for note in bus.drop_notes():
                recorder.log("warning", f"dropped: {note}", ns(result.sim_seconds), name=first)
            stats = dict(bus.stats())
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
    return {
        unit.name: {
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
        for unit in units
    }
