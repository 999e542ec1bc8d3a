"""A hot topic's record read back as its rows and units: a ``/rx/spike`` block's units
(``spike_units``), one record a unit (``each_unit_spikes``) and its spikes a sample at a time
(``spike_samples``); a ``/rx/decodes`` record's units (``decode_units``) and its decodes one
``/rx/decode`` record at a time (``decode_rows``); and a stream of messages with its blocks
as rows (``spikes_per_sample``, ``spikes_per_unit``, ``pulses_per_row``, ``decodes_per_row``:
how two logs are compared, however their writers grouped records). The records themselves
are built by ``records``; readers, the verifier and ``merge`` read them through here."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from typing import Any, cast

from rgtbus.errors import BadLog
from rgtbus.telemetry import records as r
from rgtbus.telemetry.pulse_blocks import pulse_rows
from rgtbus.telemetry.recorder import LogMessage
from rgtbus.telemetry.records import (
    DECODE_COLUMNS,
    DECODE_TABLES,
    NAMED_COLUMNS,
    RX_DECODES,
    RX_SPIKE,
    DecodeRecord,
    decode,
)
from rgtbus.timebase import ns, time_of


def spike_units(record: Mapping[str, Any]) -> list[str]:
    """The units whose spikes a ``/rx/spike`` record holds: its ``units``, or its one
    ``unit`` (the only form before records were shared)."""
    units = record.get("units")
    if units is None:
        return [record["unit"]]
    ok = isinstance(units, list) and len(units) >= 2 and "unit" not in record
    if not ok or not all(isinstance(u, str) for u in units) or len(set(units)) < len(units):
        # a record written by hand or tampered with: readers name it by its schema
        raise TypeError(f"{RX_SPIKE} units {units!r}: not two or more unit names alone")
    names: list[str] = units
    return names


def each_unit_spikes(record: Mapping[str, Any]) -> list[dict[str, Any]]:
    """A ``/rx/spike`` record as one record a unit: a shared record's spikes once for each of
    its units (with its ``unit``), any other as it is. How two logs compare whose units kept
    their spikes in other groups (another engine, another split of units into processes)."""
    if "units" not in record:
        return [dict(record)]
    rest = {k: v for k, v in record.items() if k != "units"}
    return [{"unit": u, **rest} for u in spike_units(record)]


def _spikes_of(record: Mapping[str, Any]) -> str:
    return f"{RX_SPIKE} of {record.get('unit', record.get('units'))!r}"


def spike_samples(record: Mapping[str, Any]) -> Iterator[tuple[int, list[str]]]:
    """A block of spikes (``/rx/spike``, as read) one sample at a time: (sample, the names
    of the channels that fired there, in order). Reads the columns of one entry a spike
    (``samples``, ``channel`` into ``names``) and the block of logs before them (``samples``
    and a list of names per sample). A channel index outside ``names``: RgtbusError."""
    samples = record["samples"]
    if "names" not in record:
        yield from zip(samples, record["channels"], strict=True)
        return
    names, channel = record["names"], record["channel"]
    if len(channel) != len(samples):
        raise BadLog(
            f"{_spikes_of(record)} at sample {record.get('sample')}: "
            f"{len(samples)} samples but {len(channel)} channels"
        )
    i, n = 0, len(samples)
    while i < n:
        k = samples[i]
        fired = []
        while i < n and samples[i] == k:
            c = channel[i]
            if not 0 <= c < len(names):
                raise BadLog(
                    f"{_spikes_of(record)} at sample {k}: channel {c} is not "
                    f"one of its {len(names)} names"
                )
            fired.append(names[c])
            i += 1
        yield k, fired


def _named(unit: str, record: dict[str, Any]) -> None:
    """A record's columns of indexes (``decodes_of_columns`` with tables) as names, in place;
    a table that is not a list of names, or an index out of it: RgtbusError naming both."""
    where = f"{RX_DECODES} of {unit!r} at t = {record.get('t')}"
    for column, table_name in NAMED_COLUMNS.items():
        table, col = record.get(table_name), record.get(column)
        if not (isinstance(table, list) and all(isinstance(x, str) for x in table)):
            raise BadLog(f"{where}: {table_name!r} is not a list of names")
        if not isinstance(col, list):
            continue  # said below, with the other columns
        bad = [i for i in col if not (type(i) is int and 0 <= i < len(table))]
        if bad:
            raise BadLog(
                f"{where}: {column} {bad[0]!r} is no index into its {len(table)} {table_name}"
            )
        record[column] = [table[i] for i in col]


def decode_rows(record: Mapping[str, Any]) -> Iterator[DecodeRecord]:
    """The decodes of a ``/rx/decodes`` record (as read) one at a time, each as ``decode``
    builds it (what a log of one record a decode holds). Columns of unequal length:
    RgtbusError naming the unit and the column."""
    units = decode_units(record)
    unit = units[0]
    # columns a writer holds as arrays (a record not yet written) read as a log gives them
    record = {
        k: v.tolist() if hasattr(v, "tolist") else list(v) if type(v) is tuple else v
        for k, v in record.items()
    }
    if any(t in record for t in DECODE_TABLES):
        _named(unit, record)
    times = record.get("times")
    n = len(times) if isinstance(times, list) else -1
    for name in ("times", *DECODE_COLUMNS):  # the times first: the others are held to them
        col = record.get(name)
        if isinstance(col, list) and len(col) == n:
            continue
        got = (
            "missing"
            if col is None
            else f"{len(col)} entries"
            if isinstance(col, list)
            else type(col).__name__
        )
        want = "a list" if n < 0 else f"{n} entries like times"
        raise BadLog(
            f"{RX_DECODES} of {unit!r} at t = {record.get('t')}: column {name!r} is {got}, "
            f"not {want}"
        )
    for unit in units:  # a record of several units' decodes alike: each unit's in turn
        for turn, sender, addressee, channel, kind, code, margin, t, accepted in zip(
            *(record[c] for c in DECODE_COLUMNS), strict=True
        ):
            yield decode(unit, turn, sender, addressee, channel, kind, code, margin, t, accepted)


def decode_units(record: Mapping[str, Any]) -> list[str]:
    """The units whose decodes a ``/rx/decodes`` record holds: its ``unit``, or its ``units``
    (two or more names, each once, which each made its decodes alike). Anything else:
    RgtbusError naming the record."""
    units = record.get("units")
    if units is None:
        return [cast(str, record.get("unit"))]
    units = list(units) if isinstance(units, list | tuple) else units
    if (
        not isinstance(units, list)
        or len(units) < 2
        or not all(type(u) is str for u in units)
        or len(set(units)) < len(units)
        or "unit" in record
    ):
        raise BadLog(
            f"{RX_DECODES} at t = {record.get('t')}: units {units!r}: not two or more unit "
            "names alone"
        )
    return units


# -- a stream of messages with its blocks as rows (how two logs are compared) ------------


def spikes_per_sample(messages: Iterable[LogMessage], tau: float) -> Iterator[LogMessage]:
    """The messages with every ``/rx/spike`` block as one message per sample (as logs before
    the columnar record held them): spikes are compared sample by sample, so a log of either
    form verifies, and a mismatch names its sample."""
    for topic, t_ns, m in messages:
        if topic != r.RX_SPIKE or not isinstance(m, dict) or "samples" not in m:
            yield topic, t_ns, m
            continue
        units = spike_units(m)  # a record the units of a process share: each unit's own
        for k, chans in spike_samples(m):
            t = time_of(k, tau)
            for unit in units:
                yield topic, ns(t), {"unit": unit, "t": t, "sample": k, "channels": chans}


def spikes_per_unit(
    messages: Iterable[LogMessage],
) -> Iterator[LogMessage]:
    """The messages with every ``/rx/spike`` record that units shared as one record a unit
    (``each_unit_spikes``): how logs compare whose units were split into processes, or
    engines, that share records differently."""
    for topic, t_ns, m in messages:
        if topic != r.RX_SPIKE or not isinstance(m, dict):
            yield topic, t_ns, m
            continue
        for one in each_unit_spikes(m):
            yield topic, t_ns, one


def pulses_per_row(messages: Iterable[LogMessage]) -> Iterator[LogMessage]:
    """The messages with every ``/tx/pulse`` block as one message a pulse at its own time:
    pulses are compared one by one, and a mismatch names its pulse."""
    for topic, t_ns, m in messages:
        if topic != r.TX_PULSE or not isinstance(m, dict) or "sample" not in m:
            yield topic, t_ns, m
            continue
        for row in pulse_rows(m):
            yield topic, ns(row["t"]), cast(dict[str, Any], row)


def decodes_per_row(
    messages: Iterable[LogMessage],
) -> Iterator[LogMessage]:
    """The messages with every ``/rx/decodes`` record as one ``/rx/decode`` message a decode
    at its own time (as logs before the columnar record held them): decodes are compared one
    by one, however a run grouped them into records, and a mismatch names its decode."""
    for topic, t_ns, m in messages:
        if topic != r.RX_DECODES or not isinstance(m, dict):
            yield topic, t_ns, m
            continue
        for row in decode_rows(m):
            yield r.RX_DECODE, ns(row["t"]), cast(dict[str, Any], row)
