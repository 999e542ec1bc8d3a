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
sample. A wake is a plain call, not a SimPy event per unit: a large run wakes its units once per
decode, and an event, a generator resume and a heap entry each time would cost more than the
wake's own work. The simulated time of a wake is exact all the same. The ears
advance only when every listening unit has asked, never past the smallest
boundary asked for nor past the horizon of the known medium (``hear``), and stop at the first
watched spike of any unit: what a unit reacts to happens in time order, each at its exact
sample. A unit's quench times (``quench_at``: its resonators back to rest before a sample)
are the ears' to keep: they need no wake-up.

The ears walk the resonators only when a spike matters: a unit whose plans can wait for one
(``Listener.awaits``), a log of spikes (``SpikeKeeper``, handed a block at a time) or traces
(``TraceWindows``). A
decode reads the increment readout, which is the input each unit heard
(``input_readout``), so a run with none of the three needs no walk at all.

``dense=True`` is the time-stepped reference: every window of ``window`` samples is fed to
every unit, silent or not.
"""

from __future__ import annotations

import heapq
from collections.abc import Generator, Mapping, Sequence
from typing import Any

import numpy as np
import simpy

from rgtbus.engine.listener import HEARD_NOTHING, Heard, Listener, Wake
from rgtbus.engine.queues import SharedQueues
from rgtbus.engine.reading import Readings
from rgtbus.engine.spike_log import SpikeKeeper
from rgtbus.engine.traces import TraceWindows
from rgtbus.errors import BadInput
from rgtbus.protocol import NEVER
from rgtbus.signal.channel import heard_by, render
from rgtbus.signal.decoder import ReadoutHistory
from rgtbus.signal.pulses import Pulses
from rgtbus.signal.resonator import (
    BankModel,
    BankState,
    ResonatorBank,
    first_spike,
    input_readout,
    resonate,
)
from rgtbus.timebase import sample_of, time_of


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
            raise BadInput(f"{len(listeners)} listeners for a bank of {bank.n_receivers}")
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
                raise BadInput("some listeners hear delays and clocks and others do not")
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
        # rest before a sample: the samples (a heap, each once) and the units at each (every
        # unit of a concurrent run quenches at each round's start: n a sample, n² in all)
        self._quench: list[int] = []
        self._quench_units: dict[int, list[int]] = {}
        self.quiet = env.event()  # every unit is done listening
        self._gains = np.stack([lst.gains for lst in self.listeners])  # listeners × senders
        self._unit_gains = bool(np.all(self._gains == 1.0))
        self._unit_gain = [bool(np.all(lst.gains == 1.0)) for lst in self.listeners]
        self.kept = SpikeKeeper(self.listeners)  # the spikes of logged units, for their logs
        self._lane_models: dict[int, BankModel] = {}  # one resonator picked out, per channel
        self._traced = any(lst.trace is not None for lst in self.listeners)
        # the dense engine is the reference: it walks every resonator every sample, always
        self._walks = dense or any(
            lst.awaits or lst.spike_log is not None or lst.trace is not None
            for lst in self.listeners
        )
        self.traces = TraceWindows(self.listeners, window)
        self.steps = 0  # bank advances so far
        # every decode on the readout, single codes and a batch's columns (engine/reading.py)
        self.reading = Readings(self.readout, tuple(float(w) for w in bank.omegas), self.tau)
        self.queues = SharedQueues(len(self.listeners))  # what every unit reads alike
        self._read_span = max(1, sample_of(READ_AS_HEARD_SECONDS, self.tau))
        self.pos = bank.n_fed  # the next sample the ears will hear (only _advance moves it)
        self.process = env.process(self._run())

    # -- the world's side ---------------------------------------------------------------------

    def links_changed(self) -> None:
        """A listener's gains or arrivals changed (a steered run): the ears hear with the new
        ones what they are handed from now on."""
        if self._timed:
            self._arrival = np.stack([lst.arrival for lst in self.listeners])  # type: ignore[misc]
        self._gains = np.stack([lst.gains for lst in self.listeners])
        self._unit_gains = bool(np.all(self._gains == 1.0))
        self._unit_gain = [bool(np.all(lst.gains == 1.0)) for lst in self.listeners]

    @property
    def timed(self) -> bool:
        """Whether pulses land off their samples (delays, clocks): see ``hear``'s ``cuts``."""
        return self._timed

    def hear(
        self, horizon: int, pulses: Mapping[str, Pulses], cuts: Mapping[str, int] | None = None
    ) -> None:
        """The medium is now known up to ``horizon`` (exclusive): these are the new pulses.
        Timed, ``cuts`` may say, sender by sender, how far its pulses are known (at least
        ``horizon``: its promise): a sender's unknown pulses then land no earlier than its cut
        mapped onto each listener's samples, and with propagation delays the ears' horizon
        passes ``horizon`` by the shortest delay from the binding sender (the lookahead a
        channel's speed gives, docs/engine.md)."""
        if horizon < self.horizon and not self._timed:  # timed: on the listeners' samples
            raise BadInput(f"horizon {horizon} goes back from {self.horizon}")
        parts = [(n, pulses[u]) for n, u in enumerate(self.senders) if u in pulses]
        parts = [(n, p) for n, p in parts if p[0].size]
        if self._timed:
            parts, horizon = self._landed(parts, horizon, cuts)
        if parts:
            rows = np.concatenate([p[0] for _, p in parts])
            if rows.min() < self.horizon:
                raise BadInput(f"a pulse at sample {int(rows.min())} arrived after its time")
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
                # a near sender's new pulses may land before a far one's known ones: in
                # sample order, each sample's shares in the order they came
                merged = np.argsort(self._rows, kind="stable")
                self._rows, self._who = self._rows[merged], self._who[merged]
                self._val, self._rcv = self._val[merged], self._rcv[merged]
            self._cur = 0
        self.horizon = horizon
        _fire(self._more)

    def _landed(
        self, parts: list[tuple[int, Pulses]], horizon: int, cuts: Mapping[str, int] | None
    ) -> tuple[list[tuple[int, Any]], int]:
        """Timed: each sender's pulses as every listener gets them (``render``), with the
        listener of each share; and the horizon on the listeners' samples: the earliest
        sample a pulse not yet known (sent at or after its sender's cut, else ``horizon``)
        could land on: min over listener l and sender s of ⌊a_ls + b_ls · cut_s⌋."""
        A = self._arrival  # listeners × 2 × senders
        out: list[tuple[int, Any]] = []
        for n, (rows, vals) in parts:
            for lst in range(A.shape[0]):
                r, v = render(rows, vals, float(A[lst, 0, n]), float(A[lst, 1, n]))
                out.append((n, (r, v, np.full(r.size, lst, dtype=np.int64))))
        if horizon < NEVER:
            cut = np.full(len(self.senders), float(horizon))
            if cuts:
                for n, u in enumerate(self.senders):
                    cut[n] = max(horizon, min(cuts.get(u, horizon), NEVER - 1))
            at = A[:, 0, :] + A[:, 1, :] * cut[None, :]
            horizon = int(min(np.floor(at.min()), NEVER))
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
            raise BadInput(f"{lst.name} stopped listening")
        if boundary < self.pos:
            raise BadInput(f"{lst.name}: boundary {boundary} is behind the ears ({self.pos})")
        if lst.request is None:
            self._asking -= 1
        lst.request = (boundary, at, wake)
        lst.watch = watch
        lst.watch_from = watch_from
        if not self._asking:
            _fire(self._poke)

    def quench_at(self, i: int, sample: int) -> None:
        """Unit ``i``'s resonators back to rest before ``sample`` (the ears stop there)."""
        if sample < self.pos:
            raise BadInput(
                f"{self.listeners[i].name}: quench before sample {sample}, "
                f"but the ears are at {self.pos}"
            )
        units = self._quench_units.get(sample)
        if units is None:
            self._quench_units[sample] = [i]
            heapq.heappush(self._quench, sample)
        else:
            units.append(i)

    def quench_between(self, i: int, lo: int, hi: int) -> list[int]:
        """The samples in [lo, hi) before which unit ``i``'s resonators go back to rest."""
        return sorted(
            q for q, units in self._quench_units.items() if lo <= q < hi for n in units if n == i
        )

    @property
    def spikes_from(self) -> int:
        """No block of spikes still to be handed to a unit's log ends before this sample (the
        last boundary the keeper handed blocks over at; or the present, with no spike log)."""
        kept = self.kept
        return kept.due - kept.block if kept.logging else self.pos

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
        self.queues.stop(i)
        self.kept.stop(i)
        self.end_spikes(i, at)
        if lst.trace is not None:
            self.traces.flush(i)
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
            raise BadInput(f"{lst.name}: a look-ahead for a spike on a timed channel")
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

    def _run(self) -> Generator[simpy.Event, Any, None]:
        """The ears' SimPy process: advance while every listening unit has asked, wake each at
        its spike or boundary, wait for the world when the known medium ends."""
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
            if self._quench and self._quench[0] == self.pos:
                heapq.heappop(self._quench)
                # before this sample: one copy of the state for all of them, in unit order
                resting = sorted(
                    n for n in self._quench_units.pop(self.pos) if self.listeners[n].active
                )
                if resting:
                    self.bank.quench(resting)
            boundary = min(lst.request[0] for lst in live)  # type: ignore[index]
            target = min(boundary, self.horizon)
            if self._quench:
                target = min(target, self._quench[0])
            for lst in live:  # a watch that starts later splits the advance there
                if lst.watch is not None and lst.watch_from > self.pos:
                    target = min(target, lst.watch_from)
            if self.dense:
                target = min(target, (self.pos // self.window + 1) * self.window)
            if self.queues.eager:  # a queue read as heard reads back no further than this
                target = min(target, self.pos + self._read_span)
            if self.kept.logging and self._walks:  # what the walk and the hand-over hold stays
                # small in a large run (a block or so of every lane's spikes), while a small
                # one still advances a long wait at once
                blocks = WALK_LANE_SAMPLES // (self.bank.model.lanes * self.kept.block)
                target = min(target, self.kept.due + blocks * self.kept.block)
            if self.pos < target:
                k = self._advance(target)
                self.queues.read_heard(self.pos)
                if k is not None:  # a watched spike: wake whoever watched it, at its time
                    yield env.timeout(max(0.0, time_of(k, self.tau) - env.now))
                    yield env.timeout(0)  # after what is already due then (see _after_due)
                    for lst in self.listeners:
                        if lst.active and lst.heard and lst.heard[-1][0] == k:
                            chans = lst.heard[-1][1]
                            if lst.watch in chans and k >= lst.watch_from:
                                self._wake(lst, reached=False)
                continue
            due = sorted(
                (lst.request[1], n)
                for n, lst in enumerate(self.listeners)
                if lst.active and lst.request is not None and lst.request[0] == self.pos
            )
            if due:
                woke_at = None
                for at, n in due:
                    if time_of(at, self.tau) > env.now:
                        yield env.timeout(time_of(at, self.tau) - env.now)
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
            wake(HEARD_NOTHING if reached else Heard((), False))

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
                    self.traces.add(n, lo, res.z[:, n].real, res.y[:, n])
        # sorted by sample, receiver, channel: the walkers' alone when receivers walked as
        # one (``walker_of``: each receiver's walker), every receiver's otherwise
        sp, walker_of = res.spikes, res.walker_of
        if len(sp) and res.stopped:  # a watched spike: the unit that watched it wakes for it
            for k, w, ch in sp[sp[:, 0] == end - 1].tolist():
                for n in [w] if walker_of is None else np.flatnonzero(walker_of == w).tolist():
                    lst = self.listeners[n]
                    if lst.active and ch == lst.watch and k >= lst.watch_from:
                        lst.heard.append((k, (ch,)))
        if self.kept.logging:  # kept for the logs, handed over a block at a time
            self.kept.keep(sp, walker_of)
            self.kept.heard_to(end)
        return end - 1 if res.stopped else None

    def end_spikes(self, i: int, at: int | None = None) -> None:
        """Hand unit ``i`` every spike kept for its log (it stopped, or the run ended): its
        last block as far as the ears heard, or up to sample ``at`` (the rest is dropped)."""
        self.kept.end(i, self.pos, at)

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


WALK_LANE_SAMPLES = 1 << 22  # a logged run's advance: about this many lane-samples at most
# with a queue read as it is heard (``SharedQueues.read_as_heard``), the ears advance at most
# this far at a time: a position is read at most this long after its last sample
READ_AS_HEARD_SECONDS = 10.0


def _fire(ev: simpy.Event) -> None:
    if not ev.triggered:
        ev.succeed()
