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

from rgtbus import __version__
from rgtbus.bus import open_bus
from rgtbus.scenario import Scenario
from rgtbus.sim import World, ns
from units.unit import AutonomousUnit


@dataclass
class RunOutput:
    summary: dict[str, Any]
    units: list[AutonomousUnit]


def _interval_json(u, r) -> list[list[str]] | None:
    return None if r.frustrated else [u.to_list(r.B), u.to_list(r.A)]


def run_group(
    scenario: Scenario,
    bus_kind: str,
    recorder,
    *,
    run_id: str | None = None,
    traces: bool = False,
    gather_timeout: float = 5.0,
    progress: Callable[[float, int], None] | None = None,
) -> RunOutput:
    sc = scenario
    run_id = run_id or f"{sc.name}-{sc.seed}"
    recorder.metadata("scenario", {"name": sc.name, "path": sc.path, "text": sc.text})
    recorder.metadata(
        "run",
        {
            "seed": str(sc.seed),
            "version": __version__,
            "bus": bus_kind,
            "run_id": run_id,
            "python": platform.python_version(),
        },
    )
    recorder.metadata("frequencies", {u: repr(w) for u, w in sc.frequencies.items()})
    recorder.metadata("codebook", {k: json.dumps(v) for k, v in sc.codebook.to_dict().items()})
    members = [AutonomousUnit(u, sc, recorder, traces=traces) for u in sc.units]
    with open_bus(
        bus_kind, run_id, sc.units, sc.timing.sample_rate, sc.timing.window_samples
    ) as bus:
        world = World(
            members,
            bus,
            recorder,
            sample_rate=sc.timing.sample_rate,
            window_samples=sc.timing.window_samples,
            max_seconds=sc.timing.max_seconds,
            gather_timeout=gather_timeout,
            progress=progress,
        )
        result = world.run()
    summary = summarise(sc, members, result)
    recorder.write(
        "/run",
        {
            "scenario": sc.name,
            "seed": sc.seed,
            "outcome": summary["outcome"],
            "agree": summary["agree"],
            "sim_seconds": summary["sim_seconds"],
            "error": summary["error"],
        },
        ns(result.sim_seconds),
    )
    return RunOutput(summary, members)


def summarise(sc: Scenario, members: list[AutonomousUnit], result) -> dict[str, Any]:
    u = sc.universe
    tables = {}
    for m in members:
        tables[m.name] = m.mind.installed()
    first = tables[members[0].name]
    agree = all(t == first for t in tables.values()) and all(
        m.mind.polynomial == members[0].mind.polynomial for m in members
    )
    # Ground truth for decode errors: what was actually sent, per (turn, kind).
    truth = {}
    for m in members:
        for s in m.sent:
            truth[(s.turn, "id" if s.kind == "id" else "payload")] = (s.addressee, s.code)
    decode_errors = []
    for m in members:
        for d in m.decoded:
            key = (d.turn, "id" if d.kind == "id" else "payload")
            if key not in truth:
                continue
            addressee, code = truth[key]
            wrong = (
                (d.code != "id") if d.kind == "id" else (d.code != code or d.addressee != addressee)
            )
            if wrong:
                decode_errors.append(
                    {
                        "unit": m.name,
                        "turn": d.turn,
                        "kind": d.kind,
                        "decoded": d.code,
                        "sent": code,
                    }
                )
    ref = members[0].mind
    units_out = {}
    for m in members:
        r = m.mind.results[m.name] if m.mind.results else None
        units_out[m.name] = {
            "interval": _interval_json(u, r) if r else None,
            "frustrated": bool(r.frustrated) if r else False,
            "choice": None if m.mind.choice is None else u.to_list(m.mind.choice),
            "canonical": m.mind.canonical(m.name) if m.mind.df else None,
            "A": u.to_list(r.A) if r else None,
            "B": u.to_list(r.B) if r else None,
            "decided": r is not None,
        }
    outcome: Any = None
    if sc.outcome is not None and all(m.mind.results for m in members):
        ok = all(
            members[sc.units.index(x)].mind.choice == sc.outcome.choose for x in sc.outcome.all_of
        )
        outcome = f"{sc.outcome.name}: {sc.outcome.then if ok else sc.outcome.otherwise}"
    error = result.failure
    if error is None:
        errs = [m.mind.error for m in members if m.mind.error]
        error = errs[0] if errs else None
    return {
        "scenario": sc.name,
        "seed": sc.seed,
        "polynomial": ref.polynomial,
        "relations": ref.installed(),
        "sent_relations": {
            f"{s}>{r}": "alliance" if v else "conflict" for (s, r), v in sorted(ref.sent.items())
        },
        "unit_relations": tables,
        "agree": agree,
        "influences": {f"{s}>{r}": u.to_list(v) for (s, r), v in sorted(ref.influences.items())},
        "units": units_out,
        "outcome": outcome,
        "decode_errors": decode_errors,
        "sim_seconds": round(result.sim_seconds, 6),
        "wall_seconds": round(result.wall_seconds, 3),
        "windows": result.windows,
        "bus": result.bus_stats,
        "error": error,
    }


def check_expectations(scenario, s: dict[str, Any]) -> list[tuple[str, bool, str]]:
    """Compare the run with the scenario's ``[expect]`` table."""
    u = scenario.universe
    exp = scenario.expect
    out: list[tuple[str, bool, str]] = []

    def check(what: str, got: Any, want: Any) -> None:
        out.append((what, got == want, f"got {got!r}, expected {want!r}"))

    if "polynomial" in exp:
        check("polynomial", s["polynomial"], exp["polynomial"])
    if "agree" in exp:
        check("agree", s["agree"], exp["agree"])
    if "outcome" in exp:
        check("outcome", s["outcome"], exp["outcome"])
    for pair, rel in exp.get("relations", {}).items():
        check(f"relation {pair}", s["relations"].get(pair), rel)
    for name, text in exp.get("intervals", {}).items():
        lo, hi = u.parse_interval(text)
        check(f"interval of {name}", s["units"][name]["interval"], [u.to_list(lo), u.to_list(hi)])
    for name, text in exp.get("choices", {}).items():
        check(f"choice of {name}", s["units"][name]["choice"], u.to_list(u.parse_alternative(text)))
    for name, flag in exp.get("frustrated", {}).items():
        check(f"frustration of {name}", s["units"][name]["frustrated"], flag)
    check("no decode errors", len(s["decode_errors"]), 0)
    return out
