"""The medium's transport: every member's frames (pulses and promises), seen by every member.

``open_bus(kind, run_id, members, sample_rate, **options)``, ``kind`` one of the registry's
(``rgtbus.bus.registry``: zenoh, memory); ``LogBus`` serves a logged run back (the replay twin).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from rgtbus.bus.base import STAT_KEYS, Bus, MemberStatus, QueueBus, drop_summary
from rgtbus.bus.keys import tx_key
from rgtbus.bus.memory import MemoryBus
from rgtbus.bus.payload import FAILED, FINAL, NEVER, Frame, decode, encode
from rgtbus.bus.registry import bus_kind, bus_kinds
from rgtbus.errors import BadInput
from rgtbus.signal.pulses import Pulses

if TYPE_CHECKING:
    from rgtbus.bus.logbus import LogBus
    from rgtbus.bus.zenoh import ZenohBus

    def _every_bus_is_a_bus(memory: MemoryBus, zenoh: ZenohBus, log: LogBus) -> list[Bus]:
        """Never called: mypy holds each bus to the ``Bus`` protocol here."""
        return [memory, zenoh, log]


KINDS = bus_kinds()

__all__ = [
    "FAILED",
    "FINAL",
    "KINDS",
    "NEVER",
    "STAT_KEYS",
    "Bus",
    "Frame",
    "MemberStatus",
    "MemoryBus",
    "Pulses",
    "QueueBus",
    "decode",
    "drop_summary",
    "encode",
    "open_bus",
    "tx_key",
]


def open_bus(
    kind: str,
    run_id: str,
    members: Sequence[str],
    sample_rate: float,
    **options: Any,
) -> QueueBus:
    """Open a bus of ``kind`` (``rgtbus.bus.registry``: its adapter's module is imported now,
    so zenoh loads only when asked for); unknown kinds and options are refused by name."""
    cls = bus_kind(kind).load()
    unknown = sorted(set(options) - cls.OPTIONS)
    if unknown:
        raise BadInput(
            f"unknown option(s) {', '.join(unknown)} for the {kind} bus "
            f"(known: {', '.join(sorted(cls.OPTIONS))})"
        )
    return cls(run_id, members, sample_rate, **options)
