"""A unit's reasoning: what it decoded -> relationships -> polynomial -> decisions (pure).

A unit knows only what it decoded off the medium: the relationship code every unit sent to
every other (alliance iff both sent alliance: AND), and every influence. From those it builds
the graph, the polynomial and F, runs the forward task for itself and predicts the others, and
picks its own choice from its interval by its decision policy:

* ``max``: the largest alternative of the interval (A); ``min``: the smallest (B);
* ``seeded-random``: uniform over the interval, from the unit's seeded generator;
* a preferred alternative (e.g. ``{alpha}``): chosen when within the interval, else ``max``.

A frustrated unit makes no choice.

What a unit sends is chosen here too: its relationship code to each peer (fixed by the scenario,
or alliance with probability p, the "positive pole", from its own seeded draws) and its
influence on each peer.
"""

from __future__ import annotations

import random
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from rgtbus.errors import RgtbusError
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
)
from rgtbus.rgt.expr import needs_star


def choose_relations(
    me: str,
    units: Sequence[str],
    *,
    seed: int,
    fixed: Mapping[tuple[str, str], bool],
    draws: Mapping[tuple[str, str], float],
    p: float,
) -> dict[str, str]:
    """``{peer: "alliance" | "conflict"}``: fixed where the scenario fixes it, else alliance
    iff this unit's draw for the peer is at most ``p`` (an explicit draw replaces the random
    one). A draw is made for every peer, so fixing one never shifts the others."""
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
    me: str, units: Sequence[str], influences: Mapping[tuple[str, str], int], universe: Universe
) -> dict[str, str]:
    """``{peer: alternative text}``: the influence this unit sends to each peer."""
    return {r: universe.format(influences[(me, r)]) for r in units if r != me}


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
