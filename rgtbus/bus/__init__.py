"""The medium's transport: every member's samples for a window, gathered by every member.

``open_bus("zenoh" | "memory", run_id, members, sample_rate, window_len, **options)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rgtbus.bus.base import STAT_KEYS, Bus, QueueBus, tx_key
from rgtbus.bus.memory import MemoryBus
from rgtbus.bus.payload import decode, encode
from rgtbus.errors import RgtbusError

KINDS = ("zenoh", "memory")

__all__ = [
    "KINDS",
    "STAT_KEYS",
    "Bus",
    "MemoryBus",
    "QueueBus",
    "decode",
    "encode",
    "open_bus",
    "tx_key",
]


def open_bus(
    kind: str,
    run_id: str,
    members: Sequence[str],
    sample_rate: float,
    window_len: int,
    **options: Any,
) -> QueueBus:
    """Open a bus of ``kind``; unknown kinds and options are refused by name."""
    if kind == "memory":
        cls: type[QueueBus] = MemoryBus
    elif kind == "zenoh":
        from rgtbus.bus.zenoh import ZenohBus  # zenoh loads only when asked for

        cls = ZenohBus
    else:
        raise RgtbusError(f"unknown bus kind {kind!r} (use {', '.join(KINDS)})")
    unknown = sorted(set(options) - cls.OPTIONS)
    if unknown:
        raise RgtbusError(
            f"unknown option(s) {', '.join(unknown)} for the {kind} bus "
            f"(known: {', '.join(sorted(cls.OPTIONS))})"
        )
    return cls(run_id, members, sample_rate, window_len, **options)
