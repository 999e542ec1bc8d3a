"""Recorders: where every step of a run is written. MCAP for real runs, memory for tests.

Messages are JSON with a JSON Schema per topic (see ``topics.py``), so Foxglove opens the file.
Time is simulated: ``log_time = publish_time = t_ns`` (integer nanoseconds from the run start).
"""

from __future__ import annotations

import contextlib
import json
import operator
import os
import struct
import threading
import time
import zlib
from collections import Counter
from collections.abc import Callable, Collection, Iterator, Mapping
from dataclasses import dataclass, field
from typing import IO, Any, BinaryIO, Protocol, Self, cast, runtime_checkable

import foxglove
import mcap.exceptions
import orjson
from foxglove.mcap import MCAPCompression, MCAPWriteOptions
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk

from rgtbus.errors import RgtbusError
from rgtbus.telemetry import topics, validate
from rgtbus.timebase import ns, seconds

LOG_TOPIC = "/log"
LOG_LEVELS = {"unknown": 0, "debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}
_COMPRESSION = {
    "zstd": MCAPCompression.Zstd,
    "lz4": MCAPCompression.Lz4,
    "none": None,
}
_U64_MAX = 2**64 - 1
MCAP_MAGIC = b"\x89MCAP0\r\n"


@runtime_checkable
class Recorder(Protocol):
    enabled: bool

    def write(self, topic: str, message: Mapping[str, Any], t_ns: int) -> None: ...
    def log(self, level: str, text: str, t_ns: int, name: str = "rgtbus") -> None: ...
    def metadata(self, name: str, values: dict[str, str]) -> None: ...
    def close(self) -> None: ...


class LiveSink(Protocol):
    """Where a recorder also offers each encoded message (a live view)."""

    def put(self, topic: str, schema: str, data: bytes, t_ns: int) -> None: ...


def _default(obj: Any) -> Any:
    # numpy arrays and scalars without importing numpy here
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def _check_t_ns(t_ns: Any) -> int:
    try:
        if isinstance(t_ns, bool):
            raise TypeError
        t = operator.index(t_ns)  # ints and numpy integers; never floats
    except TypeError:
        raise RgtbusError(f"t_ns must be an int of nanoseconds, got {t_ns!r}") from None
    if not 0 <= t <= _U64_MAX:
        raise RgtbusError(f"t_ns {t} out of range 0..2**64-1")
    return t


def level_number(level: str) -> int:
    """foxglove.Log level for a level name: debug 1, info 2, warning 3, error 4, fatal 5."""
    try:
        return LOG_LEVELS[level]
    except (KeyError, TypeError):
        names = ", ".join(k for k in LOG_LEVELS if k != "unknown")
        raise RgtbusError(f"unknown log level {level!r} (use {names})") from None


def log_message(
    level: str, text: str, t_ns: int, name: str = "rgtbus", file: str = "", line: int = 0
) -> dict[str, Any]:
    """A foxglove.Log message."""
    t = _check_t_ns(t_ns)
    return {
        "timestamp": {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000},
        "level": level_number(level),
        "message": str(text),
        "name": str(name),
        "file": str(file),
        "line": int(line),
    }


# The standard encoder refuses NaN and infinity (JSON has neither); orjson writes them as null.
_JSON = json.JSONEncoder(separators=(",", ":"), allow_nan=False, default=_default)
_ORJSON = orjson.OPT_SERIALIZE_NUMPY | orjson.OPT_NON_STR_KEYS


def encode_json(message: Any) -> bytes:
    """A message as compact JSON (numpy values as numbers and lists); TypeError for what JSON
    cannot hold, ValueError for NaN or infinity."""
    data = orjson.dumps(message, default=_default, option=_ORJSON)
    if b"null" in data:  # a None, or a NaN or infinity written as null: let json tell
        _JSON.encode(message)
    return data


class _Encoding:
    """Topic check, JSON encoding and optional validation, shared by the real recorders."""

    enabled = True

    def __init__(self, validate: bool) -> None:
        self.validate = validate
        self.counts: Counter[str] = Counter()  # messages written per topic
        self._closed = False
        self._schemas: dict[str, str] = {}  # topic -> schema name, once looked up

    def _encode(self, topic: str, message: Mapping[str, Any], t_ns: int) -> tuple[str, bytes, int]:
        if self._closed:
            raise RgtbusError(f"write to {topic!r} on a closed recorder")
        schema = self._schemas.get(topic) or self._schemas.setdefault(
            topic, topics.schema_for(topic)
        )
        # the common case first: a plain int in range (a run writes millions of these)
        t = t_ns if type(t_ns) is int and 0 <= t_ns <= _U64_MAX else _check_t_ns(t_ns)
        if type(message) is not dict and not isinstance(message, dict):
            raise RgtbusError(f"message on {topic} must be a dict, got {type(message).__name__}")
        try:
            data = encode_json(message)
        except (TypeError, ValueError) as e:
            raise RgtbusError(f"message on {topic} at t_ns={t} is not JSON: {e}") from None
        if self.validate:
            errs = validate.errors(json.loads(data), topics.load_schema(schema))
            if errs:
                more = f" (+{len(errs) - 1} more)" if len(errs) > 1 else ""
                raise RgtbusError(f"message on {topic} breaks {schema}: {errs[0]}{more}")
        self.counts[topic] += 1
        return schema, data, t

    @staticmethod
    def _check_metadata(name: str, values: dict[str, str]) -> dict[str, str]:
        if not isinstance(name, str) or not name:
            raise RgtbusError(f"metadata name must be a non-empty string, got {name!r}")
        if not isinstance(values, dict):
            raise RgtbusError(f"metadata {name!r} must be a dict of strings")
        for k, v in values.items():
            if not isinstance(k, str) or not isinstance(v, str):
                raise RgtbusError(f"metadata {name!r}: {k!r}: {v!r} is not a string to a string")
        return dict(values)

    def log(
        self,
        level: str,
        text: str,
        t_ns: int,
        name: str = "rgtbus",
        *,
        file: str = "",
        line: int = 0,
    ) -> None:
        self.write(LOG_TOPIC, log_message(level, text, t_ns, name, file, line), t_ns)

    def write(self, topic: str, message: Mapping[str, Any], t_ns: int) -> None:
        raise NotImplementedError

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _WatchedStream:
    """The caller's stream as foxglove's writer sees it. The Rust writer reports a failed
    write only as "I/O error" (and, inside ``Channel.log``, not at all): this keeps the first
    ``OSError`` so the recorder can name it (a full disk, a closed pipe)."""

    def __init__(self, stream: BinaryIO) -> None:
        self.stream = stream
        self.error: OSError | None = None

    def _watch(self, call: Callable[[], Any]) -> Any:
        try:
            return call()
        except OSError as e:
            if self.error is None:
                self.error = e
            raise

    def write(self, data: bytes | bytearray) -> int:
        return cast(int, self._watch(lambda: self.stream.write(data)))

    def seek(self, offset: int, whence: int = 0) -> int:
        return cast(int, self._watch(lambda: self.stream.seek(offset, whence)))

    def tell(self) -> int:
        return cast(int, self._watch(self.stream.tell))

    def flush(self) -> None:
        flush = getattr(self.stream, "flush", None)
        if flush is not None:
            self._watch(flush)


def topic_channel(context: foxglove.Context, topic: str, schema: str) -> foxglove.Channel:
    """A foxglove channel for ``topic``: JSON messages under the topic's JSON Schema (the same
    for the MCAP file and the live view)."""
    return foxglove.Channel(
        topic,
        schema=foxglove.Schema(
            name=schema, encoding=topics.SCHEMA_ENCODING, data=topics.schema_bytes(schema)
        ),
        message_encoding=topics.MESSAGE_ENCODING,
        context=context,
    )


class McapRecorder(_Encoding):
    """Writes an MCAP file to ``stream`` (opened by the caller, never closed here; it must
    support ``write``, ``seek`` and ``tell``). ``close`` finishes the file (summary, footer).

    The writer is foxglove-sdk's (Rust; a message costs ~3 µs against ~10 µs in mcap-py's,
    which matters for runs of millions of records). Every recorder has its own
    ``foxglove.Context``; its channels carry each topic with its JSON Schema, so a live sink
    on the same context (``context``) sees exactly what the file gets.

    A failed write (an unwritable path, a full disk) raises ``RgtbusError`` naming the stream;
    ``failed`` then holds that line and nothing more is written (``close`` writes nothing).

    The log is written as the run goes: the chunk in progress is finished and flushed to the
    stream once it holds ``flush_messages`` messages, once the present (the latest log time
    of a record) is ``flush_seconds`` past where it was at the chunk's first record (records
    told late, like a unit's spikes, change nothing; a topic written ahead of the present by
    design, ``ahead_topics``, the medium, neither holds the others back nor finishes a chunk
    by its time), and at least every ``flush_wall`` seconds of wall time (a
    background flusher: a paced or waiting run writes little), so a process killed outright
    loses at most about ``flush_wall`` seconds of its records (the file then reads as
    truncated)."""

    def __init__(
        self,
        stream: BinaryIO,
        *,
        compression: str = "zstd",
        validate: bool = False,
        chunk_size: int = 256 * 1024,
        flush_seconds: float = 1.0,
        flush_messages: int = 4096,
        flush_wall: float = 0.5,
        live: LiveSink | None = None,
        ahead_topics: Collection[str] = ("/medium",),
    ) -> None:
        super().__init__(validate)
        self.live = live  # every message is offered to it too (rgtbus.telemetry.live)
        if compression not in _COMPRESSION:
            raise RgtbusError(
                f"unknown MCAP compression {compression!r} (use {', '.join(_COMPRESSION)})"
            )
        if not (flush_seconds > 0 and flush_messages > 0 and flush_wall > 0):
            raise RgtbusError("flush_seconds, flush_messages and flush_wall must be positive")
        self.stream = stream
        self.failed: str | None = None
        self._sink = _WatchedStream(stream)
        self.context = foxglove.Context()
        # Smaller chunks than mcap's 1 MiB default: a killed run loses at most one chunk.
        # Compression on the calling thread: a launch runs one writer per unit process.
        options = MCAPWriteOptions(
            compression=_COMPRESSION[compression],
            profile="",
            chunk_size=chunk_size,
            compression_threads=0,
            calculate_chunk_crcs=True,
            calculate_data_section_crc=True,
            calculate_summary_section_crc=True,
        )
        try:
            self._writer = foxglove.open_mcap(
                self._sink, context=self.context, writer_options=options
            )
            self._writer.flush()  # a target that takes no bytes fails here, before any run
        except (OSError, RuntimeError) as e:
            raise self._broken(e) from None
        self._flush_ns = ns(flush_seconds)
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
            raise RgtbusError(self.failed)
        try:
            yield
        except (OSError, RuntimeError) as e:
            raise self._broken(e) from None
        if self._sink.error is not None:  # a write inside the writer failed quietly
            raise self._broken(self._sink.error)

    def _broken(self, e: Exception) -> RgtbusError:
        """The stream failed: remember the one line that says so (nothing more is written)."""
        cause = self._sink.error or e
        why = cause.strerror if isinstance(cause, OSError) and cause.strerror else str(cause)
        name = getattr(self.stream, "name", "<stream>")
        self.failed = f"cannot write log {str(name)!r}: {why}"
        return RgtbusError(self.failed)

    def _channel(self, topic: str, schema: str) -> foxglove.Channel:
        channel = topic_channel(self.context, topic, schema)
        self._channels[topic] = channel
        # the channel's own log takes bytes straight to the Rust writer; foxglove's Python
        # wrapper around it re-checks the message type on every call (~2 µs of ~7)
        base = getattr(channel, "base", None)
        self._logs[topic] = base.log if base is not None else channel.log
        return channel

    def write(self, topic: str, message: Mapping[str, Any], t_ns: int) -> None:
        schema, data, t = self._encode(topic, message, t_ns)
        if self.failed:
            raise RgtbusError(self.failed)
        log = self._logs.get(topic)
        if log is None:
            self._channel(topic, schema)
            log = self._logs[topic]
        with self._lock:
            log(data, t)
            self._unflushed += 1
            if topic in self._ahead_topics:
                # written ahead of the present by design: its time says nothing of how far
                # the run has come, so it neither sets nor meets the due time (the medium
                # used to finish a chunk every few dozen messages: ~2,800 flushes at n = 20)
                due = self._unflushed >= self._flush_messages
            else:
                # due once the present (the latest record's time) is one span past where it
                # was at the chunk's first record: records told late (a unit's spikes, logged
                # when it wakes) do not finish a chunk every few dozen messages
                if t > self._present:
                    self._present = t
                if self._flush_due == _U64_MAX:
                    self._flush_due = self._present + self._flush_ns
                due = self._unflushed >= self._flush_messages or self._present >= self._flush_due
        if self.live is not None:
            self.live.put(topic, schema, data, t)
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
            self._writer.flush()

    def metadata(self, name: str, values: dict[str, str]) -> None:
        if self._closed:
            raise RgtbusError(f"metadata {name!r} on a closed recorder")
        values = self._check_metadata(name, values)
        with self._lock, self._io():
            self._writer.write_metadata(name, values)

    def close(self) -> None:
        if self._closed:
            return
        self._stop_flusher.set()
        self._flusher.join()
        self._closed = True
        for channel in self._channels.values():
            channel.close()
        if self.failed:
            return  # the file is lost either way; its error is already on its way
        with self._io():
            self._writer.close()
            self._sink.flush()


class MemoryRecorder(_Encoding):
    """The in-process twin: keeps what an MCAP file would hold, JSON round-tripped so reading
    it back equals ``read_log`` of the same writes. Validates by default (it serves tests)."""

    def __init__(self, *, validate: bool = True) -> None:
        super().__init__(validate)
        self.messages: list[tuple[str, int, dict]] = []
        self.metadata_records: dict[str, dict[str, str]] = {}
        self.logs: list[dict[str, Any]] = []

    def write(self, topic: str, message: Mapping[str, Any], t_ns: int) -> None:
        _, data, t = self._encode(topic, message, t_ns)
        decoded = orjson.loads(data)
        self.messages.append((topic, t, decoded))
        if topic == LOG_TOPIC:
            self.logs.append(decoded)

    def metadata(self, name: str, values: dict[str, str]) -> None:
        if self._closed:
            raise RgtbusError(f"metadata {name!r} on a closed recorder")
        values = self._check_metadata(name, values)
        if values:  # as in the MCAP file: foxglove's writer skips a record with no values
            self.metadata_records[name] = values

    def read(self) -> LogContents:
        """What ``read_log`` would return for the same writes."""
        msgs = sorted(self.messages, key=lambda m: m[1])
        return LogContents(msgs, {k: dict(v) for k, v in self.metadata_records.items()})

    def close(self) -> None:
        self._closed = True


class NullRecorder:
    """Records nothing. ``enabled`` is False so callers can skip building messages."""

    enabled = False
    closed = False

    def write(self, topic: str, message: Mapping[str, Any], t_ns: int) -> None:
        pass

    def log(self, level: str, text: str, t_ns: int, name: str = "rgtbus", **_: Any) -> None:
        pass

    def metadata(self, name: str, values: dict[str, str]) -> None:
        pass

    def close(self) -> None:
        self.closed = True

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LogContents(tuple):
    """``(messages, metadata)`` — unpacks as a pair — plus how the read ended.

    messages: ``[(topic, log_time_ns, message), ...]`` in log-time order (file order on ties);
    metadata: ``{name: {key: value}}`` (a repeated name: the last record wins).
    ``truncated``: the file ended before its footer; ``note``: one line saying where and why;
    ``end_ns``: log time of the last message read (None when there was none).
    """

    messages: list[tuple[str, int, dict]]
    metadata: dict[str, dict[str, str]]
    truncated: bool
    note: str

    def __new__(
        cls,
        messages: list[tuple[str, int, dict]],
        metadata: dict[str, dict[str, str]],
        truncated: bool = False,
        note: str = "",
    ) -> LogContents:
        self = super().__new__(cls, (messages, metadata))
        self.messages = messages
        self.metadata = metadata
        self.truncated = truncated
        self.note = note
        return self

    @property
    def end_ns(self) -> int | None:
        return max((m[1] for m in self.messages), default=None)


def read_log(source: str | os.PathLike[str] | IO[bytes]) -> LogContents:
    """Read an MCAP log written by McapRecorder: a path or a binary stream.

    Reads sequentially (no index needed), so a truncated file yields every complete record
    before the cut and ``truncated=True`` with a note. Not an MCAP file: RgtbusError.
    """
    if isinstance(source, str | os.PathLike):
        try:
            with open(source, "rb") as f:
                return _read(f, os.fspath(source))
        except OSError as e:
            raise RgtbusError(f"cannot read log {os.fspath(source)!r}: {e.strerror}") from None
    return _read(source, getattr(source, "name", "<stream>"))


@dataclass
class RawLog:
    """An MCAP file's records as written, undecoded (what ``merge`` needs).

    ``messages``: ``[(channel_id, log_time, publish_time, sequence, data), ...]`` in file
    order; ``metadata``: every Metadata record in file order (repeated names kept);
    ``note``: empty, or one line saying where and why the file was cut.
    """

    label: str
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: list[tuple[int, int, int, int, bytes]] = field(default_factory=list)
    metadata: list[tuple[str, dict[str, str]]] = field(default_factory=list)
    note: str = ""
    corruption: str = ""  # one line: what is damaged and where (read up to there)
    library: str | None = None  # the writer named in the Header (None: no header read)

    @property
    def truncated(self) -> bool:
        return bool(self.note)

    @property
    def corrupt(self) -> bool:
        return bool(self.corruption)

    @property
    def header_only(self) -> bool:
        """Nothing but a Header: no schema, channel, message or metadata record."""
        return not (self.schemas or self.channels or self.messages or self.metadata)


def scan_log(source: str | os.PathLike[str] | IO[bytes]) -> RawLog:
    """Every record of an MCAP file (path or binary stream), read sequentially so a truncated
    file yields all complete records before the cut. Not an MCAP file: RgtbusError."""
    if isinstance(source, str | os.PathLike):
        try:
            with open(source, "rb") as f:
                return _scan(f, os.fspath(source))
        except OSError as e:
            raise RgtbusError(f"cannot read log {os.fspath(source)!r}: {e.strerror}") from None
    return _scan(source, getattr(source, "name", "<stream>"))


class _Corrupt(Exception):
    """Raised inside the scan to stop at damage; its text says what and where."""


class _Tracked:
    """The stream as StreamReader reads it (exact reads, no read-ahead): the position, whether
    a read came back short (the file ended inside a record: truncation, not damage), and from
    the data section's end on, the bytes the footer's summary CRC covers."""

    def __init__(self, stream: IO[bytes]) -> None:
        self.stream = stream
        self.pos = 0
        self.short = False
        self.capture: bytearray | None = None

    def read(self, n: int = -1) -> bytes:
        data = self.stream.read(n)
        if n is not None and n >= 0 and len(data) < n:
            self.short = True
        self.pos += len(data)
        if self.capture is not None:
            self.capture += data
        return data


def _ends_with_magic(stream: IO[bytes]) -> bool:
    """A finished MCAP file ends with the magic: a record running past the end of such a file
    has a damaged length, it was not cut. False when the stream cannot tell."""
    try:
        if not stream.seekable():
            return False
        here = stream.tell()
        size = stream.seek(0, os.SEEK_END)
        if size < 2 * len(MCAP_MAGIC):
            stream.seek(here)
            return False
        stream.seek(size - len(MCAP_MAGIC))
        tail = stream.read(len(MCAP_MAGIC))
        stream.seek(here)
        return tail == MCAP_MAGIC
    except (OSError, ValueError, AttributeError):
        return False


def _chunk_in_progress(stream: IO[bytes], start: int) -> bool:
    """Whether the record at ``start`` is a chunk whose length is still the placeholder a
    streaming writer (foxglove-sdk's) puts there until the chunk is finished: the writer
    stopped inside it, so the file is cut, not damaged."""
    try:
        stream.seek(start)
        head = stream.read(9)
    except (OSError, ValueError):
        return False
    return len(head) == 9 and head[0] == 0x06 and head[1:] == b"\xff" * 8


def _seconds(t_ns: int) -> str:
    return f"{seconds(t_ns):.3f}"


def _scan(stream: IO[bytes], label: str) -> RawLog:
    raw = RawLog(label)
    src = _Tracked(stream)
    # Chunks come out whole (emit_chunks) so each is CRC-checked here and damage is located;
    # validate_crcs makes the reader check the data section's CRC at DataEnd (when written).
    reader = StreamReader(
        cast(IO[bytes], src), emit_chunks=True, validate_crcs=True, record_size_limit=2**30
    )
    started = finished = False  # a Header read; the data section's end (DataEnd) reached
    start = len(MCAP_MAGIC)  # byte offset of the record being read

    def take(rec: Any) -> None:
        if isinstance(rec, Message):
            if rec.channel_id not in raw.channels:
                raise _Corrupt(
                    f"record at byte {start}: message on unknown channel {rec.channel_id}"
                )
            raw.messages.append(
                (rec.channel_id, rec.log_time, rec.publish_time, rec.sequence, rec.data)
            )
        elif isinstance(rec, Channel):
            raw.channels[rec.id] = rec
        elif isinstance(rec, Schema):
            raw.schemas[rec.id] = rec

    try:
        for rec in reader.records:
            if src.short:  # the record's declared length ran past the end: not taken
                raise mcap.exceptions.EndOfFile()
            if not started and not isinstance(rec, Header):
                raise _Corrupt(f"record at byte {start}: the first record is not a Header")
            if isinstance(rec, Header):
                started = True
                raw.library = rec.library
            elif isinstance(rec, Chunk):
                where = (
                    f"chunk at byte {start} (log time {_seconds(rec.message_start_time)}"
                    f"–{_seconds(rec.message_end_time)} s)"
                )
                try:
                    inner = breakup_chunk(rec, validate_crc=True)
                except CRCValidationError as e:
                    raise _Corrupt(
                        f"{where}: CRC mismatch (stored {e.expected:#010x}, "
                        f"computed {e.actual:#010x})"
                    ) from None
                except Exception as e:  # a complete chunk that does not decompress or parse
                    raise _Corrupt(f"{where}: cannot be read ({type(e).__name__}: {e})") from None
                for r in inner:
                    take(r)
            elif isinstance(rec, Metadata) and not finished:
                raw.metadata.append((rec.name, dict(rec.metadata)))
            elif isinstance(rec, DataEnd):
                finished = True
                src.capture = bytearray()  # the summary, then the footer
            elif isinstance(rec, Footer):
                finished = True
                covered = bytes(src.capture or b"")[:-4]  # all but the CRC field itself
                if rec.summary_crc != 0 and zlib.crc32(covered) != rec.summary_crc:
                    raise _Corrupt(
                        f"summary section (from byte {rec.summary_start}): CRC mismatch "
                        f"(stored {rec.summary_crc:#010x}, computed {zlib.crc32(covered):#010x})"
                    )
                src.capture = None
            elif not finished:
                take(rec)  # unchunked records; the summary's copies are not needed
            start = src.pos
        extra = len(src.read(1))
        while extra and (more := len(stream.read(1 << 20))):
            extra += more
        if extra:
            raise _Corrupt(
                f"{extra} bytes of trailing garbage after the footer (the log itself is complete)"
            )
    except _Corrupt as e:
        raw.corruption = f"{label}: corrupt log: {e}"
    except mcap.exceptions.InvalidMagic:
        if not started:
            raise RgtbusError(f"{label}: not an MCAP file (bad magic)") from None
        raw.corruption = f"{label}: corrupt log: bad magic after the footer"
    except CRCValidationError as e:  # the data section's CRC, checked at DataEnd
        raw.corruption = (
            f"{label}: corrupt log: data section CRC mismatch (stored {e.expected:#010x}, "
            f"computed {e.actual:#010x})"
        )
    except Exception as e:  # EndOfFile, short struct reads, a damaged record
        if not started:
            if src.pos > len(MCAP_MAGIC) and not (src.short and not _ends_with_magic(stream)):
                raise RgtbusError(
                    f"{label}: corrupt log: its header record is damaged ({type(e).__name__})"
                ) from None
            raise RgtbusError(
                f"{label}: not an MCAP file (empty or cut before its header)"
            ) from None
        if _chunk_in_progress(stream, start) and not _ends_with_magic(stream):
            raw.note = (
                f"{label}: log truncated after {len(raw.messages)} messages (cut in a chunk "
                "the writer had not finished)"
            )
        elif src.short and not _ends_with_magic(stream):
            n = len(raw.messages)
            where = "in its summary (all messages present)" if finished else f"after {n} messages"
            cut = isinstance(e, mcap.exceptions.EndOfFile | struct.error)
            why = "cut mid-record" if cut else f"{type(e).__name__}: {e}"
            raw.note = f"{label}: log truncated {where} ({why})"
        elif src.short:
            raw.corruption = (
                f"{label}: corrupt log: record at byte {start} runs past the end of a file "
                "that ends with MCAP's closing magic (a damaged record length)"
            )
        else:
            raw.corruption = (
                f"{label}: corrupt log: record at byte {start}: {type(e).__name__}: {e}"
            )
    if raw.note and raw.messages:  # how far it read, in the run's own time
        raw.note += f"; last log time read {seconds(max(m[1] for m in raw.messages)):.6f} s"
    return raw


def require_run_log(raw: RawLog) -> None:
    """Refuse (one-line ``RgtbusError``) a log that is corrupt, holds only a header, or was
    not written by an rgtbus run (no ``scenario`` or ``run`` metadata). Truncation passes:
    everything before the cut is good."""
    if raw.corrupt:
        raise RgtbusError(raw.corruption)
    _require_run(raw.label, raw.library, {name for name, _ in raw.metadata}, raw.header_only)


def _require_run(label: str, library: str | None, names: set[str], header_only: bool) -> None:
    by = f" (written by {library!r})" if library else ""
    if header_only:
        raise RgtbusError(f"{label}: holds only an MCAP header{by}: no records to read")
    if not names & {"scenario", "run"}:
        raise RgtbusError(f"{label}: not an rgtbus run log: no scenario or run metadata{by}")


# -- one way to open a log: checked whole before anything is read from it ----------------------

_FOOTER_BYTES = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, CRC
_DATA_END_BYTES = 1 + 8 + 4  # opcode, length, data_section_crc


def _crc_of(stream: IO[bytes], start: int, end: int) -> int | None:
    """CRC-32 of the bytes ``start:end`` (None when the file ends before ``end``)."""
    stream.seek(start)
    crc, left = 0, end - start
    while left > 0:
        block = stream.read(min(left, 1 << 20))
        if not block:
            return None
        crc = zlib.crc32(block, crc)
        left -= len(block)
    return crc


def verified_by_crcs(stream: IO[bytes]) -> bool:
    """Whether ``stream`` is a finished MCAP file whose data-section CRC and summary CRC were
    both written and both hold: together they cover every byte but the closing magic (checked
    too), so the whole file is vouched for without decompressing anything (zlib's CRC-32 runs
    at about 2 GB/s). False when it cannot tell (cut short, a CRC not written, not seekable)
    or a CRC does not hold: ``scan_log`` then says which and where."""
    magic = len(MCAP_MAGIC)
    try:
        size = stream.seek(0, os.SEEK_END)
        if size < 2 * magic + _DATA_END_BYTES + _FOOTER_BYTES:
            return False
        footer_at = size - magic - _FOOTER_BYTES
        stream.seek(footer_at)
        tail = stream.read(_FOOTER_BYTES + magic)
        if len(tail) != _FOOTER_BYTES + magic or tail[_FOOTER_BYTES:] != MCAP_MAGIC:
            return False
        opcode, length, summary_start, _, summary_crc = struct.unpack_from("<BQQQI", tail)
        if opcode != 0x02 or length != _FOOTER_BYTES - 9 or summary_crc == 0:
            return False
        data_end_at = (summary_start or footer_at) - _DATA_END_BYTES
        if not magic <= data_end_at <= footer_at - _DATA_END_BYTES:
            return False
        stream.seek(data_end_at)
        rec = stream.read(_DATA_END_BYTES)
        if len(rec) != _DATA_END_BYTES:
            return False
        opcode, length, data_crc = struct.unpack_from("<BQI", rec)
        if opcode != 0x0F or length != 4 or data_crc == 0:
            return False
        # the data section from the opening magic to DataEnd's CRC field; the summary section
        # (from DataEnd's end) through the footer's last field before its own CRC
        return (
            _crc_of(stream, 0, data_end_at) == data_crc
            and _crc_of(stream, data_end_at + _DATA_END_BYTES, footer_at + _FOOTER_BYTES - 4)
            == summary_crc
        )
    except (OSError, ValueError, AttributeError, struct.error):
        return False


@dataclass
class CheckedLog:
    """A run's log file, opened and checked whole by ``check_log`` (so nothing read from it
    later can be damaged). ``raw`` is the file's records as scanned (every chunk CRC-checked)
    when it was read record by record; None when its CRCs vouched for every byte: read it
    then through ``summary`` (mcap's) and its index, from ``stream``. ``metadata``: every
    Metadata record, in file order. ``truncated``: the file ends early; ``note`` says where
    and how far it was read (the last log time)."""

    label: str
    stream: IO[bytes]
    size: int
    raw: RawLog | None
    summary: Any = None
    library: str | None = None
    metadata: list[tuple[str, dict[str, str]]] = field(default_factory=list)

    @property
    def truncated(self) -> bool:
        return self.raw is not None and self.raw.truncated

    @property
    def note(self) -> str:
        return self.raw.note if self.raw is not None else ""


def _by_summary(stream: IO[bytes], label: str, size: int) -> CheckedLog | None:
    """A file its CRCs vouch for, read through its summary (None: no usable summary)."""
    from mcap.reader import SeekingReader, make_reader

    try:
        stream.seek(0)
        reader = make_reader(stream)
        if not isinstance(reader, SeekingReader):
            return None
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            return None
        library = reader.get_header().library
        metadata = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
    except Exception:  # a layout mcap's reader does not take: scan it instead
        return None
    empty = not (summary.schemas or summary.channels or summary.statistics.message_count)
    _require_run(label, library, {name for name, _ in metadata}, empty and not metadata)
    return CheckedLog(label, stream, size, None, summary, library, metadata)


@contextlib.contextmanager
def check_log(path: str | os.PathLike[str], *, scan: bool = False) -> Iterator[CheckedLog]:
    """Open a run's log and check it whole: the one way ``rgtbus info``, ``cat`` and
    ``scenario`` open a log (``rgtbus replay``, ``merge`` and ``rgtbus.open_log`` scan it
    with ``scan_log`` and refuse with ``require_run_log``: the same checks, record by record).

    A finished file whose data-section and summary CRCs hold (``verified_by_crcs``) is not
    scanned unless ``scan``: it is read through its summary. Anything else is scanned record by
    record, every chunk's CRC checked. Refused with one line (``RgtbusError``): unreadable, a
    directory, not an MCAP file, corrupt (where and what), only a header, not an rgtbus run
    log. A file cut short (a killed run) is read to its cut: ``truncated``, with a note."""
    label = os.fspath(path)
    try:
        if os.path.isdir(path):
            raise RgtbusError(f"cannot read log {label!r}: is a directory")
        stream = open(path, "rb")  # noqa: SIM115 - closed below
    except OSError as e:
        raise RgtbusError(f"cannot read log {label!r}: {e.strerror}") from None
    with stream:
        try:
            size = os.fstat(stream.fileno()).st_size
            log = None
            if not scan and verified_by_crcs(stream):
                log = _by_summary(stream, label, size)
            if log is None:
                stream.seek(0)
                raw = _scan(stream, label)
                require_run_log(raw)
                log = CheckedLog(label, stream, size, raw, None, raw.library, raw.metadata)
        except OSError as e:
            raise RgtbusError(f"cannot read log {label!r}: {e.strerror}") from None
        yield log


def _read(stream: IO[bytes], label: str) -> LogContents:
    return decode_log(_scan(stream, label))


def decode_log(raw: RawLog, keep_raw: Callable[[str], bool] | None = None) -> LogContents:
    """A scanned log as ``read_log`` returns it. Messages on topics for which ``keep_raw``
    is true stay undecoded JSON ``bytes`` (for readers that may never need them)."""
    label = raw.label
    if raw.corrupt:
        raise RgtbusError(raw.corruption)
    messages: list[tuple[str, int, Any]] = []
    topics = {cid: ch.topic for cid, ch in raw.channels.items()}
    lazy = {cid for cid, t in topics.items() if keep_raw is not None and keep_raw(t)}
    for cid, t, _, _, data in raw.messages:
        if cid in lazy:
            messages.append((topics[cid], t, bytes(data)))
            continue
        try:
            messages.append((topics[cid], t, orjson.loads(data)))
        except ValueError as e:
            raise RgtbusError(
                f"{label}: message on {topics[cid]} at {t} ns is not JSON: {e}"
            ) from None
    messages.sort(key=lambda m: m[1])
    metadata = {name: values for name, values in raw.metadata}  # a repeated name: last wins
    note = raw.note  # says how far it read (the scan's last log time)
    return LogContents(messages, metadata, bool(note), note)
