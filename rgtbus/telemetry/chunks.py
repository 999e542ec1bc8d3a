"""A chunk of an MCAP log read fast and checked: decompressed and CRC-checked
(``decompressed``), its records split with one ``struct`` call a record (``split_chunk``);
and mcap's stream reader with message indexes skipped undecoded (``Reader``). mcap's own
splitter reads each field of each message through a stream object (about 8 MB/s here): a
chunk's messages are most of a log (docs/format.md, "Reading a log")."""

from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Callable, Container
from typing import Any

import lz4.frame
import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Schema
from mcap.stream_reader import CRCValidationError, StreamReader

# The most a chunk may claim to hold once decompressed: rgtbus and mcap's writers write chunks of
# 1 MiB by default. A chunk claiming more is refused before anything is allocated
# (a compression bomb: 56 KB of file claiming gigabytes).
MAX_CHUNK_BYTES = 64 << 20


_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, length


Row = tuple[int, int, int, int, bytes]  # a message as ``RawLog.messages`` holds it


def split_chunk(
    data: bytes,
    on_record: Callable[[Channel | Schema], None],
    later: Container[int] = (),
    only: Container[int] | None = None,
) -> tuple[list[Row], dict[int, list[int]]]:
    """A chunk's records (``data``, decompressed): its messages as rows (those of the
    channels ``only``, when given), but those of the channels ``later`` (their topics read
    when asked for), counted with their latest log time (``{channel: [count, last]}``);
    each schema and channel record handed to
    ``on_record`` as mcap reads it (a channel before its messages, as writers write them);
    any other record skipped, as ``mcap.stream_reader.breakup_chunk`` skips it. mcap's own
    splitter reads each field of each message through a stream object, about 8 MB/s here; a
    chunk's messages are most of a log, so they are split here, with two ``struct`` calls a
    message. A run of messages of one length (a trace's rows: most of a traced log) is split
    as arrays (``_equal_run``). Raises ``ValueError`` where the records do not fit the chunk."""
    size, pos = len(data), 0
    head, message = _RECORD_HEAD.unpack_from, _MESSAGE_HEAD.unpack_from
    rows: list[Row] = []
    seen: dict[int, list[int]] = {}
    last, streak = -1, 0  # the length of the messages just before, and how many in a row
    while pos < size:
        if pos + 9 > size:
            raise ValueError(f"a record's header cut at byte {pos} of the chunk's records")
        opcode, length = head(data, pos)
        # a third message of one length: tried once a streak as a run (at most linear work)
        if opcode == _MESSAGE and length == last and streak == 2:
            ran = _equal_run(data, pos, length, rows, seen, later, only)
            pos += ran * (9 + length)
            streak += 1
            if ran:
                continue
        start, pos = pos + 9, pos + 9 + length
        if pos > size:
            raise ValueError(f"the record at byte {start - 9} runs past the chunk's records")
        if opcode != _MESSAGE or length != last:
            last, streak = (length, 1) if opcode == _MESSAGE else (-1, 0)
        elif streak < 2:
            streak += 1
        if opcode == _MESSAGE:
            if length < 22:
                raise ValueError(f"the message at byte {start - 9} is {length} bytes long")
            cid, seq, log_time, publish_time = message(data, start)
            if cid not in later:
                if only is None or cid in only:
                    rows.append((cid, log_time, publish_time, seq, data[start + 22 : pos]))
            elif (got := seen.get(cid)) is None:
                seen[cid] = [1, log_time]
            else:
                got[0] += 1
                if log_time > got[1]:
                    got[1] = log_time
        elif opcode == Opcode.CHANNEL:
            on_record(Channel.read(ReadDataStream(io.BytesIO(data[start:pos]))))
        elif opcode == Opcode.SCHEMA:
            on_record(Schema.read(ReadDataStream(io.BytesIO(data[start:pos]))))
    return rows, seen


_MESSAGE = int(Opcode.MESSAGE)
_RUN_LEAST = 16  # a run shorter than this is split one record at a time


def _equal_run(
    data: bytes,
    pos: int,
    length: int,
    rows: list[Row],
    seen: dict[int, list[int]],
    later: Container[int],
    only: Container[int] | None,
) -> int:
    """The messages of ``length`` bytes one after another from ``pos`` (where such a message
    starts) taken as ``split_chunk`` takes them, read as strided arrays: how many (0: fewer
    than ``_RUN_LEAST``, left to the loop)."""
    stride = 9 + length
    fit = (len(data) - pos) // stride
    if fit < _RUN_LEAST:
        return 0

    def column(offset: int, dtype: str, n: int) -> np.ndarray:
        return np.ndarray((n,), dtype=dtype, buffer=data, offset=pos + offset, strides=(stride,))

    n = _RUN_LEAST  # windows growing fourfold: the work is linear in the run found
    while True:
        n = min(n, fit)
        same = (column(0, "u1", n) == _MESSAGE) & (column(1, "<u8", n) == length)
        if not same.all():
            count = int(np.argmin(same))
            break
        count = n
        if n == fit:
            break
        n *= 4
    if count < _RUN_LEAST:
        return 0
    cids, times = column(9, "<u2", count), column(15, "<u8", count)
    kept = np.ones(count, dtype=bool)
    for cid in np.unique(cids).tolist():
        if cid in later:
            mine = cids == cid
            kept &= ~mine
            latest = int(times[mine].max())
            got = seen.setdefault(cid, [0, latest])
            got[0] += int(np.count_nonzero(mine))
            got[1] = max(got[1], latest)
        elif only is not None and cid not in only:
            kept &= cids != cid
    message = _MESSAGE_HEAD.unpack_from
    for i in np.flatnonzero(kept).tolist():
        start = pos + i * stride + 9
        cid, seq, log_time, publish_time = message(data, start)
        rows.append((cid, log_time, publish_time, seq, data[start + 22 : start + length]))
    return count


def decompressed(chunk: Chunk) -> bytes:
    """A chunk's records, decompressed (zstd, lz4 or none, as the MCAP spec allows) and
    CRC-checked (``CRCValidationError``)."""
    if chunk.compression == "zstd":
        data = zstandard.decompress(chunk.data, chunk.uncompressed_size)
    elif chunk.compression == "lz4":
        data = lz4.frame.decompress(chunk.data)
    elif chunk.compression == "":
        data = bytes(chunk.data)
    else:
        raise ValueError(f"unknown compression {chunk.compression[:40]!r}")
    if chunk.uncompressed_crc != 0 and zlib.crc32(data) != chunk.uncompressed_crc:
        raise CRCValidationError(chunk.uncompressed_crc, zlib.crc32(data), chunk)
    return data


class Reader(StreamReader):
    """mcap's reader, message index records (a chunk's table of offsets, one a channel and
    chunk: a scan has no use for them) skipped undecoded: their bytes still go into the data
    section's CRC. mcap decodes each entry through a stream object, and a traced log's
    9,197 indexes took longer to read than its 1.35 M messages."""

    def _read_record(self, opcode: int, length: int) -> Any:
        if opcode == Opcode.MESSAGE_INDEX:
            self._stream.read(length)
            return _SKIPPED  # yielded (not None): the scan keeps each record's offset
        return super()._read_record(opcode, length)


class _Skipped:
    """A record read past, undecoded (``_Reader``)."""


_SKIPPED = _Skipped()
