"""``[decision]``: every unit's decision policy (max, min, seeded-random or a preferred
alternative), one ``policy`` for all and per-unit ``units`` overrides."""

from __future__ import annotations

from typing import Any

from rgtbus.errors import RgtbusError
from rgtbus.rgt import Universe
from rgtbus.scenario.context import Ctx, check_keys, sub_table
from rgtbus.scenario.values import unit_of

DECISION_KEYS = {"policy", "units"}
DECISION_POLICIES = ("max", "min", "seeded-random")


def decisions_of(
    ctx: Ctx, data: dict[str, Any], units: tuple[str, ...], universe: Universe
) -> dict[str, str]:
    """``[decision]``: each unit's decision policy (``policy`` for every unit, ``units`` by
    unit)."""
    dec = sub_table(ctx, data, "decision")
    check_keys(ctx, dec, DECISION_KEYS, "decision")
    default_policy = dec.get("policy", "max")
    per_unit = dec.get("units", {})
    if not isinstance(per_unit, dict):
        raise ctx.error("decision", "units", "must be a table {unit = policy}")
    default_policy = _policy_of(ctx, universe, default_policy, "decision", "policy")
    decisions = dict.fromkeys(units, default_policy)
    for key, v in per_unit.items():
        policy = _policy_of(ctx, universe, v, "decision.units", key)  # checked before the unit
        decisions[unit_of(ctx, units, key, "decision.units", key)] = policy
    return decisions


def _policy_of(ctx: Ctx, universe: Universe, v: Any, section: str, key: str) -> str:
    if isinstance(v, str):
        if v in DECISION_POLICIES:
            return v
        try:
            universe.parse_alternative(v)
            return v
        except RgtbusError:
            pass
    raise ctx.error(
        section,
        key,
        f"unknown decision policy {v!r} (max, min, seeded-random, or a preferred alternative)",
    )
