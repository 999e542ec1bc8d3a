"""The SimPy world: the medium, the units' ears and the conservative time horizon (docs/engine.md).

The world moves from event to event. Every local member publishes what it transmits (its pulses,
as soon as they are planned) and a promise "nothing more from me before sample t"
(``promise``: its earliest unplanned send, ``NEVER`` once it is done). The medium before the
smallest promise of all members, local or in other processes, is final: the world takes it from
the bus, hands it to the ears, and lets SimPy run every event before it — spikes, reactions
(timeouts of the reaction delay), decodes, decisions — each at its exact sample. Then the
members promise again (conservative synchronisation with null messages, Chandy–Misra–Bryant;
the reaction delay is the lookahead that keeps the promises ahead). Silence costs nothing.

``engine="dense"`` is the time-stepped reference: the horizon moves one window (``timing.window``)
at a time, every member publishes every window and every unit feeds its own resonators every
sample. Both engines give identical results.

The run ends when every member is done (decided or failed; a done unit listens no more) and
every transmission is out. The world knows members only through ``Member`` (no import of
``units/``); remote members only through the bus.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import simpy
import simpy.rt

from rgtbus.bus.base import Bus
from rgtbus.bus.payload import FAILED, FINAL, NEVER
from rgtbus.checks import ENGINES
from rgtbus.engine.hearing import Ears
from rgtbus.engine.listener import OwnHearing, Reception
from rgtbus.engine.steering import SteeredMember, Steering
from rgtbus.errors import BadInput, MembersSilent, RgtbusError
from rgtbus.scenario import Scenario
from rgtbus.signal.channel import Channel, Clock
from rgtbus.signal.pulses import Pulses, medium_sum, merge_pulses, split_pulses
from rgtbus.signal.resonator import ResonatorBank
from rgtbus.steering import Refused
from rgtbus.telemetry import Recorder, records
from rgtbus.telemetry.group_log import GroupLog
from rgtbus.timebase import ns, time_of


class Member(SteeredMember, Protocol):
    """What the world uses of a local unit (and steering: ``SteeredMember``)."""

    name: str
    done: bool
    done_at: int
    failure: str | None

    def hearing(self) -> OwnHearing: ...
    def join_log(self, group: GroupLog, at: int) -> None: ...
    def begin(self, env: simpy.Environment, ears: Ears, index: int) -> None: ...
    def take_outbox(self) -> Pulses: ...
    def promise(self, horizon: int) -> int: ...
    def awaited(self) -> tuple[int, int, int] | None: ...


_NONE: Pulses = (np.zeros(0, dtype=np.int64), np.zeros(0))


@dataclass(frozen=True)
class Receivers:
    """How the units hear: every unit has one resonator per channel of the run, and hears
    the medium as the run's channel makes it (``reception``: each receiver's view)."""

    omegas: tuple[float, ...]
    mode: str
    tau: float
    reception: Reception


@dataclass
class WorldResult:
    steps: int  # rounds of the horizon (windows for the dense engine)
    sim_seconds: float
    wall_seconds: float
    failure: str | None  # the world's own: a member gone or stalled, the log ended
    bus_stats: dict[str, Any] = field(default_factory=dict)
    end_sample: int = 0  # the last sample of the run
    silent: tuple[str, ...] = ()  # the members it gave up on (no news within the timeout)
    sync: dict[str, Any] = field(default_factory=dict)  # SyncCost.as_dict()


@dataclass
class SyncCost:
    """What keeping the members' clocks together cost a world (docs/engine.md, "The cost of
    the clock"): rounds of the horizon, frames its members published (``null_frames``: a
    promise and no pulse), wall seconds blocked in ``bus.wait`` (waiting for other processes,
    their work included), and the rounds in which propagation delays let the ears run past
    the horizon (``ahead_rounds``)."""

    members: int = 0
    rounds: int = 0
    frames: int = 0
    null_frames: int = 0
    wait_seconds: float = 0.0
    ahead_rounds: int = 0

    def as_dict(self) -> dict[str, Any]:
        return {
            "members": self.members,
            "rounds": self.rounds,
            "frames": self.frames,
            "null_frames": self.null_frames,
            "wait_seconds": round(self.wait_seconds, 3),
            "ahead_rounds": self.ahead_rounds,
        }


PACED_SLICE_WALL = 0.5  # wall seconds a paced world sleeps at most before it looks at the bus


class World:
    """Runs local members over a bus until every member is done; see the module docstring."""

    def __init__(
        self,
        members: Sequence[Member],
        bus: Bus,
        recorder: Recorder,
        receivers: Receivers,
        *,
        window_samples: int,
        engine: str = "event",
        timeout: float = 5.0,
        progress: Callable[[float, int], None] | None = None,
        write_medium: bool = True,
        realtime: float | None = None,
        steering: Steering | None = None,
    ) -> None:
        if engine not in ENGINES:
            raise BadInput(f"unknown engine {engine!r} (use {', '.join(ENGINES)})")
        if window_samples < 1:
            raise BadInput(f"window of {window_samples} samples: need at least one")
        self.members = list(members)
        self.bus = bus
        self.recorder = recorder
        self.receivers = receivers
        self.tau = receivers.tau
        self.window = window_samples
        self.engine = engine
        self.timeout = timeout
        self.progress = progress
        self.write_medium = write_medium  # one process of a cross-process run logs the medium
        self.env: simpy.Environment = (
            simpy.rt.RealtimeEnvironment(factor=1.0 / realtime, strict=False)
            if realtime
            else simpy.Environment()
        )
        # A paced world sleeps toward the horizon in slices of this much simulated time, and
        # asks the bus between them: a member's promise far ahead (an impostor's frame taken
        # before the member's own) is never a sleep of years, and its fault ends the run.
        self._slice = PACED_SLICE_WALL * realtime if realtime else math.inf
        self.failure: str | None = None
        self.steps = 0
        self.horizon = 0
        self._medium: dict[str, list[Pulses]] = {}  # pulses received, not yet logged
        self._last_pulse = -1
        self._held: dict[str, list[Pulses]] = {m.name: [] for m in self.members}
        self._sent_promise: dict[str, int] = {m.name: -1 for m in self.members}
        self._sent_flags: dict[str, int] = {m.name: 0 for m in self.members}
        self._ears: list[Ears] = []
        self._group_log: GroupLog | None = None  # the local units' log, when logged
        self._where: dict[str, tuple[Ears, int]] = {}
        self._ahead: dict[str, Pulses] = {}  # local members' published pulses not yet heard
        self._heard = 0  # the world ran every event before this sample
        self.sync = SyncCost(members=len(self.members))
        # Timed channels with delays only (no clock of its own): each sender's pulses are
        # handed to the ears up to its promise (``_fed``: how far), so the ears run ahead of
        # the horizon by the shortest propagation delay from the binding sender.
        self._ahead_of_horizon = False  # set with the ears (``_build_ears``)
        self._fed: dict[str, int] = {}
        self.steering = steering  # a steered run's changes, applied at window boundaries
        self._steered_channel: Channel | None = None  # its channel as changed (clocks)

    @classmethod
    def for_scenario(
        cls,
        sc: Scenario,
        members: Sequence[Member],
        bus: Bus,
        recorder: Recorder,
        **options: Any,
    ) -> World:
        """The world of a scenario's ``members``: its channels, resonator mode and sample
        rate; its window (the medium's log blocks, and the dense engine's step)."""
        tau = sc.timing.tau
        receivers = Receivers(
            tuple(sc.frequencies[u] for u in sc.units),
            sc.mode,
            tau,
            Reception(sc.channel, sc.units, sc.seed, tau),
        )
        return cls(
            members, bus, recorder, receivers, window_samples=sc.timing.window_samples, **options
        )

    # -- set-up ---------------------------------------------------------------------------------

    def _build_ears(self) -> None:
        r = self.receivers
        if self.recorder.enabled:  # the local units' pulses and alike decodes: one record
            names = [m.name for m in self.members]  # the log in time order (GroupLog.clock)
            shared = GroupLog(self.recorder, r.tau, names, ordered=self.recorder)
            self._group_log = shared
            for k, m in enumerate(self.members):
                m.join_log(shared, k)
        dense = self.engine == "dense"
        # The event engine shares one bank among its local units; the reference gives each
        # unit its own, fed every window.
        groups = [[m] for m in self.members] if dense else [self.members]
        arrivals: list[np.ndarray | None] = []
        for group in groups:
            if not group:
                continue
            bank = ResonatorBank(r.omegas, mode=r.mode, tau=r.tau, n_receivers=len(group))
            listeners = [r.reception.listener(m.name, m.hearing()) for m in group]
            arrivals.extend(lst.arrival for lst in listeners)
            ears = Ears(
                self.env,
                self.bus.members,
                listeners,
                bank,
                dense=dense,
                window=self.window,
            )
            self._ears.append(ears)
            for i, m in enumerate(group):
                m.begin(self.env, ears, i)
                self._where[m.name] = (ears, i)
        # (a steered world's ears hear no further than the horizon: a change may come there)
        self._ahead_of_horizon = not dense and self.steering is None and _delays_only(arrivals)

    # -- the SimPy process ------------------------------------------------------------------

    def _coordinate(self) -> Generator[simpy.Event, Any, None]:
        """The world's SimPy process: publish, wait for the horizon, let the ears hear and the
        units act up to it, again, until every member is done; then what is on its way."""
        env = self.env
        self._build_ears()
        yield env.timeout(0)  # every unit begins (its first sends and requests)
        steering = self.steering
        while True:
            if steering is not None:  # what is due at this horizon, before anyone plans on
                steering.poll(self.computed(), self._promised())
                steering.apply(self, self.horizon)
                steering.gate(self)
            self._publish()
            if self._finished():
                break
            beyond = self.horizon + self.window - 1 if self.engine == "dense" else self.horizon
            waited = time.perf_counter()
            h = self.bus.wait(beyond, timeout=self.timeout, stop=self._change_came)
            self.sync.wait_seconds += time.perf_counter() - waited
            if self.engine == "dense":
                h = min(h, self.horizon + self.window)
            if steering is not None:
                # a change placed by another process at this very horizon came while this
                # one waited (it could not pass it before): applied before anything after it
                steering.poll(self.computed(), self._promised())
                steering.apply(self, self.horizon)
                h = min(h, max(self.horizon, steering.next_at()))  # nothing heard past the next
            pulses = self.bus.take(h)
            cuts = None
            if self._ahead_of_horizon and h < NEVER:
                pulses, cuts = self._up_to_promises(h, pulses)
            self.horizon = h
            self.steps += 1
            for ears in self._ears:
                ears.hear(h, pulses, cuts)
            self._log_medium(pulses, final_before=h)
            if self.progress is not None:
                self.progress(env.now, self.steps)
            if h < NEVER:
                # the ears hear no further than their own horizon (pulses that land later on
                # a listener's samples than they were sent: delays, clocks); with each
                # sender's pulses known up to its promise, past h by the shortest delay
                heard = min([h, *(e.horizon for e in self._ears)])
                if cuts is not None and self._ears:
                    heard = min(e.horizon for e in self._ears)
                    if heard > h:
                        self.sync.ahead_rounds += 1
                self._heard = max(h, heard)
                until = (heard - 0.5) * self.tau
                while until - env.now > self._slice:
                    yield env.timeout(self._slice)
                    self.bus.wait(h - 1, timeout=self.timeout)  # every promise is past: a look
                yield env.timeout(max(0.0, until - env.now))
            else:  # every member promised silence: run until the local units are done
                yield env.all_of([e.quiet for e in self._ears])
        if steering is not None:
            steering.finish(self)
        end = self.end_sample()
        self._log_medium({}, final_before=NEVER)
        # what is still on its way (transmissions of units that are done) goes out
        yield env.timeout(max(0.0, (end + 0.5) * self.tau - env.now))

    def _up_to_promises(
        self, h: int, taken: dict[str, Pulses]
    ) -> tuple[dict[str, Pulses], dict[str, int]]:
        """Each member's pulses up to its own promise (its cut: every pulse before it has
        arrived, frames keep their order), not only up to the horizon ``h``: what was taken,
        and what the bus holds past ``h`` below the cut; less what earlier rounds handed the
        ears already (``_fed``). Returns those pulses and the cuts."""
        cuts = {u: max(h, s.promise) for u, s in self.bus.status().items()}
        pending = self.bus.known(NEVER)  # not yet taken: all at or after h
        out: dict[str, Pulses] = {}
        for u, cut in cuts.items():
            fed = self._fed.get(u, 0)
            parts = [p for p in (taken.get(u, _NONE), split_pulses(pending.get(u, _NONE), cut)[0])
                     if p[0].size]  # fmt: skip
            out[u] = split_pulses(merge_pulses(parts), fed)[1] if parts else _NONE
            self._fed[u] = max(fed, cut)
        return out, cuts

    def _publish(self) -> None:
        """Every local member's frame: its new pulses and its promise (event engine), or its
        pulses of the next window and the window's end (dense engine)."""
        fresh: dict[str, Pulses] = {}
        for m in self.members:
            samples, values = m.take_outbox()
            if samples.size:
                self._held[m.name].append((samples, values))
                fresh[m.name] = (samples, values)
        dense = self.engine == "dense"
        promises = self._promises(fresh) if self.engine == "event" else {}
        binding = self._binding(promises) if promises else set()
        hold = NEVER if self.steering is None else self.steering.hold()
        for m in self.members:
            flags = (FAILED if m.failure else FINAL) if m.done else 0
            held = merge_pulses(self._held[m.name]) if self._held[m.name] else _NONE
            if dense:
                limit = self.horizon + self.window
                now, later = split_pulses(held, limit)
                promise = NEVER if m.done and not later[0].size else limit
                self._held[m.name] = [later] if later[0].size else []
            else:
                now = held
                self._held[m.name] = []
                promise = promises[m.name]
            if hold < NEVER:  # not past a change the other processes lack
                promise = max(min(promise, hold), self._sent_promise[m.name])
            changed = (
                now[0].size
                or flags != self._sent_flags[m.name]
                or dense
                or (promise != self._sent_promise[m.name] and m.name in binding)
            )
            if changed:
                self.sync.frames += 1
                self.sync.null_frames += not now[0].size
                self.bus.publish(
                    m.name,
                    now[0],
                    now[1],
                    promise=promise,
                    flags=flags,
                    done_at=m.done_at if m.done else 0,
                )
                if now[0].size and self.engine == "event":
                    self._ahead[m.name] = merge_pulses([self._ahead.get(m.name, _NONE), now])
                self._sent_promise[m.name] = promise
                self._sent_flags[m.name] = flags

    def _promises(self, fresh: dict[str, Pulses]) -> dict[str, int]:
        """Each local member's promise: its protocol's earliest unplanned send given that it
        heard no spike to react to before the horizon; sharpened, for a member whose promise
        holds everyone back, by looking ahead at its own resonators: every other member has
        promised silence until B, so the pulses already planned are all it will hear before
        B, and its reaction cannot come before its first spike on them."""
        h = self.horizon
        for u, p in list(self._ahead.items()):  # what is before the horizon has been heard
            if p[0].size and p[0][0] < h:
                self._ahead[u] = split_pulses(p, h)[1]
        # every event before the heard horizon ran: no spike before it is still to come
        plain = {m.name: m.promise(max(h, self._heard)) for m in self.members}
        remote = [s.promise for u, s in self.bus.status().items() if u not in plain]
        out = dict(plain)
        least = _two_least([*plain.values(), *remote])
        # a steered world makes no look-ahead: a change may come for any sample past the horizon
        for m in self.members if self.steering is None else ():
            bound = least[1] if plain[m.name] == least[0] else least[0]  # every other's least
            aw = m.awaited()
            if aw is None or plain[m.name] >= bound or m.name not in self._where:
                continue
            ears, i = self._where[m.name]
            until = min(bound, aw[2] + 1)  # no reaction after the ID's deadline
            # Remote members' pulses as received; the local ones' as sent (a bus may hand our
            # own frames back later than the peers' frames that depend on them).
            known = {u: p for u, p in self.bus.known(until).items() if u not in plain}
            for u in plain:
                parts = [split_pulses(self._ahead[u], until)[0]] if u in self._ahead else []
                if u in fresh:
                    parts.append(fresh[u])
                known[u] = merge_pulses(parts)
            k = ears.peek(i, until, known, ears.quench_between(i, h, until), aw[0], aw[1])
            out[m.name] = m.promise(until if k is None else k)
        # A promise made stays true: a later one computed without a look-ahead may be lower.
        return {u: max(p, self._sent_promise[u]) for u, p in out.items()}

    def _binding(self, promises: dict[str, int]) -> set[str]:
        """The local members whose last promise may hold the horizon back: those not above
        every other member's newest promise. The others need send no null message yet (an
        older, lower promise stays true); once theirs is the smallest, the horizon has
        reached it, the world runs a round, and they send it then."""
        remote = [s.promise for u, s in self.bus.status().items() if u not in promises]
        least = _two_least([*promises.values(), *remote])
        out = set()
        for u, p in promises.items():
            others = least[1] if p == least[0] else least[0]  # the least promise but u's
            if self._sent_promise[u] <= others:
                out.add(u)
        return out

    def _finished(self) -> bool:
        status = self.bus.status()
        return all(s.flags and s.promise == NEVER for s in status.values())

    def end_sample(self) -> int:
        """The run's last sample: the last sample any member listened to or transmitted."""
        done = [s.done_at for s in self.bus.status().values() if s.flags]
        return max([*done, self._last_pulse, 0])

    # -- steering (``rgtbus.engine.steering``) ------------------------------------------------

    def computed(self) -> int:
        """How far the run has computed: no change may take effect before this sample (past
        the run's last sample once every member promised silence)."""
        k = max([self.horizon, self._heard, *(e.horizon for e in self._ears)])
        if k >= NEVER:
            k = max([self.end_sample() + 1, *(e.pos for e in self._ears)])
        return k

    def _change_came(self) -> bool:
        """While waiting for the others: whether a change came that is due at this very
        horizon (another process placed it here: it is applied before waiting on)."""
        st = self.steering
        if st is None or len(self.bus.local) == len(self.bus.members):
            return False
        st.poll(self.computed(), self._promised())
        return st.next_at() <= self.horizon

    def _promised(self) -> int:
        """What a change placed here must not precede, besides what this process computed:
        in a run across processes, the least promise its members have sent (no other process
        has passed it); in one process, nothing."""
        if len(self.bus.local) == len(self.bus.members):
            return 0
        return min(self._sent_promise.values(), default=0)

    def member(self, name: str) -> Member | None:
        """The local member ``name``; None: a member of the run that runs in another process
        (``Refused``: no member at all)."""
        for m in self.members:
            if m.name == name:
                return m
        if name in self.bus.members:
            return None
        raise Refused(f"unit {name!r} is not a member of this run")

    def set_noise(self, sigma: float) -> None:
        """Every local receiver's white noise is σ = ``sigma`` from the horizon on."""
        reception = self.receivers.reception
        for ears in self._ears:
            for lst in ears.listeners:
                reception.set_noise(lst, sigma)

    def set_gain(self, link: tuple[str, str], gain: float) -> None:
        """Link ``link``'s gain at its receiver is ``gain`` from the horizon on."""
        reception = self.receivers.reception
        for ears in self._ears:
            if any(lst.name == link[1] for lst in ears.listeners):
                for lst in ears.listeners:
                    if lst.name == link[1]:
                        reception.set_gain(lst, link[0], gain)
                ears.links_changed()

    def set_drift(self, unit: str, ppm: float, at: int) -> None:
        """Unit ``unit``'s clock drifts ``ppm`` from its sample ``at`` on, running on from
        where it is (its offset moves so that its sample ``at`` keeps its true time):
        ``offset' = offset + at·τ·(rate − rate')``. Where each sender's samples land on
        each local receiver's is worked out again (``Channel.arrivals``) for what is heard
        from the horizon on."""
        reception = self.receivers.reception
        ch = self._steered_channel or reception.channel
        old = ch.clocks.get(unit, Clock())
        new = Clock(old.offset + at * self.tau * (old.rate - (1 + ppm * 1e-6)), ppm)
        ch = dataclasses.replace(ch, clocks={**ch.clocks, unit: new})
        self._steered_channel = ch
        for ears in self._ears:
            for lst in ears.listeners:
                lst.arrival = ch.arrivals(reception.units, lst.name, self.tau)
            ears.links_changed()

    def set_pace(self, realtime: float) -> None:
        """A paced world's clock runs at ``realtime`` simulated seconds a wall second now."""
        if isinstance(self.env, simpy.rt.RealtimeEnvironment):
            self.env.sync()
            self.env._factor = 1.0 / realtime  # simpy's own: no setter
            self._slice = PACED_SLICE_WALL * realtime

    def beat(self) -> None:
        """Paused, not stalled: whoever follows the run's progress hears it is there."""
        if self.progress is not None:
            self.progress(self.env.now, self.steps)

    def resync(self) -> None:
        """After a pause: a paced world's clock takes up from now (it does not catch up)."""
        if isinstance(self.env, simpy.rt.RealtimeEnvironment):
            self.env.sync()

    # -- the medium's log --------------------------------------------------------------------

    def _log_medium(self, pulses: dict[str, Pulses], final_before: int) -> None:
        """Log every window that carries a pulse (silent ones are not logged), once final: the
        sum of every member's samples, added in member order as each unit hears them."""
        log = self.write_medium and self.recorder.enabled
        for u, p in pulses.items():
            if p[0].size:
                self._last_pulse = max(self._last_pulse, int(p[0][-1]))
                if log:
                    self._medium.setdefault(u, []).append(p)
        if not log or not self._medium:
            return
        L = self.window
        cut_at = final_before if final_before >= NEVER else (final_before // L) * L
        now: dict[str, Pulses] = {}
        for u in list(self._medium):
            ready, later = split_pulses(merge_pulses(self._medium[u]), cut_at)
            if ready[0].size:
                now[u] = ready
            if later[0].size:
                self._medium[u] = [later]
            else:
                del self._medium[u]
        if not now:
            return
        rows, values = self._sum_medium(now)  # rows ascending: each window's are a slice
        if not rows.size:  # pulses that cancel out: silence
            return
        windows = rows // L
        first = np.flatnonzero(np.concatenate(([True], windows[1:] != windows[:-1])))
        bounds = [*first.tolist(), len(rows)]
        for i, w in enumerate(windows[first].tolist()):
            a, b = bounds[i], bounds[i + 1]
            samples = np.zeros(L)
            samples[rows[a:b] - w * L] = values[a:b]
            t = time_of(w * L, self.tau)
            record = records.medium_window(w, t, 1.0 / self.tau, samples.tolist())
            self.recorder.write(records.MEDIUM, record, ns(t))

    def _sum_medium(self, pulses: dict[str, Pulses]) -> Pulses:
        """The medium from each member's pulses, members in order (``medium_sum``)."""
        return medium_sum([pulses[u] for u in self.bus.members if u in pulses])

    # -- running ----------------------------------------------------------------------------

    def run(self, *, interruptible: bool = False) -> WorldResult:
        """Run until every local member is done. ``interruptible``: a KeyboardInterrupt (a
        unit process asked to stop: SIGTERM, SIGINT) ends the run as a failure that says so,
        so what the units know so far is still reported (else it propagates)."""
        t0 = time.perf_counter()
        silent: tuple[str, ...] = ()
        done = self.env.process(self._coordinate())
        try:
            self.env.run(until=done)
        except MembersSilent as exc:  # a member gone or stalled, or this process cut off
            self.failure, silent = str(exc), exc.silent
        except RgtbusError as exc:  # a log that ends early
            self.failure = str(exc)
        except KeyboardInterrupt:
            if not interruptible:
                raise
            self.failure = f"stopped (asked to, at t = {self.env.now:.3f} s)"
        if self._group_log is not None:
            self._group_log.finish()
        return WorldResult(
            steps=self.steps,
            sim_seconds=round(time_of(self.end_sample() + 1, self.tau), 9),
            wall_seconds=time.perf_counter() - t0,
            failure=self.failure,
            bus_stats=dict(self.bus.stats()),
            end_sample=self.end_sample(),
            silent=silent,
            sync={**self.sync.as_dict(), "rounds": self.steps},
        )


def _two_least(values: Sequence[int]) -> tuple[int, int]:
    """The smallest and second smallest (NEVER where there are too few)."""
    a = b = NEVER
    for v in values:
        if v < a:
            a, b = v, a
        elif v < b:
            b = v
    return a, b


def as_jsonable(value: Any) -> Any:
    """numpy scalars and tuples -> plain JSON types (for log messages)."""
    if isinstance(value, dict):
        return {str(k): as_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [as_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _delays_only(arrivals: Sequence[np.ndarray | None]) -> bool:
    """Whether every local listener hears every sender late by a fixed delay and on the same
    clock (``Listener.arrival``: a ≥ 0, b = 1): the lookahead of propagation applies."""
    if not arrivals:
        return False
    return all(
        a is not None and bool(np.all(a[1] == 1.0) and np.all(a[0] >= 0.0)) for a in arrivals
    )
