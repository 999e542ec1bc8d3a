"""A run's MCAP log served over the Foxglove WebSocket protocol, to be played back from a
Foxglove client: play, pause, seek, speed (``rgtbus replay LOG --serve``; docs/foxglove.md).

What is served. Every channel of the log, exactly as the log holds it: its topic, its message
encoding and its schema (name, encoding, bytes) as read from the log, so whatever reads the
file reads the served messages (Foxglove's layout, docs/foxglove-layout.json, unchanged). Each
message goes out with its own log time, in log-time order (file order on ties), every message
once during a continuous play. The server (foxglove-sdk's) has the Time and PlaybackControl
capabilities, its playback range the log's first to last log time: a client's playback bar
plays, pauses, seeks (playing then restarts from the first message at or after the seek time)
and sets the speed, clamped to ``MIN_SPEED``..``MAX_SPEED`` (the state sent back says the
speed taken). Time is the log's own: at speed s, a message of log time t is sent once
``(t - t0) / s`` wall seconds have passed since playing started from t0; the server's time
(the Time capability) follows that clock. At the end of the log the state is Ended and the
server goes on serving (a Play then starts again from the beginning; a seek anywhere too).

Memory: bounded by the chunks it needs, never the log. ``index_log`` reads where each chunk is
and which log times it spans (from the summary's chunk indexes; a log without a usable
summary, one cut short, is scanned once, a chunk at a time, to find them). Playing reads a
chunk when the clock reaches its first log time and lets it go once its last message is sent:
chunks overlap in time (a run writes its medium ahead of the present), so a few are held at
once, each about 1 MiB decompressed (``MAX_CHUNK_BYTES`` at most). The server keeps at most
``backlog`` messages a client (the SDK drops the oldest of a client that does not read).

A log cut short, or damaged: served as far as it reads, and said (``LogIndex.note`` at the
start; ``LogServer.problem`` where a chunk fails to read while playing: playing ends there).

Threads: the server's callbacks (a client's playback request, a subscription) only change the
state under a lock and return; one player thread reads the log and hands messages to the
server.

    from rgtbus.telemetry.serve import serve_log
    server = serve_log("logs/gate.mcap", speed=2)   # ws://127.0.0.1:8765, plays once a
    server.seek(120.0); server.play()               # client subscribes; or from here
    server.close()
"""

from __future__ import annotations

import heapq
import io
import math
import os
import struct
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import IO, Any

import foxglove
from foxglove.websocket import (
    Capability,
    PlaybackCommand,
    PlaybackControlRequest,
    PlaybackState,
    PlaybackStatus,
    ServerListener,
)
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Schema

from rgtbus.errors import BadInput, BadLog, IOFailure
from rgtbus.telemetry.chunks import MAX_CHUNK_BYTES, decompressed, split_chunk
from rgtbus.telemetry.live import DEFAULT_ADDRESS, open_server, parse_address, stop_server
from rgtbus.timebase import ns, seconds

MIN_SPEED = 0.1  # the slowest playback a client may ask for (slower: this)
MAX_SPEED = 100.0  # the fastest (faster: this)
BACKLOG = 16384  # messages per client in the server (the oldest dropped for a client that lags)
_TICK = 0.05  # s of wall time between two time broadcasts while playing
_BATCH = 256  # messages read ahead (and handed over under the lock) at most at a time
_SETTLE = 0.3  # s without a new subscription before a first client's autoplay starts

_CHUNK = 0x06
_MESSAGE = 0x05
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, length

Row = tuple[int, int, bytes]  # a message as served: (log time ns, channel id, data)


def _stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def clamp_speed(speed: float, current: float = 1.0) -> float:
    """A playback speed a client asked for, taken into ``MIN_SPEED``..``MAX_SPEED`` (NaN:
    ``current``, the speed unchanged)."""
    if math.isnan(speed):
        return current
    return min(MAX_SPEED, max(MIN_SPEED, float(speed)))


def check_speed(speed: float, where: str = "speed") -> float:
    """``speed`` if it is a factor from ``MIN_SPEED`` to ``MAX_SPEED``, else ``BadInput``."""
    if not MIN_SPEED <= speed <= MAX_SPEED:  # NaN too
        raise BadInput(f"{where} {speed!r}: must be a factor from {MIN_SPEED:g} to {MAX_SPEED:g}")
    return float(speed)


# -- where the messages are ------------------------------------------------------------------


@dataclass(frozen=True)
class Span:
    """One record of the log holding messages: a chunk, or a message written outside any."""

    start: int  # the earliest log time of its messages, ns
    end: int  # the latest
    offset: int  # the record's byte offset in the file
    crc: int | None = None  # a chunk's CRC as the scan read it (None: found in the summary)


@dataclass
class LogIndex:
    """What serving a log needs to know of it, read without its messages: its channels and
    schemas (as mcap reads them), where its messages are (``spans``, by first log time), the
    log times it spans, how many messages it holds, and ``note``: empty, or one line saying
    where and why the log stops short (cut or damaged: served up to there)."""

    path: str
    size: int
    channels: dict[int, Channel]
    schemas: dict[int, Schema]
    spans: list[Span]
    start_ns: int
    end_ns: int
    messages: int
    note: str = ""
    indexed_by: str = "summary"  # or "scan": no usable summary (a log cut short, say)

    @property
    def topics(self) -> list[str]:
        """The log's topics, each once, in channel order."""
        return list(dict.fromkeys(c.topic for _, c in sorted(self.channels.items())))


def index_log(path: str | os.PathLike[str]) -> LogIndex:
    """The ``LogIndex`` of the MCAP log at ``path``: from its summary (chunk indexes,
    channels, schemas, statistics) when it has a usable one, else from one scan record by
    record (a chunk at a time, CRC-checked; messages counted, not kept), which reads a log cut
    short to its cut and a damaged one to its damage (``note`` says which). Refused with one
    line (``RgtbusError``): unreadable, not an MCAP file, no channel at all."""
    label = os.fspath(path)
    try:
        if os.path.isdir(path):
            raise IOFailure(f"cannot read log {label!r}: is a directory")
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            index = _by_summary(f, label, size)
            if index is None:
                index = _by_scan(f, label, size)
    except OSError as e:
        raise IOFailure(f"cannot read log {label!r}: {e.strerror}") from None
    if not index.channels:
        raise BadLog(f"{label}: no channels: nothing to serve")
    return index


def _by_summary(f: IO[bytes], label: str, size: int) -> LogIndex | None:
    """The index from the summary section; None where there is none to trust (none at all,
    no statistics, messages outside chunks, a chunk index that does not fit the file)."""
    try:
        summary = make_reader(f).get_summary()
    except Exception:  # no footer (a log cut short), or a layout mcap does not take
        return None
    if summary is None or summary.statistics is None:
        return None
    stats = summary.statistics
    chunks = summary.chunk_indexes
    if stats.chunk_count != len(chunks) or (stats.message_count and not chunks):
        return None  # messages outside chunks, or chunks without an index: scanned
    for ci in chunks:
        if not 0 < ci.chunk_start_offset < size or ci.uncompressed_size > MAX_CHUNK_BYTES:
            return None  # the scan says what is wrong with the file, and where
    spans = sorted(
        (Span(ci.message_start_time, ci.message_end_time, ci.chunk_start_offset) for ci in chunks),
        key=lambda s: (s.start, s.offset),
    )
    start, end = (stats.message_start_time, stats.message_end_time) if spans else (0, 0)
    return LogIndex(
        label, size, dict(summary.channels), dict(summary.schemas), spans, start, end,
        stats.message_count,
    )  # fmt: skip


def _by_scan(f: IO[bytes], label: str, size: int) -> LogIndex:
    """The index from a scan of the whole file (``scan_log``, every topic's messages left in
    the file): each record holding messages found, its log times read from its header."""
    from rgtbus.telemetry.scan import scan_log

    f.seek(0)
    raw = scan_log(f, defer=lambda topic: True)
    deferred = raw.deferred
    offsets = sorted({o for where in deferred.records.values() for o in where}) if deferred else []
    spans: list[Span] = []
    for offset in offsets:
        f.seek(offset)
        head = f.read(25)
        if len(head) == 25 and head[0] == _CHUNK:
            start, end = struct.unpack_from("<QQ", head, 9)
            crc = deferred.crcs.get(offset) if deferred else None
            spans.append(Span(start, end, offset, crc))
        elif len(head) >= 23 and head[0] == _MESSAGE:
            (t,) = struct.unpack_from("<Q", head, 15)  # after channel id and sequence
            spans.append(Span(t, t, offset))
    spans.sort(key=lambda s: (s.start, s.offset))
    start = min((s.start for s in spans), default=0)
    end = max((s.end for s in spans), default=0)
    count = raw.count
    return LogIndex(
        label, size, dict(raw.channels), dict(raw.schemas), spans, start, end, count,
        raw.corruption or raw.note, "scan",
    )  # fmt: skip


class _Unreadable(Exception):
    """A record of the log that cannot be read where the index says it is; its text says
    what and where."""


def _span_rows(f: IO[bytes], span: Span, size: int) -> list[Row]:
    """The messages of the record ``span`` names, as ``(log time, channel id, data)`` in file
    order; ``_Unreadable`` saying what is wrong with it otherwise."""
    at = span.offset
    f.seek(at)
    head = f.read(_RECORD_HEAD.size)
    if len(head) < _RECORD_HEAD.size:
        raise _Unreadable(f"no record at byte {at} (the file ends)")
    opcode, length = _RECORD_HEAD.unpack(head)
    if length > min(size - at - _RECORD_HEAD.size, MAX_CHUNK_BYTES):
        raise _Unreadable(f"the record at byte {at} runs past the end of the file")
    body = f.read(length)
    stream = ReadDataStream(io.BytesIO(body))
    try:
        if opcode == _CHUNK:
            chunk = Chunk.read(stream)
            if chunk.uncompressed_size > MAX_CHUNK_BYTES:
                raise _Unreadable(f"the chunk at byte {at} claims {chunk.uncompressed_size} bytes")
            if span.crc is not None and chunk.uncompressed_crc != span.crc:
                raise _Unreadable(f"the chunk at byte {at} changed since the log was scanned")
            rows, _ = split_chunk(decompressed(chunk), lambda record: None)
            return [(t, cid, data) for cid, t, _, _, data in rows]
        if opcode == _MESSAGE:
            m = Message.read(stream, length)
            return [(m.log_time, m.channel_id, bytes(m.data))]
    except _Unreadable:
        raise
    except Exception as e:  # a CRC that does not hold, a record that does not parse
        raise _Unreadable(
            f"the record at byte {at} cannot be read ({type(e).__name__}: {e})"
        ) from None
    raise _Unreadable(f"no chunk or message at byte {at} (opcode {opcode:#04x})")


class _Cursor:
    """The log's messages from log time ``t0`` on, in log-time order (file order on ties),
    each once. A chunk is read when the earliest message still to come is no earlier than its
    first log time, and dropped once its last message is taken: what is held is the chunks
    the present overlaps. A record that does not read ends the messages at its first log time
    (``problem`` says why)."""

    def __init__(self, f: IO[bytes], index: LogIndex, t0: int) -> None:
        self._f = f
        self._size = index.size
        self._todo = [s for s in index.spans if s.end >= t0]  # by first log time
        self._next = 0
        self._t0 = t0
        self._heap: list[tuple[int, int, int, list[Row]]] = []  # (t, offset, position, rows)
        self._limit: int | None = None  # no message from here on (a record that did not read)
        self.problem = ""

    def _fill(self) -> None:
        while self._next < len(self._todo) and self._limit is None:
            span = self._todo[self._next]
            if self._heap and span.start > self._heap[0][0]:
                return
            self._next += 1
            try:
                rows = _span_rows(self._f, span, self._size)
            except _Unreadable as e:
                self.problem = f"{e}; nothing served from log time {seconds(span.start):.6f} s"
                self._limit = span.start
                return
            except OSError as e:
                self.problem = f"cannot read the log: {e.strerror}"
                self._limit = span.start
                return
            rows = [r for r in rows if r[0] >= self._t0]
            if rows:
                rows.sort(key=_log_time)  # stable: file order on ties
                heapq.heappush(self._heap, (rows[0][0], span.offset, 0, rows))

    def peek(self) -> int | None:
        """The log time of the next message (None: there is none)."""
        self._fill()
        if not self._heap or (self._limit is not None and self._heap[0][0] >= self._limit):
            return None
        return self._heap[0][0]

    def pop(self) -> Row:
        """The next message (after ``peek`` said there is one)."""
        _, offset, position, rows = self._heap[0]
        row = rows[position]
        if position + 1 < len(rows):
            heapq.heapreplace(self._heap, (rows[position + 1][0], offset, position + 1, rows))
        else:
            heapq.heappop(self._heap)
        return row


def _log_time(row: Row) -> int:
    return row[0]


def iter_log(
    log: str | os.PathLike[str] | LogIndex, start: float | None = None
) -> Iterator[tuple[str, int, bytes]]:
    """Every message of an MCAP log from ``start`` (simulated seconds; None: the first) on,
    as ``(topic, log time ns, data)``, in log-time order (file order on ties), read as the
    server reads it: a chunk at a time, in memory bounded by the chunks the present overlaps.
    A record that does not read ends the messages there (``BadLog`` naming it)."""
    index = log if isinstance(log, LogIndex) else index_log(log)
    topic = {cid: ch.topic for cid, ch in index.channels.items()}
    t0 = index.start_ns if start is None else ns(start)
    try:
        f = open(index.path, "rb")  # noqa: SIM115 - closed below (a generator)
    except OSError as e:
        raise IOFailure(f"cannot read log {index.path!r}: {e.strerror}") from None
    with f:
        cursor = _Cursor(f, index, t0)
        while cursor.peek() is not None:
            t, cid, data = cursor.pop()
            if cid in topic:
                yield topic[cid], t, data
        if cursor.problem:
            raise BadLog(f"{index.path}: {cursor.problem}")


# -- the server ------------------------------------------------------------------------------


class _Listener(ServerListener):
    """The server's callbacks, from its threads: they change the player's state and return."""

    def __init__(self, player: LogServer) -> None:
        self.player = player

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self.player._subscribed(client.id, channel.id, True)

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        self.player._subscribed(client.id, channel.id, False)

    def on_playback_control_request(
        self, playback_control_request: PlaybackControlRequest
    ) -> PlaybackState:
        req = playback_control_request
        return self.player._control(
            play=req.playback_command == PlaybackCommand.Play,
            speed=req.playback_speed,
            seek_ns=req.seek_time,
            request_id=req.request_id,
        )


def _status_name(status: PlaybackStatus) -> str:
    """``playing``, ``paused``, ``ended`` or ``buffering`` (the SDK's statuses do not hash)."""
    return str(status.name).lower()


class LogServer:
    """Serves the MCAP log ``log`` (a path, or its ``LogIndex``) on ``host:port`` over the
    Foxglove WebSocket protocol, played back at ``speed`` (see the module docstring).

    It starts paused at the log's first message; with ``autoplay`` it starts playing once a
    first client has subscribed (and its subscriptions have settled for ``_SETTLE`` s), unless a
    client or the caller took control first (a playback request, ``play``, ``pause``, ``seek``,
    ``set_speed``). ``play``, ``pause``, ``seek`` and ``set_speed`` do what a client's playback
    bar does, and tell every client. ``wait_ended`` waits for the end of the log; ``close``
    stops the server. ``say`` gets its warnings (default: stderr).

    ``sent``: messages handed to the server; ``seeks``: seeks done (a client's or the
    caller's); ``problem``: empty, or why playing ended before the end of the log (a chunk
    that did not read)."""

    def __init__(
        self,
        log: str | os.PathLike[str] | LogIndex,
        host: str = "127.0.0.1",
        port: int = 8765,
        *,
        speed: float = 1.0,
        autoplay: bool = True,
        name: str = "rgtbus replay",
        backlog: int = BACKLOG,
        say: Callable[[str], None] | None = None,
    ) -> None:
        self._speed = check_speed(speed)
        self.index = log if isinstance(log, LogIndex) else index_log(log)
        self.host = host
        self._say = say or _stderr
        self._cond = threading.Condition(threading.Lock())
        self._status = PlaybackStatus.Paused
        self._autoplay = autoplay
        self._pos = self.index.start_ns  # the playback time while not playing
        self._anchor = (time.monotonic(), self._pos)  # (wall, log time) playing started from
        self._gen = 0  # seeks so far: the player starts again from _pos when it changes
        self._pairs: set[tuple[int, int]] = set()  # (client, channel) subscribed
        self._last_change = 0.0
        self._announce = False  # a new subscriber: the player tells every client the state
        self._closing = False
        self._closed = False
        self.sent = 0
        self.seeks = 0
        self.problem = ""
        try:
            self._file = open(self.index.path, "rb")  # noqa: SIM115 - closed in close()
        except OSError as e:
            raise IOFailure(f"cannot read log {self.index.path!r}: {e.strerror}") from None
        self.context = foxglove.Context()
        self._channels = self._make_channels()
        try:
            self.server = open_server(
                host, port, "serve",
                name=name, capabilities=[Capability.Time, Capability.PlaybackControl],
                server_listener=_Listener(self), context=self.context,
                playback_time_range=(self.index.start_ns, self.index.end_ns),
                message_backlog_size=backlog,
            )  # fmt: skip
        except BadInput:
            self._file.close()
            raise
        self._port = int(self.server.port)  # (the SDK's reads 0 once it has stopped)
        self._thread = threading.Thread(target=self._play_loop, name="serve", daemon=True)
        self._thread.start()

    def _make_channels(self) -> dict[int, foxglove.Channel]:
        """A server channel for each of the log's channels: its topic, message encoding,
        schema and metadata as the log holds them. Two channels of one topic share the first
        one's (the SDK keeps one channel a topic)."""
        out: dict[int, foxglove.Channel] = {}
        by_topic: dict[str, foxglove.Channel] = {}
        for cid, ch in sorted(self.index.channels.items()):
            if ch.topic in by_topic:
                out[cid] = by_topic[ch.topic]
                continue
            sc = self.index.schemas.get(ch.schema_id) if ch.schema_id else None
            schema = (
                foxglove.Schema(name=sc.name, encoding=sc.encoding, data=bytes(sc.data))
                if sc is not None
                else None
            )
            out[cid] = by_topic[ch.topic] = foxglove.Channel(
                ch.topic,
                message_encoding=ch.message_encoding,
                schema=schema,
                metadata=dict(ch.metadata) or None,
                context=self.context,
            )
        return out

    # -- where it is -----------------------------------------------------------------------

    @property
    def port(self) -> int:
        """The port the server listens on (the one it was given, or the free one it took for 0)."""
        return self._port

    @property
    def url(self) -> str:
        """The server's WebSocket address, ``ws://HOST:PORT`` (an IPv6 host in brackets)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def _clock(self, now: float) -> int:
        """The playback time at wall time ``now`` (under the lock)."""
        if self._status != PlaybackStatus.Playing:
            return self._pos
        wall, t = self._anchor
        return min(self.index.end_ns, t + int((now - wall) * self._speed * 1e9))

    def state(self) -> dict[str, Any]:
        """``{"status": "playing"|"paused"|"ended", "time": log time in s, "speed": x}``."""
        with self._cond:
            t = self._clock(time.monotonic())
            return {"status": _status_name(self._status), "time": seconds(t), "speed": self._speed}

    # -- control ---------------------------------------------------------------------------

    def _control(
        self,
        *,
        play: bool | None = None,
        speed: float | None = None,
        seek_ns: int | None = None,
        request_id: str = "",
    ) -> PlaybackState:
        """Apply a playback request (a client's, or the caller's) and return the state it
        leaves: the seek first, then the speed (clamped), then play or pause. A play at the end
        of the log starts again from its beginning. Never waits for the player."""
        with self._cond:
            now = time.monotonic()
            pos = self._clock(now)
            self._autoplay = False  # someone took control
            did_seek = False
            if seek_ns is not None:
                pos = min(self.index.end_ns, max(self.index.start_ns, int(seek_ns)))
                did_seek = True
            elif play and self._status == PlaybackStatus.Ended:
                pos, did_seek = self.index.start_ns, True  # play again from the beginning
            if did_seek:
                self._gen += 1
                self.seeks += 1
                if self._status == PlaybackStatus.Ended:
                    self._status = PlaybackStatus.Paused
            if speed is not None:
                self._speed = clamp_speed(speed, self._speed)
            if play is True:
                self._status = PlaybackStatus.Playing
            elif play is False and self._status == PlaybackStatus.Playing:
                self._status = PlaybackStatus.Paused
            self._pos = pos
            self._anchor = (now, pos)
            self._cond.notify_all()
            return PlaybackState(self._status, pos, self._speed, did_seek, request_id)

    def _tell(self, state: PlaybackState) -> None:
        if not self._closed:
            self.server.broadcast_playback_state(state)

    def play(self) -> None:
        """Play from where it is (from the beginning, at the end of the log)."""
        self._tell(self._control(play=True))

    def pause(self) -> None:
        """Pause where it is: nothing more is sent until ``play``."""
        self._tell(self._control(play=False))

    def seek(self, t: float) -> None:
        """Go to log time ``t`` (simulated seconds, taken into the log's range): playing goes
        on from the first message at or after it; paused stays paused there."""
        self._tell(self._control(seek_ns=ns(t)))

    def set_speed(self, speed: float) -> float:
        """Play at ``speed`` times the log's own pace, clamped to ``MIN_SPEED``..``MAX_SPEED``;
        the speed taken."""
        self._tell(self._control(speed=speed))
        with self._cond:
            return self._speed  # (the state sent has it as a 32-bit float)

    def _subscribed(self, client: int, channel: int, on: bool) -> None:
        with self._cond:
            if on:
                self._pairs.add((client, channel))
                self._announce = True
            else:
                self._pairs.discard((client, channel))
            self._last_change = time.monotonic()
            self._cond.notify_all()

    def wait_for_client(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s until a client has subscribed to a channel; whether one
        did."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while not self._pairs:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            return True

    def wait_ended(self, timeout: float | None = None) -> bool:
        """Wait (up to ``timeout`` s; None: as long as it takes) until playing has reached the
        end of the log; whether it has."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while self._status != PlaybackStatus.Ended and not self._closing:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return False
                self._cond.wait(left)
            return self._status == PlaybackStatus.Ended

    # -- the player ------------------------------------------------------------------------

    def _play_loop(self) -> None:
        """The player's thread: reads the log from the latest seek on and hands each message
        to the server once the clock reaches it, a batch at a time; broadcasts the time."""
        try:
            self._play()
        except Exception as e:  # never silent: the server stays up, playing stops
            with self._cond:
                self.problem = f"the player stopped: {type(e).__name__}: {e}"
                self._status = PlaybackStatus.Ended
                self._cond.notify_all()
            self._say(f"serve: {self.problem}")

    def _play(self) -> None:
        gen, start, horizon = -1, self._pos, 0
        cursor: _Cursor | None = None
        held: list[Row] = []  # read ahead, not yet sent (their log times are in order)
        exhausted = False
        last_broadcast = 0.0
        while True:
            tell: PlaybackState | None = None
            broadcast: int | None = None
            with self._cond:
                if self._closing:
                    return
                now = time.monotonic()
                if self._gen != gen:  # a seek (or the start): read again from there
                    gen, start = self._gen, self._pos
                    cursor, held, exhausted = None, [], False
                elif self._autoplay and self._status == PlaybackStatus.Paused:
                    if self._pairs and now - self._last_change >= _SETTLE:
                        self._autoplay = False
                        self._status = PlaybackStatus.Playing
                        self._anchor = (now, self._pos)
                        tell = PlaybackState(self._status, self._pos, self._speed, False, "")
                    else:
                        self._cond.wait(_SETTLE if self._pairs else None)
                        continue
                elif self._announce:
                    self._announce = False
                    tell = PlaybackState(self._status, self._clock(now), self._speed, False, "")
                elif self._status != PlaybackStatus.Playing:
                    self._cond.wait()
                    continue
                else:
                    clock = self._clock(now)
                    n = 0
                    sent = 0
                    while n < len(held) and held[n][0] <= clock:
                        t, cid, data = held[n]
                        channel = self._channels.get(cid)
                        if channel is not None:  # (a message on no channel of the log: none)
                            channel.log(data, log_time=t)
                            sent += 1
                        n += 1
                    if n:
                        del held[:n]
                        self.sent += sent
                    if not held and exhausted:  # every message sent: the end
                        self._status = PlaybackStatus.Ended
                        self._pos = self.index.end_ns
                        tell = PlaybackState(self._status, self._pos, self._speed, False, "")
                        broadcast = self._pos
                        self._cond.notify_all()
                    elif held:
                        if now - last_broadcast >= _TICK:  # every message up to it sent
                            broadcast = min(clock, held[0][0] - 1)
                        due = self._anchor[0] + (held[0][0] - self._anchor[1]) / (self._speed * 1e9)
                        if due > now and broadcast is None:
                            self._cond.wait(min(_TICK, due - now))
                            continue
                    horizon = clock + int(_TICK * self._speed * 1e9)  # read what is due soon
            if cursor is None:  # outside the lock: reading may take a while
                cursor = _Cursor(self._file, self.index, start)
                self._broadcast(start)
                last_broadcast = time.monotonic()
                continue
            if tell is not None:
                self._tell(tell)
            if broadcast is not None:
                self._broadcast(broadcast)
                last_broadcast = time.monotonic()
            if tell is not None or exhausted or held:
                continue
            # nothing held: read ahead what falls due before the next tick (at least one)
            while len(held) < _BATCH:
                t_next = cursor.peek()
                if t_next is None:
                    exhausted = True
                    self._note_problem(cursor)
                    break
                if held and t_next > horizon:
                    break
                held.append(cursor.pop())

    def _note_problem(self, cursor: _Cursor) -> None:
        if cursor.problem and cursor.problem != self.problem:
            self.problem = cursor.problem
            self._say(f"serve: {self.index.path}: {cursor.problem}")

    def _broadcast(self, t_ns: int) -> None:
        if not self._closed:
            self.server.broadcast_time(int(t_ns))

    # -- the end ---------------------------------------------------------------------------

    def close(self, linger: float = 0.0) -> None:
        """Stop playing, give subscribed clients up to ``linger`` s to take what the server
        still holds for them and leave, and stop the server (waiting at most ``STOP_TIMEOUT``
        s for it: a client that no longer reads is left behind, said through ``say``)."""
        with self._cond:
            if self._closing:
                return
            self._closing = True
            self._cond.notify_all()
        self._thread.join()
        deadline = time.monotonic() + linger
        with self._cond:
            while self._pairs and (left := deadline - time.monotonic()) > 0:
                self._cond.wait(left)
        self._closed = True
        problem = stop_server(self.server, "serve")
        if problem:
            self._say(problem)
        self._file.close()

    def __enter__(self) -> LogServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def serve_log(
    log: str | os.PathLike[str],
    address: str = DEFAULT_ADDRESS,
    *,
    speed: float = 1.0,
    autoplay: bool = True,
) -> LogServer:
    """Serve the MCAP log ``log`` to Foxglove on ``address`` (``HOST:PORT``; port 0: a free
    one, see ``.url``) at ``speed`` (0.1 to 100) times its own pace, playing once a client
    subscribes (``autoplay``); a ``LogServer`` to control (``play``, ``pause``, ``seek``,
    ``set_speed``) and to ``close``. In Foxglove: Open connection, Foxglove WebSocket, the URL.
    """
    host, port = parse_address(address, "address")
    return LogServer(log, host, port, speed=speed, autoplay=autoplay)
