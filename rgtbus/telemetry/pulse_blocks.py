"""A sender's pulses as ``/tx/pulse`` blocks (``rgtbus.PulseBlock``, ``blocks.PULSE``): the
batch of one block (``PulseBatch``), the rule that says when a block is whole
(``PulseBlocks``, the writer's and ``convert``'s), and a block read back one pulse at a time
(``pulse_rows``). docs/format.md says what a block holds."""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from rgtbus.errors import BadInput
from rgtbus.telemetry import records as r
from rgtbus.telemetry.untrusted import printable
from rgtbus.timebase import times_of

# -- a block of pulses, one pulse at a time (what a reader of single pulses wants) ---------------


def pulse_rows(block: Mapping[str, Any]) -> list[r.PulseRecord]:
    """The pulses of a ``/tx/pulse`` block as the records of one pulse each (``records.pulse``),
    in the block's order (by sample, then sender)."""
    tau = block["tau"]
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
                "unit": units[s],
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


class PulseBatch:
    """The pulses of one block, any number of senders', held until the block is over
    (``take``): a row a message (its samples and magnitudes, and what it is), no Python object
    a pulse; the block's columns and tables are made once, when it is taken."""

    __slots__ = ("rows", "tau")

    def __init__(self, tau: float) -> None:
        self.tau = tau
        # (samples, magnitudes, channel, omega, id, kind, code, sender, addressee, block)
        self.rows: list[tuple[Any, ...]] = []

    def add(self, pulse: Mapping[str, Any]) -> None:
        """One pulse (``records.pulse``'s record) into the batch: a pulse is its sender's (a
        record whose unit is not its message's sender: RgtbusError naming both)."""
        m = pulse["message"]
        if pulse["unit"] != m["sender"]:
            raise BadInput(
                f"a pulse of {printable(repr(pulse['unit']))} in a message sent by "
                f"{printable(repr(m['sender']))}"
            )
        # checked as it comes (a pulse read from an old log): a batch is made into columns
        # only once its block is over, far from the record that was wrong
        for key, value in (("sample", pulse["sample"]), ("message id", m["id"]),
                           ("block", m.get("block", 0))):  # fmt: skip
            if type(value) is not int or value < 0:
                raise ValueError(f"{key} {printable(repr(value))} is not a count")
        for key, value in (("magnitude", pulse["magnitude"]), ("omega", pulse["omega"])):
            if type(value) not in (int, float) or not math.isfinite(value):
                raise ValueError(f"{key} {printable(repr(value))} is not a finite number")
        for key in ("kind", "code", "sender", "addressee"):
            if type(m[key]) is not str:
                raise ValueError(f"{key} {printable(repr(m[key]))} is not a name")
        if type(pulse["channel"]) is not str:
            raise ValueError(f"channel {printable(repr(pulse['channel']))} is not a name")
        self.add_send(
            (pulse["sample"],), (pulse["magnitude"],), pulse["channel"], pulse["omega"], m
        )

    def add_send(
        self,
        samples: Sequence[int],
        magnitudes: Sequence[float],
        channel: str,
        omega: float,
        m: Mapping[str, Any],
    ) -> None:
        """Pulses of one message (``m``, ``records.message_ref``) on ``channel`` (its ω): at
        ``samples``, of ``magnitudes``."""
        self.rows.append(
            (samples, magnitudes, channel, omega, m["id"], m["kind"], m["code"], m["sender"],
             m["addressee"], m.get("block", 0))
        )  # fmt: skip

    def take(self) -> dict[str, Any]:
        """The batch as a ``/tx/pulse`` block record (at least one pulse); the batch is done
        with. Canonical: its tables sorted, its rows in order of sample (then sender, message,
        repair block, channel, kind, code, addressee, magnitude), whatever order the pulses
        came in."""
        rows, self.rows = self.rows, []
        by = list(zip(*rows, strict=True))
        counts = np.fromiter(map(len, by[0]), dtype=np.int64, count=len(rows))
        total = int(counts.sum())
        sample = np.fromiter(itertools.chain.from_iterable(by[0]), dtype=np.int64, count=total)
        magnitude = np.fromiter(
            itertools.chain.from_iterable(by[1]), dtype=np.float64, count=total
        )
        omega_of = dict(zip(by[2], by[3], strict=True))
        channels = sorted(omega_of)
        kinds, codes = sorted(set(by[5])), sorted(set(by[6]))
        names = sorted(set(by[7]) | set(by[8]))

        def column(values: Sequence[Any], dtype: Any = np.uint32) -> np.ndarray:
            return np.repeat(np.fromiter(values, dtype=dtype, count=len(rows)), counts)

        def indexes(values: Sequence[str], table: list[str]) -> np.ndarray:
            at = {name: i for i, name in enumerate(table)}
            return column([at[v] for v in values])

        cols = [
            sample,
            indexes(by[2], channels),
            magnitude,
            column(by[4], np.int64),
            indexes(by[5], kinds),
            indexes(by[6], codes),
            indexes(by[7], names),
            indexes(by[8], names),
            column(by[9]),
        ]
        _, channel, _, message, kind, code, sender, addressee, block = cols
        # the last key first: np.lexsort sorts by its last key
        order = np.lexsort(
            (magnitude, addressee, code, kind, channel, block, message, sender, sample)
        )
        if not (order[1:] > order[:-1]).all():
            cols = [c[order] for c in cols]
        return {
            "t": float(int(sample.max()) * self.tau),
            "tau": self.tau,
            "channels": channels,
            "omegas": [float(omega_of[c]) for c in channels],
            "names": names,
            "kinds": kinds,
            "codes": codes,
            **dict(zip(_COLUMNS, cols, strict=True)),
        }


_COLUMNS = ("sample", "channel", "magnitude", "message", "kind", "code", "sender", "addressee",
            "block")  # fmt: skip


class PulseBlocks:
    """Pulses held in the batches of their blocks (``block`` samples each, on the senders'
    clock), any number of senders': a block let go (``before``) once every sender's clock is
    past its end, and the rest at the end. Which pulses a ``/tx/pulse`` record holds depends
    on the pulses alone, never on the order they were logged in (a sender plans a late choice
    before sends it planned earlier), and when it is written on how far its senders have
    come. The one rule for the writer (``GroupLog``), ``convert`` and ``merge``."""

    def __init__(self, tau: float, block: int) -> None:
        self.tau, self.block = tau, block
        self._held: dict[int, PulseBatch] = {}
        self._order: list[int] = []  # the blocks held, a heap

    def batch(self, sample: int) -> PulseBatch:
        """The batch of the block of ``sample``."""
        b = sample // self.block
        batch = self._held.get(b)
        if batch is None:
            batch = self._held[b] = PulseBatch(self.tau)
            heapq.heappush(self._order, b)
        return batch

    def add(self, pulse: Mapping[str, Any]) -> None:
        """Hold ``pulse`` in its block's batch."""
        self.batch(int(pulse["sample"])).add(pulse)

    def add_send(
        self,
        samples: Sequence[int],
        magnitudes: Sequence[float],
        channel: str,
        omega: float,
        m: Mapping[str, Any],
    ) -> None:
        """Hold a message's pulses (``PulseBatch.add_send``) in their blocks' batches."""
        block = self.block
        if samples[0] // block == samples[-1] // block:
            self.batch(samples[0]).add_send(samples, magnitudes, channel, omega, m)
            return
        # a long message (a slow channel's pulses are seconds apart): its pulses of each block
        parts: dict[int, tuple[list[int], list[float]]] = {}
        for k, v in zip(samples, magnitudes, strict=True):
            ks, vs = parts.setdefault(k // block, ([], []))
            ks.append(k)
            vs.append(v)
        for ks, vs in parts.values():
            self.batch(ks[0]).add_send(ks, vs, channel, omega, m)

    def before(self, sample: int) -> list[dict[str, Any]]:
        """The blocks held that end at or before ``sample``, in order: every sender's clock has
        passed them (their other records say so), no pulse of theirs is still to come."""
        order, out = self._order, []
        while order and (order[0] + 1) * self.block <= sample:
            out.append(self._held.pop(heapq.heappop(order)).take())
        return out

    def end(self) -> list[dict[str, Any]]:
        """Every block still held, in order (the senders are done)."""
        out = [self._held[k].take() for k in sorted(self._held)]
        self._held.clear()
        self._order.clear()
        return out


def join_pulse_blocks(blocks: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Blocks of one block of time from several writers (processes), as the one block a
    single writer of all their senders writes (``merge``)."""
    batch = PulseBatch(float(blocks[0]["tau"]))
    for block in blocks:
        for p in pulse_rows(block):
            batch.add(p)
    return batch.take()


def pulse_block_of(pulses: Sequence[Mapping[str, Any]], tau: float) -> dict[str, Any]:
    """Single pulses (records of ``records.pulse``) as one block record: what a live view is
    offered, a pulse at a time."""
    batch = PulseBatch(tau)
    for p in pulses:
        batch.add(p)
    return batch.take()
