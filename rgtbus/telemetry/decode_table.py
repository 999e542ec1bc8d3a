"""Every decode of a log as columns: arrays of numbers and indexes into small tables of names,
built a ``/rx/decodes`` record at a time, with no Python object per decode.

A 50-unit run decodes 490,000 times; as row objects (``Replay.decodes``) that was 890 MB of
Python for a 3 MB log. Here a record's columns go straight into arrays: its names are indexes
into its own tables (``names``, ``kinds``, ``codes``), mapped onto the log's tables once a
record (a table holds a few dozen names), each index checked to lie in its table first.

``match_sent`` then finds, for each decode, the transmission it read (the one of its sender,
class and turn: a later one of the same turn wins, as ``Replay._decodes`` says) with arrays:
a transmission's key is one integer, looked up with ``searchsorted``.
"""

from __future__ import annotations

import contextlib
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeGuard

import numpy as np

from rgtbus.errors import BadLog
from rgtbus.misreads import HeldDecodes
from rgtbus.telemetry.record_rows import decode_units
from rgtbus.telemetry.records import DECODE_TABLES, NAMED_COLUMNS, RX_DECODES


class _Names:
    """A table of names, grown as records name more, and each name's index."""

    def __init__(self) -> None:
        self.names: list[str] = []
        self.index: dict[str, int] = {}
        self._maps: dict[tuple[str, ...], np.ndarray] = {}

    def of(self, name: str) -> int:
        i = self.index.get(name)
        if i is None:
            i = self.index[name] = len(self.names)
            self.names.append(name)
        return i

    def indexes(self, names: Sequence[str]) -> np.ndarray:
        return np.fromiter((self.of(n) for n in names), dtype=np.int32, count=len(names))

    def known(self, own: Any) -> np.ndarray | None:
        """``mapped(own)`` where ``own`` is a table seen before (so checked), else None."""
        if type(own) is not list:
            return None
        try:
            return self._maps.get(tuple(own))
        except TypeError:  # a list of lists (a log written by hand): checked by the caller
            return None

    def mapped(self, own: list[str]) -> np.ndarray:
        """A record's own table as indexes into this one (each table once: the records of a
        run hold the same few tables again and again)."""
        key = tuple(own)
        got = self._maps.get(key)
        if got is None:
            got = self._maps[key] = self.indexes(own)
        return got


@dataclass
class DecodeTable:
    """Every decode of a log, in log-time order (a record's own order kept among decodes of
    one time, records in file order): ``unit``, ``sender``, ``addressee`` and ``channel``
    index ``names``, ``kind`` indexes ``kinds`` and ``code`` ``codes``; ``t`` seconds,
    ``turn`` the turn the decoder read it in."""

    unit: np.ndarray
    t: np.ndarray
    turn: np.ndarray
    sender: np.ndarray
    addressee: np.ndarray
    channel: np.ndarray
    kind: np.ndarray
    code: np.ndarray
    margin: np.ndarray
    accepted: np.ndarray
    names: list[str] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)
    codes: list[str] = field(default_factory=list)
    # a table of each record's rows once (``decode_table(..., once=True)``): each row's
    # record, and each record's units (indexes into ``names``); ``unit`` is then its first
    record: np.ndarray | None = None
    holders: list[list[int]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.t)


_NUMBER_COLUMNS = {"turn": np.int64, "margin": np.float64, "times": np.float64}


def decode_table(
    records: Iterable[tuple[int, Mapping[str, Any]]], units: Sequence[str] = (), once: bool = False
) -> DecodeTable:
    """The decodes of ``records`` (``/rx/decodes`` messages as read: ``(log_time, record)``,
    each checked against its schema) as one ``DecodeTable``, each unit's of a record of
    several units' (``units``) rows of its own; in order of time, then unit (as ``units``
    orders them; others by name), then as logged. ``once``: a record's rows once, whatever
    units it names (``DecodeTable.record``, ``holders``), in order of time, then as logged:
    a 100-unit run's 39,600 distinct decodes rather than 3.96 M. A record whose columns
    differ in length or whose index lies outside its table: RgtbusError naming the unit,
    the record's time and the column."""
    tables = {"names": _Names(), "kinds": _Names(), "codes": _Names()}
    parts: dict[str, list[np.ndarray]] = {c: [] for c in (*_COLUMNS, "unit", "record")}
    holders: list[list[int]] = []
    for t_ns, record in records:
        if not isinstance(record, Mapping):
            raise BadLog(f"{RX_DECODES} at log time {t_ns} ns: not an object")
        whose = decode_units(record)
        unit = whose[0] if len(whose) == 1 else whose
        where = f"{RX_DECODES} of {unit!r} at t = {record.get('t')}"
        # a record as its writer built it (a re-run's: arrays, tuples of names) reads alike
        record = {k: list(v) if type(v) is tuple else v for k, v in record.items()}
        n = _length(record, where)
        if not n:
            continue
        for column, dtype in _NUMBER_COLUMNS.items():
            parts[column].append(_numbers(record[column], dtype, column, where))
        accepted = record["accepted"]
        if isinstance(accepted, np.ndarray) and accepted.dtype == np.bool_:
            parts["accepted"].append(accepted)
        elif all(type(a) is bool for a in accepted):
            parts["accepted"].append(np.asarray(accepted, dtype=np.bool_))
        else:
            raise BadLog(f"{where}: column 'accepted' holds other than true and false")
        for column, table_name in NAMED_COLUMNS.items():
            parts[column].append(_named(record, column, table_name, tables[table_name], where))
        of = [tables["names"].of(u) for u in whose]
        if once:
            parts["unit"].append(np.full(n, of[0], dtype=np.int32))
            parts["record"].append(np.full(n, len(holders), dtype=np.int32))
            holders.append(of)
            continue
        if len(whose) > 1:  # the same rows, once a unit
            for column in _COLUMNS:
                parts[column][-1] = np.tile(parts[column][-1], len(whose))
        parts["unit"].append(np.repeat(np.asarray(of, dtype=np.int32), n))
    cols = {c: np.concatenate(p) if p else np.empty(0, _dtype(c)) for c, p in parts.items()}
    # in log-time order, as Replay.decode_records sorts the rows: by integer ns, then unit,
    # stable (np.lexsort is: a unit's decodes of one time keep the order logged)
    names = tables["names"].names
    first = {u: i for i, u in enumerate(units)}
    by_name = {u: len(first) + i for i, u in enumerate(sorted(set(names) - set(first)))}
    rank = np.asarray([first.get(u, by_name.get(u, 0)) for u in names] or [0], dtype=np.int64)
    at_ns = np.rint(cols["times"] * 1e9).astype(np.int64)
    order = np.argsort(at_ns, kind="stable") if once else np.lexsort((rank[cols["unit"]], at_ns))
    return DecodeTable(
        unit=cols["unit"][order],
        t=cols["times"][order],
        turn=cols["turn"][order],
        sender=cols["sender"][order],
        addressee=cols["addressee"][order],
        channel=cols["channel"][order],
        kind=cols["kind"][order],
        code=cols["code"][order],
        margin=cols["margin"][order],
        accepted=cols["accepted"][order],
        names=tables["names"].names,
        kinds=tables["kinds"].names,
        codes=tables["codes"].names,
        record=cols["record"][order] if once else None,
        holders=holders,
    )


_COLUMNS = ("turn", "sender", "addressee", "channel", "kind", "code", "margin", "times", "accepted")


def _dtype(column: str) -> type:
    if column in _NUMBER_COLUMNS:
        return _NUMBER_COLUMNS[column]
    return np.bool_ if column == "accepted" else np.int32


def _numbers(values: Any, dtype: type, column: str, where: str) -> np.ndarray:
    if isinstance(values, np.ndarray):  # a writer's own: its dtype says what it holds
        if values.dtype.kind not in ("iu" if dtype is np.int64 else "iuf"):
            raise BadLog(f"{where}: column {column!r} holds other than numbers")
        return values.astype(dtype, copy=False)
    if not all(type(v) in (int, float) for v in values) or (
        dtype is np.int64 and not all(type(v) is int for v in values)
    ):
        raise BadLog(f"{where}: column {column!r} holds other than numbers")
    try:
        return np.asarray(values, dtype=dtype)
    except OverflowError:
        raise BadLog(f"{where}: column {column!r} holds a number out of range") from None


def _is_column(values: Any) -> TypeGuard[list[Any] | np.ndarray]:
    """A list as read, or a writer's one-dimensional array."""
    return isinstance(values, list) or (isinstance(values, np.ndarray) and values.ndim == 1)


def _length(record: Mapping[str, Any], where: str) -> int:
    """The number of decodes in ``record``: the length of its ``times``, which every column
    must share (the words of ``decode_rows``)."""
    times = record.get("times")
    n = len(times) if _is_column(times) else -1
    for column in ("times", *_COLUMNS):
        col = record.get(column)
        if _is_column(col) and len(col) == n:
            continue
        got = (
            "missing"
            if col is None
            else f"{len(col)} entries"
            if _is_column(col)
            else type(col).__name__
        )
        want = "a list" if n < 0 else f"{n} entries like times"
        raise BadLog(f"{where}: column {column!r} is {got}, not {want}")
    return n


def _named(
    record: Mapping[str, Any], column: str, table_name: str, table: _Names, where: str
) -> np.ndarray:
    """A column of names as indexes into the log's ``table``: the record's indexes into its
    own table (each checked to lie in it), or its names (logs before the tables)."""
    col = record[column]
    if not any(t in record for t in DECODE_TABLES):
        names = col.tolist() if isinstance(col, np.ndarray) else col
        if not all(isinstance(x, str) for x in names):
            raise BadLog(f"{where}: {column} holds other than names")
        return table.indexes(names)
    own: Any = record.get(table_name)
    mapped = table.known(own)
    if mapped is None:
        if not (isinstance(own, list) and all(isinstance(x, str) for x in own)):
            raise BadLog(f"{where}: {table_name!r} is not a list of names")
        mapped = table.mapped(own)
    idx = None
    if isinstance(col, np.ndarray):  # a writer's own record, or one read as arrays
        if col.dtype.kind in "iu":
            idx = col.astype(np.int64, copy=False)
        col = col.tolist()
    elif all(type(i) is int for i in col):
        with contextlib.suppress(OverflowError):  # an index beyond 64 bits: named below
            idx = np.asarray(col, dtype=np.int64)
    if idx is None or (idx.size and (idx.min() < 0 or idx.max() >= len(own))):
        bad = next(i for i in col if not (type(i) is int and 0 <= i < len(own)))
        raise BadLog(f"{where}: {column} {bad!r} is no index into its {len(own)} {table_name}")
    return mapped[idx] if own else np.empty(0, np.int32)


@dataclass
class Sent:
    """What each decode of a ``DecodeTable`` read: ``tx`` the index of the transmission (-1:
    none logged), and whether it decoded what was sent (``matches``; meaningless where
    ``tx`` is -1)."""

    tx: np.ndarray
    matches: np.ndarray


def match_sent(table: DecodeTable, transmissions: Sequence[tuple[str, str, int, str, str]]) -> Sent:
    """Each decode's transmission: the one of its sender, class (an ID code, or any other:
    a payload) and turn, the latest of them in ``transmissions`` (``(sender, kind, turn,
    code, addressee)`` in start order, ``kind`` "id" or "payload"); it matches where an ID
    decoded as ``id``, or a payload as the code sent to the addressee sent to."""
    names = {n: i for i, n in enumerate(table.names)}
    codes = {c: i for i, c in enumerate(table.codes)}
    width = int(max([table.turn.max(initial=0), *(t[2] for t in transmissions)], default=0)) + 1
    keys: dict[int, int] = {}
    for i, (sender, kind, turn, _, _) in enumerate(transmissions):
        s = names.get(sender)
        if s is not None and turn >= 0 and kind in ("id", "payload"):  # a repair's: none
            keys[(s * 2 + (kind != "id")) * width + turn] = i  # the latest of a turn wins
    tx_keys = np.fromiter(keys, dtype=np.int64, count=len(keys))
    tx_index = np.fromiter(keys.values(), dtype=np.int64, count=len(keys))
    by_key = np.argsort(tx_keys)
    tx_keys, tx_index = tx_keys[by_key], tx_index[by_key]
    is_id = (
        table.kind == table.kinds.index("id") if "id" in table.kinds else np.zeros(len(table), bool)
    )
    row_keys = (table.sender.astype(np.int64) * 2 + (~is_id).astype(np.int64)) * width + table.turn
    at = np.searchsorted(tx_keys, row_keys)
    at[at == len(tx_keys)] = 0
    found = (len(tx_keys) > 0) & (table.turn >= 0)
    found &= tx_keys[at] == row_keys if len(tx_keys) else False
    tx = np.where(found, tx_index[at] if len(tx_keys) else -1, -1)
    sent_code = np.array([codes.get(t[3], -1) for t in transmissions] + [-2], dtype=np.int64)
    sent_to = np.array([names.get(t[4], -1) for t in transmissions] + [-2], dtype=np.int64)
    id_code = codes.get("id", -3)
    matches = np.where(
        is_id,
        table.code == id_code,
        (table.code == sent_code[tx]) & (table.addressee == sent_to[tx]),
    )
    return Sent(tx=tx, matches=matches & (tx >= 0))


def held_decodes(
    records: Iterable[tuple[int, Mapping[str, Any]]], units: Sequence[str] = ()
) -> dict[str, HeldDecodes]:
    """Each unit's decodes of ``records`` (``/rx/decodes`` messages as read), in log-time
    order (stable: as logged within one time), as the summary judges them: each decode's turn
    and the index of its (kind, addressee, code) among the distinct ones, read from the
    records' columns with a record's rows once, whatever units it names (``once``), and no
    Python object per decode."""
    table = decode_table(records, units, once=True)
    names, kinds, codes = table.names, table.kinds, table.codes
    # each distinct (kind, addressee, code) once: a decode's is an index into them
    span = max(1, len(codes))
    key = (table.kind.astype(np.int64) * len(names) + table.addressee) * span + table.code
    distinct, what = np.unique(key, return_inverse=True)
    k, rest = np.divmod(distinct, len(names) * span)
    a, c = np.divmod(rest, span)
    rows = [(kinds[i], names[j], codes[m]) for i, j, m in zip(
        k.tolist(), a.tolist(), c.tolist(), strict=True)]  # fmt: skip
    held: dict[int, list[int]] = defaultdict(list)  # a unit's records
    for r, holders in enumerate(table.holders):
        for u in holders:
            held[u].append(r)
    assert table.record is not None
    out: dict[str, HeldDecodes] = {}
    for u, name in enumerate(names):
        if held.get(u):
            mine = np.flatnonzero(np.isin(table.record, held[u]))  # in the table's order
            out[name] = HeldDecodes(table.turn[mine], what[mine], rows)
    return out
