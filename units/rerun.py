"""Re-running a logged run: the units' receivers and reasoning fed with the logged medium.

``rerun`` rebuilds every unit (``AutonomousUnit``, exactly as ``run_group`` does) from the
scenario and runs them in the SimPy ``World`` over a ``LogBus`` that serves the logged
medium instead of a live bus:
the units render their own transmissions again (so their pulses can be compared with the
log), hear the logged medium (with their own seeded noise), spike, decode, build tables and
decide. What they record goes into a ``CaptureRecorder``; ``rgtbus.telemetry.verify`` diffs it
against the log. ``verify_log`` glues reading, re-running and diffing for the CLI.

It lives in ``units/`` because it needs the unit itself: adapters never import ``units/``.
"""

from __future__ import annotations

import os
from collections import defaultdict
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import IO, Any

from rgtbus.units.unit import AutonomousUnit, decision_records

from rgtbus.bus.logbus import LogBus
from rgtbus.bus.payload import NEVER
from rgtbus.engine.sim import World
from rgtbus.engine.steering import Steering
from rgtbus.errors import RgtbusError
from rgtbus.mind import Mind, mind_of
from rgtbus.pairs import parse_pair_key
from rgtbus.scenario import Scenario
from rgtbus.signal.pulses import Pulses
from rgtbus.steering import Request
from rgtbus.summary import summarise
from rgtbus.telemetry import log_message, records
from rgtbus.telemetry.log_parts import stack_traces
from rgtbus.telemetry.mismatch import Mismatch
from rgtbus.telemetry.read import Replay, load_replay
from rgtbus.telemetry.verify import VerifyReport, verify
from rgtbus.timebase import ns, seconds


class CaptureRecorder:
    """Keeps every write as given (no JSON round trip: the diff normalises what it compares)."""

    enabled = True
    closed = False

    def __init__(self) -> None:
        self.messages: list[tuple[str, int, dict[str, Any]]] = []

    def write(self, topic: str, message: Mapping[str, Any], t_ns: int) -> None:
        self.messages.append((topic, t_ns, dict(message)))

    def log(self, level: str, text: str, t_ns: int, name: str = "rgtbus", **_: Any) -> None:
        self.messages.append((records.LOG, t_ns, log_message(level, text, t_ns, name)))

    def metadata(self, name: str, values: dict[str, str]) -> None:
        pass

    def watched(self) -> bool:
        return False

    def offer(self, topic: str, message: Mapping[str, Any], t_ns: int) -> None:
        pass

    def advance(self, t_ns: int) -> None:
        """Nothing: writes are kept in the order made (the diff compares by time)."""

    def close(self) -> None:
        self.closed = True


@dataclass
class Rerun:
    # what the re-run units recorded, in write order
    messages: list[tuple[str, int, dict[str, Any]]]
    summary: dict[str, Any]  # summarise() of the re-run units (the run's own summary fields)
    units: list[AutonomousUnit]
    complete: bool  # every re-run unit decided or failed within the logged medium


def rerun(
    scenario: Scenario,
    medium: Mapping[str, Pulses],
    *,
    end: int = NEVER,
    traces: Collection[str] = (),
    only: Collection[str] | None = None,
    engine: str = "event",
    control: Sequence[tuple[int, int, Request]] | None = None,
) -> Rerun:
    """Feed the logged medium to freshly built units.

    ``medium``: the logged pulses, either the whole medium under the first unit's name (what
    every unit heard, bit for bit) or each sender's own pulses (needed when the scenario has
    link gains: each unit hears ``sum(gain[s -> me] * pulses[s])``). ``end``: the first sample
    the log does not cover (a truncated log). ``traces``: units that record
    ``/trace/<unit>``; ``only``: re-run just these units (each unit's receiver depends on the
    medium alone, so one unit can be re-run on its own). The units run in the ``World`` itself,
    over a ``LogBus`` serving the log, so the re-run ends exactly where the run did.
    """
    sc = scenario
    rec = CaptureRecorder()
    names = [u for u in sc.units if only is None or u in only]
    steerable = control is not None
    members = [AutonomousUnit(u, sc, rec, traces=u in traces, steerable=steerable) for u in names]
    bus = LogBus("replay", sc.units, medium, local=names, end=end)
    steering = None
    if control is not None:
        steering = Steering(sc, sc.timing.window_samples, logged=control)
    world = World.for_scenario(
        sc,
        members,
        bus,
        rec,
        engine=engine,
        write_medium=False,  # the log has the medium; the diff compares what units did
        steering=steering,
    )
    result = world.run()
    for m in members:  # as the run's units did at its end
        m.end_log()
    complete = all(m.done for m in members)
    summary = summarise(sc, [m.report() for m in members], result) if only is None else {}
    return Rerun(rec.messages, summary, members, complete)


def rerun_replay(
    replay: Replay, *, traces: Collection[str] | None = None, only: Collection[str] | None = None
) -> Rerun:
    """Re-run the units of a loaded log on its medium (per-sender pulses when gains need them).

    ``traces``: units to record traces for (default: the units whose traces the log holds)."""
    sc = replay.require_scenario()
    if replay.has_gains():
        medium: Mapping[str, Pulses] = replay.sender_pulses()
    else:
        medium = {sc.units[0]: replay.medium_pulses()}
    end = NEVER
    if replay.truncated:
        until = replay.units_until_ns() or 0
        w_last = max((m["window"] for _, m in replay.by_topic[records.MEDIUM]), default=-1)
        end = max(
            (w_last + 1) * sc.timing.window_samples, round(seconds(until) / sc.timing.tau) + 1
        )
    if traces is None:
        traces = replay.traced_units()
    control = replay.control_requests() if replay.steered else None
    return rerun(sc, medium, end=end, traces=traces, only=only, control=control)


def check_reasoning(replay: Replay) -> list[Mismatch]:
    """Every logged table and decision follows from the logged tables: each unit's relations
    table gives its installed relations and polynomial (RGT phase 2), and its relations and
    influence tables give its decisions (phase 4), by a fresh copy of the unit's own mind."""
    sc = replay.require_scenario()
    out: list[Mismatch] = []
    # a log cut short may end inside a unit's decisions of one time: those at or after its
    # bound may be missing (what is there must still agree)
    cut_ns = (replay.units_until_ns() or 0) if replay.truncated else None
    logged_decisions: defaultdict[tuple[str, int], dict[str, Mapping[str, Any]]] = defaultdict(dict)
    for d in replay.decisions:
        logged_decisions[(d["unit"], d.get("round", 1))][d["subject"]] = d
    # a unit's tables, round by round
    tables: defaultdict[str, list[dict[str, Any]]] = defaultdict(list)
    for _, m in replay.by_topic[records.UNIT_INFLUENCES]:
        tables[str(m.get("unit"))].append(m)
    for name in sc.units:
        rel = replay.relations.get(name)
        if rel is None:
            continue
        mind = mind_of(sc, name)  # a fresh mind: the unit's policy and generator
        try:
            mind.sent = {parse_pair_key(k): v == "alliance" for k, v in rel["sent"].items()}
        except (AttributeError, ValueError):
            bad = Mismatch(records.UNIT_RELATIONS, rel.get("t"), name, "sent", rel["sent"], None)
            out.append(bad)
            continue
        if not mind.relations_complete():
            continue
        mind.build_group()
        want = {"installed": mind.installed(), "polynomial": mind.polynomial}
        for key, value in want.items():
            if rel.get(key) != value:
                out.append(
                    Mismatch(
                        records.UNIT_RELATIONS,
                        rel["t"],
                        name,
                        f"{key} (from its sent table)",
                        rel.get(key),
                        value,
                    )
                )
        if mind.df is None:
            continue
        # every round in order: a seeded-random policy draws once a round
        for infl in tables.get(name, []):
            out.extend(_check_round(sc, name, mind, infl, logged_decisions, cut_ns))
    return out


def _check_round(
    sc: Scenario,
    name: str,
    mind: Mind,
    infl: dict[str, Any],
    logged_decisions: Mapping[tuple[str, int], Mapping[str, Mapping[str, Any]]],
    cut_ns: int | None = None,
) -> list[Mismatch]:
    """One round's decisions of unit ``name`` re-derived by its ``mind`` from its logged
    influence table (``cut_ns``: the bound of a log cut short, at or after which a decision
    may be missing)."""
    u = sc.universe
    rnd = infl.get("round", 1)
    try:
        mind.influences = {parse_pair_key(k): u.from_list(v) for k, v in infl["influences"].items()}
    except (AttributeError, ValueError, RgtbusError):
        return [
            Mismatch(
                records.UNIT_INFLUENCES, infl.get("t"), name, "influences", infl["influences"], None
            )
        ]
    if not mind.influences_complete():
        return []
    mind.decide_round(rnd)
    out = []
    for record in decision_records(name, mind, u, infl["t"], rnd):
        m: dict[str, Any] = dict(record)
        logged = logged_decisions.get((name, rnd), {}).get(m["subject"])
        if logged is None and cut_ns is not None and ns(m["t"]) >= cut_ns:
            continue  # written after where the log was cut
        if logged is None:
            out.append(
                Mismatch(
                    records.UNIT_DECISION,
                    m["t"],
                    name,
                    f"subject {m['subject']} (from its tables)",
                    "(missing)",
                    m,
                )
            )
            continue
        for key, value in m.items():
            if logged.get(key) != value:
                out.append(
                    Mismatch(
                        records.UNIT_DECISION,
                        logged["t"],
                        name,
                        f"subject {m['subject']}: {key} (from its tables)",
                        logged.get(key),
                        value,
                    )
                )
    return out


def verify_log(source: str | os.PathLike[str] | IO[bytes] | Replay) -> VerifyReport:
    """Read a log, re-run its units on its medium, re-derive the decisions from the logged
    tables, and list every disagreement."""
    replay = source if isinstance(source, Replay) else load_replay(source)
    return verify(replay, rerun_replay(replay), check_reasoning(replay))


def traces_for(replay: Replay, unit: str) -> dict[str, Any]:
    """A unit's resonator y traces: logged, else recomputed by re-running that unit alone.

    ``{"t": seconds (n,), "y": (n, channels), "channels": [...], "recomputed": bool}``."""
    logged = replay.trace_arrays(unit)
    if logged is not None:
        return {**logged, "recomputed": False}
    out = rerun_replay(replay, traces=[unit], only=[unit])
    topic = records.trace_topic(unit)
    return {
        **stack_traces([m for t, _, m in out.messages if t == topic], replay.units),
        "recomputed": True,
    }
