"""One unit's protocol machine (``ProtocolState``): what it knows of the schedule and what it
must do next, event by event (its start, an ID spike or attention, a deadline). Pure."""

from __future__ import annotations

import bisect
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

from rgtbus.errors import BadInput
from rgtbus.protocol.timetable import plan_of
from rgtbus.protocol.turns import (
    ANCHORS,
    ATTENTIONS,
    NEVER,
    NOTHING,
    Actions,
    Listen,
    Send,
    Turn,
    code_samples,
)
from rgtbus.timebase import sample_of


@functools.lru_cache(maxsize=512)  # every unit chains the same turns from the same spike
def _chain_steps(
    k: int, tails: tuple[float, ...], tau: float, delay: float, guard: float
) -> tuple[tuple[int, int], ...]:
    """Turn after turn from an ID spike at sample k, each reacting as early as it can: per
    turn (its payload's first pulse, the next turn's first ID pulse), the next turn starting
    ``guard`` after the payload's last pulse (``tails``: each turn's (N − 1)·T)."""
    out = []
    for tail in tails:
        payload_start = k * tau + delay
        k = sample_of(payload_start + tail + guard, tau)
        out.append((sample_of(payload_start, tau), k))
    return tuple(out)


@dataclass
class ProtocolState:
    """What one unit knows of the schedule, and what it must do next."""

    me: str
    units: tuple[str, ...]
    omegas: dict[str, float]
    tau: float
    pulses: int = 3
    start: float = 0.001
    reaction_delay: float = 0.5
    guard: float = 0.5
    search: int = 2  # samples of timing search around a payload's expected start
    anchor: str = "spike"  # what a reaction counts from: the ID spike, or the ID's last pulse
    kind: str = "serial"  # the schedule: one code at a time, or rounds of n at once
    influence_rounds: int = 1  # influence phases after the relationship phase (the paper: 1)
    repair_rounds: int = 0  # repair blocks after each phase ([protocol] repair "arq"); 0: none
    attention: str = "confirmed"  # spike anchor: "confirmed" by the ID decode, or "threshold"
    read_margin: int = 0  # samples a read reaches past its instant (1: a timed channel)
    # the sample of a clean channel's attention spike to an ID: (sender, the ID's samples,
    # its deadline) -> sample or None (none by the deadline); without it, the ID's last pulse
    # (``expected_reaction``)
    expect_spike: Callable[[str, tuple[int, ...], int], int | None] | None = field(
        default=None, compare=False, repr=False
    )
    schedule: tuple[Turn, ...] = field(init=False)
    turn: int = field(init=False, default=0)
    turn_start: float = field(init=False)
    errors: list[str] = field(init=False, default_factory=list)

    def __post_init__(self) -> None:
        if self.anchor not in ANCHORS:
            raise BadInput(f"unknown anchor {self.anchor!r} (anchors: {', '.join(ANCHORS)})")
        if self.attention not in ATTENTIONS:
            raise BadInput(
                f"unknown attention {self.attention!r} (attentions: {', '.join(ATTENTIONS)})"
            )
        if self.kind == "concurrent" and self.anchor != "schedule":
            raise BadInput(
                "the concurrent schedule is timed by the schedule (anchor schedule): every "
                "round is known before the run"
            )
        if self.repair_rounds and self.anchor != "schedule":
            raise BadInput(
                "repair needs turns timed by the schedule (anchor schedule): a repair block "
                "sits at samples every unit must know whatever it heard"
            )
        self.plan = plan_of(
            tuple(self.units),
            tuple((u, float(self.omegas[u])) for u in self.units),
            self.tau,
            self.pulses,
            self.reaction_delay,
            self.guard,
            self.search,
            self.kind,
            self.start,
            self.influence_rounds,
            self.repair_rounds,
            self.read_margin,
        )
        self.schedule = self.plan.schedule
        self._periods = self.plan.periods
        self._own_turns = self.plan.turns_sent_by(self.me)
        # each turn's payload length, (N − 1)·T of its addressee (the chain of reactions)
        self._tails = self.plan.tails
        self.turn_start = self.start
        self.turn_starts = [self.start]  # every turn's start known so far
        self._ids_key: tuple[int, float] | None = None
        self._ids: tuple[int, ...] = ()
        self._bound_key: tuple[int, int] | None = None
        self._bound = NEVER
        self._awaited: tuple[str, int, int] | None = None  # None: not known for this turn yet
        self._expected_key: tuple[int, float] | None = None
        self._expected = 0

    # -- helpers

    def period(self, unit: str) -> float:
        return self._periods[unit]

    def current(self) -> Turn | None:
        return self.schedule[self.turn] if self.turn < len(self.schedule) else None

    @property
    def finished(self) -> bool:
        return self.turn >= len(self.schedule)

    def id_samples(self) -> tuple[int, ...]:
        t = self.current()
        assert t is not None
        key = (t.index, self.turn_start)
        if self._ids_key != key:  # asked every window by the deadline check: compute once
            self._ids_key = key
            self._ids = code_samples(self.turn_start, self.omegas[t.sender], self.pulses, self.tau)
        return self._ids

    def id_deadline(self) -> int:
        """The last sample at which the current ID may still make its sender's resonator spike:
        the last ID pulse plus one period (y can cross threshold between pulses)."""
        t = self.current()
        assert t is not None
        return self.id_samples()[-1] + math.ceil(self.period(t.sender) / self.tau)

    def expected_reaction(self) -> int:
        """Where the current turn's reaction counts from on a clean channel: the later of its
        attention spike (``expect_spike``, when it comes) and the ID's last pulse. A confirmed
        attention reacts at it, moved by the ID decode's timing search (``on_attention``)."""
        t = self.current()
        assert t is not None
        key = (t.index, self.turn_start)
        if self._expected_key != key:  # asked at every promise: once a turn
            ids = self.id_samples()
            k = (
                None
                if self.expect_spike is None
                else self.expect_spike(t.sender, ids, self.id_deadline())
            )
            self._expected_key = key
            self._expected = ids[-1] if k is None else max(k, ids[-1])
        return self._expected

    @property
    def confirmed(self) -> bool:
        """Turns timed by confirmed attention (the spike anchor's default)."""
        return self.anchor == "spike" and self.attention == "confirmed"

    # -- events

    def begin(self, relation_code: dict[str, str], influence_code: dict[str, str]) -> Actions:
        """Start of the run: the first turn's sender sends its ID. Anchored on the schedule,
        the whole run is known now: every send, listen and quench of every turn."""
        self._codes = {"relations": relation_code, "influences": influence_code}
        if self.kind == "concurrent":
            return self._begin_concurrent()
        acts = Actions(sends=self._id_actions())
        listens: list[Listen] = []
        while self.anchor == "schedule" and not self.finished:
            more = self._react(self.id_samples()[-1])
            acts.sends += more.sends
            listens += more.listens
            acts.quench += more.quench
            acts.repairs += more.repairs
        acts.listens = listens
        acts.deadline = self._deadline()
        return acts

    def _begin_concurrent(self) -> Actions:
        """Every round at once: this unit's IDs and payloads, every decode of every round, a
        quench at every round's start but the first."""
        acts = Actions()
        quench, starts, repairs = self.plan.rounds_at()
        acts.quench.extend(quench)
        self.turn_starts.extend(starts)
        acts.repairs.extend(repairs)
        for p in self.plan.placed_by(self.me):
            t = p.turn
            acts.sends.append(
                Send(t.index, "id", t.sender, "id", p.id_start, p.id_samples, t.sender,
                     t.addressee)
            )  # fmt: skip
            acts.sends.append(
                Send(t.index, "payload", t.addressee, self._codes[t.phase][t.addressee],
                     p.payload_start, p.payload_samples, t.sender, t.addressee)
            )  # fmt: skip
        acts.queue = self.plan.concurrent_listens()  # its listens as columns: no Listen each
        acts.sends.sort(key=lambda s: s.samples[0])
        self.turn = len(self.schedule)  # every reaction is known: nothing left to wait for
        return acts

    def _id_actions(self) -> list[Send]:
        t = self.current()
        if t is None or t.sender != self.me:
            return []
        return [
            Send(
                t.index,
                "id",
                t.sender,
                "id",
                self.turn_start,
                self.id_samples(),
                t.sender,
                t.addressee,
            )
        ]

    def on_attention(self, shift: int) -> Actions:
        """Confirmed attention to the current turn's ID: its decode with a timing search read
        the ID-code, ``shift`` samples from where the schedule puts it. The reaction counts
        from the expected reaction moved by that shift (0 on a clean channel: the reaction
        the attention spike gives there, so the run and its log are the paper's)."""
        acts = self._react(self.expected_reaction() + shift)
        acts.deadline = self._deadline()
        return acts

    def on_spike(self, channel: str, sample: int) -> Actions:
        """A spike on ``channel``'s resonator at ``sample``: the ID spike of the current turn
        (once its first pulse is on the medium) moves the schedule on. Any other spike asks
        for nothing (the shared, empty ``NOTHING``)."""
        t = self.current()
        if self.anchor != "spike" or self.confirmed or t is None or channel != t.sender:
            return NOTHING
        if sample < self.id_samples()[0]:
            return NOTHING
        acts = self._react(sample)
        acts.deadline = self._deadline()
        return acts

    def _react(self, sample: int) -> Actions:
        """The current turn's ID counts from ``sample``: plan its payload and the next turn."""
        t = self.current()
        assert t is not None
        r = self.plan.reaction(self.turn, self.turn_start, sample)
        sends: list[Send] = []
        if t.sender == self.me:
            code = self._codes[t.phase][t.addressee]
            sends.append(
                Send(
                    t.index,
                    "payload",
                    t.addressee,
                    code,
                    r.payload_start,
                    r.payload,
                    t.sender,
                    t.addressee,
                )
            )
        # Next turn: the chain is known now, well ahead of its first pulse.
        self.turn += 1
        self.turn_start = r.next_start
        self._awaited = None
        quench = []
        if not self.finished:
            self.turn_starts.append(self.turn_start)
            quench.append(r.next_quench)
        sends.extend(self._id_actions())
        return Actions(sends, list(r.listens), quench, repairs=list(r.repairs))

    def _deadline(self) -> int | None:
        """The current turn's ID deadline when the chain depends on its spike; with confirmed
        attention the sample after which its ID is decoded and reacted to (``on_attention``):
        the expected reaction plus the timing search."""
        if self.anchor != "spike" or self.finished:
            return None
        if self.confirmed:
            return self.expected_reaction() + self.search + self.read_margin
        return self.id_deadline()

    def awaited(self) -> tuple[str, int, int] | None:
        """The spike the chain waits for: (channel, earliest sample, latest sample), or None
        when nothing this unit hears can plan a send any more (every reaction known, or the
        run's end). Past the latest sample (the ID's deadline) the chain is broken."""
        if self.anchor != "spike" or self.confirmed or self.turn >= len(self.schedule):
            return None
        if self._awaited is None:  # asked at every wake and spike: the same until the chain moves
            t = self.schedule[self.turn]
            self._awaited = (t.sender, self.id_samples()[0], self.id_deadline())
        return self._awaited

    def send_bound(self, h: int) -> int:
        """A lower bound on the first sample of any send this machine has not planned yet,
        given that it has heard no ID spike before sample ``h`` (``NEVER`` if none can come).

        Only a reaction plans sends: to turn i's ID spike at k (k ≥ h and k ≥ the ID's first
        pulse) this unit plans its payload if it sends turn i, or turn i+1's ID if it sends
        that one; a later turn starts no earlier than the previous reaction plus the delay,
        the payload and the guard. Every step is monotone in k, so chaining from the earliest
        possible spike gives the earliest send: the promise behind the conservative
        synchronisation of the event engine (docs/engine.md). With confirmed attention no
        spike is awaited: the reaction comes within the timing search of the expected one."""
        if self.anchor != "spike" or self.finished:
            return NEVER
        j = bisect.bisect_left(self._own_turns, self.turn)
        if j == len(self._own_turns):
            return NEVER
        mine = self._own_turns[j]
        i = self.turn
        if self.confirmed:  # it reacts within the timing search of the expected reaction
            k = max(self.id_samples()[0], self.expected_reaction() - self.search)
        else:
            k = max(h, self.id_samples()[0])
        if self._bound_key == (i, k):  # asked every round: the same until the chain moves
            return self._bound
        self._bound_key = (i, k)
        self._bound = self._chain(i, k, mine)
        return self._bound

    def _chain(self, i: int, k: int, mine: int) -> int:
        # stopping early only loosens the bound, and 8 turns is far enough
        steps = _chain_steps(k, self._tails[i : i + 8], self.tau, self.reaction_delay, self.guard)
        for j, (payload, next_id) in enumerate(steps):
            if i + j == mine:
                return payload  # the payload's first pulse
            if i + j + 1 == mine:
                return next_id  # the next turn's ID, first pulse
        return steps[-1][1]

    def check_deadline(self, received_upto: int) -> str | None:
        """An error text when the current ID's spike is overdue (the chain cannot go on)."""
        t = self.current()
        if t is None or self.anchor != "spike" or self.confirmed:
            return None
        if received_upto > self.id_deadline():
            msg = (
                f"{self.me}: no ID spike on {t.sender}'s channel for turn {t.index} "
                f"({t.sender} -> {t.addressee}, {t.phase}) by t = "
                f"{self.id_deadline() * self.tau:.3f} s"
            )
            self.errors.append(msg)
            return msg
        return None
