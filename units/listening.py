"""A unit's listening: what it decoded (``DecodeColumns``), how it reads a code off its own
readout, and how it takes a shared listen queue's decodes a batch at a time as columns.

A listen names a code's instants; the unit decodes it on its own resonators' readout through
the ears' readings, where every decode is made (``rgtbus.engine.reading``: ``read_code`` at the
schedule's instants, or ``decode_among`` with a timing search over the channels it may be on;
for a batch, the column forms), and hands the result to the unit (``act``), which records,
checks and learns. Listening decides what to read and when, never how. Under the concurrent
schedule every unit of a process decodes the same queue of codes: the ears read each position
once for all of them (``SharedQueues``), and a unit takes a batch of its decodes as arrays
(recorded, logged and learned from with no Python call per decode) up to the first that needs
more than that (a code refused, a table completed), which it takes on its own. The same
decodes either way (tested).
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from rgtbus.units.timers import Timer, Timers

from rgtbus.errors import BadInput
from rgtbus.misreads import DECODE_KINDS, HeldDecodes, Misreads, SentTruth, misreads_of
from rgtbus.pairs import PairTable
from rgtbus.protocol import Listen, ListenQueue, ProtocolState, code_samples
from rgtbus.scenario import Scenario
from rgtbus.signal.decoder import (
    Decision,
    WordSet,
    code_candidates,
    nearer_than_silence,
)
from rgtbus.signal.resonator import clean_first_spike
from rgtbus.signal.rules import rule_named
from rgtbus.telemetry import records
from rgtbus.telemetry.unit_log import DecodePart, UnitLog
from rgtbus.timebase import samples_of

if TYPE_CHECKING:
    from rgtbus.engine.hearing import Ears
    from rgtbus.mind import Mind

DecodedRow = tuple[int, str, str, str]  # (turn, kind, addressee, code): what the summary needs
Act = Callable[[Listen, str, float, int], None]  # what a decode read: code, margin, channel

_ID, _RELATION, _INFLUENCE = 0, 1, 2  # the kinds of a listen, as a column
KINDS = DECODE_KINDS


class DecodeColumns:
    """A unit's decodes as the summary judges them, held as the state they are, not as a
    Python object per decode. An ID read as the ID (``("id", *, "id")``) is only counted: the
    summary never finds one wrong, and half of a run's n³ decodes are such IDs. A run of a
    shared listen queue taken as a batch (``extend_run``) keeps one byte a payload: the word
    it read; its turn, kind and addressee are the queue's own (``QueueReads``, one copy for
    every unit). Any other decode is a row: its turn (4 bytes) and which (kind, addressee,
    code) it read (2 bytes, 4 past 65,535 distinct ones: an index into the few distinct
    ones). ``len`` and ``count`` count every decode; ``arrays()`` gives every held decode in
    decode order; it iterates as ``DecodedRow`` tuples, in order; ``tolist()`` for JSON."""

    __slots__ = ("_counted", "_ids_read_right", "_rows", "_runs", "_seen", "_turns", "_what",
                 "_words")  # fmt: skip

    def __init__(self) -> None:
        self._turns = array("i")
        self._what = array("H")
        self._rows: list[tuple[str, str, str]] = []
        self._seen: dict[tuple[str, str, str], int] = {}
        self._counted = bytearray()  # per distinct row: 1 for an ID read as the ID
        self._ids_read_right = 0
        self._words = array("B")  # the runs' payload words, in decode order
        # [rows before it, queue reads, first position, end position, its first word]
        self._runs: list[list[Any]] = []

    def append(self, turn: int, kind: str, addressee: str, code: str) -> None:
        """One decode."""
        i = self.index((kind, addressee, code))
        if self._counted[i]:
            self._ids_read_right += 1
            return
        self._turns.append(turn)
        self._what.append(i)

    def index(self, key: tuple[str, str, str]) -> int:
        """The index of a (kind, addressee, code) among the distinct ones (made on first use)."""
        i = self._seen.get(key)
        if i is None:
            i = self._seen[key] = len(self._rows)
            self._rows.append(key)
            self._counted.append(key[0] == "id" and key[2] == "id")
            if i > 0xFFFF and self._what.typecode == "H":  # past two bytes: four
                self._what = array("I", self._what)
        return i

    def extend_run(self, reads: QueueReads, a: int, b: int, word: np.ndarray) -> None:
        """Positions [a, b) of a shared queue, each read as the word ``word`` names and
        accepted (every ID read as the ID: counted)."""
        ids = reads.is_id[a:b]
        self._ids_read_right += int(np.count_nonzero(ids))
        if len(reads.names) > 0xFF and self._words.typecode == "B":
            self._words = array("H", self._words)
        dtype = np.uint8 if self._words.typecode == "B" else np.uint16
        start = len(self._words)
        self._words.frombytes(np.asarray(word)[~ids].astype(dtype).tobytes())
        last = self._runs[-1] if self._runs else None
        if last is not None and last[0] == len(self._turns) and last[1] is reads and last[3] == a:
            last[3] = b  # goes on from the last run: one run
        else:
            self._runs.append([len(self._turns), reads, a, b, start])

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled (a unit process's report) as rows: a run's queue stays in its process."""
        turns, what, rows = self.arrays()
        return (_decodes_of_rows, (turns.tobytes(), what.astype(np.uintc).tobytes(), rows,
                                   self._ids_read_right))  # fmt: skip

    def __len__(self) -> int:
        """Every decode, the IDs only counted too."""
        return len(self._turns) + len(self._words) + self._ids_read_right

    def count(self, kind: str) -> int:
        """How many of the decodes are of ``kind`` (id, relation or influence)."""
        _, what, rows = self.arrays()
        of_kind = np.array([row[0] == kind for row in rows] or [False])
        held = int(of_kind[what].sum()) if len(what) else 0
        return held + (self._ids_read_right if kind == "id" else 0)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, list[tuple[str, str, str]]]:
        """(each held decode's turn, the index of its (kind, addressee, code) in the third),
        in decode order (``rgtbus.misreads.misreads_of``): over the rows' own memory when
        there is no run, else built (a unit's, once)."""
        dtype = np.uint16 if self._what.typecode == "H" else np.uintc
        turns = np.frombuffer(self._turns, dtype=np.intc)
        what: np.ndarray = np.frombuffer(self._what, dtype=dtype)
        if not self._runs:
            return turns, what, self._rows
        words = np.frombuffer(
            self._words, dtype=np.uint8 if self._words.typecode == "B" else np.uint16
        )
        parts_t: list[np.ndarray] = []
        parts_w: list[np.ndarray] = []
        done = 0  # rows taken so far
        lookups: dict[int, np.ndarray] = {}
        for rows_before, reads, a, b, w0 in self._runs:
            parts_t.append(turns[done:rows_before])
            parts_w.append(what[done:rows_before].astype(np.int64))
            done = rows_before
            pay = ~reads.is_id[a:b]
            codes = reads.what[a:b][pay] + words[w0 : w0 + int(np.count_nonzero(pay))]
            lookup = lookups.get(id(reads))  # a code's row index (-1: not made yet)
            if lookup is None:
                size = len(KINDS) * len(reads.units) * len(reads.names)
                lookup = lookups[id(reads)] = np.full(size, -1, dtype=np.int64)
            index = lookup[codes]
            if (index < 0).any():
                for c in np.unique(codes[index < 0]).tolist():
                    lookup[c] = self.index(reads.key(c))
                index = lookup[codes]
            parts_t.append(reads.turn[a:b][pay].astype(np.intc))
            parts_w.append(index)
        parts_t.append(turns[done:])
        parts_w.append(what[done:].astype(np.int64))
        return np.concatenate(parts_t), np.concatenate(parts_w), self._rows

    def misreads(self, truth: SentTruth) -> Misreads:
        """``rgtbus.misreads.misreads_of`` these decodes (the summary asks this), in decode
        order, without building every held decode: rows are judged as rows, a run against its
        queue's truth, worked out once a queue for every unit (``_queue_truth``): a few array
        operations over its bytes."""
        dtype = np.uint16 if self._what.typecode == "H" else np.uintc
        turns = np.frombuffer(self._turns, dtype=np.intc)
        what = np.frombuffer(self._what, dtype=dtype)
        words = np.frombuffer(
            self._words, dtype=np.uint8 if self._words.typecode == "B" else np.uint16
        )
        parts: list[Misreads] = []
        done = 0  # rows judged so far
        code_of = truth.arrays()[2] if self._runs else None
        for rows_before, reads, a, b, w0 in self._runs:
            rows = HeldDecodes(turns[done:rows_before], what[done:rows_before], self._rows)
            parts.append(misreads_of(rows, truth))
            done = rows_before
            judged, addressed, sent_word, where = _queue_truth(reads, truth)
            pa, pb = int(reads.n_pay[a]), int(reads.n_pay[b])
            read = words[w0 : w0 + pb - pa]
            bad = np.flatnonzero(judged[pa:pb] & ((sent_word[pa:pb] != read) | ~addressed[pa:pb]))
            p = where[pa + bad]
            turn = reads.turn[p].astype(np.int64)
            kinds, names = _numbers(reads, truth)
            assert code_of is not None
            read_as = names[read[bad]]
            parts.append(Misreads.of(turn, kinds[reads.kind[p]], read_as, code_of[1, turn]))
        parts.append(misreads_of(HeldDecodes(turns[done:], what[done:], self._rows), truth))
        return Misreads.concat([m for m in parts if len(m)])

    def __iter__(self) -> Iterator[DecodedRow]:
        turns, what, rows = self.arrays()
        for turn, i in zip(turns.tolist(), what.tolist(), strict=True):
            yield (turn, *rows[i])

    def tolist(self) -> list[list[Any]]:
        """Every held decode as a list (turn, kind, addressee, code)."""
        return [list(row) for row in self]


def _decodes_of_rows(
    turns: bytes, what: bytes, rows: list[tuple[str, str, str]], ids_read_right: int
) -> DecodeColumns:
    """``DecodeColumns`` of held rows (``DecodeColumns.__reduce__``)."""
    out = DecodeColumns()
    for key in rows:
        out.index(key)
    out._turns.frombytes(turns)
    index = np.frombuffer(what, dtype=np.uintc)
    dtype = np.uint16 if out._what.typecode == "H" else np.uintc
    out._what.frombytes(index.astype(dtype).tobytes())
    out._ids_read_right = ids_read_right
    return out


def _queue_truth(
    reads: QueueReads, truth: SentTruth
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Over a queue's payloads, in queue order (once a queue and truth: ``truth.shared``):
    whether each is judged (its turn's payload is known), whether it was sent to the
    addressee whose channel the queue reads it on, the index in ``reads.names`` of the word
    sent (-1: none of them), and each payload's position in the queue. As ``misreads_of``
    judges a payload row: wrong when the code or the addressee differs from what was sent."""

    def build() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        known, to_of, code_of = truth.arrays()
        where = np.flatnonzero(~reads.is_id)
        t = reads.turn[where]
        in_span = (t >= 0) & (t < known.shape[1])
        t = np.where(in_span, t, 0)
        judged = in_span & known[1, t]
        unit_number = np.array([truth.number(u) for u in reads.units], dtype=np.int64)
        addressed = to_of[1, t] == unit_number[reads.expected[where]]
        sent_word = np.full(where.size, -1, dtype=np.int64)
        for w, name in enumerate(reads.names):
            sent_word[code_of[1, t] == truth.number(name)] = w
        return judged, addressed, sent_word, where

    return truth.shared(reads, build)


def _numbers(reads: QueueReads, truth: SentTruth) -> tuple[np.ndarray, np.ndarray]:
    """The numbers (``SentTruth.number``) of a queue's kinds and of its word names."""

    def build() -> tuple[np.ndarray, np.ndarray]:
        kinds = np.array([truth.number(k) for k in KINDS], dtype=np.int64)
        return kinds, np.array([truth.number(w) for w in reads.names], dtype=np.int64)

    return truth.shared(reads.names, build)  # they depend on the names alone


@dataclass(frozen=True, eq=False)
class QueueReads:
    """A shared listen queue as columns over its positions (the i-th to fall due), worked out
    once for every unit of a process (``SharedQueues.shared``): what a unit needs to take a
    batch of its decodes as arrays, and ``read``, which decodes one position for every
    receiver at once (``SharedQueues.decodes``)."""

    bounds: np.ndarray  # boundary (ready sample + 1)
    seq: np.ndarray  # the listen's index in the queue (its seq after the queue's first)
    kind: np.ndarray  # _ID, _RELATION, _INFLUENCE
    turn: np.ndarray
    sender: np.ndarray  # unit index
    expected: np.ndarray  # unit index of the expected addressee
    slot: np.ndarray  # the (sender, expected) pair's slot in a PairTable of the units
    rnd: np.ndarray  # the turn's influence round
    t_ready: np.ndarray  # the decode's time, s
    is_id: np.ndarray  # bool: an ID
    is_rel: np.ndarray  # bool: a relation code
    is_inf: np.ndarray  # bool: an influence
    n_rel: np.ndarray  # relation codes before each position (one more entry than positions)
    n_inf: np.ndarray  # influences before each position (likewise)
    n_pay: np.ndarray  # payloads before each position (likewise)
    unique: bool  # no pair of one table twice (a batch sets each slot once)
    what: np.ndarray  # (kind · units + addressee) · len(names): + the word, a decoded row
    channel: np.ndarray  # unit index of the channel it is carried on (an ID: its sender's)
    names: tuple[str, ...]  # every word name a decode can read
    alliance: np.ndarray  # per name: 1 if "alliance"
    value: np.ndarray  # per name: its alternative (-1: not one)
    id_word: int  # the name index of "id"
    read: Callable[[int], tuple[np.ndarray, np.ndarray, np.ndarray]]
    # positions [q0, q1) for every receiver at once, (positions × receivers) each
    read_block: Callable[[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]]
    units: tuple[str, ...] = ()  # the group, as ``what`` indexes it

    def key(self, code: int) -> tuple[str, str, str]:
        """The (kind, addressee, code) a ``what`` + word stands for."""
        k, w = divmod(code, len(self.names))
        kind, addressee = divmod(k, len(self.units))
        return (KINDS[kind], self.units[addressee], self.names[w])


def _completes(table: PairTable | None, had: int, slots: np.ndarray, full: int) -> int:
    """Which of ``slots``, set in order into ``table`` (holding ``had`` entries; None: none
    yet), first makes it hold ``full``, or every one when it holds them already (each then
    completes it again); ``len(slots)`` if none."""
    if had >= full:
        return 0
    new = np.ones(slots.size, dtype=bool) if table is None else table.absent(slots)
    first = np.zeros(slots.size, dtype=bool)
    first[np.unique(slots, return_index=True)[1]] = True  # a slot counts once
    hit = np.flatnonzero(had + np.cumsum(new & first) >= full)
    return int(hit[0]) if hit.size else slots.size


class ExpectedSpike:
    """Where unit ``name``'s attention spike to a sender's ID comes on a clean channel
    (``ProtocolState.expect_spike``): its resonator on the sender's frequency, at rest from the
    turn's start, hears the ID's pulses ``ids`` through its link's gain and nothing else
    (serial: one code at a time), up to the ID's ``deadline``."""

    def __init__(self, scenario: Scenario, name: str) -> None:
        self.scenario = scenario
        self._index = {u: i for i, u in enumerate(scenario.units)}
        # its link gains as the engine made its receiver (``hear``, as the run begins)
        self._gains: np.ndarray | None = None

    def hear(self, gains: np.ndarray) -> None:
        """The link gains of its receiver, as the engine made it (``Reception``)."""
        self._gains = gains

    def __call__(self, sender: str, ids: tuple[int, ...], deadline: int) -> int | None:
        sc = self.scenario
        ch = self._index[sender]
        within = deadline - ids[0] + 1
        offsets = tuple(k - ids[0] for k in ids)
        assert self._gains is not None, "an expected spike before the run began"
        gain = float(self._gains[ch])
        k = clean_first_spike(
            sc.frequencies[sender], sc.mode, sc.timing.tau, sc.codebook.id_word, offsets, gain,
            within,
        )  # fmt: skip
        return None if k is None else ids[0] + k


class Listening:
    """How unit ``name`` reads codes off its readout (see the module docstring). Parts it is
    given: the unit's ``mind`` (a batch learns into its tables), ``decoded`` and ``log`` (a
    batch is recorded there), and two callbacks into the unit: ``act(listen, code, margin,
    channel)``, what a decode taken on its own read, and ``settle(sample)``, the unit is done
    if it has decided or failed by then. ``repairs``: the unit may hold a payload for repair
    (then every decode is taken on its own)."""

    def __init__(
        self,
        name: str,
        scenario: Scenario,
        protocol: ProtocolState,
        mind: Mind,
        decoded: DecodeColumns,
        log: UnitLog,
        *,
        act: Act,
        settle: Callable[[int], None],
        repairs: bool,
    ) -> None:
        sc = scenario
        self.name = name
        self.scenario = sc
        self.units = sc.units
        self.tau = sc.timing.tau
        self.cb = sc.codebook
        self.protocol = protocol
        self.mind = mind
        self.decoded = decoded
        self.log = log
        self.act = act
        self.settle = settle
        self.repairs = repairs
        self.omegas = [sc.frequencies[u] for u in self.units]
        # its payloads' words, read by the scenario's rule; an ID (which must read as the
        # ID-code, else the turn fails) and its attention, below, by the nearest word: the
        # matched filter weighs words by direction alone, and the ID-code lies close in
        # direction to alternatives' words (docs/model.md, "Decoding rules")
        rule = rule_named(sc.decoding)
        self.id_words = WordSet.of(self.cb.distinct_words())
        self.families = {
            f: WordSet.of(self.cb.family(f), rule=rule) for f in ("relation", "alternative")
        }
        # every word name a decode can read, each once: a batch's codes index into it, and
        # the log's records of decodes index into these tables (``UnitLog.tables``)
        words: list[str] = []
        for family in (self.id_words, *self.families.values()):
            for word in family.names:
                if word not in words:
                    words.append(word)
        self.words = tuple(words)
        self.log_tables: records.DecodeTables = (self.units, KINDS, self.words)
        log.tables = self.log_tables
        self.index_of = {u: i for i, u in enumerate(self.units)}
        self._gains = np.ones(0)  # what it hears of each sender: its receiver's (``begin``)
        self._timed = sc.channel.timed  # pulses land off their samples (delays, clocks)
        # by channel (``attend``): the ID as its link delivers it, alone and as a word set
        self._attention_words: dict[int, tuple[WordSet, tuple[float, ...]]] = {}
        self._channel_sets: dict[tuple[str, ...], tuple[int, ...]] = {}
        # a decoded row's index in ``decoded``, by its integer code (``_take_batch``)
        self.ears: Ears | None = None
        self.member = 0  # its index among the ears' listeners

    def begin(self, ears: Ears, member: int) -> None:
        """The ears it hears through, and its index among their listeners (whose link
        gains, made by the engine, are what it hears of each sender)."""
        self.ears, self.member = ears, member
        self._gains = ears.listeners[member].gains

    # -- a decode on its own ---------------------------------------------------------------------

    def decode(self, listen: Listen) -> None:
        """Decode ``listen`` on this unit's own readout, and act on it."""
        assert self.ears is not None
        if listen.kind == "id":
            # An ID counts only if it reads as the ID-code on the sender's own frequency
            # (a↔c crosstalk makes resonators fire for other codes).
            ch = self.index_of[listen.sender]
            if self._timed:  # it lands where its link puts it: timed by the search
                dec, _ = self.ears.reading.decode_among(
                    self.member, (ch,), listen.start, self.id_words, self.protocol.search
                )
            else:
                dec = self.read(code_samples(listen.start, self.omegas[ch], self.cb.pulses,
                                             self.tau), ch, self.id_words)  # fmt: skip
            self.act(listen, dec.name, dec.margin, ch)
            return
        dec, ch = self.ears.reading.decode_among(
            self.member, self.channels_of(listen), listen.start, self.words_of(listen),
            self.protocol.search,
        )  # fmt: skip
        self.act(listen, dec.name, dec.margin, ch)

    def read(self, samples: tuple[int, ...], channel: int, words: WordSet) -> Decision:
        """The nearest of ``words`` to its readout at ``samples`` on ``channel``."""
        assert self.ears is not None
        return self.ears.reading.read_code(self.member, samples, channel, words)

    def attend(self, sender: str) -> int | None:
        """Confirmed attention (docs/protocol.md, "Attention"): the current turn's ID timed on
        ``sender``'s channel by a timing search around the schedule's instants (the shift whose
        reads fit the ID-code best, as its link's gain delivers it), then found there if its
        reads are nearer that ID-code than silence (in its slot nothing else is on that
        channel: whether the ID came, not which word it is). Returns the shift, or None when
        no ID came."""
        assert self.ears is not None
        ch = self.index_of[sender]
        words = self._attention_words.get(ch)
        if words is None:  # the ID as its link delivers it alone (to time it), and against
            # silence (to find it): the threshold between them adapted to the link's gain
            heard = tuple(float(self._gains[ch]) * m for m in self.cb.id_word)
            words = self._attention_words[ch] = (WordSet.of({"id": heard}), heard)
        dec, _ = self.ears.reading.decode_among(
            self.member, (ch,), self.protocol.turn_start, words[0], self.protocol.search
        )
        return dec.shift if nearer_than_silence(dec.values, words[1]) else None

    def words_of(self, listen: Listen) -> WordSet:
        """The words a payload listen reads (an ID reads ``id_words``)."""
        return self.families["relation" if listen.kind == "relation" else "alternative"]

    def channels_of(self, listen: Listen) -> tuple[int, ...]:
        """The channel indexes a payload listen may find its code on."""
        channels = self._channel_sets.get(listen.channels)
        if channels is None:
            channels = tuple(self.index_of[r] for r in listen.channels)
            self._channel_sets[listen.channels] = channels
        return channels

    # -- a shared queue, a batch at a time -----------------------------------------------------

    def take_queue(self, t: Timer, pos: int, timers: Timers, done: Callable[[], bool]) -> None:
        """A listen of a shared queue, and the queue's next ones while they fall due before
        ``pos`` ahead of every other timer: in the order the heap would give them (boundary,
        then seq), without a heap entry each, and a batch at a time as columns. Stops when
        the unit is ``done``."""
        assert t.queued is not None and self.ears is not None
        queue, first_seq, i = t.queued
        reads = self.ears.queues.shared(queue, lambda: self._queue_reads(queue))
        end = self._queue_due(reads, first_seq, i, pos, timers)
        while i < end and not done():
            i = self._take_decodes(queue, reads, i, end)
        self.ears.queues.passed(self.member, queue, i)
        timers.queue_next(queue, first_seq, i)

    def expect_queue(self, queue: ListenQueue) -> None:
        """Its listens are ``queue``'s (shared by the units of its ears): the ears read each
        position for all of them as soon as it is heard whole (``read_as_heard``), so a unit
        that takes them a batch at a time needs no readout kept for its batch."""
        assert self.ears is not None
        reads = self.ears.queues.shared(queue, lambda: self._queue_reads(queue))
        self.ears.queues.read_as_heard(queue, reads.bounds, reads.read_block)

    def _queue_reads(self, queue: ListenQueue) -> QueueReads:
        """``QueueReads`` of ``queue`` for the units of this unit's ears (each would build the
        same: the first to ask does; ``read`` decodes for all of them)."""
        ears = self.ears
        assert ears is not None
        index, tau, cb = self.index_of, self.tau, self.cb
        if queue.units != tuple(self.units):
            raise BadInput(f"{self.name}: a listen queue of another group")
        due = queue.order  # the i-th position: the listen planned due[i]-th
        start = queue.start[due]
        names = self.words
        maps = {
            key: np.array([names.index(name) for name in words.names], dtype=np.int64)
            for key, words in (("id", self.id_words), *self.families.items())
        }
        universe = self.scenario.universe
        alternatives = set(self.families["alternative"].names)
        value = [universe.parse_alternative(n) if n in alternatives else -1 for n in names]
        n = len(self.units)
        sender = queue.sender[due].astype(np.int64)
        expected = queue.addressee[due].astype(np.int64)
        channel = queue.channel[due].astype(np.int64)
        kind = queue.kind[due].astype(np.int64)  # LISTEN_KINDS, KINDS: the same order
        schedule = self.protocol.schedule
        search = self.protocol.search
        omegas = ears.bank.omegas
        reading = ears.reading  # every decode on the ears' readout (engine/reading.py)

        def read(q: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            listen = queue.listen(int(due[q]))
            if listen.kind == "id":
                ch = index[listen.sender]
                samples = code_samples(listen.start, self.omegas[ch], cb.pulses, tau)
                w, m = reading.id_columns(samples, ch, self.id_words)
                return maps["id"][w], np.full(w.size, ch, dtype=np.int64), m
            family = "relation" if listen.kind == "relation" else "alternative"
            w, c, m = reading.among_columns(
                self.channels_of(listen), listen.start, self.families[family], search
            )
            return maps[family][w], c, m

        periods = np.array([2 * math.pi / w for w in self.omegas])  # as pulse_samples makes T
        pulse_index = np.arange(cb.pulses)[None, :]

        def read_block(q0: int, q1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            """Positions [q0, q1) for every receiver, (positions × receivers) each: the codes
            of one kind and number of candidates decoded in one vectorised step (the same
            answers as ``read`` a position at a time; one whose candidates reach past what
            has been heard is ``read`` alone, as ``decode_among_columns`` trims them)."""
            R = reading.receivers
            word = np.empty((q1 - q0, R), dtype=np.int64)
            chan = np.empty((q1 - q0, R), dtype=np.int64)
            margin = np.empty((q1 - q0, R))
            end = reading.end
            groups: dict[tuple[str, int], tuple[list[Any], list[Any], list[Any]]] = {}
            ks, cs, ts = kind[q0:q1], channel[q0:q1], start[q0:q1]
            # every ID of the block at once: pulse j at round((start + j·T)/τ), T = 2π/ω
            # (``pulse_samples``, the same float operations in the same order)
            ids = np.flatnonzero(ks == _ID)
            id_inst = samples_of(ts[ids, None] + pulse_index * periods[cs[ids], None], tau)
            heard = id_inst[:, -1] < end
            if heard.any():
                at = ids[heard]
                groups[("id", 1)] = ([at], [id_inst[heard, None, :]], [cs[at, None]])
            late = ids[~heard].tolist()
            for q in late:  # past what has been heard: read alone
                word[q], chan[q], margin[q] = read(q0 + q)
            for q in np.flatnonzero(ks != _ID).tolist():
                k, c, t0 = int(ks[q]), int(cs[q]), float(ts[q])
                family = "relation" if k == _RELATION else "alternative"
                chans, inst = code_candidates(c, float(omegas[c]), t0, cb.pulses, tau, search)
                if int(inst[:, -1].max()) >= end:
                    word[q], chan[q], margin[q] = read(q0 + q)
                    continue
                at_, insts, chs = groups.setdefault((family, inst.shape[0]), ([], [], []))
                at_.append(q)
                insts.append(inst[None])
                chs.append(chans[None])
            for (family, _), (ats, insts, chs) in groups.items():
                words = self.id_words if family == "id" else self.families[family]
                cands = np.concatenate(chs)
                at = np.concatenate(ats) if family == "id" else np.array(ats, dtype=np.int64)
                row, w, m = reading.block_columns(
                    np.concatenate(insts),
                    cands,
                    words,
                    "name" if family == "id" else "order",
                )
                word[at] = maps[family][w]
                chan[at] = np.take_along_axis(cands, row, axis=1)
                margin[at] = m
            return word, chan, margin

        turn = queue.turn[due]
        rounds = np.array([t.round for t in schedule], dtype=np.int64)
        rnd = rounds[turn]
        slot = sender * n + expected
        # a (kind, round, slot) of a payload twice: a batch could not set each slot once
        table_key = (np.where(kind == _INFLUENCE, rnd, 0) * 3 + kind) * (n * n) + slot
        unique = np.unique(table_key[kind != _ID]).size == int(np.count_nonzero(kind != _ID))
        # 4-byte columns where every value fits (4n(n−1) positions: 16 MB a column at n = 500)
        what = (kind * n + expected) * len(names)
        fits = max(n * n, int(what.max(initial=0)) + len(names), len(kind) + 1) < 2**31

        def small(col: np.ndarray) -> np.ndarray:
            return col.astype(np.int32) if fits else col

        return QueueReads(
            bounds=queue.boundaries,
            seq=queue.order,
            kind=small(kind),
            turn=small(turn),
            sender=small(sender),
            expected=small(expected),
            slot=small(slot),
            rnd=small(rnd),
            t_ready=queue.ready[due] * tau,
            is_id=kind == _ID,
            is_rel=kind == _RELATION,
            is_inf=kind == _INFLUENCE,
            n_rel=small(np.concatenate(([0], np.cumsum(kind == _RELATION)))),
            n_inf=small(np.concatenate(([0], np.cumsum(kind == _INFLUENCE)))),
            n_pay=small(np.concatenate(([0], np.cumsum(kind != _ID)))),
            unique=unique,
            what=small(what),
            channel=small(channel),
            names=names,
            alliance=np.array([nm == "alliance" for nm in names], dtype=np.int64),
            value=np.array(value, dtype=np.int64),
            id_word=names.index("id") if "id" in names else -1,
            read=read,
            read_block=read_block,
            units=tuple(self.units),
        )

    def _queue_due(
        self, reads: QueueReads, first_seq: int, i: int, pos: int, timers: Timers
    ) -> int:
        """The end of the run of queue positions from ``i`` (due) that fall due before
        ``pos`` ahead of every other timer (the heap's order: boundary, rank, seq)."""
        bounds = reads.bounds
        end = max(i + 1, int(bounds.searchsorted(pos, side="right")))
        if timers:
            top = timers.first
            q = max(i + 1, int(bounds.searchsorted(top.boundary, side="left")))
            while (
                q < end
                and bounds[q] == top.boundary
                and (0, first_seq + int(reads.seq[q])) < (top.rank, top.seq)
            ):
                q += 1
            end = min(end, q)
        return end

    def _take_decodes(self, queue: ListenQueue, reads: QueueReads, a: int, b: int) -> int:
        """Decode queue positions from ``a`` on (before ``b``) and act on them: as arrays up
        to the first that needs more than recording and learning (a code refused, a table
        completed: ``_first_event``), that one as a decode of its own. Returns the next
        position to take."""
        assert self.ears is not None
        word, chan, margin = self.ears.queues.decodes(self.member, queue, a, b, reads.read_block)
        # accepted: an ID read as "id", a payload found on its addressee's channel
        refused = np.flatnonzero(
            (word != reads.id_word) & reads.is_id[a:b]
            | (chan != reads.expected[a:b]) & ~reads.is_id[a:b]
        )
        e = self._first_event(reads, a, int(refused[0]) if refused.size else b - a)
        if e:
            self._take_batch(reads, a, a + e, word[:e], margin[:e])
        q = a + e
        if q < b:
            listen = queue.listen(int(reads.seq[q]))
            self.act(listen, reads.names[int(word[e])], float(margin[e]), int(chan[e]))
            self.settle(int(reads.bounds[q]) - 1)
            return q + 1
        return b

    def _first_event(self, reads: QueueReads, a: int, e: int) -> int:
        """The first of positions [a, a + e) (relative to a) whose decode completes a table
        of the mind (the relations, or the next round's influences, which the unit then acts
        on), else ``e``; 0 when the mind's tables are not this run's arrays."""
        mind = self.mind
        sent = mind.sent
        if self.repairs:  # a decode may be unsure (held for repair): each is taken on its own
            return 0
        if not isinstance(sent, PairTable) or sent.units != self.units or not reads.unique:
            return 0
        full = len(self.units) * (len(self.units) - 1)
        had = len(sent)
        if had + int(reads.n_rel[a + e] - reads.n_rel[a]) >= full:  # it may complete here
            rel = np.flatnonzero(reads.is_rel[a : a + e])
            k = _completes(sent, had, reads.slot[a + rel], full)
            e = min(e, int(rel[k]) if k < rel.size else e)
        if mind.decided_rounds < mind.rounds:
            nxt = mind.decided_rounds + 1
            table = mind.heard.get(nxt)
            if table is not None and not isinstance(table, PairTable):
                return 0
            had = 0 if table is None else len(table)
            if had + int(reads.n_inf[a + e] - reads.n_inf[a]) >= full:
                inf = np.flatnonzero(reads.is_inf[a : a + e] & (reads.rnd[a : a + e] == nxt))
                k = _completes(table, had, reads.slot[a + inf], full)
                e = min(e, int(inf[k]) if k < inf.size else e)
        return e

    def _take_batch(
        self, reads: QueueReads, a: int, b: int, word: np.ndarray, margin: np.ndarray
    ) -> None:
        """Positions [a, b), each accepted and completing no table: recorded (and logged)
        and learned from as arrays, as ``act`` would one by one."""
        self.decoded.extend_run(reads, a, b, word)
        if self.log.enabled:  # names as indexes into the batch's tables
            part = DecodePart(
                turn=reads.turn[a:b],
                sender=reads.sender[a:b],
                addressee=reads.expected[a:b],
                channel=reads.channel[a:b],
                kind=reads.kind[a:b],
                code=word,
                margin=margin,
                times=reads.t_ready[a:b],
                accepted=np.ones(b - a, dtype=bool),
            )
            self.log.decode_batch(part, self.log_tables)
        self._learn_batch(reads, a, b, word)

    def _learn_batch(self, reads: QueueReads, a: int, b: int, word: np.ndarray) -> None:
        """What positions [a, b) read, set into the mind's tables at once."""
        mind = self.mind
        if reads.n_rel[b] > reads.n_rel[a]:
            rel = reads.is_rel[a:b]
            sent = mind.sent
            assert isinstance(sent, PairTable)
            sent.set_slots(reads.slot[a:b][rel], reads.alliance[word[rel]], unique=True)
        if reads.n_inf[b] > reads.n_inf[a]:
            inf = reads.is_inf[a:b]
            rnd = reads.rnd[a:b]
            first, last = int(reads.rnd[a + int(np.argmax(inf))]), int(rnd[inf].max())
            for r in range(first, last + 1):
                mine = inf & (rnd == r) if first != last else inf
                table = mind.heard_in(r)
                assert isinstance(table, PairTable)
                table.set_slots(reads.slot[a:b][mine], reads.value[word[mine]], unique=True)
