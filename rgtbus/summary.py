"""The summary of a run: one contract for ``run``, ``launch``, ``replay`` and ``sweep``.

A run's summary is built here from what its units report (in one process or many), and the
pieces a log reader recomputes (agreement, outcome, decode errors, the non-decomposable note)
are the same functions. ``SUMMARY_JSON_KEYS`` is what ``rgtbus run --json`` and ``rgtbus launch
--json`` print and what a sweep stores per run. Pure: no SimPy, zenoh or MCAP here.

Fields beyond the tables and decisions:

* ``decomposable``: whether the installed group has an RGT polynomial (``None`` when the
  relationship phase did not finish); ``p4`` the induced path a-b-c-d that made it not
  decomposable. A non-decomposable random group is a result (no decisions), never an error.
* ``frustrated``: the units whose own forward task has no solution (empty interval).
* ``wrong_decisions``: the units that decided otherwise than they would have on a perfect
  medium (the forward task on the relations and influences the units intended:
  ``rgtbus.truth``): a misread code that changed a decision.
* ``goals``: each goal of ``[goals.UNIT]``, judged (``judge_goals``): reached
  by the target's decision, reachable by the unit's own influence given what the others sent,
  and the share of the others' influences for which it would be.
* ``rounds``: the influence rounds: ``count``; ``influences``, what was sent in each round
  (``"s>r"``: alternative); ``state`` (fixed point, cycle, neither; ``None`` for fewer than two
  whole rounds: a run that stopped early is judged on the rounds every pair was sent in),
  ``since`` and ``length`` (``round_dynamics``).
* ``decode_errors``: counts of the misreads (each unit's decode that differs from what was
  sent): ``misread``, ``set_right`` (a repair's copy, or the payload of a misread ID, read
  right), ``left_wrong`` (what the unit took from its turn stayed wrong: ``--check`` judges the
  run on those), the same ``by_kind`` (id, relation, influence); the first few as a ``sample``,
  and in ``rest`` where the others are (``rgtbus.misreads``: every one of them, as a
  DataFrame, is ``RunResult.decode_errors()`` or ``open_log(LOG).decode_errors()``).
* ``codebook``: the name of the codebook the run's codes came from (``paper``, or a generated
  one: ``generated-k2-N5-seed0``: K actions, N pulses a code, the generator's seed).
* ``error``: why the run did not finish (the root cause), else ``None``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, TypedDict, TypeVar, cast

from rgtbus.mind import decision_fields
from rgtbus.misreads import DecodeErrors, decode_errors_of
from rgtbus.pairs import PairTexts, pair_key, parse_pair_key
from rgtbus.rgt import SubjectResult, Universe
from rgtbus.scenario import Scenario
from rgtbus.steering import steered_in
from rgtbus.truth import Truth

_V = TypeVar("_V")

SUMMARY_JSON_KEYS = (
    "scenario",
    "seed",
    "schedule",
    "codebook",
    "polynomial",
    "decomposable",
    "p4",
    "relations",
    "agree",
    "influences",
    "units",
    "frustrated",
    "wrong_decisions",
    "decisions",
    "goals",
    "rounds",
    "outcome",
    "sim_seconds",
    "wall_seconds",
    "engine",
    "log",
    "decode_errors",
    "repair",
    "steered",
    "error",
)


# How a run was carried out, not what it gave: a log does not keep them (``RunEnd``), and two
# runs of one scenario may differ in them (rounds follow when frames happen to arrive).
HOW_IT_RAN = ("steps", "bus", "sync")


def summary_json(summary: Mapping[str, Any]) -> dict[str, Any]:
    """The fields ``--json`` prints (a summary without some, e.g. from an old log: ``None``)."""
    return {k: summary.get(k) for k in SUMMARY_JSON_KEYS}


def not_decomposable_text(p4: Sequence[str]) -> str:
    """How a run (and its units' logs) say a group has no polynomial."""
    return f"not decomposable: induced P4 {'-'.join(p4)}; no decisions"


def agreement(tables: Sequence[Any], polynomials: Sequence[Any], expected: int) -> bool:
    """Every one of ``expected`` units holds the same relationship table and polynomial."""
    # a process's units share equal tables as one object (``shared_reports``): n² entries a
    # table, compared only where they are not the very same
    return (
        len(tables) == expected
        and all(t is tables[0] or t == tables[0] for t in tables)
        and all(p == polynomials[0] for p in polynomials)
    )


def outcome_of(sc: Scenario, units: Mapping[str, Mapping[str, Any]]) -> str | None:
    """The scenario's ``[outcome]`` line for these decisions (``None``: no outcome defined, or
    a unit has not decided). ``units``: unit -> {"choice": [...], "decided": bool}."""
    if sc.outcome is None or any(not units.get(u, {}).get("decided") for u in sc.units):
        return None
    want = sc.universe.to_list(sc.outcome.choose)
    ok = all(units[x]["choice"] == want for x in sc.outcome.all_of)
    return f"{sc.outcome.name}: {sc.outcome.then if ok else sc.outcome.otherwise}"


class DecisionRow(TypedDict):
    """A unit's own decision after one influence round (``low``/``high``: the interval's ends,
    alternatives as sorted lists of action names)."""

    round: int
    unit: str
    low: list[str] | None
    high: list[str] | None
    choice: list[str] | None
    frustrated: bool
    t: float


def decision_row(
    unit: str,
    rnd: int,
    t: float,
    result: SubjectResult,
    choice: int | None,
    universe: Universe,
) -> DecisionRow:
    """A unit's own decision after influence round ``rnd`` at ``t`` seconds: a row of the
    summary's ``decisions`` (``low``/``high`` the interval's ends, ``None`` when frustrated;
    ``wrong`` is filled in by ``summarise``)."""
    f = decision_fields(result, choice, universe)
    low, high = f["interval"] or (None, None)
    return {
        "round": rnd,
        "unit": unit,
        "low": low,
        "high": high,
        "choice": f["choice"],
        "frustrated": f["frustrated"],
        "t": t,
    }


def judged_decisions(
    sc: Scenario, reports: Sequence[Mapping[str, Any]], truth: Sequence[Mapping[str, Any]]
) -> list[dict[str, Any]]:
    """Every unit's decision of every round (units in scenario order, then rounds), each with
    ``wrong``: whether it differs from the noise-free decision of that round
    (``noise_free_rounds``)."""
    by_unit = {r["unit"]: r for r in reports}
    out = []
    for u in sc.units:
        for row in by_unit.get(u, {}).get("decisions", ()):
            clean = truth[min(row["round"], len(truth)) - 1].get(u, {})
            interval = None if row["low"] is None else [row["low"], row["high"]]
            wrong = not clean.get("decided") or (
                interval != clean.get("interval")
                or row["frustrated"] != clean.get("frustrated")
                or row["choice"] != clean.get("choice")
            )
            out.append({**row, "wrong": bool(wrong)})
    return out


def frustrated_units(units: Mapping[str, Mapping[str, Any]]) -> list[str]:
    return [u for u, r in units.items() if r.get("frustrated")]


@dataclass
class RunEnd:
    """How a run ended, as a log states it (``failure``: the run's error from its ``/run``
    record; a log does not keep steps, wall time or bus statistics)."""

    steps: int = 0
    sim_seconds: float = 0.0
    wall_seconds: float = 0.0
    failure: str | None = None
    bus_stats: Any = None
    sync: Any = None


class WorldEnd(Protocol):
    """How a world ended, as ``rgtbus.engine.sim.WorldResult`` says it (``failure``: the world's own
    root cause, e.g. a member gone)."""

    steps: int
    sim_seconds: float
    wall_seconds: float
    failure: str | None
    bus_stats: Any
    sync: Any


def summarise(
    sc: Scenario,
    reports: Iterable[dict[str, Any]],
    result: WorldEnd,
    *,
    engine: str = "event",
    misreads: DecodeErrors | None = None,
) -> dict[str, Any]:
    """The run's summary from every unit's ``report()`` (one process or many) and how the
    world ended; a steered run's truth accounts for the changes its units' reports say they
    took (``steered_in``). Units without a report (a process that died) are absent from
    ``units`` and the run does not agree; the shared fields are the first reporting unit's
    (none at all: empty). ``misreads``: the
    reports' ``decode_errors_of`` where the caller keeps them (else worked out here)."""
    reports = list(reports)
    steered = steered_in(reports)
    by_unit = {r["unit"]: r for r in reports}
    ref = next((by_unit[u] for u in sc.units if u in by_unit), _NO_REPORT)
    tables = {r["unit"]: r["installed"] for r in reports}
    agree = agreement(
        [r["installed"] for r in reports], [r["polynomial"] for r in reports], len(sc.units)
    )
    if misreads is None:
        misreads = decode_errors_of(reports)
    units_out = {name: by_unit[name]["result"] for name in sc.units if name in by_unit}
    outcome = outcome_of(sc, units_out) if len(units_out) == len(sc.units) else None
    error = root_cause(result.failure, reports)
    p4 = ref.get("p4")
    decomposable = None if p4 is None and ref["polynomial"] is None else p4 is None
    rounds, whole, last_round = influence_rounds(sc, reports)
    should = Truth(sc, steered)  # what a perfect medium would have given
    clean = should.rounds if units_out else [{}]
    u = sc.universe
    summary = {
        "scenario": sc.name,
        "seed": sc.seed,
        "schedule": sc.protocol.schedule,
        "codebook": sc.codebook.name,  # the words the run's codes were drawn from
        "polynomial": ref["polynomial"],
        "decomposable": decomposable,
        "p4": None if p4 is None else list(p4),
        "relations": ref["installed"],
        "sent_relations": _plain(ref["sent_relations"]),
        "unit_relations": tables,
        "agree": agree,
        "influences": _plain(ref["influences"]),
        "units": units_out,
        "frustrated": frustrated_units(units_out),
        "wrong_decisions": wrong_decisions(units_out, clean[-1]) if units_out else [],
        # every unit's decision on a perfect medium (the last round's; not in --json): what
        # wrong_decisions judges against, kept so that a study need not work it out again
        "noise_free": clean[-1] if units_out else None,
        "decisions": judged_decisions(sc, reports, clean) if units_out else [],
        "goals": [],
        "rounds": {
            "count": sc.protocol.influence_rounds,
            **round_dynamics(rounds[:whole]),
            "influences": [_alternative_lists(u, r) for r in rounds],
        },
        "outcome": outcome,
        "decode_errors": misreads.counts(),
        "repair": repair_summary(sc, reports),
        "sim_seconds": round(result.sim_seconds, 6),
        "wall_seconds": round(result.wall_seconds, 3),
        "engine": engine,
        "steps": result.steps,
        "bus": result.bus_stats,
        "sync": result.sync,
        "error": error,
    }
    summary["goals"] = judge_goals(sc, units_out, should.goal_prospects(last_round))
    # what a steered run's truth accounts for (docs/foxglove.md); None: not steered
    summary["steered"] = None
    if steered is not None:
        summary["steered"] = {
            "influences": len(steered.injected),
            "relations": len(steered.relations),
        }
    return summary


def _plain(table: Mapping[str, _V]) -> Mapping[str, _V]:
    """A report's table as the summary holds it: a dict (a report may hold a unit's table as
    the mind's view of it, ``PairTexts``: made a dict once, here)."""
    return table.to_dict() if isinstance(table, PairTexts) else table


def _alternative_lists(u: Universe, texts: Mapping[str, str]) -> dict[str, list[str]]:
    """A table of alternatives' texts in their JSON form (each distinct text parsed once: a
    round holds n(n−1) influences of a few distinct values)."""
    forms: dict[str, list[str]] = {}
    out: dict[str, list[str]] = {}
    for k, v in texts.items():
        form = forms.get(v)
        if form is None:
            form = forms[v] = u.to_list(u.parse_alternative(v))
        out[k] = list(form)  # a list of its own, as each entry had
    return out


def root_cause(world_failure: str | None, reports: Sequence[Mapping[str, Any]]) -> str | None:
    """Why a run did not finish: the world's own failure (a member gone or stalled), else the
    earliest unit failure (others may fail after it, for want of its transmissions), else a
    unit whose mind could not go on; None when it finished."""
    if world_failure is not None:
        return world_failure
    failed = sorted((r["failed_at"], order) for order, r in enumerate(reports) if r["failure"])
    if failed:
        return cast(str, reports[failed[0][1]]["failure"])
    errs = [r["mind_error"] for r in reports if r["mind_error"]]
    return errs[0] if errs else None


def influence_rounds(
    sc: Scenario, reports: Iterable[Mapping[str, Any]]
) -> tuple[list[dict[str, str]], int, dict[tuple[str, str], int] | None]:
    """What the units sent in each influence round (``sent_rounds``); how many rounds every
    pair was sent in (a run that stopped early sends no more: the dynamics are what those
    did); and the last round's influences by pair when every round is whole (a goal is
    judged on it only then)."""
    rounds = sent_rounds(sc, reports)
    pairs = len(sc.units) * (len(sc.units) - 1)
    whole = 0
    while whole < len(rounds) and len(rounds[whole]) == pairs:
        whole += 1
    u = sc.universe
    last_round = (
        {parse_pair_key(k): u.parse_alternative(v) for k, v in rounds[-1].items()}
        if rounds and whole == len(rounds)
        else None
    )
    return rounds, whole, last_round


def wrong_decisions(
    decided: Mapping[str, Mapping[str, object]], truth: Mapping[str, Mapping[str, object]]
) -> list[str]:
    """The units that decided otherwise than a perfect medium would have them decide: another
    interval, frustration or choice (a unit that decided where no decision exists counts)."""
    keys = ("interval", "frustrated", "choice")
    return [
        u
        for u, r in decided.items()
        if r.get("decided")
        and (not truth.get(u, {}).get("decided") or any(r.get(k) != truth[u].get(k) for k in keys))
    ]


def round_dynamics(trajectory: Sequence[Mapping[Any, Any]]) -> dict[str, Any]:
    """What the influences did over the rounds: ``{"state", "since", "length"}``.

    The first round equal to an earlier one: equal to the one before, a **fixed point**
    (``since``: the first round of it); to one ``L`` rounds before, a **cycle** of ``length``
    L entered at ``since``; none, **neither**. Each round's influences are a function of the
    round before (every goal-driven choice is), so a repeat repeats for ever. One round
    tells nothing: ``None``."""
    if len(trajectory) < 2:
        return {"state": None, "since": None, "length": None}
    seen: dict[str, int] = {}
    for r, infl in enumerate(trajectory, 1):
        key = repr(sorted(infl.items()))  # values may be lists (alternatives as action names)
        if key in seen:
            first = seen[key]
            length = r - first
            return {
                "state": "fixed point" if length == 1 else "cycle",
                "since": first,
                "length": length,
            }
        seen[key] = r
    return {"state": "neither", "since": None, "length": None}


def judge_goals(
    sc: Scenario,
    units: Mapping[str, Mapping[str, Any]],
    prospects: Sequence[Mapping[str, Any]],
) -> list[dict[str, Any]]:
    """Each goal of the scenario, judged: ``reached`` (the target decided so; ``None`` when it
    did not decide), with its ``reachable`` and ``share`` on the intended group
    (``Truth.goal_prospects``, one entry a goal, in order)."""
    if not sc.goals:
        return []
    from rgtbus.rgt.control import meets  # a run without goals never loads it

    u = sc.universe
    out: list[dict[str, Any]] = []
    for g, prospect in zip(sc.goals, prospects, strict=True):
        r = units.get(g.target, {})
        reached = None
        if r.get("decided"):
            a, b = r.get("A"), r.get("B")
            if isinstance(a, list) and isinstance(b, list):
                reached = meets(u.from_list(a), u.from_list(b), g.lo, g.hi, g.mode)
        out.append(
            {
                "unit": g.unit,
                "target": g.target,
                "want": [u.to_list(g.lo), u.to_list(g.hi)],
                "mode": g.mode,
                "reached": reached,
                "reachable": prospect["reachable"],
                "share": prospect["share"],
            }
        )
    return out


def check_expectations(scenario: Scenario, s: dict[str, Any]) -> list[tuple[str, bool | None, str]]:
    """Compare the run with the scenario's ``[expect]`` table: ``(what, ok, detail)`` a check.
    At a seed other than the scenario's own, the expectations it marks ``own_seed_only`` are
    left out, each said (``ok`` None: not judged)."""
    u = scenario.universe
    exp = dict(scenario.expect)
    out: list[tuple[str, bool | None, str]] = []
    own = exp.get("own_seed")
    if own is not None and s.get("seed") != own:
        for key in exp.get("own_seed_only", []):
            if key in exp:
                del exp[key]
                out.append((f"{key} (left out)", None,
                            f"it holds for the scenario's own seed {own} only, not seed "
                            f"{s.get('seed')}"))  # fmt: skip

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
    for pair, alt in exp.get("influences", {}).items():
        check(f"influence {pair}", s["influences"].get(pair), alt)
    for name, flag in exp.get("goals", {}).items():
        mine = [g["reached"] for g in s.get("goals") or [] if g["unit"] == name]
        # labelled as the expectation reads: "goals of b not reached" where none should be
        label = f"goals of {name} {'reached' if flag else 'not reached'}"
        check(label, bool(mine) and all(x is True for x in mine), flag)
    if "dynamics" in exp:
        check("influence dynamics", (s.get("rounds") or {}).get("state"), exp["dynamics"])
    # judged on what the run decided: a misread a repair's copy (or the payload itself) set
    # right is no error of the run; the summary lists every misread all the same
    misread, left = s["decode_errors"]["misread"], s["decode_errors"]["left_wrong"]
    label = "no decode error left wrong" + (
        f" ({misread - left} misread, set right)" if misread > left else ""
    )
    check(label, left, 0)
    return out


REPAIR_COUNTS = ("requests", "repeats", "copies", "missing", "resolved", "unresolved")


def repair_summary(sc: Scenario, reports: Sequence[Mapping[str, Any]]) -> dict[str, Any] | None:
    """What the repair cost and did (``[protocol] repair = "arq"``; None without): its blocks
    after each phase, the simulated seconds they add, and the units' counts summed (requests
    and repeats sent, copies read and missing, payloads resolved and still unsure)."""
    if sc.protocol.repair == "none":
        return None
    counts = [r["repair"] for r in reports if r.get("repair") is not None]
    return {
        "mode": sc.protocol.repair,
        "blocks_per_phase": sc.protocol.repair_rounds,
        "seconds": max((c["seconds"] for c in counts), default=0.0),
        **{k: sum(int(c[k]) for c in counts) for k in REPAIR_COUNTS},
    }


def sent_rounds(sc: Scenario, reports: Iterable[Mapping[str, Any]]) -> list[dict[str, str]]:
    """What the units sent in each influence round: ``[{"s>r": code}, ...]`` (pairs in
    scenario order; a unit without a report is missing from them)."""
    out: list[dict[str, str]] = [{} for _ in range(sc.protocol.influence_rounds)]
    by_unit = {r["unit"]: r.get("sent_influences", []) for r in reports}
    for rnd, row in enumerate(out):
        for s, r in sc.pairs():
            sent = by_unit.get(s)
            if sent and rnd < len(sent) and r in sent[rnd]:
                row[pair_key(s, r)] = sent[rnd][r]
    return out


_NO_REPORT: dict[str, Any] = {
    "polynomial": None,
    "p4": None,
    "installed": {},
    "sent_relations": {},
    "influences": {},
}
