"""A sender's pulses as ``/tx/pulse`` blocks (``rgtbus.PulseBlock``, ``blocks.PULSE``): the
batch of one block (``PulseBatch``), the rule that says when a block is whole
(``PulseBlocks``, the writer's and ``convert``'s), and a block read back one pulse at a time
(``pulse_rows``). docs/format.md says what a block holds."""

from __future__ import annotations

import array
import heapq
import itertools
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from rgtbus.telemetry import records as r
from rgtbus.timebase import times_of

# -- a block of pulses, one pulse at a time (what a reader of single pulses wants) ---------------


def pulse_rows(block: Mapping[str, Any]) -> list[r.PulseRecord]:
    """The pulses of a ``/tx/pulse`` block as the records of one pulse each (``records.pulse``),
    in the order sent."""
    unit, tau = block["unit"], block["tau"]
    channels, omegas = block["channels"], np.asarray(block["omegas"]).tolist()
    units, kinds, codes = block["names"], block["kinds"], block["codes"]
    samples = np.asarray(block["sample"])
    t = times_of(samples, tau).tolist()
    out: list[r.PulseRecord] = []
    for k, tk, c, m, mid, kd, cd, s, a, b in zip(
        samples.tolist(), t, *(np.asarray(block[c]).tolist() for c in _PULSE_ROW), strict=True
    ):
        ref = r.message_ref(0, kinds[kd], codes[cd], units[s], units[a], b)
        ref["id"] = mid
        out.append(
            {
                "unit": unit,
                "channel": channels[c],
                "omega": omegas[c],
                "magnitude": m,
                "t": tk,
                "sample": k,
                "message": ref,
            }
        )
    return out


_PULSE_ROW = ("channel", "magnitude", "message", "kind", "code", "sender", "addressee", "block")


_PULSE_TYPES = "qIdqIIIII"  # the typecodes of PulseBatch's columns


def _pulse_columns() -> tuple[array.array[Any], ...]:
    return tuple(array.array(code) for code in _PULSE_TYPES)


class PulseBatch:
    """A sender's pulses of one block, held until the block is over (``take``): the columns of
    a ``/tx/pulse`` block, with its tables built as pulses come."""

    __slots__ = ("channels", "codes", "cols", "kinds", "names", "omegas", "tau", "unit")

    def __init__(self, unit: str, tau: float) -> None:
        self.unit, self.tau = unit, tau
        # sample, channel, magnitude, message, kind, code, sender, addressee, block: typed
        # arrays, no Python object a pulse (a sender plans a run's sends ahead: its pulses
        # wait here until its clock passes their block)
        self.cols: tuple[array.array[Any], ...] = _pulse_columns()
        self.channels: dict[str, int] = {}
        self.omegas: list[float] = []
        self.names: dict[str, int] = {}
        self.kinds: dict[str, int] = {}
        self.codes: dict[str, int] = {}

    @classmethod
    def of(cls, unit: str, tau: float) -> PulseBatch:
        return cls(unit, tau)

    def add(self, pulse: Mapping[str, Any]) -> None:
        """One pulse (``records.pulse``'s record) into the batch."""
        m = pulse["message"]
        c = self.channels.get(pulse["channel"])
        if c is None:
            c = self.channels[pulse["channel"]] = len(self.omegas)
            self.omegas.append(float(pulse["omega"]))
        names, kinds, codes = self.names, self.kinds, self.codes
        sample, channel, magnitude, message, kind, code, sender, addressee, block = self.cols
        sample.append(pulse["sample"])
        channel.append(c)
        magnitude.append(pulse["magnitude"])
        message.append(m["id"])
        kind.append(kinds.setdefault(m["kind"], len(kinds)))
        code.append(codes.setdefault(m["code"], len(codes)))
        sender.append(names.setdefault(m["sender"], len(names)))
        addressee.append(names.setdefault(m["addressee"], len(names)))
        block.append(m.get("block", 0))

    def take(self) -> dict[str, Any]:
        """The batch as a ``/tx/pulse`` block record (at least one pulse); the batch is done
        with. Canonical: its tables sorted, its rows in order of sample (then message, repair
        block, channel, kind, code, sender, addressee, magnitude), whatever order the pulses
        came in. Pulses logged in time order into tables first seen in sorted order (the
        usual case) are that already: its columns are then its arrays as they are."""
        tables = (self.channels, self.kinds, self.codes, self.names)
        sample = self.cols[0]
        if all(list(t) == sorted(t) for t in tables) and all(
            a < b for a, b in itertools.pairwise(sample)
        ):
            cols = [np.frombuffer(c, dtype=c.typecode) for c in self.cols]
            channels, kinds, codes, names = (list(t) for t in tables)
            return self._record(channels, kinds, codes, names, cols)
        return self._sorted()

    def _sorted(self) -> dict[str, Any]:
        channels, c_at = _sorted_table(self.channels)
        kinds, k_at = _sorted_table(self.kinds)
        codes, d_at = _sorted_table(self.codes)
        names, n_at = _sorted_table(self.names)
        sample, channel, magnitude, message, kind, code, sender, addressee, block = self.cols
        rows = sorted(
            zip(
                sample,
                message,
                block,
                [c_at[c] for c in channel],
                [k_at[k] for k in kind],
                [d_at[d] for d in code],
                [n_at[u] for u in sender],
                [n_at[u] for u in addressee],
                magnitude,
                strict=True,
            )
        )
        by = list(zip(*rows, strict=True))
        cols = [by[0], by[3], by[8], by[1], by[4], by[5], by[6], by[7], by[2]]
        typed = [np.array(c, dtype=code) for c, code in zip(cols, _PULSE_TYPES, strict=True)]
        return self._record(channels, kinds, codes, names, typed)

    def _record(
        self,
        channels: list[str],
        kinds: list[str],
        codes: list[str],
        names: list[str],
        cols: Sequence[np.ndarray],
    ) -> dict[str, Any]:
        sample, channel, magnitude, message, kind, code, sender, addressee, block = cols
        return {
            "unit": self.unit,
            "tau": self.tau,
            "t": float(int(sample[-1]) * self.tau),
            "channels": channels,
            "omegas": [self.omegas[self.channels[c]] for c in channels],
            "names": names,
            "kinds": kinds,
            "codes": codes,
            "sample": sample,
            "channel": channel,
            "magnitude": magnitude,
            "message": message,
            "kind": kind,
            "code": code,
            "sender": sender,
            "addressee": addressee,
            "block": block,
        }

    def __len__(self) -> int:
        return len(self.cols[0])


class PulseBlocks:
    """A sender's pulses held in the batches of their blocks (``block`` samples each), a block
    let go once the sender's own clock is past its end (``before``: its other records say how
    far it has come, and no pulse is ever planned in its past), and the rest at the end: which
    pulses a ``/tx/pulse`` record holds depends on the pulses alone, never on the order they
    were logged in (a sender plans a late choice before sends it planned earlier), and when it
    is written on how far the sender has come. The one rule for the writer
    (``UnitLog.pulse``) and ``convert``."""

    def __init__(self, unit: str, tau: float, block: int) -> None:
        self.unit, self.tau, self.block = unit, tau, block
        self._held: dict[int, PulseBatch] = {}
        self._order: list[int] = []  # the blocks held, a heap

    def add(self, pulse: Mapping[str, Any]) -> None:
        """Hold ``pulse`` in its block's batch."""
        b = int(pulse["sample"]) // self.block
        batch = self._held.get(b)
        if batch is None:
            batch = self._held[b] = PulseBatch(self.unit, self.tau)
            heapq.heappush(self._order, b)
        batch.add(pulse)

    def before(self, sample: int) -> list[dict[str, Any]]:
        """The blocks held that end at or before ``sample``, in order: the sender's clock has
        passed them (its other records say so), no pulse of theirs is still to come."""
        order, out = self._order, []
        while order and (order[0] + 1) * self.block <= sample:
            out.append(self._held.pop(heapq.heappop(order)).take())
        return out

    def end(self) -> list[dict[str, Any]]:
        """Every block still held, in order (the sender is done)."""
        out = [self._held[k].take() for k in sorted(self._held)]
        self._held.clear()
        self._order.clear()
        return out


def _sorted_table(table: dict[str, int]) -> tuple[list[str], list[int]]:
    """A table of names (name -> index as first seen) sorted: (its names, each old index's
    new one)."""
    names = sorted(table)
    at = [0] * len(table)
    for i, name in enumerate(names):
        at[table[name]] = i
    return names, at


def pulse_block_of(pulses: Sequence[Mapping[str, Any]], unit: str, tau: float) -> dict[str, Any]:
    """Single pulses of one sender (records of ``records.pulse``, in order) as one block record:
    how ``convert`` writes a format-1 log's pulses."""
    batch = PulseBatch.of(unit, tau)
    for p in pulses:
        batch.add(p)
    return batch.take()
