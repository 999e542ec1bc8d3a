"""Every kind of bus a run can go over, named once (``BUS_KINDS``): ``open_bus``, ``rgtbus.run``,
the CLI's ``--bus``, the launcher and the shared bus suite (``tests/conftest.py``) all read it.

A new transport is its adapter (a ``QueueBus``: ``rgtbus.bus.base``; the join barrier it may
use is ``rgtbus.bus.join``) and one line here; the shared suite runs it at once. An adapter's
module is imported only when a bus of its kind is opened, so zenoh loads only when asked for.
The log bus (``rgtbus.bus.logbus``) is no kind: it serves a logged run back to its re-run.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING

from rgtbus.errors import BadInput

if TYPE_CHECKING:
    from rgtbus.bus.base import QueueBus


@dataclass(frozen=True)
class BusKind:
    """A kind of bus: its ``name`` (``--bus NAME``), where its adapter is (``module``,
    ``adapter``: the class), whether units in other processes can be its members
    (``cross_process``: ``rgtbus launch`` runs over it) and one line on what it is."""

    name: str
    module: str
    adapter: str
    cross_process: bool
    about: str

    def load(self) -> type[QueueBus]:
        """The adapter class (its module imported now)."""
        cls: type[QueueBus] = getattr(importlib.import_module(self.module), self.adapter)
        return cls


BUS_KINDS: dict[str, BusKind] = {
    kind.name: kind
    for kind in (
        BusKind(
            "zenoh", "rgtbus.bus.zenoh", "ZenohBus", True,
            "Eclipse Zenoh pub/sub: in one process, or across processes and hosts",
        ),
        BusKind("memory", "rgtbus.bus.memory", "MemoryBus", False, "every member in this process"),
    )
}  # fmt: skip


def bus_kinds() -> tuple[str, ...]:
    """Every kind's name, the default first (``rgtbus run --bus``)."""
    return tuple(BUS_KINDS)


def cross_process_kind() -> str:
    """The kind ``rgtbus launch`` and its unit processes go over: the first that can."""
    return next(k.name for k in BUS_KINDS.values() if k.cross_process)


def bus_kind(name: str) -> BusKind:
    """The kind named ``name``; a one-line error naming the kinds there are."""
    kind = BUS_KINDS.get(name) if isinstance(name, str) else None
    if kind is None:
        raise BadInput(f"unknown bus kind {name!r} (use {', '.join(BUS_KINDS)})")
    return kind
