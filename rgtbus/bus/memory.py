"""The in-process twin of the zenoh bus: a queue instead of a network.

Payloads still go through the codec and the shared receive path (the gate, then the queue), so
the memory bus drops and counts exactly what the zenoh bus would, and stays bounded the same way
whatever ``put_raw`` sends.
"""

from __future__ import annotations

from collections.abc import Sequence

from rgtbus.bus.base import QueueBus
from rgtbus.bus.keys import matches_subscription


class MemoryBus(QueueBus):
    """Every member in this process, the frames through the codec and the gate as over zenoh (see
    the module docstring); ``count_foreign`` False hears only this run's keys."""

    kind = "memory"
    OPTIONS = frozenset({"local", "count_foreign", "key"})

    def __init__(
        self,
        run_id: str,
        members: Sequence[str],
        sample_rate: float,
        *,
        local: Sequence[str] | None = None,
        count_foreign: bool = True,
        key: bytes | None = None,
    ) -> None:
        super().__init__(run_id, members, sample_rate, local=local, key=key)
        # Same filter as the zenoh subscriber's key expression.
        self._sub_run = None if count_foreign else self.run_id

    def _send(self, key: str, data: bytes) -> None:
        if matches_subscription(key, self._sub_run):
            self._deliver(key, data)  # the same gate as the zenoh bus's callback

    def _close_transport(self) -> None:
        pass
