"""The autonomous unit: its timers, what it does with what it decodes, what it learns and
chooses, and its report; made of parts it calls, which never call it back but through the
callbacks it hands them.

One unit lives in the SimPy world (``rgtbus.engine.sim.World``) at its own samples: the ears'
process wakes it (a plain call, at the exact simulated time) at the spike it awaits and at its
own timers. At a wake it runs the pure protocol machine (``rgtbus.protocol``) on the spike it
heard, takes every timer that fell due (a decode, a deadline, a goal's choice, a repair step)
and acts on what it decoded: it records each decode, checks it, and learns from it (``Mind``,
its reasoning). What the protocol plans it transmits. It shares no Python object with the
other units: its knowledge comes only from the medium. Once it has decided, or failed, it
listens no more.

Its parts: ``Listening`` (reading codes off its readout, a shared queue's decodes a batch at a
time), ``Transmitter`` (sends to pulses, and their log), ``Arq`` (its side of repair, when the
scenario asks for it), ``Timers`` and ``UnitLog`` (its decode and spike blocks and its own
records). Unless a live view waits for its records, a unit that awaits no spike takes its
decodes a batch at a wake (``BATCH_SECONDS``; docs/engine.md): the same decodes, fewer wakes.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING, Any, cast, overload

import simpy
import simpy.rt
from rgtbus.units.arq import Arq
from rgtbus.units.listening import DecodeColumns, ExpectedSpike, Listening
from rgtbus.units.timers import REPAIR_STEPS, Timer, Timers
from rgtbus.units.transmitter import Transmitter

from rgtbus.bus.payload import NEVER
from rgtbus.engine.hearing import READ_AS_HEARD_SECONDS
from rgtbus.engine.listener import Heard, OwnHearing
from rgtbus.mind import (
    Mind,
    decision_fields,
    intents,
    mind_of,
    result_fields,
    steering_reason,
)
from rgtbus.protocol import NOTHING, PHASES, Actions, Listen, ProtocolState, Send, choice_sample
from rgtbus.repair import RepairBook
from rgtbus.rgt import Universe
from rgtbus.scenario import Goal, Scenario
from rgtbus.signal.pulses import Pulses
from rgtbus.signal.resonator import ResonatorBank
from rgtbus.signal.rules import rule_named
from rgtbus.steering import Refused
from rgtbus.summary import DecisionRow, decision_row, not_decomposable_text
from rgtbus.telemetry import Recorder, records
from rgtbus.telemetry.group_log import GroupLog
from rgtbus.telemetry.scene import scene_update
from rgtbus.telemetry.unit_log import UnitLog
from rgtbus.timebase import ns, sample_of, time_of

if TYPE_CHECKING:
    from rgtbus.engine.hearing import Ears
    from rgtbus.rgt.control import SteeringChoice

KEEP_SECONDS = 30.0  # readout a decode may reach back (longest code + reaction + search)
# a unit's decodes of this much time wait for one wake (no live view): a wake costs about
# 100 µs of Python, so at 4 s a 300-unit run spent a minute waking its units; 300 units run
# in 20 s batching a minute, 18 s two minutes (16 MB more decoded codes held), 17 s four
BATCH_SECONDS = 120.0
# with a log, what a batch holds for it (its decodes, the blocks of spikes handed meanwhile)
# grows with the batch, and so do the wakes' cost with their number: 100 units with their log
# took 7.0 s batching 10 s, 6.2 s at 20 s, 5.8 s at 30 s, 6.0 s at a minute in chunks of
# 256 KiB (which then held fewer units' records of one time); in chunks of 1 MiB, 4.5 s at
# 30 s and 4.3 s at a minute, 200 units 25.5 s and 23.3 s (141 and 158 MB of log, a peak of
# 400 and 418 MB). 300 units peak at 816 MB batching 30 s, 775-805 MB at 10 s: a group larger
# than LARGE_GROUP batches its log's 10 s
LOGGED_BATCH_SECONDS = 60.0
LARGE_GROUP = 200
LARGE_GROUP_LOGGED_BATCH_SECONDS = 10.0
# a logged batch's records leave at the wake after it: a paced run's units batch at most
# this much of its wall time, so that a log cut by a kill trails the paced clock by little
PACED_BATCH_WALL_SECONDS = 1.0
# on a medium its receivers hear differently (``Channel.alike``) every unit holds its own
# spikes and decodes for its log, and a wake costs little against its walk: 100 units at
# noise 0.01 took 64.2 s and 530 MB batching a minute, 64.6 s and 356 MB at 10 s, 65.1 s and
# 303 MB at 5 s, 71.7 s and 301 MB at 2 s
DIFFER_LOGGED_BATCH_SECONDS = 5.0


def batch_seconds(
    units: int, logged: bool, realtime: float | None = None, alike: bool = True
) -> float:
    """How much time of its decodes a unit of a group of ``units`` takes at one wake, when
    it batches (``BATCH_SECONDS``; with a log ``LOGGED_BATCH_SECONDS``, shorter in a group
    larger than ``LARGE_GROUP``, where what a batch holds weighs most, on a medium its
    receivers do not hear ``alike`` (``DIFFER_LOGGED_BATCH_SECONDS``), and in a run paced at
    ``realtime`` simulated seconds a wall second at most ``PACED_BATCH_WALL_SECONDS`` of wall
    time)."""
    if not logged:
        return BATCH_SECONDS
    batch = LOGGED_BATCH_SECONDS if units <= LARGE_GROUP else LARGE_GROUP_LOGGED_BATCH_SECONDS
    if not alike:
        batch = min(batch, DIFFER_LOGGED_BATCH_SECONDS)
    if realtime is not None:
        batch = min(batch, realtime * PACED_BATCH_WALL_SECONDS)
    return batch


def protocol_of(sc: Scenario, name: str, expect: ExpectedSpike | None = None) -> ProtocolState:
    """Unit ``name``'s protocol state in scenario ``sc`` (its schedule's plan is shared by
    every unit of a process: ``plan_of``), expecting its attention spikes by ``expect``."""
    return ProtocolState(
        name, sc.units, dict(sc.frequencies), sc.timing.tau,
        pulses=sc.codebook.pulses, start=sc.timing.start,
        reaction_delay=sc.timing.reaction_delay, guard=sc.timing.guard,
        search=sc.timing.search, anchor=sc.timing.anchor, kind=sc.protocol.schedule,
        influence_rounds=sc.protocol.influence_rounds, repair_rounds=sc.protocol.repairs_per_phase,
        attention=sc.timing.attention, read_margin=1 if sc.channel.timed else 0,
        expect_spike=ExpectedSpike(sc, name) if expect is None else expect,
    )  # fmt: skip


def lay_out_plan(sc: Scenario) -> None:
    """Work out in this process what every unit of ``sc`` shares, so processes forked from it
    start with it: its plan (the concurrent schedule's rounds and decodes: a third of a
    second for 50 units) and its resonators' tables. A launch does this once, not once a unit
    process."""
    plan = protocol_of(sc, sc.units[0]).plan
    if plan.kind == "concurrent":
        plan.timing()
        plan.concurrent_listens()
    omegas = tuple(sc.frequencies[u] for u in sc.units)
    ResonatorBank(omegas, mode=sc.mode, tau=sc.timing.tau)  # its tables: an LRU cache


class AutonomousUnit:
    """Unit ``name`` of ``scenario``, writing to ``recorder`` (``traces``: its resonators'
    states too; ``realtime``: the run is paced, at that many simulated seconds a wall second,
    ``batch_seconds``). See the module docstring."""

    def __init__(
        self,
        name: str,
        scenario: Scenario,
        recorder: Recorder,
        traces: bool = False,
        realtime: float | None = None,
        steerable: bool = False,
    ) -> None:
        sc = scenario
        self.name, self.scenario, self.recorder, self.traces = name, sc, recorder, traces
        self.units = sc.units
        self.tau = sc.timing.tau
        self.finished = False  # it decided every round (and ran every repair step)
        self.failure: str | None = None
        self.done = False  # decided or failed: it listens no more
        self.done_at = 0  # the sample of what made it done
        self.decoded = DecodeColumns()  # every decode, as the summary reads it
        # its own decision after each influence round it decided (``decision_row``)
        self.decisions: list[DecisionRow] = []
        self._index = {u: i for i, u in enumerate(self.units)}
        self._alternatives: dict[str, int] = {}  # decoded names, parsed once
        self._aw_named: tuple[str, int, int] | None = None
        self._aw: tuple[int, int, int] = (0, 0, 0)
        self._asked: tuple[int, int, int] | None = None  # what the last ask awaited
        self._expected = ExpectedSpike(sc, name)  # told its link gains as the run begins
        self.protocol = protocol_of(sc, name, self._expected)
        self.mind = mind_of(sc, name)
        self.goals = sc.goals_of(name)
        # goal-driven influence sends: timed by the protocol, their code chosen at their
        # choice sample (``choice_sample``); nothing goes out before (the promise says so)
        self._pending: dict[int, Send] = {}
        self._pending_first = NEVER
        # a steered run (``rgtbus.engine.steering``): every influence waits for its choice
        # sample, so that one injected before then goes out instead; and the relations it was
        # made to hold, which what it decodes does not undo
        self.steerable = steerable
        self._injected: dict[int, int] = {}  # turn -> the alternative to send
        self._held: dict[tuple[str, str], bool] = {}
        self._held_from: list[list[Any]] = []  # [sender, receiver, alliance?, from round]
        self.relation_choice, self.influence_choice = intents(sc, name)
        # it listens to samples before its limit: max_seconds, or a deliberate stop before it
        stop = sc.timing.stop
        self.cut = stop is not None and stop < sc.timing.max_seconds
        self.limit = sample_of(min(stop or math.inf, sc.timing.max_seconds), self.tau)
        self.timers = Timers()
        self._batches = False  # its decodes may wait for one wake a batch (set at begin)
        self._batch_seconds = batch_seconds(
            len(sc.units), recorder.enabled, realtime, sc.channel.alike
        )
        self._batch_span = max(1, sample_of(self._batch_seconds, self.tau))
        self.log = UnitLog(name, recorder, self.tau, self.units, self._holds_spikes)
        self.transmitter = Transmitter(sc.codebook, dict(sc.frequencies), self.tau, self.log)
        self.listening = Listening(
            name, sc, self.protocol, self.mind, self.decoded, self.log,
            act=self._act, settle=self._settle, repairs=bool(sc.protocol.repairs_per_phase),
        )  # fmt: skip
        self.arq: Arq | None = None  # [protocol] repair = "arq" (docs/protocol.md, "Repair")
        if sc.protocol.repairs_per_phase:
            self.arq = Arq(
                name, sc,
                RepairBook(
                    sc.codebook, sc.protocol.repair_margin, sc.protocol.repairs_per_phase,
                    rule_named(sc.decoding),
                ),
                payload_codes=self.transmitter.payload_code, schedule=self._schedule,
                emit=self.transmitter.emit, record=self._record, learn=self._learn, log=self.log,
            )  # fmt: skip
        self.env: simpy.Environment | None = None
        self.ears: Ears | None = None
        self.index = 0  # its index among its ears' listeners
        # its last /unit/relations and /unit/influences records (its report leaves out what
        # they hold as it is at its end)
        self._logged_relations: records.RelationsRecord | None = None
        self._logged_influences: records.InfluencesRecord | None = None

    @property
    def sent(self) -> list[Send]:
        """Every send it made (but a repair's), in planning order."""
        return self.transmitter.sent

    # -- the world's interface ---------------------------------------------------------------

    def hearing(self) -> OwnHearing:
        """What it supplies of its receiver (the engine makes the rest from the channel,
        ``Reception``): the readout it keeps, its traces, its spikes, whether it waits for
        one."""
        return OwnHearing(
            keep=sample_of(self._keep_seconds(), self.tau),
            trace=self.log.trace if self.traces else None,
            spike_log=self.log if self.recorder.enabled else None,  # only a log needs every spike
            # else its plans never wait for a spike
            awaits=self.protocol.anchor == "spike" and not self.protocol.confirmed,
        )

    def join_log(self, group: GroupLog, at: int) -> None:
        """Its pulses and decodes go to the log of its process's units, as unit ``at``."""
        self.log.join(group, at)

    def begin(self, env: simpy.Environment, ears: Ears, index: int) -> None:
        """The run begins: its world, its ears and its index among their listeners."""
        self.env, self.ears, self.index = env, ears, index
        # its pulses go to the log as the run's clock reaches each only where someone may
        # look on while it runs (a paced run, a live view watched as it begins); else as they
        # are planned (a unit process's feed that nobody watches costs a SimPy event a pulse)
        on_time = self.watched() or isinstance(env, simpy.rt.RealtimeEnvironment)
        self.transmitter.begin(env, on_time)
        self.listening.begin(ears, index)
        self._expected.hear(ears.listeners[index].gains)
        self.log.member = index
        if self.arq is not None:
            self.arq.begin(self.listening.read)
        self._batches = self.batching()
        self.timers.add(self.limit, self.limit - 1, "limit")
        self._draw(0.0)
        self._apply(self.protocol.begin(self.relation_choice, self.influence_choice))
        self._ask()

    def _keep_seconds(self) -> float:
        """How far back its readout is kept: ``KEEP_SECONDS``, plus its longest code (slow
        channels make codes of tens of seconds), plus how late a code may be read: a batch's
        listens at its wake, the concurrent schedule's as the ears hear them whole
        (``Listening.expect_queue``, at most ``READ_AS_HEARD_SECONDS`` late), plus, with the
        repair on the concurrent schedule, the reach of its blocks (``Plan.repair_reach``)."""
        sc = self.scenario
        longest = (sc.codebook.pulses - 1) * max(2 * math.pi / w for w in sc.frequencies.values())
        concurrent = sc.protocol.schedule == "concurrent"
        late = READ_AS_HEARD_SECONDS if concurrent else self._batch_seconds
        # a repair block re-reads its phase's payloads: the history spans the phase and its blocks
        return KEEP_SECONDS + longest + late + self.protocol.plan.repair_reach()

    def batching(self) -> bool:
        """Whether this unit may take its decodes a batch at a wake (``Timers.batch_end``):
        their records then leave at the wake, each at its own log time, up to
        ``BATCH_SECONDS`` behind the run's clock, and the blocks of spikes the ears hand on
        meanwhile wait for the wake too. Not with traces, nor while a live view may be looking
        (``watched``): it then wakes for each thing it does and offers each decode as it is
        made (``UnitLog.offers``). Asked at every wake, with no block held: a watcher that
        comes mid-run gets this unit's records on time from its next wake on, one that leaves
        lets it batch again. Either way the log holds the same records."""
        if self.traces or self.protocol.confirmed:
            return False
        return not self.watched()

    def watched(self) -> bool:
        """Whether a live view may be looking (``Recorder.watched``)."""
        return self.recorder.watched()

    def take_outbox(self) -> Pulses:
        """The pulses planned since the last call (``Transmitter.take_outbox``)."""
        return self.transmitter.take_outbox()

    def promise(self, horizon: int) -> int:
        """Nothing unplanned from this unit before this sample, given no spike it reacts to
        before ``horizon``."""
        if self.done:
            return NEVER
        repair = None if self.arq is None else self.arq.first_send
        return min(
            self.protocol.send_bound(horizon),
            self._pending_first,
            NEVER if repair is None else repair,
        )

    def awaited(self) -> tuple[int, int, int] | None:
        """The spike this unit's next plans wait for: (channel index, earliest sample, latest
        sample)."""
        aw = None if self.done else self.protocol.awaited()
        if aw is None:
            return None
        if aw is not self._aw_named:  # the chain moved on: name its channel by index once
            self._aw_named, self._aw = aw, (self._index[aw[0]], aw[1], aw[2])
        return self._aw

    def end_log(self) -> None:
        """The run is over for this unit (done, or the world stopped): what it and its ears
        still keep for its log is written."""
        self.log.end()
        if self.ears is not None:
            self.ears.end_spikes(self.index)

    def write_report(self, sim_seconds: float) -> None:
        """The run is over at ``sim_seconds``: what it keeps for its log is written, then its
        ``/unit/report``, what the log's summary is computed from (with its ``/rx/decodes``
        records), exactly as the live summary is."""
        self.end_log()
        if self.recorder.enabled:
            self.recorder.write(records.UNIT_REPORT, self.report_record(), ns(sim_seconds))

    # -- living: receive -> protocol -> decode -> reason -> send ------------------------------

    def _holds_spikes(self) -> bool:
        """Whether a block of spikes handed now waits for its next wake (``UnitLog``): it
        takes its decodes a batch at a wake, and does not know yet whether it was done
        before the block."""
        return self._batches and not self.done

    def _is_done(self) -> bool:
        return self.done

    def _ask(self) -> None:
        """Ask the ears for the next thing this unit must act on: its first timer's boundary,
        or the spike it awaits, whichever comes first (``_woken`` is called then)."""
        assert self.ears is not None
        if self.done:  # its log holds its spikes before the sample after the one it was done at
            stop = self.done_at + 1
            self.log.release_spikes(stop)
            self.ears.stop(self.index, stop)  # and hands it what it kept for its log
            return
        if self.log.holds_spikes:  # not done before the samples of this wake: they are its
            self.log.release_spikes(None)
        self._batches = self.batching()  # none held now: it may change (a watcher came)
        self.log.offers = self.watched()
        t = self.timers.first
        aw = self._asked = self.awaited()
        if aw is None and self._batches:  # nothing it hears can change its plans
            boundary = self.timers.batch_end(t.boundary, self._batch_span)
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
        while not self.done:
            t = self.timers.pop_due(pos)
            if t is None:
                break
            if t.queued is None:
                self._on_timer(t)
            else:
                self.listening.take_queue(t, pos, self.timers, self._is_done)
        self.log.after_wake(pos, self.ears.spikes_from)
        self._ask()

    def _on_timer(self, t: Timer) -> None:
        """A timer of its own (a shared queue's listens are ``Listening.take_queue``'s)."""
        if t.kind == "listen":
            assert t.listen is not None
            self.listening.decode(t.listen)
        elif t.kind == "deadline":
            self.timers.deadline_passed()
            if self.protocol.confirmed:
                self._attend(t.at)
            else:
                err = self.protocol.check_deadline(t.at + 1)
                if err:
                    self._fail(err, t.at)
        elif t.kind == "choose":
            self._choose(t.seq, t.at)
        elif t.kind in REPAIR_STEPS:
            assert self.arq is not None
            self.arq.step(t.kind, t.seq, t.at, failed=self.failure is not None)
            if self.failure is None and not self.arq.left and self.mind.all_rounds_decided:
                self.finished = True
        elif t.kind == "limit":
            timing = self.scenario.timing
            self._fail(
                f"{self.name}: stopped at {timing.stop:g} s of simulated time, not finished "
                "(timing.stop)"
                if self.cut
                else f"{self.name}: not finished after {timing.max_seconds:g} s of "
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
            self.log.log("error", message, time_of(at, self.tau))
            # what the protocol planned still goes out; an unchosen code is the policy's
            for seq in sorted(self._pending):
                self._choose(seq, at, why="it failed before its choice")
            if self.arq is not None:
                self.arq.give_up()

    def _schedule(self, boundary: int, at: int, kind: str) -> int:
        """A timer of ``kind`` (for a part: a repair step); returns its seq."""
        return self.timers.add(boundary, at, kind).seq

    def _apply(self, acts: Actions) -> None:
        """What the protocol asks for: sends, listens, quenches, the turn's deadline, repair
        blocks."""
        if acts is NOTHING:
            return
        for send in acts.sends:
            self._transmit(send)
        if acts.queue is not None:  # shared: a cursor into it, not a timer per listen
            self.timers.add_queue(acts.queue)
            self.listening.expect_queue(acts.queue)
        else:
            for listen in acts.listens:
                self.timers.add(listen.ready_sample + 1, listen.ready_sample, "listen", listen)
        assert self.ears is not None
        for q in acts.quench:
            self.ears.quench_at(self.index, q)
        if acts.deadline is not None:
            self.timers.set_deadline(acts.deadline)
        for block in acts.repairs:
            assert self.arq is not None
            self.arq.plan(block)

    def _attend(self, at: int) -> None:
        """Confirmed attention at the turn's deadline (``Listening.attend``): the ID timed and
        found, its shift times the reaction; not found, the chain cannot go on and the unit
        fails. The ID's decode among every word is still logged (``_act``)."""
        turn = self.protocol.current()
        assert turn is not None
        shift = self.listening.attend(turn.sender)
        if shift is None:
            t = time_of(at, self.tau)
            self._fail(
                f"{self.name}: no ID heard on {turn.sender}'s channel for turn {turn.index} "
                f"({turn.sender} -> {turn.addressee}, {turn.phase}) by t = {t:.3f} s",
                at,
            )
            return
        self._apply(self.protocol.on_attention(shift))

    # -- sending and choosing ----------------------------------------------------------------

    def _transmit(self, send: Send) -> None:
        """A send the protocol planned goes out, but an influence on a goal's target, which
        waits for its choice sample (``_choose``)."""
        turn = self.protocol.schedule[send.turn]
        chosen = send.addressee in self.goals or self.steerable
        if send.kind == "payload" and turn.phase == PHASES[1] and chosen:
            b = choice_sample(send.start, self.scenario.timing.reaction_delay, self.tau)
            timer = self.timers.add(b, b - 1, "choose")  # its seq names the send
            self._pending[timer.seq] = send
            self._pending_first = min(self._pending_first, send.samples[0])
            return
        self.transmitter.emit(send)

    def _choose(self, seq: int, at: int, why: str | None = None) -> None:
        """Pending send ``seq``, a goal-driven influence: its code by the inverse task on what
        this unit decoded before sample ``at + 1`` (or its policy's, with the reason ``why``),
        logged on /unit/goal."""
        send = self._pending.pop(seq, None)
        if send is None:  # sent already, with its policy's code, when the unit failed
            return
        self._pending_first = min((s.samples[0] for s in self._pending.values()), default=NEVER)
        rnd = self.protocol.schedule[send.turn].round
        injected = self._injected.get(send.turn)
        if injected is not None or send.addressee not in self.goals:
            if injected is not None:
                send = dataclasses.replace(send, code=self.scenario.universe.format(injected))
            self.transmitter.emit(send)
            return
        goal = self.goals[send.addressee]
        got: SteeringChoice | str = why or self.mind.steer(goal, rnd)
        u = self.scenario.universe
        value = None if isinstance(got, str) else got.value
        code = send.code if value is None else u.format(value)
        reason = steering_reason(got, goal, u)
        t = time_of(at, self.tau)
        if self.log.enabled:
            record = goal_record(self.name, self.mind, goal, send.turn, rnd, t, got, code, reason)
            self.log.write_in_order(records.UNIT_GOAL, record, t)
            level = "info" if value is not None else "warning"
            self.log.log(level, f"{self.name}: goal {reason}", t)
        self.transmitter.emit(dataclasses.replace(send, code=code))

    # -- reacting to what it decoded, learning ------------------------------------------------

    def _act(self, listen: Listen, code: str, margin: float, ch: int) -> None:
        """What ``listen`` decoded (``code`` at ``margin``, found on channel index ``ch``):
        recorded, checked, learned from."""
        t_ready = time_of(listen.ready_sample, self.tau)
        repairs = self.arq is not None
        if listen.kind == "id":
            accepted = code == "id"
            # an ID is for the turn's addressee; it is carried on the sender's own channel
            self._record(listen, listen.expected_addressee, code, margin, t_ready, accepted,
                         listen.sender)  # fmt: skip
            if not accepted:
                text = (
                    f"{self.name}: turn {listen.turn}: the ID of {listen.sender} "
                    f"decoded as {code!r}"
                )
                # the schedule (a repair) or the attention (confirmed) says when the payload
                # comes: a misread ID is a decode error, not the chain's end
                if repairs or self.protocol.confirmed:
                    self.log.log("warning", text, t_ready)
                else:
                    self._fail(text, listen.ready_sample)
            return
        addressee = self.units[ch]
        accepted = addressee == listen.expected_addressee
        self._record(listen, addressee, code, margin, t_ready, accepted, addressee)
        if not accepted:
            self.log.log(
                "warning",
                f"{self.name}: turn {listen.turn}: code from {listen.sender} found on "
                f"{addressee}'s channel, expected {listen.expected_addressee}",
                t_ready,
            )
        if self.arq is not None and self.arq.hold(listen, code, accepted, margin):
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
        channel: str,
    ) -> None:
        """A decode, for the summary and (a block of time a record) the log."""
        self.decoded.append(listen.turn, listen.kind, addressee, code)
        if self.log.enabled:
            self.log.decode(listen.turn, listen.sender, addressee, channel, listen.kind, code,
                            margin, t, accepted)  # fmt: skip

    def _learn(self, listen: Listen, code: str, t: float) -> None:
        """What a payload said, into the mind: a relationship (the group once every pair is
        known) or an influence (a decision once a round is complete)."""
        mind = self.mind
        key = listen.pair
        if listen.kind == "relation":
            mind.sent[key] = self._held.get(key, code == "alliance")
            if mind.relations_complete():
                mind.build_group()
                if self.log.enabled:
                    record = records.relations(
                        self.name, t, mind.sent_table(), mind.installed(), mind.polynomial,
                        mind.p4,
                    )  # fmt: skip
                    self.log.write_in_order(records.UNIT_RELATIONS, record, t)
                    self._logged_relations = record
                    self._draw(t, mind.installed())
                if mind.error:
                    self.log.log("error", f"{self.name}: {mind.error}", t)
                elif mind.p4 is not None:  # a result, said once by each unit that found it
                    self.log.log("warning", f"{self.name}: {not_decomposable_text(mind.p4)}", t)
            return
        value = self._alternatives.get(code)
        if value is None:
            value = self._alternatives[code] = self.scenario.universe.parse_alternative(code)
        rnd = self.protocol.schedule[listen.turn].round
        for done in mind.hear_influence(rnd, key, value):  # rounds now complete, decided
            if self.log.enabled:
                table = records.influences(self.name, t, mind.influence_table(), done)
                self.log.write_in_order(records.UNIT_INFLUENCES, table, t)
                self._logged_influences = table
            self._log_decisions(t, done)
        if mind.all_rounds_decided and (self.arq is None or not self.arq.left):
            self.finished = True

    # -- steering (``rgtbus.engine.steering``) ------------------------------------------------

    def _steerable(self, what: str) -> None:
        if self.done:
            state = "failed" if self.failure else "finished"
            raise Refused(f"{what}: {self.name} has {state}: it sends and decides nothing more")

    def inject(self, peer: str, value: int) -> tuple[int, int]:
        """Its influence on ``peer`` is ``value`` in the next round whose code it has not sent
        yet (its choice sample not reached); returns (turn, round)."""
        self._steerable("influence")
        if not self.steerable:
            raise Refused("influence: this run is not steered (--control)")
        for t in self.protocol.schedule:
            if (
                t.phase == PHASES[1] and t.sender == self.name and t.addressee == peer
                and t.index not in self.transmitter.payload_code
                and t.index not in self._injected
            ):  # fmt: skip
                self._injected[t.index] = value
                return t.index, t.round
        raise Refused(f"influence: {self.name} has no round left in which to influence {peer}")

    def hold_relation(self, pair: tuple[str, str], alliance: bool, at: int) -> int:
        """It holds ``pair``'s relation code as ``alliance`` (or conflict) from sample ``at``
        on, whatever it decodes: its group is built again if it knows every pair. Returns the
        first round it decides with it."""
        self._steerable("relation")
        mind = self.mind
        if mind.all_rounds_decided:
            raise Refused(f"relation: {self.name} has decided every round")
        self._held[pair] = alliance
        self._held_from.append([pair[0], pair[1], alliance, mind.decided_rounds + 1])
        mind.sent[pair] = alliance
        t = time_of(at, self.tau)
        if mind.relations_complete():
            mind.build_group()
            if self.log.enabled:
                record = records.relations(
                    self.name, t, mind.sent_table(), mind.installed(), mind.polynomial, mind.p4
                )
                self.log.write_in_order(records.UNIT_RELATIONS, record, t)
                self._logged_relations = record
                self._draw(t, mind.installed())
        return mind.decided_rounds + 1

    def set_repair_budget(self, blocks: int) -> None:
        """It asks for repeats in at most ``blocks`` repair blocks after each phase from now."""
        if self.arq is not None:
            self.arq.budget = blocks

    def state(self) -> dict[str, Any]:
        """What it knows now, as plain data (a mark's record)."""
        mind, u = self.mind, self.scenario.universe
        return {
            "done": self.done,
            "failure": self.failure,
            "decided_rounds": mind.decided_rounds,
            "relations": mind.installed(),
            "polynomial": mind.polynomial,
            "influences": mind.influence_table(),
            "choice": None if mind.choice is None else u.format(mind.choice),
            "decisions": [dict(d) for d in self.decisions],
        }

    def _draw(self, t: float, installed: dict[str, str] | None = None) -> None:
        """Its place on ``/scene`` (a spatial scenario's only): its sphere and name, and once it
        holds its relationship table its half of each link (``scene_update``)."""
        positions = self.scenario.channel.positions
        if self.log.enabled and positions:
            update = scene_update(self.name, t, positions, installed)
            self.log.write_in_order(records.SCENE, update, t)

    def _log_decisions(self, t: float, rnd: int) -> None:
        """Its decision of round ``rnd`` (kept for its report), and the forward task of every
        subject as it solved it (logged)."""
        mind = self.mind
        u = self.scenario.universe
        decided = mind.round_results.get(rnd)
        if decided is None:
            if mind.p4 is None:  # a group with no polynomial has said so already
                why = mind.error or "the relationship phase did not finish"
                self.log.log("error", f"{self.name}: no decision: {why}", t)
            return
        results, choice = decided
        self.decisions.append(decision_row(self.name, rnd, t, results[self.name], choice, u))
        if not self.log.enabled:  # the canonical forms cost more than the decision
            return
        for record in decision_records(self.name, mind, u, t, rnd):
            self.log.write_in_order(records.UNIT_DECISION, record, t)

    # -- what this unit knows, as plain data (one process's share of a run summary) ----------

    def report_record(self) -> records.UnitReportRecord:
        """What this unit knows at the end of its run (``/unit/report``): everything its share
        of the run summary needs but its decodes (those are ``/rx/decodes``), and but its
        tables where its last ``/unit/relations`` or ``/unit/influences`` record holds them as
        they are now (``records.slim_report``: a group's n² tables once a unit, not twice)."""
        return records.slim_report(
            self._report_fields(SendRows(self.sent).tolist()),
            self._logged_relations,
            self._logged_influences,
        )

    def report(self) -> dict[str, Any]:
        """This unit's share of the run summary (``rgtbus.summary.summarise``): its report
        record and its decodes."""
        return {
            # read from its sends as they are iterated: a group's 4n(n−1) sends, not held twice
            **self._report_fields(SendRows(self.sent), views=True),
            "decodes": self.decoded,  # columns (DecodeColumns): iterates as rows
        }

    def _report_fields(
        self, sends: Sequence[list[Any]], *, views: bool = False
    ) -> records.UnitReportRecord:
        """The report record with ``sends`` as its rows of sends (``views``: its tables of
        relation codes and influences as the mind's views, ``PairTexts``, not dicts)."""
        mind = self.mind
        out: records.UnitReportRecord = {
            "unit": self.name,
            "installed": mind.installed(),
            "polynomial": mind.polynomial,
            "p4": None if mind.p4 is None else list(mind.p4),
            "sent_relations": cast(
                dict[str, str], mind.sent_view() if views else mind.sent_table()
            ),
            "influences": cast(
                dict[str, list[str]], mind.influence_view() if views else mind.influence_table()
            ),
            "result": result_fields(mind),
            "decisions": list(self.decisions),
            "sends": cast(list[list[Any]], sends),
            "sent_influences": influences_sent(self.sent, self.protocol, self.scenario),
            "failure": self.failure,
            "failed_at": self.done_at if self.failure else None,
            "done_at": self.done_at if self.done else None,
            "mind_error": mind.error,
        }
        if self.arq is not None:
            out["repair"] = self.arq.book.report()  # type: ignore[typeddict-item]
        if self.steerable:  # what it took of a steered run's changes (``steered_in``)
            injected = [[turn, value] for turn, value in sorted(self._injected.items())]
            out["steered"] = {"injected": injected, "held": [list(h) for h in self._held_from]}
        return out


class SendRows(Sequence[list[Any]]):
    """A unit's sends as its report's rows, ``[turn, kind, addressee, code]``, made as they
    are read; pickled (a unit process's report) as the list of them."""

    __slots__ = ("_sent",)

    def __init__(self, sent: Sequence[Send]) -> None:
        self._sent = sent

    def __len__(self) -> int:
        return len(self._sent)

    @overload
    def __getitem__(self, i: int) -> list[Any]: ...
    @overload
    def __getitem__(self, i: slice) -> list[list[Any]]: ...
    def __getitem__(self, i: int | slice) -> list[Any] | list[list[Any]]:
        if isinstance(i, slice):
            return [_send_row(s) for s in self._sent[i]]
        return _send_row(self._sent[i])

    def __iter__(self) -> Iterator[list[Any]]:
        return (_send_row(s) for s in self._sent)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Sequence) and list(self) == list(other)

    __hash__ = None  # type: ignore[assignment]

    def tolist(self) -> list[list[Any]]:
        """Every row, as a list (for JSON)."""
        return list(self)

    def __reduce__(self) -> tuple[Any, ...]:
        return (list, (list(self),))


def _send_row(s: Send) -> list[Any]:
    """A send as a row of a unit's report (``/unit/report``'s ``sends``)."""
    return [s.turn, s.kind, s.addressee, s.code]


def decision_records(
    name: str, mind: Mind, universe: Universe, t: float, rnd: int
) -> list[records.DecisionRecord]:
    """The ``/unit/decision`` records of unit ``name`` for round ``rnd`` at ``t`` seconds: the
    forward task of every subject as its ``mind`` solved it (its own choice on its own record);
    none when it did not decide that round."""
    decided = mind.round_results.get(rnd)
    if decided is None:
        return []
    results, choice = decided
    out = []
    for s, r in results.items():
        fields = decision_fields(r, choice if s == name else None, universe)
        out.append(records.decision(name, s, t, fields, mind.canonical(s), rnd))
    return out


def goal_record(
    name: str,
    mind: Mind,
    goal: Goal,
    turn: int,
    rnd: int,
    t: float,
    got: SteeringChoice | str,
    code: str,
    reason: str,
) -> records.GoalRecord:
    """The ``/unit/goal`` record of unit ``name``'s choice of its influence on ``goal.target``
    in turn ``turn`` (round ``rnd``) at ``t`` seconds: what it heard and predicted, what the
    inverse task gave (``got``; a text: none), the ``code`` it sends and why."""
    u = mind.universe
    heard, predicted = mind.steering_inputs(goal.target, rnd)
    steered = None if isinstance(got, str) else got
    value = None if steered is None else steered.value
    return records.goal(
        name, t, rnd, turn, goal.target,
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


def influences_sent(
    sent: list[Send], protocol: ProtocolState, scenario: Scenario
) -> list[dict[str, str]]:
    """The influences among ``sent`` (a unit's sends), per influence round:
    ``[{addressee: code}, ...]``."""
    out: list[dict[str, str]] = [{} for _ in range(scenario.protocol.influence_rounds)]
    for send in sent:
        turn = protocol.schedule[send.turn]
        if send.kind == "payload" and turn.phase == PHASES[1]:
            out[turn.round - 1][send.addressee] = send.code
    return out
