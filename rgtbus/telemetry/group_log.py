"""The log of the units one process runs, where their records are one (``GroupLog``).

* **Pulses.** Every local sender's pulses of one block of ``BLOCK_SECONDS`` are one
  ``/tx/pulse`` record (``PulseBlocks``), let go once every sender's own records are past the
  block (no sender plans a pulse in its past) or the sender is done.
* **Decodes.** Each unit hands its decodes a piece at a time: the decodes of one block of
  ``BLOCK_SECONDS`` up to where its own records cut it (``UnitLog.flush_decodes``, in the
  block's canonical form). Once every local unit is past the block, the pieces that hold the
  same decodes are one ``/rx/decodes`` record naming their units (two or more: ``units``, in
  sorted order; one: ``unit``): on a clean medium the units of a group decode each code alike,
  and a 100-unit run writes its 3.96 M decodes as 39,600 rows, not once per receiver. A
  unit's deviations (another margin, a misread, a miss, a block cut elsewhere by its own
  records) make its piece a record of its own.

What a record holds is a function of the blocks' contents alone: ``merge`` joins the records of
several processes by the same rules (blocks of pulses of one block of time become one; records
of decodes that hold the same bytes after their units become one), so a run's merged log is the
same whatever the split of its units into processes (docs/format.md, "Canonical").

* **Time order.** Each unit says how far it has come (``clock``: it writes no record before
  that sample, save what its group holds here); the least of them is how far the process
  has come, and the recorder writes the records held before it in log-time order
  (``Recorder.advance``; ``ordered``). A unit that is done is past everything.

A log cut short is whole before the start of the block of the earliest of its units' last
records (``Replay.units_until_ns``): a block goes out once every unit has moved past it, and a
unit's records go out after it has.
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from rgtbus.telemetry import records
from rgtbus.telemetry.blocks import block_samples
from rgtbus.telemetry.pulse_blocks import PulseBlocks
from rgtbus.timebase import ns


class RecordSink(Protocol):
    """Where a group's records go: a ``Recorder`` (or ``convert``'s writer)."""

    def write(self, topic: str, message: Any, t_ns: int) -> None: ...


class OrderedSink(RecordSink, Protocol):
    """A sink that holds records until the run has passed them (``Recorder.advance``)."""

    def advance(self, t_ns: int) -> None: ...


_DONE = 2**62  # a unit that is done is past every block
_FOREVER = 2**63  # past every log time

# how each column of a decode piece is compared (its values' bits: equal bits, equal bytes on
# the wire, so a join here is the join ``merge`` makes)
_BITS = {
    "turn": np.int64, "sender": np.int64, "addressee": np.int64, "channel": np.int64,
    "kind": np.int64, "code": np.int64, "margin": np.float64, "times": np.float64,
    "accepted": np.uint8,
}  # fmt: skip


class _Cursors:
    """How far each unit is (every block before its cursor is whole for it), and the least
    cursor of them all: blocks before it are whole for every unit."""

    def __init__(self, n: int) -> None:
        self.at = [0] * n
        self.low = 0 if n else _DONE

    def move(self, member: int, block: int) -> bool:
        """Unit ``member`` is past every block before ``block``; whether the least moved."""
        at = self.at
        old = at[member]
        if block <= old:
            return False
        at[member] = block
        if old != self.low:
            return False
        low = min(at)
        moved = low > self.low
        self.low = low
        return moved


class GroupLog:
    """The pulses and decodes of the units ``names`` (one process's, in member order) as the
    records they share (see the module docstring), on ``recorder``."""

    def __init__(
        self,
        recorder: RecordSink,
        tau: float,
        names: Sequence[str],
        ordered: OrderedSink | None = None,
    ) -> None:
        """``ordered``: the recorder to tell how far every unit has come (``clock``), which
        then writes in log-time order; None: nobody is told."""
        self.recorder = recorder
        self.tau = tau
        self.names = list(names)
        self.span = block_samples(tau)
        self._ordered = ordered
        self._clock = _Cursors(len(names))
        if ordered is not None:
            ordered.advance(0)
        self.pulses = PulseBlocks(tau, self.span)  # every unit's pulses, held: add them here
        self._pulse_at = _Cursors(len(names))
        self._decode_at = _Cursors(len(names))
        # block -> its pieces: (member, columns as records.DECODE_COLUMNS, tables)
        self._pieces: dict[int, list[tuple[int, Sequence[Any], records.DecodeTables]]] = {}
        self._blocks: list[int] = []  # the blocks of pieces held, a heap
        # id(tables) -> (tables, its token): kept alive, so an id is never another's
        self._keys: dict[int, tuple[Any, int]] = {}
        self._tokens: dict[tuple[tuple[str, ...], ...], int] = {}  # tables -> a token

    # -- pulses ------------------------------------------------------------------------------

    def pulses_passed(self, member: int, sample: int) -> None:
        """Unit ``member``'s records have come to ``sample``: no pulse of its is still to come
        in a block that ends by then; the blocks every sender is past go out."""
        if self._pulse_at.move(member, sample // self.span):
            self._write_pulses(self._pulse_at.low * self.span)

    def _write_pulses(self, sample: int) -> None:
        for block in self.pulses.before(sample):
            self.recorder.write(records.TX_PULSE, block, ns(block["t"]))

    # -- decodes -----------------------------------------------------------------------------

    def decodes(
        self, member: int, block: int, part: Sequence[Any], tables: records.DecodeTables
    ) -> None:
        """A piece of unit ``member``'s decodes of block ``block`` (its canonical columns, in
        ``records.DECODE_COLUMNS`` order, indexes into ``tables``), held until every unit is
        past the block."""
        held = self._pieces.get(block)
        if held is None:
            held = self._pieces[block] = []
            heapq.heappush(self._blocks, block)
        held.append((member, part, tables))

    def decoded_to(self, member: int, block: int) -> None:
        """Unit ``member`` has handed every piece of the blocks before ``block``: the blocks
        every unit is past go out."""
        if self._decode_at.move(member, block):
            self._write_decodes(self._decode_at.low)

    def _write_decodes(self, upto: int) -> None:
        blocks, write = self._blocks, self.recorder.write
        while blocks and blocks[0] < upto:
            pieces = self._pieces.pop(heapq.heappop(blocks))
            out = []
            for group in self._alike(pieces):
                units = sorted({self.names[pieces[i][0]] for i in group})
                _, part, tables = pieces[group[0]]
                if len(units) < len(group):  # one unit's two pieces alike: kept apart
                    out += [self._record(i, pieces) for i in group]
                    continue
                record = records.decodes_of_columns(units[0] if len(units) == 1 else units,
                                                    part, tables)  # fmt: skip
                out.append(record)
            out.sort(key=_order)
            for record in out:
                write(records.RX_DECODES, record, ns(record["t"]))

    def _record(
        self, i: int, pieces: list[tuple[int, Sequence[Any], records.DecodeTables]]
    ) -> records.DecodesRecord:
        member, part, tables = pieces[i]
        return records.decodes_of_columns(self.names[member], part, tables)

    def _alike(
        self, pieces: list[tuple[int, Sequence[Any], records.DecodeTables]]
    ) -> list[list[int]]:
        """The pieces (their indexes) that hold the same decodes, grouped, in order of each
        group's first: a bucket of pieces of one length and tables at a time, each column of
        the bucket joined into one array (its values as ``merge`` compares them: equal
        numbers of any dtype alike, floats by their bits), the rows of their bytes compared."""
        buckets: dict[tuple[int, int], list[int]] = {}
        for i, (_, part, tables) in enumerate(pieces):
            buckets.setdefault((len(part[7]), self._token(tables)), []).append(i)
        groups: list[list[int]] = []
        for (rows, _), idx in buckets.items():
            if len(idx) == 1:
                groups.append(idx)
                continue
            columns = [
                np.ascontiguousarray(
                    np.concatenate([pieces[i][1][c] for i in idx]), dtype=dtype
                )
                .reshape(len(idx), rows)
                .view(np.uint8)
                for c, dtype in enumerate(_BITS.values())
            ]
            found: dict[bytes, list[int]] = {}
            for i, row in zip(idx, np.concatenate(columns, axis=1), strict=True):
                found.setdefault(row.tobytes(), []).append(i)
            groups += found.values()
        groups.sort(key=lambda g: g[0])
        return groups

    def _token(self, tables: records.DecodeTables) -> int:
        """``tables`` as a small number, one a distinct content: a unit's own tables (a
        tuple, the same in every piece) looked up once."""
        got = self._keys.get(id(tables))
        if got is not None and got[0] is tables:
            return got[1]
        content = tuple(tuple(t) for t in tables)
        token = self._tokens.setdefault(content, len(self._tokens))
        if type(tables) is tuple:
            self._keys[id(tables)] = (tables, token)
        return token

    # -- time order ----------------------------------------------------------------------------

    def clock(self, member: int, sample: int) -> None:
        """Unit ``member`` will write no record of its own before ``sample`` (what it hands
        here aside): once every unit is past a point, the records held before it go out."""
        if self._clock.move(member, sample) and self._ordered is not None:
            low = self._clock.low
            if low < _DONE:  # all done: the run's last words may still come (``finish``)
                self._ordered.advance(ns(low * self.tau))

    def finish(self) -> None:
        """The run is over (its units' last blocks of spikes handed): what is held goes out."""
        if self._ordered is not None:
            self._ordered.advance(_FOREVER)

    # -- the end -----------------------------------------------------------------------------

    def end(self, member: int) -> None:
        """Unit ``member`` is done: past every block."""
        self.clock(member, _DONE)
        if self._pulse_at.move(member, _DONE):
            self._write_pulses(_DONE * self.span)
        if self._decode_at.move(member, _DONE):
            self._write_decodes(_DONE)


def _order(record: records.DecodesRecord) -> tuple[float, list[str]]:
    """Records of one block in the order they are written: by time, then units."""
    units = record.get("units") or [record.get("unit", "")]
    return (float(record["t"]), list(units))
