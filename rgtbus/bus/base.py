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
never memory, and a member's own frames are never crowded out (docs/security.md). Before the
tag, what a frame's header alone rules out is dropped (a number already accepted, or far ahead),
and the tags checked that fail are held to a rate a member's key (``dropped_rate`` beyond it):
a flood of wrongly tagged frames costs a bounded number of HMACs a second.

A frame lost (a full queue, a link that hiccuped, the rate above) is asked for again
(docs/engine.md, "A frame lost is asked for again"): frames after a gap are held, and a member
that holds the horizon with a gap before its frames, or quiet for ``REPAIR_QUIET`` s, is asked
for what follows its last frame received (``_ask_resend``); every bus keeps its own units'
recent frames as sent and sends them again when asked. A member is judged by what it proved to
say: two different frames under one number, or a frame no member running rgtbus would send, from
a member whose frames are authenticated (a key, or TLS identities) names it at once
(``MembersSilent``); its silence names it at the run's timeout.
"""

from __future__ import annotations

import hashlib
import math
import os
import queue
import re
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
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
from rgtbus.errors import BadInput, MembersSilent, RgtbusError
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
# Repair. A member's frames held after a gap (at most so many, so many bytes), and what is
# dropped unread as too far ahead of its last frame accepted (a member in lockstep is a few
# frames ahead at most).
AHEAD_FRAMES = 1024
AHEAD_BYTES = 16 << 20
AHEAD_WINDOW = 4096
# A member holding the horizon and quiet this long is asked for what follows its last frame
# (then again at twice the gap, up to REPAIR_GAP_MAX s, until it makes progress).
REPAIR_QUIET = 0.25
REPAIR_GAP_MAX = 2.0
_REPAIR_TICK = 0.05  # s: how often a wait looks for gaps
# Each local unit's frames as sent, for a resend: at most so many, so many bytes.
HISTORY_FRAMES = 4096
HISTORY_BYTES = 32 << 20
RESEND_BATCH = 256  # frames sent again for one request at most
_RESEND_AGAIN = 0.1  # s: a request for the same frames within this is served once
# Each member's recent frames' digests: a second frame under one of these numbers that differs
# is an impostor's (or a broken member's); further back, a number seen is a duplicate.
RECENT_DIGESTS = 64
# Tags checked a second on a member's key that may fail (a burst of twice as many): a flood of
# wrongly tagged frames costs at most this many HMACs, but for frames under the one number the
# run waits for next (always checked); a frame whose tag holds costs nothing.
CHECKS_PER_S = 2000.0
# ... and of frames under a number already accepted (kept only to catch two different frames
# under one number): beyond this, such a frame is a duplicate unchecked, and a flood of old
# numbers takes nothing from the checks of the frames a run waits for.
OLD_CHECKS_PER_S = 200.0


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

    def wait(
        self, beyond: int, timeout: float = 5.0, stop: Callable[[], bool] | None = None
    ) -> int:
        """Block until every member promised past sample ``beyond``; the horizon (the
        smallest promise). RgtbusError when no such promise comes. ``stop``: asked as it
        waits; once it says so, the horizon as it is (a steered run's change came)."""
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
        raise BadInput(
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
            raise BadInput(
                f"members must be a sequence of unit names, got the string {members!r}"
            )
        self.members = tuple(check_name("unit name", m) for m in members)
        if not self.members:
            raise BadInput(f"run {run_id!r} has no members")
        dup = sorted({m for m in self.members if self.members.count(m) > 1})
        if dup:
            raise BadInput(f"duplicate member(s) {', '.join(dup)} in run {run_id!r}")
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
            raise BadInput(f"{what} on closed {self.kind} bus of run {self.run_id!r}")

    def _check_member(self, unit: object) -> None:
        if unit not in self._member_set:
            raise BadInput(
                f"unit {unit!r} is not a member of run {self.run_id!r} "
                f"(members: {', '.join(self.members)})"
            )

    def _check_local(self, unit: str) -> None:
        """RgtbusError unless ``unit`` is a member this bus publishes for."""
        self._check_member(unit)
        if unit not in self.local:
            raise BadInput(
                f"unit {unit!r} is not published from this bus (local: {', '.join(self.local)})"
            )

    def _check_take(self, until: int, horizon: int) -> None:
        """RgtbusError for a take up to ``until`` past the ``horizon`` (what is final)."""
        if until > horizon:
            raise BadInput(f"take up to sample {until}: only samples before {horizon} are final")

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
    "dropped_rate",  # beyond the tags a member's key may fail a second: dropped unchecked
    "hellos_unanswered",  # hellos heard again or too fast (replays): not answered
    "held",  # frames after a gap, held until it is filled (now): received, not yet read
    "resend_asked",  # requests this bus sent for frames it missed
    "resent",  # frames this bus sent again, asked to
)
# What the gate drops and every other drop reason: the counters a flood shows in.
DROP_KEYS = tuple(k for k in STAT_KEYS if k.startswith("dropped_"))


def drop_summary(stats: dict[str, int]) -> str | None:
    """One line on what a bus dropped, for the log and a summary (None: nothing): the total and
    each reason's count."""
    counts = {k: int(stats.get(k, 0)) for k in DROP_KEYS if stats.get(k)}
    if not counts:
        return None
    parts = ", ".join(f"{k.removeprefix('dropped_')} {n}" for k, n in counts.items())
    return f"{sum(counts.values())} payloads dropped in all ({parts})"


class Budget:
    """A token bucket: ``take()`` at most ``rate`` times a second on average, ``burst`` at
    once; ``give_back()`` returns a token taken for nothing (a check that passed)."""

    def __init__(self, rate: float, burst: float) -> None:
        self.rate, self.burst = rate, burst
        self.tokens = burst
        self.at = time.monotonic()

    def take(self) -> bool:
        """Whether a token was left (and now is spent)."""
        now = time.monotonic()
        self.tokens = min(self.burst, self.tokens + (now - self.at) * self.rate)
        self.at = now
        if self.tokens < 1.0:
            return False
        self.tokens -= 1.0
        return True

    def give_back(self) -> None:
        """A token taken for a check that passed."""
        self.tokens = min(self.burst, self.tokens + 1.0)


def frame_digest(data: bytes) -> bytes:
    """What tells two frames apart (16 bytes of BLAKE2b): a resend is the frame itself."""
    return hashlib.blake2b(data, digest_size=16).digest()


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
            raise BadInput(f"sample rate must be finite and > 0, got {sample_rate!r}")
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
        # a keyed run's checked frames queued and not yet read, by number: their bytes (the
        # queue's own; a copy of one is known for a duplicate before any HMAC)
        self._queued_seqs: dict[str, dict[int, bytes]] = {u: {} for u in self.members}
        self._inbox_cap = INBOX_BYTES_OPEN if self._key is None else INBOX_BYTES_KEYED
        self.nonce = os.urandom(16)  # this process's, bound into every tag it makes
        # Whose tags we can check: our own units now, the others' once their hello is heard.
        self._nonces: dict[str, bytes] = dict.fromkeys(self.local, self.nonce)
        self._closed = False
        self.close_problem: str | None = None  # a transport slow to close, once closed
        # Members the transport saw leave (their session ended), and when: under _gate_lock.
        self._gone: dict[str, float] = {}
        # Whether a member's frames prove who sent them (a key; TLS identities under an ACL):
        # then a bad frame, or two different frames under one number, names it at once.
        self._identified = self._key is not None
        now = time.monotonic()
        # Repair (the module docstring): each local unit's recent frames as sent (number ->
        # bytes, oldest first); frames after a gap, held; each member's recent frames' digests;
        # when each made progress last, and when to ask it next.
        self._history: dict[str, dict[int, bytes]] = {u: {} for u in self.local}
        self._history_bytes = dict.fromkeys(self.local, 0)
        self._ahead: dict[str, dict[int, tuple[str, bytes, bool]]] = {u: {} for u in self.members}
        self._ahead_bytes = dict.fromkeys(self.members, 0)
        self._recent: dict[str, dict[int, bytes]] = {u: {} for u in self.members}
        self._progress_at = dict.fromkeys(self.members, now)
        self._ask_at = dict.fromkeys(self.members, 0.0)
        self._ask_gap = dict.fromkeys(self.members, REPAIR_QUIET)
        self._served: dict[tuple[str, int], float] = {}
        self._budgets = {u: Budget(CHECKS_PER_S, 2 * CHECKS_PER_S) for u in self.members}
        self._old_budgets = {u: Budget(OLD_CHECKS_PER_S, OLD_CHECKS_PER_S) for u in self.members}
        # A member's bad authenticated frames: how many, and the latest reason; and a member
        # named untrustworthy (an identified run): why.
        self._bad: dict[str, tuple[int, str]] = {}
        self._faulty: dict[str, str] = {}

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
            raise BadInput(
                f"unit {unit!r}: pulse at sample {int(s[0])} is before its earlier promise "
                f"(sample {mine.promise})"
            )
        if promise < mine.promise:
            raise BadInput(f"unit {unit!r}: promise {promise} goes back from {mine.promise}")
        if s.size > self.max_pulses:  # every receiver would drop it unread: say so here
            raise BadInput(
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
        self._keep(unit, frame.seq, data)
        self._send(self._keys[unit], data)
        mine.seq, mine.promise = frame.seq, frame.promise
        self._stats["published"] += 1

    def _keep(self, unit: str, seq: int, data: bytes) -> None:
        """A local unit's frame as sent, for a resend (the oldest go past the bounds)."""
        history = self._history[unit]
        history[seq] = data
        self._history_bytes[unit] += len(data)
        while len(history) > HISTORY_FRAMES or self._history_bytes[unit] > HISTORY_BYTES:
            self._history_bytes[unit] -= len(history.pop(next(iter(history))))

    def wait(
        self, beyond: int, timeout: float = 5.0, stop: Callable[[], bool] | None = None
    ) -> int:
        """Block until every member has promised past sample ``beyond`` (once everyone has
        promised silence for good: until every member is done); return the horizon (the
        smallest promise). RgtbusError naming the silent members after ``timeout`` s.
        ``stop``: asked every tick; once it says so, the horizon as it is, at once."""
        self._check_open("wait")
        started = time.monotonic()
        deadline = started + max(0.0, float(timeout))
        self._drain()
        self._stats["waits"] += 1
        self._check_trusted()
        next_look = started + _REPAIR_TICK  # the first look for gaps, requests
        while not self._past(beyond):
            if stop is not None and stop():
                break
            self._check_trusted()
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
                    f"{', '.join(late)} {what}: stalled or gone{self._why_late(late)}",
                    tuple(late),
                )
            now = time.monotonic()
            if now >= next_look:  # at most every tick: each is a pass over the members
                next_look = now + _REPAIR_TICK
                self._between_frames()
                self._repair(beyond, started)
            try:
                item = self._inbox.get(timeout=min(remaining, _REPAIR_TICK))
            except queue.Empty:
                continue
            self._accept(*item)
            self._drain()
        return self.horizon()

    def _why_late(self, late: Sequence[str]) -> str:
        """What this bus knows of why ``late`` members are late: bad frames, a gap."""
        said = []
        for u in late:
            if u in self._bad:
                n, why = self._bad[u]
                said.append(f"{u} sent {n} bad frame{'s' * (n != 1)} (last: {why})")
            held = self._ahead[u]
            if held:
                first = self._members[u].seq + 1
                said.append(f"{u}'s frame {first} never came ({len(held)} after it held)")
        return f" ({'; '.join(said)})" if said else ""

    def _check_trusted(self) -> None:
        """MembersSilent naming a member whose frames proved it untrustworthy (an identified
        run: two different frames under one number, or a frame no healthy member sends)."""
        if self._faulty:
            unit, why = next(iter(self._faulty.items()))
            raise MembersSilent(
                f"{unit} is not trusted in run {self.run_id!r}: {why} (another process speaks "
                "with its identity, or it is broken)",
                (unit,),
            )

    def _between_frames(self) -> None:
        """What a transport does while a wait waits (answer requests): nothing here."""

    def _ask_resend(self, unit: str, first: int) -> None:
        """Ask member ``unit`` for its frames from number ``first`` on: nothing here (a bus
        whose members are all local never misses a frame of another process)."""

    def _repair(self, beyond: int, started: float) -> None:
        """Ask again for what is missing of each member that holds the horizon at or before
        ``beyond``: one with a gap before frames held, or quiet since ``REPAIR_QUIET`` s
        (counted from the wait's start, ``started``, at the earliest); then at twice the gap,
        up to ``REPAIR_GAP_MAX``. A local unit's own frames lost on the way back are taken
        from what it sent."""
        now = time.monotonic()
        for u in self.members:
            if self._past(beyond, u) or u in self._faulty:
                continue
            m = self._members[u]
            quiet = now - max(self._progress_at[u], started) >= REPAIR_QUIET
            if u in self._sent:
                if quiet and m.seq < self._sent[u].seq:
                    self._refeed(u)
                continue
            if (self._ahead[u] or quiet) and now >= self._ask_at[u]:
                self._ask_resend(u, m.seq + 1)
                self._stats["resend_asked"] += 1
                self._ask_at[u] = now + self._ask_gap[u]
                if not self._ahead[u]:  # a known gap is asked for again and again; quiet less
                    self._ask_gap[u] = min(REPAIR_GAP_MAX, 2.0 * self._ask_gap[u])

    def _refeed(self, unit: str) -> None:
        """A local unit's frames after the last one received back, from what it sent."""
        history, key = self._history[unit], self._keys[unit]
        while (data := history.get(self._members[unit].seq + 1)) is not None:
            seq = self._members[unit].seq
            self._accept_frame(key, data, unit, True)
            if self._members[unit].seq == seq:
                return

    def _resend(self, unit: str, first: int, asker: str) -> None:
        """Local unit ``unit``'s frames from ``first`` on, sent again (at most
        ``RESEND_BATCH``; the same request within ``_RESEND_AGAIN`` s served once)."""
        history = self._history.get(unit)
        if history is None:
            return  # not one of ours: its own process answers
        last = self._sent[unit].seq
        if first > last:
            return  # nothing sent after what it has: the member is behind, not lost
        now = time.monotonic()
        if now - self._served.get((unit, first), -math.inf) < _RESEND_AGAIN:
            return
        if len(self._served) > 4 * len(self.members):
            self._served = {k: t for k, t in self._served.items() if now - t < _RESEND_AGAIN}
        self._served[(unit, first)] = now
        key, sent = self._keys[unit], 0
        for seq in range(first, min(last, first + RESEND_BATCH - 1) + 1):
            data = history.get(seq)
            if data is None:
                self._drop_note("resent", f"{asker} asked for {unit}'s frame {seq}: no longer held")
                continue
            self._send(key, data)
            sent += 1
        self._stats["resent"] += sent

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
        if not self._link_up():
            return []  # we are the one cut off: the run's timeout judges
        cut = time.monotonic() - _LEFT_GRACE
        # gone, and nothing authenticated heard from it since (its last frames had time)
        return [
            u
            for u in self.members
            if max(gone.get(u, cut + 1), self._progress_at[u]) <= cut and not self._past(beyond, u)
        ]

    def _member_back(self, unit: str) -> None:
        """The transport sees member ``unit`` again (its session back after a hiccup)."""
        with self._gate_lock:
            self._gone.pop(unit, None)

    def _link_up(self) -> bool:
        """Whether this process still reaches the others (a transport that knows says)."""
        return True

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
        payload received is counted once as accepted, under one ``dropped_*`` reason, or
        ``held`` (after a gap, until it is filled)."""
        if not self._closed:
            self._drain()
        with self._gate_lock:
            out = {k: v + self._gate_stats[k] for k, v in self._stats.items()}
        out["pending"] = sum(int(p[0].size) for m in self._members.values() for p in m.pending)
        out["held"] = sum(len(h) for h in self._ahead.values())
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
        self._drop_note(counter, note)

    def _drop_note(self, counter: str, note: str) -> None:
        with self._gate_lock:
            if self._noting(counter):
                self._notes.append(note)

    def _bad_frame(self, unit: str, counter: str, note: str, checked: bool) -> None:
        """A frame of ``unit`` that no healthy member sends, dropped under ``counter``; with
        proof of who sent it (an identified run: its tag ``checked`` on a keyed run, its
        transport's identity on a run without a key) the member is not trusted."""
        self._drop(counter, note)
        n, _ = self._bad.get(unit, (0, ""))
        why = note.split(": ", 1)[-1]
        self._bad[unit] = (n + 1, why)
        if self._identified and (checked or self._key is None):
            self._faulty.setdefault(unit, why)

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
        # What the header alone rules out, before the tag: a number accepted long ago (its
        # digest forgotten: only a duplicate), or far ahead of the last accepted.
        accepted = self._members[unit].seq
        if header.seq <= accepted and header.seq not in self._recent[unit]:
            self._gate_drop("dropped_duplicate", key, f"frame {header.seq} received twice")
            return
        if header.seq > accepted + AHEAD_WINDOW:
            self._gate_drop("dropped_ahead", key, f"frame {header.seq} while {accepted + 1} is due")
            return
        if self._copy_of_known(unit, header.seq, accepted, data):
            # a replay: the same bytes under a number queued or lately accepted cost a
            # look-up (and a digest), never an HMAC; another frame under it is checked below
            self._gate_drop("dropped_duplicate", key, f"frame {header.seq} received twice")
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
            # The frame the run waits for now (the next number) is always checked: that costs
            # a flood aimed at it one HMAC a frame, no more than its callback already costs.
            old, due = header.seq <= accepted, header.seq == accepted + 1
            budget = (self._old_budgets if old else self._budgets)[unit]
            with self._gate_lock:
                allowed = due or budget.take()
            if not allowed and old:
                self._gate_drop("dropped_duplicate", key, f"frame {header.seq} received twice")
                return
            if not allowed:
                self._gate_drop(
                    "dropped_rate",
                    key,
                    f"more than {CHECKS_PER_S:g} frames a second on {unit!r}'s key failed "
                    "their tag: dropped unchecked",
                )
                return
            try:
                check_tag(
                    self._key, "frame", self.run_id, unit, nonce, data[:-TAG_SIZE], data[-TAG_SIZE:]
                )
            except AuthError as e:
                self._gate_drop("dropped_unauthenticated", key, e)
                return
            if not due:
                with self._gate_lock:
                    budget.give_back()
            checked = True
        with self._gate_lock:
            if checked:
                # Signed frames are the member's own: each sequence number is queued once (a
                # replay of a frame seen on the network can cost one queue place, not more).
                seqs = self._queued_seqs[unit]
                if header.seq in seqs:
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
                seqs[header.seq] = data
            self._queued_bytes[unit] += size
            self._inbox.put((key, data, unit, header.seq, checked))  # never blocks

    def _copy_of_known(self, unit: str, seq: int, accepted: int, data: bytes) -> bool:
        """Whether ``data`` is byte for byte a frame of ``unit`` numbered ``seq`` that is
        queued (a keyed run's, its tag checked) or among the last accepted (by its digest).
        Runs on the transport's threads, as the gate does."""
        if seq <= accepted:
            kept = self._recent[unit].get(seq)
            return kept is not None and kept == frame_digest(data)
        if self._key is None:
            return False
        with self._gate_lock:
            queued = self._queued_seqs[unit].get(seq)
        return queued is not None and queued == data

    def _accept(self, key: str, data: bytes, unit: str, seq: int, checked: bool) -> None:
        """A queued frame (it passed the gate), on the caller's thread: held when it comes
        after a gap, else read; then the frames held after it that are now due."""
        try:
            m = self._members[unit]
            if seq > m.seq + 1:
                self._hold(key, data, unit, seq, checked)
                return
            self._accept_frame(key, data, unit, checked)
            held = self._ahead[unit]
            while held and (item := held.pop(m.seq + 1, None)) is not None:
                self._ahead_bytes[unit] -= len(item[1])
                self._read_frame(*item[:2], unit, item[2])  # received when it was held
        finally:
            with self._gate_lock:
                self._queued_bytes[unit] -= len(data)
                if checked:
                    self._queued_seqs[unit].pop(seq, None)

    def _hold(self, key: str, data: bytes, unit: str, seq: int, checked: bool) -> None:
        """A frame after a gap, held until the gap is filled (bounded: beyond, dropped).
        Received now: it is then accepted or dropped, or still held."""
        held = self._ahead[unit]
        self._stats["received"] += 1
        if seq in held:
            self._drop("dropped_duplicate", f"{key}: frame {seq} received twice")
            return
        if len(held) >= AHEAD_FRAMES or self._ahead_bytes[unit] + len(data) > AHEAD_BYTES:
            due = self._members[unit].seq + 1
            self._drop("dropped_ahead", f"{key}: frame {seq} while {due} is due (too many held)")
            return
        held[seq] = (key, data, checked)
        self._ahead_bytes[unit] += len(data)
        now = time.monotonic()
        self._ask_at[unit] = min(self._ask_at[unit], now)  # a gap: ask at once

    def _remember(self, unit: str, seq: int, data: bytes) -> None:
        recent = self._recent[unit]
        recent[seq] = frame_digest(data)
        if len(recent) > RECENT_DIGESTS:
            del recent[next(iter(recent))]

    def _accept_frame(self, key: str, data: bytes, unit: str, checked: bool) -> None:
        self._stats["received"] += 1
        self._read_frame(key, data, unit, checked)

    def _read_frame(self, key: str, data: bytes, unit: str, checked: bool) -> None:
        """A frame received: into its member's state, or dropped and counted."""
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
            seen = self._recent[unit].get(frame.seq)
            if seen is not None and seen != frame_digest(data):
                self._bad_frame(
                    unit,
                    "dropped_duplicate",
                    f"{key}: two different frames numbered {frame.seq}",
                    checked,
                )
                return
            self._drop("dropped_duplicate", f"{key}: frame {frame.seq} received twice (replayed?)")
            return
        if frame.seq != m.seq + 1:
            self._drop("dropped_ahead", f"{key}: frame {frame.seq} while {m.seq + 1} is due")
            return
        if frame.promise < m.promise:
            self._bad_frame(
                unit,
                "dropped_malformed",
                f"{key}: promise {frame.promise} goes back from {m.promise}",
                checked,
            )
            return
        if frame.samples.size and frame.samples[0] < max(m.promise, self._taken):
            self._bad_frame(
                unit,
                "dropped_late",
                f"{key}: pulse at sample {int(frame.samples[0])} is before its promise "
                f"(sample {m.promise})",
                checked,
            )
            return
        if m.flags and frame.flags != m.flags:
            self._bad_frame(
                unit, "dropped_malformed", f"{key}: done flags changed after it was done", checked
            )
            return
        m.seq, m.promise, m.flags, m.done_at = frame.seq, frame.promise, frame.flags, frame.done_at
        if frame.samples.size:
            m.pending.append((frame.samples, frame.values))
        self._stats["accepted"] += 1
        self._remember(unit, frame.seq, data)
        now = time.monotonic()
        self._progress_at[unit] = now
        self._ask_gap[unit] = REPAIR_QUIET
        self._ask_at[unit] = now + REPAIR_QUIET
        gone_at = self._gone.get(unit)
        if gone_at is not None and now - gone_at > _LEFT_GRACE:
            self._member_back(unit)  # heard, authenticated, well after it seemed to leave
