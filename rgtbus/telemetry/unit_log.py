"""A unit's log: its decodes and spikes held in blocks and written as columns, and its own
records written in time order (``UnitLog``).

* **Decodes** go to the log one ``/rx/decodes`` record a decode block of
  ``DECODE_BLOCK_SECONDS`` (each at its last decode's time; decodes that units of one process
  made alike, one record naming them: ``group_log.GroupLog``), whatever the unit's wakes: a batch
  of decodes as arrays (its names as indexes into the batch's tables), a decode taken on its
  own as a row. A block is written before any other record of the unit, so its records stay in
  time order (a log cut short is complete before its last one), and at the end of a wake past
  it. Which decodes a record holds, and how it holds them (``canonical``), depend on the
  blocks and the unit's other records alone, never on its wakes or on how the decodes were
  taken, so every engine, bus and attention, watched by a live view or not, writes the same
  records. While a live view may be looking (``offers``) each decode is also offered to it
  alone as it is made, one ``/rx/decode`` message at its own time (``Recorder.offer``).
* **Spikes** come from the ears a block of ``SPIKE_BLOCK_SECONDS`` at a time (the engine's
  ``SpikeLog``), one ``/rx/spike`` record of columns a block; a unit that takes its decodes a
  batch at a wake holds a block until that wake says whether it was done before the block
  ends (``release_spikes``). A block several units heard alike is one record of them all,
  written by the last of them to settle it.

The columns of a decode are named by ``records.DECODE_COLUMNS`` (``DecodePart``): no column is
read by its position.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple, Protocol

import numpy as np

from rgtbus.telemetry import records
from rgtbus.telemetry.blocks import BLOCK_SECONDS, block_samples
from rgtbus.telemetry.group_log import GroupLog
from rgtbus.telemetry.pulse_blocks import pulse_block_of
from rgtbus.telemetry.record_rows import decode_rows
from rgtbus.telemetry.recorder import Recorder
from rgtbus.timebase import ns, sample_of, samples_of

SPIKE_BLOCK_SECONDS = 1.0  # a unit's spikes of this much time make one /rx/spike record
DECODE_BLOCK_SECONDS = BLOCK_SECONDS  # a unit's decodes of this much time: one record
_NEVER = 2**63 - 1  # no block ends before it


class DecodePart(NamedTuple):
    """Decodes as columns, one entry a decode, named as ``records.DECODE_COLUMNS``: lists of
    names, or (a batch, with its ``records.DecodeTables``) arrays of indexes into its tables."""

    turn: Any
    sender: Any
    addressee: Any
    channel: Any
    kind: Any
    code: Any
    margin: Any
    times: Any
    accepted: Any


if DecodePart._fields != records.DECODE_COLUMNS:  # one order of columns, the records'
    raise ImportError("DecodePart's fields are not records.DECODE_COLUMNS")


class SharedBlock(Protocol):
    """A block of spikes that units heard alike (the engine's ``SharedSpikes``)."""

    samples: np.ndarray
    index: np.ndarray
    fired: np.ndarray
    end: int

    def settle(self, member: int, kept: bool) -> list[str] | None:
        """Member ``member`` kept the block or left it; the names of those that kept it once
        every member has settled, else None."""
        ...


class _OwnBlock:
    """A block of this unit's own spikes, held until its wake (a ``SharedBlock`` of one)."""

    __slots__ = ("end", "fired", "index", "name", "samples")

    def __init__(
        self, samples: np.ndarray, index: np.ndarray, fired: np.ndarray, end: int, name: str
    ) -> None:
        self.samples, self.index, self.fired, self.end, self.name = (
            samples, index, fired, end, name,
        )  # fmt: skip

    def settle(self, member: int, kept: bool) -> list[str] | None:
        return [self.name] if kept else []


def _named_column(col: Any, tables: records.DecodeTables, column: str) -> list[Any]:
    """A column of a batch held as indexes, as names; any other column as a list."""
    table = records.NAMED_COLUMNS.get(column)
    if table is None:
        return col if type(col) is list else list(col.tolist())
    names = tables[records.DECODE_TABLES.index(table)]
    return [names[i] for i in col.tolist()]


def _indexed_part(part: DecodePart, tables: records.DecodeTables) -> DecodePart | None:
    """A part of single decodes (columns of names) as the arrays of a batch with ``tables``
    (its names as indexes into them), or None when a name is in none of them: then the block
    is written in names."""
    index = [{name: i for i, name in enumerate(names)} for names in tables]
    out: list[Any] = []
    for column, col in zip(records.DECODE_COLUMNS, part, strict=True):
        table = records.NAMED_COLUMNS.get(column)
        if table is None:  # numbers: as a batch holds them
            out.append(np.asarray(col, dtype=bool if column == "accepted" else None))
            continue
        of = index[records.DECODE_TABLES.index(table)]
        try:
            out.append(np.array([of[v] for v in col], dtype=np.int64))
        except (KeyError, TypeError):  # unhashable or unknown: stays named
            return None
    return DecodePart(*out)


def _joined(
    parts: list[DecodePart], tables: list[records.DecodeTables | None]
) -> tuple[DecodePart, records.DecodeTables | None]:
    """The parts held as one: arrays with the batches' tables where every part can be
    indexed into one set of tables, else lists of names."""
    if len(parts) == 1 and tables[0] is not None:  # one batch (the usual case): as it is
        return parts[0], tables[0]
    table = next((t for t in tables if t is not None), None)
    indexed: list[DecodePart] = []
    if table is not None and all(t is None or t == table for t in tables):
        for p, t in zip(parts, tables, strict=True):
            q = p if t is not None else _indexed_part(p, table)
            if q is None:  # a name in none of the tables: the block stays in names
                indexed = []
                break
            indexed.append(q)
    if indexed:
        if len(indexed) == 1:
            return indexed[0], table
        return DecodePart(*(np.concatenate(cols) for cols in zip(*indexed, strict=True))), table
    named = []
    for column in records.DECODE_COLUMNS:
        col: list[Any] = []
        for p, t in zip(parts, tables, strict=True):
            value = getattr(p, column)
            col.extend(_named_column(value, t, column) if t is not None else list(value))
        named.append(col)
    return DecodePart(*named), None


def canonical(
    part: DecodePart, tables: records.DecodeTables | None, own: records.DecodeTables | None
) -> tuple[DecodePart, records.DecodeTables]:
    """A block's decodes as its record holds them, whatever way they were taken (``tables``:
    those ``part``'s indexes point into; None: ``part`` holds names): its names as indexes
    into the unit's own tables (``own``: every name its decodes can hold), or, where a name
    is in none of those, into tables of the names the block uses, each sorted. A batch taken
    at one wake and the same decodes taken one at a time (a unit a live view watches) make
    the same record."""
    if own is not None:
        if tables is own or (
            tables is not None and all(a is b or a == b for a, b in zip(tables, own, strict=True))
        ):
            return part, own  # a batch's: indexes into the unit's tables already
        named = part if tables is None else _names_of(part, tables)
        indexed = _indexed_part(named, own)
        if indexed is not None:
            return indexed, own
        part, tables = named, None
    elif tables is not None:
        part, tables = _names_of(part, tables), None
    cols = dict(zip(records.DECODE_COLUMNS, part, strict=True))
    out: list[list[str]] = []
    for table_name in records.DECODE_TABLES:
        columns = [c for c, t in records.NAMED_COLUMNS.items() if t == table_name]
        used = sorted(set().union(*(cols[c] for c in columns)))
        at = {name: i for i, name in enumerate(used)}
        for c in columns:
            cols[c] = np.array([at[name] for name in cols[c]], dtype=np.int64)
        out.append(used)
    return DecodePart(**cols), (out[0], out[1], out[2])


def _names_of(part: DecodePart, tables: records.DecodeTables) -> DecodePart:
    """A part of indexes into ``tables`` as columns of names."""
    columns = zip(records.DECODE_COLUMNS, part, strict=True)
    return DecodePart(*(_named_column(col, tables, c) for c, col in columns))


class UnitLog:
    """Unit ``name``'s log on ``recorder``: its decode and spike blocks, its traces, and its
    own records in time order (see the module docstring). ``units``: the channels' names, in
    order; ``holding()``: whether a block of spikes handed now waits for the unit's next wake
    (it takes its decodes a batch at a wake and is not done)."""

    def __init__(
        self,
        name: str,
        recorder: Recorder,
        tau: float,
        units: Sequence[str],
        holding: Callable[[], bool],
    ) -> None:
        self.name = name
        self.recorder = recorder
        self.enabled = recorder.enabled
        self.tau = tau
        self.units = tuple(units)
        self.holding = holding
        self.member = 0  # this unit's index among its ears' listeners (``SharedBlock.settle``)
        # spikes go to the log in blocks of this many samples (a fixed span of time, not the
        # engine's window: what a record holds never depends on how the run was stepped)
        self.block = max(1, round(SPIKE_BLOCK_SECONDS / tau))
        self._held: list[SharedBlock] = []  # blocks of spikes handed, until its wake
        self._parts: list[DecodePart] = []
        self._tables: list[records.DecodeTables | None] = []  # a part's (None: names)
        self._rows: list[tuple[Any, ...]] = []  # single decodes since the last part
        self._decode_block = block_samples(tau)
        self.held_block = -1  # the decode block of the first decode held (-1: none)
        self.offers = False  # each decode offered to a live view as it is made (never logged)
        # the log of the units of its process, where their pulses and alike decodes are one
        # record (``join``); until it joins one, a group of its own
        self.group = GroupLog(recorder, tau, [name])
        self.at = 0  # its index in the group
        # the unit's tables of every name its decodes can hold (``canonical``): set by its
        # Listening; None: each record's own tables of the names it uses
        self.tables: records.DecodeTables | None = None

    # -- lines and records ---------------------------------------------------------------------

    def log(self, level: str, text: str, t: float) -> None:
        """A log line of this unit at ``t`` seconds."""
        self.recorder.log(level, text, ns(t), name=self.name)

    def write(self, topic: str, record: Any, t: float) -> None:
        """A record at ``t`` seconds, written as it comes."""
        self.recorder.write(topic, record, ns(t))

    def join(self, group: GroupLog, at: int) -> None:
        """Its pulses and decodes go to ``group`` (the log of its process's units), as unit
        ``at`` of it; before it logs any."""
        self.group, self.at = group, at

    def pulse(self, record: records.PulseRecord) -> None:
        """One pulse this unit sends (``records.pulse``), held in the batch of its block and
        written one ``/tx/pulse`` record a block of its process's units (``GroupLog``: which
        pulses a record holds depends on the pulses alone). While a live view may be
        looking, each pulse is also offered to it alone as it is made, as a block of one."""
        self.group.pulses.add(record)
        if self.recorder.watched():
            one = pulse_block_of([record], self.tau)
            self.recorder.offer(records.TX_PULSE, one, ns(one["t"]))

    def send(
        self,
        samples: Sequence[int],
        magnitudes: Sequence[float],
        channel: str,
        omega: float,
        message: records.MessageRef,
    ) -> None:
        """The pulses of one message this unit sends, as ``pulse`` would each (while nobody
        may be looking: none is offered)."""
        self.group.pulses.add_send(samples, magnitudes, channel, omega, message)

    def write_in_order(self, topic: str, record: Any, t: float) -> None:
        """A record of this unit's own at ``t`` seconds, after the decodes that came before."""
        self.flush_decodes()
        self.group.decoded_to(self.at, self._block_of(t))
        self._pulses_before(t)
        self.recorder.write(topic, record, ns(t))

    def _pulses_before(self, t: float) -> None:
        """This unit's clock is at ``t``, the time of a record of its own (it is written at or
        after its time, and no pulse is logged for a time already past): the pulse blocks
        every unit of its group is past go out, so a log cut after that record holds them
        (``Replay.units_until_ns``)."""
        self.group.pulses_passed(self.at, sample_of(t, self.tau))

    def trace(self, first: int, x: np.ndarray, y: np.ndarray) -> None:
        """Resonator states from sample ``first`` on (x, y: samples × channels), one message a
        sample: Foxglove's Plot panel draws ``/trace/<unit>.y[i]`` as channel i's curve at the
        full sample rate (docs/foxglove.md)."""
        topic = records.trace_topic(self.name)
        write = self.recorder.write
        tau = self.tau
        for k, (yk, xk) in enumerate(zip(y.tolist(), x.tolist(), strict=True)):
            s = first + k
            t = s * tau
            write(topic, records.trace(self.name, s, t, yk, xk), ns(t))

    # -- decodes ---------------------------------------------------------------------------------

    def decode(
        self,
        turn: int,
        sender: str,
        addressee: str,
        channel: str,
        kind: str,
        code: str,
        margin: float,
        t: float,
        accepted: bool,
    ) -> None:
        """One decode taken on its own, held for its block's record."""
        if self.offers:
            row = records.decode(
                self.name, turn, sender, addressee, channel, kind, code, margin, t, accepted
            )
            self.recorder.offer(records.RX_DECODE, row, ns(t))
        if self.held_block < 0:
            self.held_block = self._block_of(t)
        self._rows.append((turn, sender, addressee, channel, kind, code, margin, t, accepted))

    def decode_batch(self, part: DecodePart, tables: records.DecodeTables) -> None:
        """A batch of decodes as arrays (its names as indexes into ``tables``), held for its
        block's record; the arrays are the record's from then on."""
        if self.offers:
            for row in decode_rows(records.decodes_of_columns(self.name, part, tables)):
                self.recorder.offer(records.RX_DECODE, row, ns(row["t"]))
        self._rows_to_part()
        if self.held_block < 0:
            self.held_block = self._block_of(float(part.times[0]))
        self._parts.append(part)
        self._tables.append(tables)

    def after_wake(self, pos: int, spikes_from: int) -> None:
        """The unit's wake is over, every sample before ``pos`` heard: the decode blocks that
        ended go out. ``spikes_from``: no block of spikes still to be handed to it ends
        before that sample. It writes nothing more before the least of ``pos``, that and
        the starts of the blocks of spikes it holds (``GroupLog.clock``)."""
        if 0 <= self.held_block < pos // self._decode_block:  # past a block of decodes
            self.flush_decodes(before=pos)
        self.group.decoded_to(self.at, pos // self._decode_block)
        low = min(pos, spikes_from)
        for block in self._held:  # logged at its end, or cut short where the unit was done
            low = min(low, block.end - self.block)
        self.group.clock(self.at, low)

    def _block_of(self, t: float) -> int:
        """The decode block of a decode at time ``t``."""
        return sample_of(t, self.tau) // self._decode_block

    def _rows_to_part(self) -> None:
        """The single decodes logged since the last batch, as a part of columns of names."""
        if self._rows:
            self._parts.append(DecodePart(*(list(c) for c in zip(*self._rows, strict=True))))
            self._tables.append(None)
            self._rows = []

    def flush_decodes(self, before: int | None = None) -> None:
        """Write the decodes held, one record a decode block, each at its last decode's time
        (``before``: only those of the blocks before the one of that sample; the others stay
        held)."""
        self._rows_to_part()
        parts, self._parts = self._parts, []
        tables, self._tables = self._tables, []
        self.held_block = -1
        if not parts:
            return
        cols, table = _joined(parts, tables)
        times = cols.times
        total = len(times)
        if type(times) is list:
            blocks = [self._block_of(t) for t in times]
            cuts = [0, *(i for i in range(1, total) if blocks[i] != blocks[i - 1])]
            firsts = [blocks[a] for a in cuts]
        else:  # a batch's: in time order, so a block's decodes are one run
            of = samples_of(times, self.tau) // self._decode_block
            cuts = [0, *(np.flatnonzero(of[1:] != of[:-1]) + 1).tolist()]
            firsts = of[cuts].tolist()  # each block's, not each decode's
        now = _NEVER if before is None else before // self._decode_block
        own, hand = self.tables, self.group.decodes
        for a, b, block in zip(cuts, [*cuts[1:], total], firsts, strict=True):
            if block >= now:  # the block still going on: held, as one part
                self._parts = [DecodePart(*[c[a:] for c in cols])]
                self._tables = [table]
                self.held_block = block
                return
            part = cols if b - a == total else DecodePart(*[c[a:b] for c in cols])
            piece, piece_tables = canonical(part, table, own)
            self._pulses_before(float(piece.times[-1]))
            hand(self.at, block, piece, piece_tables)

    # -- spikes (the engine's SpikeLog) ----------------------------------------------------------

    def spikes(self, samples: np.ndarray, index: np.ndarray, fired: np.ndarray, end: int) -> None:
        """One block's spikes of this unit's resonators, as one ``/rx/spike`` record of columns
        at the block's end (or where the unit was done, for its last block) as its log time;
        held until the unit's wake while ``holding()``."""
        if self.holding():
            self._held.append(_OwnBlock(samples, index, fired, end, self.name))
        else:
            self._log_spikes(self.name, samples, index, fired, end)

    def shared_spikes(self, block: SharedBlock) -> None:
        """A block of spikes this unit heard alike with others of its process: held until
        its wake, as its own blocks are, then settled (``release_spikes``)."""
        if self.holding():
            self._held.append(block)
        else:
            self._settle_spikes(block, None)

    def keeps_now(self) -> bool:
        """Whether a block handed now is kept at once (``shared_spikes`` would settle it as
        kept)."""
        return not self.holding()

    def shared_kept(
        self, names: list[str], samples: np.ndarray, index: np.ndarray, fired: np.ndarray, end: int
    ) -> None:
        """A block that ``names`` heard alike and all keep at once."""
        self._log_spikes(names, samples, index, fired, end)

    def release_spikes(self, stop: int | None) -> None:
        """Log the blocks held for this wake: all of them, or (``stop``: done before that
        sample) their spikes before ``stop``, the last block ending there."""
        held, self._held = self._held, []
        if stop is not None:
            for block in held:
                self._settle_spikes(block, stop)
            return
        member = self.member  # all kept (``_settle_spikes``), in a loop of its own: a large
        for block in held:  # group settles each of its blocks once a unit
            units = block.settle(member, True)
            if units:
                self._log_spikes(units, block.samples, block.index, block.fired, block.end)

    @property
    def holds_spikes(self) -> bool:
        """Whether blocks of spikes wait for this wake."""
        return bool(self._held)

    def _settle_spikes(self, block: SharedBlock, stop: int | None) -> None:
        """Keep a block (its units' record is written once every unit of it has settled), or,
        done before its end (``stop``), leave it and log its spikes before ``stop`` alone."""
        samples, index, fired, end = block.samples, block.index, block.fired, block.end
        kept = stop is None or end <= stop
        units = block.settle(self.member, kept)
        if units:
            self._log_spikes(units, samples, index, fired, end)
        if stop is None or kept:
            return
        cut = int(samples.searchsorted(stop))
        if cut:
            channels = fired[index[:cut]]
            fired = np.unique(channels)
            index = np.searchsorted(fired, channels)
            self._log_spikes(self.name, samples[:cut], index, fired, stop)

    def _log_spikes(
        self,
        units: str | list[str],
        samples: np.ndarray,
        index: np.ndarray,
        fired: np.ndarray,
        end: int,
    ) -> None:
        names = [self.units[c] for c in fired.tolist()]
        record = records.spikes(units, self.tau, samples, index, names)
        self.recorder.write(records.RX_SPIKE, record, ns(end * self.tau))

    def end(self) -> None:
        """The run is over for this unit: what it holds is written (what it shares with its
        group, once every unit of it is past)."""
        self.flush_decodes()
        self.release_spikes(None)  # before the group hears it is done: held, to be joined
        self.group.end(self.at)
