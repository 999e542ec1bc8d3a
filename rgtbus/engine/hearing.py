"""The units' ears: the resonator banks of the units one process runs, advanced as one (SimPy).

Every unit hears the medium through its own resonators: its own lanes of the bank, its own link
gains and noise, its own quench times and its own readout; it learns nothing from another unit's
lanes. The lanes of all the units of one process are simply advanced by one call of the core
(``resonate``), because a call costs about the same for one unit as for twenty: the numeric
work of a run then grows with its events, not with events × units. Lanes are independent and
every value depends only on the absolute sample, so how the work is batched or chunked never
changes a result (docs/engine.md).

A unit asks ``listen(i, boundary, at, wake, watch, watch_from)``: "advance me up to sample
``boundary`` (exclusive); wake me at a spike on channel ``watch`` at or after ``watch_from``"
(the one spike its protocol can react to). The ears' SimPy process calls ``wake`` at that
spike's time, or when the boundary is reached at time ``at`` (its timer's own sample), with a
``Heard``: every spike of the unit's resonators since it last woke, in order, each with its
sample. A wake is a plain call, not a SimPy event per unit: a large run wakes its units millions
of times (once per decode), and an event, a generator resume and a heap entry each time were
most of its cost (issue 23). The simulated time of a wake is exact all the same. The ears
advance only when every listening unit has asked, never past the smallest
boundary asked for nor past the horizon of the known medium (``hear``), and stop at the first
watched spike of any unit: what a unit reacts to happens in time order, each at its exact
sample. A unit's quench times (``quench_at``: its resonators back to rest before a sample)
are the ears' to keep: they need no wake-up.

The ears walk the resonators only when a spike matters: a unit whose plans can wait for one
(``Listener.awaits``), a log of spikes (``SpikeLog``, handed a block at a time) or traces. A
decode reads the increment readout, which is the input each unit heard
(``input_readout``), so a run with none of the three needs no walk at all.

``dense=True`` is the time-stepped reference: every window of ``window`` samples is fed to
every unit, silent or not.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol, TypeVar, cast

import numpy as np
import simpy

from rgtbus.errors import RgtbusError
from rgtbus.protocol import NEVER
from rgtbus.signal.channel import BurstStates, heard_by, render
from rgtbus.signal.decoder import (
    Decision,
    ReadoutHistory,
    ReceiverReadout,
    WordSet,
    decode_among_each,
    nearest_each,
)
from rgtbus.signal.pulses import Pulses
from rgtbus.signal.resonator import (
    BankModel,
    BankState,
    ResonatorBank,
    first_spike,
    input_readout,
    resonate,
)

TraceSink = Callable[[int, np.ndarray, np.ndarray], None]  # (first sample, x (n, C), y (n, C))


_T = TypeVar("_T")


class Heard(NamedTuple):
    """What woke a unit: ``spikes`` of its resonators since it last woke, in order, as
    (sample, channel indexes); ``reached``: its boundary (else: its watched spike, the last).
    A plain tuple: made at every wake, millions of times in a large run."""

    spikes: tuple[tuple[int, tuple[int, ...]], ...]
    reached: bool


_HEARD_NOTHING = Heard((), True)  # a unit woken at its boundary that heard no spike
Wake = Callable[[Heard], None]  # a unit's handler: what it heard, then it asks again or stops


class SpikeLog(Protocol):
    """Where a unit's spikes go for its log, a block of ``block`` samples at a time. The ears
    keep the spikes of the units they log in arrays (no call per spike: a large run's
    receivers fire millions of times, issue 23) and hand each unit a block's spikes once they
    have heard the whole block, or as far as they heard when the unit stops (or up to the
    sample it names then) or the run ends: a unit wakes only for the spike it awaits, and
    records written at its wake could trail the run's clock by seconds."""

    block: int

    def spikes(self, samples: np.ndarray, index: np.ndarray, fired: np.ndarray, end: int) -> None:
        """The spikes of one block: at ``samples[i]`` (ascending) the resonator of channel
        ``fired[index[i]]`` fired (a sample's channels ascending; ``fired``: the channels
        that fired in the block, ascending); heard up to sample ``end`` (the block's end, or
        less for the last block of a unit that stopped)."""
        ...

    def shared_spikes(self, block: SharedSpikes) -> None:
        """The spikes of one block that this unit and others heard alike (``SharedSpikes``):
        the unit settles it (``SharedSpikes.settle``) once it knows whether it listened
        through the block's end."""
        ...

    def keeps_now(self) -> bool:
        """Whether this unit would keep a block handed now at once (it holds none for a
        later wake, which may find it was done before the block's end)."""
        ...

    def shared_kept(
        self, names: list[str], samples: np.ndarray, index: np.ndarray, fired: np.ndarray, end: int
    ) -> None:
        """The record of one block that the units ``names`` (this one among them) heard alike
        and every one keeps at once (``keeps_now``): written as handed, with nothing to settle
        (a serial 10-unit run hands ~750 blocks of ~2 spikes each to all ten units)."""
        ...


class SharedSpikes:
    """One block's spikes that several logged units of one process heard alike, bit for bit
    (a noise-free medium through equal link gains: they walk as one, ``resonate``'s share),
    for a single ``/rx/spike`` record of them all instead of one copy a unit (fields as
    ``SpikeLog.spikes``; ``members`` the units' indices among the listeners, ``names`` theirs).

    Each member settles it once: it kept the block (it listened through its end) or it left
    it (it was done before: its own record holds its spikes up to there). The last to settle
    learns which members kept it, and writes their record."""

    __slots__ = ("_kept", "_member_set", "end", "fired", "index", "members", "names", "samples")

    def __init__(
        self,
        samples: np.ndarray,
        index: np.ndarray,
        fired: np.ndarray,
        end: int,
        members: Sequence[int],
        names: Sequence[str],
    ) -> None:
        self.samples, self.index, self.fired, self.end = samples, index, fired, end
        self.members, self.names = list(members), list(names)
        self._member_set = frozenset(self.members)  # fifty members settle each block
        self._kept: dict[int, bool] = {}

    def settle(self, member: int, kept: bool) -> list[str] | None:
        """Member ``member`` kept the block, or left it; once every member has settled, the
        names of those that kept it (member order), else None."""
        if member not in self._member_set:
            raise RgtbusError(f"unit {member} settles a block of units {self.members}")
        if member in self._kept:
            raise RgtbusError(f"unit {member} settles a block of units {self.members} again")
        self._kept[member] = kept
        if len(self._kept) < len(self.members):
            return None
        return [n for m, n in zip(self.members, self.names, strict=True) if self._kept[m]]


class _SpikePiece(NamedTuple):
    """The kept spikes of one advance: ``k`` sample, ``w`` walker (the receiver that walked),
    ``c`` channel, in the walk's order (sample, walker, channel); ``walker_of`` each
    receiver's walker (-1: it stood still), None when every receiver walked on its own."""

    k: np.ndarray
    w: np.ndarray
    c: np.ndarray
    walker_of: np.ndarray | None

    def cut(self, a: int, b: int) -> _SpikePiece:
        return _SpikePiece(self.k[a:b], self.w[a:b], self.c[a:b], self.walker_of)


@dataclass
class Listener:
    """One unit's share of the ears."""

    name: str
    gains: np.ndarray  # gain of each sender's signal at this unit, in member order
    noise: float  # σ of the white noise this unit's receiver adds to every sample
    rng: np.random.Generator | None  # its noise's generator (None: a receiver with no noise)
    keep: int  # samples of readout history the unit decodes from
    trace: TraceSink | None = None
    spike_log: SpikeLog | None = None  # where its every spike goes as it is heard (a log)
    # whether its plans can wait for a spike (an ID spike, under anchor "spike"): when no
    # unit's can and none logs or traces its spikes, the event engine's ears never walk the
    # resonators (the readout a decode needs is the input itself)
    awaits: bool = True
    active: bool = True
    request: tuple[int, int, Wake] | None = None  # (boundary, at, what to call)
    watch: int | None = None  # the channel whose spike could change this unit's plans
    watch_from: int = 0  # ... from this sample on (earlier spikes there change nothing)
    heard: list[tuple[int, tuple[int, ...]]] = field(default_factory=list)  # not yet told
    bursts: BurstStates | None = None  # when its noise comes in bursts (σ_b, not ``noise``)
    # where each sender's sample j lands in its own samples, a + b·j (rows a, b; None: on j):
    # delays and clocks (``Channel.arrivals``)
    arrival: np.ndarray | None = None
    _noise: np.ndarray = field(default_factory=lambda: np.zeros(0))
    _noise_at: int = 0  # sample of _noise[0]

    @property
    def noisy(self) -> bool:
        """Whether this receiver hears any noise (white, or in bursts)."""
        return self.noise > 0 or self.bursts is not None

    def noise_for(self, lo: int, hi: int) -> np.ndarray:
        """This unit's noise for samples [lo, hi), drawn in order from its own generator (the
        same numbers however the stretch is cut)."""
        have = self._noise_at + self._noise.size
        if lo < self._noise_at:
            raise RgtbusError(f"{self.name}: noise for sample {lo} was already used")
        if hi > have:
            assert self.rng is not None, f"{self.name}: noise {self.noise} with no generator"
            if self.bursts is None:
                more = self.rng.normal(0.0, self.noise, hi - have)
            else:  # the same draws, each times its sample's σ (normal(0, σ) is σ·z)
                more = self.rng.standard_normal(hi - have) * self.bursts.sigma(have, hi, self.noise)
            self._noise = np.concatenate([self._noise[lo - self._noise_at :], more])
            self._noise_at = lo
        out = self._noise[lo - self._noise_at : hi - self._noise_at]
        return out

    def used_noise(self, upto: int) -> None:
        if upto > self._noise_at:
            cut = min(upto - self._noise_at, self._noise.size)
            self._noise = self._noise[cut:]
            self._noise_at += cut


class Ears:
    """The banks of the listening units of one process (see the module docstring)."""

    def __init__(
        self,
        env: simpy.Environment,
        senders: Sequence[str],
        listeners: Sequence[Listener],
        bank: ResonatorBank,
        *,
        dense: bool = False,
        window: int = 20,
    ) -> None:
        if bank.n_receivers != len(listeners):
            raise RgtbusError(f"{len(listeners)} listeners for a bank of {bank.n_receivers}")
        self.env = env
        self.tau = bank.tau
        self.senders = tuple(senders)
        self.listeners = list(listeners)
        self.bank = bank
        self.dense = dense
        self.window = window
        # pulses that land off their samples (delays, clocks): each (pulse, listener) is
        # rendered on the listener's own samples, and reads take two samples
        arrivals = [lst.arrival for lst in self.listeners if lst.arrival is not None]
        self._timed = bool(arrivals)
        if self._timed:
            if len(arrivals) != len(self.listeners):  # one channel: every link or none
                raise RgtbusError("some listeners hear delays and clocks and others do not")
            self._arrival = np.stack(arrivals)  # listeners × 2 × senders
        self.readout = ReadoutHistory(
            bank.n_channels,
            max(lst.keep for lst in self.listeners),
            len(self.listeners),
            window=2 if self._timed else 1,
        )
        self._rcv = np.zeros(0, dtype=np.int64)  # timed: each entry's listener
        self.horizon = 0  # every sender's pulses before this sample are known
        # the known medium: every pulse in sample order (each sender's in its own order)
        self._rows = np.zeros(0, dtype=np.int64)
        self._who = np.zeros(0, dtype=np.int64)
        self._val = np.zeros(0)
        self._cur = 0  # pulses before this index were heard
        self._poke = env.event()  # fired when the last listening unit has asked
        self._more = env.event()
        self._asking = len(self.listeners)  # listening units that have not asked yet
        self._quench: list[tuple[int, int]] = []  # (sample, unit): rest before that sample
        self.quiet = env.event()  # every unit is done listening
        self._gains = np.stack([lst.gains for lst in self.listeners])  # listeners × senders
        self._unit_gains = bool(np.all(self._gains == 1.0))
        self._unit_gain = [bool(np.all(lst.gains == 1.0)) for lst in self.listeners]
        self._logged = [lst for lst in self.listeners if lst.spike_log is not None]
        blocks = {lst.spike_log.block for lst in self.listeners if lst.spike_log is not None}
        if len(blocks) > 1:
            raise RgtbusError(f"the units log spikes in blocks of different sizes: {blocks}")
        self._spike_block = blocks.pop() if blocks else 1
        # the spikes of logged units not yet handed to their logs, an advance a piece
        self._spike_pieces: list[_SpikePiece] = []
        self._pending: list[np.ndarray] = []  # advances' spikes not yet made a piece
        self._pending_of: np.ndarray | None = None  # their walkers (None: each its own)
        self._spikes_due = self._spike_block  # the next block boundary to hand blocks over at
        # which units' spikes are kept for a log: logged and still listening (``stop``)
        self._log_mask = np.array([lst.spike_log is not None for lst in self.listeners])
        self._spikes_ended = np.zeros(len(self.listeners), dtype=bool)  # its last handed
        self._lane_models: dict[int, BankModel] = {}  # one resonator picked out, per channel
        self._traced = any(lst.trace is not None for lst in self.listeners)
        # the dense engine is the reference: it walks every resonator every sample, always
        self._walks = dense or any(
            lst.awaits or lst.spike_log is not None or lst.trace is not None
            for lst in self.listeners
        )
        self._trace_buf: dict[int, list[tuple[int, np.ndarray, np.ndarray]]] = {}
        self.steps = 0  # bank advances so far
        # decodes asked at the present end of the readout: every unit of the process decodes
        # the same code at about the same time, so the first ask reads all of them
        self._decodes: dict[tuple, list] = {}
        self._decodes_end = -1
        # the decodes of shared listen queues, for every receiver, a chunk at a time
        self._queues: dict[int, _QueueDecodes] = {}
        self._shared: dict[int, tuple[object, object]] = {}
        self._listening = np.ones(len(self.listeners), dtype=bool)
        self.pos = bank.n_fed  # the next sample the ears will hear (only _advance moves it)
        self.process = env.process(self._run())

    # -- the world's side ---------------------------------------------------------------------

    def hear(self, horizon: int, pulses: Mapping[str, Pulses]) -> None:
        """The medium is now known up to ``horizon`` (exclusive): these are the new pulses."""
        if horizon < self.horizon:
            raise RgtbusError(f"horizon {horizon} goes back from {self.horizon}")
        parts = [(n, pulses[u]) for n, u in enumerate(self.senders) if u in pulses]
        parts = [(n, p) for n, p in parts if p[0].size]
        if self._timed:
            parts, horizon = self._landed(parts, horizon)
        if parts:
            rows = np.concatenate([p[0] for _, p in parts])
            if rows.min() < self.horizon:
                raise RgtbusError(f"a pulse at sample {int(rows.min())} arrived after its time")
            who = np.concatenate([np.full(p[0].size, n) for n, p in parts])
            val = np.concatenate([p[1] for _, p in parts])
            order = np.argsort(rows, kind="stable")
            keep = slice(self._cur, None)
            self._rows = np.concatenate([self._rows[keep], rows[order]])
            self._who = np.concatenate([self._who[keep], who[order]])
            self._val = np.concatenate([self._val[keep], val[order]])
            if self._timed:
                rcv = np.concatenate([p[2] for _, p in parts])  # type: ignore[misc]
                self._rcv = np.concatenate([self._rcv[keep], rcv[order]])
            self._cur = 0
        self.horizon = horizon
        _fire(self._more)

    def _landed(
        self, parts: list[tuple[int, Pulses]], horizon: int
    ) -> tuple[list[tuple[int, Any]], int]:
        """Timed: each sender's pulses as every listener gets them (``render``), with the
        listener of each share; and the horizon on the listeners' samples: the earliest
        sample a pulse not yet known (sent at or after ``horizon``) could land on."""
        A = self._arrival  # listeners × 2 × senders
        out: list[tuple[int, Any]] = []
        for n, (rows, vals) in parts:
            for lst in range(A.shape[0]):
                r, v = render(rows, vals, float(A[lst, 0, n]), float(A[lst, 1, n]))
                out.append((n, (r, v, np.full(r.size, lst, dtype=np.int64))))
        if horizon < NEVER:
            horizon = int(np.floor((A[:, 0, :] + A[:, 1, :] * horizon).min()))
        return out, max(horizon, self.horizon)

    # -- a unit's side --------------------------------------------------------------------------

    def listen(
        self,
        i: int,
        boundary: int,
        at: int,
        wake: Wake,
        watch: int | None = None,
        watch_from: int = 0,
    ) -> None:
        """Advance unit ``i`` up to sample ``boundary``; see the module docstring. ``watch``:
        the channel on which a spike at or after ``watch_from`` could change the unit's plans
        (the ears stop there; the unit hears every other spike too, each at its sample, but
        nothing waits on them)."""
        lst = self.listeners[i]
        if not lst.active:
            raise RgtbusError(f"{lst.name} stopped listening")
        if boundary < self.pos:
            raise RgtbusError(f"{lst.name}: boundary {boundary} is behind the ears ({self.pos})")
        if lst.request is None:
            self._asking -= 1
        lst.request = (boundary, at, wake)
        lst.watch = watch
        lst.watch_from = watch_from
        if not self._asking:
            _fire(self._poke)

    def readout_of(self, i: int) -> ReceiverReadout:
        """Unit ``i``'s own readout (its resonators' view of the medium)."""
        return self.readout.of(i)

    def decode_among(
        self, i: int, channels: tuple[int, ...], start: float, words: WordSet, search: int
    ) -> tuple[Decision, int]:
        """Unit ``i``'s ``decode_among`` over these channel indexes, on its own readout (see
        ``decode_among_each``)."""
        key = (channels, start, words, search)
        got = self._decoded(key)
        if got is None:
            pairs = tuple((c, float(self.bank.omegas[c])) for c in channels)
            got = self._decodes[key] = decode_among_each(
                self.readout, pairs, start, words, tau=self.tau, search=search
            )
        return got[i]

    def read_code(self, i: int, samples: tuple[int, ...], channel: int, words: WordSet) -> Decision:
        """Unit ``i``'s nearest word to its readout at ``samples`` on ``channel``."""
        key = (samples, channel, words)  # never equal to a decode_among key (4 items)
        got = self._decoded(key)
        if got is None:
            got = self._decodes[key] = nearest_each(self.readout, samples, channel, words)
        return got[i]

    def shared(self, key: object, build: Callable[[], _T]) -> _T:
        """What every unit of these ears works out alike from ``key`` (a listen queue, say),
        built once by the first that asks (``key`` is kept alive: it is found by id)."""
        got = self._shared.get(id(key))
        if got is None:
            got = self._shared[id(key)] = (key, build())
        return cast(_T, got[1])

    def queue_decodes(
        self, i: int, queue: object, lo: int, hi: int, read: QueueRead
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit ``i``'s decodes of positions [lo, hi) of a listen queue shared by the units of
        these ears (all heard): each one's word, channel index and margin, as columns.
        ``read(q)`` decodes position q for every receiver at once; each position is read
        once, by whichever unit gets there first, and kept until every listening unit has
        taken it (a chunk of ``QUEUE_CHUNK`` positions at a time)."""
        cache = self._queues.get(id(queue))
        if cache is None:
            cache = self._queues[id(queue)] = _QueueDecodes(queue, len(self.listeners))
        parts = [
            cache.rows(c, lo, hi, read, i)
            for c in range(lo // QUEUE_CHUNK, (hi - 1) // QUEUE_CHUNK + 1)
        ]
        cache.cursor[i] = hi
        cache.forget(int(cache.cursor[self._listening].min(initial=hi)))
        if len(parts) == 1:
            return parts[0]
        word, chan, margin = zip(*parts, strict=True)
        return np.concatenate(word), np.concatenate(chan), np.concatenate(margin)

    def _decoded(self, key: tuple) -> list | None:
        if self._decodes_end != self.readout.end:  # the readout moved on: start afresh
            self._decodes.clear()
            self._decodes_end = self.readout.end
        return self._decodes.get(key)

    def quench_at(self, i: int, sample: int) -> None:
        """Unit ``i``'s resonators back to rest before ``sample`` (the ears stop there)."""
        if sample < self.pos:
            raise RgtbusError(
                f"{self.listeners[i].name}: quench before sample {sample}, "
                f"but the ears are at {self.pos}"
            )
        heapq.heappush(self._quench, (sample, i))

    def quench_between(self, i: int, lo: int, hi: int) -> list[int]:
        """The samples in [lo, hi) before which unit ``i``'s resonators go back to rest."""
        return sorted(q for q, n in self._quench if n == i and lo <= q < hi)

    def stop(self, i: int, at: int | None = None) -> None:
        """Unit ``i`` is done: it listens no more (and draws no more noise). ``at``: the
        sample it was done before, if the ears went on past it meanwhile (a unit that took a
        batch of decodes at one wake learns it only then): its log holds its spikes before
        that sample, the last block ending there, as if it had stopped on time."""
        lst = self.listeners[i]
        if lst.active and lst.request is None:
            self._asking -= 1
        lst.active = False
        lst.request = None
        self._listening[i] = False
        self._log_mask[i] = False
        self.end_spikes(i, at)
        if lst.trace is not None:
            self._flush_trace(i)
        _fire(self._poke)

    def peek(
        self,
        i: int,
        until: int,
        extra: Mapping[str, Pulses],
        quench: Sequence[int],
        channel: int,
        after: int,
    ) -> int | None:
        """Look ahead for unit ``i``: the first sample in [here, ``until``), at or after
        ``after``, at which its resonator on ``channel`` would spike if the medium held only the
        pulses known so far plus ``extra``, its quench times applied. Pure: the ears, the bank
        and the unit do not move (the unit's noise is drawn ahead and kept for the real run)."""
        lst = self.listeners[i]
        lo = self.pos
        if until <= lo or not lst.active:
            return None
        if self._timed:  # a timed channel needs confirmed attention: no spike is awaited
            raise RgtbusError(f"{lst.name}: a look-ahead for a spike on a timed channel")
        parts = [
            (n, p)
            for n, u in enumerate(self.senders)
            if u in extra and (p := extra[u])[0].size and p[0][0] < until
        ]
        rows = np.concatenate([self._rows[self._cur :], *(p[0] for _, p in parts)])
        who = np.concatenate([self._who[self._cur :], *(np.full(p[0].size, n) for n, p in parts)])
        val = np.concatenate([self._val[self._cur :], *(p[1] for _, p in parts)])
        order = np.argsort(rows, kind="stable")
        rows, who, val = rows[order], who[order], val[order]
        cut = int(rows.searchsorted(until))
        at, heard = heard_by(
            rows[:cut], who[:cut], val[:cut], lst.gains[None, :], self._unit_gain[i]
        )
        heard = heard[:, 0]
        if lst.noisy:
            dense = lst.noise_for(lo, until).copy()
            dense[at - lo] = heard + dense[at - lo]
            at, heard = np.arange(lo, until, dtype=np.int64), dense
        # Lanes are independent: the awaited channel's resonator alone, from the same tables.
        lane = i * self.bank.n_channels + channel
        st = self.bank.state
        state = BankState(st.wr[[lane]], st.wi[[lane]], st.pend[[lane]], lo)
        model = self._lane_models.get(channel)
        if model is None:
            model = self.bank.model.pick(np.array([channel]), np.array([0]), 1)
            self._lane_models[channel] = model
        stops = [*sorted(q for q in quench if lo <= q < until), until]
        for stop in stops:
            while state.n < stop:
                k0, k1 = at.searchsorted([state.n, stop])
                k = first_spike(model, state, stop, at[k0:k1], heard[k0:k1, None])
                if k is None:
                    break  # silent to the stop: nothing to carry over a quench
                if k >= after:
                    return k
                # too early to react to: walk past it and look on
                k1 = int(at.searchsorted(k + 1))
                state, _ = resonate(model, state, k + 1, at[k0:k1], heard[k0:k1, None])
            if stop < until:
                state = BankState.rest(1, stop)
        return None

    # -- the SimPy process ----------------------------------------------------------------------

    def _run(self):
        env = self.env
        while True:
            if self._asking:
                self._poke = env.event()
                yield self._poke
                continue
            live = [lst for lst in self.listeners if lst.active]
            if not live:
                self.quiet.succeed()
                return
            while self._quench and self._quench[0][0] == self.pos:  # before this sample
                n = heapq.heappop(self._quench)[1]
                if self.listeners[n].active:
                    self.bank.quench(n)
            boundary = min(lst.request[0] for lst in live)  # type: ignore[index]
            target = min(boundary, self.horizon)
            if self._quench:
                target = min(target, self._quench[0][0])
            for lst in live:  # a watch that starts later splits the advance there
                if lst.watch is not None and lst.watch_from > self.pos:
                    target = min(target, lst.watch_from)
            if self.dense:
                target = min(target, (self.pos // self.window + 1) * self.window)
            if self._logged and self._walks:  # what the walk and the hand-over hold stays
                # small in a large run (a block or so of every lane's spikes), while a small
                # one still advances a long wait at once
                blocks = WALK_LANE_SAMPLES // (self.bank.model.lanes * self._spike_block)
                target = min(target, self._spikes_due + blocks * self._spike_block)
            if self.pos < target:
                k = self._advance(target)
                if k is not None:  # a watched spike: wake whoever watched it, at its time
                    yield env.timeout(max(0.0, k * self.tau - env.now))
                    yield env.timeout(0)  # after what is already due then (see _after_due)
                    for lst in self.listeners:
                        if lst.active and lst.heard and lst.heard[-1][0] == k:
                            chans = lst.heard[-1][1]
                            if lst.watch in chans and k >= lst.watch_from:
                                self._wake(lst, reached=False)
                continue
            due = sorted(
                (lst.request[1], n)  # type: ignore[index]
                for n, lst in enumerate(self.listeners)
                if lst.active and lst.request is not None and lst.request[0] == self.pos
            )
            if due:
                woke_at = None
                for at, n in due:
                    if at * self.tau > env.now:
                        yield env.timeout(at * self.tau - env.now)
                    if woke_at != at:  # one hop a sample, not a SimPy event per unit
                        woke_at = at
                        yield env.timeout(0)
                    lst = self.listeners[n]
                    if lst.active and lst.request is not None:
                        self._wake(lst, reached=True)
                continue
            self._more = env.event()
            yield self._more  # the medium is known no further: wait for the world

    # _after_due: a woken unit acts after every event already due at its sample (a pulse
    # logged at that sample, say), whichever way the horizon reached it: the hop puts the wakes
    # at the end of SimPy's queue for that time, so a log's order of records at one log time
    # does not depend on the bus (memory, zenoh, log replay) or on how frames arrived.

    def _wake(self, lst: Listener, *, reached: bool) -> None:
        assert lst.request is not None
        wake = lst.request[2]
        lst.request = None
        self._asking += 1
        # the unit asks again (or stops) before this returns
        if lst.heard:
            heard, lst.heard = tuple(lst.heard), []
            wake(Heard(heard, reached))
        else:
            wake(_HEARD_NOTHING if reached else Heard((), False))

    def _advance(self, target: int) -> int | None:
        """Every unit's lanes from here towards ``target``, up to the first spike on a watched
        channel: one call of the core, however many other spikes ring on the way (each unit
        keeps its own until it wakes). Returns the watched spike's sample, if it stopped at one."""
        lo = self.pos
        cut = self._cur + int(self._rows[self._cur :].searchsorted(target))
        rows, heard = self._medium_rows(slice(self._cur, cut))
        C = self.bank.n_channels
        noisy: list[int] = []
        done: list[int] = []
        watched: list[int] = []  # lanes
        for n, lst in enumerate(self.listeners):
            if not lst.active:
                done.append(n)
                continue
            if lst.noisy:
                noisy.append(n)
            if lst.watch is not None and lst.watch_from <= lo:
                watched.append(n * C + lst.watch)
        if noisy:
            all_rows = np.arange(lo, target, dtype=np.int64)
            dense = np.zeros((all_rows.size, len(self.listeners)))
            dense[rows - lo] = heard
            rows, heard = all_rows, dense
            for n in noisy:
                heard[:, n] += self.listeners[n].noise_for(lo, target)
        if done and heard.size:
            heard[:, done] = 0.0  # a unit that is done hears nothing more
        if not self._walks:  # no spike is awaited, logged or traced: decoding needs the input
            at, d = input_readout(rows, heard)
            self.readout.store(lo, target - lo, at, d[:, :, None])
            self.pos = target
            self.steps += 1
            self._cur = cut
            for n in noisy:
                self.listeners[n].used_noise(target)
            return None
        stop_lanes = None
        if watched:
            stop_lanes = np.zeros(self.bank.model.lanes, dtype=bool)
            stop_lanes[watched] = True
        walking = None
        if done:  # a unit that is done hears nothing more: its resonators stand still
            walking = np.ones(len(self.listeners), dtype=bool)
            walking[done] = False
        res = self.bank.advance(
            target,
            rows,
            heard,
            stop=bool(watched),
            stop_lanes=stop_lanes,
            readout=True,
            record=self._traced,
            receivers=walking,
            expand=False,  # units that walk as one keep one copy of their spikes
        )
        end = lo + res.n
        self.pos = end
        self.steps += 1
        self._cur += int(self._rows[self._cur : cut].searchsorted(end))
        self.readout.extend(res)
        for n in noisy:
            self.listeners[n].used_noise(end)
        if self._traced and res.z is not None and res.y is not None:
            for n, lst in enumerate(self.listeners):
                if lst.active and lst.trace is not None:
                    self._add_trace(n, lo, res.z[:, n].real, res.y[:, n])
        # sorted by sample, receiver, channel: the walkers' alone when receivers walked as
        # one (``walker_of``: each receiver's walker), every receiver's otherwise
        sp, walker_of = res.spikes, res.walker_of
        if len(sp) and res.stopped:  # a watched spike: the unit that watched it wakes for it
            for k, w, ch in sp[sp[:, 0] == end - 1].tolist():
                for n in [w] if walker_of is None else np.flatnonzero(walker_of == w).tolist():
                    lst = self.listeners[n]
                    if lst.active and ch == lst.watch and k >= lst.watch_from:
                        lst.heard.append((k, (ch,)))
        if self._logged:  # kept for the logs, handed over a block at a time
            if len(sp):
                if walker_of is None:
                    serves = self._log_mask
                else:  # a walk is kept while a logged unit took it
                    serves = np.zeros(len(self.listeners), dtype=bool)
                    serves[walker_of[self._log_mask & (walker_of >= 0)]] = True
                keep = sp if serves.all() else sp[serves[sp[:, 1]]]
                if len(keep):  # as columns, walker and channel in 4 bytes: 16 bytes a spike
                    self._keep_spikes(keep, walker_of)
            if end >= self._spikes_due:
                upto = end // self._spike_block * self._spike_block
                self._hand_spikes(upto)
                self._spikes_due = upto + self._spike_block
        return end - 1 if res.stopped else None

    def _keep_spikes(self, keep: np.ndarray, walker_of: np.ndarray | None) -> None:
        """Keep one advance's spikes (sample, walker, channel) for the logs. Advances that
        walked alike (the same walker for each receiver) make one piece: a serial run
        advances a few samples at a time, and a piece each made the hand-over's work grow
        with the advances, not the spikes."""
        same = self._pending_of is walker_of or (
            self._pending_of is not None
            and walker_of is not None
            and np.array_equal(self._pending_of, walker_of)
        )
        if self._pending and not same:
            self._close_pending()
        self._pending.append(keep)
        self._pending_of = walker_of

    def _close_pending(self) -> None:
        """The spikes kept since the walkers last changed, as one piece."""
        if not self._pending:
            return
        rows = np.concatenate(self._pending) if len(self._pending) > 1 else self._pending[0]
        self._pending = []
        self._spike_pieces.append(
            _SpikePiece(
                rows[:, 0].copy(),
                rows[:, 1].astype(np.int32),
                rows[:, 2].astype(np.int32),
                self._pending_of,
            )
        )

    def end_spikes(self, i: int, at: int | None = None) -> None:
        """Hand unit ``i`` every spike kept for its log (it stopped, or the run ended): its
        last block as far as the ears heard, or up to sample ``at`` (the rest is dropped)."""
        self._hand_spikes(at, only=i)

    def _hand_spikes(self, upto: int | None, only: int | None = None) -> None:
        """Each logged unit's kept spikes before sample ``upto`` (None: all), a block at a
        time, in the order (block, unit): which records a log holds, and their order, depend
        only on the blocks, not on how the ears advanced. Units that heard the same spikes in
        a block get them as one ``SharedSpikes``. ``only``: unit ``only``'s last spikes, its
        last block ending at ``upto`` (or as far as the ears heard); its spikes at or after
        ``upto`` are dropped, and it gets no more."""
        self._close_pending()
        if not self._spike_pieces:
            return
        heard = self.pos
        if only is None:  # a block boundary: the spikes before it, slices (no copy)
            mine, rest = [], []
            for p in self._spike_pieces:
                cut = len(p.k) if upto is None else int(p.k.searchsorted(upto))
                mine.append(p.cut(0, cut))
                if cut < len(p.k):
                    rest.append(p.cut(cut, len(p.k)))
            self._spike_pieces = rest
            members = np.flatnonzero(self._log_mask)
        else:  # the others still need the walks it took: read, not taken
            if self._spikes_ended[only]:  # handed its last already
                return
            self._spikes_ended[only] = True
            if upto is not None:
                heard = min(heard, upto)
            mine = [
                p if upto is None else p.cut(0, int(p.k.searchsorted(upto)))
                for p in self._spike_pieces
            ]
            members = np.array([only])
            self._log_mask[only] = False
        self._hand_blocks([p for p in mine if len(p.k)], members, heard)

    def _hand_blocks(self, pieces: list[_SpikePiece], members: np.ndarray, heard: int) -> None:
        """Hand the ``members`` their spikes in ``pieces`` (in time order), a block at a time:
        a unit's spikes in a block are its walker's in each piece. Units whose spikes in a
        block are equal share one ``SharedSpikes``, whichever walks they came from."""
        if not pieces or not members.size:
            return
        if self._hand_as_one(pieces, members, heard):
            return
        if sum(len(p.k) for p in pieces) <= SMALL_HAND_OVER:
            self._hand_blocks_small(pieces, members, heard)
            return
        U = len(self.listeners)
        B = self._spike_block
        k = np.concatenate([p.k for p in pieces])
        w = np.concatenate([p.w for p in pieces])
        c = np.concatenate([p.c for p in pieces])
        piece = np.repeat(np.arange(len(pieces)), [len(p.k) for p in pieces])
        block = k // B
        # segments: one piece within one block (in time order); sorted by (segment, walker),
        # stable, each walker's spikes of a segment are one run, in (sample, channel) order
        new = np.concatenate(([True], (block[1:] != block[:-1]) | (piece[1:] != piece[:-1])))
        seg = np.cumsum(new) - 1
        n_seg = int(seg[-1]) + 1
        if n_seg * U < 2**15:  # numpy's stable sort of a 16-bit key is a radix sort
            order = np.argsort((seg * U + w).astype(np.int16), kind="stable")
        else:
            order = np.lexsort((w, seg))
        k, w, c, seg = k[order], w[order], c[order], seg[order]
        starts = np.flatnonzero(np.concatenate(([True], (seg[1:] != seg[:-1]) | (w[1:] != w[:-1]))))
        ends = np.append(starts[1:], len(k))
        run = np.full((n_seg, U), -1, dtype=np.int64)  # (segment, walker) -> its run
        run[seg[starts], w[starts]] = np.arange(starts.size)
        seg_first = np.flatnonzero(new)  # in the unsorted order: each segment's block, piece
        seg_block, seg_piece = block[seg_first], piece[seg_first]
        # each segment's walker of every member (a piece where every receiver walked alone:
        # the member itself)
        src = np.empty((n_seg, members.size), dtype=np.int64)
        for p in np.unique(seg_piece).tolist():
            wo = pieces[p].walker_of
            src[seg_piece == p] = members if wo is None else wo[members]
        runs_of = np.where(src >= 0, run[np.arange(n_seg)[:, None], np.maximum(src, 0)], -1)
        blocks, first = np.unique(seg_block, return_index=True)
        bounds = [*first.tolist(), n_seg]
        starts_l, ends_l = starts.tolist(), ends.tolist()
        for b, s0, s1 in zip(blocks.tolist(), bounds, bounds[1:], strict=False):
            # a member's runs in this block, one per segment: equal rows, equal spikes
            if s1 - s0 == 1:  # one piece in this block (the usual case): a run a member
                sigs, inverse = np.unique(runs_of[s0], return_inverse=True)
                sigs = sigs[:, None]
            else:
                sigs, inverse = np.unique(runs_of[s0:s1].T, axis=0, return_inverse=True)
            groups: dict[tuple, list[int]] = {}  # equal spikes, from whichever walks
            arrays: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
            for g, sig in enumerate(sigs.tolist()):
                cuts = [(starts_l[r], ends_l[r]) for r in sig if r >= 0]
                if not cuts:
                    continue
                samples = np.concatenate([k[x:y] for x, y in cuts])
                channel = np.concatenate([c[x:y] for x, y in cuts])
                key: tuple[int, ...] = (len(samples), int(samples.sum()), int(channel.sum()))
                while key in arrays and not (
                    np.array_equal(arrays[key][0], samples)
                    and np.array_equal(arrays[key][1], channel)
                ):
                    key = (*key, g)  # the same sums, other spikes: a group of its own
                arrays.setdefault(key, (samples, channel))
                groups.setdefault(key, []).extend(
                    members[np.flatnonzero(inverse.reshape(-1) == g)].tolist()
                )
            end = min((b + 1) * B, heard)
            for key in sorted(groups, key=lambda key: min(groups[key])):
                samples, channel = arrays[key]
                self._hand_block(sorted(groups[key]), samples, channel, end)

    def _hand_blocks_small(
        self, pieces: list[_SpikePiece], members: np.ndarray, heard: int
    ) -> None:
        """``_hand_blocks`` for a few spikes (a serial run hands a block or two of a few
        spikes at a time, from receivers that each walked alone since their own quench):
        the same blocks, groups and order, grouped in plain Python, where the arrays' fixed
        cost per call was ~1 ms a hand-over."""
        B = self._spike_block
        mine: dict[int, dict[int, list[tuple[int, int]]]] = {}  # block -> member -> spikes
        for p in pieces:
            walks: dict[int, dict[int, list[tuple[int, int]]]] = {}  # walker -> block -> spikes
            for k, w, c in zip(p.k.tolist(), p.w.tolist(), p.c.tolist(), strict=True):
                walks.setdefault(w, {}).setdefault(k // B, []).append((k, c))
            of = None if p.walker_of is None else p.walker_of.tolist()
            for m in members.tolist():
                for b, spikes in walks.get(m if of is None else of[m], {}).items():
                    mine.setdefault(b, {}).setdefault(m, []).extend(spikes)
        for b in sorted(mine):
            groups: dict[tuple[tuple[int, int], ...], list[int]] = {}
            for m, spikes in mine[b].items():
                groups.setdefault(tuple(spikes), []).append(m)
            end = min((b + 1) * B, heard)
            for heard_alike, units in sorted(groups.items(), key=lambda g: min(g[1])):
                samples = np.array([k for k, _ in heard_alike], dtype=np.int64)
                channel = np.array([c for _, c in heard_alike], dtype=np.int32)
                self._hand_block(sorted(units), samples, channel, end)

    def _hand_as_one(self, pieces: list[_SpikePiece], members: np.ndarray, heard: int) -> bool:
        """``_hand_blocks`` where every member took one and the same walk in each piece (a
        noise-free medium through equal gains: the usual case), so all have the same spikes
        in every block: one group a block, with no grouping to do. False (nothing handed)
        otherwise."""
        parts = []
        for p in pieces:
            wo = p.walker_of
            if wo is None:
                if members.size != 1:
                    return False
                walker = int(members[0])
            else:
                walkers = wo[members]
                walker = int(walkers[0])
                if walker < 0 or not (walkers == walker).all():
                    return False
            mine = p.w == walker
            parts.append((p.k, p.c) if mine.all() else (p.k[mine], p.c[mine]))
        k = np.concatenate([a for a, _ in parts]) if len(parts) > 1 else parts[0][0]
        c = np.concatenate([b for _, b in parts]) if len(parts) > 1 else parts[0][1]
        if not k.size:
            return True
        B = self._spike_block
        units = sorted(members.tolist())
        blocks = k // B
        cuts = [*np.flatnonzero(blocks[1:] != blocks[:-1]) + 1, k.size]
        a = 0
        for z in cuts:
            z = int(z)
            self._hand_block(units, k[a:z], c[a:z], min((int(blocks[a]) + 1) * B, heard))
            a = z
        return True

    def _hand_block(
        self, units: list[int], samples: np.ndarray, channel: np.ndarray, end: int
    ) -> None:
        """One block's spikes (sample order, then channel) that ``units`` heard alike, heard
        up to ``end``: a unit's own ``spikes``, or one ``SharedSpikes`` for two or more."""
        # the channels that fired and each spike's index among them
        present = np.zeros(int(channel.max()) + 1, dtype=bool)
        present[channel] = True
        fired = np.flatnonzero(present)
        index = (np.cumsum(present, dtype=np.int32) - 1)[channel]
        if len(units) == 1:
            log = self.listeners[units[0]].spike_log
            assert log is not None
            log.spikes(samples, index, fired, end)
            return
        names = [self.listeners[u].name for u in units]
        logs = [cast(SpikeLog, self.listeners[u].spike_log) for u in units]
        if all(log.keeps_now() for log in logs):  # as the last of them to settle would write
            logs[-1].shared_kept(names, samples, index, fired, end)
            return
        share = SharedSpikes(samples, index, fired, end, units, names)
        for log in logs:
            log.shared_spikes(share)

    def _medium_rows(self, part: slice) -> tuple[np.ndarray, np.ndarray]:
        """Samples of these pulses, and what each unit hears there."""
        if self._timed:  # each share is one listener's: added in the order the shares come
            rows, where = np.unique(self._rows[part], return_inverse=True)
            rcv, who = self._rcv[part], self._who[part]
            heard = np.zeros((rows.size, len(self.listeners)))
            np.add.at(heard, (where, rcv), self._val[part] * self._gains[rcv, who])
            return rows, heard
        return heard_by(
            self._rows[part], self._who[part], self._val[part], self._gains, self._unit_gains
        )

    # -- traces ---------------------------------------------------------------------------------

    def _add_trace(self, n: int, lo: int, x: np.ndarray, y: np.ndarray) -> None:
        buf = self._trace_buf.setdefault(n, [])
        buf.append((lo, x, y))
        first = buf[0][0]
        end = lo + x.shape[0]
        w0 = first // self.window
        while (w0 + 1) * self.window <= end:
            self._emit_trace(n, (w0 + 1) * self.window)
            buf = self._trace_buf.get(n, [])
            if not buf:
                return
            w0 = buf[0][0] // self.window

    def _emit_trace(self, n: int, upto: int) -> None:
        """Hand unit n the trace rows before ``upto`` (a window boundary, or where it stopped)."""
        buf = self._trace_buf.get(n, [])
        if not buf:
            return
        first = buf[0][0]
        xs = np.concatenate([b[1] for b in buf])
        ys = np.concatenate([b[2] for b in buf])
        k = upto - first
        sink = self.listeners[n].trace
        assert sink is not None
        sink(first, xs[:k], ys[:k])
        rest = [(upto, xs[k:], ys[k:])] if xs.shape[0] > k else []
        self._trace_buf[n] = rest

    def _flush_trace(self, n: int) -> None:
        buf = self._trace_buf.get(n, [])
        if buf:
            self._emit_trace(n, buf[-1][0] + buf[-1][1].shape[0])


SMALL_HAND_OVER = 4096  # spikes of a hand-over grouped in plain Python (_hand_blocks_small)
WALK_LANE_SAMPLES = 1 << 22  # a logged run's advance: about this many lane-samples at most
QUEUE_CHUNK = 256  # positions of a shared queue read (for every receiver) and kept together
QueueRead = Callable[[int], tuple[np.ndarray, np.ndarray, np.ndarray]]


class _QueueDecodes:
    """A shared listen queue's decodes for every receiver of the ears: chunks of
    ``QUEUE_CHUNK`` positions, each (positions × receivers) arrays of word, channel and
    margin, filled in order as units reach them and dropped once every listening unit has
    passed them (a run of n units decodes 4n²(n−1) codes: no object each)."""

    def __init__(self, queue: object, receivers: int) -> None:
        self.queue = queue  # kept alive: the ears find it by id
        self.receivers = receivers
        self.cursor = np.zeros(receivers, dtype=np.int64)  # each unit's next position
        self.chunks: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]] = {}

    def rows(
        self, c: int, lo: int, hi: int, read: QueueRead, i: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        chunk = self.chunks.get(c)
        if chunk is None:
            R = self.receivers
            chunk = self.chunks[c] = (
                np.empty((QUEUE_CHUNK, R), dtype=np.int64),
                np.empty((QUEUE_CHUNK, R), dtype=np.int64),
                np.empty((QUEUE_CHUNK, R)),
                [0],  # positions filled
            )
        word, chan, margin, filled = chunk
        base = c * QUEUE_CHUNK
        a, b = max(lo, base) - base, min(hi, base + QUEUE_CHUNK) - base
        while filled[0] < b:  # in order: every position before is heard too
            k = filled[0]
            word[k], chan[k], margin[k] = read(base + k)
            filled[0] = k + 1
        return word[a:b, i], chan[a:b, i], margin[a:b, i]

    def forget(self, low: int) -> None:
        """Drop the chunks every listening unit has passed (``low``: the least cursor)."""
        for c in [c for c in self.chunks if (c + 1) * QUEUE_CHUNK <= low]:
            del self.chunks[c]


def _fire(ev: simpy.Event) -> None:
    if not ev.triggered:
        ev.succeed()
