"""A unit's reasoning: what it decoded -> relationships -> polynomial -> decisions (pure).

A unit knows only what it decoded off the medium: the relationship code every unit sent to
every other (alliance iff both sent alliance: AND), and every influence. From those it builds
the graph, the polynomial and F, runs the forward task for itself and predicts the others, and
picks its own choice from its interval by its decision policy:

* ``max``: the largest alternative of the interval (A); ``min``: the smallest (B);
* ``seeded-random``: uniform over the interval, from the unit's seeded generator;
* a preferred alternative (e.g. ``{alpha}``): chosen when within the interval, else ``max``.

A frustrated unit makes no choice.

Influence rounds (``[protocol] influence_rounds``): every unit re-sends its influences in each
round and decides after each (the forward task on that round's influences); its last round's
decision is its decision. A goal-driven unit (``[goals.UNIT]``) chooses its influence on each
target when its turn comes, by the inverse task (``steer``, docs/goals.md), on the group it
decoded, the influences on the target heard so far in this round, and, as a prediction of the
rest, what they sent the round before.

What a unit sends is chosen here too: its relationship code to each peer (fixed by the scenario;
alliance with probability p, the "positive pole", from its own seeded draws; or its side of a
seeded random decomposable group, ``cograph``, which every unit draws alike from the scenario's
seed) and its influence on each peer (listed per pair; else one value for all, ``uniform``; or
drawn from its own seeded generator over weighted alternatives, ``random``).

What a run should give on a perfect medium is ``rgtbus.truth``'s to say, and judging a run is
``rgtbus.summary``'s: a mind only reasons on what its unit decoded.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Hashable, Mapping, MutableMapping, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import TYPE_CHECKING, Any, TypeVar, cast

import numpy as np

from rgtbus.errors import BadInput, NotDecomposable, RgtbusError
from rgtbus.pairs import (
    PairTable,
    PairTexts,
    SharedTable,
    ordered_pairs,
    pair_key,
    relation_key,
    sorted_slots,
    unordered_slots,
)
from rgtbus.rgt import (
    DecisionFunction,
    InfluenceMatrix,
    SubjectResult,
    Universe,
    canonical_form,
    decision_function,
    format_expr,
    forward,
    graph_to_polynomial,
    install_relations,
    polynomial_to_graph,
    random_polynomial,
)
from rgtbus.rgt.expr import needs_star
from rgtbus.scenario import Goal, Scenario

if TYPE_CHECKING:
    from rgtbus.rgt.control import SteeringChoice

Pair = tuple[str, str]


@lru_cache(maxsize=16)
def cograph_relations(units: tuple[str, ...], seed: int) -> dict[tuple[str, str], bool]:
    """A seeded random decomposable group over ``units`` (a random cotree: no induced P4, so
    decisions exist at any n), as the relationship every unit sends to every other (both
    directions alike). Every unit draws the same group from the same seed."""
    graph = polynomial_to_graph(random_polynomial(units, random.Random(f"{seed}:cograph")), units)
    return {(a, b): graph.allied(a, b) for a in units for b in units if a != b}


def choose_relations(
    me: str,
    units: Sequence[str],
    *,
    seed: int,
    fixed: Mapping[tuple[str, str], bool],
    draws: Mapping[tuple[str, str], float],
    p: float,
    policy: str = "random",
) -> dict[str, str]:
    """``{peer: "alliance" | "conflict"}``: fixed where the scenario fixes it, else alliance
    iff this unit's draw for the peer is at most ``p`` (an explicit draw replaces the random
    one). A draw is made for every peer, so fixing one never shifts the others. ``cograph``:
    this unit's side of ``cograph_relations``."""
    if policy == "cograph":
        group = cograph_relations(tuple(units), seed)
        return {r: "alliance" if group[(me, r)] else "conflict" for r in units if r != me}
    rng = random.Random(f"{seed}:{me}:relations")
    out = {}
    for r in units:
        if r == me:
            continue
        key = (me, r)
        draw = rng.random()
        if key in fixed:
            out[r] = "alliance" if fixed[key] else "conflict"
        else:
            out[r] = "alliance" if draws.get(key, draw) <= p else "conflict"
    return out


def choose_influences(
    me: str,
    units: Sequence[str],
    influences: Mapping[tuple[str, str], int],
    universe: Universe,
    *,
    policy: str = "fixed",
    value: int | None = None,
    weights: Mapping[int, float] | None = None,
    seed: int = 0,
) -> dict[str, str]:
    """``{peer: alternative text}``: the influence this unit sends to each peer. A pair listed
    in ``influences`` is sent as listed; the others by ``policy``: ``uniform`` sends ``value``;
    ``random`` draws from this unit's seeded generator over ``weights`` (alternative: weight;
    none: every alternative alike), one draw per peer in unit order, listed or not (listing
    one never shifts the others)."""
    rng = random.Random(f"{seed}:{me}:influences")
    table = dict(weights) if weights else dict.fromkeys(universe, 1.0)
    alts, ws = list(table), list(table.values())
    out = {}
    for r in units:
        if r == me:
            continue
        drawn = rng.choices(alts, ws)[0] if policy == "random" else None
        if (me, r) in influences:
            chosen = influences[(me, r)]
        elif policy == "uniform" and value is not None:
            chosen = value
        elif drawn is not None:
            chosen = drawn
        else:
            raise BadInput(f"no influence for {me}>{r} (policy {policy})")
        out[r] = universe.format(chosen)
    return out


def choose(
    policy: str, result: SubjectResult, universe: Universe, rng: random.Random
) -> int | None:
    if result.frustrated:
        return None
    choices = result.choices(universe)
    if policy == "max":
        return result.A
    if policy == "min":
        return result.B
    if policy == "seeded-random":
        return rng.choice(choices)
    preferred = universe.parse_alternative(policy)
    return preferred if preferred in choices else result.A


_T = TypeVar("_T")
_RELATION_TEXT = np.array(["conflict", "alliance"], dtype=object)  # by alliance?
_RELATION_NAMES = {0: "conflict", 1: "alliance"}
_MEMO: dict[tuple[Hashable, tuple[tuple[str, ...], bool, int, bytes]], Any] = {}
_MEMO_SIZE = 16


def _memo(kind: Hashable, table: Mapping[Pair, Any], build: Callable[[], _T]) -> _T:
    """``build()``, the same object for every table equal to ``table`` (a ``PairTable``;
    another mapping is built afresh): the units of a group mostly hold equal tables, and a
    report built from one of n² entries for each of n units would be n³ work. What is
    returned is shared: read, never changed (a table as a ``SharedTable``)."""
    if not isinstance(table, PairTable):
        return build()
    key = (kind, table.snapshot())
    got = _MEMO.get(key)
    if got is None:
        if len(_MEMO) >= _MEMO_SIZE:  # a few tables at a time are the run's; drop the old
            _MEMO.clear()
        built: Any = build()
        _MEMO[key] = got = SharedTable(built) if type(built) is dict else built
    return cast(_T, got)


@dataclass
class _Group:
    """What a relations table builds (``Mind.build_group``): the decision function and its
    polynomial, or the P4 or error that left the group without one; ``texts`` the canonical
    forms of its subjects as text, filled as they are asked for."""

    df: DecisionFunction | None
    polynomial: str | None
    p4: tuple[str, str, str, str] | None
    error: str | None
    texts: dict[str, str] = field(default_factory=dict)


@dataclass
class Mind:
    me: str
    units: tuple[str, ...]
    universe: Universe
    policy: str
    rng: random.Random
    # s>r: alliance? (a PairTable once the mind exists: n² small slots, not a dict)
    sent: MutableMapping[Pair, bool] = field(default_factory=dict)
    influences: Mapping[Pair, int] = field(default_factory=dict)  # the last round decided
    polynomial: str | None = None
    error: str | None = None
    p4: tuple[str, str, str, str] | None = None  # the induced P4 of a group with no polynomial
    df: DecisionFunction | None = None
    results: dict[str, SubjectResult] | None = None
    choice: int | None = None
    rounds: int = 1  # influence rounds to hear and decide
    heard: dict[int, MutableMapping[Pair, int]] = field(default_factory=dict)  # round -> table
    decided_rounds: int = 0  # rounds decided so far (their influences complete)
    # round -> (every subject's result, this unit's choice) as decided in that round
    round_results: dict[int, tuple[dict[str, SubjectResult], int | None]] = field(
        default_factory=dict
    )
    # subject -> its canonical form as text, of the decision function ``_texts_of``
    _texts: dict[str, str] = field(default_factory=dict, repr=False, compare=False)
    _texts_of: DecisionFunction | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.sent:  # every unit holds the group's tables: arrays, not dicts (n³ in all)
            # boolean: it reads back bools
            self.sent = cast(MutableMapping[Pair, bool], PairTable(self.units, boolean=True))

    def heard_in(self, rnd: int) -> MutableMapping[Pair, int]:
        """The influences heard in round ``rnd`` so far (a table made on first use)."""
        table = self.heard.get(rnd)
        if table is None:
            table = self.heard[rnd] = PairTable(self.units)
        return table

    def pairs(self) -> list[tuple[str, str]]:
        return ordered_pairs(self.units)

    def relations_complete(self) -> bool:
        n = len(self.units)
        sent = self.sent
        if isinstance(sent, PairTable) and sent.units == self.units:
            return sent.holds_every_pair()
        return len(sent) == n * (n - 1) and all(p in sent for p in self.pairs())

    def influences_complete(self) -> bool:
        n = len(self.units)
        return len(self.influences) == n * (n - 1) and all(
            p in self.influences for p in self.pairs()
        )

    def installed(self) -> dict[str, str]:
        """``{"a-b": "alliance" | "conflict"}`` for every pair known from both sides."""
        return _memo("installed", self.sent, self._installed)

    def _installed(self) -> dict[str, str]:
        sent = self.sent
        if isinstance(sent, PairTable) and sent.units == self.units:  # a table: as arrays
            vals, held = sent.columns()
            ab, ba, keys = unordered_slots(self.units)
            known = np.flatnonzero(held[ab] & held[ba])
            allied = (vals[ab[known]] != 0) & (vals[ba[known]] != 0)
            return dict(
                zip(
                    keys[known].tolist(), _RELATION_TEXT[allied.view(np.int8)].tolist(), strict=True
                )
            )
        out = {}
        for i, a in enumerate(self.units):
            for b in self.units[i + 1 :]:
                if (a, b) in self.sent and (b, a) in self.sent:
                    both = self.sent[(a, b)] and self.sent[(b, a)]
                    out[relation_key(a, b)] = "alliance" if both else "conflict"
        return out

    def sent_table(self) -> dict[str, str]:
        """The relation codes heard (and sent): ``{"s>r": "alliance" | "conflict"}``."""
        return _memo("sent", self.sent, self._sent_table)

    def _sent_table(self) -> dict[str, str]:
        sent = self.sent
        if isinstance(sent, PairTable):  # a table: as arrays
            vals, held = sent.columns()
            order, keys = sorted_slots(sent.units)
            mine = held[order]
            texts = _RELATION_TEXT[(vals[order][mine] != 0).view(np.int8)]
            return dict(zip(keys[mine].tolist(), texts.tolist(), strict=True))
        return {
            pair_key(s, r): "alliance" if v else "conflict"
            for (s, r), v in sorted(self.sent.items())
        }

    def sent_view(self) -> Mapping[str, str]:
        """``sent_table`` as a report holds it: read from the table's bytes (``PairTexts``,
        not n² dict entries a unit), one object for every mind holding an equal table."""
        sent = self.sent
        if not isinstance(sent, PairTable):
            return self.sent_table()
        return _memo("sent view", sent, lambda: PairTexts(sent, _RELATION_NAMES))

    def influence_view(self) -> Mapping[str, list[str]]:
        """``influence_table`` as a report holds it (``sent_view``)."""
        table, u = self.influences, self.universe
        if not isinstance(table, PairTable):
            return self.influence_table()

        def build() -> PairTexts[list[str]]:
            vals, held = table.columns()
            return PairTexts(table, {v: u.to_list(v) for v in set(vals[held].tolist())})

        return _memo(f"influence view {u.actions}", table, build)

    def influence_table(self) -> dict[str, list[str]]:
        """The influences of the last round decided: ``{"s>r": [action, ...]}``."""
        key = f"influences {self.universe.actions}"
        return _memo(key, self.influences, self._influence_table)

    def _influence_table(self) -> dict[str, list[str]]:
        u = self.universe
        lists: dict[int, list[str]] = {}  # one list an alternative (a few), not one a pair
        table = self.influences
        if isinstance(table, PairTable):  # a table: as arrays
            vals, held = table.columns()
            order, keys = sorted_slots(table.units)
            mine = held[order]
            got = vals[order][mine].tolist()
            for v in set(got):
                lists[v] = u.to_list(v)
            return dict(zip(keys[mine].tolist(), map(lists.__getitem__, got), strict=True))
        return {
            pair_key(s, r): lists[v] if v in lists else lists.setdefault(v, u.to_list(v))
            for (s, r), v in sorted(self.influences.items())
        }

    def build_group(self) -> None:
        """Phase 2: graph and polynomial from the decoded relationship codes. Units that
        decoded equal tables share the result (``_memo``), and with it the canonical texts
        of its decisions (``canonical``)."""
        group = _memo("group", self.sent, self._group)
        self.df, self.polynomial, self.p4, self.error = (
            group.df,
            group.polynomial,
            group.p4,
            (group.error),
        )
        self._texts, self._texts_of = group.texts, group.df

    def _group(self) -> _Group:
        try:
            graph = install_relations(self.units, self.sent)
            poly = graph_to_polynomial(graph)
        except NotDecomposable as exc:  # a result of random socialisation: no decisions
            return _Group(None, None, exc.p4, None)
        except RgtbusError as exc:
            return _Group(None, None, None, str(exc))
        df = decision_function(poly, self.units)
        return _Group(df, format_expr(poly, needs_star(self.units)), None, None)

    def decide(self) -> None:
        """Phase 4: forward task for every subject, then this unit's own choice."""
        if self.df is None:
            return
        df = self.df

        def results() -> dict[str, SubjectResult]:
            matrix = InfluenceMatrix.from_mapping(self.influences, self.units, self.universe)
            return forward(df, self.universe, matrix)

        # the forward task is a function of the relations and influences decoded: units that
        # decoded alike share one result (read, never changed)
        sent = self.sent
        if isinstance(sent, PairTable):
            kind = ("forward", sent.snapshot(), self.universe.actions)
            self.results = _memo(kind, self.influences, results)
        else:
            self.results = results()
        self.choice = choose(self.policy, self.results[self.me], self.universe, self.rng)

    def decide_round(self, rnd: int) -> None:
        """``decide`` on the current influences as round ``rnd``'s decision (kept in
        ``round_results``)."""
        self.decide()
        if self.results is not None:
            self.round_results[rnd] = (self.results, self.choice)

    def hear_influence(self, rnd: int, pair: Pair, value: int) -> list[int]:
        """An influence decoded in round ``rnd``; decides every round whose influences are now
        complete, in order, and returns those rounds (``influences`` is then the last one's)."""
        table = self.heard.get(rnd)
        (table if table is not None else self.heard_in(rnd))[pair] = value
        done = []
        n = len(self.units)
        while self.decided_rounds < self.rounds:
            nxt = self.heard.get(self.decided_rounds + 1, {})
            if len(nxt) != n * (n - 1):
                break
            self.decided_rounds += 1
            self.influences = nxt  # complete: the round's table itself, not a copy a unit
            self.decide_round(self.decided_rounds)
            done.append(self.decided_rounds)
        return done

    @property
    def all_rounds_decided(self) -> bool:
        return self.decided_rounds >= self.rounds

    def steer(self, goal: Goal, rnd: int) -> SteeringChoice | str:
        """This unit's influence on ``goal.target`` in round ``rnd`` by the inverse task on
        the group it decoded: the influences on the target heard in this round so far, and
        what the others sent it the round before as the prediction of the rest. A text says
        why there is none to compute (the group is not known, or has no polynomial)."""
        if self.df is None:
            if self.p4 is not None:
                return "the group is not decomposable: no decision function to invert"
            return self.error or "the relationship phase is not complete: no group yet"
        from rgtbus.rgt.control import steer  # a run without goals never loads it

        heard, predicted = self.steering_inputs(goal.target, rnd)
        return steer(
            self.df, self.universe, self.me, goal.target, goal.lo, goal.hi, goal.mode, heard,
            predicted,
        )  # fmt: skip

    def steering_inputs(self, target: str, rnd: int) -> tuple[dict[str, int], dict[str, int]]:
        """What steering ``target`` in round ``rnd`` knows: the influences on it heard in this
        round, and (the prediction) those of the round before not heard again yet."""
        heard = {s: v for (s, r), v in self.heard.get(rnd, {}).items() if r == target}
        before = {s: v for (s, r), v in self.heard.get(rnd - 1, {}).items() if r == target}
        heard.pop(self.me, None)
        return heard, {s: v for s, v in before.items() if s != self.me and s not in heard}

    def canonical(self, subject: str) -> str:
        """The canonical form of ``subject``'s decision in this unit's group, as text."""
        assert self.df is not None
        if self._texts_of is not self.df:  # a group set by hand (a copy of another's)
            self._texts, self._texts_of = {}, self.df
        text = self._texts.get(subject)
        if text is None:
            text = canonical_form(self.df, subject).text(needs_star(self.units))
            self._texts[subject] = text
        return text


# -- a unit's own intents, and the decisions a perfect medium would give ------------------------


def intents(sc: Scenario, me: str) -> tuple[dict[str, str], dict[str, str]]:
    """What unit ``me`` sends under scenario ``sc``: ``({peer: relation}, {peer: influence})``."""
    relations = choose_relations(
        me,
        sc.units,
        seed=sc.seed,
        fixed=sc.relations.fixed,
        draws=sc.relations.draws,
        p=sc.relations.p,
        policy=sc.relations.policy,
    )
    influences = choose_influences(
        me,
        sc.units,
        sc.influences.pairs,
        sc.universe,
        policy=sc.influences.policy,
        value=sc.influences.value,
        weights=sc.influences.weights,
        seed=sc.seed,
    )
    return relations, influences


def mind_of(sc: Scenario, me: str) -> Mind:
    """Unit ``me``'s mind before it hears anything (its decision generator seeded by the run)."""
    return Mind(
        me,
        sc.units,
        sc.universe,
        sc.decisions[me],
        random.Random(f"{sc.seed}:{me}:decision"),
        rounds=sc.protocol.influence_rounds,
    )


def goal_text(target: str, lo: int, hi: int, mode: str, universe: Universe) -> str:
    """A goal in words, as logs and ``run`` say it: ``a: exactly 1``, ``a: within [0, 1]``,
    ``a: largest {alpha}``."""
    low, high = universe.format(lo), universe.format(hi)
    want = low if lo == hi else f"[{low}, {high}]"
    how = {"exact": "exactly", "contains": "within"}.get(mode, mode)
    return f"{target}: {how} {want}"


def steering_reason(choice: SteeringChoice | str, goal: Goal, universe: Universe) -> str:
    """Why a goal-driven unit sends what it sends (its log line and the goal record's
    ``reason``)."""
    what = goal_text(goal.target, goal.lo, goal.hi, goal.mode, universe)
    if isinstance(choice, str):
        return f"{what}: no inverse task ({choice}); keeps its policy's influence"
    if choice.value is None:
        return (
            f"{what}: unreachable by its own influence ({choice.solutions} joint influences "
            "meet it, none with what it heard); keeps its policy's influence"
        )
    v = universe.format(choice.value)
    if choice.rule == "robust" and choice.of == 1:
        return f"{what}: {v} meets it (every other influence on {goal.target} heard)"
    if choice.rule == "robust":
        return f"{what}: {v} meets it whatever the unheard send ({choice.of} completions)"
    if choice.rule == "predicted":
        return (
            f"{what}: {v} meets it if the unheard send as last round "
            f"({choice.reached} of {choice.of} completions)"
        )
    return f"{what}: {v} meets it for the most completions ({choice.reached} of {choice.of})"


def decision_fields(
    result: SubjectResult | None, choice: int | None, universe: Universe
) -> dict[str, Any]:
    """One subject's decision as every record, report and summary states it (the one place):
    ``interval`` ``[B, A]`` (``None`` when frustrated or undecided), ``frustrated``, ``choice``,
    ``A`` and ``B``, alternatives as sorted lists of action names."""
    u = universe
    r = result
    return {
        "interval": None if r is None or r.frustrated else [u.to_list(r.B), u.to_list(r.A)],
        "frustrated": bool(r.frustrated) if r else False,
        "choice": None if choice is None else u.to_list(choice),
        "A": u.to_list(r.A) if r else None,
        "B": u.to_list(r.B) if r else None,
    }


def result_fields(mind: Mind) -> dict[str, Any]:
    """A unit's decision as its report and the run summary state it (``decided``: it ran the
    forward task; ``interval``: ``[B, A]``, ``None`` when frustrated)."""
    r = mind.results[mind.me] if mind.results else None
    fields = decision_fields(r, mind.choice, mind.universe)
    return {
        "interval": fields["interval"],
        "frustrated": fields["frustrated"],
        "choice": fields["choice"],
        "canonical": mind.canonical(mind.me) if mind.df else None,
        "A": fields["A"],
        "B": fields["B"],
        "decided": r is not None,
    }
