"""``frequencies``: a table per unit, or ``"auto"`` (a plan by the rules of docs/model.md).

With ``"auto"`` and neither mode nor codebook given, the plan chooses them too: the pulses a code
and the mode that n units on this schedule need (``rgtbus plan N`` prints the same)."""

from __future__ import annotations

from typing import Any, NamedTuple

from rgtbus.errors import RgtbusError
from rgtbus.rgt import Universe
from rgtbus.scenario.codebook_section import codebook_of
from rgtbus.scenario.context import Ctx
from rgtbus.scenario.values import unit_of
from rgtbus.signal.codebook import Codebook
from rgtbus.signal.plan import (
    auto_plan,
    check_plan,
    make_plan,
    max_units,
    parse_omega,
    pulses_for,
)


class Frequencies(NamedTuple):
    """``[frequencies]`` as read: ω by unit, as written, and the mode and codebook they go with."""

    frequencies: dict[str, float]  # rad/s by unit
    text: dict[str, str]  # as written (or as planned, 6 digits)
    mode: str  # as given, or chosen by the plan
    codebook: Codebook  # as given, or lengthened to the plan's pulses


def frequencies_of(
    ctx: Ctx,
    data: dict[str, Any],
    units: tuple[str, ...],
    universe: Universe,
    mode: str,
    codebook: Codebook,
    tau: float,
    schedule: str,
) -> Frequencies:
    """``[frequencies]``: given by unit, or ``auto`` (planned, with the mode and codebook the plan
    needs where the scenario names neither)."""
    freq = data.get("frequencies", "auto")
    if freq == "auto" and "mode" not in data and "codebook" not in data:
        mode, codebook = _planned(ctx, len(units), universe, codebook, tau, schedule)
    if freq == "auto" and "codebook" in data:
        _fits(ctx, len(units), codebook, schedule)
    if freq == "auto":
        frequencies, text = _auto(ctx, units, codebook.pulses, mode, tau, schedule)
    elif isinstance(freq, dict):
        frequencies, text = _given(ctx, freq, units, codebook.pulses, mode, tau, schedule)
    else:
        raise ctx.error("", "frequencies", 'must be a table {unit = "3pi/2", ...} or "auto"')
    return Frequencies(frequencies, text, mode, codebook)


def _fits(ctx: Ctx, n: int, codebook: Codebook, schedule: str) -> None:
    """A codebook the scenario names must fit its units: the serial schedule's plan spaces n
    channels 0.3/N apart in one octave, so N pulses a code hold at most ``max_units(N)`` units;
    refused naming the codebook and what fits (the default picks it: docs/scenarios.md)."""
    if schedule == "concurrent" or n <= max_units(codebook.pulses):
        return
    more = pulses_for(n)
    fits = (
        f'codebook = {{kind = "generated", pulses = {more}}}, or no codebook (the plan then '
        f"picks the fewest pulses that fit)"
        if more
        else "the concurrent schedule"
    )
    raise ctx.error(
        "",
        "codebook",
        f"{codebook.name!r} has {codebook.pulses} pulses a code: one octave at 0.3/N spacing "
        f"holds at most {max_units(codebook.pulses)} units on the serial schedule, not {n}; "
        f"use {fits}",
    )


def _planned(
    ctx: Ctx, n: int, universe: Universe, codebook: Codebook, tau: float, schedule: str
) -> tuple[str, Codebook]:
    """The mode and the codebook the plan for n units chooses."""
    try:
        chosen = make_plan(n, schedule=schedule, tau=tau, crosstalk=False)
        if chosen.pulses < codebook.pulses:  # the actions need longer words than the plan
            chosen = make_plan(
                n, schedule=schedule, tau=tau, crosstalk=False, pulses=codebook.pulses
            )
    except RgtbusError as exc:
        raise ctx.error("", "frequencies", str(exc)) from None
    if chosen.pulses != codebook.pulses:
        codebook = codebook_of(ctx, {"kind": "generated", "pulses": chosen.pulses}, universe)
    return chosen.mode, codebook


def _auto(
    ctx: Ctx, units: tuple[str, ...], pulses: int, mode: str, tau: float, schedule: str
) -> tuple[dict[str, float], dict[str, str]]:
    try:
        plan = auto_plan(len(units), pulses=pulses, mode=mode, tau=tau, schedule=schedule)
    except RgtbusError as exc:
        raise ctx.error("", "frequencies", str(exc)) from None
    frequencies: dict[str, float] = {}
    text: dict[str, str] = {}
    for u, w in zip(units, plan, strict=True):
        frequencies[u] = float(w)
        text[u] = f"{float(w):.6g}"
    return frequencies, text


def _given(
    ctx: Ctx,
    freq: dict[str, Any],
    units: tuple[str, ...],
    pulses: int,
    mode: str,
    tau: float,
    schedule: str,
) -> tuple[dict[str, float], dict[str, str]]:
    """A frequency for every unit, no two alike, and a plan the schedule can run."""
    frequencies: dict[str, float] = {}
    text: dict[str, str] = {}
    for key, value in freq.items():
        unit_of(ctx, units, key, "frequencies", key)
        try:
            frequencies[key] = parse_omega(value, "frequency")
        except RgtbusError as exc:
            raise ctx.error("frequencies", key, str(exc)) from None
        text[key] = str(value)
    missing = [u for u in units if u not in frequencies]
    if missing:
        raise ctx.error("frequencies", None, f"no frequency for unit {missing[0]!r}")
    seen: dict[float, str] = {}
    for u in units:
        w = frequencies[u]
        if w in seen:
            raise ctx.error(
                "frequencies", u, f"frequency clash: {u} and {seen[w]} share {w:.6g} rad/s"
            )
        seen[w] = u
    try:
        check_plan(
            [frequencies[u] for u in units], pulses=pulses, mode=mode, tau=tau, schedule=schedule
        )
    except RgtbusError as exc:
        raise ctx.error("frequencies", None, str(exc)) from None
    return frequencies, text
