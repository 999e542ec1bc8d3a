"""The Bus protocol and the receive logic both live buses share.

A bus carries every member's frames (docs/engine.md): the pulses it transmits and its promise
"nothing more from me before sample t". ``wait(h)`` blocks until every member has promised past
sample h and returns the horizon H (the smallest promise): the medium before H is then final and
``take(H)`` hands it out. Received payloads go through one path: first the gate
(``QueueBus._deliver``, on the transport's thread, O(1) but for the tag): key, size, header and,
on a keyed run, the tag and the sequence number; then, queued, ``QueueBus._accept`` on the
caller's thread: frame decode, checks against the run and the member's earlier frames, then into
the member's state. Everything else is dropped and counted, never returned.

Bounded whatever arrives: the gate drops a frame larger than the run's bound
(``dropped_oversize``) before any other work, and queues at most a bounded number of bytes per
member (``dropped_overflow``). On a keyed run only frames with a valid tag, each sequence number
once, are queued at all: what an outsider sends costs at most one HMAC over a bounded frame and
never memory, and a member's own frames are never crowded out (docs/security.md).
"""

from __future__ import annotations

import math
import os
import queue
import re
import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from types import TracebackType
from typing import Protocol, Self, runtime_checkable

import numpy as np

from rgtbus.bus.auth import TAG_SIZE, AuthError, check_key, check_tag, tag
from rgtbus.bus.keys import tx_key, tx_prefix
from rgtbus.bus.payload import (
    NEVER,
    Frame,
    check_header,
    decode,
    encode,
    frame_size,
    max_frame_pulses,
)
from rgtbus.errors import MembersSilent, RgtbusError
from rgtbus.signal.pulses import Pulses as Pulses  # re-exported: units/ take it from here
from rgtbus.signal.pulses import merge_pulses, split_pulses

# One key-expression chunk: no wildcards, separators or zenoh's reserved characters.
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]*$")
_MAX_NOTES = 100
_NOTES_PER_REASON = 20  # notes kept per drop counter between two drop_notes(); the rest counted
_LEFT_GRACE = 1.0  # s: a member that left may still have frames on their way
# Bytes queued per member, not yet drained by wait(): frames that passed the gate. A member in
# lockstep has a few frames in flight; on a keyed run only its own (tag checked, each sequence
# number once) get here, so the cap is a safety net; on an open run it is what bounds a flood.
INBOX_BYTES_OPEN = 4 << 20
INBOX_BYTES_KEYED = 64 << 20


@dataclass
class MemberStatus:
    """What the bus knows of a member: its promise, FINAL/FAILED flags and done_at."""

    promise: int = 0
    flags: int = 0
    done_at: int = 0
    seq: int = 0
    pending: list[Pulses] = field(default_factory=list)


@runtime_checkable
class Bus(Protocol):
    """Everything the world (``rgtbus.engine.sim``, ``units/``) uses of a bus: memory, zenoh
    and the log-replay twin (``LogBus``) each keep it (``rgtbus.bus`` has mypy check so)."""

    run_id: str
    members: tuple[str, ...]
    local: tuple[str, ...]  # the members this bus publishes for
    close_problem: str | None  # a transport slow to close, once closed (a warning)

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
        """One frame of local member ``unit``: its new pulses and its promise of silence
        before sample ``promise``; ``flags`` FINAL or FAILED once it is done (``done_at``:
        the last sample it listened to)."""
        ...

    def wait(self, beyond: int, timeout: float = 5.0) -> int:
        """Block until every member promised past sample ``beyond``; the horizon (the
        smallest promise). RgtbusError when no such promise comes."""
        ...

    def take(self, until: int) -> dict[str, Pulses]:
        """Every member's pulses before sample ``until`` (at most the horizon), handed out
        once."""
        ...

    def known(self, until: int) -> dict[str, Pulses]:
        """Every member's pulses before ``until`` not yet taken, past the horizon too
        (nothing is handed out)."""
        ...

    def status(self) -> dict[str, MemberStatus]:
        """Every member's promise, flags and done_at as known so far."""
        ...

    def join(self, units: str | Sequence[str], digest: str, timeout: float = 10.0) -> None:
        """Barrier before the run, as ``units`` (this process's) on the scenario ``digest``."""
        ...

    def stats(self) -> dict[str, int]:
        """Counters so far (``published``: frames this bus sent)."""
        ...

    def drop_notes(self) -> list[str]:
        """Why recent frames were dropped, one line each; clears them."""
        ...

    @property
    def closed(self) -> bool:
        """Whether ``close`` was called."""
        ...

    def close(self) -> None:
        """Release the transport; again does nothing."""
        ...

    def __enter__(self) -> Self:
        """The bus itself, closed when the block ends."""
        ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Close (the error that ended the block stays the one reported)."""
        ...


def check_name(kind: str, name: object) -> str:
    """``name`` if it can stand in a zenoh key (one chunk, no wildcard or separator);
    RgtbusError naming ``kind`` otherwise."""
    if not isinstance(name, str) or not _NAME.match(name):
        raise RgtbusError(
            f"bad {kind} {name!r}: use letters, digits, '_', '.', '-' (no '/', '*', '$', '?', '#')"
        )
    return name


class BusBase:
    """What every bus shares (the live ones and the log twin): its run (id and members),
    being open until ``close`` (once: again does nothing), as a context manager too, and the
    checks of what it is asked. Subclasses release their transport in ``_close_transport``."""

    kind = "abstract"
    run_id: str
    members: tuple[str, ...]
    local: tuple[str, ...]  # the members this bus publishes for
    _member_set: frozenset[str]
    _closed = False

    def _take_run(self, run_id: str, members: Sequence[str]) -> None:
        """The run's id and members, checked: names a key can hold, one member at least,
        none twice; RgtbusError naming what is wrong."""
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
        self._member_set = frozenset(self.members)

    def _local_members(self, local: Sequence[str] | None) -> tuple[str, ...]:
        """The members this bus publishes for (all when None), each checked."""
        units = self.members if local is None else tuple(local)
        for u in units:
            self._check_member(u)
        return units

    @property
    def closed(self) -> bool:
        """Whether ``close`` was called."""
        return self._closed

    def close(self) -> None:
        """Close the bus (its transport); again does nothing."""
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
        if exc is None:
            self.close()
            return
        try:  # the error that ended the block is the one to report, not a slow close's
            self.close()
        except Exception as close_error:
            exc.add_note(f"and then, closing the bus: {close_error}")

    def _check_open(self, what: str) -> None:
        if self._closed:
            raise RgtbusError(f"{what} on closed {self.kind} bus of run {self.run_id!r}")

    def _check_member(self, unit: object) -> None:
        if unit not in self._member_set:
            raise RgtbusError(
                f"unit {unit!r} is not a member of run {self.run_id!r} "
                f"(members: {', '.join(self.members)})"
            )

    def _check_local(self, unit: str) -> None:
        """RgtbusError unless ``unit`` is a member this bus publishes for."""
        self._check_member(unit)
        if unit not in self.local:
            raise RgtbusError(
                f"unit {unit!r} is not published from this bus (local: {', '.join(self.local)})"
            )

    def _check_take(self, until: int, horizon: int) -> None:
        """RgtbusError for a take up to ``until`` past the ``horizon`` (what is final)."""
        if until > horizon:
            raise RgtbusError(f"take up to sample {until}: only samples before {horizon} are final")

    def _close_transport(self) -> None:
        raise NotImplementedError


STAT_KEYS = (
    "published",
    "received",
    "accepted",
    "waits",
    "pending",
    "dropped_foreign",
    "dropped_malformed",
    "dropped_late",
    "dropped_duplicate",
    "dropped_ahead",
    "dropped_unauthenticated",
    "dropped_oversize",  # larger than the run's frame (or hello) bound: dropped unread
    "dropped_overflow",  # the member's receive queue was full (or the hello queue)
    "hellos_unanswered",  # hellos heard again or too fast (replays): not answered
)


class Payload(Protocol):
    """What a transport hands the gate: ``bytes``, or zenoh's ``ZBytes`` (its length is known
    before it is copied out)."""

    def __len__(self) -> int: ...

    def to_bytes(self) -> bytes:
        """The payload's bytes, copied out."""
        ...


class _Bytes:
    """``bytes`` as a ``Payload``."""

    __slots__ = ("data",)

    def __init__(self, data: bytes) -> None:
        self.data = data

    def __len__(self) -> int:
        return len(self.data)

    def to_bytes(self) -> bytes:
        return self.data


_NO_PULSES: Pulses = (np.zeros(0, dtype=np.int64), np.zeros(0))  # shared: never written
_NO_PULSES[0].flags.writeable = False
_NO_PULSES[1].flags.writeable = False


class QueueBus(BusBase):
    """Shared core: publish validation + encode, and a receive queue drained by ``wait``.

    Subclasses provide ``_send(key, data)`` and ``_close_transport()``; whatever delivers
    payloads only ever calls ``self._deliver(key, payload)`` (the gate: thread-safe, never
    blocks, bounded work per payload; it queues what passes for ``wait``).

    ``key`` (bytes, at least 16) closes the run to outsiders: every frame is signed and every
    received frame must carry a valid tag from the member's process (its ``nonce``, announced
    when it joined; rgtbus.bus.auth); anything else is dropped as ``dropped_unauthenticated``.
    """

    OPTIONS: frozenset[str] = frozenset()  # keyword options open_bus may pass

    def __init__(
        self,
        run_id: str,
        members: Sequence[str],
        sample_rate: float,
        *,
        local: Sequence[str] | None = None,
        key: bytes | None = None,
    ) -> None:
        self._take_run(run_id, members)
        rate = float(sample_rate)
        if not (math.isfinite(rate) and rate > 0):
            raise RgtbusError(f"sample rate must be finite and > 0, got {sample_rate!r}")
        self.sample_rate = rate
        self.local = self._local_members(local)
        self._prefix = tx_prefix(self.run_id)
        self._keys = {u: tx_key(self.run_id, u) for u in self.members}
        # (key, data, unit, seq, tag checked): what passed the gate (_deliver), for _accept
        self._inbox: queue.SimpleQueue[tuple[str, bytes, str, int, bool]] = queue.SimpleQueue()
        self._tx_units = {k: u for u, k in self._keys.items()}
        self.max_pulses = max_frame_pulses(len(self.members))
        self._members = {u: MemberStatus() for u in self.members}
        self._sent = {u: MemberStatus() for u in self.local}  # what we published, per local unit
        self._taken = 0  # samples below this were handed out by take()
        self._stats = dict.fromkeys(STAT_KEYS, 0)
        self._notes: deque[str] = deque(maxlen=_MAX_NOTES)
        self._key = check_key(key)
        self.max_frame = frame_size(self.max_pulses, tagged=self._key is not None)
        # The gate's own state, shared with the transport's threads: under _gate_lock.
        self._gate_lock = threading.Lock()
        self._gate_stats = dict.fromkeys(STAT_KEYS, 0)
        self._noted = dict.fromkeys(STAT_KEYS, 0)  # notes kept per counter since drop_notes()
        self._queued_bytes = dict.fromkeys(self.members, 0)
        self._queued_seqs: dict[str, set[int]] = {u: set() for u in self.members}
        self._inbox_cap = INBOX_BYTES_OPEN if self._key is None else INBOX_BYTES_KEYED
        self.nonce = os.urandom(16)  # this process's, bound into every tag it makes
        # Whose tags we can check: our own units now, the others' once their hello is heard.
        self._nonces: dict[str, bytes] = dict.fromkeys(self.local, self.nonce)
        self._closed = False
        self.close_problem: str | None = None  # a transport slow to close, once closed
        # Members the transport saw leave (their session ended), and when: under _gate_lock.
        self._gone: dict[str, float] = {}

    # -- public API -------------------------------------------------------------------------

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
        """Send one frame of ``unit`` (a local member): its new pulses and its promise."""
        self._check_open("publish")
        self._check_local(unit)
        mine = self._sent[unit]
        s = np.asarray(samples, dtype=np.int64).reshape(-1)
        if s.size and s[0] < mine.promise:
            raise RgtbusError(
                f"unit {unit!r}: pulse at sample {int(s[0])} is before its earlier promise "
                f"(sample {mine.promise})"
            )
        if promise < mine.promise:
            raise RgtbusError(f"unit {unit!r}: promise {promise} goes back from {mine.promise}")
        if s.size > self.max_pulses:  # every receiver would drop it unread: say so here
            raise RgtbusError(
                f"unit {unit!r}: a frame of {s.size} pulses, a run of {len(self.members)} "
                f"units carries at most {self.max_pulses} in one"
            )
        frame = Frame(
            mine.seq + 1, int(promise), s, np.asarray(values, dtype=np.float64), flags, done_at
        )
        sign = None
        if self._key is not None:
            key, run_id, nonce = self._key, self.run_id, self.nonce

            def sign(body: bytes) -> bytes:
                return tag(key, "frame", run_id, unit, nonce, body)

        data = encode(frame, self.sample_rate, sign=sign)
        self._send(self._keys[unit], data)
        mine.seq, mine.promise = frame.seq, frame.promise
        self._stats["published"] += 1

    def wait(self, beyond: int, timeout: float = 5.0) -> int:
        """Block until every member has promised past sample ``beyond`` (once everyone has
        promised silence for good: until every member is done); return the horizon (the
        smallest promise). RgtbusError naming the silent members after ``timeout`` s."""
        self._check_open("wait")
        deadline = time.monotonic() + max(0.0, float(timeout))
        self._drain()
        self._stats["waits"] += 1
        while not self._past(beyond):
            left = self._left_holding(beyond)
            if left:
                raise MembersSilent(
                    f"{', '.join(left)} left run {self.run_id!r} before "
                    f"{'it was' if len(left) == 1 else 'they were'} done: "
                    "its zenoh session ended (its process killed, or its link lost)",
                    tuple(left),
                )
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                late = [u for u in self.members if not self._past(beyond, u)]
                what = (
                    "did not say it was done"
                    if beyond >= NEVER
                    else f"promised nothing past sample {beyond} "
                    f"(t = {beyond / self.sample_rate:.3f} s)"
                )
                raise MembersSilent(
                    f"no news for {timeout:g} s in run {self.run_id!r}: "
                    f"{', '.join(late)} {what}: stalled or gone",
                    tuple(late),
                )
            try:
                item = self._inbox.get(timeout=min(remaining, _LEFT_GRACE))
            except queue.Empty:
                continue
            self._accept(*item)
            self._drain()
        return self.horizon()

    def _member_gone(self, unit: str) -> None:
        """The transport saw member ``unit``'s session end (any thread; never blocks)."""
        if unit in self._members and unit not in self.local:
            with self._gate_lock:
                self._gone.setdefault(unit, time.monotonic())

    def _forget_gone(self) -> None:
        """Every member is here (the join proved it): who left before does not count."""
        with self._gate_lock:
            self._gone.clear()

    def _left_holding(self, beyond: int) -> list[str]:
        """The members that left (``_LEFT_GRACE`` s ago or more: their last frames had time
        to arrive) while still holding the horizon at or before ``beyond``."""
        with self._gate_lock:
            if not self._gone:
                return []
            gone = dict(self._gone)
        cut = time.monotonic() - _LEFT_GRACE
        return [
            u for u in self.members if gone.get(u, cut + 1) <= cut and not self._past(beyond, u)
        ]

    def _past(self, beyond: int, unit: str | None = None) -> bool:
        members = [self._members[unit]] if unit else self._members.values()
        if beyond >= NEVER:
            return all(m.flags and m.promise >= NEVER for m in members)
        return all(m.promise > beyond for m in members)

    def horizon(self) -> int:
        """The smallest promise: the medium before it is final (as far as received)."""
        return min(m.promise for m in self._members.values())

    def take(self, until: int) -> dict[str, Pulses]:
        """Every member's pulses before sample ``until`` (at most the horizon), handed out once."""
        self._check_open("take")
        self._check_take(until, self.horizon())
        out = {}
        for u, m in self._members.items():
            if not m.pending:
                out[u] = _NO_PULSES
                continue
            now, later = split_pulses(merge_pulses(m.pending), until)
            m.pending = [later] if later[0].size else []
            out[u] = now
        self._taken = max(self._taken, until)
        return out

    def known(self, until: int) -> dict[str, Pulses]:
        """Every member's pulses received so far before sample ``until``, taken or not yet:
        what is on its way, for looking ahead (nothing is handed out)."""
        if not self._closed:
            self._drain()
        out = {}
        for u, m in self._members.items():
            if not m.pending:
                out[u] = _NO_PULSES
                continue
            merged = merge_pulses(m.pending)
            m.pending = [merged] if merged[0].size else []
            out[u] = split_pulses(merged, until)[0]
        return out

    def status(self) -> dict[str, MemberStatus]:
        """Every member's promise, flags and done_at as received so far."""
        if not self._closed:
            self._drain()
        return self._members

    def join(self, units: str | Sequence[str], digest: str, timeout: float = 10.0) -> None:
        """Barrier before the run for runs spread over processes (``units``: this process's,
        one or several); in-process buses have every member at hand already."""
        for unit in [units] if isinstance(units, str) else units:
            self._check_member(unit)

    def stats(self) -> dict[str, int]:
        """Counters so far; drains what already arrived first so they are current. Every
        payload received is counted once as accepted or under one ``dropped_*`` reason."""
        if not self._closed:
            self._drain()
        with self._gate_lock:
            out = {k: v + self._gate_stats[k] for k, v in self._stats.items()}
        out["pending"] = sum(int(p[0].size) for m in self._members.values() for p in m.pending)
        return out

    def drop_notes(self) -> list[str]:
        """Why recent payloads were dropped (one line each; at most 20 a reason, 100 in all,
        then how many more there were); clears them."""
        if not self._closed:
            self._drain()
        with self._gate_lock:
            notes = list(self._notes)
            self._notes.clear()
            for counter, n in self._noted.items():
                if n > _NOTES_PER_REASON:
                    notes.append(f"... and {n - _NOTES_PER_REASON} more {counter} (counted)")
            self._noted = dict.fromkeys(STAT_KEYS, 0)
        return notes

    def put_raw(self, key: str, data: bytes) -> None:
        """Send raw bytes on any key through this bus's transport (diagnostics and tests)."""
        self._check_open("put_raw")
        self._send(key, bytes(data))

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"<{type(self).__name__} run={self.run_id!r} members={self.members} {state}>"

    # -- for subclasses ---------------------------------------------------------------------

    def _send(self, key: str, data: bytes) -> None:
        raise NotImplementedError

    # -- internals --------------------------------------------------------------------------

    def _drain(self) -> None:
        get = self._inbox.get_nowait
        while True:
            try:
                item = get()
            except queue.Empty:
                return
            self._accept(*item)

    def _noting(self, counter: str) -> bool:
        """Whether a drop under ``counter`` gets its note (a flood is counted, not noted:
        at most _NOTES_PER_REASON a reason between two drop_notes()). Under _gate_lock."""
        self._noted[counter] += 1
        return self._noted[counter] <= _NOTES_PER_REASON

    def _drop(self, counter: str, note: str) -> None:
        # On the caller's thread (_accept, hellos); the notes are shared with the gate.
        self._stats[counter] += 1
        with self._gate_lock:
            if self._noting(counter):
                self._notes.append(note)

    def _gate_drop(self, counter: str, key: str, why: object, received: bool = True) -> None:
        """A payload dropped at the gate (any thread): counted, its note kept if not flooded."""
        with self._gate_lock:
            self._gate_stats[counter] += 1
            if received:
                self._gate_stats["received"] += 1
            if self._noting(counter):
                self._notes.append(f"{key}: {why}")

    def _deliver(self, key: str, payload: Payload | bytes) -> None:
        """The gate: what a transport received on ``key``, checked in O(1) (on a keyed run one
        HMAC over at most ``max_frame`` bytes) and queued for ``wait``, or dropped and counted.
        Runs on the transport's threads: never blocks, never raises, holds nothing but a short
        lock."""
        if isinstance(payload, bytes | bytearray):
            payload = _Bytes(bytes(payload))
        try:
            self._gate(key, payload)
        except Exception as e:  # a callback must not raise (docs/zenoh-notes.md)
            self._gate_drop("dropped_malformed", key, f"{type(e).__name__}: {e}")

    def _gate(self, key: str, payload: Payload) -> None:
        unit = self._tx_units.get(key)
        if unit is None:
            if not key.startswith(self._prefix):
                self._gate_drop("dropped_foreign", key, f"not run {self.run_id!r}")
            else:
                self._gate_drop(
                    "dropped_foreign", key, f"{key[len(self._prefix) :]!r} is not a member"
                )
            return
        size = len(payload)
        if size > self.max_frame:  # before anything else: not even copied out
            self._gate_drop(
                "dropped_oversize",
                key,
                f"frame of {size} bytes, the run's bound is {self.max_frame}",
            )
            return
        nonce = None
        if self._key is not None:
            nonce = self._nonces.get(unit)
            if nonce is None:
                self._gate_drop("dropped_unauthenticated", key, f"no hello heard from {unit!r}")
                return
        data = payload.to_bytes()
        try:
            header = check_header(data)
        except RgtbusError as e:
            self._gate_drop("dropped_malformed", key, e)
            return
        checked = False
        if self._key is not None and nonce is not None:
            if not header.tagged:
                self._gate_drop(
                    "dropped_unauthenticated",
                    key,
                    "frame not authenticated (no tag) on a run with a key",
                )
                return
            try:
                check_tag(
                    self._key, "frame", self.run_id, unit, nonce, data[:-TAG_SIZE], data[-TAG_SIZE:]
                )
            except AuthError as e:
                self._gate_drop("dropped_unauthenticated", key, e)
                return
            checked = True
        with self._gate_lock:
            if checked:
                # Signed frames are the member's own: each sequence number is queued once (a
                # replay of a frame seen on the network can cost one queue place, not more).
                seqs = self._queued_seqs[unit]
                if header.seq <= self._members[unit].seq or header.seq in seqs:
                    self._gate_stats["dropped_duplicate"] += 1
                    self._gate_stats["received"] += 1
                    if self._noting("dropped_duplicate"):
                        self._notes.append(f"{key}: frame {header.seq} received twice (replayed?)")
                    return
            if self._queued_bytes[unit] + size > self._inbox_cap:
                self._gate_stats["dropped_overflow"] += 1
                self._gate_stats["received"] += 1
                if self._noting("dropped_overflow"):
                    self._notes.append(
                        f"{key}: receive queue full ({self._queued_bytes[unit]} bytes of "
                        f"{unit!r} not yet read)"
                    )
                return
            if checked:
                seqs.add(header.seq)
            self._queued_bytes[unit] += size
            self._inbox.put((key, data, unit, header.seq, checked))  # never blocks

    def _accept(self, key: str, data: bytes, unit: str, seq: int, checked: bool) -> None:
        """A queued frame (it passed the gate), on the caller's thread."""
        try:
            self._accept_frame(key, data, unit, checked)
        finally:
            with self._gate_lock:
                self._queued_bytes[unit] -= len(data)
                if checked:
                    self._queued_seqs[unit].discard(seq)

    def _accept_frame(self, key: str, data: bytes, unit: str, checked: bool) -> None:
        self._stats["received"] += 1
        check = None
        if self._key is not None:
            if not checked:  # every frame of a keyed run had its tag checked at the gate
                self._drop("dropped_unauthenticated", f"{key}: tag not checked")
                return

            def check(body: bytes, got: bytes) -> None:
                pass  # checked at the gate

        try:
            frame, rate = decode(data, check=check)
        except AuthError as e:
            self._drop("dropped_unauthenticated", f"{key}: {e}")
            return
        except RgtbusError as e:
            self._drop("dropped_malformed", f"{key}: {e}")
            return
        if rate != self.sample_rate:
            self._drop(
                "dropped_malformed", f"{key}: sample rate {rate:g}, run has {self.sample_rate:g}"
            )
            return
        m = self._members[unit]
        if frame.seq <= m.seq:
            self._drop("dropped_duplicate", f"{key}: frame {frame.seq} received twice (replayed?)")
            return
        if frame.seq != m.seq + 1:
            self._drop("dropped_ahead", f"{key}: frame {frame.seq} while {m.seq + 1} is due")
            return
        if frame.promise < m.promise:
            self._drop(
                "dropped_malformed", f"{key}: promise {frame.promise} goes back from {m.promise}"
            )
            return
        if frame.samples.size and frame.samples[0] < max(m.promise, self._taken):
            self._drop(
                "dropped_late",
                f"{key}: pulse at sample {int(frame.samples[0])} is before its promise "
                f"(sample {m.promise})",
            )
            return
        if m.flags and frame.flags != m.flags:
            self._drop("dropped_malformed", f"{key}: done flags changed after the unit was done")
            return
        m.seq, m.promise, m.flags, m.done_at = frame.seq, frame.promise, frame.flags, frame.done_at
        if frame.samples.size:
            m.pending.append((frame.samples, frame.values))
        self._stats["accepted"] += 1
