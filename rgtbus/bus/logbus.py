"""The log bus: a finished run's medium served back (the replay twin of the live buses).

``World`` runs re-built units over it exactly as over a live bus: it keeps the same ``Bus``
contract (members, local members, the horizon, flags, closing; the same errors for the same
misuse). The medium comes from the log, all of it known from the start (every member promises
silence past the log's end); what the re-run members publish is not needed (the log already
holds the medium) but their FINAL/FAILED flags are kept, so the run ends as it did. Members of
the run that are not re-run count as finished. Waiting past the end of a log that was cut
short raises ``LogEnded``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from rgtbus.bus.base import BusBase, MemberStatus
from rgtbus.bus.payload import FINAL, NEVER
from rgtbus.errors import BadLog
from rgtbus.signal.pulses import Pulses, merge_pulses, split_pulses


class LogEnded(BadLog):
    """The log holds no more of the medium (a truncated log)."""


class LogBus(BusBase):
    """A logged medium served as a bus (see the module docstring). Nothing goes anywhere:
    closing it releases nothing."""

    kind = "log"
    close_problem: str | None = None  # nothing to close that could be slow

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
        self._take_run(run_id, members)
        self.local = self._local_members(local)
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
        """Keep a local member's flags and done_at (its pulses and promise are the log's)."""
        self._check_open("publish")
        self._check_local(unit)
        st = self._status[unit]
        st.flags, st.done_at = flags, done_at
        self._published += 1

    def wait(
        self, beyond: int, timeout: float = 0.0, stop: Callable[[], bool] | None = None
    ) -> int:
        """The horizon, the log's end, at once; ``LogEnded`` past the end of a log cut short."""
        self._check_open("wait")
        if beyond >= self.end and self.end < NEVER:
            raise LogEnded(f"the log ends at sample {self.end}")
        return self.end

    def take(self, until: int) -> dict[str, Pulses]:
        """Every member's logged pulses before ``until`` (at most the log's end), once."""
        self._check_open("take")
        self._check_take(until, self.end)
        out = {}
        for u in self.members:
            out[u], self._pending[u] = split_pulses(self._pending[u], until)
        return out

    def known(self, until: int) -> dict[str, Pulses]:
        """Every member's logged pulses before ``until`` not yet taken."""
        return {u: split_pulses(self._pending[u], until)[0] for u in self.members}

    def status(self) -> dict[str, MemberStatus]:
        """Every member's promise (the log's end), flags and done_at."""
        return self._status

    def join(self, units: str | Sequence[str], digest: str, timeout: float = 0.0) -> None:
        """Every member is at hand: only checks that ``units`` are members."""
        for unit in [units] if isinstance(units, str) else units:
            self._check_member(unit)

    def stats(self) -> dict[str, int]:
        """How many frames were published."""
        return {"published": self._published}

    def drop_notes(self) -> list[str]:
        """Nothing is ever dropped: no notes."""
        return []

    def _close_transport(self) -> None:
        pass  # nothing to release


def _none() -> Pulses:
    return np.zeros(0, dtype=np.int64), np.zeros(0)
