"""Values several sections share: numbers, unit names, ``"a>b"`` pairs, alternatives and
intervals, each refused with the section and key it was read from."""

from __future__ import annotations

import math
import re
from typing import Any

from rgtbus.errors import RgtbusError
from rgtbus.pairs import Pair, parse_pair_key
from rgtbus.rgt import Universe
from rgtbus.scenario.context import Ctx

IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
# The rule IDENT keeps, in words (every refusal of a name states it): a unit's name is part of
# zenoh key expressions, MCAP topics (/trace/<unit>), file names and certificate names, which
# are held to ASCII here so that every tool on every platform reads them alike.
NAME_RULE = "ASCII letters A-Z a-z, digits 0-9 and _, not starting with a digit"

# Noise, gains and pulse magnitudes above this can overflow the resonators' floats mid-run;
# it is far above any level a run still decodes at (pulses are about 0.4).
MAX_LEVEL = 1000.0


def is_int(v: Any) -> bool:
    """An integer, not a bool (bool is an int in Python)."""
    return isinstance(v, int) and not isinstance(v, bool)


def is_finite(v: Any) -> bool:
    """A real, finite number (TOML allows inf and nan; bool is an int in Python)."""
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def unit_of(ctx: Ctx, units: tuple[str, ...], value: str, section: str, key: str) -> str:
    """``value`` if it names one of ``units``."""
    if value not in units:
        raise ctx.error(section, key, f"unknown unit {value!r} (units: {', '.join(units)})")
    return value


def pair_of(ctx: Ctx, units: tuple[str, ...], key: str, section: str) -> Pair:
    """A ``"SENDER>ADDRESSEE"`` key of two distinct units (``parse_pair_key``; spaces around
    the names allowed): the one reading of a pair key in a scenario file."""
    if key.count(">") != 1:
        raise ctx.error(section, key, 'write the pair as SENDER>ADDRESSEE, e.g. "a>b"')
    s, r = (unit_of(ctx, units, x.strip(), section, key) for x in parse_pair_key(key))
    if s == r:
        raise ctx.error(section, key, "a unit does not address itself")
    return s, r


def interval_of(ctx: Ctx, universe: Universe, text: str, section: str, key: str) -> tuple[int, int]:
    """An interval as a scenario writes it, "[LOW,HIGH]", non-empty (LOW within HIGH)."""
    try:
        lo, hi = universe.parse_interval(text)
    except RgtbusError as exc:
        raise ctx.error(section, key, str(exc)) from None
    if lo & ~hi:
        raise ctx.error(
            section, key, f"empty interval {text!r}: its low end is not within its high end"
        )
    return lo, hi


def alternative_of(ctx: Ctx, universe: Universe, value: Any, section: str, key: str) -> int:
    """An alternative as a scenario writes it: "1", "{alpha}", a list of actions, 0 or 1."""
    if isinstance(value, list) and not all(isinstance(x, str) for x in value):
        raise ctx.error(section, key, f"bad alternative {value!r}: a list of action names")
    try:
        if isinstance(value, list):
            return universe.from_list(value)
        if isinstance(value, int) and not isinstance(value, bool) and value in (0, 1):
            return universe.full if value else 0
        if isinstance(value, str):
            return universe.parse_alternative(value)
    except RgtbusError as exc:
        raise ctx.error(section, key, str(exc)) from None
    raise ctx.error(section, key, f"bad alternative {value!r}")
