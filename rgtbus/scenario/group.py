"""The top-level keys that make the group: ``name``, ``seed``, ``units``, ``actions`` and the
``description``."""

from __future__ import annotations

from typing import Any, NamedTuple

from rgtbus.errors import RgtbusError
from rgtbus.rgt import Universe
from rgtbus.scenario.context import Ctx
from rgtbus.scenario.values import IDENT, NAME_RULE


class Group(NamedTuple):
    """The scenario's name, seed, units and universe of actions."""

    name: str
    seed: int
    units: tuple[str, ...]
    universe: Universe


def group_of(ctx: Ctx, data: dict[str, Any]) -> Group:
    """The scenario's name and seed, its units and the universe of its actions."""
    name = data.get("name")
    if not isinstance(name, str) or not IDENT.match(name):
        raise ctx.error("", "name", f"need a scenario name ({NAME_RULE}), got {name!r}")
    seed = data.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise ctx.error("", "seed", f"must be a non-negative integer, got {seed!r}")
    return Group(name, seed, _units_of(ctx, data), _universe_of(ctx, data))


def _units_of(ctx: Ctx, data: dict[str, Any]) -> tuple[str, ...]:
    units = data.get("units")
    if not isinstance(units, list) or len(units) < 2:
        raise ctx.error("", "units", "need a list of at least two unit names")
    for u in units:
        if not isinstance(u, str) or not IDENT.match(u):
            raise ctx.error("", "units", f"bad unit name {u!r}: a name is {NAME_RULE}")
    if len(set(units)) != len(units):
        dup = next(u for u in units if units.count(u) > 1)
        raise ctx.error("", "units", f"unit {dup!r} is listed twice")
    return tuple(units)


def _universe_of(ctx: Ctx, data: dict[str, Any]) -> Universe:
    actions = data.get("actions")
    if not isinstance(actions, list) or not actions or not all(isinstance(a, str) for a in actions):
        raise ctx.error("", "actions", 'need a list of action names, e.g. ["alpha", "beta"]')
    try:
        return Universe(tuple(actions))
    except RgtbusError as exc:
        raise ctx.error("", "actions", str(exc)) from None


def description_of(ctx: Ctx, data: dict[str, Any]) -> str:
    """``description``: a string (empty when absent)."""
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ctx.error("", "description", "must be a string")
    return description
