"""A group of units socialising over one medium: build it from a scenario, run it, summarise.

This is the top of the stack (scenarios -> units -> rgtbus orchestration -> adapters -> core):
it creates one ``AutonomousUnit`` per scenario unit, the bus, and the SimPy ``World``, and
writes the run's metadata and summary to the recorder. Bus and recorder are passed in.
"""

from __future__ import annotations

import json
import platform
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from rgtbus.units.unit import AutonomousUnit

from rgtbus._version import __version__
from rgtbus.bus import drop_summary, open_bus
from rgtbus.engine.sim import World
from rgtbus.engine.steering import Requests, Steering
from rgtbus.misreads import DecodeErrors, decode_errors_of
from rgtbus.scenario import Scenario
from rgtbus.summary import summarise
from rgtbus.telemetry import Recorder, records
from rgtbus.timebase import ns


@dataclass
class RunOutput:
    summary: dict[str, Any]
    units: list[AutonomousUnit]
    reports: list[dict[str, Any]]  # what the summary was made from (``shared_reports``)
    misreads: DecodeErrors  # every misread decode, as the summary counts them


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
    control: Requests | None = None,
) -> RunOutput:
    """Every unit of ``scenario`` in this process on one bus; ``key`` signs and checks every
    frame (rgtbus.bus.auth); ``control``: a steered run's requests (``rgtbus.engine.steering``),
    applied at window boundaries and logged."""
    sc = scenario
    run_id = run_id or default_run_id(sc)
    extra = {"steered": "yes"} if control is not None else {}
    write_metadata(recorder, sc, bus_kind, run_id, engine=engine, auth=auth_name(key), **extra)
    steerable = control is not None
    members = [
        AutonomousUnit(u, sc, recorder, traces=traces, realtime=realtime, steerable=steerable)
        for u in sc.units
    ]
    steering = None
    if control is not None:
        steering = Steering(sc, sc.timing.window_samples, source=control, pace=realtime)
    with open_bus(bus_kind, run_id, sc.units, sc.timing.sample_rate, key=key) as bus:
        result = World.for_scenario(
            sc, members, bus, recorder,
            engine=engine, timeout=timeout, progress=progress, realtime=realtime,
            steering=steering,
        ).run()  # fmt: skip
        for note in bus.drop_notes():  # what reached the bus and was refused, say why
            recorder.log("warning", f"dropped: {note}", ns(result.sim_seconds))
        dropped = drop_summary(bus.stats())
        if dropped:  # once, with the counts
            recorder.log("warning", f"dropped: {dropped}", ns(result.sim_seconds))
    for m in members:
        m.write_report(result.sim_seconds)
    reports = shared_reports(members)
    misreads = decode_errors_of(reports)
    summary = summarise(sc, reports, result, engine=engine, misreads=misreads)
    recorder.write(records.RUN, records.run_record(summary), ns(summary["sim_seconds"]))
    return RunOutput(summary, members, reports, misreads)


def shared_reports(members: Sequence[AutonomousUnit]) -> list[dict[str, Any]]:
    """Every member's ``report()``, the tables they agree on held once (``shared_tables``)."""
    reports: list[dict[str, Any]] = []
    for m in members:
        reports.append(shared_tables(m.report(), reports[0] if reports else None))
    return reports
