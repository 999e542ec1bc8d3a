"""``rgtbus log cat``: a log's messages as lines of JSON, in log-time order, chosen by topic,
unit and time (``cat_messages``), blocks as their rows unless asked for as stored; and the
one rule for a ``--from``/``--to`` range of log time (``check_time_range``)."""

from __future__ import annotations

import heapq
import math
import os
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import Any

from mcap.reader import make_reader

from rgtbus.errors import BadInput, BadLog
from rgtbus.telemetry.blocks import MESSAGE_ENCODING, schema_of
from rgtbus.telemetry.log_check import CheckedLog, check_log
from rgtbus.telemetry.logtools import log_info
from rgtbus.telemetry.pulse_blocks import pulse_rows
from rgtbus.telemetry.record_rows import decode_rows
from rgtbus.telemetry.records import (
    LOG,
    RX_DECODES,
    TRACE_PREFIX,
    TX_PULSE,
    is_trace_topic,
)
from rgtbus.telemetry.untrusted import message as checked
from rgtbus.timebase import ns, seconds


def _unit_of(topic: str, message: dict[str, Any]) -> str | None:
    """The unit a message is about: the receiving, sending or reasoning unit; a trace's unit;
    a log line's name. The medium and the run summary belong to no unit."""
    if is_trace_topic(topic):
        return topic[len(TRACE_PREFIX) :]
    if not isinstance(message, dict):
        return None
    if topic == LOG:
        return message.get("name")
    unit = message.get("unit")
    return unit if isinstance(unit, str) else None


def _units_of_block(topic: str, message: Any) -> list[str]:
    """The units a block without one ``unit`` is about: a ``/tx/pulse`` block's senders (every
    sender of a process's block of time), a shared record's ``units``."""
    if not isinstance(message, dict):
        return []
    if topic == TX_PULSE:
        names, senders = message.get("names"), message.get("sender")
        if isinstance(names, list) and isinstance(senders, list):
            return [names[i] for i in sorted(set(senders)) if isinstance(i, int) and i < len(names)]
        return []
    shared = message.get("units")
    return shared if isinstance(shared, list) else []


def cat_messages(
    log: str | os.PathLike[str] | CheckedLog,
    *,
    topics: Sequence[str] = (),
    unit: str | None = None,
    t_from: float | None = None,
    t_to: float | None = None,
    blocks: bool = False,
) -> Iterator[dict[str, Any]]:
    """Messages in log-time order as ``{"topic", "t", "log_time", "message"}`` (t in
    simulated seconds), on ``topics`` (all when empty), about ``unit``, with from <= t <= to,
    from a path or a log ``check_log`` opened (checked whole before the first message: a
    damaged log is refused, never printed in part). Unknown topics or units: RgtbusError
    naming them and what the log has.

    A ``/rx/decodes`` block (a unit's decodes of a block, as columns) is given one decode a
    message (``decode_rows``: what a ``/rx/decode`` holds), and a ``/tx/pulse`` block
    one pulse a message (``pulse_blocks.pulse_rows``), each at its own time and filtered by it;
    ``blocks``: the blocks as stored instead (their columns as lists)."""
    if not isinstance(log, CheckedLog):
        with check_log(log) as checked:
            yield from cat_messages(checked, topics=topics, unit=unit, t_from=t_from,
                                    t_to=t_to, blocks=blocks)  # fmt: skip
        return
    info = log_info(log)
    known = list(info["topics"])
    for t in topics:
        if t not in known:
            raise BadInput(f"--topic {t!r}: not in this log (topics: {', '.join(known)})")
    if unit is not None and unit not in info["units"]:
        raise BadInput(f"--unit {unit!r}: not a unit of this log ({', '.join(info['units'])})")
    if info["start"] is not None:
        check_time_range(t_from, t_to, info["start"], info["end"])
    start = None if t_from is None else ns(t_from)
    end = None if t_to is None else ns(t_to)  # inclusive, like start
    wanted = set(topics or known)
    rows = set() if blocks else wanted & set(_ROWS)
    stored = _cat_scanned if log.raw is not None else _cat_indexed
    messages = stored(log, wanted - rows, unit, start, end)
    for topic in sorted(rows):  # a block's rows reach back before its log time: all are read
        blocks_of = stored(log, {topic}, unit, None, None)
        each = _block_rows(topic, blocks_of, start, end, log.label, unit)
        messages = heapq.merge(messages, each, key=lambda m: m["log_time"])
    yield from messages


# the block topics whose blocks ``cat`` gives one row a message: what one row is
_ROWS: dict[str, Callable[[Mapping[str, Any]], Iterable[Mapping[str, Any]]]] = {
    RX_DECODES: decode_rows,
    TX_PULSE: pulse_rows,
}


def _block_rows(
    topic: str,
    blocks: Iterator[dict[str, Any]],
    start: int | None,
    end: int | None,
    label: str,
    unit: str | None = None,
) -> Iterator[dict[str, Any]]:
    """The rows of ``topic``'s blocks (as ``_record`` gives them) one a message, at their own
    times, from ``start`` to ``end`` ns, ``unit``'s alone where one is named, in time order
    (stable: as logged)."""
    out: list[tuple[int, dict[str, Any]]] = []
    for block in blocks:
        try:
            rows = [(ns(row["t"]), row) for row in _ROWS[topic](block["message"])]
        except (TypeError, ValueError, KeyError, OverflowError, AttributeError) as exc:
            raise BadLog(
                f"{label}: message on {topic} at t = {seconds(block['log_time']):.3f} s "
                f"is no block of rows ({type(exc).__name__}: {exc})"
            ) from None
        for t, row in rows:
            if unit is not None and row.get("unit") != unit:
                continue
            if (start is None or t >= start) and (end is None or t <= end):
                line = {"topic": topic, "t": seconds(t), "log_time": t, "message": dict(row)}
                out.append((t, line))
    out.sort(key=lambda m: m[0])
    return (line for _, line in out)


def _cat_indexed(
    log: CheckedLog, wanted: set[str], unit: str | None, start: int | None, end: int | None
) -> Iterator[dict[str, Any]]:
    if not wanted:
        return
    log.stream.seek(0)
    reader = make_reader(log.stream)  # its CRCs vouched for every byte: the index narrows
    for _, channel, m in reader.iter_messages(
        topics=list(wanted), starting_at=start, ending_at=end, log_time_order=True
    ):
        msg = _record(log.label, channel, m.log_time, m.data, unit)
        if msg is not None:
            yield msg


def _cat_scanned(
    log: CheckedLog, wanted: set[str], unit: str | None, start: int | None, end: int | None
) -> Iterator[dict[str, Any]]:
    raw = log.raw
    assert raw is not None
    topics = {cid: ch.topic for cid, ch in raw.channels.items()}
    channels = raw.channels
    rows = sorted(
        ((t, i, cid, data) for i, (cid, t, _, _, data) in enumerate(raw.messages)),
        key=lambda r: (r[0], r[1]),
    )
    for t, _, cid, data in rows:
        if topics[cid] not in wanted or (start is not None and t < start):
            continue
        if end is not None and t > end:
            continue
        msg = _record(log.label, channels[cid], t, data, unit)
        if msg is not None:
            yield msg


def _record(
    label: str, channel: Any, log_time: int, data: bytes, unit: str | None
) -> dict[str, Any] | None:
    """A message as ``cat`` prints it (None: not about ``unit``). A message of a JSON
    channel that is not JSON, or nests too deep, is refused as every reader refuses it
    (``untrusted.message``); one of another encoding is shown as its length."""
    topic = channel.topic
    if channel.message_encoding == "json" or (
        channel.message_encoding == MESSAGE_ENCODING and schema_of(topic) is not None
    ):
        message = checked(topic, log_time, data, label, check=False)
        if schema_of(topic) is not None:  # a block: its columns as lists
            message = {k: v.tolist() if hasattr(v, "tolist") else v for k, v in message.items()}
    else:
        message = {"undecodable": len(data)}
    if unit is not None and _unit_of(topic, message) != unit:
        if unit not in _units_of_block(topic, message):
            return None
        if "units" in message:  # a record units share (/rx/spike, /rx/decodes): as its own
            message = {"unit": unit, **{k: v for k, v in message.items() if k != "units"}}
    return {"topic": topic, "t": seconds(log_time), "log_time": log_time, "message": message}


def check_time_range(
    t_from: float | None, t_to: float | None, start: float, end: float
) -> tuple[float, float]:
    """The range ``--from``/``--to`` ask for within a run from ``start`` to ``end`` s, as
    ``(lo, hi)`` (a missing bound is the run's); ``RgtbusError``, one line naming the values
    and the run's span, when it holds none of the run: a bound that is no number, from ≥ to,
    from at or past the run's end, or to at or before its start. A range that overlaps the run
    only in part is kept as asked. A run of one instant (a log whose every record is at one
    time: a unit whose join failed) is held by a range that holds that instant, and by no
    range at all."""
    bounds = (("from", t_from), ("to", t_to))
    given = " ".join(f"--{name} {value:g}" for name, value in bounds if value is not None)
    span = f"{start:g} to {end:g} s"
    for value in (t_from, t_to):
        if value is not None and not math.isfinite(value):
            raise BadInput(f"{given}: not a time (the run is {span})")
    if t_from is not None and t_to is not None and not t_to > t_from:
        raise BadInput(f"{given}: empty time range (the run is {span})")
    lo = start if t_from is None else float(t_from)
    hi = end if t_to is None else float(t_to)
    # a run of one instant: a range holds it or not
    outside = lo > end or hi < start if start == end else lo >= end or hi <= start
    if outside:
        raise BadInput(f"{given or 'the log'}: outside the run ({span})")
    return lo, hi
