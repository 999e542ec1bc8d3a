"""The hot topics' blocks (log format 2, docs/format.md): each topic's protobuf message type
and the one conversion each way between a block's bytes and the record readers use.

A block is a flat protobuf message of packed fixed-width columns (``codec``): written from a
record's arrays at array speed, read back as NumPy views of the message's bytes. ``encode``
is what the recorder writes; ``decode`` is what every reader reads a hot message by, bounds
checked before anything is allocated (``codec.decode``) and its indexes checked against its
tables, so a record a reader gets from a block is as sound as one its writer built.

| topic | block | rows |
| --- | --- | --- |
| ``/tx/pulse`` | ``rgtbus.PulseBlock`` | a sender's pulses of one decode block (5 s) |
| ``/rx/spike`` | ``rgtbus.SpikeBlock`` | one block's spikes of a unit, or of units alike |
| ``/rx/decodes`` | ``rgtbus.DecodeBlock`` | a unit's decodes of one decode block |
| ``/medium`` | ``rgtbus.MediumBlock`` | one window of the medium (its samples) |
| ``/trace/<unit>`` | ``rgtbus.TraceBlock`` | a unit's resonator states at one sample |
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from functools import cache
from typing import Any

import numpy as np

from rgtbus.errors import BadInput, BadLog, RgtbusError
from rgtbus.telemetry import records as r
from rgtbus.telemetry.codec import Block, BlockSchema, Field, encode
from rgtbus.telemetry.codec import decode as decode_block

# A unit's decodes, and a sender's pulses, of this much time make one block: short enough that
# a log cut by a kill holds a unit's records to within a few seconds of each other (so a paced
# run's verified prefix reaches about a wall second before the cut), long enough that a block
# carries many rows (1 s blocks cost a 50-unit run 25 % more time, 5 s blocks 8 %, against
# 60 s blocks)
BLOCK_SECONDS = 5.0


def block_samples(tau: float) -> int:
    """The samples of one block of ``BLOCK_SECONDS`` on a clock of period ``tau``: block k
    holds samples [k·n, (k+1)·n). The one rule of the writer (pulses, decodes), ``merge``,
    ``convert`` and a cut log's bound."""
    return max(1, round(BLOCK_SECONDS / tau))

SCHEMA_ENCODING = "protobuf"
MESSAGE_ENCODING = "protobuf"

# The most rows a block may hold, and the most names in one of its tables: far beyond what a
# run writes (a 300-unit run's largest block of decodes holds ~30 k rows), checked before a
# reader allocates anything (a hostile block claiming more is one line, not gigabytes).
MAX_ROWS = 1 << 24
MAX_NAMES = 1 << 16


def _col(name: str, number: int, kind: Any, table: str | None = "rows") -> Field:
    return Field(name, number, kind, repeated=True, table=table)


PULSE = BlockSchema(
    "rgtbus.PulseBlock",
    (
        Field("t", 1, "double"),  # the last pulse's time: the block's log time
        Field("tau", 2, "double"),  # the senders' sample period: a pulse's t is sample × tau
        _col("channels", 3, "string", "channels"),  # the channels its pulses are on
        _col("omegas", 4, "double", "channels"),  # each channel's ω (rad/s)
        _col("names", 5, "string", None),  # the units sender and addressee index
        _col("kinds", 6, "string", None),  # the message kinds kind indexes
        _col("codes", 7, "string", None),  # the code names code indexes
        _col("sample", 8, "sfixed64"),  # each pulse's sample on the senders' clock
        _col("channel", 9, "fixed32"),  # into channels
        _col("magnitude", 10, "double"),
        _col("message", 11, "sfixed64"),  # the message's id (turn × 2, +1 for a payload)
        _col("kind", 12, "fixed32"),  # into kinds
        _col("code", 13, "fixed32"),  # into codes
        _col("sender", 14, "fixed32"),  # into names: the unit that sent the pulse
        _col("addressee", 15, "fixed32"),  # into names
        _col("block", 16, "fixed32"),  # a request's or a repeat's repair block (1..K), else 0
    ),
)

SPIKE = BlockSchema(
    "rgtbus.SpikeBlock",
    (
        Field("unit", 1, "string"),  # the one unit whose spikes these are, or
        _col("units", 2, "string", None),  # the units (two or more) that heard these alike
        Field("t", 3, "double"),  # the first spike's time
        Field("sample", 4, "sfixed64"),  # the first spike's sample
        _col("samples", 5, "sfixed64"),  # one a spike
        _col("channel", 6, "fixed32"),  # one a spike: into names
        _col("names", 7, "string", None),  # the channels that fired, by name
    ),
)

DECODE = BlockSchema(
    "rgtbus.DecodeBlock",
    (
        Field("unit", 1, "string"),  # the one unit that decoded these, or
        _col("units", 2, "string", None),  # the units (two or more) that decoded these alike
        Field("t", 3, "double"),  # the last decode's time: the block's log time
        _col("names", 4, "string", None),  # the units sender, addressee and channel index
        _col("kinds", 5, "string", None),  # the kinds kind indexes
        _col("codes", 6, "string", None),  # the code names code indexes
        _col("turn", 7, "sfixed32"),
        _col("sender", 8, "fixed32"),
        _col("addressee", 9, "fixed32"),
        _col("channel", 10, "fixed32"),
        _col("kind", 11, "fixed32"),
        _col("code", 12, "fixed32"),
        _col("margin", 13, "double"),
        _col("times", 14, "double"),
        _col("accepted", 15, "bool"),
    ),
)

MEDIUM = BlockSchema(
    "rgtbus.MediumBlock",
    (
        Field("window", 1, "sfixed64"),
        Field("t", 2, "double"),  # the window's first sample's time
        Field("sample_rate", 3, "double"),
        _col("samples", 4, "double", None),  # the window's samples of the medium
    ),
)

TRACE = BlockSchema(
    "rgtbus.TraceBlock",
    (
        Field("unit", 1, "string"),
        Field("sample", 2, "sfixed64"),
        Field("t", 3, "double"),
        _col("y", 4, "double", "channels"),  # each resonator's state (imaginary part)
        _col("x", 5, "double", "channels"),  # (real part)
    ),
)

SCHEMAS: dict[str, BlockSchema] = {
    s.name: s for s in (PULSE, SPIKE, DECODE, MEDIUM, TRACE)
}  # fmt: skip


def schema_of(topic: str) -> BlockSchema | None:
    """The block type of a hot ``topic``, or None for a topic of JSON records."""
    if r.is_trace_topic(topic):
        return TRACE
    return _BY_TOPIC.get(topic)


_BY_TOPIC = {r.TX_PULSE: PULSE, r.RX_SPIKE: SPIKE, r.RX_DECODES: DECODE, r.MEDIUM: MEDIUM}


# -- records -> blocks (the writer) ---------------------------------------------------------------


def _names_and_index(column: Any) -> tuple[list[str], np.ndarray]:
    """A column of names as (its table, first seen first; each row's index into it)."""
    table: dict[str, int] = {}
    index = [table.setdefault(str(x), len(table)) for x in column]
    return list(table), np.asarray(index, dtype=np.uint32)


def _array(record: Mapping[str, Any], key: str, dtype: Any) -> np.ndarray:
    """``record[key]`` as a 1-D array of ``dtype``; what cannot be one: ValueError naming it."""
    try:
        array = np.asarray(record[key], dtype=dtype)
    except (TypeError, ValueError, OverflowError) as e:
        raise ValueError(f"{key}: {e}") from None
    return _finite(key, array)


def _finite(key: str, array: np.ndarray) -> np.ndarray:
    """``array`` itself; a NaN or infinity in a float column (no run computes one: a log
    holds finite numbers, as its JSON did): ValueError naming the column."""
    if array.dtype.kind == "f" and array.size and not np.isfinite(array).all():
        bad = array[~np.isfinite(array)][0]
        raise ValueError(f"{key}: {float(bad)!r} is not a finite number")
    return array


def _number(record: Mapping[str, Any], key: str, kind: type) -> Any:
    """A scalar field as ``kind`` (int or float): a bool, a None or text is refused naming it."""
    value = record[key]
    ok = isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )
    if not ok or (kind is int and not float(value).is_integer()):
        raise ValueError(f"{key}: {value!r} is not {'an integer' if kind is int else 'a number'}")
    out = kind(value)
    if kind is float and not np.isfinite(out):
        raise ValueError(f"{key}: {value!r} is not a finite number")
    return out


def _decode_block(record: Mapping[str, Any]) -> Block:
    block: Block = {"t": _number(record, "t", float)}
    if "units" in record:
        block["units"] = _texts(record, "units")
    else:
        block["unit"] = record["unit"]
    if "names" in record:  # indexes into the record's own tables
        for key in r.DECODE_TABLES:  # a unit's own tables: the same tuple in every record
            table = record[key]
            block[key] = table if type(table) is tuple else _texts(record, key)  # type: ignore[assignment]
        for key in r.NAMED_COLUMNS:
            block[key] = _index(record[key])
    else:  # columns of names: tables made here (units first, as a unit's own tables are)
        units: dict[str, int] = {}
        for key in ("sender", "addressee", "channel"):
            block[key] = np.asarray(
                [units.setdefault(str(x), len(units)) for x in record[key]], dtype=np.uint32
            )
        block["names"] = list(units)
        block["kinds"], block["kind"] = _names_and_index(record["kind"])
        block["codes"], block["code"] = _names_and_index(record["code"])
    for column, table in r.NAMED_COLUMNS.items():
        block[column] = _within(np.asarray(block[column]), block[table], column, table)  # type: ignore[arg-type]
    turn = _array(record, "turn", np.int64)
    if turn.size and (int(turn.min()) < -(2**31) or int(turn.max()) >= 2**31):
        raise ValueError("turn: values outside sfixed32")
    block["turn"] = turn.astype("<i4")
    block["margin"] = _array(record, "margin", np.float64)
    block["times"] = _array(record, "times", np.float64)
    block["accepted"] = _array(record, "accepted", np.bool_)
    return block


def _index(column: Any) -> np.ndarray:
    array = np.asarray(column)
    if array.size and array.dtype.kind not in "iu":
        raise BadInput(f"an index column of {array.dtype}, not integers")
    return array


_U4 = np.dtype("<u4")
_I8 = np.dtype("<i8")


def _within(index: np.ndarray, table: Sequence[Any], column: str, name: str) -> np.ndarray:
    """``index`` as the wire's ``fixed32``; an entry outside ``table`` (its ``name``), or no
    integer: ValueError naming both."""
    if index.dtype == _U4:
        if index.size and int(index.max()) >= len(table):
            bad = int(index[index >= len(table)][0])
            raise ValueError(f"{column} {bad} is no index into its {len(table)} {name}")
        return index
    if index.dtype == _I8 and index.flags.c_contiguous:
        # a negative index seen as unsigned is beyond any table: one pass finds both
        if index.size and int(index.view(np.uint64).max()) >= len(table):
            bad = int(index[(index < 0) | (index >= len(table))][0])
            raise ValueError(f"{column} {bad} is no index into its {len(table)} {name}")
        return index.astype(_U4)
    if index.size and index.dtype.kind not in "iu":
        raise ValueError(f"{column}: {index.dtype} values, not indexes")
    if index.size and (int(index.min()) < 0 or int(index.max()) >= len(table)):
        bad = int(index[(index < 0) | (index >= len(table))][0])
        raise ValueError(f"{column} {bad} is no index into its {len(table)} {name}")
    return index.astype(_U4)


def _texts(record: Mapping[str, Any], key: str) -> list[str]:
    """``record[key]`` as a list of names: a list or tuple of text, nothing else."""
    value = record[key]
    if not isinstance(value, list | tuple) or not all(type(v) is str for v in value):
        raise ValueError(f"{key}: {value!r} is not a list of names")
    return list(value)


def _spike_block(record: Mapping[str, Any]) -> Block:
    block: Block = {
        "t": _number(record, "t", float),
        "sample": _number(record, "sample", int),
        "samples": _array(record, "samples", np.int64),
        "channel": _within(np.asarray(record["channel"]), record["names"], "channel", "names"),
        "names": _texts(record, "names"),
    }
    if "units" in record:
        block["units"] = _texts(record, "units")
    else:
        block["unit"] = record["unit"]
    return block


def _medium_block(record: Mapping[str, Any]) -> Block:
    return {
        "window": _number(record, "window", int),
        "t": _number(record, "t", float),
        "sample_rate": _number(record, "sample_rate", float),
        "samples": _array(record, "samples", np.float64),
    }


def _trace_block(record: Mapping[str, Any]) -> Block:
    return {
        "unit": record["unit"],
        "sample": _number(record, "sample", int),
        "t": _number(record, "t", float),
        "y": _array(record, "y", np.float64),
        "x": _array(record, "x", np.float64),
    }


def _pulse_block(record: Mapping[str, Any]) -> Block:
    block = dict(record)
    for key in ("omegas", "magnitude"):
        values = record[key]
        if type(values) is list and all(type(v) is float for v in values):
            if not all(map(math.isfinite, values)):
                _finite(key, np.asarray(values))  # says which
        else:
            block[key] = _finite(key, np.asarray(values))
    block["t"] = _number(record, "t", float)
    block["tau"] = _number(record, "tau", float)
    return block


_TO_BLOCK: dict[str, Callable[[Mapping[str, Any]], Block]] = {
    PULSE.name: _pulse_block,
    SPIKE.name: _spike_block,
    DECODE.name: _decode_block,
    MEDIUM.name: _medium_block,
    TRACE.name: _trace_block,
}


def encode_record(schema: BlockSchema, record: Mapping[str, Any]) -> bytes:
    """A hot topic's record as its block's bytes (canonical: a function of its values). A
    record the block cannot hold (a missing field, a value of the wrong kind): RgtbusError."""
    extra = set(record) - {f.name for f in schema.fields}
    if extra:
        raise BadInput(f"{schema.name}: unexpected field {sorted(extra)[0]!r}")
    unit = record.get("unit", "")
    if type(unit) is not str:
        raise BadInput(f"{schema.name}: unit {unit!r} is not a name")
    try:
        block = _TO_BLOCK[schema.name](record)
    except KeyError as e:
        raise BadInput(f"{schema.name}: the record has no {e.args[0]!r}") from None
    except (TypeError, ValueError, OverflowError) as e:
        raise BadInput(f"{schema.name}: {e}") from None
    try:
        return encode(schema, block)
    except RgtbusError as e:
        raise BadInput(f"{schema.name}: {e}") from None


# -- blocks -> records (every reader) -------------------------------------------------------------


def _check_index(block: Block, column: str, table: str, where: str) -> None:
    index = block[column]
    names = block[table]
    assert isinstance(index, np.ndarray) and isinstance(names, list)
    if index.size and int(index.max()) >= len(names):
        bad = int(index[int(np.argmax(index >= len(names)))])
        raise BadLog(f"{where}: {column} {bad} is no index into its {len(names)} {table}")


def _unit(block: Block, where: str) -> str:
    unit = block["unit"]
    if not unit:
        raise BadLog(f"{where}: no unit")
    return str(unit)


def _decode_record(block: Block, where: str) -> dict[str, Any]:
    for column, table in r.NAMED_COLUMNS.items():
        _check_index(block, column, table, where)
    return _units_record(block, where)


def _spike_record(block: Block, where: str) -> dict[str, Any]:
    _check_index(block, "channel", "names", where)
    return _units_record(block, where)


def _units_record(block: Block, where: str) -> dict[str, Any]:
    """A block of one unit's (``unit``) or of several units' alike (``units``, two or more
    names, each once), as its record."""
    units = block.pop("units")
    assert isinstance(units, list)
    if units:
        if block["unit"] or len(units) < 2 or len(set(units)) < len(units):
            raise BadLog(f"{where}: units {units!r}: not two or more unit names alone")
        del block["unit"]
        return {"units": units, **block}
    return {"unit": _unit(block, where), **block}


def _pulse_record(block: Block, where: str) -> dict[str, Any]:
    _check_index(block, "channel", "channels", where)
    _check_index(block, "kind", "kinds", where)
    _check_index(block, "code", "codes", where)
    _check_index(block, "sender", "names", where)
    _check_index(block, "addressee", "names", where)
    tau = block["tau"]
    if not (isinstance(tau, float) and 0 < tau <= 1):
        raise BadLog(f"{where}: tau {tau!r} is not a sample period (0 < tau <= 1 s)")
    sample = block["sample"]
    assert isinstance(sample, np.ndarray)
    if sample.size and int(sample.max()) * tau > MAX_SECONDS:
        raise BadLog(f"{where}: sample {int(sample.max())} is beyond {MAX_SECONDS:g} s")
    return dict(block)


def _medium_record(block: Block, where: str) -> dict[str, Any]:
    return dict(block)


def _trace_record(block: Block, where: str) -> dict[str, Any]:
    return {"unit": _unit(block, where), **block}


_TO_RECORD: dict[str, Callable[[Block, str], dict[str, Any]]] = {
    PULSE.name: _pulse_record,
    SPIKE.name: _spike_record,
    DECODE.name: _decode_record,
    MEDIUM.name: _medium_record,
    TRACE.name: _trace_record,
}


# Every float a block holds is finite, a time lies in [0, MAX_SECONDS] and a sample index in
# [0, MAX_SAMPLE]: what no run writes beyond, and what keeps every reader's arithmetic (times to
# integer ns, samples to times) exact and in range.
MAX_SECONDS = 1e9  # ~31 years of simulated time
MAX_SAMPLE = 1 << 53  # a float64 holds every integer up to here
_TIMES = frozenset({"t", "times"})
_SAMPLES = frozenset({"sample", "samples", "window", "message"})  # indexes and counts: >= 0


_NOT_FINITE = "a value that is not a finite number"


def _ranges(schema: BlockSchema, block: Block, where: str) -> None:
    for f in schema.fields:
        value = block[f.name]
        if f.kind in ("double", "float"):
            if isinstance(value, np.ndarray):
                if not value.size:
                    continue
                lo, hi = float(value.min()), float(value.max())  # NaN: both NaN
                if not (math.isfinite(lo) and math.isfinite(hi)):
                    raise BadLog(f"{where}: {f.name} holds {_NOT_FINITE}")
            else:
                lo = hi = float(value)  # type: ignore[arg-type]
                if not math.isfinite(lo):
                    raise BadLog(f"{where}: {f.name} holds {_NOT_FINITE}")
            if f.name in _TIMES and (lo < 0 or hi > MAX_SECONDS):
                raise BadLog(f"{where}: {f.name} holds a time outside 0..{MAX_SECONDS:g} s")
        elif f.name in _SAMPLES:
            if isinstance(value, np.ndarray):
                if not value.size:
                    continue
                lo_i, hi_i = int(value.min()), int(value.max())
            else:
                lo_i = hi_i = int(value)  # type: ignore[arg-type]
            if lo_i < 0 or hi_i > MAX_SAMPLE:
                raise BadLog(f"{where}: {f.name} holds an index outside 0..2^53")


def decode_record(schema: BlockSchema, data: bytes, where: str) -> dict[str, Any]:
    """A block's bytes as the record readers use (columns as read-only NumPy views of
    ``data``, tables as lists of names). Anything wrong (a length past the end, more rows than
    ``MAX_ROWS``, columns of one table of unequal length, an index outside its table): one
    RgtbusError naming ``where``, the block type and the field, before anything is made."""
    block = decode_block(schema, data, max_rows=MAX_ROWS, where=where)
    where = f"{where}: {schema.name}"
    for f in schema.fields:
        if f.kind == "string" and f.repeated and len(block[f.name]) > MAX_NAMES:  # type: ignore[arg-type]
            raise BadLog(f"{where}: {f.name} holds more than {MAX_NAMES}")
    _ranges(schema, block, where)
    return _TO_RECORD[schema.name](block, where)


# -- a block's units, read and written alone (merge joins blocks units made alike) ----------------


def units_head(data: bytes) -> tuple[list[str], bytes] | None:
    """A ``/rx/spike`` or ``/rx/decodes`` block's units and the rest of its bytes after them,
    when it is as rgtbus writes it (its one ``unit`` or its ``units`` first: fields 1 and 2,
    in number order, in both block types); else None (left as it is). Only the head is read,
    not the block's columns."""
    units: list[str] = []
    pos, n, tag = 0, len(data), 0
    while pos < n and data[pos] in (0x0A, 0x12):
        if units and (tag == 0x0A or data[pos] == 0x0A):
            return None  # a unit after another, or beside units: not rgtbus's
        tag = data[pos]
        length, pos = _short_varint(data, pos + 1)
        if length < 0 or pos + length > n:
            return None
        try:
            units.append(data[pos : pos + length].decode())
        except UnicodeDecodeError:
            return None
        pos += length
    if not units or (tag == 0x12 and len(units) < 2):
        return None
    return (units, data[pos:]) if data[:pos] == units_head_bytes(units, tag == 0x0A) else None


def join_alike(datas: Sequence[bytes]) -> list[bytes | None]:
    """The ``/rx/spike`` (or ``/rx/decodes``) blocks of one log time and channel, with the ones
    that hold the same spikes (decodes) — their bytes after the units — made one block naming
    every unit of them, in sorted order, where the first of them was; None where one was
    joined into an earlier one. A block not as rgtbus writes it stays as it is. The one rule
    by which the units of one process write a block they made alike once, and ``merge``
    joins the blocks of several processes: the result is the same for any split."""
    groups: dict[bytes, list[str]] = {}
    heads: list[bytes | None] = []
    for data in datas:
        parsed = units_head(data)
        if parsed is None:
            heads.append(None)
            continue
        heads.append(parsed[1])
        groups.setdefault(parsed[1], []).extend(parsed[0])
    out: list[bytes | None] = []
    for data, head in zip(datas, heads, strict=True):
        if head is None:
            out.append(data)
            continue
        joined = groups.pop(head, None)
        out.append(None if joined is None else units_head_bytes(sorted(set(joined))) + head)
    return out


def _short_varint(data: bytes, pos: int) -> tuple[int, int]:
    """A varint of at most 4 bytes at ``pos`` (a name's length): (value, where it ends), or
    (-1, pos) when there is none."""
    value = shift = 0
    for i in range(pos, min(pos + 4, len(data))):
        value |= (data[i] & 0x7F) << shift
        if data[i] < 0x80:
            return value, i + 1
        shift += 7
    return -1, pos


def units_head_bytes(units: list[str], one: bool | None = None) -> bytes:
    """The first bytes of a ``/rx/spike`` or ``/rx/decodes`` block of ``units``: one unit's
    ``unit`` field, two or more units' ``units`` fields (``one``: which, when the list says it
    not by its length)."""
    if one is None:
        one = len(units) == 1
    if one:
        return encode(SPIKE, {"unit": units[0]})
    return encode(SPIKE, {"units": units})


if [(f.name, f.number, f.kind) for f in SPIKE.fields[:2]] != [
    (f.name, f.number, f.kind) for f in DECODE.fields[:2]
]:  # units_head reads both
    raise ImportError("SpikeBlock and DecodeBlock begin with different fields")


@cache
def descriptor(name: str) -> bytes:
    """The block type ``name``'s ``FileDescriptorSet`` (the schema data of its channel)."""
    from rgtbus.telemetry.codec import file_descriptor_set

    return file_descriptor_set(SCHEMAS[name])
