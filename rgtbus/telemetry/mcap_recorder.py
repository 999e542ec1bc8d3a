"""The MCAP recorder: a run's records into an MCAP file through foxglove-sdk's writer, the file
a valid MCAP prefix at every moment (docs/foxglove.md, "A log cut short")."""

from __future__ import annotations

import contextlib
import errno
import functools
import logging
import threading
import time
from collections.abc import Callable, Collection, Iterator
from typing import Any, BinaryIO

import foxglove
from foxglove.mcap import MCAPCompression, MCAPWriteOptions

from rgtbus.errors import BadInput, IOFailure, RgtbusError
from rgtbus.telemetry import topics
from rgtbus.telemetry.message_json import _U64_MAX
from rgtbus.telemetry.recorder import LiveSink, _Encoding, unfinished_trailer
from rgtbus.telemetry.records import MEDIUM
from rgtbus.telemetry.version import FORMAT_RECORD, format_metadata
from rgtbus.timebase import ns

_COMPRESSION = {
    "zstd": MCAPCompression.Zstd,
    "lz4": MCAPCompression.Lz4,
    "none": None,
}


class _WatchedStream:
    """The caller's stream as foxglove's writer sees it, so that the file is always a valid
    MCAP prefix (docs/foxglove.md, "A log cut short").

    The writer streams a chunk as it fills it: its header first, with placeholder lengths it
    seeks back to patch once the chunk is finished. A process killed in between would leave a
    chunk whose length says 2⁶⁴ − 1, and the standard readers stop there, reading nothing
    after the last good record. So what the writer writes since the last ``commit`` is held
    here in memory (seeks and patches within it included) and reaches the stream only at
    ``commit``, which the recorder calls once the writer has finished its chunk: the file
    grows by whole records only. A seek before the held bytes (none is expected) writes
    through to the stream.

    The Rust writer reports a failed write only as "I/O error" (and, inside ``Channel.log``,
    not at all): this keeps the first ``OSError`` so the recorder can name it (a full disk, a
    closed pipe)."""

    def __init__(self, stream: BinaryIO) -> None:
        self.stream = stream
        self.error: OSError | None = None
        self._seekable = _seekable(stream)
        self._base = self._watch(stream.tell) if self._seekable else 0  # where held starts
        self._trailing = 0  # bytes of trailer on the stream after _base
        self._last_trailer = b""  # those bytes
        self._held = bytearray()  # the bytes from _base on, not yet on the stream
        self._pos = self._base  # the writer's position

    def _watch(self, call: Callable[[], Any]) -> Any:
        try:
            return call()
        except OSError as e:
            if self.error is None:
                self.error = e
            raise

    def write(self, data: bytes | bytearray) -> int:
        n = len(data)
        at = self._pos - self._base
        if at < 0:  # before what is held: straight to the stream, where it was asked for
            head = data[: min(n, -at)]
            self._watch(lambda: self.stream.seek(self._pos))
            self._watch(lambda: self.stream.write(head))
            self._watch(lambda: self.stream.seek(self._base + self._trailing))
            data, at = data[len(head) :], 0
            self._pos += len(head)
        end = at + len(data)
        if end > len(self._held):
            self._held.extend(b"\0" * (end - len(self._held)))
        self._held[at:end] = data
        self._pos += len(data)
        return n

    def seek(self, offset: int, whence: int = 0) -> int:
        if whence == 0:
            self._pos = offset
        elif whence == 1:
            self._pos += offset
        else:
            self._pos = self._base + len(self._held) + offset
        return self._pos

    def tell(self) -> int:
        return self._pos

    def commit(self, trailer: bytes = b"") -> None:
        """Hand what is held to the stream (the writer has finished its chunk), followed by
        ``trailer`` (which the next commit overwrites: a seekable stream only), and flush it.
        One write: a process killed now leaves the last trailer or this one whole. A write
        that fails part way (a full disk) puts the last trailer back where it was, cutting
        what was written after it: the file stays whole to every reader, as far as the last
        flush that went through."""
        held, self._held = bytes(self._held), bytearray()
        seekable = self._seekable
        if not held and not (trailer and seekable) and not self._trailing:
            return
        if seekable and self._trailing:
            self._watch(lambda: self.stream.seek(self._base))
        tail = trailer if seekable else b""
        try:
            self._write_all(held + tail)
        except OSError:
            self._put_back_trailer()
            raise
        self._base += len(held)
        if seekable and self._trailing > len(tail):  # the last trailer was longer: cut it
            self._watch(lambda: self.stream.truncate(self._base + len(tail)))
        self._trailing, self._last_trailer = len(tail), tail
        flush = getattr(self.stream, "flush", None)
        if flush is not None:
            self._watch(flush)

    def _write_all(self, data: bytes) -> None:
        """``data`` to the stream, however many writes an unbuffered file takes."""
        view = memoryview(data)
        while view:
            try:
                n = self.stream.write(view)
                if not n:  # a stream that takes nothing and says no error
                    raise OSError(errno.EIO, "the stream took no bytes")
            except OSError as e:
                if self.error is None:
                    self.error = e
                raise
            view = view[n:]

    def _put_back_trailer(self) -> None:
        """After a failed write: the file cut back to the last flush and its trailer written
        again where it was (best effort: the space it needs was just given back)."""
        if not (self._seekable and self._trailing):
            return
        with contextlib.suppress(OSError, ValueError):
            self.stream.seek(self._base)
            self.stream.truncate(self._base)
            view = memoryview(self._last_trailer)
            while view:
                n = self.stream.write(view)
                if not n:
                    return
                view = view[n:]
            flush = getattr(self.stream, "flush", None)
            if flush is not None:
                flush()

    def flush(self) -> None:
        """The writer's own flushes hand nothing on: a chunk may be half written."""


def _seekable(stream: BinaryIO) -> bool:
    try:
        return bool(stream.seekable())
    except (AttributeError, OSError, ValueError):
        return False


@functools.cache
def sdk_logs_to_python() -> None:
    """foxglove-sdk's own messages go to Python's ``logging``, from level ERROR, instead of
    straight to stderr: a write that fails inside its writer ("error logging message: ...", a
    warning) is reported by the recorder itself, in one line. Called before the first sink
    (the SDK takes its level once); the root logger is left as the caller configured it
    (the SDK would otherwise ``basicConfig`` it)."""
    root = logging.getLogger()
    placeholder = logging.NullHandler()
    root.addHandler(placeholder)
    try:
        foxglove.set_log_level("ERROR")
    finally:
        root.removeHandler(placeholder)


def topic_channel(context: foxglove.Context, topic: str, schema: str) -> foxglove.Channel:
    """A foxglove channel for ``topic``: a hot topic's protobuf blocks under their
    ``FileDescriptorSet``, any other's JSON under its JSON Schema (the same for the MCAP file
    and the live view)."""
    schema_encoding, message_encoding = topics.encodings(schema)
    return foxglove.Channel(
        topic,
        schema=foxglove.Schema(
            name=schema, encoding=schema_encoding, data=topics.schema_bytes(schema)
        ),
        message_encoding=message_encoding,
        context=context,
    )


class McapRecorder(_Encoding):
    """Writes an MCAP file to ``stream`` (opened by the caller, never closed here; it must
    support ``write``, ``seek`` and ``tell``). ``close`` finishes the file (summary, footer).

    The writer is foxglove-sdk's (Rust; a message costs a fraction of what it costs in
    mcap-py's, which matters for runs of millions of records). Every recorder has its own
    ``foxglove.Context``; its channels carry each topic with its JSON Schema, so a live sink
    on the same context (``context``) sees exactly what the file gets. Chunks are compressed
    with ``compression`` (zstd, lz4 or none) at ``compression_level`` (0: the compressor's
    own default; 1, zstd's fastest, by default).

    A failed write (an unwritable path, a full disk) raises ``RgtbusError`` naming the stream;
    ``failed`` then holds that line and nothing more is written (``close`` writes nothing).

    The log is written as the run goes: the chunk in progress is finished and flushed to the
    stream once it holds ``flush_messages`` messages, once it holds ``chunk_size`` bytes, and at
    least every ``flush_wall`` seconds of wall time (a background flusher: a paced or waiting
    run writes little), so a process killed outright loses at most about ``flush_wall`` seconds
    of its records (the file then reads as truncated). ``flush_seconds`` (off by default) also
    finishes a chunk once the present (the latest log time of a record) is that many simulated
    seconds past where it was at the chunk's first record (records told late, like a unit's
    spikes, change nothing; a topic written ahead of the present by design, ``ahead_topics``,
    the medium, neither holds the others back nor finishes a chunk by its time). Off, because
    what a killed process keeps is a matter of wall time, which ``flush_wall`` bounds, and a
    long run that finishes a chunk every simulated second spends much of its log's cost on
    flushes."""

    def __init__(
        self,
        stream: BinaryIO,
        *,
        compression: str = "zstd",
        compression_level: int = 1,
        validate: bool = False,
        chunk_size: int = 1024 * 1024,
        flush_seconds: float | None = None,
        flush_messages: int = 4096,
        flush_wall: float = 0.5,
        live: LiveSink | None = None,
        ahead_topics: Collection[str] = (MEDIUM,),
    ) -> None:
        super().__init__(validate, live)
        if compression not in _COMPRESSION:
            raise BadInput(
                f"unknown MCAP compression {compression!r} (use {', '.join(_COMPRESSION)})"
            )
        if type(compression_level) is not int or not 0 <= compression_level <= 19:
            raise BadInput(
                f"MCAP compression level {compression_level!r} is not an integer 0..19 "
                "(0: the compressor's own default)"
            )
        if not (
            (flush_seconds is None or flush_seconds > 0) and flush_messages > 0 and flush_wall > 0
        ):
            raise BadInput("flush_seconds, flush_messages and flush_wall must be positive")
        self.stream = stream
        self.failed = None
        self._sink = _WatchedStream(stream)
        self.context = foxglove.Context()
        # mcap's default chunk of 1 MiB: what a killed run loses is bounded by flush_wall and
        # flush_messages; a chunk holds more units' records of one block, which compress as
        # one (a 200-unit run's log: 140 MB in chunks of 1 MiB, 195 MB in chunks of 256 KiB,
        # in the same time).
        # Compression on the calling thread: a launch runs one writer per unit process.
        # zstd's fastest level by default: a 200-unit run with its log took 28.7 s at level 1
        # and 30.5 s at zstd's default (3), for 195 MB of log instead of 190.
        options = MCAPWriteOptions(
            compression=_COMPRESSION[compression],
            compression_level=compression_level,
            profile="",
            chunk_size=chunk_size,
            compression_threads=0,
            calculate_chunk_crcs=True,
            calculate_data_section_crc=True,
            calculate_summary_section_crc=True,
        )
        sdk_logs_to_python()
        try:
            self._writer = foxglove.open_mcap(
                self._sink, context=self.context, writer_options=options
            )
            self._writer.write_metadata(FORMAT_RECORD, format_metadata())  # first, always
            self._writer.flush()
            # a valid (empty, unfinished) MCAP file from the start; a target that takes no
            # bytes fails here, before any run
            self._sink.commit(unfinished_trailer())
        except (OSError, RuntimeError) as e:
            raise self._broken(e) from None
        self._flush_ns = _U64_MAX if flush_seconds is None else ns(flush_seconds)
        self._by_time = flush_seconds is not None  # a chunk finished by simulated time too
        self._flush_messages = int(flush_messages)
        self._unflushed = 0
        # the present at which the chunk in progress is due (flush_ns after its first record)
        self._flush_due = _U64_MAX
        self._present = 0  # the latest log time of a record of the present so far
        self._ahead_topics = frozenset(ahead_topics)
        self._channels: dict[str, foxglove.Channel] = {}
        self._logs: dict[str, Callable[..., None]] = {}  # topic -> its channel's log
        # the writer is used from the run's thread and the wall-clock flusher: one at a time
        self._lock = threading.Lock()
        self._flush_wall = float(flush_wall)
        self._flushed_at = time.monotonic()
        self._stop_flusher = threading.Event()
        self._flusher = threading.Thread(
            target=self._flush_by_wall, name="rgtbus-log-flusher", daemon=True
        )
        self._flusher.start()

    def _flush_by_wall(self) -> None:
        """Flush what waits longer than ``flush_wall`` of wall time (never raises: a failed
        write is the run thread's to report)."""
        while not self._stop_flusher.wait(self._flush_wall / 2):
            if self._unflushed and time.monotonic() - self._flushed_at >= self._flush_wall:
                with contextlib.suppress(RgtbusError):
                    self.flush()

    @contextlib.contextmanager
    def _io(self) -> Iterator[None]:
        if self.failed:
            raise IOFailure(self.failed)
        try:
            yield
        except (OSError, RuntimeError) as e:
            raise self._broken(e) from None
        if self._sink.error is not None:  # a write inside the writer failed quietly
            raise self._broken(self._sink.error)

    @contextlib.contextmanager
    def raw_io(self) -> Iterator[None]:
        """Around a write to a channel of this recorder's ``context`` made elsewhere (``convert``
        copies topics under their own schemas): one writer at a time, a failed write one line."""
        with self._lock, self._io():
            yield
        self._unflushed += 1
        if self._unflushed >= self._flush_messages:
            self.flush()

    def _broken(self, e: Exception) -> RgtbusError:
        """The stream failed: remember the one line that says so (nothing more is written)."""
        cause = self._sink.error or e
        why = cause.strerror if isinstance(cause, OSError) and cause.strerror else str(cause)
        name = getattr(self.stream, "name", "<stream>")
        self.failed = f"cannot write log {str(name)!r}: {why}"
        return IOFailure(self.failed)

    def _channel(self, topic: str, schema: str) -> foxglove.Channel:
        channel = topic_channel(self.context, topic, schema)
        self._channels[topic] = channel
        # the channel's own log takes bytes straight to the Rust writer; foxglove's Python
        # wrapper around it re-checks the message type on every call, a good part of the cost
        base = getattr(channel, "base", None)
        self._logs[topic] = base.log if base is not None else channel.log
        return channel

    def _emit(self, topic: str, schema: str, data: bytes, t: int) -> None:
        """Hand one encoded message to the writer; the chunk is finished when due."""
        if self.failed:
            raise IOFailure(self.failed)
        log = self._logs.get(topic)
        if log is None:
            self._channel(topic, schema)
            log = self._logs[topic]
        with self._lock:
            log(data, t)
            self._unflushed += 1
            due = self._unflushed >= self._flush_messages
            if self._by_time and topic not in self._ahead_topics:
                # due once the present (the latest record's time) is one span past where it
                # was at the chunk's first record: records told late (a unit's spikes, logged
                # when it wakes) do not finish a chunk every few dozen messages; a topic
                # written ahead of the present by design says nothing of how far the run has
                # come, so it neither sets nor meets the due time (else it would finish a chunk
                # every few dozen messages)
                if t > self._present:
                    self._present = t
                if self._flush_due == _U64_MAX:
                    self._flush_due = min(self._present + self._flush_ns, _U64_MAX)
                due = due or self._present >= self._flush_due
        if self._sink.error is not None:
            raise self._broken(self._sink.error)
        if due:
            self.flush()

    def flush(self) -> None:
        """Finish the chunk in progress and hand everything to the stream (and flush it)."""
        if self.failed or self._closed:
            return
        with self._lock, self._io():
            if self._closed:
                return
            self._unflushed = 0
            self._flush_due = _U64_MAX  # set by the next chunk's first record of the present
            self._flushed_at = time.monotonic()
            self._writer.flush()  # the chunk in progress finished, its lengths patched
            self._sink.commit(unfinished_trailer())  # only now does the file grow

    def metadata(self, name: str, values: dict[str, str]) -> None:
        """Write a metadata record ``name`` of string values."""
        if self._closed:
            raise BadInput(f"metadata {name!r} on a closed recorder")
        values = self._check_metadata(name, values)
        with self._lock, self._io():
            self._writer.write_metadata(name, values)

    def close(self, finished: bool = True) -> None:
        """Stop the flusher and finish the file (summary and footer); again does nothing. Nothing
        is written once the stream has failed. ``finished=False`` (a run interrupted): what was
        logged goes out and the file ends as a cut log does (its ``UNFINISHED`` trailer: a
        whole file to every reader, truncated to rgtbus), not as a whole run's."""
        if self._closed:
            return
        if not self.failed:  # what is still held goes out (a failed write ends it here)
            with contextlib.suppress(RgtbusError):
                self._release_all()
        self._stop_flusher.set()
        self._flusher.join()
        if not finished:
            self.flush()
            self._closed = True
            for channel in self._channels.values():
                channel.close()
            return
        self._closed = True
        for channel in self._channels.values():
            channel.close()
        if self.failed:
            return  # the file is lost either way; its error is already on its way
        with self._io():
            self._writer.close()
            self._sink.commit()
