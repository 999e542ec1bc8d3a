"""Recorders: where every step of a run is written. MCAP for real runs, memory for tests.

Messages are JSON with a JSON Schema per topic (see ``topics.py``), so Foxglove opens the file.
Time is simulated: ``log_time = publish_time = t_ns`` (integer nanoseconds from the run start).
"""

from __future__ import annotations

import contextlib
import errno
import functools
import heapq
import itertools
import json
import logging
import math
import operator
import threading
import time
import weakref
from collections import Counter
from collections.abc import Callable, Collection, Iterator, Mapping
from typing import Any, BinaryIO, Protocol, Self, runtime_checkable

import foxglove
import orjson
from foxglove.mcap import MCAPCompression, MCAPWriteOptions
from mcap.data_stream import RecordBuilder
from mcap.records import DataEnd, Footer
from mcap.records import Metadata as McapMetadata

from rgtbus.errors import RgtbusError
from rgtbus.pairs import SharedTable
from rgtbus.telemetry import topics, validate
from rgtbus.telemetry.blocks import decode_record, encode_record, join_alike, schema_of
from rgtbus.telemetry.records import LOG, MEDIUM, RX_SPIKE
from rgtbus.telemetry.version import FORMAT_RECORD, format_metadata
from rgtbus.timebase import NS_PER_SECOND, ns

LOG_LEVELS = {"unknown": 0, "debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}
_COMPRESSION = {
    "zstd": MCAPCompression.Zstd,
    "lz4": MCAPCompression.Lz4,
    "none": None,
}
_U64_MAX = 2**64 - 1
MCAP_MAGIC = b"\x89MCAP0\r\n"

# The metadata record that ends a log its writer has not finished (a run still going, or one
# killed): written, with a DataEnd and a footer, after the last finished chunk at every flush,
# and overwritten by the next one; the real summary and footer replace it at close.
UNFINISHED = "rgtbus.unfinished"


@functools.cache
def unfinished_trailer() -> bytes:
    """What ends a log between two flushes: the ``UNFINISHED`` record, a DataEnd without a
    CRC and a footer without a summary, then the magic. Every MCAP reader reads the file up
    to it as a whole file; rgtbus reads it as cut there (``scan_log``)."""
    out = RecordBuilder()
    why = "its writer had not finished: a run still going, or one stopped before its end"
    McapMetadata(name=UNFINISHED, metadata={"why": why}).write(out)
    DataEnd(data_section_crc=0).write(out)
    Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(out)
    return bytes(out.end()) + MCAP_MAGIC  # type: ignore[no-untyped-call]  # mcap leaves it bare


# one message as read back: (topic, log time in ns, the message)
LogMessage = tuple[str, int, dict[str, Any]]


@runtime_checkable
class Recorder(Protocol):
    """Where a run writes its log: messages by topic at a log time, text lines, metadata records.
    ``enabled`` False: nothing is kept, so callers may skip building messages."""

    enabled: bool

    def write(self, topic: str, message: Mapping[str, Any], t_ns: int) -> None:
        """``message`` on ``topic`` at log time ``t_ns`` (integer nanoseconds)."""
        ...

    def log(self, level: str, text: str, t_ns: int, name: str = "rgtbus") -> None:
        """A text line (``/log``) of ``level`` from ``name`` at ``t_ns``."""
        ...

    def metadata(self, name: str, values: dict[str, str]) -> None:
        """A metadata record ``name`` of string values."""
        ...

    def watched(self) -> bool:
        """Whether a live view may be looking now (``LiveSink.watched``): then a unit wakes for
        each thing it does and offers it as it happens (``offer``). Never changes what is
        logged."""
        ...

    def offer(self, topic: str, message: Mapping[str, Any], t_ns: int) -> None:
        """``message`` for the live view alone, never logged (nothing without a live view):
        e.g. each decode on ``/rx/decode`` as it is made, where the log holds them in blocks."""
        ...

    def advance(self, t_ns: int) -> None:
        """The run will write no record before ``t_ns`` (records told late aside): what is held
        before it is written, in log-time order, and from the first call on a record at or
        after the present one is held until the run has passed it (``_Encoding``)."""
        ...

    def close(self) -> None:
        """Finish the log; nothing is written after."""
        ...


class LiveSink(Protocol):
    """Where a recorder also offers each encoded message (a live view)."""

    def put(self, topic: str, schema: str, data: bytes, t_ns: int) -> None:
        """One encoded message (``data``, JSON under ``schema``) on ``topic`` at ``t_ns``."""
        ...

    def watched(self) -> bool:
        """Whether someone may be looking now, so each message should leave as the run's
        clock reaches it (a unit then takes no batch of decodes: ``AutonomousUnit.batching``).
        Asked at every wake of every unit: cheap, and True when in doubt."""
        ...


def _default(obj: Any) -> Any:
    """What orjson does not write itself, as what it does: a table units share as its JSON
    encoded once (``_shared_json``), numpy arrays and scalars as lists and numbers (without
    importing numpy here), and (``OPT_PASSTHROUGH_SUBCLASS`` hands them here, so that a
    ``SharedTable`` costs no look at every message) any other subclass of a dict, list, str or
    int as that plain type."""
    if type(obj) is SharedTable:
        return _shared_json(obj)
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, dict):
        return dict(obj)
    if isinstance(obj, list):
        return list(obj)
    if isinstance(obj, str):
        return str.__str__(obj)  # its text, whatever its own __str__ says
    if isinstance(obj, int):
        return int(obj)
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
        "timestamp": {"sec": t // NS_PER_SECOND, "nsec": t % NS_PER_SECOND},
        "level": level_number(level),
        "message": str(text),
        "name": str(name),
        "file": str(file),
        "line": int(line),
    }


_ORJSON = orjson.OPT_SERIALIZE_NUMPY | orjson.OPT_NON_STR_KEYS | orjson.OPT_PASSTHROUGH_SUBCLASS


_SHARED: dict[int, orjson.Fragment] = {}  # id of a live shared table -> its JSON
_SHARED_SIZE = 3  # a report's three tables


def _shared_json(table: SharedTable[Any]) -> orjson.Fragment | dict[str, Any]:
    """A shared table's JSON, encoded once for every record that holds it (the units of a
    group hold one table object: n tables of n² entries a run would be n³ bytes to encode).
    Kept under the table's identity while it lives (a weak reference drops it with the
    table: the cache never keeps a table of n² entries alive), a few at a time."""
    key = id(table)
    got = _SHARED.get(key)
    if got is None:
        try:
            data = encode_json(dict(table))
        except (TypeError, ValueError):  # raised here, orjson would only say "not JSON"
            return dict(table)  # not kept: the message's own checks name what is wrong
        if len(_SHARED) >= _SHARED_SIZE:  # a few tables at a time are the run's: the oldest
            del _SHARED[next(iter(_SHARED))]
        got = _SHARED[key] = orjson.Fragment(data)
        weakref.finalize(table, _SHARED.pop, key, None)
    return got


_TEXT = frozenset({str})


# scanning a message's JSON for null costs ~0.7 ns a byte, half of what orjson took to write
# it: above this many bytes, a message whose values show by their types that none is a NaN
# (``_finite_by_type``) is not scanned (a decode record of 200 units is ~11 kB)
_LOOK_BEFORE_SCAN = 2048


def _finite_by_type(message: dict[str, Any]) -> bool:
    """Whether no value of ``message`` can be a NaN or infinity, as their types show without
    a walk: text, integers, None, finite floats, lists of text, columns already written
    (``column_json``) and numpy columns of integers or booleans, or of floats whose sum is
    finite. False says only that the JSON must be looked into."""
    for v in message.values():
        kind = type(v)
        if kind is str or kind is int or kind is bool or v is None or kind is orjson.Fragment:
            continue
        if kind is float:
            if math.isfinite(v):
                continue
            return False
        if kind is list:  # a list of names: the types of its items, in one pass in C
            if set(map(type, v)) <= _TEXT:
                continue
            return False
        dtype = getattr(v, "dtype", None)
        if dtype is None:
            return False  # a dict, a table, a list of more than names: its JSON is looked into
        if dtype.kind in "iub":
            continue
        if dtype.kind != "f" or not math.isfinite(v.sum()):  # one NaN or inf: not finite
            return False
    return True


def kept_bytes(data: bytes) -> bytes:
    """``data`` as bytes of its own size, to keep: orjson's ``dumps`` gives bytes that hold a
    4 KiB buffer behind a ~150-byte message (what the recorder holds for its time, and a live
    view queues)."""
    return bytes(memoryview(data))


def encode_json(message: Any) -> bytes:
    """A message as compact JSON (numpy values as numbers and lists); TypeError for what JSON
    cannot hold, ValueError for NaN or infinity. A ``SharedTable`` in it is encoded once
    (``_shared_json``): the same bytes, n times less work."""
    data = orjson.dumps(message, default=_default, option=_ORJSON)
    if len(data) > _LOOK_BEFORE_SCAN and type(message) is dict and _finite_by_type(message):
        return data  # a large record of plain values and columns: no NaN, nothing to scan
    if b"null" in data:  # a None, or a NaN or infinity written as null: find out which
        # each None writes one null, as does each NaN (and a text may hold the word): as many
        # nulls as the record's own None fields leave no null for a NaN (a unit's report)
        if type(message) is dict and data.count(b"null") == sum(
            v is None for v in message.values()
        ):
            return data
        bad = _not_finite(message)
        if bad is not None:
            raise ValueError(f"Out of range float values are not JSON compliant: {bad!r}")
    return data


def message_bytes(topic: str, message: Mapping[str, Any]) -> bytes:
    """``message`` on ``topic`` as the log holds it: a hot topic's block (``blocks``), any
    other's JSON. Two records are the same record when these bytes are equal."""
    block = schema_of(topic)
    return encode_json(message) if block is None else encode_record(block, message)


_CONTAINERS = (dict, list, tuple)


def _not_finite(value: Any) -> float | None:
    """A NaN or infinity in ``value`` (which orjson writes as null, as it writes None), or
    None. Only the parts whose JSON holds a null are looked into: a unit's report of n² pairs
    with a None at its top is a few orjson passes, not a walk of every entry."""
    kind = type(value)
    if kind is float:
        return None if math.isfinite(value) else value
    if kind in _CONTAINERS or isinstance(value, _CONTAINERS):
        for item in value.values() if isinstance(value, dict) else value:
            nested = type(item) in _CONTAINERS or hasattr(item, "tolist")
            if nested and b"null" not in orjson.dumps(item, default=_default, option=_ORJSON):
                continue  # no null in it: no NaN either
            bad = _not_finite(item)
            if bad is not None:
                return bad
        return None
    if hasattr(value, "tolist"):  # a numpy array or scalar: as JSON has it
        return _not_finite(value.tolist())
    return None


# a record held for its time: (log time, arrival, topic, schema, bytes)
_Held = tuple[int, int, str, str, bytes]


# the topics a run tells out of log-time order, held for their time: a send's log line is
# made when the send is planned (up to the whole run ahead), a unit's blocks of spikes at its
# wake. Every other topic comes in order already (a unit's own records at its own time, the
# medium ahead and in order, blocks of pulses and decodes once every unit is past them), and
# goes out at once (a 100-unit run's relation tables are 34 MB of JSON, each written once).
_TOLD_OUT_OF_ORDER = frozenset((LOG, RX_SPIKE))


class _Encoding:
    """Topic check, JSON encoding and optional validation, shared by the real recorders; and
    the order of what they write.

    **Time order.** Units plan sends ahead (a send's log line is made when it is planned) and
    tell blocks of spikes late (at their wake): those two topics (``_TOLD_OUT_OF_ORDER``) come
    in an order of their own. Once the run says how far it has come (``advance``: no record
    before that log time is still to come), a record of theirs at or after that point is
    held, and the held ones go out in log-time order (then the order they came in) as the
    point moves on. Every other topic comes in order already and goes out at once: a unit's
    own records at its own time, the medium ahead of the run and in order (a cut log holds it
    past its units' records, as its re-run needs), blocks of pulses and decodes once every
    unit is past them. Each topic's messages then follow log time in the file, chunk after
    chunk, as readers that index a file by its chunks' times expect (``rerun mcap check``,
    Foxglove's player). A live view gets every record as it is made, not held (a block of
    spikes as written, joined: it is told late anyway). ``close`` writes what is still held.
    Before the first ``advance`` nothing is held.
    """

    enabled = True
    failed: str | None = None  # the one line that says why the stream failed (McapRecorder)

    def __init__(self, validate: bool, live: LiveSink | None = None) -> None:
        self.validate = validate
        self.live = live  # every message is offered to it too (rgtbus.telemetry.live)
        self.counts: Counter[str] = Counter()  # messages written per topic
        self._closed = False
        self._schemas: dict[str, str] = {}  # topic -> schema name, once looked up
        # held records (log time, arrival, topic, schema, bytes), a heap; None: none held
        self._held: list[_Held] | None = None
        self._hold_from = -1  # no record before this log time is still to come
        self._arrival = 0

    def _schema(self, topic: str) -> str:
        """``topic``'s schema name, looked up once."""
        return self._schemas.get(topic) or self._schemas.setdefault(topic, topics.schema_for(topic))

    def _encode(self, topic: str, message: Mapping[str, Any], t_ns: int) -> tuple[str, bytes, int]:
        if self._closed:
            raise RgtbusError(f"write to {topic!r} on a closed recorder")
        schema = self._schema(topic)
        # the common case first: a plain int in range (a run writes millions of these)
        t = t_ns if type(t_ns) is int and 0 <= t_ns <= _U64_MAX else _check_t_ns(t_ns)
        if type(message) is not dict and not isinstance(message, dict):
            raise RgtbusError(f"message on {topic} must be a dict, got {type(message).__name__}")
        block = schema_of(topic)
        if block is not None:  # a hot topic: its block's bytes, checked as they are built
            try:
                data = encode_record(block, message)
            except RgtbusError as e:
                raise RgtbusError(f"message on {topic} at t_ns={t}: {e}") from None
            self.counts[topic] += 1
            return schema, data, t
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
        self.write(LOG, log_message(level, text, t_ns, name, file, line), t_ns)

    def write(self, topic: str, message: Mapping[str, Any], t_ns: int) -> None:
        """Encode ``message`` on ``topic`` at ``t_ns`` and write it, or hold it for its time
        (see the class docstring); the live sink gets it now. RgtbusError for a message its
        topic's schema or JSON cannot take, and once the stream has failed."""
        schema, data, t = self._encode(topic, message, t_ns)
        if self.failed:
            raise RgtbusError(self.failed)
        if self.live is not None and topic != RX_SPIKE:
            self.live.put(topic, schema, data, t)  # as made (a block of spikes as joined)
        if self._held is not None and t >= self._hold_from and topic in _TOLD_OUT_OF_ORDER:
            heapq.heappush(self._held, (t, self._arrival, topic, schema, kept_bytes(data)))
            self._arrival += 1
            return
        self._out(topic, schema, data, t)  # nothing held, or told late

    def _out(self, topic: str, schema: str, data: bytes, t: int) -> None:
        """Write one message; the live sink gets a block of spikes as written."""
        if self.live is not None and topic == RX_SPIKE:
            self.live.put(topic, schema, data, t)
        self._emit(topic, schema, data, t)

    def _emit(self, topic: str, schema: str, data: bytes, t: int) -> None:
        """Write one encoded message (the recorder's own medium)."""
        raise NotImplementedError

    def advance(self, t_ns: int) -> None:
        """No record before ``t_ns`` is still to come (see the class docstring): the held ones
        before it go out, in order."""
        if self._held is None:
            self._held = []
        if t_ns <= self._hold_from:
            return
        self._hold_from = t_ns
        held = self._held
        if held and held[0][0] < t_ns:
            out = []
            while held and held[0][0] < t_ns:
                out.append(heapq.heappop(held))
            self._write_held(out)

    def _write_held(self, out: list[_Held]) -> None:
        """Write held records (in log-time order, then arrival). Blocks of spikes of one log
        time that hold the same spikes become one naming every unit of them (``join_alike``,
        the rule ``merge`` follows): all of one time leave together."""
        for t, group in itertools.groupby(out, key=operator.itemgetter(0)):
            run = list(group)
            spikes = [k for k, e in enumerate(run) if e[2] == RX_SPIKE]
            joined: dict[int, bytes | None] = {}
            if len(spikes) > 1:
                joined = dict(zip(spikes, join_alike([run[k][4] for k in spikes]), strict=True))
            for k, (_, _, topic, schema, data) in enumerate(run):
                got = joined.get(k, data)
                if got is None:
                    self.counts[topic] -= 1
                else:
                    self._out(topic, schema, got, t)

    def _release_all(self) -> None:
        """Write every record still held (the run is over), and hold none from now on."""
        held, self._held = self._held, None
        self._hold_from = -1
        if held:
            held.sort()
            self._write_held(held)

    def watched(self) -> bool:
        """Whether the live sink (if any) may be looking now (``LiveSink.watched``)."""
        return self.live is not None and self.live.watched()

    def offer(self, topic: str, message: Mapping[str, Any], t_ns: int) -> None:
        """``message`` to the live sink alone (encoded as ``write`` would; not counted, not
        logged); nothing without a live sink, or once closed."""
        live = self.live
        if live is None or self._closed or self.failed:
            return
        schema = self._schema(topic)
        block = schema_of(topic)
        try:
            data = encode_json(message) if block is None else encode_record(block, message)
        except (TypeError, ValueError) as e:
            raise RgtbusError(f"message on {topic} at t_ns={t_ns} is not JSON: {e}") from None
        live.put(topic, schema, data, _check_t_ns(t_ns))

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
            raise RgtbusError(
                f"unknown MCAP compression {compression!r} (use {', '.join(_COMPRESSION)})"
            )
        if type(compression_level) is not int or not 0 <= compression_level <= 19:
            raise RgtbusError(
                f"MCAP compression level {compression_level!r} is not an integer 0..19 "
                "(0: the compressor's own default)"
            )
        if not (
            (flush_seconds is None or flush_seconds > 0) and flush_messages > 0 and flush_wall > 0
        ):
            raise RgtbusError("flush_seconds, flush_messages and flush_wall must be positive")
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
            raise RgtbusError(self.failed)
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
        return RgtbusError(self.failed)

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
            raise RgtbusError(self.failed)
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
            raise RgtbusError(f"metadata {name!r} on a closed recorder")
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


class MemoryRecorder(_Encoding):
    """The in-process twin: keeps what an MCAP file would hold, JSON round-tripped so reading
    it back equals ``read_log`` of the same writes, and offers each to ``live`` as the file's
    recorder does. Validates by default (it serves tests)."""

    def __init__(self, *, validate: bool = True, live: LiveSink | None = None) -> None:
        super().__init__(validate, live)
        self.messages: list[LogMessage] = []
        self.metadata_records: dict[str, dict[str, str]] = {FORMAT_RECORD: format_metadata()}
        self.logs: list[dict[str, Any]] = []

    def _emit(self, topic: str, schema: str, data: bytes, t: int) -> None:
        """Keep a message as the file would hold it (JSON round-tripped, validated)."""
        block = schema_of(topic)
        if block is None:
            decoded = orjson.loads(data)
        else:  # as a reader of the file gets it back
            decoded = decode_record(block, data, f"memory log: message on {topic}")
        self.messages.append((topic, t, decoded))
        if topic == LOG:
            self.logs.append(decoded)

    def metadata(self, name: str, values: dict[str, str]) -> None:
        """Keep a metadata record (one with no values is skipped, as in the file)."""
        if self._closed:
            raise RgtbusError(f"metadata {name!r} on a closed recorder")
        values = self._check_metadata(name, values)
        if values:  # as in the MCAP file: foxglove's writer skips a record with no values
            self.metadata_records[name] = values

    def read(self) -> LogContents:
        """What ``read_log`` would return for the same writes (what is held too: ``close``
        would write it)."""
        self._release_all()
        msgs = sorted(self.messages, key=lambda m: m[1])
        return LogContents(msgs, {k: dict(v) for k, v in self.metadata_records.items()})

    def close(self) -> None:
        """Write what is held; refuse further writes."""
        self._release_all()
        self._closed = True


class NullRecorder:
    """Records nothing. ``enabled`` is False so callers can skip building messages."""

    enabled = False
    closed = False

    def write(self, topic: str, message: Mapping[str, Any], t_ns: int) -> None:
        """Nothing."""
        pass

    def log(self, level: str, text: str, t_ns: int, name: str = "rgtbus", **_: Any) -> None:
        """Nothing."""
        pass

    def metadata(self, name: str, values: dict[str, str]) -> None:
        """Nothing."""
        pass

    def watched(self) -> bool:
        """Nobody: nothing is recorded."""
        return False

    def offer(self, topic: str, message: Mapping[str, Any], t_ns: int) -> None:
        """Nothing."""
        pass

    def advance(self, t_ns: int) -> None:
        """Nothing."""
        pass

    def close(self) -> None:
        """Say it is closed; nothing else."""
        self.closed = True

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class DeferredTopics(Protocol):
    """Topics a reader left in the file, to be read when asked for (``scan.Deferred``)."""

    last_ns: int | None  # the log time of the last such message

    def held(self) -> dict[str, int]:
        """How many messages each such topic holds."""
        ...

    def read(self, topic: str) -> list[tuple[int, bytes]]:
        """``topic``'s messages as ``(log_time, data)`` in log-time order."""
        ...


class LogContents(tuple[list[LogMessage], dict[str, dict[str, str]]]):
    """``(messages, metadata)`` — unpacks as a pair — plus how the read ended.

    messages: ``[(topic, log_time_ns, message), ...]`` in log-time order (file order on ties);
    metadata: ``{name: {key: value}}`` (a repeated name: the last record wins).
    ``truncated``: the file ended before its footer; ``note``: one line saying where and why;
    ``end_ns``: log time of the last message read (None when there was none).
    ``deferred``: the topics whose messages were left in the file (``DeferredTopics``), or None.
    ``current``: the topics whose channel's schema is this rgtbus's own.
    """

    messages: list[LogMessage]
    metadata: dict[str, dict[str, str]]
    truncated: bool
    note: str
    deferred: DeferredTopics | None = None
    # topics whose channel's schema is this rgtbus's own (``scan.current_topics``): their
    # messages are checked against it before use; an older log's are read as they are
    current: frozenset[str] = frozenset()

    def __new__(
        cls,
        messages: list[LogMessage],
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
        """The log time of the last message read; None when there was none."""
        last = max((m[1] for m in self.messages), default=None)
        later = self.deferred.last_ns if self.deferred is not None else None
        return last if later is None else later if last is None else max(last, later)
