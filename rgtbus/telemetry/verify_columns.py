"""Verifying the hot topics as columns: a log's decodes and spikes against a re-run's, compared as
arrays, with no Python object per decode or per spike (``verify.diff_messages`` asks here
first).

Both sides are read into columns (``decode_table``; spikes expanded to one row per unit and
spike with ``np.repeat``), names mapped onto one table, rows put in the order the row-by-row
comparison pairs them (its key, then the order logged), and compared column by column, floats
bit for bit. Equal: how many records the row-by-row comparison would have compared, and no
row is ever built. Not equal (or a form of logs before the columns): None, and the caller
compares row by row, which explains each difference. So a verified log costs arrays, and
only a log that disagrees costs rows.
"""

from __future__ import annotations

import contextlib
import hashlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from rgtbus.telemetry.decode_table import DecodeTable, decode_table
from rgtbus.telemetry.record_rows import spike_units

Message = tuple[int, Any]  # (log time, message) of one topic


def same_decodes(
    logged: Sequence[Message], recomputed: Sequence[Message], until_ns: int | None
) -> int | None:
    """How many decodes were compared, when the ``/rx/decodes`` records of both sides hold the
    same decodes (before ``until_ns``), each paired as ``verify`` pairs them (unit, kind,
    sender, time; then in the order logged) and equal in every field; else None."""
    a, b = decode_table(logged), decode_table(recomputed)
    names = _union(a.names, b.names)
    kinds = _union(a.kinds, b.kinds)
    codes = _union(a.codes, b.codes)
    cols_a, cols_b = (
        _decode_columns(a, names, kinds, codes),
        _decode_columns(b, names, kinds, codes),
    )
    if until_ns is not None:
        cols_a = _before(cols_a, until_ns)
        cols_b = _before(cols_b, until_ns)
    if len(cols_a["t_ns"]) != len(cols_b["t_ns"]):
        return None
    order_a = np.lexsort([cols_a[k] for k in ("position", "t_ns", "sender", "kind", "unit")])
    order_b = np.lexsort([cols_b[k] for k in ("position", "t_ns", "sender", "kind", "unit")])
    for column in cols_a:
        if column == "position":
            continue
        if not np.array_equal(cols_a[column][order_a], cols_b[column][order_b]):
            return None
    return len(order_a)


def _union(first: list[str], second: list[str]) -> dict[str, int]:
    out = {n: i for i, n in enumerate(first)}
    for n in second:
        out.setdefault(n, len(out))
    return out


def _remap(own: list[str], table: dict[str, int]) -> np.ndarray:
    return np.array([table[n] for n in own] or [0], dtype=np.int64)


def _decode_columns(
    t: DecodeTable, names: dict[str, int], kinds: dict[str, int], codes: dict[str, int]
) -> dict[str, np.ndarray]:
    """A table's columns in the shared index space; floats as their bits (a log's JSON tells
    -0.0 from 0.0); ``position`` the order logged (the table keeps it among equal times)."""
    to_name, to_kind, to_code = (
        _remap(t.names, names),
        _remap(t.kinds, kinds),
        _remap(t.codes, codes),
    )
    return {
        "unit": to_name[t.unit],
        "t_ns": np.rint(t.t * 1e9).astype(np.int64),
        "t": t.t.view(np.int64),
        "turn": t.turn,
        "sender": to_name[t.sender],
        "addressee": to_name[t.addressee],
        "channel": to_name[t.channel],
        "kind": to_kind[t.kind],
        "code": to_code[t.code],
        "margin": t.margin.view(np.int64),
        "accepted": t.accepted,
        "position": np.arange(len(t), dtype=np.int64),
    }


def _before(cols: dict[str, np.ndarray], until_ns: int) -> dict[str, np.ndarray]:
    keep = cols["t_ns"] < until_ns
    return {k: v[keep] for k, v in cols.items()}


def compact(message: Any) -> Any:
    """A hot record with its columns (lists of numbers, or of booleans, all of one type) as
    NumPy arrays: what the records of a large run hold as Python lists costs gigabytes, as
    arrays megabytes; and a writer's own record holds arrays already. A list of mixed types
    (a log written by hand) stays as it is, for the rows to name."""
    if not isinstance(message, dict):
        return message
    out = dict(message)
    for key, value in message.items():
        if type(value) is list and value and len(kinds := set(map(type, value))) == 1:
            kind = kinds.pop()
            if kind is int or kind is float or kind is bool:
                with contextlib.suppress(OverflowError):
                    out[key] = np.asarray(value, dtype=_ARRAY_OF[kind])
    return out


_ARRAY_OF = {int: np.int64, float: np.float64, bool: np.bool_}


def same_spikes(
    logged: Sequence[Message],
    recomputed: Sequence[Message],
    tau: float,
    until_ns: int | None,
) -> int | None:
    """How many records of one unit's spikes at one sample were compared, when the
    ``/rx/spike`` records of both sides hold, for every unit, the same spikes (before
    ``until_ns``): the same channels at the same samples in the same order, however the
    records group units and blocks; else None (or a record of a form before the columns).

    Each unit's spikes, (sample, channel) pairs, are digested in the order of its records'
    first samples (a unit's records are blocks: they never overlap), a record shared by many
    units once a unit: no array a unit is built."""
    names: dict[str, int] = {}
    for whole in (False, True):  # by records' digests first: the same blocks, as a rule
        a = _spike_digests(logged, names, tau, until_ns, whole)
        b = _spike_digests(recomputed, names, tau, until_ns, whole)
        if a is None or b is None:
            return None
        if a[0] == b[0]:
            return a[1]
    return None


def _spike_digests(
    records: Sequence[Message],
    names: dict[str, int],
    tau: float,
    until_ns: int | None,
    whole: bool,
) -> tuple[dict[str, tuple[int, bytes]], int] | None:
    """Each unit's spikes as (how many, their digest), and how many (record, unit, sample)
    messages the row-by-row comparison counts; None for a record of an older form. The
    digest of a unit's spikes themselves (``whole``: whatever blocks hold them), or of the
    digests of its records' spikes (each record's hashed once, however many units share it:
    equal where both sides cut the same blocks)."""
    blocks: list[tuple[int, int, list[str], bytes, int, int]] = []  # first sample, order, ...
    for order, (_, m) in enumerate(records):
        if not isinstance(m, Mapping) or "samples" not in m or "channel" not in m:
            return None
        try:
            units = spike_units(m)
            samples, channel = np.asarray(m["samples"]), np.asarray(m["channel"])
            own = np.asarray([names.setdefault(str(n), len(names)) for n in m["names"]] or [0])
        except (TypeError, ValueError, OverflowError, KeyError):
            return None
        if not samples.size and not channel.size:
            continue  # a record of no spike
        if samples.dtype.kind not in "iu" or channel.dtype.kind not in "iu":
            return None
        samples, channel = samples.astype(np.int64), channel.astype(np.int64)
        if samples.shape != channel.shape or samples.ndim != 1 or not samples.size:
            if samples.size:
                return None
            continue
        if channel.min() < 0 or channel.max() >= len(m["names"]):
            return None
        if until_ns is not None:
            keep = int(np.searchsorted(np.rint(samples * tau * 1e9), until_ns, side="left"))
            samples, channel = samples[:keep], channel[:keep]
            if not samples.size:
                continue
        # (sample, channel) pairs: a unit's spikes digest alike however records cut them
        data = np.column_stack((samples, own[channel])).astype(np.int64).tobytes()
        per_sample = 1 + int(np.count_nonzero(samples[1:] != samples[:-1]))
        spikes = len(data) // 16
        if not whole:
            data = hashlib.blake2b(data, digest_size=32).digest()
        blocks.append((int(samples[0]), order, units, data, per_sample, spikes))
    digests: dict[str, Any] = {}
    counts: dict[str, int] = {}
    messages = 0
    for _, _, units, data, per_sample, spikes in sorted(blocks, key=lambda b: (b[0], b[1])):
        for unit in units:
            h = digests.get(unit)
            if h is None:
                h = digests[unit] = hashlib.blake2b(digest_size=32)
            h.update(data)
            counts[unit] = counts.get(unit, 0) + spikes
            messages += per_sample
    return {u: (counts[u], h.digest()) for u, h in digests.items()}, messages
