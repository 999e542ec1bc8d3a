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
* ``decode_errors``: every misread (each unit's decode that differs from what was sent);
  ``decode_errors_left`` how many of them stayed wrong in what the unit took from its turn
  (``decode_errors_left``: a repair's copy, or the payload of a misread ID, read right sets
  one right). ``--check`` judges the run on those left.
* ``codebook``: the name of the codebook the run's codes came from (``paper``, or a generated
  one: ``generated-k2-N5-seed0``: K actions, N pulses a code, the generator's seed).
* ``error``: why the run did not finish (the root cause), else ``None``.
"""

from __future__ import annotations

from array import array
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, TypedDict, TypeVar, cast

import numpy as np

from rgtbus.mind import decision_fields
from rgtbus.pairs import pair_key, parse_pair_key
from rgtbus.rgt import SubjectResult, Universe
from rgtbus.scenario import Scenario
from rgtbus.truth import Truth

_T = TypeVar("_T")

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
    "decode_errors_left",
    "repair",
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


def is_wrong_decode(kind: str, code: str, addressee: str, sent: str, sent_to: str) -> bool:
    """Whether a decode differs from what was sent: an ID must read as the ID-code; a payload
    must be the code sent, found on its addressee's channel."""
    return (code != "id") if kind == "id" else (code != sent or addressee != sent_to)


class DecodeArrays(Protocol):
    """Decodes held as columns (a unit's ``DecodeColumns``): ``arrays()`` gives each
    decode's turn and the index of its (kind, addressee, code) among the distinct ones."""

    def arrays(self) -> tuple[np.ndarray, np.ndarray, Sequence[tuple[str, str, str]]]: ...


class HeldDecodes:
    """Decodes held as columns already (``DecodeArrays``): each one's turn, and the index
    of its (kind, addressee, code) in ``rows`` (a slice of a unit's, or a unit's decodes
    read from a log's columns)."""

    def __init__(self, turns: np.ndarray, what: np.ndarray, rows: Sequence[tuple[str, str, str]]):
        self._arrays = (turns, what, rows)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, Sequence[tuple[str, str, str]]]:
        return self._arrays

    def __len__(self) -> int:
        return len(self._arrays[0])

    def __iter__(self) -> Iterator[list[Any]]:
        """Each decode as a row: ``[turn, kind, addressee, code]``."""
        turns, what, rows = self._arrays
        for turn, w in zip(turns.tolist(), what.tolist(), strict=True):
            yield [turn, *rows[w]]


class SentTruth:
    """What was sent, per (turn, "id" | "payload"): (addressee, code), the ground truth of
    decode errors. Built once a run; its arrays (by turn) once, on first use by columns."""

    def __init__(self, sent: Mapping[tuple[int, str], tuple[str, str]]) -> None:
        self.sent = sent
        self._arrays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.names: dict[str, int] = {}  # every addressee and code, as a number
        self._shared: dict[int, tuple[object, Any]] = {}

    def shared(self, key: object, build: Callable[[], _T]) -> _T:
        """What every unit's decodes judge alike from ``key`` (a shared listen queue, say),
        built once with this truth by the first that asks (``key`` is kept alive: it is found
        by id)."""
        got = self._shared.get(id(key))
        if got is None:
            got = self._shared[id(key)] = (key, build())
        return cast(_T, got[1])

    def number(self, text: str) -> int:
        return self.names.setdefault(text, len(self.names))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """[class (0: ID, 1: payload), turn] -> known, the addressee's and the code's number."""
        if self._arrays is None:
            self._arrays = self._by_turn(
                (turn, cls != "id", addressee, code)
                for (turn, cls), (addressee, code) in self.sent.items()
                if turn >= 0
            )
        return self._arrays

    @classmethod
    def of_sends(cls, sends: Iterable[Sequence[Any]]) -> SentTruth:
        """The truth of sends given as rows ``(turn, kind, addressee, code)`` (the last send
        of a key counts), held as arrays by turn: a run of n units sends 4n(n−1) codes, and a
        dict of tuples held about 190 bytes a send."""
        truth = cls({})
        other: dict[tuple[int, str], tuple[str, str]] = {}

        def of_turns() -> Iterator[tuple[int, bool, str, str]]:
            for turn, kind, addressee, code in sends:
                if isinstance(turn, int) and turn >= 0:
                    yield turn, kind != "id", addressee, code
                else:  # not a turn of the arrays: looked up as it is
                    other[(turn, "id" if kind == "id" else "payload")] = (addressee, code)

        truth._arrays = truth._by_turn(of_turns())
        truth.sent = _SentByTurn(truth, other)
        return truth

    def _by_turn(
        self, sends: Iterable[tuple[int, bool, str, str]]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``arrays`` of sends ``(turn, payload?, addressee, code)``, in order: the last of a
        key wins."""
        number = self.number
        turns, classes, to, codes = array("q"), array("q"), array("q"), array("q")
        for turn, payload, addressee, code in sends:
            turns.append(turn)
            classes.append(payload)
            to.append(number(addressee))
            codes.append(number(code))
        t, c = np.frombuffer(turns, dtype=np.int64), np.frombuffer(classes, dtype=np.int64)
        span = int(t.max()) + 1 if t.size else 0
        known = np.zeros((2, span), dtype=bool)
        to_of = np.full((2, span), -1)
        code_of = np.full((2, span), -1)
        known[c, t] = True
        to_of[c, t] = np.frombuffer(to, dtype=np.int64)
        code_of[c, t] = np.frombuffer(codes, dtype=np.int64)
        return known, to_of, code_of


def wrong_decodes(
    unit: str, decodes: Iterable[Sequence[Any]] | DecodeArrays, truth: SentTruth
) -> list[dict[str, Any]]:
    """A unit's decodes that differ from what was sent (``is_wrong_decode``), in decode
    order, as ``decode_error`` entries; a decode of a turn with no known send is not judged.
    Rows (turn, kind, addressee, code) are judged one by one; columns in one vectorised step
    (n³ decodes at n units)."""
    judge = getattr(decodes, "wrong", None)
    if judge is not None:  # decodes that judge themselves (a unit's ``DecodeColumns``)
        return cast(list[dict[str, Any]], judge(unit, truth))
    sent_of = truth.sent
    arrays = getattr(decodes, "arrays", None)
    if arrays is None:
        out = []
        for turn, kind, addressee, code in cast(Iterable[Sequence[Any]], decodes):
            key = (turn, "id" if kind == "id" else "payload")
            if key in sent_of:
                sent_to, sent = sent_of[key]
                if is_wrong_decode(kind, code, addressee, sent, sent_to):
                    out.append(decode_error(unit, turn, kind, code, sent))
        return out
    turns, what, rows = arrays()
    if not len(turns) or not sent_of:
        return []
    known, to_of, code_of = truth.arrays()
    number = truth.number
    row_cls = np.array([int(k != "id") for k, _, _ in rows])
    row_id_ok = np.array([k != "id" or c == "id" for k, _, c in rows])  # an ID read as the ID
    row_to = np.array([number(a) for _, a, _ in rows])
    row_code = np.array([number(c) for _, _, c in rows])
    cls, t = row_cls[what], turns.astype(np.int64)
    in_span = (t >= 0) & (t < known.shape[1])
    t = np.where(in_span, t, 0)
    judged = in_span & known[cls, t]
    bad = np.where(
        cls == 0,
        ~row_id_ok[what],
        (code_of[1, t] != row_code[what]) | (to_of[1, t] != row_to[what]),
    )
    out = []
    for i in np.flatnonzero(judged & bad).tolist():
        turn = int(turns[i])
        kind, _, code = rows[what[i]]
        key = (turn, "id" if kind == "id" else "payload")
        out.append(decode_error(unit, turn, kind, code, sent_of[key][1]))
    return out


def decode_error(
    unit: str, turn: int | None, kind: str, decoded: str, sent: str | None
) -> dict[str, Any]:
    """One entry of a summary's ``decode_errors``."""
    return {"unit": unit, "turn": turn, "kind": kind, "decoded": decoded, "sent": sent}


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
    sc: Scenario, reports: Iterable[dict[str, Any]], result: WorldEnd, *, engine: str = "event"
) -> dict[str, Any]:
    """The run's summary from every unit's ``report()`` (one process or many) and how the
    world ended. Units without a
    report (a process that died) are absent from ``units`` and the run does not agree; the
    shared fields are the first reporting unit's (none at all: empty)."""
    reports = list(reports)
    by_unit = {r["unit"]: r for r in reports}
    ref = next((by_unit[u] for u in sc.units if u in by_unit), _NO_REPORT)
    tables = {r["unit"]: r["installed"] for r in reports}
    agree = agreement(
        [r["installed"] for r in reports], [r["polynomial"] for r in reports], len(sc.units)
    )
    decode_errors = all_wrong_decodes(reports)
    left = decode_errors_left(reports, decode_errors) if decode_errors else 0
    units_out = {name: by_unit[name]["result"] for name in sc.units if name in by_unit}
    outcome = outcome_of(sc, units_out) if len(units_out) == len(sc.units) else None
    error = root_cause(result.failure, reports)
    p4 = ref.get("p4")
    decomposable = None if p4 is None and ref["polynomial"] is None else p4 is None
    rounds, whole, last_round = influence_rounds(sc, reports)
    should = Truth(sc)  # what a perfect medium would have given
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
        "sent_relations": ref["sent_relations"],
        "unit_relations": tables,
        "agree": agree,
        "influences": ref["influences"],
        "units": units_out,
        "frustrated": frustrated_units(units_out),
        "wrong_decisions": wrong_decisions(units_out, clean[-1]) if units_out else [],
        "decisions": judged_decisions(sc, reports, clean) if units_out else [],
        "goals": [],
        "rounds": {
            "count": sc.protocol.influence_rounds,
            **round_dynamics(rounds[:whole]),
            "influences": [_alternative_lists(u, r) for r in rounds],
        },
        "outcome": outcome,
        "decode_errors": decode_errors,
        "decode_errors_left": left,
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
    return summary


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


def _sent_truth(reports: Sequence[Mapping[str, Any]]) -> SentTruth:
    """The ground truth of decode errors: every report's sends (``SentTruth.of_sends``)."""
    return SentTruth.of_sends(row for r in reports for row in r["sends"])


class _SentByTurn(Mapping[tuple[int, str], tuple[str, str]]):
    """``SentTruth.sent`` read from its arrays: (turn, "id" | "payload") -> (addressee, code)."""

    def __init__(self, truth: SentTruth, other: dict[tuple[int, str], tuple[str, str]]) -> None:
        self._arrays = truth.arrays()
        self._names = list(truth.names)  # a number's text
        self._other = other

    def __getitem__(self, key: tuple[int, str]) -> tuple[str, str]:
        known, to_of, code_of = self._arrays
        turn, cls = key
        if isinstance(turn, int) and 0 <= turn < known.shape[1] and cls in ("id", "payload"):
            c = int(cls != "id")
            if known[c, turn]:
                return self._names[to_of[c, turn]], self._names[code_of[c, turn]]
        return self._other[key]

    def __iter__(self) -> Iterator[tuple[int, str]]:
        cls, turn = np.nonzero(self._arrays[0])
        for c, t in zip(cls.tolist(), turn.tolist(), strict=True):
            yield (t, "payload" if c else "id")
        yield from self._other

    def __len__(self) -> int:
        return int(self._arrays[0].sum()) + len(self._other)


def all_wrong_decodes(reports: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Every unit's decodes that differ from what was sent (the ground truth: every report's
    sends, per (turn, kind)), unit by unit in report order."""
    sent_truth = _sent_truth(reports)
    out = []
    for r in reports:
        out.extend(wrong_decodes(r["unit"], r["decodes"], sent_truth))
    return out


def decode_errors_left(
    reports: Sequence[Mapping[str, Any]], errors: Sequence[Mapping[str, Any]]
) -> int:
    """How many of ``errors`` (``all_wrong_decodes``) stayed wrong in what the unit took from
    its turn: a misread counts unless the unit's last read of that turn's payload matched what
    was sent (a repair's copy read right, ``[protocol] repair``; or, for a misread ID, the
    payload read right all the same). What ``--check`` judges: what the run decided on."""
    sent_truth = _sent_truth(reports)
    asked: dict[str, set[int]] = {}  # per unit, the turns of its errors
    for e in errors:
        asked.setdefault(e["unit"], set()).add(e["turn"])
    right = {
        r["unit"]: _payloads_read_right(r["decodes"], sent_truth, asked[r["unit"]])
        for r in reports
        if r["unit"] in asked
    }
    return sum(1 for e in errors if e["turn"] not in right.get(e["unit"], set()))


def _payloads_read_right(
    decodes: Iterable[Sequence[Any]] | DecodeArrays, truth: SentTruth, turns_asked: set[int]
) -> set[int]:
    """Which of ``turns_asked`` have their payload last read by the unit as it was sent (code
    and addressee); the decodes of other turns are not looked at (held as columns, a large
    run's are n² a unit)."""
    last: dict[int, bool] = {}
    arrays = getattr(decodes, "arrays", None)
    sent_of = truth.sent
    if arrays is None:
        for turn, kind, addressee, code in cast(Iterable[Sequence[Any]], decodes):
            key = (turn, "payload")
            if turn in turns_asked and kind != "id" and key in sent_of:
                sent_to, sent = sent_of[key]
                last[turn] = not is_wrong_decode(kind, code, addressee, sent, sent_to)
        return {t for t, ok in last.items() if ok}
    turns, what, rows = arrays()
    asked = np.array(sorted(t for t in turns_asked if t is not None), dtype=np.int64)
    at = np.flatnonzero(np.isin(turns, asked))
    for i, t in zip(at.tolist(), turns[at].tolist(), strict=True):  # the last read wins
        kind, addressee, code = rows[what[i]]
        key = (int(t), "payload")
        if kind != "id" and key in sent_of:
            sent_to, sent = sent_of[key]
            last[int(t)] = not is_wrong_decode(kind, code, addressee, sent, sent_to)
    return {t for t, ok in last.items() if ok}


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
    misread = len(s["decode_errors"])
    left = s.get("decode_errors_left", misread)
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
