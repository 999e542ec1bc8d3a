"""A record as the log's JSON (the person-read tier: docs/format.md): compact, numpy values
as numbers and lists, a table shared by many records encoded once, NaN and infinity refused;
and a ``foxglove.Log`` line. The hot topics' blocks are ``blocks``; ``message_bytes`` picks."""

from __future__ import annotations

import math
import operator
import weakref
from collections.abc import Mapping
from typing import Any

import orjson

from rgtbus.errors import BadInput
from rgtbus.pairs import SharedTable
from rgtbus.telemetry.blocks import encode_record, schema_of
from rgtbus.timebase import NS_PER_SECOND

LOG_LEVELS = {"unknown": 0, "debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}
_U64_MAX = 2**64 - 1


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
        raise BadInput(f"t_ns must be an int of nanoseconds, got {t_ns!r}") from None
    if not 0 <= t <= _U64_MAX:
        raise BadInput(f"t_ns {t} out of range 0..2**64-1")
    return t


def level_number(level: str) -> int:
    """foxglove.Log level for a level name: debug 1, info 2, warning 3, error 4, fatal 5."""
    try:
        return LOG_LEVELS[level]
    except (KeyError, TypeError):
        names = ", ".join(k for k in LOG_LEVELS if k != "unknown")
        raise BadInput(f"unknown log level {level!r} (use {names})") from None


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
