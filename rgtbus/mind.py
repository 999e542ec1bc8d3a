"""A unit's reasoning: what it decoded -> relationships -> polynomial -> decisions (pure).

A unit knows only what it decoded off the medium: the relationship code every unit sent to
every other (alliance iff both sent alliance: AND), and every influence. From those it builds
the graph, the polynomial and F, runs the forward task for itself and predicts the others, and
picks its own choice from its interval by its decision policy:

* ``max``: the largest alternative of the interval (A); ``min``: the smallest (B);
* ``seeded-random``: uniform over the interval, from the unit's seeded generator;
* a preferred alternative (e.g. ``{alpha}``): chosen when within the interval, else ``max``.

A frustrated unit makes no choice.

What a unit sends is chosen here too: its relationship code to each peer (fixed by the scenario;
alliance with probability p, the "positive pole", from its own seeded draws; or its side of a
seeded random decomposable group, ``cograph``, which every unit draws alike from the scenario's
seed) and its influence on each peer (listed per pair; else one value for all, ``uniform``; or
drawn from its own seeded generator over weighted alternatives, ``random``).
"""

from __future__ import annotations

import random
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import lru_cache

from rgtbus.errors import NotDecomposable, RgtbusError
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
from rgtbus.scenario import Scenario


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
            raise RgtbusError(f"no influence for {me}>{r} (policy {policy})")
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


@dataclass
class Mind:
    me: str
    units: tuple[str, ...]
    universe: Universe
    policy: str
    rng: random.Random
    sent: dict[tuple[str, str], bool] = field(default_factory=dict)  # s>r: alliance?
    influences: dict[tuple[str, str], int] = field(default_factory=dict)
    polynomial: str | None = None
    error: str | None = None
    p4: tuple[str, str, str, str] | None = None  # the induced P4 of a group with no polynomial
    df: DecisionFunction | None = None
    results: dict[str, SubjectResult] | None = None
    choice: int | None = None

    def pairs(self) -> list[tuple[str, str]]:
        return [(s, r) for s in self.units for r in self.units if s != r]

    def relations_complete(self) -> bool:
        n = len(self.units)
        return len(self.sent) == n * (n - 1) and all(p in self.sent for p in self.pairs())

    def influences_complete(self) -> bool:
        n = len(self.units)
        return len(self.influences) == n * (n - 1) and all(
            p in self.influences for p in self.pairs()
        )

    def installed(self) -> dict[str, str]:
        """``{"a-b": "alliance" | "conflict"}`` for every pair known from both sides."""
        out = {}
        for i, a in enumerate(self.units):
            for b in self.units[i + 1 :]:
                if (a, b) in self.sent and (b, a) in self.sent:
                    both = self.sent[(a, b)] and self.sent[(b, a)]
                    out[f"{a}-{b}"] = "alliance" if both else "conflict"
        return out

    def build_group(self) -> None:
        """Phase 2: graph and polynomial from the decoded relationship codes."""
        try:
            graph = install_relations(self.units, self.sent)
            poly = graph_to_polynomial(graph)
        except NotDecomposable as exc:  # a result of random socialisation: no decisions
            self.p4 = exc.p4
            return
        except RgtbusError as exc:
            self.error = str(exc)
            return
        self.df = decision_function(poly, self.units)
        self.polynomial = format_expr(poly, needs_star(self.units))

    def decide(self) -> None:
        """Phase 4: forward task for every subject, then this unit's own choice."""
        if self.df is None:
            return
        matrix = InfluenceMatrix.from_mapping(self.influences, self.units, self.universe)
        self.results = forward(self.df, self.universe, matrix)
        self.choice = choose(self.policy, self.results[self.me], self.universe, self.rng)

    def canonical(self, subject: str) -> str:
        assert self.df is not None
        return canonical_form(self.df, subject).text(needs_star(self.units))


# -- a unit's own intents, and the decisions a perfect medium would give ------------------------


def intents(sc: Scenario, me: str) -> tuple[dict[str, str], dict[str, str]]:
    """What unit ``me`` sends under scenario ``sc``: ``({peer: relation}, {peer: influence})``."""
    relations = choose_relations(
        me,
        sc.units,
        seed=sc.seed,
        fixed=sc.fixed_relations,
        draws=sc.draws,
        p=sc.alliance_p,
        policy=sc.relation_policy,
    )
    influences = choose_influences(
        me,
        sc.units,
        sc.influences,
        sc.universe,
        policy=sc.influence_policy,
        value=sc.influence_value,
        weights=sc.influence_weights,
        seed=sc.seed,
    )
    return relations, influences


def mind_of(sc: Scenario, me: str) -> Mind:
    """Unit ``me``'s mind before it hears anything (its decision generator seeded by the run)."""
    return Mind(
        me, sc.units, sc.universe, sc.decisions[me], random.Random(f"{sc.seed}:{me}:decision")
    )


def result_fields(mind: Mind) -> dict[str, object]:
    """A unit's decision as its report and the run summary state it (``decided``: it ran the
    forward task; ``interval``: ``[B, A]``, ``None`` when frustrated)."""
    u = mind.universe
    r = mind.results[mind.me] if mind.results else None
    return {
        "interval": None if r is None or r.frustrated else [u.to_list(r.B), u.to_list(r.A)],
        "frustrated": bool(r.frustrated) if r else False,
        "choice": None if mind.choice is None else u.to_list(mind.choice),
        "canonical": mind.canonical(mind.me) if mind.df else None,
        "A": u.to_list(r.A) if r else None,
        "B": u.to_list(r.B) if r else None,
        "decided": r is not None,
    }


def noise_free(sc: Scenario) -> dict[str, dict[str, object]]:
    """Every unit's decision (``result_fields``) had it read every code exactly as sent: the
    forward task on the group and influences the units intended. A group with no polynomial
    gives no decisions (``decided`` false for all)."""
    sent: dict[tuple[str, str], bool] = {}
    influences: dict[tuple[str, str], int] = {}
    for s in sc.units:
        relations, infl = intents(sc, s)
        for r, code in relations.items():
            sent[(s, r)] = code == "alliance"
        for r, text in infl.items():
            influences[(s, r)] = sc.universe.parse_alternative(text)
    # The forward task is the same for every unit that knows everything: solve it once.
    known = mind_of(sc, sc.units[0])
    known.sent, known.influences = sent, influences
    known.build_group()
    known.decide()
    out = {}
    for me in sc.units:
        mind = mind_of(sc, me)
        mind.df, mind.polynomial, mind.p4, mind.results = (
            known.df,
            known.polynomial,
            known.p4,
            known.results,
        )
        if mind.results is not None:
            mind.choice = choose(mind.policy, mind.results[me], mind.universe, mind.rng)
        out[me] = result_fields(mind)
    return out


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
