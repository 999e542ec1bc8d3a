"""``[goals.UNIT]``: influences chosen by the inverse task.

target = alternative or "[LOW,HIGH]" (or an inline table with ``want`` and ``mode``), ``mode``
for the table's targets (exact, the default; contains; choice), ``outcome`` = the ``then`` of
the scenario's [outcome]: every unit of its ``all_of`` is a target that must choose its
alternative (mode choice unless given)."""

from __future__ import annotations

from typing import Any

from rgtbus.rgt import Universe
from rgtbus.rgt.diagonal import EXACT_VARS
from rgtbus.scenario.context import Ctx
from rgtbus.scenario.model import Goal, Outcome
from rgtbus.scenario.values import alternative_of, interval_of

GOAL_KEYS = {"mode", "outcome"}  # any other key of [goals.UNIT] is a target unit
GOAL_TARGET_KEYS = {"want", "mode"}
GOAL_MODES = ("exact", "contains", "choice")

Wanted = dict[str, tuple[int, int, str]]  # target -> (lo, hi, mode as written)


def goals_of(
    ctx: Ctx,
    goals: dict[str, Any],
    units: tuple[str, ...],
    universe: Universe,
    decisions: dict[str, str],
    outcome: Outcome | None,
) -> tuple[Goal, ...]:
    """``[goals.UNIT]``: what each unit steers its targets to, checked against the units, the
    decisions and the outcome."""
    out: list[Goal] = []
    if goals and len(units) > EXACT_VARS:
        first = next(iter(goals))
        raise ctx.error(
            f"goals.{first}",
            None,
            f"goals need the inverse task, solved on F's truth table: groups of at most "
            f"{EXACT_VARS} units (this one has {len(units)})",
        )
    for name, spec in goals.items():
        section = f"goals.{name}"
        if name not in units:
            raise ctx.error(section, None, f"unknown unit {name!r} (units: {', '.join(units)})")
        if not isinstance(spec, dict):
            raise ctx.error("goals", name, 'must be a table [goals.UNIT] with target = "1", ...')
        mode = spec.get("mode", "exact")
        if mode not in GOAL_MODES:
            raise ctx.error(section, "mode", f"unknown mode {mode!r} ({', '.join(GOAL_MODES)})")
        wanted = _outcome_targets(ctx, name, spec, outcome)
        wanted.update(_targets(ctx, name, spec, mode, units, universe))
        if not wanted:
            raise ctx.error(section, None, "names no target")
        for target, (lo, hi, m) in wanted.items():
            if m == "choice":
                if lo != hi:
                    raise ctx.error(
                        section, target, "mode choice wants one alternative, not an interval"
                    )
                policy = decisions[target]
                m = {"max": "largest", "min": "smallest"}.get(policy, "exact")
            out.append(Goal(name, target, lo, hi, m))
    return tuple(out)


def _outcome_targets(ctx: Ctx, name: str, spec: dict[str, Any], outcome: Outcome | None) -> Wanted:
    """``outcome = "..."``: every other unit of the rule's ``all_of`` chooses its alternative."""
    wanted: Wanted = {}
    if "outcome" not in spec:
        return wanted
    section = f"goals.{name}"
    said = spec["outcome"]
    if outcome is None:
        raise ctx.error(section, "outcome", "the scenario has no [outcome] rule")
    if said not in (outcome.then, f"{outcome.name}: {outcome.then}"):
        raise ctx.error(
            section,
            "outcome",
            f"{said!r}: a goal names the outcome's then ({outcome.then!r}); "
            "its else is not a choice each target can make",
        )
    for target in outcome.all_of:
        if target != name:
            v = outcome.choose
            wanted[target] = (v, v, spec.get("mode", "choice"))
    return wanted


def _targets(
    ctx: Ctx,
    name: str,
    spec: dict[str, Any],
    mode: str,
    units: tuple[str, ...],
    universe: Universe,
) -> Wanted:
    """The target units named as keys (in file order; they override the outcome's)."""
    section = f"goals.{name}"
    wanted: Wanted = {}
    for key, value in spec.items():
        if key in GOAL_KEYS:
            continue
        if key not in units:
            allowed = ", ".join(sorted(GOAL_KEYS))
            raise ctx.error(section, key, f"unknown unit {key!r} (a target unit, or {allowed})")
        if key == name:
            raise ctx.error(section, key, "a unit does not influence itself")
        target_mode = mode
        if isinstance(value, dict):
            for k in value:
                if k not in GOAL_TARGET_KEYS:
                    raise ctx.error(section, key, f"unknown key {k!r} (want, mode)")
            if "want" not in value:
                raise ctx.error(section, key, 'an inline goal needs want = "..."')
            target_mode = value.get("mode", mode)
            if target_mode not in GOAL_MODES:
                raise ctx.error(
                    section, key, f"unknown mode {target_mode!r} ({', '.join(GOAL_MODES)})"
                )
            value = value["want"]
        if isinstance(value, str) and value.strip().startswith("["):
            lo, hi = interval_of(ctx, universe, value, section, key)
        else:
            lo = hi = alternative_of(ctx, universe, value, section, key)
        wanted[key] = (lo, hi, target_mode)
    return wanted
