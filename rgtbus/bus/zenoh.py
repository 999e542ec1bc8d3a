"""The zenoh bus: each member's frames on ``rgtbus/<run_id>/tx/<unit>``.

Default: one in-process session, peer mode, no listen/connect endpoints, multicast scouting off;
a session's own puts reach its own subscriber, so a single process hears itself. For
cross-process runs pass ``connect``/``listen``/``mode`` (or a zenoh config file or a session),
and ``tls`` for identities under the run's CA (every config: rgtbus.bus.config).

The subscriber callbacks run on zenoh threads and never block: the frame callback is the bus's
gate (``QueueBus._deliver``: size, header and, on a keyed run, tag checks, then a bounded queue),
the hello callback checks key and size and puts into a bounded queue; decoding and bookkeeping
happen in ``wait`` (and ``join``) on the caller's thread. Hellos are answered at a bounded rate.
"""

from __future__ import annotations

import contextlib
import functools
import os
import queue
import socket
import threading
import time
import weakref
from collections.abc import Callable, Sequence
from typing import Any

import zenoh

from rgtbus.bus import keys
from rgtbus.bus.auth import AuthError, check_tag, tag
from rgtbus.bus.base import REPAIR_GAP_MAX, Budget, QueueBus
from rgtbus.bus.certs import process_tls
from rgtbus.bus.config import TlsRun, make_config, zenoh_reason
from rgtbus.bus.hello import (
    MAX_HELLO,
    MAX_PROCESS,
    Hello,
    check_digest,
    encode_hello,
    read_hello,
    view_digest,
)
from rgtbus.bus.join import JoinBarrier, hello_gap, hello_period
from rgtbus.bus.payload import (
    ResendAsk,
    decode_resend,
    encode_resend,
    encode_telemetry,
    max_resend_size,
    sign_telemetry,
)
from rgtbus.errors import BadInput, IOFailure, PeerSilent, RgtbusError

# A declared callback subscriber leaves a non-daemon zenoh thread behind, and the interpreter
# waits for it before atexit handlers run: a bus left open hangs the process at exit
# (docs/zenoh-notes.md).
# threading's own pre-join hook (what concurrent.futures uses) runs early enough to close them.
_open_buses: weakref.WeakSet[ZenohBus] = weakref.WeakSet()
_exit_hook_lock = threading.Lock()
_exit_hook_registered = False


def _close_open_buses() -> None:
    for bus in list(_open_buses):
        with contextlib.suppress(Exception):  # best effort at exit: the alternative is a hang
            bus.close()


def _ensure_exit_hook() -> None:
    global _exit_hook_registered
    with _exit_hook_lock:
        if _exit_hook_registered:
            return
        register = getattr(threading, "_register_atexit", None)
        if register is not None:
            try:
                register(_close_open_buses)
            except RuntimeError:  # already shutting down
                return
        _exit_hook_registered = True


CLOSE_TIMEOUT = 2.0  # seconds; a close that waits longer is waiting for a peer that is gone
_SLOW_CLOSE = "zenoh session did not close within"


def close_session(session: zenoh.Session, timeout: float) -> str | None:
    """Close ``session``, waiting at most ``timeout`` seconds; what went wrong, or None.

    zenoh's close says goodbye on every link and can block for seconds when a peer no longer
    reads (a process stopped with SIGSTOP fills its socket; docs/zenoh-notes.md): a unit that
    has finished must not wait for that. The close goes on in a daemon thread, which never
    holds up the interpreter's exit."""
    outcome: list[str] = []
    done = threading.Event()

    def close() -> None:
        try:
            session.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves it bare
        except Exception as e:  # zenoh's ZError: one readable line
            outcome.append(zenoh_reason(e))
        finally:
            done.set()

    threading.Thread(target=close, name="rgtbus-zenoh-close", daemon=True).start()
    if not done.wait(timeout):
        return f"{_SLOW_CLOSE} {timeout:g} s (a peer no longer answering?)"
    return outcome[0] if outcome else None


def telemetry_key(run_id: str, unit: str) -> str:
    """The key on which ``unit``'s process publishes its log messages."""
    return keys.key(keys.TELEMETRY, run_id, unit)


class TelemetryFeed:
    """A unit process's log messages on zenoh (``encode_telemetry`` frames); a live sink. On a
    keyed run each frame is signed (``sign_telemetry``: the process's nonce, a sequence number,
    an HMAC tag), so ``rgtbus watch --key-file`` shows only what the run's processes said.
    Nothing is encoded, signed or put while no subscriber matches its key: zenoh's matching
    listener says when one comes or goes (a run nobody watches pays nothing a record)."""

    def __init__(
        self,
        publisher: Any,
        sign: Callable[[bytes], bytes] | None = None,
        nonce: bytes = b"",
    ) -> None:
        self.publisher = publisher
        self.closed = False
        self.seq = 0
        self._sign = sign
        self._nonce = nonce
        self._matching = True  # until zenoh says otherwise: as if watched
        self.listener: Any = None
        try:
            self.listener = publisher.declare_matching_listener(self._on_matching)
            self._matching = bool(publisher.matching_status.matching)
        except Exception:  # zenoh cannot say: every message goes out, as if watched
            self._matching = True

    def _on_matching(self, status: Any) -> None:  # zenoh's thread: a flag, never blocks
        self._matching = bool(status.matching)

    def put(self, topic: str, schema: str, data: bytes, t_ns: int) -> None:
        """Publish one log message (signed on a keyed run); nothing once closed, nor while
        nobody watches (a watcher reads the log for what came before it)."""
        if self.closed or not self._matching:
            return
        frame = encode_telemetry(topic, schema, data, t_ns)
        if self._sign is not None:
            self.seq += 1
            frame = sign_telemetry(frame, self._nonce, self.seq, self._sign)
        self.publisher.put(frame)

    def watched(self) -> bool:
        """Whether a subscriber (``rgtbus watch``) matches this feed's key now, as zenoh's
        routing knows it; True if zenoh cannot say."""
        return not self.closed and self._matching


HELLO_QUEUE = 256  # hellos heard, not yet read (more: dropped_overflow; members repeat theirs)
_LATE_ANSWERS_PER_S = 20.0  # answers to hellos heard after the start ("too late")
_ANSWERED_MAX = 4096  # (unit, nonce) pairs remembered as answered


def max_hello(members: Sequence[str]) -> int:
    """The largest hello a member of this run can say: fixed fields, its unit's name, where
    its process runs and a tag (well under 1 KB whatever the roster); larger ones are dropped
    unread (``dropped_oversize``)."""
    return min(MAX_HELLO, 1024 + max((len(u) for u in members), default=0))


RESEND_QUEUE = 256  # resend requests heard, not yet read (more: dropped_overflow)
_ASKS_PER_S = 50.0  # resend requests read a second from one member (more: dropped_rate)
# s: a finished process answers resend requests this long when nobody asks, this long after
# the last request once one came, and at most LINGER_MAX (the run's timeout, where a unit
# process lingers): its last frames may have been lost on the way (ZenohBus.linger)
LINGER = 0.6
LINGER_ASKED = REPAIR_GAP_MAX + 0.5
LINGER_MAX = 10.0


def _check_ask(key: bytes, run_id: str, asker: str, nonce: bytes, body: bytes, got: bytes) -> None:
    """AuthError unless ``got`` is ``asker``'s tag of the resend request ``body``."""
    check_tag(key, "resend", run_id, asker, nonce, body, got)


class ZenohBus(QueueBus):
    """The bus over zenoh (see the module docstring): a session of its own, or one given
    (``session``: then left open for its owner), or options for one (``mode``, ``connect``,
    ``listen``, ``multicast``, ``config``, ``send_patience``: see rgtbus.bus.config's
    ``make_config``; and ``tls``: the run's directory of TLS identities, rgtbus.bus.certs, whose
    certificate of this process's one local unit it proves itself with); ``local`` the members
    this process publishes for."""

    kind = "zenoh"
    OPTIONS = frozenset(
        {
            "local",
            "count_foreign",
            "mode",
            "connect",
            "listen",
            "multicast",
            "config",
            "session",
            "key",
            "send_patience",
            "tls",
        }
    )

    def __init__(
        self,
        run_id: str,
        members: Sequence[str],
        sample_rate: float,
        *,
        local: Sequence[str] | None = None,
        count_foreign: bool = True,
        mode: str | None = None,
        connect: Sequence[str] | None = None,
        listen: Sequence[str] | None = None,
        multicast: bool | None = None,
        config: zenoh.Config | str | os.PathLike[str] | None = None,
        session: zenoh.Session | None = None,
        key: bytes | None = None,
        send_patience: float | None = None,
        tls: str | os.PathLike[str] | None = None,
    ) -> None:
        super().__init__(run_id, members, sample_rate, local=local, key=key)
        self._publishers: dict[str, Any] = {}
        self._telemetry: list[TelemetryFeed] = []
        self._subscriber: Any = None
        self._hello_sub: Any = None
        self._tokens: list[Any] = []  # one liveliness token a local unit
        self._alive_sub: Any = None
        # hellos heard, not yet read: (what was said, when it arrived)
        self._hellos: queue.Queue[tuple[bytes, float]] = queue.Queue(maxsize=HELLO_QUEUE)
        self._last_hello: dict[str, bytes] = {}  # each member's last hello heard, as said
        self.repeated_at: dict[str, float] = {}  # when each member last said it again unchanged
        self.process = f"{socket.gethostname()}:{os.getpid()}"[:MAX_PROCESS]  # who says it
        self._hello_prefix = keys.prefix(keys.HELLO, self.run_id)
        self.max_hello = max_hello(self.members)
        # (this process's units, digest) once the run has started
        self._joined: tuple[tuple[str, ...], str] | None = None
        self._late_answered: set[tuple[str, bytes]] = set()
        self._late_rate = Budget(_LATE_ANSWERS_PER_S, _LATE_ANSWERS_PER_S)
        # resend requests heard, not yet read: (asker, what it said)
        self._asks: queue.Queue[tuple[str, bytes]] = queue.Queue(maxsize=RESEND_QUEUE)
        self._ask_budgets = {u: Budget(_ASKS_PER_S, _ASKS_PER_S) for u in self.members}
        self._resend_prefix = keys.prefix(keys.RESEND, self.run_id)
        self._resend_sub: Any = None
        self._resend_pub: Any = None
        self._identified = self._key is not None or tls is not None
        self._via_router = False  # whether the join found a router (_link_up)
        self._owns_session = session is None
        if session is None:
            tls_run = None
            if tls is not None:
                tls_run = TlsRun(process_tls(tls, self.local), self.members, self.run_id)
            cfg = make_config(
                mode=mode,
                connect=connect,
                listen=listen,
                multicast=multicast,
                config=config,
                send_patience=send_patience,
                tls=tls_run,
            )
            try:
                session = zenoh.open(cfg)
            except Exception as e:
                given = [
                    f"{k} {v if isinstance(v, str) else list(v)}"
                    for k, v in (
                        ("mode", mode),
                        ("connect", connect),
                        ("listen", listen),
                        ("tls", None if tls is None else [os.fspath(tls)]),
                    )
                    if v is not None
                ]
                if config is not None:
                    given.insert(
                        0,
                        f"config {os.fspath(config)!r}"
                        if not isinstance(config, zenoh.Config)
                        else "config",
                    )
                raise IOFailure(
                    f"cannot open zenoh session ({', '.join(given) or 'mode peer'}): "
                    f"{zenoh_reason(e)}"
                ) from None
        elif any(v is not None for v in (mode, connect, listen, multicast, config, tls)):
            raise BadInput("zenoh bus: pass either a session or session options, not both")
        self.session = session
        try:
            # Count foreign runs: listen one level wider than our own run's keys.
            sub_key = keys.every_unit(keys.TX, None if count_foreign else self.run_id)
            deliver = self._deliver  # the gate: bounded work, never blocks
            self._subscriber = session.declare_subscriber(
                sub_key, lambda s: deliver(str(s.key_expr), s.payload)
            )
            ask_gate = self._ask_gate  # the same: bounded work, never blocks
            self._resend_sub = session.declare_subscriber(
                keys.every_unit(keys.RESEND, self.run_id),
                lambda s: ask_gate(str(s.key_expr), s.payload),
            )
            for unit in self.local:
                # BLOCK: a frame must never be lost to congestion (the run would stall);
                # express: no batching delay between a frame's publish and the peers' wait.
                self._publishers[unit] = session.declare_publisher(
                    self._keys[unit],
                    congestion_control=zenoh.CongestionControl.BLOCK,
                    express=True,
                )
            if self.local:  # the same for what asks for lost frames (a flood congests links)
                self._resend_pub = session.declare_publisher(
                    keys.key(keys.RESEND, self.run_id, self.local[0]),
                    congestion_control=zenoh.CongestionControl.BLOCK,
                    express=True,
                )
        except BaseException:
            self._closed = True
            self._close_transport()
            raise
        _ensure_exit_hook()
        _open_buses.add(self)

    # -- telemetry for watchers ----------------------------------------------------------------

    def telemetry_feed(self, unit: str) -> TelemetryFeed:
        """Where unit ``unit``'s process publishes every message it logs, for ``rgtbus watch``
        (``McapRecorder.live``): ``rgtbus/<run>/telemetry/<unit>``. Watchers only subscribe,
        so they are never members and cannot hold the run back."""
        self._check_member(unit)
        pub = self.session.declare_publisher(
            telemetry_key(self.run_id, unit),
            # DROP: a slow watcher loses telemetry, never delays the run's own frames
            congestion_control=zenoh.CongestionControl.DROP,
        )
        sign = None
        if self._key is not None:
            secret, run_id, nonce = self._key, self.run_id, self.nonce

            def sign(body: bytes) -> bytes:
                return tag(secret, "telemetry", run_id, unit, nonce, body)

        feed = TelemetryFeed(pub, sign, self.nonce)
        self._telemetry.append(feed)
        return feed

    # -- joining a cross-process run --------------------------------------------------------

    def hello_key(self, unit: str) -> str:
        """The key of ``unit``'s hellos in this run."""
        return keys.key(keys.HELLO, self.run_id, unit)

    def join(self, units: str | Sequence[str], digest: str, timeout: float = 10.0) -> None:
        """Barrier before the run: wait until every member is up, on the same scenario.
        ``units``: the units this process runs (one, or several: each says its hello, all with
        the process's nonce, and counts the others of its process as heard).

        Each process declares a liveliness token ``rgtbus/<run>/alive/<unit>`` and says a hello
        (rgtbus.bus.hello: its unit, scenario digest, nonce, where it runs, and its view: a digest
        of every member's nonce as it heard them, once it heard all) 50, 100, 200 ms ... apart and
        then every ``hello_period`` (longer in a larger run; ``hello_gap``), and once a round
        more when a hello brought news (one answer for all of
        it), until every member's hello holds our view (it was said after our nonce, so it is fresh,
        not a recording) and says it is ready (it has such a hello from everyone). A hello is the
        same size whatever the roster; one said again unchanged is not read again. Data and
        subscriber declarations share a link in order, so a hello from a peer proves its tx
        subscriber is declared: nobody's first frame can be lost. Refused: a member on another
        scenario or seed (digest differs), a run that already started (a late joiner), and two live
        processes claiming one unit: every process that hears both before it said it is ready
        stops its join, naming the unit and both claimants (``JoinBarrier.claim``); one that said it
        is ready takes the later one as late, unless a member shows it never was (``JoinBarrier``:
        either all open with one view, or none). Running members answer late hellos (a later
        claimant of one of their own units too) from ``wait``.
        On a keyed run only hellos with a valid tag count; the nonces heard are what later frames
        are checked with, from the moment a member's hello proves fresh (it starts sending only once
        we said we are ready, after that).
        """
        mine = [units] if isinstance(units, str) else list(units)
        if not mine:
            raise BadInput("join: no unit to join as")
        for u in mine:
            self._check_member(u)
        if len(set(mine)) != len(mine):
            raise BadInput(f"join: a unit named twice in {mine}")
        check_digest(digest)
        self._declare_presence(mine[0])  # the process's voice for what it says once
        period = hello_period(len(self.members))
        barrier = JoinBarrier(self, mine, digest, period)
        deadline = time.monotonic() + timeout
        said, unprompted = -period, 0
        stop_at: float | None = None  # a conflict: said on a while, for all to hear it too
        while True:
            now = time.monotonic()
            gap = hello_gap(period, unprompted)
            if barrier.news or now - said >= gap:
                unprompted += not barrier.news
                barrier.say()
                said = now
            self._hear_round(barrier, now + gap / 4)
            if barrier.conflict is not None:
                stop_at = stop_at or time.monotonic() + 4 * period
                if time.monotonic() >= stop_at:
                    raise BadInput(barrier.conflict)
                continue
            if barrier.done():
                barrier.say(ready=True)
                # What is queued now was said before the start (a link keeps its order).
                while not self._hellos.empty():
                    self._hellos.get_nowait()
                self._nonces.update({u: barrier.nonces[u] for u in barrier.others})
                self._joined = (tuple(mine), digest)
                self._via_router = self._routers() > 0
                self._forget_gone()  # a claimant that left before the start is no member
                return
            if time.monotonic() > deadline:
                # nobody heard at all: the units are most likely not connected to each other
                # (e.g. each connected only to a watcher, which relays nothing between units)
                alone = not barrier.nonces.keys() & barrier.others
                hint = (
                    "; no other unit was heard at all: connect the units to a router (rgtbus "
                    "router -l ENDPOINT, units -e ENDPOINT) or to each other; a watcher "
                    "(rgtbus watch) relays nothing between units"
                    if alone
                    else ""
                )
                # a member that stopped for a conflict before it was ready leaves those that
                # were waiting for it: the claim they heard once ready is why
                rival = f"; heard once ready: {barrier.rival}" if barrier.rival else ""
                raise PeerSilent(
                    f"joining run {self.run_id!r} timed out after {timeout:g} s: no answer from "
                    f"{', '.join(barrier.missing())}{hint}{rival}"
                )

    def _declare_presence(self, unit: str) -> None:
        """The hello subscriber, and the liveliness token ``rgtbus/<run>/alive/<unit>``."""
        if self._hello_sub is None:
            hello_gate = self._hello_gate
            self._hello_sub = self.session.declare_subscriber(
                keys.every_unit(keys.HELLO, self.run_id),
                lambda s: hello_gate(str(s.key_expr), s.payload),
            )
        try:
            liveliness = self.session.liveliness()
            self._tokens.append(liveliness.declare_token(keys.key(keys.ALIVE, self.run_id, unit)))
            if self._alive_sub is None:
                alive_prefix, gone = keys.prefix(keys.ALIVE, self.run_id), self._member_gone
                back = self._member_back
                delete = zenoh.SampleKind.DELETE

                def on_token(s: zenoh.Sample) -> None:  # on zenoh's thread: never blocks
                    key = str(s.key_expr)
                    if not key.startswith(alive_prefix):
                        return
                    unit = key[len(alive_prefix) :]
                    if s.kind == delete:
                        gone(unit)
                    else:  # declared (again: its session back after a hiccup)
                        back(unit)

                # history: a member's token that reached the router before this subscription
                # did is reported too, so its end is seen (without it, such a token ends unseen)
                self._alive_sub = liveliness.declare_subscriber(
                    keys.every_unit(keys.ALIVE, self.run_id), on_token, history=True
                )
        except Exception as e:  # presence is a shortcut: the run's timeout still holds
            self._notes.append(f"liveliness not declared: {e}")

    def _hear_round(self, barrier: JoinBarrier, until: float) -> None:
        """The hellos heard until ``until`` (monotonic), each to the barrier, which may open
        before then."""
        while (left := until - time.monotonic()) > 0:
            try:
                raw, heard_at = self._hellos.get(timeout=left)
            except queue.Empty:
                break
            h = self._read_hello(raw)
            if h is None:
                continue
            if h.unit in barrier.local:
                if h.nonce != self.nonce:  # another process says it is one of our units
                    barrier.claim(h, heard_at)
                continue
            if barrier.hear(h, heard_at):
                break

    def say_hello(
        self,
        unit: str,
        digest: str,
        view: bytes,
        *,
        ready: bool,
        started: bool = False,
        to: bytes = b"",
    ) -> None:
        h = Hello(unit, digest, self.nonce, view, started, self._taken, ready, self.process, to)
        self.session.put(self.hello_key(unit), encode_hello(h, self.run_id, self._key))

    def accept(self, unit: str, nonce: bytes) -> None:
        """Frames of ``unit`` are checked with ``nonce`` from now on (its claimant heard fresh
        in the join: ``JoinBarrier``)."""
        self._nonces[unit] = nonce

    def _read_hello(self, raw: bytes) -> Hello | None:
        try:
            return read_hello(raw, self.run_id, self._member_set, self._key)
        except AuthError as e:
            self._drop("dropped_unauthenticated", f"hello: {e}")
        except RgtbusError as e:
            self._drop("dropped_malformed", f"hello: {e} ({bytes(raw[:40])!r})")
        return None

    def wait(
        self, beyond: int, timeout: float = 5.0, stop: Callable[[], bool] | None = None
    ) -> int:
        """As ``QueueBus.wait``, answering late hellos and resend requests while it waits once
        the run has started."""
        self._between_frames()
        return super().wait(beyond, timeout, stop)

    def _between_frames(self) -> None:
        if self._joined is not None:
            self._answer_late_hellos()
            self._answer_asks()

    # -- resend requests (QueueBus._repair) ---------------------------------------------------

    def _ask_resend(self, unit: str, first: int) -> None:
        if not self.local or self._closed:
            return
        asker = self.local[0]
        sign = None
        if self._key is not None:
            secret, run_id, nonce = self._key, self.run_id, self.nonce

            def sign(body: bytes) -> bytes:
                return tag(secret, "resend", run_id, asker, nonce, body)

        data = encode_resend(ResendAsk(unit, first), sign=sign)
        with contextlib.suppress(Exception):  # a request lost is asked again
            self._resend_pub.put(data)

    def _ask_gate(self, key: str, payload: Any) -> None:
        """The resend subscriber's callback (a zenoh thread, never blocks): a member's key
        other than ours, at most ``max_resend_size`` bytes, within the asker's rate, room in
        the queue; else dropped and counted (``received`` counts frames only)."""
        try:
            asker = key[len(self._resend_prefix) :] if key.startswith(self._resend_prefix) else ""
            if asker not in self._member_set:
                why = "resend request on a non-member's key"
                self._gate_drop("dropped_foreign", key, why, False)
                return
            if asker in self.local:
                return  # our own request, heard back
            size = len(payload)
            if size > max_resend_size():
                self._gate_drop("dropped_oversize", key, f"resend request of {size} bytes", False)
                return
            with self._gate_lock:
                allowed = self._ask_budgets[asker].take()
            if not allowed:
                self._gate_drop(
                    "dropped_rate", key, f"more than {_ASKS_PER_S:g} resend requests a second",
                    False,
                )  # fmt: skip
                return
            raw = payload if isinstance(payload, bytes) else payload.to_bytes()
            self._asks.put_nowait((asker, raw))
        except queue.Full:
            self._gate_drop("dropped_overflow", key, "resend request queue full", False)
        except Exception as e:  # a callback must not raise (docs/zenoh-notes.md)
            self._gate_drop("dropped_malformed", key, f"resend request: {type(e).__name__}", False)

    def _answer_asks(self) -> int:
        """The resend requests heard, each read (its tag checked on a keyed run) and answered
        (``QueueBus._resend``); how many were read."""
        read = 0
        while True:
            try:
                asker, raw = self._asks.get_nowait()
            except queue.Empty:
                return read
            read += 1
            check = None
            if self._key is not None:
                nonce = self._nonces.get(asker)
                if nonce is None:
                    self._drop("dropped_unauthenticated", f"resend request: {asker!r} unheard")
                    continue
                check = functools.partial(_check_ask, self._key, self.run_id, asker, nonce)

            try:
                ask = decode_resend(raw, check=check)
            except AuthError as e:
                self._drop("dropped_unauthenticated", f"resend request of {asker!r}: {e}")
                continue
            except RgtbusError as e:
                self._drop("dropped_malformed", f"resend request of {asker!r}: {e}")
                continue
            if ask.unit in self._history:
                self._resend(ask.unit, ask.first, asker)

    def linger(self, at_most: float = LINGER_MAX) -> None:
        """A finished run: answer resend requests a while before closing, since a member whose
        last frames were lost on the way asks for them again and nobody else holds them:
        ``LINGER`` s if nobody asks, and once one did, until ``LINGER_ASKED`` s pass without a
        request (an asker waits up to ``REPAIR_GAP_MAX`` s between two), every other member
        has left (it had all it needed), or ``at_most`` s in all."""
        if self._closed or self._joined is None or set(self.local) >= self._member_set:
            return
        start = last = time.monotonic()
        quiet = LINGER
        others = self._member_set - set(self.local)
        while (now := time.monotonic()) - start < at_most and now - last < quiet:
            with self._gate_lock:
                if others <= self._gone.keys():
                    return
            if self._answer_asks():
                last, quiet = time.monotonic(), LINGER_ASKED
            time.sleep(0.02)

    def _routers(self) -> int:
        """How many routers this session reaches now (0 if zenoh cannot say)."""
        try:
            return len(list(self.session.info.routers_zid()))
        except Exception:
            return 0

    def _link_up(self) -> bool:
        # Through a router, losing it is being cut off (every member seems to leave at once,
        # and comes back with the link); in a mesh, a peer gone is a member gone.
        return not self._via_router or self._routers() > 0

    def _answer_late_hellos(self) -> None:
        assert self._joined is not None
        mine, digest = self._joined
        unit = mine[0]
        while True:
            try:
                raw, _ = self._hellos.get_nowait()
            except queue.Empty:
                return
            h = self._read_hello(raw)
            if h is None or h.started or (h.unit in mine and h.nonce == self.nonce):
                continue  # an answer, or our own hello
            if h.ready and self._nonces.get(h.unit) == h.nonce:
                continue  # a member's last barrier hello, not a late joiner
            # A late joiner (or a replay of an old hello): answered once per (unit, nonce), at
            # a bounded rate; a joiner repeats its hello until answered.
            why = (
                f"hello from {h.unit!r} after the start (nonce {h.nonce.hex()[:8]}), heard "
                "again or too fast: not answered (replayed?)"
            )
            pair = (h.unit, h.nonce)
            if not self._may_answer(self._late_answered, pair, self._late_rate.take, why):
                continue
            with self._gate_lock:
                self._notes.append(f"hello from {h.unit!r} after the start: refused")
            view = view_digest(self.run_id, digest, self._nonces)
            self.say_hello(unit, digest, view, ready=True, started=True, to=h.nonce)

    def _may_answer(
        self, answered: set[Any], news: object, allowed: Callable[[], bool], why: str
    ) -> bool:
        """Whether a hello that brings ``news`` is answered now: not when that was answered
        already (a replay) or ``allowed()`` says no (asked only then: it may spend a token);
        such a hello is counted as ``hellos_unanswered``, ``why`` its note. At most
        ``_ANSWERED_MAX`` answers are remembered."""
        if news in answered or not allowed():
            self._drop("hellos_unanswered", why)
            return False
        if len(answered) < _ANSWERED_MAX:
            answered.add(news)
        return True

    def _hello_gate(self, key: str, payload: Any) -> None:
        """The hello subscriber's callback (a zenoh thread, never blocks): a member's key, at
        most ``max_hello`` bytes, room in the queue; else dropped and counted."""
        try:
            who = key[len(self._hello_prefix) :] if key.startswith(self._hello_prefix) else ""
            if who not in self._member_set:
                self._gate_drop("dropped_foreign", key, "hello on a non-member's key", False)
                return
            size = len(payload)
            if size > self.max_hello:
                self._gate_drop(
                    "dropped_oversize",
                    key,
                    f"hello of {size} bytes, the run's bound is {self.max_hello}",
                    False,
                )
                return
            raw = payload if isinstance(payload, bytes) else payload.to_bytes()
            if self._last_hello.get(who) == raw:  # said again, unchanged: nothing new to read,
                self.repeated_at[who] = time.monotonic()  # but its claimant is still there
                return
            self._last_hello[who] = raw
            self._hellos.put_nowait((raw, time.monotonic()))
        except queue.Full:
            self._gate_drop("dropped_overflow", key, "hello queue full", False)
        except Exception as e:  # a callback must not raise (docs/zenoh-notes.md)
            self._gate_drop("dropped_malformed", key, f"hello: {type(e).__name__}", False)

    def _send(self, key: str, data: bytes) -> None:
        # Our own units' keys go through their declared publishers; anything else (put_raw)
        # through the session.
        pub = (
            self._publishers.get(key[len(self._prefix) :]) if key.startswith(self._prefix) else None
        )
        if pub is not None:
            pub.put(data)
        else:
            self.session.put(key, data)

    def _close_transport(self) -> None:
        # Subscriber first so no callback runs while the rest goes away; then the session
        # (a declared callback subscriber keeps the interpreter from exiting:
        # docs/zenoh-notes.md).
        _open_buses.discard(self)
        errors: list[str] = []
        for feed in self._telemetry:
            feed.closed = True  # the recorder may still log after the bus is gone: dropped
        entities = [
            self._hello_sub,
            self._resend_sub,
            self._resend_pub,
            self._subscriber,
            *self._publishers.values(),
            *(f.listener for f in self._telemetry),
            *(f.publisher for f in self._telemetry),
            self._alive_sub,
            *self._tokens,
        ]
        self._telemetry = []
        self._tokens = []
        self._hello_sub = self._alive_sub = self._resend_sub = self._resend_pub = None
        self._subscriber = None
        self._publishers = {}
        for ent in entities:
            if ent is None:
                continue
            try:
                ent.undeclare()
            except Exception as e:  # session may already be closed by its owner
                errors.append(str(e))
        if self._owns_session and getattr(self, "session", None) is not None:
            problem = close_session(self.session, CLOSE_TIMEOUT)
            if problem and problem.startswith(_SLOW_CLOSE):
                self.close_problem = problem  # the run is over and whole: a warning, no error
            elif problem:
                errors.append(problem)
        if errors and self._owns_session:
            raise BadInput(f"closing zenoh bus of run {self.run_id!r}: {errors[0]}")
