"""Merging MCAP logs (one per process of a cross-process run) into one time-ordered log.

Records are copied undecoded. Schemas are shared when identical (name, encoding, bytes);
channels when identical (topic, encoding, schema, metadata); messages are ordered by log time
(ties: input order, then file order) and renumbered per channel. A message that is byte for
byte the same on the same topic at the same time in two inputs (e.g. the medium, logged by
every process) is kept once unless ``dedupe=False``; and then blocks of spikes that units
heard alike, and of decodes they made alike, are one record naming them all, whichever
process wrote them (``shared_blocks``), and the blocks of pulses of one block of time are one
(``joined_pulses``): the merge of a run's logs is the same whatever the split of its units
into processes.
Metadata records are kept once when identical; a record whose name is taken by a different
one (e.g. each process's ``run``) is kept as ``NAME.K`` (K = the input's position, from 1).
A ``merge`` record lists the inputs. A corrupt input (``RawLog.corrupt``) is refused; a
truncated one is merged as far as it goes.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, BinaryIO

from mcap.writer import CompressionType, IndexType, Writer

from rgtbus._version import __version__
from rgtbus.errors import BadInput, BadLog, RgtbusError
from rgtbus.telemetry.blocks import (
    PULSE,
    block_samples,
    decode_record,
    encode_record,
    join_alike,
)
from rgtbus.telemetry.pulse_blocks import join_pulse_blocks
from rgtbus.telemetry.records import RX_DECODES, RX_SPIKE, TX_PULSE
from rgtbus.telemetry.scan import RawLog
from rgtbus.telemetry.version import FORMAT_RECORD, format_metadata, require_format

_COMPRESSION = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}


@dataclass
class MergeResult:
    """What ``merge_logs`` wrote: message, channel and schema counts, the metadata records and the
    names it gave the ones it renamed, and the inputs that were cut short."""

    messages: int = 0
    duplicates: int = 0  # identical messages dropped
    joined: int = 0  # records of spikes or decodes units made alike, made part of another
    pulses_joined: int = 0  # blocks of pulses made part of another of their block of time
    channels: int = 0
    schemas: int = 0
    metadata: list[str] = field(default_factory=list)  # record names written
    renamed: dict[str, str] = field(default_factory=dict)  # "input K: NAME" -> new name
    notes: list[str] = field(default_factory=list)  # truncated inputs


# one message to write: (log time, input, order in its input, channel id, publish time, data)
_Entry = tuple[int, int, int, int, int, bytes]


def merge_logs(
    logs: Sequence[RawLog],
    stream: BinaryIO,
    *,
    compression: str = "zstd",
    dedupe: bool = True,
    salvage: bool = False,
) -> MergeResult:
    """Write the merge of ``logs`` (from ``scan_log``) as one MCAP file to ``stream``.
    ``salvage`` (``recover_log``): a damaged input gives what was read before its damage
    (every chunk of it CRC-checked), its damage noted like a cut, instead of a refusal."""
    if not logs:
        raise BadInput("merge: no input logs")
    if compression not in _COMPRESSION:
        raise BadLog(
            f"unknown MCAP compression {compression!r} (use {', '.join(_COMPRESSION)})"
        )
    for log in logs:
        if log.corrupt and not salvage:  # never copy a damaged chunk into a whole-looking log
            raise BadLog(f"{log.corruption}; not merged")
        if not log.header_only:  # (one that holds nothing adds nothing)
            require_format(log.label, log.metadata)  # a format-1 input: convert it first
    res = MergeResult()
    writer = _writer(logs, stream, compression)
    writer.start(profile="", library=f"rgtbus {__version__} {'recover' if salvage else 'merge'}")
    writer.add_metadata(FORMAT_RECORD, format_metadata())  # first, as in every rgtbus file
    entries, shared, pulses = _register(writer, logs, res)
    if salvage:  # read up to the damage, and no further: a cut as far as readers go
        res.notes += [f"{log.corruption} (recovered up to there)" for log in logs if log.corrupt]
    elif dedupe:
        entries = list(shared_blocks(entries, shared, res))
        if len(logs) > 1:
            entries = joined_pulses(entries, pulses, res)
    _write_messages(writer, entries, dedupe, res)
    kept = _merged_metadata(logs, res)
    for name, values in kept.items():
        writer.add_metadata(name, values)
    res.metadata = list(kept)
    writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer leaves it bare
    return res


def _writer(logs: Sequence[RawLog], stream: BinaryIO, compression: str) -> Writer:
    """An MCAP writer whose summary has a group (and a summary offset) only for records the
    merge writes: a summary offset for a group that is not there (mcap's writer gives one for
    every kind it indexes, even with none of it) is what ``mcap doctor`` rejects
    (SUMMARY_OFFSET_WITHOUT_GROUP). No attachments are ever written; there is always metadata
    (the ``merge`` record)."""
    indexes = IndexType.MESSAGE | IndexType.METADATA
    if any(log.messages for log in logs):
        indexes |= IndexType.CHUNK
    return Writer(
        stream,
        compression=_COMPRESSION[compression],
        index_types=indexes,
        repeat_schemas=any(log.schemas for log in logs),
        repeat_channels=any(log.channels for log in logs),
        enable_data_crcs=True,
    )


def _register(
    writer: Writer, logs: Sequence[RawLog], res: MergeResult
) -> tuple[list[_Entry], set[int], set[int]]:
    """Every input's schemas and channels registered once each (identical ones shared), and
    every message as an entry on its merged channel, in log-time order (ties: input order,
    then file order); and the merged channels of ``/rx/spike`` and ``/rx/decodes``, and of
    ``/tx/pulse``."""
    schema_ids: dict[tuple[str, str, bytes], int] = {}
    channel_ids: dict[tuple[str, str, int, tuple[tuple[str, str], ...]], int] = {}
    entries: list[_Entry] = []
    for k, log in enumerate(logs):
        if log.note:
            res.notes.append(log.note)
        local_schema: dict[int, int] = {0: 0}  # schema id 0: no schema
        for sid, s in log.schemas.items():
            schema_key = (s.name, s.encoding, bytes(s.data))
            if schema_key not in schema_ids:
                schema_ids[schema_key] = writer.register_schema(s.name, s.encoding, s.data)
            local_schema[sid] = schema_ids[schema_key]
        local_channel: dict[int, int] = {}
        for cid, c in log.channels.items():
            if c.schema_id not in local_schema:
                raise BadLog(f"{log.label}: channel {c.topic} names unknown schema")
            sid = local_schema[c.schema_id]
            channel_key = (c.topic, c.message_encoding, sid, tuple(sorted(c.metadata.items())))
            if channel_key not in channel_ids:
                channel_ids[channel_key] = writer.register_channel(
                    c.topic, c.message_encoding, sid, dict(c.metadata)
                )
            local_channel[cid] = channel_ids[channel_key]
        for order, (cid, log_time, publish_time, _, data) in enumerate(log.messages):
            entries.append((log_time, k, order, local_channel[cid], publish_time, data))
    entries.sort(key=lambda e: (e[0], e[1], e[2]))
    res.channels = len(channel_ids)
    res.schemas = len(schema_ids)
    shared = {cid for key, cid in channel_ids.items() if key[0] in (RX_SPIKE, RX_DECODES)}
    pulses = {cid for key, cid in channel_ids.items() if key[0] == TX_PULSE}
    return entries, shared, pulses


def shared_blocks(
    entries: Sequence[_Entry], spike_channels: set[int], res: MergeResult
) -> Iterator[_Entry]:
    """``entries`` with the ``/rx/spike`` (or ``/rx/decodes``) records of one log time and
    channel that hold the same spikes (decodes) — their bytes after the units — made one
    record naming every unit of them, in sorted order (``records.spikes`` and
    ``GroupLog`` write them so), where the first of them was: units of one process write a
    block they made alike once, those of several processes once each, and the merge is the
    same for any split. A record not as rgtbus writes it is kept as it is."""
    i = 0
    while i < len(entries):
        j = i + 1
        while j < len(entries) and entries[j][0] == entries[i][0]:
            j += 1
        if j - i == 1 or not any(e[3] in spike_channels for e in entries[i:j]):
            yield from entries[i:j]
            i = j
            continue
        by_channel: dict[int, list[int]] = {}  # the shared topics' entries, a channel each
        for k in range(i, j):
            if entries[k][3] in spike_channels:
                by_channel.setdefault(entries[k][3], []).append(k)
        out: dict[int, bytes | None] = {}
        for ks in by_channel.values():
            out.update(zip(ks, join_alike([entries[k][5] for k in ks]), strict=True))
        for k in range(i, j):
            if k not in out:
                yield entries[k]
                continue
            data = out[k]
            if data is None:
                res.joined += 1
                continue
            log_time, source, order, cid, publish_time, _ = entries[k]
            yield (log_time, source, order, cid, publish_time, data)
        i = j


def joined_pulses(
    entries: list[_Entry], pulse_channels: set[int], res: MergeResult
) -> list[_Entry]:
    """``entries`` with the ``/tx/pulse`` blocks of one channel and one block of time that
    several processes wrote (each its own senders') made the one block a single process of
    all their senders writes (``join_pulse_blocks``), at its last pulse's time. A block not as
    rgtbus writes it (unreadable, or its pulses in more than one block of time) is kept as it
    is."""
    if not pulse_channels:
        return entries
    by_block: dict[tuple[int, float, int], list[tuple[int, dict[str, Any]]]] = {}
    for k, e in enumerate(entries):
        if e[3] not in pulse_channels:
            continue
        try:
            record = decode_record(PULSE, e[5], "merge")
        except RgtbusError:
            continue
        span = block_samples(record["tau"])
        blocks = {int(s) // span for s in (record["sample"][0], record["sample"][-1])}
        if len(blocks) == 1 and len(record["sample"]):
            by_block.setdefault((e[3], record["tau"], blocks.pop()), []).append((k, record))
    dropped: set[int] = set()
    added: list[_Entry] = []
    for (cid, _, _), held in by_block.items():
        if len(held) < 2:
            continue
        joined = join_pulse_blocks([record for _, record in held])
        first = entries[held[0][0]]
        t_ns = max(entries[k][0] for k, _ in held)
        added.append((t_ns, first[1], first[2], cid, t_ns, encode_record(PULSE, joined)))
        dropped.update(k for k, _ in held)
        res.pulses_joined += len(held) - 1
    if not added:
        return entries
    out = [e for k, e in enumerate(entries) if k not in dropped] + added
    out.sort(key=lambda e: (e[0], e[1], e[2]))
    return out


def _write_messages(writer: Writer, entries: list[_Entry], dedupe: bool, res: MergeResult) -> None:
    """The entries, renumbered per channel; one of two identical messages (same channel, log
    time and bytes) dropped when ``dedupe``."""
    seen: set[tuple[int, int, bytes]] = set()
    sequence: Counter[int] = Counter()
    for log_time, _, _, cid, publish_time, data in entries:
        if dedupe:
            msg_key = (cid, log_time, data)
            if msg_key in seen:
                res.duplicates += 1
                continue
            seen.add(msg_key)
        sequence[cid] += 1
        writer.add_message(cid, log_time, data, publish_time, sequence[cid])
        res.messages += 1


def _merged_metadata(logs: Sequence[RawLog], res: MergeResult) -> dict[str, dict[str, str]]:
    """Every input's metadata records, each once (a name taken by a different record renamed
    ``NAME.K``), and the ``merge`` record listing the inputs."""
    kept: dict[str, dict[str, str]] = {}
    for k, log in enumerate(logs, start=1):
        for name, values in log.metadata:
            if name == FORMAT_RECORD:
                continue  # written first, once
            if any(
                v == values and (n == name or n.startswith(f"{name}.")) for n, v in kept.items()
            ):
                continue
            new = name
            if new in kept:
                new = f"{name}.{k}"
                i = 2
                while new in kept:
                    new = f"{name}.{k}.{i}"
                    i += 1
                res.renamed[f"input {k}: {name}"] = new
            kept[new] = values
    kept["merge" if "merge" not in kept else "merge.0"] = {
        "inputs": json.dumps([log.label for log in logs]),
        "renamed": json.dumps(res.renamed),
        "truncated": json.dumps(res.notes),
        "duplicates_dropped": str(res.duplicates),
        "spike_records_joined": str(res.joined),
        "pulse_blocks_joined": str(res.pulses_joined),
    }
    return kept


@dataclass
class RecoverResult:
    """What ``recover_log`` wrote: the messages kept, and where and why the input ended
    (``ended``: empty for a whole input)."""

    messages: int
    ended: str


def recover_log(log: RawLog, stream: BinaryIO, *, compression: str = "zstd") -> RecoverResult:
    """``rgtbus recover``: from ``log`` (``scan_log`` of a cut or damaged file) a complete MCAP
    file on ``stream`` (summary, statistics, indexes, CRCs) with every message read before
    the cut or the damage, every reader's to open. Its ``merge`` record says where the input
    ended, so rgtbus still reads it as cut there (``replay --verify`` exits 3), not as a
    whole run."""
    res = merge_logs([log], stream, compression=compression, dedupe=False, salvage=True)
    return RecoverResult(res.messages, "; ".join(res.notes))
