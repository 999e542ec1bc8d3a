"""``[expect]``: what ``rgtbus run --check`` verifies, checked at load so the check never meets
a value it cannot compare.

The polynomial and the relation pairs are stored as a run prints them (``b-a`` -> ``a-b``,
``cb+a`` -> ``a+bc``): the same group written another way must not fail the check."""

from __future__ import annotations

from typing import Any

from rgtbus.errors import RgtbusError
from rgtbus.pairs import pair_key, relation_key
from rgtbus.rgt import Universe, graph_to_polynomial, parse_polynomial, polynomial_to_graph
from rgtbus.rgt.expr import format_expr, needs_star
from rgtbus.scenario.context import Ctx
from rgtbus.scenario.model import Goal, Outcome
from rgtbus.scenario.values import alternative_of, interval_of, pair_of

EXPECT_KEYS = {
    "polynomial",
    "agree",
    "outcome",
    "choices",
    "intervals",
    "frustrated",
    "relations",
    "influences",
    "goals",
    "dynamics",
    "own_seed_only",
}
# [expect] own_seed_only = ["polynomial", ...]: expectations that hold for the scenario's own
# seed only (its random relations or influences drawn otherwise at another): --check --seed N
# leaves them out at another seed, saying so (``summary.check_expectations``)
OWN_SEED = "own_seed"  # the seed they hold for, kept with them (the file's seed)
DYNAMICS = ("fixed point", "cycle", "neither")


def expect_of(
    ctx: Ctx,
    expect: dict[str, Any],
    units: tuple[str, ...],
    universe: Universe,
    outcome: Outcome | None,
    seed: int = 0,
) -> dict[str, Any]:
    """``[expect]``: what a run is checked against, each key checked against the units, the universe
    and the outcome."""
    for key in expect:
        if key not in EXPECT_KEYS:
            allowed = ", ".join(sorted(EXPECT_KEYS))
            raise ctx.error("expect", key, f"unknown key (allowed: {allowed})")
    out = dict(expect)
    if "agree" in expect and not isinstance(expect["agree"], bool):
        raise ctx.error("expect", "agree", f"must be true or false, got {expect['agree']!r}")
    if "polynomial" in expect:
        out["polynomial"] = _polynomial(ctx, expect["polynomial"], units)
    if "outcome" in expect:
        _check_outcome(ctx, expect["outcome"], outcome)
    pairs = _relations(ctx, _sub_table(ctx, expect, "relations", '"a-b" = "alliance"'), units)
    if "relations" in expect:
        out["relations"] = pairs
    _check_per_unit(ctx, expect, units, universe)
    sent = _influences(ctx, _sub_table(ctx, expect, "influences", '"a>b" = "1"'), units, universe)
    if "influences" in expect:
        out["influences"] = sent
    if "own_seed_only" in expect:
        only = expect["own_seed_only"]
        keys = EXPECT_KEYS - {"own_seed_only"}
        if not isinstance(only, list) or not all(isinstance(k, str) and k in keys for k in only):
            raise ctx.error(
                "expect",
                "own_seed_only",
                f"must list keys of [expect] ({', '.join(sorted(keys))}), got {only!r}",
            )
        out[OWN_SEED] = seed
    if "dynamics" in expect and expect["dynamics"] not in DYNAMICS:
        raise ctx.error(
            "expect",
            "dynamics",
            f"{expect['dynamics']!r} is not one of {', '.join(repr(d) for d in DYNAMICS)}",
        )
    return out


# Influence rounds a dynamics needs before it can be seen (rgtbus.summary.round_dynamics): one
# round tells nothing; a fixed point, or neither, shows from the second; a cycle (a round equal
# to one at least two before) from the third.
DYNAMICS_ROUNDS = {"fixed point": 2, "neither": 2, "cycle": 3}


def check_expected_dynamics(ctx: Ctx, expect: dict[str, Any], influence_rounds: int) -> None:
    """``[expect] dynamics`` the run's influence rounds could show (a check that can never
    hold is refused at load, not failed after the run)."""
    want = expect.get("dynamics")
    need = DYNAMICS_ROUNDS.get(want) if isinstance(want, str) else None
    if need is not None and influence_rounds < need:
        raise ctx.error(
            "expect",
            "dynamics",
            f"{want!r} shows only from {need} influence rounds, and the run has "
            f"{influence_rounds} (protocol.influence_rounds)",
        )


def check_expected_goals(ctx: Ctx, expect: dict[str, Any], goals: tuple[Goal, ...]) -> None:
    """``[expect.goals]`` names only units that have goals."""
    for who in expect.get("goals", {}):
        if not any(g.unit == who for g in goals):
            raise ctx.error("expect.goals", who, f"unit {who!r} has no [goals.{who}] table")


def _sub_table(ctx: Ctx, expect: dict[str, Any], key: str, what: str) -> dict[str, Any]:
    sub = expect.get(key, {})
    if not isinstance(sub, dict):
        raise ctx.error("expect", key, f"must be a table {{{what}}}")
    return sub


def _known_unit(
    ctx: Ctx, units: tuple[str, ...], name: str, section: str, key: str | None = None
) -> None:
    if name not in units:
        key = name if key is None else key
        raise ctx.error(section, key, f"unknown unit {name!r} (units: {', '.join(units)})")


def _polynomial(ctx: Ctx, text: Any, units: tuple[str, ...]) -> str:
    if not isinstance(text, str):
        raise ctx.error("expect", "polynomial", f'must be a string like "ab+c", got {text!r}')
    try:
        poly = parse_polynomial(text)
        graph = polynomial_to_graph(poly, units)
    except RgtbusError as exc:
        raise ctx.error("expect", "polynomial", f"{exc} (units: {', '.join(units)})") from None
    return format_expr(graph_to_polynomial(graph), needs_star(units))


def _check_outcome(ctx: Ctx, text: Any, outcome: Outcome | None) -> None:
    if not isinstance(text, str):
        raise ctx.error("expect", "outcome", f"must be a string, got {text!r}")
    if outcome is None:
        raise ctx.error("expect", "outcome", "the scenario has no [outcome] rule to expect")
    possible = [f"{outcome.name}: {v}" for v in (outcome.then, outcome.otherwise)]
    if text not in possible:
        raise ctx.error(
            "expect",
            "outcome",
            f"{text!r} is not an outcome of the [outcome] rule "
            f"({' or '.join(repr(p) for p in possible)})",
        )


def _relations(ctx: Ctx, relations: dict[str, Any], units: tuple[str, ...]) -> dict[str, str]:
    """``"a-b" = "alliance"``, stored by the pair in unit order (``b-a`` -> ``a-b``)."""
    section = "expect.relations"
    pairs: dict[str, str] = {}
    for key, v in relations.items():
        parts = key.split("-")
        if len(parts) != 2:
            raise ctx.error(section, key, 'write the pair as UNIT-UNIT, e.g. "a-b"')
        a, b = (x.strip() for x in parts)
        _known_unit(ctx, units, a, section, key)
        _known_unit(ctx, units, b, section, key)
        if a == b:
            raise ctx.error(section, key, "a unit has no relation with itself")
        if v not in ("alliance", "conflict"):
            raise ctx.error(section, key, f'must be "alliance" or "conflict", got {v!r}')
        if units.index(a) > units.index(b):
            a, b = b, a
        name = relation_key(a, b)
        if name in pairs:
            raise ctx.error(section, key, f"the pair {name} is given twice")
        pairs[name] = v
    return pairs


def _check_per_unit(
    ctx: Ctx, expect: dict[str, Any], units: tuple[str, ...], universe: Universe
) -> None:
    """``intervals`` and ``choices`` (strings the run compares), ``frustrated`` and ``goals``
    (true or false), each by unit."""
    for key, what in (("intervals", '"[LOW,HIGH]"'), ("choices", "an alternative")):
        for name, v in _sub_table(ctx, expect, key, "unit = value").items():
            _known_unit(ctx, units, name, f"expect.{key}")
            if not isinstance(v, str):
                raise ctx.error(f"expect.{key}", name, f"must be a string ({what}), got {v!r}")
            if key == "intervals":
                interval_of(ctx, universe, v, "expect.intervals", name)
            else:
                alternative_of(ctx, universe, v, "expect.choices", name)
    for key in ("frustrated", "goals"):
        for name, v in _sub_table(ctx, expect, key, "unit = true").items():
            _known_unit(ctx, units, name, f"expect.{key}")
            if not isinstance(v, bool):
                raise ctx.error(f"expect.{key}", name, f"must be true or false, got {v!r}")


def _influences(
    ctx: Ctx, table: dict[str, Any], units: tuple[str, ...], universe: Universe
) -> dict[str, list[str]]:
    """``"a>b" = "1"``, stored as the list of actions a run logs."""
    sent: dict[str, list[str]] = {}
    for key, v in table.items():
        sender, addressee = pair_of(ctx, units, key, "expect.influences")
        value = alternative_of(ctx, universe, v, "expect.influences", key)
        sent[pair_key(sender, addressee)] = universe.to_list(value)
    return sent
