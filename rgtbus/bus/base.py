"""The Bus protocol and the receive logic both buses share.

A bus carries each member's outgoing samples for a window to every member. Received payloads go
through one path (``QueueBus._accept``): key check, payload decode, header check against the run,
then into a per-window buffer. Everything else is dropped and counted, never returned.
"""

from __future__ import annotations

import math
import queue
import re
import time
from collections import deque
from collections.abc import Sequence
from types import TracebackType
from typing import Protocol, Self, runtime_checkable

import numpy as np

from rgtbus.bus.payload import decode_frame, encode
from rgtbus.errors import RgtbusError

# One key-expression chunk: no wildcards, separators or zenoh's reserved characters.
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]*$")
_MAX_NOTES = 100


@runtime_checkable
class Bus(Protocol):
    run_id: str
    members: tuple[str, ...]

    def publish(self, unit: str, window: int, samples: np.ndarray, flags: int = 0) -> None: ...
    def gather(self, window: int, timeout: float = 5.0) -> dict[str, np.ndarray]: ...
    def stats(self) -> dict[str, int]: ...
    def close(self) -> None: ...
    def __enter__(self) -> Self: ...
    def __exit__(self, *exc: object) -> None: ...


def tx_prefix(run_id: str) -> str:
    return f"rgtbus/{run_id}/tx/"


def tx_key(run_id: str, unit: str) -> str:
    return f"rgtbus/{run_id}/tx/{unit}"


def check_name(kind: str, name: object) -> str:
    if not isinstance(name, str) or not _NAME.match(name):
        raise RgtbusError(
            f"bad {kind} {name!r}: use letters, digits, '_', '.', '-' (no '/', '*', '$', '?', '#')"
        )
    return name


STAT_KEYS = (
    "published",
    "received",
    "accepted",
    "gathered",
    "buffered",
    "dropped_foreign",
    "dropped_malformed",
    "dropped_late",
    "dropped_duplicate",
    "dropped_ahead",
)


class QueueBus:
    """Shared core: publish validation + encode, and a receive queue drained by ``gather``.

    Subclasses provide ``_send(key, data)`` and ``_close_transport()``; whatever delivers
    payloads only ever calls ``self._inbox.put((key, data))`` (thread-safe, never blocks).
    """

    kind = "abstract"
    OPTIONS: frozenset[str] = frozenset()  # keyword options open_bus may pass

    def __init__(
        self,
        run_id: str,
        members: Sequence[str],
        sample_rate: float,
        window_len: int,
        *,
        local: Sequence[str] | None = None,
        max_ahead: int = 1024,
    ) -> None:
        self.run_id = check_name("run id", run_id)
        if isinstance(members, str):
            raise RgtbusError(
                f"members must be a sequence of unit names, got the string {members!r}"
            )
        self.members = tuple(check_name("unit name", m) for m in members)
        if not self.members:
            raise RgtbusError(f"run {run_id!r} has no members")
        dup = sorted({m for m in self.members if self.members.count(m) > 1})
        if dup:
            raise RgtbusError(f"duplicate member(s) {', '.join(dup)} in run {run_id!r}")
        rate = float(sample_rate)
        if not (math.isfinite(rate) and rate > 0):
            raise RgtbusError(f"sample rate must be finite and > 0, got {sample_rate!r}")
        self.sample_rate = rate
        if isinstance(window_len, bool) or not isinstance(window_len, int) or window_len < 1:
            raise RgtbusError(f"window length must be an int >= 1, got {window_len!r}")
        self.window_len = window_len
        if isinstance(max_ahead, bool) or not isinstance(max_ahead, int) or max_ahead < 1:
            raise RgtbusError(f"max_ahead must be an int >= 1, got {max_ahead!r}")
        self.max_ahead = max_ahead
        self._member_set = frozenset(self.members)
        local_units = self.members if local is None else tuple(local)
        for u in local_units:
            self._check_member(u)
        self.local = local_units
        self._prefix = tx_prefix(self.run_id)
        self._keys = {u: tx_key(self.run_id, u) for u in self.members}
        self._inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
        self._buffer: dict[int, dict[str, np.ndarray]] = {}
        self._flags: dict[int, dict[str, int]] = {}
        # Flags of the last gathered window, per member (FINAL, FAILED): how a run ends.
        self.last_flags: dict[str, int] = {}
        self._next_window = 0  # windows below this were gathered (or skipped): late
        self._last_published: dict[str, int] = {}
        self._stats = dict.fromkeys(STAT_KEYS, 0)
        self._notes: deque[str] = deque(maxlen=_MAX_NOTES)
        self._closed = False

    # -- public API -------------------------------------------------------------------------

    def publish(self, unit: str, window: int, samples: np.ndarray, flags: int = 0) -> None:
        self._check_open("publish")
        self._check_member(unit)
        if unit not in self.local:
            raise RgtbusError(
                f"unit {unit!r} is not published from this bus (local: {', '.join(self.local)})"
            )
        window = self._check_window(window)
        last = self._last_published.get(unit)
        if last is not None and window <= last:
            raise RgtbusError(
                f"unit {unit!r} already published window {last}; window {window} is not later"
            )
        arr = np.asarray(samples, dtype=np.float64)
        if arr.shape != (self.window_len,):
            raise RgtbusError(
                f"unit {unit!r} window {window}: samples shape {arr.shape}, "
                f"expected ({self.window_len},)"
            )
        data = encode(window, self.sample_rate, arr, flags)
        self._send(self._keys[unit], data)
        self._last_published[unit] = window
        self._stats["published"] += 1

    def gather(self, window: int, timeout: float = 5.0) -> dict[str, np.ndarray]:
        self._check_open("gather")
        window = self._check_window(window)
        if window < self._next_window:
            raise RgtbusError(
                f"window {window} already gathered in run {self.run_id!r} "
                f"(next is {self._next_window})"
            )
        deadline = time.monotonic() + max(0.0, float(timeout))
        self._drain()
        while not self._complete(window):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                missing = [u for u in self.members if u not in self._buffer.get(window, {})]
                raise RgtbusError(
                    f"gather timed out after {timeout:g} s in run {self.run_id!r}: "
                    f"window {window} missing unit(s) {', '.join(missing)}"
                )
            try:
                item = self._inbox.get(timeout=remaining)
            except queue.Empty:
                continue
            self._accept(*item)
            self._drain()
        got = self._buffer.pop(window)
        self.last_flags = self._flags.pop(window, {})
        # Windows below the gathered one can never complete now: forget them.
        for w in [w for w in self._buffer if w < window]:
            self._stats["dropped_late"] += len(self._buffer.pop(w))
            self._flags.pop(w, None)
        self._next_window = window + 1
        self._stats["gathered"] += 1
        return {u: got[u] for u in self.members}

    def join(self, unit: str, digest: str, timeout: float = 10.0) -> None:
        """Barrier before window 0 for runs spread over processes; in-process buses have
        every member at hand already."""
        self._check_member(unit)

    def stats(self) -> dict[str, int]:
        """Counters so far; drains what already arrived first so they are current."""
        if not self._closed:
            self._drain()
        out = dict(self._stats)
        out["buffered"] = len(self._buffer)
        return out

    def drop_notes(self) -> list[str]:
        """Why recent payloads were dropped (one line each, at most 100 kept); clears them."""
        if not self._closed:
            self._drain()
        notes = list(self._notes)
        self._notes.clear()
        return notes

    def put_raw(self, key: str, data: bytes) -> None:
        """Send raw bytes on any key through this bus's transport (diagnostics and tests)."""
        self._check_open("put_raw")
        self._send(key, bytes(data))

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._close_transport()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"<{type(self).__name__} run={self.run_id!r} members={self.members} {state}>"

    # -- for subclasses ---------------------------------------------------------------------

    def _send(self, key: str, data: bytes) -> None:
        raise NotImplementedError

    def _close_transport(self) -> None:
        raise NotImplementedError

    # -- internals --------------------------------------------------------------------------

    def _check_open(self, what: str) -> None:
        if self._closed:
            raise RgtbusError(f"{what} on closed {self.kind} bus of run {self.run_id!r}")

    def _check_member(self, unit: object) -> None:
        if unit not in self._member_set:
            raise RgtbusError(
                f"unit {unit!r} is not a member of run {self.run_id!r} "
                f"(members: {', '.join(self.members)})"
            )

    @staticmethod
    def _check_window(window: object) -> int:
        if isinstance(window, bool) or not isinstance(window, int | np.integer) or window < 0:
            raise RgtbusError(f"window must be an int >= 0, got {window!r}")
        return int(window)

    def _complete(self, window: int) -> bool:
        got = self._buffer.get(window)
        return got is not None and len(got) == len(self.members)

    def _drain(self) -> None:
        get = self._inbox.get_nowait
        while True:
            try:
                item = get()
            except queue.Empty:
                return
            self._accept(*item)

    def _drop(self, counter: str, note: str) -> None:
        self._stats[counter] += 1
        self._notes.append(note)

    def _accept(self, key: str, data: bytes) -> None:
        self._stats["received"] += 1
        if not key.startswith(self._prefix):
            self._drop("dropped_foreign", f"{key}: not run {self.run_id!r}")
            return
        unit = key[len(self._prefix) :]
        if unit not in self._member_set:
            self._drop("dropped_foreign", f"{key}: {unit!r} is not a member")
            return
        try:
            window, rate, samples, flags = decode_frame(data)
        except RgtbusError as e:
            self._drop("dropped_malformed", f"{key}: {e}")
            return
        if rate != self.sample_rate:
            self._drop(
                "dropped_malformed", f"{key}: sample rate {rate:g}, run has {self.sample_rate:g}"
            )
            return
        if samples.size != self.window_len:
            self._drop(
                "dropped_malformed",
                f"{key}: window {window} has {samples.size} samples, run has {self.window_len}",
            )
            return
        if window < self._next_window:
            self._drop("dropped_late", f"{key}: window {window} arrived after it was gathered")
            return
        if window >= self._next_window + self.max_ahead:
            self._drop(
                "dropped_ahead",
                f"{key}: window {window} is more than {self.max_ahead} ahead of "
                f"{self._next_window}",
            )
            return
        slot = self._buffer.setdefault(window, {})
        if unit in slot:
            self._drop("dropped_duplicate", f"{key}: window {window} received twice")
            return
        slot[unit] = samples
        self._flags.setdefault(window, {})[unit] = flags
        self._stats["accepted"] += 1


def matches_subscription(key: str, run_id: str | None) -> bool:
    """Would a subscriber on ``rgtbus/<run_id>/tx/*`` (or ``rgtbus/*/tx/*`` when run_id is
    None) see ``key``? The memory bus uses this to deliver exactly what zenoh would."""
    parts = key.split("/")
    if len(parts) != 4 or parts[0] != "rgtbus" or parts[2] != "tx":
        return False
    if not parts[1] or not parts[3]:
        return False
    return run_id is None or parts[1] == run_id
