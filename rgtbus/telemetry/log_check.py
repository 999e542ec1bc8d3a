"""One way to open a run's log for the log tools (``rgtbus info``, ``cat``, ``scenario``):
``check_log`` checks it whole before anything is read from it, by its CRCs where they vouch for
every byte (``verified_by_crcs``), else by a scan record by record (``scan._scan``).
"""

from __future__ import annotations

import contextlib
import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import IO, Any

from rgtbus.errors import IOFailure
from rgtbus.telemetry.chunks import MAX_CHUNK_BYTES
from rgtbus.telemetry.recorder import MCAP_MAGIC
from rgtbus.telemetry.scan import RawLog, _require_run, _scan, require_run_log

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
    too), so the whole file is vouched for without decompressing anything. False when it
    cannot tell (cut short, a CRC not written, not seekable) or a CRC does not hold:
    ``scan_log`` then says which and where."""
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
        return bool(
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
        """Whether the file ends early (a killed run)."""
        return self.raw is not None and self.raw.truncated

    @property
    def note(self) -> str:
        """Where the file was cut and how far it was read; empty for a whole file."""
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
        if any(ci.uncompressed_size > MAX_CHUNK_BYTES for ci in summary.chunk_indexes):
            return None  # scanned instead, where such a chunk is refused before it is read
        library = reader.get_header().library
        metadata = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
    except Exception:  # a layout mcap's reader does not take: scan it instead
        return None
    empty = not (summary.schemas or summary.channels or summary.statistics.message_count)
    _require_run(label, library, metadata, empty and not metadata)
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
            raise IOFailure(f"cannot read log {label!r}: is a directory")
        stream = open(path, "rb")  # noqa: SIM115 - closed below
    except OSError as e:
        raise IOFailure(f"cannot read log {label!r}: {e.strerror}") from None
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
            raise IOFailure(f"cannot read log {label!r}: {e.strerror}") from None
        yield log
