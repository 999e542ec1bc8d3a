"""``rgtbus convert``: a log of format 1 (every topic JSON) written as format 2 (docs/format.md).

The hot topics become blocks as a run of today writes them (``group_log.GroupLog``, the
writer's own rules): every sender's pulses of a block of time one ``/tx/pulse`` block, the
decodes units made alike in a block one ``/rx/decodes`` record naming them; spikes, the medium
and traces one block a record (spikes of the older per-sample forms as columns). Every other
topic is copied message for message, with its own schema. The metadata records are copied,
with a ``convert`` record saying what was converted. A log cut short is converted up to its
cut and ends as a cut log does; a damaged one is refused.

The input is not trusted: a message is read only once it is needed, one at a time, and a
record that is not what format 1 held is one line naming the topic, its log time and the field.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, BinaryIO

import foxglove
import orjson

from rgtbus.errors import BadLog, RgtbusError
from rgtbus.telemetry import records as r
from rgtbus.telemetry.blocks import BLOCK_SECONDS, block_samples
from rgtbus.telemetry.group_log import GroupLog
from rgtbus.telemetry.mcap_recorder import McapRecorder
from rgtbus.telemetry.record_rows import spike_samples
from rgtbus.telemetry.scan import RawLog, _require_run
from rgtbus.telemetry.unit_log import DecodePart, canonical
from rgtbus.telemetry.untrusted import depth_error, printable
from rgtbus.telemetry.version import FORMAT_RECORD, format_of
from rgtbus.timebase import ns, sample_of, seconds

# the hot topics of format 1 (``/rx/decode``: one decode a record, older still)
_HOT = frozenset({r.MEDIUM, r.TX_PULSE, r.RX_SPIKE, r.RX_DECODE, r.RX_DECODES})


@dataclass
class ConvertResult:
    """What ``convert_log`` wrote: messages read and written, and where the input ended
    (``ended``: empty for a whole input)."""

    read: int
    written: int
    ended: str


def _decoded(label: str, topic: str, t_ns: int, data: bytes) -> Any:
    where = f"{label}: message on {printable(topic)} at t = {seconds(t_ns):.3f} s"
    try:
        message = orjson.loads(data)
    except orjson.JSONDecodeError as e:
        raise BadLog(f"{where} is not JSON: {e}") from None
    why = depth_error(message)
    if why is not None:
        raise BadLog(f"{where} {why}")
    if not isinstance(message, dict):
        raise BadLog(f"{where}: not an object")
    return message


def _scenario(raw: RawLog) -> tuple[float, list[str]]:
    """The sample period of the log's scenario (what a pulse block's rows are timed by) and
    its units."""
    from rgtbus.scenario import parse_scenario

    meta = dict(raw.metadata).get("scenario", {})
    if "text" not in meta:
        raise BadLog(f"{raw.label}: cannot convert its pulses: no scenario metadata")
    try:
        sc = parse_scenario(meta["text"], meta.get("path", "<scenario>"))
    except (RgtbusError, ValueError) as e:
        raise BadLog(f"{raw.label}: cannot convert its pulses: the scenario: {e}") from None
    return float(sc.timing.tau), list(sc.units)


def _spike_columns(record: Mapping[str, Any]) -> dict[str, Any]:
    """A ``/rx/spike`` record of any format-1 form as the columns of a block."""
    if "names" in record and "channel" in record:
        keep = ("unit", "units", "t", "sample", "samples", "channel", "names")
        return {k: record[k] for k in keep if k in record}
    samples: list[int] = []
    channel: list[int] = []
    names: dict[str, int] = {}
    if "samples" in record:
        pairs: Iterator[tuple[int, list[str]]] = spike_samples(record)
    else:  # one record a sample (the oldest form)
        pairs = iter([(record["sample"], list(record["channels"]))])
    for k, fired in pairs:
        for name in fired:
            samples.append(int(k))
            channel.append(names.setdefault(str(name), len(names)))
    if not samples:
        raise ValueError("no spike")
    return {
        **({"units": record["units"]} if "units" in record else {"unit": record["unit"]}),
        "t": record["t"],
        "sample": samples[0],
        "samples": samples,
        "channel": channel,
        "names": list(names),
    }


def _decode_row(record: Mapping[str, Any]) -> r.DecodeFields:
    """A ``/rx/decode`` record (one decode: the oldest logs) as a row of ``records.decodes``."""
    keys = ("turn", "sender", "addressee", "channel", "kind", "code", "margin", "t", "accepted")
    row = tuple(record[k] for k in keys)
    if not isinstance(row[7], float | int) or isinstance(row[7], bool):
        raise ValueError(f"t {row[7]!r} is not a time")
    return row


class _Converter:
    def __init__(self, raw: RawLog, out: McapRecorder) -> None:
        self.raw, self.out = raw, out
        self.tau: float | None = None
        self.group: GroupLog | None = None
        self.members: dict[str, int] = {}
        # unit -> decode block -> its rows (``/rx/decode``, one decode a record: the oldest logs)
        self.decodes: dict[str, dict[int, list[r.DecodeFields]]] = {}
        self.copied: dict[str, foxglove.Channel] = {}
        self.written = 0

    def write(self, topic: str, record: Mapping[str, Any], t_ns: int) -> None:
        self.out.write(topic, record, t_ns)
        self.written += 1

    def _group(self) -> GroupLog:
        """The writer's rules for pulses and decodes, over the scenario's units."""
        if self.group is None:
            self.tau, units = _scenario(self.raw)
            self.members = {u: i for i, u in enumerate(units)}
            self.group = GroupLog(self, self.tau, units)
        return self.group

    def _member(self, unit: Any) -> int:
        at = self.members.get(unit) if isinstance(unit, str) else None
        if at is None:
            raise ValueError(f"unit {printable(repr(unit))} is no unit of the scenario")
        return at

    def hot(self, topic: str, t_ns: int, message: dict[str, Any]) -> None:
        group = self._group()
        if topic == r.TX_PULSE:
            self._member(message["unit"])
            group.pulses.add(message)
        elif topic == r.RX_SPIKE:
            self.write(topic, _spike_columns(message), t_ns)
        elif topic == r.RX_DECODE:
            unit = message["unit"]
            self._member(unit)
            row = _decode_row(message)
            block = sample_of(float(row[7]), self._tau()) // self._block()
            self.decodes.setdefault(unit, {}).setdefault(block, []).append(row)
        elif topic == r.RX_DECODES:
            self._piece(message)
        else:  # the medium and traces: one block a record, as they are
            self.write(topic, message, t_ns)

    def _piece(self, record: Mapping[str, Any]) -> None:
        """A unit's decodes of one block (a format-1 ``/rx/decodes`` record), for its group's
        record."""
        member = self._member(record["unit"])
        cols = DecodePart(*(record[c] for c in r.DECODE_COLUMNS))
        tables = (
            tuple(record[t] for t in r.DECODE_TABLES)
            if all(t in record for t in r.DECODE_TABLES)
            else None
        )
        times = cols.times
        if not len(times):
            raise ValueError("no decode")
        block = sample_of(float(times[-1]), self._tau()) // self._block()
        piece, own = canonical(cols, tables, tables)
        self._group().decodes(member, block, piece, own)

    def _tau(self) -> float:
        self._group()
        assert self.tau is not None
        return self.tau

    def _block(self) -> int:
        return block_samples(self._tau())

    def _decodes_before(self, sample: int | None) -> None:
        """The held single decodes of the blocks that end at or before ``sample`` (all:
        None), one piece a unit and block, as the writer holds them."""
        for unit, held in self.decodes.items():
            for b in sorted(held):
                if sample is None or (b + 1) * self._block() <= sample:
                    self._piece(r.decodes(unit, held.pop(b)))

    def passed(self, t_ns: int) -> None:
        """The log has come to ``t_ns`` (messages in log-time order): every unit is past the
        blocks that end by then."""
        if self.group is None:
            return
        now = sample_of(seconds(t_ns), self._tau())
        self._decodes_before(now)
        for at in self.members.values():
            self.group.pulses_passed(at, now)
            self.group.decoded_to(at, now // self._block())

    def copy(self, cid: int, t_ns: int, data: bytes) -> None:
        """A message of a topic that keeps its form: as it is, under its own schema."""
        channel = self.raw.channels[cid]
        ch = self.copied.get(channel.topic)
        if ch is None:
            schema = self.raw.schemas.get(channel.schema_id)
            ch = self.copied[channel.topic] = foxglove.Channel(
                channel.topic,
                schema=None
                if schema is None
                else foxglove.Schema(name=schema.name, encoding=schema.encoding, data=schema.data),
                message_encoding=channel.message_encoding,
                context=self.out.context,
            )
        with self.out.raw_io():
            ch.log(data, log_time=t_ns)
        self.written += 1

    def end(self) -> None:
        self._decodes_before(None)
        if self.group is not None:
            for at in self.members.values():
                self.group.end(at)
        for ch in self.copied.values():
            ch.close()


def convert_log(
    raw: RawLog, stream: BinaryIO, *, compression: str = "zstd", source: str = ""
) -> ConvertResult:
    """``raw`` (``scan_log`` of a format-1 log) written to ``stream`` as a format-2 log (see
    the module docstring). Refused in one line: a damaged input, one that is no rgtbus run
    log, one already of format 2 or of a format not known, a message that is not what
    format 1 held (naming the topic, its log time and the field)."""
    if raw.corrupt:
        raise BadLog(f"{raw.corruption}; not converted")
    _require_run(raw.label, raw.library, raw.metadata, raw.header_only, fmt=False)
    version = format_of(raw.metadata)
    if version != 1:
        raise BadLog(
            f"{raw.label}: already an rgtbus log of format {printable(repr(version))}: "
            "nothing to convert"
        )
    out = McapRecorder(stream, compression=compression)
    conv = _Converter(raw, out)
    try:
        for name, values in raw.metadata:
            if name != FORMAT_RECORD:
                out.metadata(name, values)
        out.metadata("convert", {"from_format": "1", "source": source or raw.label})
        topics = {cid: ch.topic for cid, ch in raw.channels.items()}
        order = sorted(range(len(raw.messages)), key=lambda i: raw.messages[i][1])
        passed = -1
        block_ns = ns(BLOCK_SECONDS)
        for i in order:
            cid, t_ns, _, _, data = raw.messages[i]
            topic = topics[cid]
            if t_ns // block_ns != passed:  # a new block of log time: pulses behind go out
                passed = t_ns // block_ns
                conv.passed(t_ns)
            if topic not in _HOT and not r.is_trace_topic(topic):
                conv.copy(cid, t_ns, bytes(data))
                continue
            message = _decoded(raw.label, topic, t_ns, bytes(data))
            _named(raw.label, topic, t_ns, functools.partial(conv.hot, topic, t_ns, message))
        _named(raw.label, r.TX_PULSE, None, conv.end)
    except BaseException:
        out.close(finished=False)
        raise
    out.close(finished=not raw.truncated)
    return ConvertResult(len(raw.messages), conv.written, raw.note)


def _named(label: str, topic: str, t_ns: int | None, step: Callable[[], None]) -> None:
    """``step``, a record's conversion: what is wrong with the record, one line naming the
    topic and the log time."""
    at = "" if t_ns is None else f" at t = {seconds(t_ns):.3f} s"
    where = f"{label}: message on {printable(topic)}{at}"
    try:
        step()
    except KeyError as e:
        raise BadLog(f"{where}: no field {printable(repr(e.args[0]))}") from None
    except RgtbusError as e:
        raise BadLog(f"{where}: {e}") from None
    except (TypeError, ValueError, IndexError, AttributeError, OverflowError) as e:
        raise BadLog(f"{where}: {printable(str(e))}") from None
