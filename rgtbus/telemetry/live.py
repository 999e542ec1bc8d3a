"""A run served live over the Foxglove WebSocket protocol, by foxglove-sdk's server.

Every message a run logs is offered to connected clients on a channel with the same topic and
JSON Schema as in the MCAP log (``topic_channel``, one definition for both). The live channels
live on their own ``foxglove.Context``, so a slow client never holds the file back. The
server's time (the Time capability) is the run's simulated time.

Pacing. A run paced at ``realtime`` simulated seconds per wall second computes ahead of its
clock (the event engine logs everything up to its next horizon, then sleeps until it), so a
message is not sent when written but when due: at wall time

    origin + t / realtime

(``origin``: ``begin()``, just before the run starts) a thread releases every message whose
log time t has come, and broadcasts the time. Unpaced, a message goes out when written.

What the server speaks: foxglove-sdk 0.30's WebSocket server, subprotocol ``foxglove.sdk.v1``
(Foxglove desktop and app.foxglove.dev: "Open connection", "Foxglove WebSocket",
``ws://HOST:PORT``). See docs/foxglove.md.
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from collections.abc import Iterable
from typing import Any

import foxglove
from foxglove.websocket import Capability, ServerListener

from rgtbus.errors import RgtbusError
from rgtbus.telemetry.recorder import topic_channel
from rgtbus.timebase import seconds

DEFAULT_ADDRESS = "127.0.0.1:8765"
_TICK = 0.05  # s of wall time between time broadcasts while paced and idle


def parse_address(text: str, where: str = "--live") -> tuple[str, int]:
    """``HOST:PORT`` (``[::1]:8765`` for IPv6; port 0: any free port) -> (host, port)."""
    host, sep, port_text = text.rpartition(":")
    if not sep or not host:
        raise RgtbusError(f"{where} {text!r}: expected HOST:PORT, e.g. {DEFAULT_ADDRESS}")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    try:
        port = int(port_text)
    except ValueError:
        raise RgtbusError(f"{where} {text!r}: port {port_text!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise RgtbusError(f"{where} {text!r}: port {port} is not in 0..65535")
    return host, port


class _Subscriptions(ServerListener):
    """The server's listener: which (client, channel) pairs are subscribed. Callbacks come
    from the server's threads and never block."""

    def __init__(self) -> None:
        self.pairs: set[tuple[int, int]] = set()
        self.changed = threading.Condition()
        self.last_change = 0.0

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
    of a cross-process run calls it for what it hears. ``close`` releases what is still queued,
    gives subscribed clients up to ``linger`` seconds to take it and leave, and stops.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8765,
        *,
        realtime: float | None = None,
        name: str = "rgtbus",
        backlog: int = 1 << 16,
        linger: float = 2.0,
    ) -> None:
        if realtime is not None and not realtime > 0:
            raise RgtbusError(f"realtime {realtime}: must be a positive factor")
        self.host = host
        self.realtime = realtime
        self.linger = linger
        self.context = foxglove.Context()
        self.subscriptions = _Subscriptions()
        try:
            self.server = foxglove.start_server(
                name=name,
                host=host,
                port=port,
                capabilities=[Capability.Time],
                server_listener=self.subscriptions,
                context=self.context,
                message_backlog_size=backlog,
            )
        except Exception as exc:  # the SDK raises its own error type for a port in use
            raise RgtbusError(f"live view on {host}:{port}: cannot listen: {exc}") from None
        self._channels: dict[str, foxglove.Channel] = {}
        self._queue: list[tuple[int, int, str, str, bytes]] = []
        self._order = itertools.count()
        self._wake = threading.Condition()
        self._origin: float | None = None
        self._time = 0  # the latest log time sent, ns
        self._computed = 0  # the latest log time put (a paced clock never runs past it)
        self._last_broadcast = 0.0
        self._closing = False
        self._thread: threading.Thread | None = None
        self.sent = 0  # messages released to the server

    # -- set-up ---------------------------------------------------------------------------------

    @property
    def port(self) -> int:
        return int(self.server.port)

    @property
    def url(self) -> str:
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
        self._origin = time.monotonic()
        if self.realtime is not None and self._thread is None:
            self._thread = threading.Thread(target=self._release_loop, name="live", daemon=True)
            self._thread.start()

    # -- messages -------------------------------------------------------------------------------

    def put(self, topic: str, schema: str, data: bytes, t_ns: int) -> None:
        if self.realtime is None:
            self._send(topic, schema, data, t_ns)
            if time.monotonic() - self._last_broadcast >= _TICK:
                self._broadcast(self._time)
            return
        with self._wake:
            self._computed = max(self._computed, t_ns)
            heapq.heappush(self._queue, (t_ns, next(self._order), topic, schema, data))
            if self._queue[0][0] == t_ns:  # due before what the thread sleeps for
                self._wake.notify()

    def due_wall(self, t_ns: int) -> float:
        """The monotonic wall time at which a message of log time ``t_ns`` is due."""
        origin = self._origin if self._origin is not None else time.monotonic()
        return origin + seconds(t_ns) / (self.realtime or float("inf"))

    def _send(self, topic: str, schema: str, data: bytes, t_ns: int) -> None:
        channel = self._channels.get(topic) or self._channel(topic, schema)
        channel.log(data, log_time=t_ns)
        self.sent += 1
        if t_ns > self._time:
            self._time = t_ns

    def _channel(self, topic: str, schema: str) -> foxglove.Channel:
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._channels[topic] = topic_channel(self.context, topic, schema)
        return channel

    def _broadcast(self, t_ns: int) -> None:
        self._last_broadcast = time.monotonic()
        self.server.broadcast_time(int(t_ns))

    def _release_loop(self) -> None:
        assert self.realtime is not None and self._origin is not None
        per_ns = seconds(1) / self.realtime
        while True:
            with self._wake:
                now = time.monotonic()
                clock = int((now - self._origin) / per_ns)
                due = []
                while self._queue and (self._queue[0][0] <= clock or self._closing):
                    due.append(heapq.heappop(self._queue))
                if not due:
                    if self._closing:
                        return
                    nxt = self._queue[0][0] if self._queue else None
                    wait = _TICK if nxt is None else (nxt - clock) * per_ns
                    self._wake.wait(max(0.0005, min(_TICK, wait)))
            for t_ns, _, topic, schema, data in due:
                self._send(topic, schema, data, t_ns)
            now_clock = int((time.monotonic() - self._origin) / per_ns)
            self._broadcast(max(self._time, min(now_clock, self._computed)))

    # -- the end --------------------------------------------------------------------------------

    def close(self) -> None:
        """Release what is queued, give subscribed clients ``linger`` s to leave, stop."""
        if self._closing:
            return
        with self._wake:
            self._closing = True
            self._wake.notify()
        if self._thread is not None:
            self._thread.join()
        self._broadcast(self._time)
        subs = self.subscriptions
        deadline = time.monotonic() + self.linger
        with subs.changed:
            while subs.pairs and time.monotonic() < deadline:
                subs.changed.wait(max(0.01, deadline - time.monotonic()))
        self.server.stop()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
