"""The log bus: a finished run's medium served back, window by window (the replay twin).

``World`` runs re-built units over it exactly as over a live bus: the members publish (their
samples are dropped: the log already has the medium; their flags are kept, so the run ends at
the same window as it did), and ``gather`` returns the logged window — as per-sender parts when
link gains need them, else the medium as one part. Members of the run that are not re-run count
as finished. When the log has no more windows, ``gather`` raises ``LogEnded``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rgtbus.bus.payload import FINAL
from rgtbus.errors import RgtbusError


class LogEnded(RgtbusError):
    """The log holds no more windows (a truncated log, or the run's last window)."""


class LogBus:
    kind = "log"

    def __init__(
        self,
        run_id: str,
        members: Sequence[str],
        windows: Sequence[np.ndarray],
        *,
        parts: Sequence[dict[str, np.ndarray]] | None = None,
        local: Sequence[str] | None = None,
    ) -> None:
        self.run_id = run_id
        self.members = tuple(members)
        self.local = tuple(self.members if local is None else local)
        self._windows = windows
        self._parts = parts
        self._flags: dict[int, dict[str, int]] = {}
        self.last_flags: dict[str, int] = {}
        self._zeros = np.zeros(len(windows[0]) if len(windows) else 0)

    def publish(self, unit: str, window: int, samples: np.ndarray, flags: int = 0) -> None:
        self._flags.setdefault(window, {})[unit] = flags

    def gather(self, window: int, timeout: float = 0.0) -> dict[str, np.ndarray]:
        if window >= len(self._windows):
            raise LogEnded(f"the log ends after window {len(self._windows) - 1}")
        published = self._flags.pop(window, {})
        self.last_flags = {
            u: published.get(u, 0 if u in self.local else FINAL) for u in self.members
        }
        if self._parts is not None:
            return dict(self._parts[window])
        # The medium as one part: what every unit heard, bit for bit (0 + x_a + x_b ...).
        out = dict.fromkeys(self.members, self._zeros)
        out[self.members[0]] = self._windows[window]
        return out

    def join(self, unit: str, digest: str, timeout: float = 0.0) -> None:
        pass

    def stats(self) -> dict[str, int]:
        return {"windows": len(self._windows)}

    def close(self) -> None:
        pass

    def __enter__(self) -> LogBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
