"""The autonomous unit: transmitter + receiver + protocol + RGT reasoning + decision policy.

One unit lives in the SimPy world (``rgtbus.engine.sim.World``) at its own samples: the ears'
process wakes it (a plain call, at the exact simulated time) at its resonators' spike it awaits
and at its own timers; it runs the pure protocol machine on what it heard,
decodes at the samples the protocol names, reasons on what it decoded, and transmits what the
protocol plans (each transmission a SimPy process that waits for its time). It shares no Python
object with the other units: its knowledge comes only from the medium. Once it has decided, or
failed, it listens no more. Unless a live view waits for its records, a unit that awaits no
spike takes its decodes a batch at a time (``BATCH_SECONDS``; docs/engine.md), those of a
shared queue as columns: the same decodes, fewer wakes, no Python call per decode.
"""

from __future__ import annotations

import dataclasses
import heapq
import itertools
from array import array
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple, cast

import numpy as np
import simpy

from rgtbus.bus.base import Pulses
from rgtbus.bus.payload import NEVER
from rgtbus.engine.hearing import Ears
from rgtbus.engine.listener import Heard, Listener
from rgtbus.engine.spike_log import SharedSpikes
from rgtbus.mind import decision_fields, intents, mind_of, result_fields, steering_reason
from rgtbus.pairs import PairTable
from rgtbus.protocol import (
    NOTHING,
    PHASES,
    Actions,
    Listen,
    ListenQueue,
    ProtocolState,
    RepairBlock,
    Send,
    choice_sample,
    code_samples,
)
from rgtbus.repair import RepairBook, family_of
from rgtbus.scenario import Scenario
from rgtbus.signal.channel import BurstStates, burst_rng, noise_rng
from rgtbus.signal.decoder import (
    Readout,
    WordSet,
    decode_among_columns,
    nearer_than_silence,
    nearest_columns,
)
from rgtbus.signal.resonator import clean_first_spike
from rgtbus.summary import decision_row, not_decomposable_text
from rgtbus.telemetry import Recorder, records
from rgtbus.timebase import ns

if TYPE_CHECKING:
    from rgtbus.rgt.control import SteeringChoice

SPIKE_BLOCK_SECONDS = 1.0  # a unit's spikes of this much time make one /rx/spike record
KEEP_SECONDS = 30.0  # readout history kept for decoding (longest code + reaction + search)
AWAKE = -1.0  # the transmitter is not asleep: it reads the next send before it sleeps
BATCH_SECONDS = 4.0  # a unit's decodes of this much time wait for one wake (no live view)
# a unit's decodes of each span of this much time go to the log as one /rx/decodes record (no
# live view), whatever its wakes: a serial 10-unit run made a record of one decode a wake
DECODE_BLOCK_SECONDS = 60.0


def _named_column(col: Any, tables: records.DecodeTables, j: int) -> list[Any]:
    """Column ``j`` of a part of decodes held as indexes (``_take_batch``), as names (a part
    joined with single decodes); any other column as a list."""
    table = records.NAMED_COLUMNS.get(records.DECODE_COLUMNS[j])
    if table is None:
        return col if type(col) is list else cast(list[Any], col.tolist())
    names = tables[records.DECODE_TABLES.index(table)]
    return [names[i] for i in col.tolist()]


def _indexed_part(part: Sequence[Any], tables: records.DecodeTables) -> list[Any] | None:
    """A part of single decodes (columns of names, ``_rows_to_part``) as the arrays of a batch
    with ``tables`` (its names as indexes into them), or None when a name is in none of them:
    a block of 50 units' batches that held one decode of its own was otherwise written (and
    copied at every wake until its block ended) as names."""
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
    return out


DecodedRow = tuple[int, str, str, str]  # (turn, kind, addressee, code): what the summary needs


class DecodeColumns:
    """A unit's decodes as columns: the turn of each (4 bytes) and which (kind, addressee,
    code) it read (4 bytes, an index into the few distinct ones), not a Python object per
    decode: a run of n units makes 4n²(n−1) of them (3.96 M at n = 100). Iterates as
    ``DecodedRow`` tuples, in order; ``tolist()`` for JSON."""

    __slots__ = ("_rows", "_seen", "_turns", "_what")

    def __init__(self) -> None:
        self._turns = array("i")
        self._what = array("I")
        self._rows: list[tuple[str, str, str]] = []
        self._seen: dict[tuple[str, str, str], int] = {}

    def append(self, turn: int, kind: str, addressee: str, code: str) -> None:
        key = (kind, addressee, code)
        i = self._seen.get(key)
        if i is None:
            i = self._seen[key] = len(self._rows)
            self._rows.append(key)
        self._turns.append(turn)
        self._what.append(i)

    def index(self, key: tuple[str, str, str]) -> int:
        """The index of a (kind, addressee, code) among the distinct ones (made on first use)."""
        i = self._seen.get(key)
        if i is None:
            i = self._seen[key] = len(self._rows)
            self._rows.append(key)
        return i

    def extend_index(self, turns: np.ndarray, what: np.ndarray) -> None:
        """A batch of decodes at once: their turns, and each one's ``index``."""
        self._turns.frombytes(np.asarray(turns, dtype=np.intc).tobytes())
        self._what.frombytes(np.asarray(what, dtype=np.uintc).tobytes())

    def __len__(self) -> int:
        return len(self._turns)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, list[tuple[str, str, str]]]:
        """(each decode's turn, the index of its (kind, addressee, code) in the third),
        as arrays over the columns' own memory (``rgtbus.summary.wrong_decodes``)."""
        return (
            np.frombuffer(self._turns, dtype=np.intc),
            np.frombuffer(self._what, dtype=np.uintc),
            self._rows,
        )

    def __iter__(self) -> Iterator[DecodedRow]:
        rows = self._rows
        for turn, i in zip(self._turns, self._what, strict=True):
            yield (turn, *rows[i])

    def tolist(self) -> list[list[Any]]:
        return [list(row) for row in self]


# a repair block's steps, each a timer: choose the requests, choose the repeats, read the copies
_REPAIR_STEPS = ("request", "repeat", "copies")
_LATE_TIMERS = frozenset(("choose", *_REPAIR_STEPS))  # after the decodes due at their boundary


def _send_text(send: Send) -> str:
    """The log line of a send going on air."""
    if send.kind == "request":
        return (
            f"{send.sender}: asks {send.addressee} for turn {send.turn} again (repair block "
            f"{send.block}) on {send.channel}'s frequency"
        )
    what = "ID" if send.kind == "id" else send.code
    again = f" again (repair block {send.block})" if send.kind == "repeat" else ""
    return f"{send.sender} -> {send.addressee}: {what}{again} on {send.channel}'s frequency"


class _Timer(NamedTuple):
    """A unit's timer. A plain tuple, so the heap orders timers in C: by boundary, then rank,
    then seq (unique, so the fields after it are never compared)."""

    boundary: int  # act once every sample before this one has been heard
    rank: int  # at one boundary: decodes and checks (0) before choices (1)
    seq: int
    at: int  # the sample it belongs to (its time)
    kind: str  # "listen" | "deadline" | "limit" | "choose" | "request" | "repeat" | "copies"
    listen: Listen | None = None
    # a listen from a shared queue: (queue, its first seq, its place in the queue); when it
    # is taken the next of the queue goes on the heap (one entry per queue, not per listen)
    queued: tuple[ListenQueue, int, int] | None = None


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


_ID, _RELATION, _INFLUENCE = 0, 1, 2  # the kinds of a listen, as a column
_KINDS = ("id", "relation", "influence")


@dataclass(frozen=True, eq=False)
class _QueueReads:
    """A shared listen queue as columns over its positions (the i-th to fall due), worked out
    once for every unit of a process (``Ears.shared``): what a unit needs to take a batch of
    its decodes as arrays (``AutonomousUnit._take_decodes``), and ``read``, which decodes one
    position for every receiver at once (``Ears.queue_decodes``)."""

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
    unique: bool  # no pair of one table twice (a batch sets each slot once)
    what: np.ndarray  # (kind · units + addressee) · len(names): + the word, a decoded row
    channel: np.ndarray  # unit index of the channel it is carried on (an ID: its sender's)
    names: tuple[str, ...]  # every word name a decode can read
    alliance: np.ndarray  # per name: 1 if "alliance"
    value: np.ndarray  # per name: its alternative (-1: not one)
    id_word: int  # the name index of "id"
    read: Callable[[int], tuple[np.ndarray, np.ndarray, np.ndarray]]


@dataclass
class AutonomousUnit:
    name: str
    scenario: Scenario
    recorder: Recorder
    traces: bool = False
    # state
    finished: bool = False
    failure: str | None = None
    done: bool = False
    done_at: int = 0
    # every decode, as the summary reads it (the margin and time are in the log's /rx/decodes)
    decoded: DecodeColumns = field(default_factory=DecodeColumns)
    sent: list[Send] = field(default_factory=list)
    # this unit's own decision after each influence round it decided (``decision_row``)
    decisions: list[records.DecisionRow] = field(default_factory=list)

    def __post_init__(self) -> None:
        sc = self.scenario
        self.units = sc.units
        self.tau = sc.timing.tau
        self.L = sc.timing.window_samples
        self.omegas = [sc.frequencies[u] for u in self.units]
        self.cb = sc.codebook
        self._id_words = WordSet.of(self.cb.distinct_words())
        self._families = {f: WordSet.of(self.cb.family(f)) for f in ("relation", "alternative")}
        self._gains = sc.channel.gain_row(sc.units, self.name)  # what it hears of each sender
        self._timed = sc.channel.timed  # pulses land off their samples (delays, clocks)
        # by channel (_attend): the ID as its link delivers it, alone and as a word set
        self._attention_words: dict[int, tuple[WordSet, tuple[float, ...]]] = {}
        self._index = {u: i for i, u in enumerate(self.units)}
        self._channel_sets: dict[tuple[str, ...], tuple[int, ...]] = {}
        # spikes go to the log in blocks of this many samples (a fixed span of time, not the
        # engine's window: what a record holds never depends on how the run was stepped)
        self.block = max(1, round(SPIKE_BLOCK_SECONDS / self.tau))
        self._alternatives: dict[str, int] = {}  # decoded names, parsed once
        self._aw_named: tuple[str, int, int] | None = None
        self._aw: tuple[int, int, int] = (0, 0, 0)
        self._asked: tuple[int, int, int] | None = None  # what the last ask awaited
        self.protocol = ProtocolState(
            self.name,
            self.units,
            dict(sc.frequencies),
            self.tau,
            pulses=self.cb.pulses,
            start=sc.timing.start,
            reaction_delay=sc.timing.reaction_delay,
            guard=sc.timing.guard,
            search=sc.timing.search,
            anchor=sc.timing.anchor,
            kind=sc.schedule,
            influence_rounds=sc.influence_rounds,
            repair_rounds=sc.repairs_per_phase,
            attention=sc.timing.attention,
            read_margin=1 if sc.channel.timed else 0,
            expect_spike=self._expected_spike,
        )
        self.mind = mind_of(sc, self.name)
        self.goals = sc.goals_of(self.name)
        # goal-driven influence sends: timed by the protocol, their code chosen at their
        # choice sample (``choice_sample``); nothing goes out before (the promise says so)
        self._pending: dict[int, Send] = {}
        self._pending_first = NEVER
        self.relation_choice, self.influence_choice = intents(sc, self.name)
        self.limit = round(sc.timing.max_seconds / self.tau)  # listen to samples before it
        self.readout: Readout | None = None  # the ears give it at the start
        self._timers: list[_Timer] = []
        self._batches = False  # its decodes may wait for one wake a batch (set at begin)
        # a decoded row's index in ``decoded``, by its integer code (``_take_batch``)
        self._what_of = np.zeros(0, dtype=np.int64)
        # blocks of its spikes the ears handed on before a batch's wake said whether it was
        # done before them (``spikes``): (samples, index, fired, end) each
        self._held: list[SharedSpikes] = []  # blocks of spikes handed, until its wake
        self._batch_span = max(1, round(BATCH_SECONDS / self.tau))
        self._others: list[int] = []  # boundaries of its timers that are not listens
        self._seq = 0  # the next timer's seq
        self._deadline: _Timer | None = None
        self._outbox: list[tuple[int, float]] = []
        # sends to log on air (``_on_air``): (time, seq, pulse index or -1, send, word, and
        # once on air its pulses' message and ω)
        self._air: list[
            tuple[float, int, int, Send, tuple[float, ...], tuple[Any, float] | None]
        ] = []
        self._air_seq = 0
        self._air_until = AWAKE  # when the transmitter sleeps until (AWAKE: it will look)
        self._transmitter: simpy.Process | None = None
        self._on_time = True  # pulses logged by the transmitter (``begin``)
        # the decodes held for the log (/rx/decodes, ``_flush_decodes``): batches as parts of
        # the nine columns (arrays, made lists once, at the flush), single decodes as rows
        # until the next part; the decode block of the first held (-1: none held); whether
        # they wait for their block's end (no live view watches)
        self._decode_parts: list[Sequence[Any]] = []
        self._decode_tables: list[records.DecodeTables | None] = []  # a part's (None: names)
        self._decode_rows: list[tuple[Any, ...]] = []
        self._decode_block = max(1, round(DECODE_BLOCK_SECONDS / self.tau))
        self._held_block = -1
        self._holds = True
        self.env: simpy.Environment | None = None
        self.ears: Ears | None = None
        self.index = 0
        # [protocol] repair = "arq" (docs/protocol.md, "Repair"): its book of what it holds
        self._arq = sc.repairs_per_phase
        self.repair = RepairBook(self.cb, sc.repair_margin, self._arq) if self._arq else None
        self._repair_of: dict[int, RepairBlock] = {}  # a repair timer's seq -> its block
        self._repair_first: list[tuple[int, int]] = []  # (first sample it may send, seq)
        self._repair_left = 0  # repair timers not yet run: it is not finished before
        self._payload_code: dict[int, str] = {}  # turn -> the payload code it sent

    # -- the world's interface ---------------------------------------------------------------

    def listener(self) -> Listener:
        """This unit's receiver: its link gains, its noise (its own seeded generator), its
        readout, its traces."""
        sc = self.scenario
        return Listener(
            name=self.name,
            gains=sc.channel.gain_row(self.units, self.name),
            noise=sc.channel.noise,
            # numpy.random costs 8 ms to import: a noise-free run never draws
            rng=noise_rng(sc.seed, self.units.index(self.name)) if sc.channel.noisy else None,
            bursts=None
            if sc.channel.burst is None
            else BurstStates(
                sc.channel.burst, self.tau, burst_rng(sc.seed, self.units.index(self.name))
            ),
            keep=round(KEEP_SECONDS / self.tau),
            arrival=sc.channel.arrivals(self.units, self.name, self.tau)
            if sc.channel.timed
            else None,
            trace=self._trace if self.traces else None,
            spike_log=self if self.recorder.enabled else None,  # only a log needs every spike
            # else its plans never wait for a spike
            awaits=self.protocol.anchor == "spike" and not self.protocol.confirmed,
        )

    def begin(self, env: simpy.Environment, ears: Ears, index: int) -> None:
        self.env, self.ears, self.index = env, ears, index
        # its pulses go to the log as the run's clock reaches each (a transmitter: a SimPy
        # process) only where someone may look on while it runs: a live view, a paced run;
        # else as they are planned, each at its own log time (as the medium is): the same
        # records, and the transmitter's wakes were a quarter of a 50-unit run's log cost
        self._on_time = getattr(self.recorder, "live", None) is not None or isinstance(
            env, simpy.rt.RealtimeEnvironment
        )
        self._batches = self.batching()
        self.readout = ears.readout_of(index)
        self._add(self.limit, self.limit - 1, "limit")
        self._apply(self.protocol.begin(self.relation_choice, self.influence_choice))
        self._ask()

    def batching(self) -> bool:
        """Whether this unit may take its decodes a batch at a wake (``_batch_boundary``):
        their records then leave at the wake, each at its own log time, up to
        ``BATCH_SECONDS`` behind the run's clock, and the blocks of spikes the ears hand on
        meanwhile wait for the wake too (``spikes``). Not with traces, nor when a live view
        must get every record as the clock reaches it: a live sink on its recorder (``run
        --live``; the telemetry a unit process publishes while ``rgtbus watch`` subscribes
        to it: ``LiveSink.watched``). Asked at every wake, with no block held: a watcher that
        comes mid-run gets this unit's records on time from its next wake on, one that leaves
        lets it batch again (a unit process that batched nothing woke 20x as often)."""
        if self.traces or self.protocol.confirmed:
            return False
        return not self.watched()

    def watched(self) -> bool:
        """Whether a live view may be looking (``LiveSink.watched``), so this unit's records
        should leave as the run's clock reaches them."""
        live = getattr(self.recorder, "live", None)
        if live is None:
            return False
        watched = getattr(live, "watched", None)
        return watched is None or watched()

    def take_outbox(self) -> Pulses:
        """The pulses planned since the last call (sample order; one sample's magnitudes in
        the order they were planned)."""
        box, self._outbox = self._outbox, []
        if not box:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        box.sort(key=lambda p: p[0])  # stable: planning order within a sample
        return np.array([p[0] for p in box], dtype=np.int64), np.array([p[1] for p in box])

    def promise(self, horizon: int) -> int:
        """Nothing unplanned from this unit before this sample, given no spike it reacts to
        before ``horizon``."""
        if self.done:
            return NEVER
        first = self._repair_first[0][0] if self._repair_first else NEVER
        return min(self.protocol.send_bound(horizon), self._pending_first, first)

    def awaited(self) -> tuple[int, int, int] | None:
        """The spike this unit's next plans wait for: (channel index, earliest sample, latest
        sample)."""
        aw = None if self.done else self.protocol.awaited()
        if aw is None:
            return None
        if aw is not self._aw_named:  # the chain moved on: name its channel by index once
            self._aw_named, self._aw = aw, (self._index[aw[0]], aw[1], aw[2])
        return self._aw

    # -- living: receive -> protocol -> decode -> reason -> send ------------------------------

    def _ask(self) -> None:
        """Ask the ears for the next thing this unit must act on: its first timer's boundary,
        or the spike it awaits, whichever comes first (``_woken`` is called then)."""
        assert self.ears is not None
        if self.done:  # its log holds its spikes before the sample after the one it was done at
            stop = self.done_at + 1
            self._release_spikes(stop)
            self.ears.stop(self.index, stop)  # and hands it what it kept for its log
            return
        if self._held:  # not done before the samples of this wake: the blocks are its
            self._release_spikes(None)
        self._batches = self.batching()  # none held now: it may change (a watcher came)
        self._holds = not self.watched()
        t = self._timers[0]
        aw = self._asked = self.awaited()
        if aw is None and self._batches:
            boundary = self._batch_boundary(t.boundary)
            self.ears.listen(self.index, boundary, boundary - 1, self._woken)
            return
        self.ears.listen(
            self.index,
            t.boundary,
            t.at,
            self._woken,
            None if aw is None else aw[0],
            0 if aw is None else aw[1],
        )

    def _batch_boundary(self, first: int) -> int:
        """How far this unit may let the ears go before it decodes, when nothing it hears can
        change its plans (no spike awaited) and no live view waits for its records
        (``batching``): its decodes up to the next timer of another kind (a deadline, a goal's
        choice, the limit), at most ``BATCH_SECONDS`` past the first, all at one wake. Each
        decode is the same (the readout keeps ``KEEP_SECONDS``; every result carries its own
        time), but a large run wakes each unit every few seconds, not once a decode (issue
        23). What they log leaves at the wake with each record's own time, in time order for
        this unit (a log cut short is complete before a unit's last record:
        ``Replay.units_until_ns``)."""
        others = self._others
        while others and others[0] < first:  # timers of the past (taken, or replaced)
            heapq.heappop(others)
        far = first + self._batch_span
        if others and others[0] < far:
            far = others[0]
        return max(first, far)

    def _woken(self, heard: Heard) -> None:
        """Receive -> protocol -> decode -> reason -> send, at the sample the ears woke it."""
        assert self.ears is not None
        aw = self._asked
        for k, channels in heard.spikes:  # the spike it awaited (the ears log every spike)
            if aw is not None and aw[0] in channels and k >= aw[1]:
                self._apply(self.protocol.on_spike(self.units[aw[0]], k))
                aw = self.awaited()
        pos = self.ears.pos
        # every timer whose samples have all been heard is due (its time, the boundary's
        # last sample, is now or was passed by the spike that woke this unit)
        timers = self._timers
        while not self.done and timers and timers[0][0] <= pos:
            t = heapq.heappop(timers)
            if t.queued is None:
                self._on_timer(t)
            else:
                self._take_queue(t, pos)
        if not self._holds:
            self._flush_decodes()
        elif 0 <= self._held_block < pos // self._decode_block:  # past a block of decodes
            self._flush_decodes(before=pos)
        self._ask()

    def _take_queue(self, t: _Timer, pos: int) -> None:
        """A listen of a shared queue, and the queue's next ones while they fall due before
        ``pos`` ahead of every other timer: in the order the heap would give them (boundary,
        then seq), without a heap entry each, and a batch at a time as columns
        (``_take_decodes``)."""
        assert t.queued is not None and self.ears is not None
        queue, first_seq, i = t.queued
        reads = self.ears.queues.shared(queue, lambda: self._queue_reads(queue))
        end = self._queue_due(reads, first_seq, i, pos)
        while i < end and not self.done:
            i = self._take_decodes(queue, reads, i, end)
        self._queue_next(queue, first_seq, i)

    def _queue_reads(self, queue: ListenQueue) -> _QueueReads:
        """``_QueueReads`` of ``queue`` for the units of this unit's ears (each would build the
        same: the first to ask does, ``Ears.shared``; ``read`` decodes for all of them)."""
        ears = self.ears
        assert ears is not None
        index, tau, cb = self._index, self.tau, self.cb
        listens = [queue.listens[i] for i in queue.order]
        names: list[str] = []
        maps = {}
        for key, words in (("id", self._id_words), *self._families.items()):
            ix = []
            for name in words.names:
                if name not in names:
                    names.append(name)
                ix.append(names.index(name))
            maps[key] = np.array(ix, dtype=np.int64)
        universe = self.scenario.universe
        alternatives = set(self._families["alternative"].names)
        value = [universe.parse_alternative(n) if n in alternatives else -1 for n in names]
        n = len(self.units)
        sender = np.array([index[li.sender] for li in listens], dtype=np.int64)
        expected = np.array([index[li.expected_addressee] for li in listens], dtype=np.int64)
        schedule = self.protocol.schedule
        search = self.protocol.search
        omegas = ears.bank.omegas

        def read(q: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            listen = listens[q]
            if listen.kind == "id":
                ch = index[listen.sender]
                samples = code_samples(listen.start, self.omegas[ch], cb.pulses, tau)
                w, m = nearest_columns(ears.readout, samples, ch, self._id_words)
                return maps["id"][w], np.full(w.size, ch, dtype=np.int64), m
            family = "relation" if listen.kind == "relation" else "alternative"
            pairs = tuple((c, float(omegas[c])) for c in self._channels_of(listen))
            w, c, m = decode_among_columns(
                ears.readout, pairs, listen.start, self._families[family], tau=tau, search=search
            )
            return maps[family][w], c, m

        kind = np.array([_KINDS.index(li.kind) for li in listens], dtype=np.int64)
        rnd = np.array([schedule[li.turn].round for li in listens], dtype=np.int64)
        slot = sender * n + expected
        payload = kind != _ID
        tables = np.stack([kind, np.where(kind == _INFLUENCE, rnd, 0), slot])[:, payload]
        return _QueueReads(
            bounds=np.array(queue.boundaries, dtype=np.int64),
            seq=np.array(queue.order, dtype=np.int64),
            kind=kind,
            turn=np.array([li.turn for li in listens], dtype=np.int64),
            sender=sender,
            expected=expected,
            slot=slot,
            rnd=rnd,
            t_ready=np.array([li.ready_sample * tau for li in listens]),
            is_id=kind == _ID,
            is_rel=kind == _RELATION,
            is_inf=kind == _INFLUENCE,
            n_rel=np.concatenate(([0], np.cumsum(kind == _RELATION))),
            n_inf=np.concatenate(([0], np.cumsum(kind == _INFLUENCE))),
            unique=np.unique(tables, axis=1).shape[1] == tables.shape[1],
            what=(kind * n + expected) * len(names),
            channel=np.where(kind == _ID, sender, expected),
            names=tuple(names),
            alliance=np.array([nm == "alliance" for nm in names], dtype=np.int64),
            value=np.array(value, dtype=np.int64),
            id_word=names.index("id") if "id" in names else -1,
            read=read,
        )

    def _queue_due(self, reads: _QueueReads, first_seq: int, i: int, pos: int) -> int:
        """The end of the run of queue positions from ``i`` (due) that fall due before
        ``pos`` ahead of every other timer (the heap's order: boundary, rank, seq)."""
        bounds = reads.bounds
        end = max(i + 1, int(bounds.searchsorted(pos, side="right")))
        if self._timers:
            top = self._timers[0]
            q = max(i + 1, int(bounds.searchsorted(top.boundary, side="left")))
            while (
                q < end
                and bounds[q] == top.boundary
                and (0, first_seq + int(reads.seq[q])) < (top.rank, top.seq)
            ):
                q += 1
            end = min(end, q)
        return end

    def _take_decodes(self, queue: ListenQueue, reads: _QueueReads, a: int, b: int) -> int:
        """Decode queue positions from ``a`` on (before ``b``) and act on them: as arrays up
        to the first that needs more than recording and learning (a code refused, a table
        completed: ``_first_event``), that one as a decode of its own (``_act``). Returns the
        next position to take."""
        assert self.ears is not None
        word, chan, margin = self.ears.queues.decodes(self.index, queue, a, b, reads.read)
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
            listen = queue.listens[int(reads.seq[q])]
            self._act(listen, reads.names[int(word[e])], float(margin[e]), int(chan[e]))
            self._settle(int(reads.bounds[q]) - 1)
            return q + 1
        return b

    def _first_event(self, reads: _QueueReads, a: int, e: int) -> int:
        """The first of positions [a, a + e) (relative to a) whose decode completes a table
        of the mind (the relations, or the next round's influences, which the unit then acts
        on), else ``e``; 0 when the mind's tables are not this run's arrays."""
        mind = self.mind
        sent = mind.sent
        if self._arq:  # a decode may be unsure (held for repair): each is taken on its own
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
        self, reads: _QueueReads, a: int, b: int, word: np.ndarray, margin: np.ndarray
    ) -> None:
        """Positions [a, b), each accepted and completing no table: recorded (and logged)
        and learned from as arrays, as ``_act`` would one by one."""
        names = reads.names
        # (kind, addressee, code) as one integer, and as the unit's index of it
        code = reads.what[a:b] + word
        if self._what_of.size != len(_KINDS) * len(self.units) * len(names):
            self._what_of = np.full(len(_KINDS) * len(self.units) * len(names), -1)
        what = self._what_of[code]
        if (what < 0).any():
            for c in np.unique(code[what < 0]).tolist():
                k, w = divmod(c, len(names))
                kind, addressee = divmod(k, len(self.units))
                key = (_KINDS[kind], self.units[addressee], names[w])
                self._what_of[c] = self.decoded.index(key)
            what = self._what_of[code]
        self.decoded.extend_index(reads.turn[a:b], what)
        if self.recorder.enabled:  # names as indexes into the batch's tables
            self._rows_to_part()
            if self._held_block < 0:
                self._held_block = self._block_of(reads.t_ready[a])
            self._decode_parts.append(
                (
                    reads.turn[a:b],
                    reads.sender[a:b],
                    reads.expected[a:b],
                    reads.channel[a:b],
                    reads.kind[a:b],
                    word,
                    margin,
                    reads.t_ready[a:b],
                    np.ones(b - a, dtype=bool),
                )
            )
            self._decode_tables.append((self.units, _KINDS, names))
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

    # -- its log of spikes (the ears' SpikeLog): one record per block, not per sample --------

    def spikes(self, samples: np.ndarray, index: np.ndarray, fired: np.ndarray, end: int) -> None:
        """One block's spikes of this unit's resonators (``SpikeLog``), as one ``/rx/spike``
        record of columns (each spike's sample and channel, as arrays the encoder writes
        whole: no Python object per spike) at the block's end (or where the unit was done,
        for its last block: a log cut there is complete before this time, the verifier's
        bound) as its log time. Written now, ahead of the run's clock, so a live view gets it
        on time; a unit that batches its decodes holds it until its wake says whether it was
        done before the block (``_release_spikes``): the ears walk on past a unit that does
        not yet know it is done."""
        if self._batches and not self.done:
            self._held.append(SharedSpikes(samples, index, fired, end, [self.index], [self.name]))
        else:
            self._log_spikes(self.name, samples, index, fired, end)

    def shared_spikes(self, block: SharedSpikes) -> None:
        """A block of spikes this unit heard alike with others of its process: held until
        its wake, as its own blocks are, then settled (``_release_spikes``)."""
        if self._batches and not self.done:
            self._held.append(block)
        else:
            self._settle_spikes(block, None)

    def keeps_now(self) -> bool:
        """Whether a block handed now is kept at once (``SpikeLog.keeps_now``): this unit
        takes no batch (or is done), so ``shared_spikes`` would settle it as kept."""
        return not self._batches or self.done

    def shared_kept(
        self, names: list[str], samples: np.ndarray, index: np.ndarray, fired: np.ndarray, end: int
    ) -> None:
        """A block that ``names`` heard alike and all keep (``SpikeLog.shared_kept``)."""
        self._log_spikes(names, samples, index, fired, end)

    def _release_spikes(self, stop: int | None) -> None:
        """Log the blocks held for this wake: all of them, or (``stop``: done before that
        sample) their spikes before ``stop``, the last block ending there."""
        held, self._held = self._held, []
        for block in held:
            self._settle_spikes(block, stop)

    def _settle_spikes(self, block: SharedSpikes, stop: int | None) -> None:
        """Keep a block (its units' record is written once every unit of it has settled), or,
        done before its end (``stop``), leave it and log its spikes before ``stop`` alone."""
        samples, index, fired, end = block.samples, block.index, block.fired, block.end
        kept = stop is None or end <= stop
        units = block.settle(self.index, kept)
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
        self.recorder.write("/rx/spike", record, ns(end * self.tau))

    def end_log(self) -> None:
        """The run is over for this unit (done, or the world stopped): what it and its ears
        still keep for its log is written."""
        self._flush_decodes()
        self._release_spikes(None)
        if self.ears is not None:
            self.ears.end_spikes(self.index)

    def _on_timer(self, t: _Timer) -> None:
        """A timer of its own (a shared queue's listens are ``_take_queue``'s)."""
        if t.kind == "listen":
            assert t.listen is not None
            self._decode(t.listen)
        elif t.kind == "deadline":
            self._deadline = None
            if self.protocol.confirmed:
                self._attend(t.at)
            else:
                err = self.protocol.check_deadline(t.at + 1)
                if err:
                    self._fail(err, t.at)
        elif t.kind == "choose":
            self._choose(t.seq, t.at)
        elif t.kind in _REPAIR_STEPS:
            self._repair_step(t)
        elif t.kind == "limit":
            self._fail(
                f"{self.name}: not finished after {self.scenario.timing.max_seconds:g} s of "
                "simulated time (timing.max_seconds)",
                t.at,
            )
        self._settle(t.at)

    def _settle(self, at: int) -> None:
        """Done once it has decided or failed, at the sample of what made it so."""
        if (self.finished or self.failure) and not self.done:
            self.done = True
            self.done_at = at

    def _fail(self, message: str, at: int) -> None:
        if self.failure is None:
            self.failure = message
            self.recorder.log("error", message, ns(at * self.tau), name=self.name)
            # what the protocol planned still goes out; an unchosen code is the policy's
            for seq in sorted(self._pending):
                self._choose(seq, at, why="it failed before its choice")
            self._repair_first = []  # a unit that failed asks for nothing and repeats nothing

    def _add(
        self,
        boundary: int,
        at: int,
        kind: str,
        listen: Listen | None = None,
    ) -> _Timer:
        timer = _Timer(boundary, int(kind in _LATE_TIMERS), self._seq, at, kind, listen)
        self._seq += 1
        heapq.heappush(self._timers, timer)
        if kind != "listen":
            heapq.heappush(self._others, boundary)
        return timer

    def _queue_next(self, queue: ListenQueue, first_seq: int, i: int) -> None:
        """The i-th listen of ``queue`` to fall due goes on the heap, with the seq it would
        have had as a timer of its own (so timers keep their order)."""
        if i < len(queue.order):
            n = queue.order[i]
            b = queue.boundaries[i]
            listen = queue.listens[n]
            heapq.heappush(
                self._timers,
                _Timer(b, 0, first_seq + n, b - 1, "listen", listen, (queue, first_seq, i)),
            )

    def _apply(self, acts: Actions) -> None:
        if acts is NOTHING:
            return
        for send in acts.sends:
            self._transmit(send)
        if acts.queue is not None:  # shared: a cursor into it, not a timer per listen
            self._queue_next(acts.queue, self._seq, 0)
            self._seq += len(acts.queue.order)
        else:
            for listen in acts.listens:
                self._add(listen.ready_sample + 1, listen.ready_sample, "listen", listen)
        assert self.ears is not None
        for q in acts.quench:
            self.ears.quench_at(self.index, q)
        if acts.deadline is not None:
            if self._deadline is not None:  # one deadline at a time: the current turn's
                self._timers.remove(self._deadline)
                heapq.heapify(self._timers)
            d = acts.deadline
            self._deadline = self._add(d + 1, d, "deadline")
        for block in acts.repairs:
            self._plan_repair(block)

    # -- transmitting ------------------------------------------------------------------------

    def word(self, send: Send) -> tuple[float, ...]:
        if send.kind in ("id", "request"):
            return self.cb.id_word
        if send.code in self.cb.relations:
            return self.cb.relations[send.code]
        return self.cb.alternatives[send.code]

    def _transmit(self, send: Send) -> None:
        """Plan a transmission: its pulses go out to the bus now (ahead of time), and a SimPy
        process puts each on the medium's log at its sample. An influence on a goal's target
        waits for its choice sample (``_choose``)."""
        turn = self.protocol.schedule[send.turn]
        if send.kind == "payload" and turn.phase == PHASES[1] and send.addressee in self.goals:
            b = choice_sample(send.start, self.scenario.timing.reaction_delay, self.tau)
            timer = self._add(b, b - 1, "choose")  # its seq names the send
            self._pending[timer.seq] = send
            self._pending_first = min(self._pending_first, send.samples[0])
            return
        self._emit(send)

    def _choose(self, seq: int, at: int, why: str | None = None) -> None:
        """Pending send ``seq``, a goal-driven influence: its code by the inverse task on what
        this unit decoded before sample ``at + 1`` (or its policy's, with the reason ``why``),
        logged on /unit/goal."""
        send = self._pending.pop(seq, None)
        if send is None:  # sent already, with its policy's code, when the unit failed
            return
        self._pending_first = min((s.samples[0] for s in self._pending.values()), default=NEVER)
        rnd = self.protocol.schedule[send.turn].round
        goal = self.goals[send.addressee]
        got: SteeringChoice | str = why or self.mind.steer(goal, rnd)
        u = self.scenario.universe
        value = None if isinstance(got, str) else got.value
        code = send.code if value is None else u.format(value)
        reason = steering_reason(got, goal, u)
        t = at * self.tau
        if self.recorder.enabled:
            heard, predicted = self.mind.steering_inputs(goal.target, rnd)
            steered = None if isinstance(got, str) else got
            record = records.goal(
                self.name, t, rnd, send.turn, goal.target,
                want=[u.to_list(goal.lo), u.to_list(goal.hi)],
                mode=goal.mode,
                heard={k: u.to_list(v) for k, v in sorted(heard.items())},
                predicted={k: u.to_list(v) for k, v in sorted(predicted.items())},
                rule=steered.rule if steered else "none",
                solutions=steered.solutions if steered else None,
                reached=steered.reached if steered else None,
                of=steered.of if steered else None,
                value=None if value is None else u.to_list(value),
                sent=u.to_list(u.parse_alternative(code)),
                reason=reason,
            )  # fmt: skip
            self._write("/unit/goal", record, ns(t))
            level = "info" if value is not None else "warning"
            self.recorder.log(level, f"{self.name}: goal {reason}", ns(t), name=self.name)
        self._emit(dataclasses.replace(send, code=code))

    def _emit(self, send: Send) -> None:
        word = self.word(send)  # the codebook's own tuple: shared, not a list a send
        self._outbox.extend((k, float(m)) for k, m in zip(send.samples, word, strict=True))
        if not send.block:  # a repair's sends are counted (``RepairBook``), not listed
            self.sent.append(send)
            if send.kind == "payload":
                self._payload_code[send.turn] = send.code
        assert self.env is not None
        if self.recorder.enabled and not self._on_time:
            self._log_send(send, word)
        elif self.recorder.enabled:  # its transmitter logs the pulses at their times
            at = min(send.start, send.samples[0] * self.tau)
            heapq.heappush(self._air, (at, self._air_seq, -1, send, word, None))
            self._air_seq += 1
            if self._transmitter is None:
                self._transmitter = self.env.process(self._on_air())
            elif at < self._air_until:  # it sleeps until later: wake it for this one
                self._transmitter.interrupt()

    def _log_send(self, send: Send, word: tuple[float, ...]) -> None:
        """A send's log line and its pulses, written now, each at its own log time."""
        ref = self._log_send_line(send)
        for j in range(len(send.samples)):
            self._log_pulse(send, word, j, ref)

    def _log_send_line(self, send: Send) -> tuple[records.MessageRef, float]:
        """A send's log line; what each of its pulses names (built once a send)."""
        self.recorder.log("info", _send_text(send), ns(send.start), name=self.name)
        message = records.message_ref(
            send.turn, send.kind, send.code, send.sender, send.addressee, send.block
        )
        return message, self.scenario.frequencies[send.channel]

    def _log_pulse(
        self,
        send: Send,
        word: tuple[float, ...],
        j: int,
        ref: tuple[records.MessageRef, float],
    ) -> None:
        """Pulse ``j`` of a send, at its sample's time."""
        k = send.samples[j]
        record = records.pulse(self.name, send.channel, ref[1], float(word[j]), self.tau, k, ref[0])
        self.recorder.write("/tx/pulse", record, ns(k * self.tau))

    def _on_air(self):
        """This unit's transmitter: one SimPy process (not one a send: a 100-unit group
        plans 40,000 sends at once) that logs each planned send as it goes on air: a log
        line at its start, then each pulse at its sample, in time order (then planning order)."""
        env = self.env
        assert env is not None
        air, tau = self._air, self.tau
        while air:
            at, seq, j, send, word, ref = air[0]
            if at > env.now:
                self._air_until = at
                try:
                    yield env.timeout(at - env.now)
                except simpy.Interrupt:  # a send planned meanwhile goes out earlier
                    continue
                finally:
                    self._air_until = AWAKE
            heapq.heappop(air)
            if j < 0:
                ref = self._log_send_line(send)
            else:
                assert ref is not None
                self._log_pulse(send, word, j, ref)
            if j + 1 < len(send.samples):
                heapq.heappush(air, (send.samples[j + 1] * tau, seq, j + 1, send, word, ref))
        self._transmitter = None

    # -- repair ([protocol] repair = "arq"; docs/protocol.md, "Repair") ------------------------

    def _plan_repair(self, block: RepairBlock) -> None:
        """A repair block's three steps as timers, each after the decodes due at its sample;
        until a step that may send has run, nothing of this unit goes out after its first
        pulse unplanned (the promise)."""
        for step, boundary in zip(
            _REPAIR_STEPS, (block.request_choice, block.repeat_choice, block.ready + 1), strict=True
        ):
            timer = self._add(boundary, boundary - 1, step)
            self._repair_of[timer.seq] = block
            self._repair_left += 1
            if step != "copies":
                first = block.first_request if step == "request" else block.first_repeat
                heapq.heappush(self._repair_first, (first, timer.seq))
        assert self.repair is not None
        self.repair.add_seconds(block)

    def _repair_step(self, t: _Timer) -> None:
        """One step of a repair block (``_REPAIR_STEPS``); the last of the run's finishes a
        unit that has decided."""
        block = self._repair_of.pop(t.seq)
        self._repair_left -= 1
        self._repair_first = [e for e in self._repair_first if e[1] != t.seq]
        heapq.heapify(self._repair_first)
        if self.failure is not None:
            return
        if t.kind == "request":
            self._request(block)
        elif t.kind == "repeat":
            self._repeat(block)
        else:
            self._read_copies(block, t.at)
        if not self._repair_left and self.mind.all_rounds_decided:
            self.finished = True

    def _hold(self, listen: Listen, code: str, accepted: bool, margin: float) -> bool:
        """Hold a payload this unit is not sure of (``RepairBook.sure``: found off its
        addressee's channel, a small margin, or read otherwise at the instants the schedule
        gives it, where the timing search found a better fit a sample or two off: other
        codes' pulses, on a noisy medium): it asks for it again in the next repair block.
        Returns whether it was held."""
        assert self.ears is not None and self.repair is not None
        family = family_of(listen)
        ch = self._index[listen.expected_addressee]
        samples = code_samples(listen.start, self.omegas[ch], self.cb.pulses, self.tau)
        exact = self.ears.read_code(self.index, samples, ch, self.repair.families[family])
        if self.repair.sure(family, code, accepted, margin, exact):
            return False
        self.repair.hold(listen, ch, exact)
        return True

    def _request(self, block: RepairBlock) -> None:
        """Ask for every payload of the block's phase it is still unsure of: the ID-code on
        the payload's sender's channel, in the payload's request slot."""
        assert self.repair is not None
        for slot in self.repair.requests(block):
            self._emit(
                Send(slot.turn, "request", slot.sender, "id", slot.request_start,
                     slot.request, self.name, slot.sender, block.number)
            )  # fmt: skip

    def _repeat(self, block: RepairBlock) -> None:
        """Repeat each payload of its own it hears asked for (the request slot reads nearer
        the ID-code than silence on its channel; any number of requesters add up there)."""
        assert self.ears is not None and self.repair is not None
        book, me = self.repair, self._index[self.name]
        for slot in block.slots:
            code = self._payload_code.get(slot.turn)
            if slot.sender != self.name or code is None:
                continue
            if not book.asked_for(self.ears.read_code(self.index, slot.request, me,
                                                      book.request_words)):  # fmt: skip
                continue
            book.counts["repeats"] += 1
            self._emit(
                Send(slot.turn, "repeat", slot.addressee, code, slot.repeat_start, slot.repeat,
                     self.name, slot.addressee, block.number)
            )  # fmt: skip

    def _read_copies(self, block: RepairBlock, at: int) -> None:
        """Read the copies it asked for (``RepairBook.copy``): each combined read is a decode
        of its turn; sure now, it learns the payload. After the phase's last block, what is
        still unsure is learned as it reads best."""
        assert self.ears is not None and self.repair is not None
        book, t = self.repair, at * self.tau
        for slot, held in book.awaited(block):
            read = self.ears.read_code(self.index, slot.repeat, held.channel,
                                       book.copy_words[held.family])  # fmt: skip
            best = book.copy(slot, held, read)
            if best is None:  # its request was not heard (or not answered)
                continue
            addressee = self.units[held.channel]
            self._record(held.listen, addressee, best.name, best.margin, t, True,
                         channel=addressee)  # fmt: skip
            if slot.turn not in book.held:
                self._learn(held.listen, best.name, t)
        for held in book.last(block):
            self.recorder.log(
                "warning",
                f"{self.name}: turn {held.listen.turn}: still unsure after {self._arq} repair "
                f"blocks, taken as {held.best!r}",
                ns(t),
                name=self.name,
            )
            self._learn(held.listen, held.best, t)

    # -- traces --------------------------------------------------------------------------------

    def _trace(self, first: int, x: np.ndarray, y: np.ndarray) -> None:
        """Resonator states from sample ``first`` on (x, y: samples × channels), one message a
        sample: Foxglove's Plot panel draws ``/trace/<unit>.y[i]`` as channel i's curve at the
        full sample rate (docs/foxglove.md)."""
        topic = f"/trace/{self.name}"
        write = self.recorder.write
        tau = self.tau
        for k, (yk, xk) in enumerate(zip(y.tolist(), x.tolist(), strict=True)):
            s = first + k
            t = s * tau
            write(topic, records.trace(self.name, s, t, yk, xk), ns(t))

    # -- decoding and reasoning --------------------------------------------------------------

    def _decode(self, listen: Listen) -> None:
        """Decode ``listen`` on this unit's own readout, and act on it (``_act``)."""
        pulses = self.cb.pulses
        assert self.ears is not None
        if listen.kind == "id":
            # An ID counts only if it reads as the ID-code on the sender's own frequency
            # (a↔c crosstalk makes resonators fire for other codes).
            ch = self._index[listen.sender]
            if self._timed:  # it lands where its link puts it: timed by the search
                dec, _ = self.ears.decode_among(
                    self.index, (ch,), listen.start, self._id_words, self.protocol.search
                )
            else:
                samples = code_samples(listen.start, self.omegas[ch], pulses, self.tau)
                dec = self.ears.read_code(self.index, samples, ch, self._id_words)
            self._act(listen, dec.name, dec.margin, ch)
            return
        dec, ch = self.ears.decode_among(
            self.index, self._channels_of(listen), listen.start, self._words_of(listen),
            self.protocol.search,
        )  # fmt: skip
        self._act(listen, dec.name, dec.margin, ch)

    def _expected_spike(self, sender: str, ids: tuple[int, ...], deadline: int) -> int | None:
        """Where its attention spike to ``sender``'s ID (pulses at ``ids``) comes on a clean
        channel: its resonator on the sender's frequency, at rest from the turn's start, hears
        the ID through its link's gain, and nothing else (serial: one code at a time), up to
        the ID's ``deadline`` (``ProtocolState.id_deadline``)."""
        ch = self._index[sender]
        omega = self.omegas[ch]
        within = deadline - ids[0] + 1
        offsets = tuple(k - ids[0] for k in ids)
        k = clean_first_spike(omega, self.scenario.mode, self.tau, self.cb.id_word, offsets,
                              float(self._gains[ch]), within)  # fmt: skip
        return None if k is None else ids[0] + k

    def _attend(self, at: int) -> None:
        """Confirmed attention (the spike anchor's default; docs/protocol.md, "Attention"):
        the current turn's ID is timed on its sender's channel by a timing search around the
        schedule's instants (the shift whose reads fit the ID-code best, as its link's gain
        delivers it), then found there if its reads are nearer that ID-code than silence (in
        its slot nothing else is on that channel: whether the ID came, not which word it is);
        found, the shift times the reaction; not found, the chain cannot go on and the unit
        fails.
        The ID's decode among every word is still logged (``_act``), an error not fatal."""
        assert self.ears is not None
        turn = self.protocol.current()
        assert turn is not None
        ch = self._index[turn.sender]
        words = self._attention_words.get(ch)
        if words is None:  # the ID as its link delivers it alone (to time it), and against
            # silence (to find it): the threshold between them adapted to the link's gain
            heard = tuple(float(self._gains[ch]) * m for m in self.cb.id_word)
            words = self._attention_words[ch] = (WordSet.of({"id": heard}), heard)
        dec, _ = self.ears.decode_among(
            self.index, (ch,), self.protocol.turn_start, words[0], self.protocol.search
        )
        if not nearer_than_silence(dec.values, words[1]):
            self._fail(
                f"{self.name}: no ID heard on {turn.sender}'s channel for turn {turn.index} "
                f"({turn.sender} -> {turn.addressee}, {turn.phase}) by t = {at * self.tau:.3f} s",
                at,
            )
            return
        self._apply(self.protocol.on_attention(dec.shift))

    def _words_of(self, listen: Listen) -> WordSet:
        """The words a payload listen reads (an ID reads ``_id_words``)."""
        return self._families["relation" if listen.kind == "relation" else "alternative"]

    def _channels_of(self, listen: Listen) -> tuple[int, ...]:
        channels = self._channel_sets.get(listen.channels)
        if channels is None:
            channels = tuple(self._index[r] for r in listen.channels)
            self._channel_sets[listen.channels] = channels
        return channels

    def _act(self, listen: Listen, code: str, margin: float, ch: int) -> None:
        """What ``listen`` decoded (``code`` at ``margin``, found on channel index ``ch``):
        recorded, checked, learned from."""
        t_ready = listen.ready_sample * self.tau
        if listen.kind == "id":
            accepted = code == "id"
            # an ID is for the turn's addressee; it is carried on the sender's own channel
            self._record(
                listen,
                listen.expected_addressee,
                code,
                margin,
                t_ready,
                accepted,
                channel=listen.sender,
            )
            if not accepted:
                text = (
                    f"{self.name}: turn {listen.turn}: the ID of {listen.sender} "
                    f"decoded as {code!r}"
                )
                # the schedule (a repair) or the attention (confirmed) says when the payload
                # comes: a misread ID is a decode error, not the chain's end
                if self._arq or self.protocol.confirmed:
                    self.recorder.log("warning", text, ns(t_ready), name=self.name)
                else:
                    self._fail(text, listen.ready_sample)
            return
        addressee = self.units[ch]
        accepted = addressee == listen.expected_addressee
        self._record(listen, addressee, code, margin, t_ready, accepted, channel=addressee)
        if not accepted:
            self.recorder.log(
                "warning",
                f"{self.name}: turn {listen.turn}: code from {listen.sender} found on "
                f"{addressee}'s channel, expected {listen.expected_addressee}",
                ns(t_ready),
                name=self.name,
            )
        if self._arq and self._hold(listen, code, accepted, margin):
            return
        self._learn(listen, code, t_ready)

    def _record(
        self,
        listen: Listen,
        addressee: str,
        code: str,
        margin: float,
        t: float,
        accepted: bool,
        *,
        channel: str,
    ) -> None:
        self.decoded.append(listen.turn, listen.kind, addressee, code)
        if self.recorder.enabled:  # logged a block of time a record (_flush_decodes)
            row = (listen.turn, listen.sender, addressee, channel, listen.kind, code, margin,
                   t, accepted)  # fmt: skip
            if self._held_block < 0:
                self._held_block = self._block_of(t)
            self._decode_rows.append(row)

    def _block_of(self, t: float) -> int:
        """The decode block (``DECODE_BLOCK_SECONDS``) of a decode at time ``t``."""
        return round(t / self.tau) // self._decode_block

    def _rows_to_part(self) -> None:
        """The single decodes logged since the last batch, as a part of columns (of names)."""
        if self._decode_rows:
            self._decode_parts.append([list(c) for c in zip(*self._decode_rows, strict=True)])
            self._decode_tables.append(None)
            self._decode_rows = []

    def _flush_decodes(self, before: int | None = None) -> None:
        """Log the decodes held, one ``/rx/decodes`` record a decode block of
        ``DECODE_BLOCK_SECONDS`` (each at its last decode's time): before any other record of
        this unit, so its records stay in time order (a log cut short is complete before its
        last one), and at the end of a wake in a later block than the first held one
        (``before``: only the decodes of blocks before the one of that sample; the others
        stay held). Which decodes a record holds depends on the blocks and the unit's other
        records alone, not on its wakes, so every engine, bus and attention writes the same
        records. With a live view watching, at the end of every wake (``_holds``)."""
        self._rows_to_part()
        parts, self._decode_parts = self._decode_parts, []
        tables, self._decode_tables = self._decode_tables, []
        self._held_block = -1
        if not parts:
            return
        table = next((t for t in tables if t is not None), None)
        indexed: list[Any] = []
        if table is not None and all(t is None or t == table for t in tables):
            # batches, and single decodes among them, as indexes into the batches' tables
            for p, t in zip(parts, tables, strict=True):
                q = p if t is not None else _indexed_part(p, table)
                if q is None:  # a name in none of the tables: the block stays in names
                    indexed = []
                    break
                indexed.append(q)
        if indexed:  # as arrays
            cols: list[Any] = (
                list(indexed[0])
                if len(indexed) == 1
                else [np.concatenate([p[j] for p in indexed]) for j in range(9)]
            )
        else:  # single decodes (a serial run's, held over a few wakes): plain lists
            cols = []
            for j in range(9):
                col = [
                    _named_column(p[j], t, j) if t is not None else list(p[j])
                    for p, t in zip(parts, tables, strict=True)
                ]
                cols.append([v for c in col for v in c])
            table = None
        times = cols[7]
        if type(times) is list:
            blocks = [self._block_of(t) for t in times]
            cuts = [0, *(i for i in range(1, len(blocks)) if blocks[i] != blocks[i - 1])]
        else:  # a batch's: in time order, so a block's decodes are one run
            of = np.rint(times / self.tau).astype(np.int64) // self._decode_block
            cuts = [0, *(np.flatnonzero(of[1:] != of[:-1]) + 1).tolist()]
            blocks = of.tolist()
        cuts.append(len(blocks))
        now = NEVER if before is None else before // self._decode_block
        for a, b in itertools.pairwise(cuts):
            if blocks[a] >= now:  # the block still going on: held, as one part
                self._decode_parts = [[c[a:] for c in cols]]
                self._decode_tables = [table]
                self._held_block = blocks[a]
                return
            part = cols if b - a == len(blocks) else [c[a:b] for c in cols]
            record = records.decodes_of_columns(self.name, part, table)
            self.recorder.write("/rx/decodes", record, ns(record["t"]))

    def _write(self, topic: str, record: Any, t_ns: int) -> None:
        """A record of this unit's own, after the decodes that came before it."""
        self._flush_decodes()
        self.recorder.write(topic, record, t_ns)

    def _learn(self, listen: Listen, code: str, t: float) -> None:
        mind = self.mind
        universe = self.scenario.universe
        key = listen.pair
        if listen.kind == "relation":
            mind.sent[key] = code == "alliance"
            if mind.relations_complete():
                mind.build_group()
                if self.recorder.enabled:
                    self._log_relations(t)
                if mind.error:
                    self.recorder.log("error", f"{self.name}: {mind.error}", ns(t), self.name)
                elif mind.p4 is not None:  # a result, said once by each unit that found it
                    text = not_decomposable_text(mind.p4)
                    self.recorder.log("warning", f"{self.name}: {text}", ns(t), self.name)
        else:
            value = self._alternatives.get(code)
            if value is None:
                value = self._alternatives[code] = universe.parse_alternative(code)
            rnd = self.protocol.schedule[listen.turn].round
            for done in mind.hear_influence(rnd, key, value):  # rounds now complete, decided
                if self.recorder.enabled:
                    self._log_influences(t, done)
                self._log_decisions(t, done)
            if mind.all_rounds_decided and not self._repair_left:
                self.finished = True

    def _log_relations(self, t: float) -> None:
        mind = self.mind
        record = records.relations(
            self.name, t, mind.sent_table(), mind.installed(), mind.polynomial, mind.p4
        )
        self._write("/unit/relations", record, ns(t))

    def _log_influences(self, t: float, rnd: int = 1) -> None:
        record = records.influences(self.name, t, self.mind.influence_table(), rnd)
        self._write("/unit/influences", record, ns(t))

    def _log_decisions(self, t: float, rnd: int = 1) -> None:
        mind = self.mind
        u = self.scenario.universe
        decided = mind.round_results.get(rnd)
        if decided is None:
            if mind.p4 is None:  # a group with no polynomial has said so already
                why = mind.error or "the relationship phase did not finish"
                self.recorder.log("error", f"{self.name}: no decision: {why}", ns(t), self.name)
            return
        results, choice = decided
        self.decisions.append(decision_row(self.name, rnd, t, results[self.name], choice, u))
        if not self.recorder.enabled:  # the canonical forms cost more than the decision
            return
        for s, r in results.items():
            fields = decision_fields(r, choice if s == self.name else None, u)
            record = records.decision(self.name, s, t, fields, mind.canonical(s), rnd)
            self._write("/unit/decision", record, ns(t))

    # -- what this unit knows, as plain data (one process's share of a run summary) ----------

    def sent_influences(self) -> list[dict[str, str]]:
        """The influences this unit sent, per influence round: ``[{addressee: code}, ...]``."""
        out: list[dict[str, str]] = [{} for _ in range(self.scenario.influence_rounds)]
        for send in self.sent:
            turn = self.protocol.schedule[send.turn]
            if send.kind == "payload" and turn.phase == PHASES[1]:
                out[turn.round - 1][send.addressee] = send.code
        return out

    def report_record(self) -> records.UnitReportRecord:
        """What this unit knows at the end of its run (``/unit/report``): everything its share
        of the run summary needs but its decodes (those are ``/rx/decodes``)."""
        mind = self.mind
        out: records.UnitReportRecord = {
            "unit": self.name,
            "installed": mind.installed(),
            "polynomial": mind.polynomial,
            "p4": None if mind.p4 is None else list(mind.p4),
            "sent_relations": mind.sent_table(),
            "influences": mind.influence_table(),
            "result": result_fields(mind),
            "decisions": list(self.decisions),
            "sends": [[s.turn, s.kind, s.addressee, s.code] for s in self.sent],
            "sent_influences": self.sent_influences(),
            "failure": self.failure,
            "failed_at": self.done_at if self.failure else None,
            "done_at": self.done_at if self.done else None,
            "mind_error": mind.error,
        }
        if self.repair is not None:
            out["repair"] = self.repair.report()  # type: ignore[typeddict-item]
        return out

    def report(self) -> dict:
        """This unit's share of the run summary (``rgtbus.summary.summarise``): its report
        record and its decodes."""
        return {
            **self.report_record(),
            "decodes": self.decoded,  # columns (DecodeColumns): iterates as rows
        }
