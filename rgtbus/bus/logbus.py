"""The log bus: a finished run's medium served back (the replay twin of the live buses).

``World`` runs re-built units over it exactly as over a live bus. The medium comes from the log,
all of it known from the start (every member promises silence past the log's end); what the
re-run members publish is not needed (the log already holds the medium) but their FINAL/FAILED
flags are kept, so the run ends as it did. Members of the run that are not re-run count as
finished. Waiting past the end of a log that was cut short raises ``LogEnded``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from rgtbus.bus.base import MemberStatus
from rgtbus.bus.payload import FINAL, NEVER
from rgtbus.errors import RgtbusError
from rgtbus.signal.pulses import Pulses, merge_pulses, split_pulses


class LogEnded(RgtbusError):
    """The log holds no more of the medium (a truncated log)."""


class LogBus:
    kind = "log"

    def __init__(
        self,
        run_id: str,
        members: Sequence[str],
        medium: Mapping[str, Pulses],
        *,
        local: Sequence[str] | None = None,
        end: int = NEVER,
    ) -> None:
        """``medium``: per member, its logged pulses (or the whole medium under one member's
        name: what every unit heard, bit for bit); ``end``: the first sample the log does not
        cover (a truncated log), else the run's medium is complete."""
        self.run_id = run_id
        self.members = tuple(members)
        self.local = tuple(self.members if local is None else local)
        self.end = end
        self._pending = {
            u: merge_pulses([medium[u]]) if u in medium else _none() for u in self.members
        }
        self._status = {
            u: MemberStatus(promise=end, flags=0 if u in self.local else FINAL)
            for u in self.members
        }
        self._published = 0

    def publish(
        self,
        unit: str,
        samples: np.ndarray,
        values: np.ndarray,
        *,
        promise: int,
        flags: int = 0,
        done_at: int = 0,
    ) -> None:
        st = self._status[unit]
        st.flags, st.done_at = flags, done_at
        self._published += 1

    def wait(self, beyond: int, timeout: float = 0.0) -> int:
        if beyond >= self.end and self.end < NEVER:
            raise LogEnded(f"the log ends at sample {self.end}")
        return self.end

    def take(self, until: int) -> dict[str, Pulses]:
        out = {}
        for u in self.members:
            out[u], self._pending[u] = split_pulses(self._pending[u], until)
        return out

    def known(self, until: int) -> dict[str, Pulses]:
        return {u: split_pulses(self._pending[u], until)[0] for u in self.members}

    def status(self) -> dict[str, MemberStatus]:
        return self._status

    def join(self, units: str | Sequence[str], digest: str, timeout: float = 0.0) -> None:
        pass

    def stats(self) -> dict[str, int]:
        return {"published": self._published}

    def drop_notes(self) -> list[str]:
        return []

    def close(self) -> None:
        pass

    def __enter__(self) -> LogBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _none() -> Pulses:
    return np.zeros(0, dtype=np.int64), np.zeros(0)
