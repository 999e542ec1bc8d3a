"""``[relations]``: the relationship policy (fixed, random or cograph), the alliance
probability ``p``, ``fixed`` relations and given ``draws`` per ordered pair."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from rgtbus.errors import RgtbusError
from rgtbus.pairs import ordered_pairs, pair_key
from rgtbus.rgt import graph_to_polynomial, install_relations
from rgtbus.scenario.context import Ctx, check_keys, sub_table
from rgtbus.scenario.values import is_finite, pair_of

RELATION_KEYS = {"policy", "p", "fixed", "draws"}
RELATION_POLICIES = ("fixed", "random", "cograph")


@dataclass(frozen=True)
class Relations:
    """``[relations]`` as read (``Scenario.relations``): the policy, the alliance probability,
    and the fixed relations and draw probabilities by pair."""

    policy: str = "random"
    p: float = 0.61  # the alliance probability
    fixed: dict[tuple[str, str], bool] = field(default_factory=dict)  # True: alliance
    draws: dict[tuple[str, str], float] = field(default_factory=dict)


def relations_of(ctx: Ctx, data: dict[str, Any], units: tuple[str, ...]) -> Relations:
    """``[relations]``: the policy, the alliance probability, and the fixed relations and draws by
    pair."""
    rel = sub_table(ctx, data, "relations")
    check_keys(ctx, rel, RELATION_KEYS, "relations")
    policy = _policy_of(ctx, rel)
    p = rel.get("p", 0.61)
    if isinstance(p, bool) or not isinstance(p, int | float) or not 0 <= p <= 1:
        raise ctx.error("relations", "p", f"alliance probability must be within [0, 1], got {p!r}")
    fixed = _fixed_of(ctx, rel, units)
    draws = _draws_of(ctx, rel, units)
    if policy == "fixed":
        missing = [pair_key(s, r) for s, r in ordered_pairs(units) if (s, r) not in fixed]
        if missing:
            raise ctx.error("relations.fixed", None, f"policy fixed: no relation for {missing[0]}")
        # Fixed relations decide the group before any run: a P4 would only fail at phase 2.
        try:
            graph_to_polynomial(install_relations(units, fixed))
        except RgtbusError as exc:
            raise ctx.error("relations.fixed", None, f"policy fixed: {exc}") from None
    return Relations(policy, float(p), fixed, draws)


def _policy_of(ctx: Ctx, rel: dict[str, Any]) -> str:
    policy = rel.get("policy", "random")
    if not isinstance(policy, str) or policy not in RELATION_POLICIES:
        raise ctx.error(
            "relations", "policy", f"unknown policy {policy!r} (fixed, random or cograph)"
        )
    if policy == "cograph":
        for key in ("fixed", "draws", "p"):
            if key in rel:
                raise ctx.error(
                    "relations",
                    key,
                    "not with policy cograph (the seed draws the whole decomposable group)",
                )
    return policy


def _fixed_of(ctx: Ctx, rel: dict[str, Any], units: tuple[str, ...]) -> dict[tuple[str, str], bool]:
    fixed: dict[tuple[str, str], bool] = {}
    fixed_table = rel.get("fixed", {})
    if not isinstance(fixed_table, dict):
        raise ctx.error("relations", "fixed", 'must be a table {"a>b" = "alliance", ...}')
    for key, v in fixed_table.items():
        if v not in ("alliance", "conflict"):
            raise ctx.error("relations.fixed", key, f'must be "alliance" or "conflict", got {v!r}')
        fixed[pair_of(ctx, units, key, "relations.fixed")] = v == "alliance"
    return fixed


def _draws_of(
    ctx: Ctx, rel: dict[str, Any], units: tuple[str, ...]
) -> dict[tuple[str, str], float]:
    draws: dict[tuple[str, str], float] = {}
    draw_table = rel.get("draws", {})
    if not isinstance(draw_table, dict):
        raise ctx.error("relations", "draws", 'must be a table {"a>b" = 0.42, ...}')
    for key, v in draw_table.items():
        if not is_finite(v) or not 0 <= v <= 1:
            raise ctx.error("relations.draws", key, f"a draw must be within [0, 1], got {v!r}")
        draws[pair_of(ctx, units, key, "relations.draws")] = float(v)
    return draws
