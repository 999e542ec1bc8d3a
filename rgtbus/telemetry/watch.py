"""A watcher of a cross-process run (a telemetry tool over the bus: the telemetry layer sits above
the bus, docs/engine.md): it joins the run's zenoh network and hears what every unit
process logs (``rgtbus/<run>/telemetry/<unit>``, rgtbus.bus.payload telemetry frames).

A watcher is never a member: it declares no hello, token or publisher, so the lockstep neither
waits for it nor notices it leave. What it shows is checked and bounded, whoever publishes on
the telemetry keys (``drops`` counts each reason):

* with ``key`` (the run's ``--key-file``) only signed telemetry with a valid tag from the unit
  its key names is shown (``unauthenticated`` otherwise), each process's sequence numbers only
  going up (``duplicate``); without a key, signed telemetry is not shown (``signed``: the watcher
  cannot check it);
* a frame must decode (``malformed``) and be at most ``MAX_FRAME`` bytes (``oversize``);
* its topic must be one of the recorder's, under the recorder's schema, or ``/trace/<unit>`` of
  the unit that published it, at most ``MAX_TRACES`` such topics (``topic``): forged topics never
  become channels;
* at most ``MAX_RUNS`` run ids and ``MAX_STREAMS`` (run, unit) senders are remembered.

The zenoh callback never blocks: it checks, and hands the message to ``sink.put`` (a LiveView
only queues it).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Sequence
from typing import Any

import zenoh

from rgtbus.bus import keys
from rgtbus.bus.auth import AuthError, check_key, check_tag
from rgtbus.bus.certs import WATCH, check_tls
from rgtbus.bus.config import TlsRun, make_config, zenoh_reason
from rgtbus.bus.payload import decode_telemetry, is_signed_telemetry, open_signed_telemetry
from rgtbus.bus.steer_link import Signer, request_payload, steer_key
from rgtbus.bus.zenoh import close_session
from rgtbus.errors import BadInput, IOFailure
from rgtbus.steering import Request
from rgtbus.telemetry import topics
from rgtbus.telemetry.control import Controller
from rgtbus.telemetry.recorder import LiveSink
from rgtbus.telemetry.records import is_trace_topic, trace_topic

MAX_FRAME = 4 << 20  # bytes: no logged message comes near it
MAX_TRACES = 1024  # /trace/<unit> topics served (one per unit: far more than a run has)
MAX_RUNS = 64  # run ids remembered (for the summary line)
MAX_WAITING = 1024  # steering requests held until a run is heard (the oldest go)
MAX_STREAMS = 4096  # (run, unit) senders whose sequence numbers are followed
DROPS = ("malformed", "oversize", "unauthenticated", "signed", "duplicate", "topic")
_TRACE_SCHEMA = topics.schema_for(trace_topic("x"))


class Watcher:
    """Subscribes to the telemetry of run ``run_id`` (every run: ``*``) and passes it on. Over
    TLS (``tls``: the run's directory of identities) it proves itself with the watcher's
    certificate, under the access control of the run's ``roster``."""

    def __init__(
        self,
        sink: LiveSink,
        *,
        run_id: str = "*",
        key: bytes | None = None,
        tls: str | os.PathLike[str] | None = None,
        roster: Sequence[str] = (),
        **zenoh_options: Any,
    ) -> None:
        if not run_id or any(c in run_id for c in "/?#$") or (run_id != "*" and "*" in run_id):
            raise BadInput(f"--run {run_id!r}: not a run id")
        self.sink = sink
        self.key = check_key(key)
        self.received = 0
        self.drops = dict.fromkeys(DROPS, 0)
        self.last_heard = time.monotonic()
        self.heard = threading.Event()  # set at the first message
        self.runs: set[str] = set()
        self._run_id = run_id
        self._closing = threading.Event()
        self._forwarder: threading.Thread | None = None
        self.forwarded = 0  # steering requests put
        self._lock = threading.Lock()  # zenoh may call back from several threads
        self._streams: dict[tuple[str, str], tuple[bytes, int]] = {}  # -> (nonce, last seq)
        self._traces: set[str] = set()
        tls_run = None
        if tls is not None:
            if not roster:
                raise BadInput("--tls: a watcher needs the run's roster (give --scenario)")
            run = None if run_id == "*" else run_id
            tls_run = TlsRun(check_tls(tls, WATCH), tuple(roster), run)
        config = make_config(**zenoh_options, tls=tls_run)  # its own errors are one line already
        try:
            self.session = zenoh.open(config)
        except Exception as e:
            raise IOFailure(f"cannot open zenoh session: {zenoh_reason(e)}") from None
        self._sub = self.session.declare_subscriber(
            keys.every_unit(keys.TELEMETRY, run_id), self._on_sample
        )

    @property
    def dropped(self) -> int:
        """Frames dropped, every reason."""
        return sum(self.drops.values())

    def _drop(self, why: str) -> None:
        with self._lock:
            self.drops[why] += 1

    def _on_sample(self, sample: Any) -> None:
        try:
            self._take(str(sample.key_expr), sample.payload)
        except Exception:  # a callback must not raise (docs/zenoh-notes.md)
            self._drop("malformed")

    def _take(self, key: str, payload: Any) -> None:
        _, run, _, unit = key.split("/", 3)  # rgtbus/<run>/telemetry/<unit>
        if len(payload) > MAX_FRAME:
            self._drop("oversize")
            return
        raw = payload.to_bytes()
        stream = None
        if self.key is not None:
            if not is_signed_telemetry(raw):
                self._drop("unauthenticated")
                return
            secret = self.key

            def check(nonce: bytes, body: bytes, got: bytes) -> None:
                check_tag(secret, "telemetry", run, unit, nonce, body, got)

            try:
                nonce, seq, raw = open_signed_telemetry(raw, check)
            except AuthError:
                self._drop("unauthenticated")
                return
            except ValueError:
                self._drop("malformed")
                return
            stream = (run, unit), nonce, seq
        elif is_signed_telemetry(raw):
            self._drop("signed")  # the run's, surely, but not to be shown unchecked
            self._heard()  # --idle-exit: the run is still talking
            return
        try:
            topic, schema, data, t_ns = decode_telemetry(raw)
        except ValueError:
            self._drop("malformed")
            return
        if topic in topics.TOPICS:
            ok = topics.TOPICS[topic][0] == schema
        else:  # only the publishing unit's own trace, and a bounded number of them
            ok = topic == trace_topic(unit) and schema == _TRACE_SCHEMA
        with self._lock:
            if ok and is_trace_topic(topic) and topic not in self._traces:
                ok = len(self._traces) < MAX_TRACES
                if ok:
                    self._traces.add(topic)
            if not ok:
                self.drops["topic"] += 1
                return
            if stream is not None:
                sender, nonce, seq = stream
                last = self._streams.get(sender)
                if last is not None and last[0] == nonce and seq <= last[1]:
                    self.drops["duplicate"] += 1  # said twice (a replay within the run)
                    return
                if last is not None or len(self._streams) < MAX_STREAMS:
                    # A new nonce: the unit's process (re)started (or a recording of an
                    # earlier run with this key and run id: a watcher hears no hellos).
                    self._streams[sender] = (nonce, seq)
            if len(self.runs) < MAX_RUNS:
                self.runs.add(run)
            self.received += 1
        self.sink.put(topic, schema, data, t_ns)
        self._heard()

    def _heard(self) -> None:
        self.last_heard = time.monotonic()
        self.heard.set()

    def steer(self, control: Controller) -> None:
        """Forward what clients of the live view ask of the runs watched (``control``: its
        ``Controller``) to their steering process (``rgtbus.bus.steer_link``), signed with
        the run's key; requests wait for a run to be heard (the watched run's id, or every
        run heard)."""
        signer = Signer(self.key, "")

        def forward() -> None:
            waiting: list[Request] = []
            while not self._closing.is_set():
                control.wait(0.2)
                waiting += control.take()
                with self._lock:  # zenoh's threads add the runs they hear
                    heard = sorted(self.runs)
                runs = [self._run_id] if self._run_id != "*" else heard
                if not waiting or not runs:
                    waiting = waiting[-MAX_WAITING:]
                    continue
                for run in runs:
                    signer.run_id = run
                    for req in waiting:
                        self.session.put(steer_key(run), request_payload(req, signer))
                self.forwarded += len(waiting)
                waiting = []

        self._forwarder = threading.Thread(target=forward, name="watch-steer", daemon=True)
        self._forwarder.start()

    def close(self, timeout: float = 5.0) -> str | None:
        """Undeclare and close; what went wrong closing, or None."""
        self._closing.set()
        if self._forwarder is not None:
            self._forwarder.join(timeout)
        try:
            self._sub.undeclare()  # type: ignore[no-untyped-call]  # zenoh's stub leaves it bare
        except Exception as e:  # zenoh's ZError
            return zenoh_reason(e)
        return close_session(self.session, timeout)

    def __enter__(self) -> Watcher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
