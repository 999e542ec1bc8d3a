"""The checks of a run's options, one rule each, for the library and the command line alike.

Each returns the value, or raises ``RgtbusError`` naming the bad value and where it came from
(``name``: ``seed`` for a keyword argument, ``--seed`` for a flag)."""

from __future__ import annotations

import math
from typing import Any

from rgtbus.errors import BadInput

ENGINES = ("event", "dense")  # how a world moves: event to event, or window by window


def is_seed(value: Any) -> bool:
    """Whether ``value`` is a seed: a non-negative integer (not a bool)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def seed(value: Any, name: str = "seed") -> int:
    """A run's seed: a non-negative integer."""
    if not is_seed(value):
        raise BadInput(f"{name} {value!r}: must be a non-negative integer")
    return int(value)


def _positive(value: Any) -> bool:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    return math.isfinite(value) and value > 0


def realtime(value: Any, name: str = "realtime") -> float:
    """A pace: simulated seconds per wall second, a positive finite factor."""
    if not _positive(value):
        raise BadInput(f"{name} {value!r}: must be a positive factor")
    return float(value)


def seconds(value: Any, name: str) -> float:
    """A wall-clock limit (a timeout): positive finite seconds."""
    if not _positive(value):
        raise BadInput(f"{name} {value!r}: must be positive seconds")
    return float(value)


def choice(value: Any, choices: tuple[str, ...], name: str) -> str:
    """One of ``choices`` (an engine, a bus kind)."""
    if value not in choices:
        raise BadInput(f"{name} {value!r}: must be one of {', '.join(choices)}")
    return str(value)
