"""``[influences]``: per ordered pair (``"a>b"`` keys), and by policy for the pairs not listed:
fixed (every pair listed), uniform (one value), random (seeded, over weights)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from rgtbus.pairs import ordered_pairs, pair_key
from rgtbus.rgt import Universe
from rgtbus.scenario.context import Ctx, sub_table
from rgtbus.scenario.values import alternative_of, is_finite, pair_of

INFLUENCE_POLICIES = ("fixed", "uniform", "random")
INFLUENCE_KEYS = {"policy", "value", "weights"}  # any other key of [influences] is a pair


@dataclass(frozen=True)
class Influences:
    """``[influences]`` as read (``Scenario.influences``): the policy, its value or weights,
    and the pairs listed (how the others are chosen: ``rgtbus.mind.choose_influences``)."""

    policy: str = "fixed"
    value: int | None = None  # policy uniform
    weights: dict[int, float] = field(default_factory=dict)  # policy random
    pairs: dict[tuple[str, str], int] = field(default_factory=dict)  # listed per pair


def influences_of(
    ctx: Ctx, data: dict[str, Any], units: tuple[str, ...], universe: Universe
) -> Influences:
    """``[influences]``: the policy and its value or weights, and the pairs listed (every pair under
    policy fixed)."""
    inf = sub_table(ctx, data, "influences")
    for key in inf:  # a typo of a policy key would otherwise be blamed on another key
        if key not in INFLUENCE_KEYS and ">" not in key:
            raise ctx.error(
                "influences",
                key,
                f'unknown key (allowed: {", ".join(sorted(INFLUENCE_KEYS))}, or a pair "a>b")',
            )
    policy = inf.get("policy", "fixed")
    if not isinstance(policy, str) or policy not in INFLUENCE_POLICIES:
        raise ctx.error(
            "influences",
            "policy",
            f"unknown policy {policy!r} ({', '.join(INFLUENCE_POLICIES)})",
        )
    value = None
    if "value" in inf:
        if policy != "uniform":
            raise ctx.error("influences", "value", "only with policy uniform")
        value = alternative_of(ctx, universe, inf["value"], "influences", "value")
    elif policy == "uniform":
        raise ctx.error("influences", "policy", 'uniform needs a value, e.g. value = "1"')
    weights = _weights_of(ctx, inf, policy, universe)
    pairs: dict[tuple[str, str], int] = {}
    for key, v in inf.items():
        if key in INFLUENCE_KEYS:
            continue
        value_of_pair = alternative_of(ctx, universe, v, "influences", key)  # checked first
        pairs[pair_of(ctx, units, key, "influences")] = value_of_pair
    missing = [pair_key(s, r) for s, r in ordered_pairs(units) if (s, r) not in pairs]
    if missing and policy == "fixed":
        raise ctx.error(
            "influences",
            None,
            f"no influence for {missing[0]} (list every pair, or use policy uniform or random)",
        )
    return Influences(policy, value, weights, pairs)


def _weights_of(ctx: Ctx, inf: dict[str, Any], policy: str, universe: Universe) -> dict[int, float]:
    """Policy random's weights by alternative: each named once, at least one above 0."""
    weights: dict[int, float] = {}
    if "weights" not in inf:
        return weights
    if policy != "random":
        raise ctx.error("influences", "weights", "only with policy random")
    w_table = inf["weights"]
    if not isinstance(w_table, dict) or not w_table:
        raise ctx.error("influences", "weights", 'must be a table {"1" = 2, "0" = 1, ...}')
    named: dict[int, str] = {}
    for key, w in w_table.items():
        if not is_finite(w) or not 0 <= w <= 1e9:
            raise ctx.error("influences.weights", key, f"weight must be within [0, 1e9], got {w!r}")
        alt = alternative_of(ctx, universe, key, "influences.weights", key)
        if alt in named:
            raise ctx.error(
                "influences.weights", key, f"names the same alternative as {named[alt]!r}"
            )
        named[alt] = key
        weights[alt] = float(w)
    if not any(weights.values()):
        raise ctx.error("influences", "weights", "at least one weight must be > 0")
    return weights
