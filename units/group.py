"""A group of units socialising over one medium: build it from a scenario, run it, summarise.

This is the top of the stack (scenarios -> units -> rgtbus orchestration -> adapters -> core):
it creates one ``AutonomousUnit`` per scenario unit, the bus, and the SimPy ``World``, and
writes the run's metadata and summary to the recorder. Bus and recorder are passed in.
"""

from __future__ import annotations

import json
import platform
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rgtbus.units.unit import AutonomousUnit

from rgtbus import __version__
from rgtbus.bus import open_bus
from rgtbus.bus.base import Bus
from rgtbus.engine.sim import Receivers, World
from rgtbus.scenario import Scenario
from rgtbus.summary import summarise
from rgtbus.telemetry import Recorder, records
from rgtbus.timebase import ns


@dataclass
class RunOutput:
    summary: dict[str, Any]
    units: list[AutonomousUnit]


def default_run_id(sc: Scenario) -> str:
    return f"{sc.name}-{sc.seed}"


def auth_name(key: bytes | None) -> str:
    """How a run's frames are authenticated, as its log says (never the key itself)."""
    return "none" if key is None else "hmac-sha256"


def write_metadata(
    recorder: Recorder, sc: Scenario, bus_kind: str, run_id: str, **extra: str
) -> None:
    recorder.metadata("scenario", {"name": sc.name, "path": sc.path, "text": sc.text})
    recorder.metadata(
        "run",
        {
            "seed": str(sc.seed),
            "version": __version__,
            "bus": bus_kind,
            "run_id": run_id,
            "python": platform.python_version(),
            **extra,
        },
    )
    recorder.metadata("frequencies", {u: repr(w) for u, w in sc.frequencies.items()})
    recorder.metadata("codebook", {k: json.dumps(v) for k, v in sc.codebook.to_dict().items()})


def scenario_world(
    sc: Scenario, members: list[AutonomousUnit], bus: Bus, recorder: Recorder, **options: Any
) -> World:
    """The SimPy world of a scenario: its channels, resonator mode and sample rate; its window
    (the medium's log blocks, and the dense engine's step)."""
    receivers = Receivers(tuple(sc.frequencies[u] for u in sc.units), sc.mode, sc.timing.tau)
    return World(
        members, bus, recorder, receivers, window_samples=sc.timing.window_samples, **options
    )


def write_unit_report(recorder: Recorder, unit: AutonomousUnit, sim_seconds: float) -> None:
    """The unit's ``/unit/report`` at the end of the run: what the log's summary is computed
    from (with the unit's ``/rx/decodes`` records), exactly as the live summary is."""
    unit.end_log()  # what it keeps for the log, if the run stopped before it was done
    if recorder.enabled:
        recorder.write(records.UNIT_REPORT, unit.report_record(), ns(sim_seconds))


_TABLES = ("installed", "sent_relations", "influences")


def shared_tables(report: dict[str, Any], first: dict[str, Any] | None) -> dict[str, Any]:
    """``report`` with each of its tables that equals ``first``'s replaced by that very
    object: units that agree keep one copy of the group's tables, not one each (n units'
    tables hold n³ entries). Reports are read, never changed."""
    if first is not None:
        for key in _TABLES:
            if report[key] is not first[key] and report[key] == first[key]:
                report[key] = first[key]
    return report


def write_run_summary(recorder: Recorder, summary: dict[str, Any]) -> None:
    recorder.write(records.RUN, records.run_record(summary), ns(summary["sim_seconds"]))


def run_group(
    scenario: Scenario,
    bus_kind: str,
    recorder: Recorder,
    *,
    run_id: str | None = None,
    traces: bool = False,
    timeout: float = 5.0,
    progress: Callable[[float, int], None] | None = None,
    engine: str = "event",
    realtime: float | None = None,
    key: bytes | None = None,
) -> RunOutput:
    """Every unit of ``scenario`` in this process on one bus; ``key`` signs and checks every
    frame (rgtbus.bus.auth)."""
    sc = scenario
    run_id = run_id or default_run_id(sc)
    write_metadata(recorder, sc, bus_kind, run_id, engine=engine, auth=auth_name(key))
    members = [AutonomousUnit(u, sc, recorder, traces=traces) for u in sc.units]
    with open_bus(bus_kind, run_id, sc.units, sc.timing.sample_rate, key=key) as bus:
        world = scenario_world(
            sc,
            members,
            bus,
            recorder,
            engine=engine,
            timeout=timeout,
            progress=progress,
            realtime=realtime,
        )
        result = world.run()
        for note in bus.drop_notes():  # what reached the bus and was refused, say why
            recorder.log("warning", f"dropped: {note}", ns(result.sim_seconds))
    for m in members:
        write_unit_report(recorder, m, result.sim_seconds)
    reports: list[dict[str, Any]] = []
    for m in members:
        reports.append(shared_tables(m.report(), reports[0] if reports else None))
    summary = summarise(sc, reports, result, engine=engine)
    write_run_summary(recorder, summary)
    return RunOutput(summary, members)
