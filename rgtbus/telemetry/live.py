"""A run served live over the Foxglove WebSocket protocol, by foxglove-sdk's server.

Every message a run logs is offered to connected clients on a channel with the same topic and
JSON Schema as in the MCAP log (``topic_channel``, one definition for both), and so is each
decode as a unit makes it (``/rx/decode``, ``Recorder.offer``: the view's alone; the log holds
them in blocks). The log is the same with a view or without. The live channels
live on their own ``foxglove.Context``, so a slow client never holds the file back. The
server's time (the Time capability) is the run's simulated time.

Pacing. A run paced at ``realtime`` simulated seconds per wall second computes ahead of its
clock (the event engine logs everything up to its next horizon, then sleeps until it), so a
message is not sent when written but when due: at wall time

    origin + t / realtime

(``origin``: ``begin()``, just before the run starts) a thread releases every message whose
log time t has come, and broadcasts the time. Unpaced, a message goes out when written.

Bounded, whatever the clients do. Handing a message to the server costs in proportion to its
clients (each gets a copy, under the GIL). While that is cheap (``_DIRECT``, measured as it
goes), ``put`` hands an unpaced message over itself; when it is not (many clients), ``put`` only
queues, and the view's thread hands messages over in batches, resting in proportion to its work
(``_SHARE``: 10% of the time at most; the server's own threads still write to every client's
socket). What is queued and not yet handed over is capped (``queue_bytes``: beyond it the
oldest messages are dropped, counted in ``dropped``); the server keeps at most ``backlog``
messages per client (the SDK drops a slow client's oldest first), so a client that never reads
costs at most its backlog; at most ``max_channels`` topics are served (more: counted in
``refused``). ``close`` gives the server ``STOP_TIMEOUT`` seconds to stop: a client that no
longer reads holds the SDK's last close frame forever, and is left behind (said on stderr)
rather than waited for.

What the server speaks: foxglove-sdk 0.30's WebSocket server, subprotocol ``foxglove.sdk.v1``
(Foxglove desktop and app.foxglove.dev: "Open connection", "Foxglove WebSocket",
``ws://HOST:PORT``). See docs/foxglove.md.
"""

from __future__ import annotations

import heapq
import itertools
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

import foxglove
from foxglove.websocket import Capability, ServerListener

from rgtbus.errors import BadInput
from rgtbus.telemetry.control import Controller
from rgtbus.telemetry.mcap_recorder import sdk_logs_to_python, topic_channel
from rgtbus.telemetry.message_json import kept_bytes
from rgtbus.timebase import seconds

DEFAULT_ADDRESS = "127.0.0.1:8765"
_TICK = 0.05  # s of wall time between time broadcasts while paced and idle
BACKLOG = 4096  # messages per client in the server (the oldest dropped)
QUEUE_BYTES = 32 << 20  # put, not yet handed to the server (beyond: the oldest dropped)
MAX_CHANNELS = 1024  # topics served (a run's own: ~12, plus one /trace/<unit> per unit)
STOP_TIMEOUT = 2.0  # s that close() waits for the server to stop
FLUSH_TIMEOUT = 2.0  # s that close() gives the view's thread to hand over what is queued
_BATCH = 256  # messages handed over between two chances for the run's thread to run
_SHARE = 0.1  # at most this share of the time handing messages over (the GIL is the run's too)
_DIRECT = 10e-6  # s a message: cheaper than this (a few clients), put() hands it over itself
_SAMPLE = 16  # put() measures what one message in this many costs (its thread's CPU time)
_OVERHEAD = 160  # bytes counted per queued message besides its topic and data (the tuple etc.)


def _stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def parse_address(text: str, where: str = "--live") -> tuple[str, int]:
    """``HOST:PORT`` (``[::1]:8765`` for IPv6; port 0: any free port) -> (host, port)."""
    host, sep, port_text = text.rpartition(":")
    if not sep or not host:
        raise BadInput(f"{where} {text!r}: expected HOST:PORT, e.g. {DEFAULT_ADDRESS}")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    try:
        port = int(port_text)
    except ValueError:
        raise BadInput(f"{where} {text!r}: port {port_text!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise BadInput(f"{where} {text!r}: port {port} is not in 0..65535")
    return host, port


def open_server(host: str, port: int, what: str, **options: Any) -> Any:
    """foxglove-sdk's WebSocket server on ``host:port`` with ``options`` (its log lines go to
    Python's logging); one that cannot listen (a port in use) is ``BadInput`` naming
    ``what``."""
    try:
        sdk_logs_to_python()
        return foxglove.start_server(host=host, port=port, **options)
    except Exception as exc:  # the SDK raises its own error type for a port in use
        raise BadInput(f"{what} on {host}:{port}: cannot listen: {exc}") from None


def stop_server(server: Any, what: str) -> str | None:
    """Stop a foxglove WebSocket server, waiting ``STOP_TIMEOUT`` s at most; what went wrong
    (None: it stopped). The SDK's stop waits for every client's last frame to be written:
    forever, for a client that stopped reading; a daemon thread never holds up the
    interpreter's exit."""
    stopped = threading.Event()

    def stop() -> None:
        try:
            server.stop()
        finally:
            stopped.set()

    threading.Thread(target=stop, name=f"{what}-stop", daemon=True).start()
    if stopped.wait(STOP_TIMEOUT):
        return None
    return (
        f"{what}: the server did not stop within {STOP_TIMEOUT:g} s (a client that no longer "
        "reads?): left to stop in the background"
    )


class _Subscriptions(ServerListener):
    """The server's listener: which (client, channel) pairs are subscribed; a steered run's
    parameters (``control``). Callbacks come from the server's threads and never block."""

    def __init__(self, control: Controller | None = None) -> None:
        self.pairs: set[tuple[int, int]] = set()
        self.changed = threading.Condition()
        self.last_change = 0.0
        self.control = control

    def on_get_parameters(
        self, client: Any, param_names: list[str], request_id: str | None = None
    ) -> list[Any]:
        return [] if self.control is None else self.control.on_get_parameters(client, param_names)

    def on_set_parameters(
        self, client: Any, parameters: list[Any], request_id: str | None = None
    ) -> list[Any]:
        if self.control is None:
            return []
        try:
            return self.control.on_set_parameters(client, parameters)
        except Exception:  # the run is stopping: nothing changes
            return self.control.parameters()

    def on_subscribe(self, client: Any, channel: Any) -> None:
        with self.changed:
            self.pairs.add((client.id, channel.id))
            self.last_change = time.monotonic()
            self.changed.notify_all()

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        with self.changed:
            self.pairs.discard((client.id, channel.id))
            self.last_change = time.monotonic()
            self.changed.notify_all()


class LiveView:
    """Serves a run's messages over the Foxglove WebSocket protocol; see the module docstring.

    ``put`` is what a recorder calls for every message (``McapRecorder(live=...)``); a watcher
    of a cross-process run calls it for what it hears (from any thread: it only queues).
    ``close`` releases what is still queued, gives subscribed clients up to ``linger`` seconds
    to take it and leave, and stops. ``say`` gets the view's warnings (default: stderr).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8765,
        *,
        realtime: float | None = None,
        name: str = "rgtbus",
        backlog: int = BACKLOG,
        linger: float = 2.0,
        queue_bytes: int = QUEUE_BYTES,
        max_channels: int = MAX_CHANNELS,
        say: Callable[[str], None] | None = None,
        control: Controller | None = None,
    ) -> None:
        if realtime is not None and not realtime > 0:
            raise BadInput(f"realtime {realtime}: must be a positive factor")
        self.host = host
        self.realtime = realtime
        self.linger = linger
        self.queue_bytes = queue_bytes
        self.max_channels = max_channels
        self._say = say or _stderr
        self.context = foxglove.Context()
        self.subscriptions = _Subscriptions(control)
        self.control = control
        steer: dict[str, Any] = {}
        capabilities = [Capability.Time]
        if control is not None:  # a steered run (docs/foxglove.md, "Steer a live run")
            capabilities += [Capability.Parameters, Capability.Services]
            steer = {
                "services": control.services(),
                "supported_encodings": ["json"],
                "session_id": control.session,
            }
        self.server = open_server(
            host, port, "live view",
            name=name, capabilities=capabilities, server_listener=self.subscriptions,
            context=self.context, message_backlog_size=backlog, **steer,
        )  # fmt: skip
        if control is not None:
            control.view = self
            control.publish = self.server.publish_parameter_values
        self._channels: dict[str, foxglove.Channel] = {}
        self._queue: list[tuple[int, int, str, str, bytes]] = []  # paced: by due time
        self._fifo: deque[tuple[int, int, str, str, bytes]] = deque()  # unpaced: as put
        self._queued = 0  # bytes in _queue or _fifo
        self._order = itertools.count()
        self._wake = threading.Condition(threading.Lock())
        self._origin: float | None = None  # begun (the clock's wall time at t = 0)
        # the paced clock: at wall time _clock_at it read _clock_t ns, and runs at _rate ns a
        # wall second (0: paused); a steered run moves it (``set_clock``)
        self._clock_at = 0.0
        self._clock_t = 0
        self._rate = (realtime or 0.0) * 1e9
        self._time = 0  # the latest log time sent, ns
        self._computed = 0  # the latest log time put (a paced clock never runs past it)
        self._last_broadcast = 0.0
        self._closing = False
        self._abandon = False  # close() ran out of time: drop what is left
        self._sending = False  # someone is handing messages to the server (one at a time)
        self._cost = 0.0  # s a message costs the server (moving average)
        self._direct_count = 0
        self.sent = 0  # messages released to the server
        self.dropped = 0  # put, never released: the view fell behind by more than queue_bytes
        self.refused = 0  # on a topic beyond max_channels
        self.stop_problem: str | None = None  # the server did not stop in time
        self._thread = threading.Thread(target=self._release_loop, name="live", daemon=True)
        self._thread.start()

    # -- set-up ---------------------------------------------------------------------------------

    @property
    def port(self) -> int:
        """The port the server listens on (the one it was given, or the free one it took for 0)."""
        return int(self.server.port)

    @property
    def url(self) -> str:
        """The server's WebSocket address, ``ws://HOST:PORT`` (an IPv6 host in brackets)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def advertise(self, topics: Iterable[tuple[str, str]]) -> None:
        """Offer these (topic, schema) channels before any message, so a client can subscribe
        to them before the run starts."""
        for topic, schema in topics:
            self._channel(topic, schema)

    def wait_for_client(self, timeout: float, settle: float = 0.3) -> bool:
        """Wait up to ``timeout`` s until a client has subscribed to a channel and its
        subscriptions have settled (none new for ``settle`` s); whether one did."""
        subs = self.subscriptions
        deadline = time.monotonic() + timeout
        with subs.changed:
            while True:
                now = time.monotonic()
                if subs.pairs and now - subs.last_change >= settle:
                    return True
                if now >= deadline:
                    return bool(subs.pairs)
                wait = settle - (now - subs.last_change) if subs.pairs else deadline - now
                subs.changed.wait(max(0.01, min(wait, deadline - now)))

    def begin(self) -> None:
        """The run starts now: simulated time 0 is this wall instant (paced runs)."""
        with self._wake:
            self._origin = self._clock_at = time.monotonic()
            self._wake.notify()

    def set_clock(self, t_ns: int, realtime: float | None, running: bool) -> None:
        """A steered run's clock (paced): at ``t_ns`` now, running at ``realtime`` simulated
        seconds a wall second, or paused; what is due is released by it from now on."""
        with self._wake:
            self._clock_t = max(self._clock_t, int(t_ns)) if running else int(t_ns)
            self._clock_at = time.monotonic()
            if realtime is not None and self.realtime is not None:
                self.realtime = realtime
            self._rate = (self.realtime or 0.0) * 1e9 if running else 0.0
            self._wake.notify()

    def _clock(self, now: float) -> int:
        """The paced clock at wall time ``now``, ns."""
        return self._clock_t + int((now - self._clock_at) * self._rate)

    # -- messages -------------------------------------------------------------------------------

    def watched(self) -> bool:
        """Always: a Foxglove client may connect at any moment and must get each message as
        the server's clock reaches it."""
        return True

    def put(self, topic: str, schema: str, data: bytes, t_ns: int) -> None:
        """Offer one message: unpaced and cheap (a few clients), handed to the server at once;
        else queued for the view's thread. Never waits for the server or a client."""
        if self.realtime is None and self._direct(topic, schema, data, t_ns):
            return
        # A copy: the recorder's JSON keeps far more allocation behind a message than its
        # length, which the queue's budget would not see.
        item = (t_ns, next(self._order), topic, schema, kept_bytes(data))
        with self._wake:
            if self._closing:
                self.dropped += 1
                return
            self._queued += len(data) + len(topic) + _OVERHEAD
            if self.realtime is None:
                self._fifo.append(item)
                wake = len(self._fifo) == 1  # the thread takes what piles up meanwhile
            else:
                self._computed = max(self._computed, t_ns)
                heapq.heappush(self._queue, item)
                wake = self._queue[0] is item  # due before what the thread sleeps for
            while self._queued > self.queue_bytes:  # the view fell behind: the oldest go
                old = self._fifo.popleft() if self.realtime is None else heapq.heappop(self._queue)
                self._queued -= len(old[4]) + len(old[2]) + _OVERHEAD
                self.dropped += 1
                wake = True
            if wake:
                self._wake.notify()

    def _direct(self, topic: str, schema: str, data: bytes, t_ns: int) -> bool:
        """Hand one message to the server from the caller's thread, if that is cheap (what a
        message costs is measured, per message, as it goes) and nothing is queued before it;
        whether it did. A thread hop a message would cost the run more than the server does
        with a few clients; with many, the view's thread takes over, at its bounded share."""
        with self._wake:
            if self._sending or self._fifo or self._closing or self._cost > _DIRECT:
                return False
            self._sending = True
            self._direct_count += 1
            sample = self._direct_count % _SAMPLE == 0
        try:
            t0 = time.thread_time() if sample else 0.0  # CPU time: not the GIL's waits
            self._send(topic, schema, data, t_ns)
            if time.monotonic() - self._last_broadcast >= _TICK:
                self._broadcast(self._time)
            cost = time.thread_time() - t0 if sample else 0.0
        finally:
            self._sending = False  # a plain store: the thread reads it under the lock
        if sample:
            self._cost += (cost - self._cost) * 0.25
        return True

    def due_wall(self, t_ns: int) -> float:
        """The monotonic wall time at which a message of log time ``t_ns`` is due (infinity
        while a steered run is paused)."""
        if self._origin is None:
            return time.monotonic() + seconds(t_ns) / (self.realtime or float("inf"))
        if not self._rate:
            return float("inf") if self.realtime is not None else self._clock_at
        return self._clock_at + (t_ns - self._clock_t) / self._rate

    def _send(self, topic: str, schema: str, data: bytes, t_ns: int) -> None:
        channel = self._channels.get(topic) or self._channel(topic, schema)
        if channel is None:
            self.refused += 1
            return
        channel.log(data, log_time=t_ns)
        self.sent += 1
        if t_ns > self._time:
            self._time = t_ns

    def _channel(self, topic: str, schema: str) -> foxglove.Channel | None:
        channel = self._channels.get(topic)
        if channel is None:
            if len(self._channels) >= self.max_channels:
                return None
            channel = self._channels[topic] = topic_channel(self.context, topic, schema)
        return channel

    def _broadcast(self, t_ns: int) -> None:
        self._last_broadcast = time.monotonic()
        self.server.broadcast_time(int(t_ns))

    def _release_loop(self) -> None:
        """The view's thread: hands queued messages to the server (paced: once due), a batch
        at a time, and broadcasts the time."""
        paced = self.realtime is not None
        while True:
            with self._wake:
                due: list[tuple[int, int, str, str, bytes]] = []
                if not paced:
                    while self._fifo and len(due) < _BATCH:
                        due.append(self._fifo.popleft())
                elif self._origin is not None:
                    clock = self._clock(time.monotonic())
                    while (
                        self._queue
                        and len(due) < _BATCH
                        and (self._queue[0][0] <= clock or self._closing)
                    ):
                        due.append(heapq.heappop(self._queue))
                for item in due:
                    self._queued -= len(item[4]) + len(item[2]) + _OVERHEAD
                if due and not paced and self._sending:  # put() is sending one: next round
                    self._fifo.extendleft(reversed(due))
                    for item in due:
                        self._queued += len(item[4]) + len(item[2]) + _OVERHEAD
                    due = []
                if not due:
                    if self._closing:
                        return
                    wait = _TICK
                    if paced and self._origin is not None and self._queue and self._rate:
                        wait = (self._queue[0][0] - clock) / self._rate
                    self._wake.wait(max(0.0005, min(_TICK, wait)))
                    if not paced or self._origin is None:
                        continue
                abandon, closing = self._abandon, self._closing
                if abandon:
                    self.dropped += len(due)
                self._sending = bool(due)
            busy, cpu = time.perf_counter(), time.thread_time()
            try:
                if not abandon:
                    for t_ns, _, topic, schema, data in due:
                        self._send(topic, schema, data, t_ns)
            finally:
                with self._wake:
                    self._sending = False
            busy = time.perf_counter() - busy
            if due and not abandon:
                self._cost += ((time.thread_time() - cpu) / len(due) - self._cost) * 0.5
            if paced and self._origin is not None:
                now_clock = self._clock(time.monotonic())
                self._broadcast(max(self._time, min(now_clock, self._computed)))
            elif time.monotonic() - self._last_broadcast >= _TICK:
                self._broadcast(self._time)
            if due and not closing and self._cost > _DIRECT:
                # The server's work grows with its clients (each message is copied to each one,
                # holding the GIL): rest in proportion, so the run keeps at least 1 - _SHARE of
                # the time however many clients there are; the queue drops what piles up.
                time.sleep(busy * (1 - _SHARE) / _SHARE)

    # -- the end --------------------------------------------------------------------------------

    def close(self) -> None:
        """Release what is queued (for up to ``FLUSH_TIMEOUT`` s: what is left then is
        dropped), give subscribed clients ``linger`` s to leave, stop the server (waiting at
        most ``STOP_TIMEOUT`` s: a client that no longer reads is left behind)."""
        with self._wake:
            if self._closing:
                return
            self._closing = True
            self._wake.notify()
        if self.control is not None:
            self.control.close()
        self._thread.join(max(FLUSH_TIMEOUT, self.linger))
        if self._thread.is_alive():  # the clients take too long: what is left is dropped
            with self._wake:
                self._abandon = True
            self._thread.join()
        self._broadcast(self._time)
        subs = self.subscriptions
        deadline = time.monotonic() + self.linger
        with subs.changed:
            while subs.pairs and time.monotonic() < deadline:
                subs.changed.wait(max(0.01, deadline - time.monotonic()))
        self.stop_problem = stop_server(self.server, "live")
        if self.stop_problem:
            self._say(self.stop_problem)
        if self.dropped or self.refused:
            what = []
            if self.dropped:
                what.append(
                    f"{self.dropped} messages dropped (the view fell more than "
                    f"{self.queue_bytes >> 20} MiB behind the run)"
                )
            if self.refused:
                what.append(f"{self.refused} refused (more than {self.max_channels} topics)")
            self._say(f"live: {'; '.join(what)}; the log has every message")

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
