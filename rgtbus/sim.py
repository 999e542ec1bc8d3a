"""The SimPy world: windows of simulated time, the medium, and the run loop.

Time advances in windows of L samples (default 0.1 s = 20 samples). Window w covers samples
[wL, (w+1)L). At t = wL·τ every member renders and publishes its outgoing samples for window w;
the medium process gathers them through the bus; at t = (w+1)L·τ, when window w is over, every
member hears it (each applies its own link gains and noise) and reacts. A reaction is decided on
exact sample indexes at least the reaction delay ahead (the lookahead, ≥ one window), so the
window size never changes a result.

The world knows the members only through this interface (no import of ``units/``):

* ``name``; ``begin(env)``; ``render(window) -> np.ndarray`` (L float64 samples);
* ``hear(window, gathered: {unit: samples})``;
* ``finished`` (bool) and ``failure`` (str | None).

The members given may be a subset of the bus's members (one unit per OS process): the others
are heard through the bus only. Each member's publish carries FINAL once it has finished and
FAILED once it has failed; the run ends after the first window in which every member is FINAL,
or in which any is FAILED, so every process stops at the same window.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import simpy

from rgtbus.bus.base import Bus
from rgtbus.bus.payload import FAILED, FINAL
from rgtbus.errors import RgtbusError
from rgtbus.telemetry import Recorder


class Member(Protocol):
    name: str
    finished: bool
    failure: str | None

    def begin(self, env: simpy.Environment) -> None: ...
    def render(self, window: int) -> np.ndarray: ...
    def hear(self, window: int, gathered: dict[str, np.ndarray]) -> None: ...


def ns(seconds: float) -> int:
    """Simulated seconds -> integer nanoseconds (the MCAP ``log_time``)."""
    return round(seconds * 1e9)


@dataclass
class WorldResult:
    windows: int
    sim_seconds: float
    wall_seconds: float
    failure: str | None
    bus_stats: dict[str, int] = field(default_factory=dict)


class World:
    """Runs members over a bus, window by window, until all have finished or one fails."""

    def __init__(
        self,
        members: Sequence[Member],
        bus: Bus,
        recorder: Recorder,
        *,
        sample_rate: float,
        window_samples: int,
        max_seconds: float,
        gather_timeout: float = 5.0,
        progress: Callable[[float, int], None] | None = None,
        write_medium: bool = True,
    ) -> None:
        if window_samples < 1:
            raise RgtbusError(f"window of {window_samples} samples: need at least one")
        self.members = list(members)
        self.bus = bus
        self.recorder = recorder
        self.sample_rate = sample_rate
        self.window_samples = window_samples
        self.window_seconds = window_samples / sample_rate
        self.max_windows = int(np.ceil(max_seconds / self.window_seconds))
        self.gather_timeout = gather_timeout
        self.progress = progress
        self.write_medium = write_medium  # one process of a cross-process run logs the medium
        self.env = simpy.Environment()
        self.failure: str | None = None
        self.windows = 0
        self._opened: simpy.Event = self.env.event()  # window w is open: render and publish
        self._heard: simpy.Event = self.env.event()  # window w is over: hear it

    # SimPy processes -------------------------------------------------------------------------

    def _medium(self):
        env = self.env
        names = self.bus.members  # every member of the run, local or not, in a fixed order
        local = {m.name: m for m in self.members}
        for w in range(self.max_windows):
            self.windows = w + 1
            opened, self._opened = self._opened, env.event()
            opened.succeed(w)
            yield env.timeout(0)  # the local members publish at the window's start
            gathered = self.bus.gather(w, timeout=self.gather_timeout)
            flags = self.bus.last_flags
            yield env.timeout(self.window_seconds)
            if self.write_medium:
                medium = np.zeros(self.window_samples)
                for name in names:  # fixed order: the same float sum in every process
                    medium += gathered[name]
                self.recorder.write(
                    "/medium",
                    {
                        "window": w,
                        "t": w * self.window_seconds,
                        "sample_rate": self.sample_rate,
                        "samples": medium.tolist(),
                    },
                    ns(w * self.window_seconds),
                )
            # Flags travel with the samples, so every process ends the run at the same window.
            failed = [u for u in names if flags.get(u, 0) & FAILED]
            if failed:
                u = failed[0]
                self.failure = (
                    local[u].failure
                    if u in local and local[u].failure
                    else f"unit {u} failed (window {w}; see its log)"
                )
                return
            if all(flags.get(u, 0) & FINAL for u in names):
                return
            heard, self._heard = self._heard, env.event()
            heard.succeed((w, gathered))
            yield env.timeout(0)  # the local members react before the next window opens
            if self.progress is not None:
                self.progress(env.now, w)
        self.failure = (
            f"not finished after {self.max_windows * self.window_seconds:.1f} s of simulated "
            "time (timing.max_seconds)"
        )

    def _member(self, member: Member):
        member.begin(self.env)
        while True:
            w = yield self._opened
            flags = FAILED if member.failure else FINAL if member.finished else 0
            self.bus.publish(member.name, w, member.render(w), flags)
            w, gathered = yield self._heard
            member.hear(w, gathered)

    def run(self) -> WorldResult:
        t0 = time.perf_counter()
        for m in self.members:
            self.env.process(self._member(m))
        done = self.env.process(self._medium())
        self.env.run(until=done)
        return WorldResult(
            windows=self.windows,
            sim_seconds=self.windows * self.window_seconds,
            wall_seconds=time.perf_counter() - t0,
            failure=self.failure,
            bus_stats=dict(self.bus.stats()),
        )


def as_jsonable(value: Any) -> Any:
    """numpy scalars and tuples -> plain JSON types (for log messages)."""
    if isinstance(value, dict):
        return {str(k): as_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [as_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value
