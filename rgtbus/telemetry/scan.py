"""Reading an MCAP log back, checked: ``scan_log`` (its records, undecoded, with every chunk's
CRC checked and a cut or corrupt file told apart), ``read_log`` (decoded messages and metadata),
(``log_check.check_log``: the summary section's CRCs first, for the log tools); a chunk's
records are split by ``chunks``. Apart from the recorder, so a run that only writes its log
never loads the reader (start-up).
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from collections.abc import Callable, Container, Mapping
from dataclasses import dataclass, field
from typing import IO, Any, TypeVar, cast

import mcap.exceptions
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError

from rgtbus.errors import BadLog, IOFailure, RgtbusError
from rgtbus.telemetry.chunks import MAX_CHUNK_BYTES, Reader, decompressed, split_chunk
from rgtbus.telemetry.recorder import MCAP_MAGIC, UNFINISHED, LogContents
from rgtbus.telemetry.version import require_format
from rgtbus.timebase import seconds


def read_log(source: str | os.PathLike[str] | IO[bytes]) -> LogContents:
    """Read an MCAP log written by McapRecorder: a path or a binary stream.

    Reads sequentially (no index needed), so a truncated file yields every complete record
    before the cut and ``truncated=True`` with a note. Not an MCAP file: RgtbusError.
    """
    return _from_source(source, _read)


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
    # topics whose messages are left in the file, found again by ``Deferred`` when asked for
    deferred: Deferred | None = None

    @property
    def truncated(self) -> bool:
        """Whether the file ends early (``note`` says where)."""
        return bool(self.note)

    @property
    def corrupt(self) -> bool:
        """Whether the file is damaged (``corruption`` says what and where)."""
        return bool(self.corruption)

    @property
    def header_only(self) -> bool:
        """Nothing but a Header: no schema, channel, message or metadata record."""
        return not (self.schemas or self.channels or self.messages or self.metadata)

    @property
    def count(self) -> int:
        """How many messages were read (those left in the file for later too)."""
        return len(self.messages) + (self.deferred.count if self.deferred else 0)

    @property
    def last_ns(self) -> int | None:
        """The log time of the last message read (those left in the file too)."""
        times = [m[1] for m in self.messages]
        if self.deferred is not None and self.deferred.last_ns is not None:
            times.append(self.deferred.last_ns)
        return max(times, default=None)


@dataclass
class Deferred:
    """Where a scanned file's messages of some topics are, to be read when asked for
    (``read``) rather than held from the start: a traced log's traces are most of it.
    ``records``: for each such channel, the byte offsets of the chunks (or unchunked message
    records) holding its messages, each CRC-checked when the file was scanned and again when
    it is read."""

    path: str
    wants: Callable[[str], bool]  # whether a topic's messages are left in the file
    topics: dict[int, str] = field(default_factory=dict)  # channel id -> topic
    records: dict[int, list[int]] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)
    last_ns: int | None = None
    crcs: dict[int, int] = field(default_factory=dict)  # a chunk's offset -> its CRC, as scanned

    @property
    def count(self) -> int:
        """How many messages were left in the file."""
        return sum(self.counts.values())

    def held(self) -> dict[str, int]:
        """How many messages each deferred topic holds (topics with none left out)."""
        out: dict[str, int] = {}
        for cid, n in self.counts.items():
            if n:
                out[self.topics[cid]] = out.get(self.topics[cid], 0) + n
        return out

    def note(self, channel_id: int, log_time: int, offset: int, count: int = 1) -> None:
        """``count`` messages of a deferred channel seen in the record at ``offset``, the
        latest at ``log_time``."""
        where = self.records.setdefault(channel_id, [])
        if not where or where[-1] != offset:
            where.append(offset)
        self.counts[channel_id] = self.counts.get(channel_id, 0) + count
        if self.last_ns is None or log_time > self.last_ns:
            self.last_ns = log_time

    def read(self, topic: str) -> list[tuple[int, bytes]]:
        """``topic``'s messages as ``(log_time, undecoded data)``, in log-time order (file
        order on ties). A file that changed since it was scanned: RgtbusError."""
        cids = {cid for cid, t in self.topics.items() if t == topic}
        offsets = sorted({o for cid in cids for o in self.records.get(cid, [])})
        out: list[tuple[int, bytes]] = []
        try:
            with open(self.path, "rb") as f:
                size = os.fstat(f.fileno()).st_size
                for offset in offsets:
                    for rec in _records_at(f, offset, size, self.crcs.get(offset), cids):
                        if type(rec) is tuple and rec[0] in cids:
                            out.append((rec[1], bytes(rec[4])))
                        elif isinstance(rec, Message) and rec.channel_id in cids:
                            out.append((rec.log_time, bytes(rec.data)))
        except _Corrupt as e:
            raise BadLog(f"{self.path}: changed since it was opened: {e}") from None
        except OSError as e:
            raise IOFailure(f"cannot read log {self.path!r}: {e.strerror}") from None
        out.sort(key=lambda m: m[0])
        return out


def _records_at(
    f: IO[bytes], offset: int, size: int, crc: int | None, only: Container[int]
) -> list[Any]:
    """The records of the one record (a chunk, or an unchunked message) at ``offset``, its
    CRC checked (a chunk's the one ``crc`` the scan found there), a chunk's messages of the
    channels ``only`` alone; ``_Corrupt`` when no such record is there."""
    f.seek(offset)
    head = f.read(9)
    if len(head) < 9:
        raise _Corrupt(f"no record at byte {offset}")
    _, length = struct.unpack("<BQ", head)
    if length > min(size - offset - 9, MAX_CHUNK_BYTES):
        raise _Corrupt(f"the record at byte {offset} runs past the end of the file")
    body = head + f.read(length)
    reader = Reader(io.BytesIO(body), skip_magic=True, emit_chunks=True)
    try:
        rec = next(iter(reader.records))
    except Exception as e:
        raise _Corrupt(f"the record at byte {offset} does not parse ({type(e).__name__})") from None
    if not isinstance(rec, Chunk):
        return [rec]
    if crc is not None and rec.uncompressed_crc != crc:
        raise _Corrupt(f"the chunk at byte {offset} is not the one read then (another CRC)")
    return _chunk_rows(rec, offset, only)


def scan_log(
    source: str | os.PathLike[str] | IO[bytes], *, defer: Callable[[str], bool] | None = None
) -> RawLog:
    """Every record of an MCAP file (path or binary stream), read sequentially so a truncated
    file yields all complete records before the cut. Not an MCAP file: RgtbusError.

    ``defer``: topics whose messages are checked but left in the file (``raw.deferred``
    reads them when asked for); for a path, or a file opened from one (``open(path, "rb")``:
    its ``name``); a stream of no file (``io.BytesIO``) is read whole."""
    path = _file_of(source) if defer is not None else None
    if defer is None or path is None:
        return _from_source(source, _scan)
    return _from_source(source, lambda f, label: _scan(f, label, Deferred(path, defer)))


def _file_of(source: str | os.PathLike[str] | IO[bytes]) -> str | None:
    """The file a source reads: a path, or a seekable stream opened from a regular file."""
    if isinstance(source, str | os.PathLike):
        return os.fspath(source)
    name = getattr(source, "name", None)
    try:
        seekable = bool(source.seekable())
    except (AttributeError, ValueError, OSError):
        return None
    return name if isinstance(name, str) and seekable and os.path.isfile(name) else None


T = TypeVar("T")


def _from_source(
    source: str | os.PathLike[str] | IO[bytes], read: Callable[[IO[bytes], str], T]
) -> T:
    """``read(stream, label)`` on a path (opened here, its error in one line) or a stream."""
    if isinstance(source, str | os.PathLike):
        try:
            with open(source, "rb") as f:
                return read(f, os.fspath(source))
        except OSError as e:
            raise IOFailure(f"cannot read log {os.fspath(source)!r}: {e.strerror}") from None
    return read(source, getattr(source, "name", "<stream>"))


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
    """Whether the record at ``start`` is a chunk a streaming writer (foxglove-sdk's) had not
    finished: it writes the chunk's record length and its records' length as placeholders
    (all ones) and fills them in when the chunk is done, the record length first, then the
    chunk header in a second write. Either still a placeholder: the writer stopped inside
    the chunk, so the file is cut, not damaged."""
    try:
        stream.seek(start)
        head = stream.read(9 + 8 + 8 + 8 + 4 + 4)  # opcode, length, times, size, crc, name
        if len(head) < 9 or head[0] != 0x06:
            return False
        if head[1:9] == _PLACEHOLDER:
            return True
        if len(head) < 41:
            return False
        (name_length,) = struct.unpack_from("<I", head, 37)
        if name_length > 64:  # no compression has such a name: not a chunk header in progress
            return False
        stream.seek(start + 41 + name_length)
        return stream.read(8) == _PLACEHOLDER
    except (OSError, ValueError):
        return False


_PLACEHOLDER = b"\xff" * 8  # a length the writer fills in once the chunk is finished


def _seconds(t_ns: int) -> str:
    return f"{seconds(t_ns):.3f}"


@dataclass
class _Progress:
    """How far a scan got: what its exception handlers need to tell a cut from damage."""

    started: bool = False  # a Header read
    finished: bool = False  # the data section's end (DataEnd) reached
    start: int = len(MCAP_MAGIC)  # byte offset of the record being read


def _scan(stream: IO[bytes], label: str, deferred: Deferred | None = None) -> RawLog:
    raw = RawLog(label, deferred=deferred)
    src = _Tracked(stream)
    at = _Progress()
    try:
        _read_records(raw, src, at)
        _refuse_trailing_bytes(src, stream)
    except _Corrupt as e:
        raw.corruption = f"{label}: corrupt log: {e}"
    except mcap.exceptions.InvalidMagic:
        if not at.started:
            raise BadLog(f"{label}: not an MCAP file (bad magic)") from None
        raw.corruption = f"{label}: corrupt log: bad magic after the footer"
    except CRCValidationError as e:  # the data section's CRC, checked at DataEnd
        raw.corruption = (
            f"{label}: corrupt log: data section CRC mismatch (stored {e.expected:#010x}, "
            f"computed {e.actual:#010x})"
        )
    except Exception as e:  # EndOfFile, short struct reads, a damaged record
        _stopped(e, raw, src, stream, at)
    last = raw.last_ns
    if raw.note and last is not None:  # how far it read, in the run's own time
        raw.note += f"; last log time read {seconds(last):.6f} s"
    return raw


def _read_records(raw: RawLog, src: _Tracked, at: _Progress) -> None:
    """Every record of the file into ``raw``, ``at`` following along; raises where it stops
    short (``_Corrupt`` for damage it locates itself)."""
    # Chunks come out whole (emit_chunks) so each is CRC-checked here and damage is located;
    # validate_crcs makes the reader check the data section's CRC at DataEnd (when written).
    reader = Reader(
        cast(IO[bytes], src), emit_chunks=True, validate_crcs=True, record_size_limit=2**30
    )
    for rec in reader.records:
        if src.short:  # the record's declared length ran past the end: not taken
            raise mcap.exceptions.EndOfFile()
        if not at.started and not isinstance(rec, Header):
            raise _Corrupt(f"record at byte {at.start}: the first record is not a Header")
        if isinstance(rec, Header):
            at.started = True
            raw.library = rec.library
        elif isinstance(rec, Chunk):
            if raw.deferred is not None:
                raw.deferred.crcs[at.start] = rec.uncompressed_crc
            _take_chunk(raw, rec, at.start)
        elif isinstance(rec, Metadata) and rec.name == UNFINISHED:
            # rgtbus's writer had not finished (still writing, or killed): the log is whole
            # up to here and cut here, as every reader sees it (recorder.unfinished_trailer)
            raw.note = (
                f"{raw.label}: log truncated after {raw.count} messages (its writer had "
                "not finished: a run still going, or one stopped before its end)"
            )
            at.finished = True
        elif isinstance(rec, Metadata) and not at.finished:
            raw.metadata.append((rec.name, dict(rec.metadata)))
        elif isinstance(rec, DataEnd):
            at.finished = True
            src.capture = bytearray()  # the summary, then the footer
        elif isinstance(rec, Footer):
            at.finished = True
            _check_summary_crc(rec, src)
        elif not at.finished:
            _take(raw, rec, at.start)  # unchunked records; the summary's copies are not needed
        at.start = src.pos


def _take(raw: RawLog, rec: Any, start: int) -> None:
    """A schema, channel or message record into ``raw`` (others are not needed)."""
    if isinstance(rec, Message):
        if rec.channel_id not in raw.channels:
            raise _Corrupt(f"record at byte {start}: message on unknown channel {rec.channel_id}")
        if raw.deferred is not None and rec.channel_id in raw.deferred.topics:
            raw.deferred.note(rec.channel_id, rec.log_time, start)
            return
        raw.messages.append(
            (rec.channel_id, rec.log_time, rec.publish_time, rec.sequence, rec.data)
        )
    elif isinstance(rec, Channel):
        raw.channels[rec.id] = rec
        if raw.deferred is not None:
            if raw.deferred.wants(rec.topic):
                raw.deferred.topics[rec.id] = rec.topic
            else:  # a channel id reused for a topic read now
                raw.deferred.topics.pop(rec.id, None)
    elif isinstance(rec, Schema):
        raw.schemas[rec.id] = rec


def _chunk_data(chunk: Chunk, start: int) -> tuple[bytes, str]:
    """A chunk's records, decompressed and CRC-checked, and the words naming the chunk;
    ``_Corrupt`` naming it otherwise."""
    where = (
        f"chunk at byte {start} (log time {_seconds(chunk.message_start_time)}"
        f"–{_seconds(chunk.message_end_time)} s)"
    )
    if chunk.uncompressed_size > MAX_CHUNK_BYTES:
        raise _Corrupt(
            f"{where}: claims {chunk.uncompressed_size} bytes once decompressed, beyond the "
            f"{MAX_CHUNK_BYTES >> 20} MiB any chunk may hold (not decompressed)"
        )
    try:
        return decompressed(chunk), where
    except CRCValidationError as e:
        raise _Corrupt(
            f"{where}: CRC mismatch (stored {e.expected:#010x}, computed {e.actual:#010x})"
        ) from None
    except Exception as e:  # a complete chunk that does not decompress
        raise _Corrupt(f"{where}: cannot be read ({type(e).__name__}: {e})") from None


def _take_chunk(raw: RawLog, chunk: Chunk, start: int) -> None:
    """A chunk's schemas, channels and messages into ``raw`` (a deferred topic's messages
    counted where they are, not kept), all or none: a chunk that does not parse is
    ``_Corrupt`` with none of its messages taken."""
    data, where = _chunk_data(chunk, start)
    deferred = raw.deferred
    try:
        rows, seen = split_chunk(
            data,
            lambda rec: _take(raw, rec, start),  # a channel: read (or deferred) from here on
            deferred.topics if deferred is not None else (),
        )
    except Exception as e:
        raise _Corrupt(f"{where}: cannot be read ({type(e).__name__}: {e})") from None
    unknown = {row[0] for row in rows}.difference(raw.channels)
    if unknown:
        raise _Corrupt(f"record at byte {start}: message on unknown channel {min(unknown)}")
    raw.messages += rows
    if deferred is not None:
        for cid, (count, last) in seen.items():
            deferred.note(cid, last, start, count)


def _chunk_rows(chunk: Chunk, start: int, only: Container[int]) -> list[Any]:
    """A chunk's records, its CRC checked: each message of the channels ``only`` as
    ``RawLog.messages`` holds it, a schema or channel record as mcap reads it; ``_Corrupt``
    naming the chunk otherwise."""
    data, where = _chunk_data(chunk, start)
    others: list[Any] = []
    try:
        rows, _ = split_chunk(data, others.append, only=only)
    except Exception as e:
        raise _Corrupt(f"{where}: cannot be read ({type(e).__name__}: {e})") from None
    return others + rows


def _check_summary_crc(footer: Footer, src: _Tracked) -> None:
    """The footer's summary CRC over what was read since DataEnd (0: not written)."""
    covered = bytes(src.capture or b"")[:-4]  # all but the CRC field itself
    if footer.summary_crc != 0 and zlib.crc32(covered) != footer.summary_crc:
        raise _Corrupt(
            f"summary section (from byte {footer.summary_start}): CRC mismatch "
            f"(stored {footer.summary_crc:#010x}, computed {zlib.crc32(covered):#010x})"
        )
    src.capture = None


def _refuse_trailing_bytes(src: _Tracked, stream: IO[bytes]) -> None:
    """``_Corrupt`` when bytes follow the footer's closing magic."""
    extra = len(src.read(1))
    while extra and (more := len(stream.read(1 << 20))):
        extra += more
    if extra:
        raise _Corrupt(
            f"{extra} bytes of trailing garbage after the footer (the log itself is complete)"
        )


def _stopped(e: Exception, raw: RawLog, src: _Tracked, stream: IO[bytes], at: _Progress) -> None:
    """A scan that stopped on ``e`` mid-record: a file cut short (``raw.note``), damage
    (``raw.corruption``), or no MCAP file at all (RgtbusError)."""
    label = raw.label
    if not at.started:
        if src.pos > len(MCAP_MAGIC) and not (src.short and not _ends_with_magic(stream)):
            raise BadLog(
                f"{label}: corrupt log: its header record is damaged ({type(e).__name__})"
            ) from None
        raise BadLog(f"{label}: not an MCAP file (empty or cut before its header)") from None
    if _chunk_in_progress(stream, at.start) and not _ends_with_magic(stream):
        raw.note = (
            f"{label}: log truncated after {raw.count} messages (cut in a chunk "
            "the writer had not finished)"
        )
    elif src.short and not _ends_with_magic(stream):
        n = raw.count
        where = "in its summary (all messages present)" if at.finished else f"after {n} messages"
        cut = isinstance(e, mcap.exceptions.EndOfFile | struct.error)
        why = "cut mid-record" if cut else f"{type(e).__name__}: {e}"
        raw.note = f"{label}: log truncated {where} ({why})"
    elif src.short:
        raw.corruption = (
            f"{label}: corrupt log: record at byte {at.start} runs past the end of a file "
            "that ends with MCAP's closing magic (a damaged record length)"
        )
    else:
        raw.corruption = f"{label}: corrupt log: record at byte {at.start}: {type(e).__name__}: {e}"


def require_run_log(raw: RawLog) -> None:
    """Refuse (one-line ``RgtbusError``) a log that is corrupt, holds only a header, or was
    not written by an rgtbus run (no ``scenario`` or ``run`` metadata). Truncation passes:
    everything before the cut is good."""
    if raw.corrupt:
        raise BadLog(raw.corruption)
    _require_run(raw.label, raw.library, raw.metadata, raw.header_only)


def _require_run(
    label: str,
    library: str | None,
    metadata: list[tuple[str, dict[str, str]]],
    header_only: bool,
    fmt: bool = True,
) -> None:
    by = f" (written by {library!r})" if library else ""
    if header_only:
        raise BadLog(f"{label}: holds only an MCAP header{by}: no records to read")
    if not {name for name, _ in metadata} & {"scenario", "run"}:
        raise BadLog(f"{label}: not an rgtbus run log: no scenario or run metadata{by}")
    if fmt:
        require_format(label, metadata)


def _read(stream: IO[bytes], label: str) -> LogContents:
    return decode_log(_scan(stream, label))


def current_topics(
    channels: Mapping[int, Channel], schemas: Mapping[int, Schema]
) -> frozenset[str]:
    """The topics whose channel's schema is this rgtbus's own, byte for byte (a log written
    by this version): the ones a reader checks every message of against its schema before
    use. An older log's schemas differ where its records did, and readers take its older
    forms as they are."""
    from rgtbus.telemetry import topics

    out = set()
    for channel in channels.values():
        schema = schemas.get(channel.schema_id)
        if schema is None:
            continue
        try:
            name = topics.schema_for(channel.topic)
            ours = topics.schema_bytes(name)
        except RgtbusError:
            continue
        if schema.name == name and bytes(schema.data) == ours:
            out.add(channel.topic)
    return frozenset(out)


def decode_log(raw: RawLog, keep_raw: Callable[[str], bool] | None = None) -> LogContents:
    """A scanned log as ``read_log`` returns it. Messages on topics for which ``keep_raw``
    is true stay undecoded JSON ``bytes`` (for readers that may never need them); the others
    are decoded (``untrusted.message``: not JSON, or nesting too deep, is RgtbusError)."""
    from rgtbus.telemetry import untrusted

    label = raw.label
    if raw.corrupt:
        raise BadLog(raw.corruption)
    messages: list[tuple[str, int, Any]] = []
    topics = {cid: ch.topic for cid, ch in raw.channels.items()}
    lazy = {cid for cid, t in topics.items() if keep_raw is not None and keep_raw(t)}
    for cid, t, _, _, data in raw.messages:
        if cid in lazy:
            messages.append((topics[cid], t, bytes(data)))
            continue
        messages.append((topics[cid], t, untrusted.message(topics[cid], t, data, label, False)))
    messages.sort(key=lambda m: m[1])
    metadata = {name: values for name, values in raw.metadata}  # a repeated name: last wins
    note = raw.note  # says how far it read (the scan's last log time)
    contents = LogContents(messages, metadata, bool(note), note)
    contents.deferred = raw.deferred
    contents.current = current_topics(raw.channels, raw.schemas)
    return contents
