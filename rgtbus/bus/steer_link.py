"""Steering a run across processes (``--control`` on a launch): the requests, the changes and
their receipts on zenoh, and each process's side of them (``rgtbus.engine.steering.Requests``).

    rgtbus/<run>/steer/watch      a watcher's requests (``rgtbus watch --control``)
    rgtbus/<run>/change/<lead>    the changes the steering process placed (sample, order)
    rgtbus/<run>/have/<unit>      a process's receipt of a change (under its first unit)

One process steers: the one that runs the roster's first unit (``lead``). It takes the
watcher's requests, places each at a window boundary no other process has passed (no earlier
than the least promise its own members sent: every other process's horizon is below it) and
announces it; until every other process has it, its members promise nothing past that sample
(``Steering.hold``), so none can pass it unawares. Every process then applies the change at
that sample: the same instant everywhere, which the lockstep gives. A process acknowledges a
change as soon as it hears it (on a thread of its own, not zenoh's), and the steering process
announces again what is not acknowledged.

Bounded whatever arrives: a payload over ``MAX_MESSAGE`` bytes, one that is not the JSON of
its kind, or (a keyed run) one whose HMAC tag fails is dropped and counted; at most
``MAX_QUEUED`` requests and changes wait. On a keyed run every payload is signed under the
run's key by its sender (a nonce of its own, a sequence number): only the run's processes and a
watcher holding the key can steer. On a TLS run the access control lets only the watcher's
certificate put requests, and each unit process put only under its own names
(``rgtbus.bus.config``).
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import threading
import time
from collections.abc import Sequence
from typing import Any

from rgtbus.bus import keys
from rgtbus.bus.auth import NONCE_SIZE, TAG_SIZE, AuthError, check_tag, tag
from rgtbus.steering import Request

MAX_MESSAGE = 16 << 10  # bytes of a request, change or receipt
MAX_QUEUED = 1024  # requests or changes not yet taken by the run
RESEND = 0.5  # s between two announcements of a change some process has not acknowledged


def _request_fields(req: Request) -> dict[str, Any]:
    return {
        "kind": req.kind, "name": req.name, "value": req.value, "who": req.who,
        "refused": req.refused, "at": req.at, "seq": req.seq,
    }  # fmt: skip


def _request_of(d: Any) -> Request:
    """A request from its JSON fields (ValueError: not one)."""
    if not isinstance(d, dict) or d.get("kind") not in ("parameter", "service"):
        raise ValueError("not a request")
    name, who = d.get("name"), d.get("who")
    if not isinstance(name, str) or not isinstance(who, str):
        raise ValueError("a request's name and who are text")
    at, seq, refused = d.get("at"), d.get("seq"), d.get("refused")
    for v in (at, seq):
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 0):
            raise ValueError("a change's sample and order are whole numbers")
    if refused is not None and not isinstance(refused, str):
        raise ValueError("a refusal is text")
    return Request(d["kind"], name, d.get("value"), who, refused=refused, at=at, seq=seq)


class Signer:
    """Signs and checks the payloads of one sender kind under a run's key (None: an open run:
    payloads travel as they are). A payload is ``nonce ‖ body ‖ tag``."""

    def __init__(self, key: bytes | None, run_id: str) -> None:
        self.key, self.run_id = key, run_id
        self.nonce = os.urandom(NONCE_SIZE)

    def seal(self, kind: str, unit: str, body: bytes) -> bytes:
        if self.key is None:
            return body
        return self.nonce + body + tag(self.key, kind, self.run_id, unit, self.nonce, body)

    def open(self, kind: str, unit: str, payload: bytes) -> bytes:
        """The body of a payload, its tag checked (AuthError)."""
        if self.key is None:
            return payload
        if len(payload) < NONCE_SIZE + TAG_SIZE:
            raise AuthError(f"{kind} of {unit!r}: too short to hold a tag")
        nonce, body, got = payload[:NONCE_SIZE], payload[NONCE_SIZE:-TAG_SIZE], payload[-TAG_SIZE:]
        check_tag(self.key, kind, self.run_id, unit, nonce, body, got)
        return body


class SteerLink:
    """One unit process's side of steering a run across processes (module docstring): the
    ``Requests`` its world's ``Steering`` takes. ``session``: its zenoh session; ``local``: its
    units; ``members``: the roster; ``key``: the run's secret (None: open)."""

    def __init__(
        self,
        session: Any,
        run_id: str,
        local: Sequence[str],
        members: Sequence[str],
        key: bytes | None = None,
    ) -> None:
        self.session, self.run_id = session, run_id
        self.local, self.members = tuple(local), tuple(members)
        self.lead = members[0]
        self.leading = self.lead in self.local
        self.me = self.local[0]
        self.signer = Signer(key, run_id)
        self._cond = threading.Condition()
        self._queue: list[Request] = []
        self._seen: set[int] = set()  # changes heard (a follower's)
        self._acked: dict[int, set[str]] = {}  # change -> the units whose processes have it
        self._announced: dict[int, bytes] = {}  # change -> its payload, until acknowledged
        self._closed = False
        self.dropped: dict[str, int] = {"oversize": 0, "unreadable": 0, "auth": 0, "overflow": 0}
        self._acks: queue.SimpleQueue[int | None] = queue.SimpleQueue()
        self._subs: list[Any] = []
        change_key = keys.key(keys.CHANGE, run_id, self.lead)
        if self.leading:
            self._subs.append(
                session.declare_subscriber(steer_key(run_id), lambda s: self._on_request(s.payload))
            )
            self._subs.append(
                session.declare_subscriber(
                    keys.every_unit(keys.HAVE, run_id), lambda s: self._on_have(s.payload)
                )
            )
            self._change_pub = session.declare_publisher(change_key)
        else:
            self._subs.append(
                session.declare_subscriber(change_key, lambda s: self._on_change(s.payload))
            )
            self._have_pub = session.declare_publisher(keys.key(keys.HAVE, run_id, self.me))
            self._acker = threading.Thread(target=self._ack_loop, name="steer-ack", daemon=True)
            self._acker.start()

    # -- zenoh's threads: never block --------------------------------------------------------

    def _read(self, kind: str, unit: str, payload: Any) -> Any:
        raw = bytes(payload.to_bytes() if hasattr(payload, "to_bytes") else payload)
        if len(raw) > MAX_MESSAGE:
            self.dropped["oversize"] += 1
            return None
        try:
            return json.loads(self.signer.open(kind, unit, raw))
        except AuthError:
            self.dropped["auth"] += 1
        except ValueError:
            self.dropped["unreadable"] += 1
        return None

    def _put(self, req: Request) -> None:
        with self._cond:
            if len(self._queue) >= MAX_QUEUED:
                self.dropped["overflow"] += 1
                return
            self._queue.append(req)
            self._cond.notify_all()

    def _on_request(self, payload: Any) -> None:
        d = self._read("steer", keys.WATCHER, payload)
        try:
            req = _request_of(d)
        except ValueError:
            self.dropped["unreadable"] += d is not None
            return
        self._put(Request(req.kind, req.name, req.value, req.who, refused=req.refused))

    def _on_change(self, payload: Any) -> None:
        d = self._read("change", self.lead, payload)
        try:
            req = _request_of(d)
        except ValueError:
            self.dropped["unreadable"] += d is not None
            return
        if req.at is None or req.seq is None:
            self.dropped["unreadable"] += 1
            return
        self._acks.put(req.seq)  # again, if heard again: its receipt may have been lost
        with self._cond:
            if req.seq in self._seen:
                return
            self._seen.add(req.seq)
        self._put(req)

    def _on_have(self, payload: Any) -> None:
        got = self._read_have(payload)
        if got is None:
            return
        units, seq = got
        with self._cond:
            if seq in self._acked:
                self._acked[seq].update(units)
                self._cond.notify_all()

    def _read_have(self, payload: Any) -> tuple[list[str], int] | None:
        """A receipt: the units of the process that has change ``seq``, and ``seq``."""
        raw = bytes(payload.to_bytes() if hasattr(payload, "to_bytes") else payload)
        if len(raw) > MAX_MESSAGE:
            self.dropped["oversize"] += 1
            return None
        try:  # who sent it is in the body, which its tag binds to it
            body = raw if self.signer.key is None else raw[NONCE_SIZE:-TAG_SIZE]
            d = json.loads(body)
            unit, seq, units = d["unit"], d["seq"], d["units"]
            if unit not in self.members or isinstance(seq, bool) or not isinstance(seq, int):
                raise ValueError("not a receipt")
            if not isinstance(units, list):
                raise ValueError("not a receipt")
            self.signer.open("have", unit, raw)
        except AuthError:
            self.dropped["auth"] += 1
            return None
        except (ValueError, KeyError, TypeError):
            self.dropped["unreadable"] += 1
            return None
        return [u for u in units if u in self.members], seq

    # -- a follower's receipts, from a thread of its own ----------------------------------------

    def _ack_loop(self) -> None:
        while True:
            seq = self._acks.get()
            if seq is None:
                return
            body = json.dumps({"unit": self.me, "seq": seq, "units": list(self.local)})
            try:
                self._have_pub.put(self.signer.seal("have", self.me, body.encode()))
            except Exception:  # the session is closing: the run is ending
                return

    # -- the run's side (``Requests``) ----------------------------------------------------------

    def take(self) -> list[Request]:
        with self._cond:
            out, self._queue = self._queue, []
            return out

    def wait(self, timeout: float) -> None:
        with self._cond:
            if not self._queue:
                self._cond.wait(timeout)

    def clock(self, t_ns: int, pace: float | None, running: bool) -> None:
        """No view of its own: the watcher serves the run as it hears it."""

    def announce(self, req: Request) -> None:
        """The steering process's change, to every other process."""
        assert req.seq is not None
        payload = self.signer.seal("change", self.lead, json.dumps(_request_fields(req)).encode())
        with self._cond:
            self._acked[req.seq] = set()
            self._announced[req.seq] = payload
        self._change_pub.put(payload)

    def settle(self, seqs: Sequence[int], timeout: float) -> list[str]:
        """Wait until every other process has the changes ``seqs`` (announced again every
        ``RESEND`` s); the units of the processes that did not say so within ``timeout``."""
        others = {u for u in self.members if u not in self.local}
        deadline = time.monotonic() + timeout
        resend = time.monotonic() + RESEND
        with self._cond:
            while True:
                missing = set()
                for seq in seqs:
                    missing |= others - self._acked.get(seq, set())
                now = time.monotonic()
                if not missing or now >= deadline:
                    break
                if now >= resend:
                    for seq in seqs:
                        if seq in self._announced:
                            self._change_pub.put(self._announced[seq])
                    resend = now + RESEND
                self._cond.wait(min(resend, deadline) - now)
            for seq in seqs:
                self._announced.pop(seq, None)
                self._acked.pop(seq, None)
        return sorted(missing)

    def close(self) -> None:
        """No more requests or changes are taken; the receipts' thread ends."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        if not self.leading:
            self._acks.put(None)

    def undeclare(self) -> None:
        """Its subscribers and publishers go (before the session closes)."""
        for sub in self._subs:
            with contextlib.suppress(Exception):  # the session is closing already
                sub.undeclare()


def request_payload(req: Request, signer: Signer) -> bytes:
    """A watcher's request as it goes on ``rgtbus/<run>/steer/watch`` (signed on a keyed run)."""
    return signer.seal("steer", keys.WATCHER, json.dumps(_request_fields(req)).encode())


def steer_key(run_id: str) -> str:
    """Where a watcher puts its requests."""
    return keys.key(keys.STEER, run_id, keys.WATCHER)
