"""Recorders: where every step of a run is written. The ``Recorder`` protocol, what every
real recorder shares (``_Encoding``: each topic checked and encoded, and written in log-time
order), the in-process twin (``MemoryRecorder``) and ``NullRecorder``. The MCAP file's writer
is ``mcap_recorder.McapRecorder``; the JSON tier's bytes are ``message_json``'s, the blocks'
``blocks``'.

Time is simulated: ``log_time = publish_time = t_ns`` (integer nanoseconds from the run start).
"""

from __future__ import annotations

import functools
import heapq
import itertools
import json
import operator
from collections import Counter
from collections.abc import Mapping
from typing import Any, Protocol, Self, runtime_checkable

import orjson
from mcap.data_stream import RecordBuilder
from mcap.records import DataEnd, Footer
from mcap.records import Metadata as McapMetadata

from rgtbus.errors import BadInput, IOFailure, RgtbusError
from rgtbus.telemetry import topics, validate
from rgtbus.telemetry.blocks import decode_record, encode_record, join_alike, schema_of
from rgtbus.telemetry.message_json import (
    _U64_MAX,
    _check_t_ns,
    encode_json,
    kept_bytes,
    log_message,
)
from rgtbus.telemetry.records import LOG, RX_SPIKE
from rgtbus.telemetry.records import LogMessage as LogMessage  # its home: records
from rgtbus.telemetry.version import FORMAT_RECORD, format_metadata

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
            raise BadInput(f"write to {topic!r} on a closed recorder")
        schema = self._schema(topic)
        # the common case first: a plain int in range (a run writes millions of these)
        t = t_ns if type(t_ns) is int and 0 <= t_ns <= _U64_MAX else _check_t_ns(t_ns)
        if type(message) is not dict and not isinstance(message, dict):
            raise BadInput(f"message on {topic} must be a dict, got {type(message).__name__}")
        block = schema_of(topic)
        if block is not None:  # a hot topic: its block's bytes, checked as they are built
            try:
                data = encode_record(block, message)
            except RgtbusError as e:
                raise BadInput(f"message on {topic} at t_ns={t}: {e}") from None
            self.counts[topic] += 1
            return schema, data, t
        try:
            data = encode_json(message)
        except (TypeError, ValueError) as e:
            raise BadInput(f"message on {topic} at t_ns={t} is not JSON: {e}") from None
        if self.validate:
            errs = validate.errors(json.loads(data), topics.load_schema(schema))
            if errs:
                more = f" (+{len(errs) - 1} more)" if len(errs) > 1 else ""
                raise BadInput(f"message on {topic} breaks {schema}: {errs[0]}{more}")
        self.counts[topic] += 1
        return schema, data, t

    @staticmethod
    def _check_metadata(name: str, values: dict[str, str]) -> dict[str, str]:
        if not isinstance(name, str) or not name:
            raise BadInput(f"metadata name must be a non-empty string, got {name!r}")
        if not isinstance(values, dict):
            raise BadInput(f"metadata {name!r} must be a dict of strings")
        for k, v in values.items():
            if not isinstance(k, str) or not isinstance(v, str):
                raise BadInput(f"metadata {name!r}: {k!r}: {v!r} is not a string to a string")
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
            raise IOFailure(self.failed)
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
            raise BadInput(f"message on {topic} at t_ns={t_ns} is not JSON: {e}") from None
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
            raise BadInput(f"metadata {name!r} on a closed recorder")
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
