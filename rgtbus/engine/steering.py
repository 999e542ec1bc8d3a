"""A steered run's changes, applied in the SimPy world (what they are: ``rgtbus.steering``).

A request takes effect at ``S = boundary(computed, window)``: the first window boundary at or
after everything the run has computed (the ears' horizon). The world never lets its horizon
pass the next such sample (``next_at``) before the change is applied there, so the medium
before S is heard as it was and the medium from S on with the change: the same results
however the run is cut, and a re-run (``replay --verify``) that applies the logged changes at
their samples agrees message for message. Each request, applied or refused, is logged at S
(``/control/parameter``, ``/control/service``, in the order applied: ``seq``).

Pausing is the wall clock's alone: a paused world waits at S (``gate``) until resumed or
stepped; a step runs on to the next window, turn or round boundary and pauses there. None
of it changes a result; a re-run keeps only the records.
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, cast

from rgtbus.bus.payload import NEVER
from rgtbus.pairs import pair_key
from rgtbus.steering import (
    PACE,
    Refused,
    Request,
    Setting,
    boundary,
    check_call,
    check_setting,
    step_target,
)
from rgtbus.telemetry import records
from rgtbus.timebase import ns, sample_of, time_of

if TYPE_CHECKING:
    import simpy

    from rgtbus.scenario import Scenario
    from rgtbus.telemetry import Recorder


class SteeredMember(Protocol):
    """What steering uses of a local member (``rgtbus.engine.sim.Member`` has it all); each
    raises ``Refused`` with why not."""

    name: str

    def inject(self, peer: str, value: int) -> tuple[int, int]: ...
    def hold_relation(self, pair: tuple[str, str], alliance: bool, at: int) -> int: ...
    def set_repair_budget(self, blocks: int) -> None: ...
    def state(self) -> dict[str, Any]: ...


class World(Protocol):
    """What steering uses of the world it steers (``rgtbus.engine.sim.World``)."""

    horizon: int
    tau: float
    env: simpy.Environment
    recorder: Recorder

    @property
    def members(self) -> Sequence[SteeredMember]: ...
    def member(self, name: str) -> SteeredMember | None: ...
    def computed(self) -> int: ...
    def set_noise(self, sigma: float) -> None: ...
    def set_gain(self, link: tuple[str, str], gain: float) -> None: ...
    def set_drift(self, unit: str, ppm: float, at: int) -> None: ...
    def set_pace(self, realtime: float) -> None: ...
    def resync(self) -> None: ...
    def beat(self) -> None: ...


class Requests(Protocol):
    """Where a live run's requests come from (``rgtbus.telemetry.control.Controller``)."""

    def take(self) -> list[Request]:
        """The requests that came since the last call, in the order they came."""
        ...

    def wait(self, timeout: float) -> None:
        """Wait (wall time) until a request comes, at most ``timeout`` s."""
        ...

    def clock(self, t_ns: int, pace: float | None, running: bool) -> None:
        """The run's clock is at ``t_ns``, paced at ``pace``, running or paused (a live view
        holds its own clock to it)."""
        ...

    def close(self) -> None:
        """The run is ending: no request is taken from now on (each is refused at once)."""
        ...

    def announce(self, req: Request) -> None:
        """A request this process placed (``req.at``, ``req.seq``): the run's other processes
        must have it before any passes its sample (a one-process run's: nothing to do)."""
        ...

    def settle(self, seqs: Sequence[int], timeout: float) -> list[str]:
        """Wait (wall time, at most ``timeout`` s) until every other process has the changes
        ``seqs``; the processes that did not say so (a one-process run's: none)."""
        ...


class RequestSource:
    """A ``Requests`` of one process to build on: ``take`` is yours; it never waits, keeps no
    clock, and has no other process to tell (``rgtbus.run(..., control=...)`` from a
    script: docs/api.md)."""

    def take(self) -> list[Request]:
        return []

    def wait(self, timeout: float) -> None:
        return None

    def clock(self, t_ns: int, pace: float | None, running: bool) -> None:
        return None

    def close(self) -> None:
        return None

    def announce(self, req: Request) -> None:
        return None

    def settle(self, seqs: Sequence[int], timeout: float) -> list[str]:
        return []


@dataclass(frozen=True)
class _Due:
    sample: int
    seq: int
    request: Request


def _fmt(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


class Steering:
    """The changes of one run: live requests (``source``) or logged ones (``logged``: the
    re-run of a steered log); see the module docstring. ``pace``: the run's, None unpaced."""

    def __init__(
        self,
        sc: Scenario,
        window: int,
        *,
        source: Requests | None = None,
        logged: Sequence[tuple[int, int, Request]] = (),
        pace: float | None = None,
    ) -> None:
        self.sc = sc
        self.window = window
        self.source = source
        self.pace = pace
        self.paused = False
        self.pause_at: int | None = None  # a step's end
        self.seq = 0
        self._due: list[tuple[int, int, _Due]] = []
        for sample, seq, req in logged:
            heapq.heappush(self._due, (sample, seq, _Due(sample, seq, req)))
            self.seq = max(self.seq, seq + 1)
        self.noise = sc.channel.noise
        self.gains = dict(sc.channel.gains)
        self.drifts = {u: c.drift for u, c in sc.channel.clocks.items()}
        self.budget = sc.protocol.repairs_per_phase
        self._starts: dict[str, list[int]] | None = None
        self._unsettled: dict[int, int] = {}  # seq -> sample: announced, not yet had by all
        self._mine: set[int] = set()  # the changes this process placed (its to refuse at the end)
        self.settle_timeout = 10.0  # s a change waits for the other processes to have it

    # -- when -----------------------------------------------------------------------------------

    def next_at(self) -> int:
        """The next sample at which something is due (a change, a step's pause); NEVER: none."""
        nxt = self._due[0][0] if self._due else NEVER
        return min(nxt, self.pause_at) if self.pause_at is not None else nxt

    def hold(self) -> int:
        """No member of this process may promise past this sample: a change it placed there
        is not yet had by every other process (NEVER: none is waiting)."""
        return min(self._unsettled.values(), default=NEVER)

    def poll(self, computed: int, promised: int = 0) -> None:
        """Take the requests that came: one placed by the process that steers the run at its
        sample; another at ``boundary``, at or after both what this process computed and
        what it ``promised`` (no other process has passed that), announced to the others."""
        if self.source is None:
            return
        at = boundary(max(computed, promised), self.window)
        for req in self.source.take():
            if req.at is not None and req.seq is not None:  # placed by the steering process
                due = _Due(req.at, req.seq, req)
                self.seq = max(self.seq, req.seq + 1)
            else:
                due = _Due(at, self.seq, req.placed(at, self.seq))
                self.seq += 1
                self._mine.add(due.seq)
                if req.refused is None:  # a refusal is this process's record alone
                    self.source.announce(due.request)
                    self._unsettled[due.seq] = at
            heapq.heappush(self._due, (due.sample, due.seq, due))

    def apply(self, world: World, horizon: int) -> None:
        """Apply (or refuse) everything due at or before ``horizon``, in order, once every
        process has it; a step that ends there pauses first."""
        if self.pause_at is not None and self.pause_at <= horizon:
            self.pause_at = None
            self._set_paused(world, True)
        waiting = [seq for seq, at in self._unsettled.items() if at <= horizon]
        if waiting and self.source is not None:
            late = self.source.settle(waiting, self.settle_timeout)
            for seq in waiting:
                del self._unsettled[seq]
            if late:  # gone, most likely (the bus names a member gone)
                world.recorder.log(
                    "warning",
                    f"steering: {', '.join(late)} did not confirm changes {waiting} within "
                    f"{self.settle_timeout:g} s",
                    ns(time_of(horizon, world.tau)),
                )
        while self._due and self._due[0][0] <= horizon:
            _, _, due = heapq.heappop(self._due)
            self._apply(world, due)

    def gate(self, world: World) -> None:
        """A live, paused run waits here (wall time) for a resume or a step; meanwhile every
        request that comes is applied at this very boundary."""
        if self.source is None or not self.paused:
            return
        while self.paused:  # it computed nothing past its horizon (the pause clamped it)
            world.beat()  # alive, paused (a launcher watching for stalls hears it)
            self.source.wait(0.2)
            self.poll(world.horizon)
            self.apply(world, world.horizon)
        world.resync()

    def finish(self, world: World) -> None:
        """The run is over: what is still due, and what came since the last look, is refused
        (and logged) at its sample; the source takes no more."""
        self.pause_at = None
        if self.source is not None:
            self.poll(world.computed())
            self.source.close()
            self.poll(world.computed())  # what came while it closed
        while self._due:
            _, _, due = heapq.heappop(self._due)
            req = due.request
            if req.logged is None:
                if due.seq not in self._mine:  # the process that placed it says what came of it
                    continue
                req = req.refuse("the run ended before it applied")
            self._apply(world, due, req)

    # -- what ------------------------------------------------------------------------------------

    def _apply(self, world: World, due: _Due, req: Request | None = None) -> None:
        req = req or due.request
        t = time_of(due.sample, world.tau)
        if req.kind == "parameter":
            rec = self._parameter(world, due, req, t)
            world.recorder.write(records.CONTROL_PARAMETER, rec, ns(t))
        else:
            for srec in self._service(world, due, req, t):
                world.recorder.write(records.CONTROL_SERVICE, srec, ns(t))

    def _parameter(
        self, world: World, due: _Due, req: Request, t: float
    ) -> records.ControlParameterRecord:
        if req.logged is not None and not req.logged.get("applied"):
            return cast(records.ControlParameterRecord, dict(req.logged))  # as it was logged
        before: Any = None
        try:
            if req.refused is not None:
                raise Refused(req.refused)
            s = check_setting(self.sc, req.name, req.value)
            if s.kind == "pace" and self.pace is None and req.logged is not None:
                self.pace = req.logged.get("from")  # a re-run is not paced: the run's pace
            before = self._current(s)
            self._set(world, s, due.sample)
            after = self._current(s)
            text = f"{s.name}: {_fmt(before)} -> {_fmt(after)} at t = {t:.3f} s"
            return records.control_parameter(
                t, due.sample, due.seq, req.who, s.name, req.value, before, after, True, text
            )
        except Refused as exc:
            return records.control_parameter(
                t, due.sample, due.seq, req.who, req.name, req.value, before, before, False,
                f"refused: {exc}",
            )  # fmt: skip

    def _current(self, s: Setting) -> Any:
        if s.kind == "noise":
            return self.noise
        if s.kind == "gain":
            assert s.link is not None
            return self.gains.get(s.link, 1.0)
        if s.kind == "budget":
            return self.budget
        if s.kind == "drift":
            assert s.link is not None
            return self.drifts.get(s.link[0], 0.0)
        return self.pace

    def _set(self, world: World, s: Setting, at: int) -> None:
        if s.kind == "noise":
            self.noise = float(s.value)
            world.set_noise(self.noise)
        elif s.kind == "gain":
            assert s.link is not None
            self.gains[s.link] = float(s.value)
            world.set_gain(s.link, float(s.value))
        elif s.kind == "drift":
            assert s.link is not None
            self.drifts[s.link[0]] = float(s.value)
            world.set_drift(s.link[0], float(s.value), at)
        elif s.kind == "budget":
            self.budget = int(s.value)
            for m in world.members:
                m.set_repair_budget(self.budget)
        else:
            if self.pace is None and self.source is not None:
                raise Refused(f"{PACE}: this run is not paced (rgtbus run --realtime X)")
            self.pace = float(s.value)
            if self.source is not None:
                world.set_pace(self.pace)
                self.source.clock(ns(world.env.now), self.pace, not self.paused)

    def _service(
        self, world: World, due: _Due, req: Request, t: float
    ) -> list[records.ControlServiceRecord]:
        """The call's records: one; one a local unit (a mark); none where the unit it is about
        runs in another process (whose record it is)."""
        args = req.value  # the record keeps what was sent (``records.loggable``)
        if req.logged is not None and not req.logged.get("applied"):
            return [cast(records.ControlServiceRecord, dict(req.logged))]  # as it was logged
        try:
            if req.refused is not None:
                raise Refused(req.refused)
            call = check_call(self.sc, req.name, req.value)
            extra: dict[str, Any] = {}
            if call.service == "pause":
                if self.paused:
                    raise Refused("pause: the run is paused already")
                self.pause_at = None  # a step on its way ends here
                self._set_paused(world, True)
                text = f"paused at t = {t:.3f} s"
            elif call.service == "resume":
                if not self.paused and self.pause_at is None:
                    raise Refused("resume: the run is not paused")
                stepping = self.pause_at is not None
                self.pause_at = None  # a step on its way goes on: no pause at its end
                self._set_paused(world, False)
                text = f"resumed at t = {t:.3f} s" + (" (the step's pause is off)" * stepping)
            elif call.service == "step":
                if not self.paused:
                    raise Refused("step: the run is not paused (pause it first)")
                assert call.by is not None
                until = step_target(call.by, due.sample, self.window, self._schedule_starts(world))
                self._set_paused(world, False)
                self.pause_at = until
                extra["until"] = until
                where = "its end" if until is None else f"t = {time_of(until, world.tau):.3f} s"
                text = f"step by {call.by} from t = {t:.3f} s: pauses at {where}"
            elif call.service == "influence":
                assert call.unit is not None and call.peer is not None and call.value is not None
                member = world.member(call.unit)
                if member is None:
                    return []
                turn, rnd = member.inject(call.peer, call.value)
                extra.update(turn=turn, rnd=rnd, value=call.value)
                text = (
                    f"influence {pair_key(call.unit, call.peer)} = "
                    f"{self.sc.universe.format(call.value)} in round {rnd} (turn {turn})"
                )
            elif call.service == "relation":
                assert call.unit is not None and call.pair is not None
                assert call.alliance is not None
                member = world.member(call.unit)
                if member is None:
                    return []
                rnd = member.hold_relation(call.pair, call.alliance, due.sample)
                extra["rnd"] = rnd
                what = "alliance" if call.alliance else "conflict"
                text = (
                    f"{call.unit} holds {pair_key(*call.pair)} as {what} from t = {t:.3f} s "
                    f"(its decisions from round {rnd} on)"
                )
            elif call.service == "auth":
                text = f"{req.who} may steer"
            else:  # mark: a record a unit (its process writes it, however the run is laid out)
                text = f"mark at t = {t:.3f} s" + (f": {call.label}" if call.label else "")
                return [
                    records.control_service(
                        t, due.sample, due.seq, req.who, req.name, args, True, text,
                        state={m.name: m.state()},
                    )
                    for m in world.members
                ]  # fmt: skip
            return [
                records.control_service(
                    t, due.sample, due.seq, req.who, req.name, args, True, text, **extra
                )
            ]
        except Refused as exc:
            return [
                records.control_service(
                    t, due.sample, due.seq, req.who, req.name, args, False, f"refused: {exc}"
                )
            ]

    def _set_paused(self, world: World, paused: bool) -> None:
        self.paused = paused
        if self.source is not None:
            self.source.clock(ns(world.env.now), self.pace, not paused)

    def _schedule_starts(self, world: World) -> dict[str, list[int]]:
        """The clean schedule's first sample of every turn and of every influence round."""
        if self._starts is None:
            from rgtbus.truth import clean_timeline

            plan, listens = clean_timeline(self.sc)
            first: dict[int, int] = {}
            for listen in listens:
                k = sample_of(listen.start, world.tau)
                first[listen.turn] = min(first.get(listen.turn, k), k)
            rounds: dict[tuple[str, int], int] = {}
            for turn, k in first.items():
                tt = plan.schedule[turn]
                key = (tt.phase, tt.round)
                rounds[key] = min(rounds.get(key, k), k)
            self._starts = {"turn": sorted(first.values()), "round": sorted(rounds.values())}
        return self._starts
