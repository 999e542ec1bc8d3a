"""``[outcome]``: ``name: then`` when every unit of ``all_of`` chooses ``choose``, else
``name: else``."""

from __future__ import annotations

from typing import Any

from rgtbus.rgt import Universe
from rgtbus.scenario.context import Ctx, check_keys, sub_table
from rgtbus.scenario.model import Outcome
from rgtbus.scenario.values import alternative_of, unit_of

OUTCOME_KEYS = {"name", "all_of", "choose", "then", "else"}


def outcome_of(
    ctx: Ctx, data: dict[str, Any], units: tuple[str, ...], universe: Universe
) -> Outcome | None:
    """``[outcome]``: the joint outcome the units decide (None when absent)."""
    if "outcome" not in data:
        return None
    o = sub_table(ctx, data, "outcome")
    check_keys(ctx, o, OUTCOME_KEYS, "outcome")
    for key in ("name", "all_of", "choose", "then", "else"):
        if key not in o:
            raise ctx.error("outcome", key, "missing")
    all_of = o["all_of"]
    if not isinstance(all_of, list) or not all_of:
        raise ctx.error("outcome", "all_of", "need a list of units")
    for key in ("name", "then", "else"):
        if not isinstance(o[key], str):
            raise ctx.error("outcome", key, f"must be a string, got {o[key]!r}")
    return Outcome(
        name=o["name"],
        all_of=tuple(unit_of(ctx, units, u, "outcome", "all_of") for u in all_of),
        choose=alternative_of(ctx, universe, o["choose"], "outcome", "choose"),
        then=o["then"],
        otherwise=o["else"],
    )
