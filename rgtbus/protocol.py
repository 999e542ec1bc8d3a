"""The timed protocol (docs/protocol.md), as a pure state machine (one per unit).

All units hear the whole medium. To send code X to unit r, unit s

1. sends the ID-code on its own frequency ω_s, starting at the turn's start time t0;
2. when its ω_s resonator spikes (sample k), waits the reaction delay D;
3. sends X on ω_r, starting at t = k·τ + D.

Medium access (paper mode): one transmission at a time, in a fixed order known to every unit
(phase 1, relationships: every s to every r ≠ s, sender-major; phase 3, influences: the same
order), separated by a guard gap G. The timing chain is therefore decided by ID spikes alone::

    pulse m of a code starting at t on ω:  sample round((t + m·2π/ω) / τ),  m = 0..N-1
    payload start      p = max(k_spike, k_last)·τ + D  (k_last: the ID's last pulse)
    next turn's start  t0' = p + (N-1)·2π/ω_r + G

Every unit runs the same machine on what it hears, so every unit knows when each turn starts,
and the turn's sender additionally acts on it. The machine does not decode: it says what to
decode and when (``Listen``); the unit decodes and reasons.

Anchor ``spike`` (the paper, the default) is the chain above. Anchor ``schedule`` counts each
reaction from the ID's last pulse instead, ``p = k_last·τ + D``: on a clean channel the paper's
ID-code fires its resonator exactly there, so nothing changes, but the whole run is then known
from the start and no unit depends on its own (noise-prone) attention spike: spikes still give
attention and are logged, decoding alone carries the messages. It keeps noisy channels decoding
far past the point where attention spikes fail (see the README).
"""

from __future__ import annotations

import bisect
import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from rgtbus.errors import RgtbusError
from rgtbus.signal.waveform import pulse_samples

PHASES = ("relations", "influences")
ANCHORS = ("spike", "schedule")
# How a spike-anchored unit attends to an ID (docs/protocol.md, "Attention"): the ID decode
# with a timing search confirms it and times the reaction, or the paper's threshold crossing
ATTENTIONS = ("confirmed", "threshold")
SCHEDULES = ("serial", "concurrent")
# Samples a code may be moved to miss every pulse already placed in its round: codes on nearby
# channels start on nearly the same samples, so the i-th is moved about i samples (200 units of
# 3 pulses: a few hundred).
MAX_STAGGER = 4096


MAX_INFLUENCE_ROUNDS = 1000  # far beyond any fixed point or cycle of a small group


@dataclass(frozen=True, slots=True)
class Turn:
    index: int
    phase: str
    sender: str
    addressee: str
    round: int = 0  # the influence round (1..K); 0 in the relationship phase


def phases(influence_rounds: int = 1) -> list[tuple[str, int]]:
    """The phases in order, each with its influence round: relations, then K influence rounds
    (every unit re-sends its influences in each; the paper has one)."""
    if not 1 <= influence_rounds <= MAX_INFLUENCE_ROUNDS:
        raise RgtbusError(
            f"influence_rounds must be 1..{MAX_INFLUENCE_ROUNDS}, got {influence_rounds!r}"
        )
    return [("relations", 0)] + [("influences", r) for r in range(1, influence_rounds + 1)]


def turns(units: Sequence[str], influence_rounds: int = 1) -> list[Turn]:
    """The serial schedule: every ordered pair, sender-major, relations then each influence
    round."""
    out: list[Turn] = []
    for phase, rnd in phases(influence_rounds):
        for s in units:
            for r in units:
                if s != r:
                    out.append(Turn(len(out), phase, s, r, rnd))
    return out


def rounds(units: Sequence[str], influence_rounds: int = 1) -> list[list[Turn]]:
    """The concurrent schedule: per phase n − 1 rounds; in round j (1..n−1) unit i sends to
    unit (i + j) mod n. Every ordered pair comes once a phase, and in every round each unit
    sends one code and is addressed by one (a cyclic Latin square: no channel carries two
    payloads at once). Turn indexes run round by round, relations first."""
    n = len(units)
    out: list[list[Turn]] = []
    index = 0
    for phase, rnd in phases(influence_rounds):
        for j in range(1, n):
            this = []
            for i, s in enumerate(units):
                this.append(Turn(index, phase, s, units[(i + j) % n], rnd))
                index += 1
            out.append(this)
    return out


def choice_sample(payload_start: float, reaction_delay: float, tau: float) -> int:
    """The sample from which a payload's code is chosen: one reaction delay before it starts
    (the moment its sender reacts to its turn's ID). What a unit decoded from samples before
    it is what it knows when it chooses (docs/goals.md); the same for every engine and bus."""
    return round((payload_start - reaction_delay) / tau)


@functools.lru_cache(maxsize=1024)  # every unit plans the same codes of every turn
def code_samples(start: float, omega: float, pulses: int, tau: float) -> tuple[int, ...]:
    """Sample index of each pulse: ``round((start + m·2π/ω) / τ)``."""
    return pulse_samples(omega, start, pulses, tau)


@dataclass(frozen=True, slots=True)
class Send:
    """Put ``code`` on ``channel``'s frequency, pulses at ``samples``. A repair block's sends
    (``block`` 1..K) are a ``request`` (the ID-code on the turn's sender's channel, sent by a
    unit unsure of the turn's payload; ``addressee`` is that sender) and a ``repeat`` (the
    turn's payload again)."""

    turn: int
    kind: str  # "id" | "payload" | "request" | "repeat"
    channel: str
    code: str
    start: float
    samples: tuple[int, ...]
    sender: str
    addressee: str
    block: int = 0  # the repair block (1..K) of a request or a repeat


@dataclass(frozen=True, slots=True)
class Listen:
    """Decode once every sample up to ``ready_sample`` has been received.

    ``kind`` "id": check the ID-code on ``channels[0]`` at ``start``. ``kind`` "relation" or
    "influence": find which of ``channels`` carries a code starting at ``start`` and read it.
    """

    turn: int
    kind: str
    sender: str
    expected_addressee: str
    channels: tuple[str, ...]
    start: float
    ready_sample: int
    # (sender, expected addressee), made once: the key of what a unit learns from it, shared
    # by every unit of a shared queue (not a tuple per unit and code)
    pair: tuple[str, str] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "pair", (self.sender, self.expected_addressee))


@dataclass(frozen=True, slots=True)
class ListenQueue:
    """Listens in the order they fall due, to be taken one at a time: ``listens[order[i]]`` is
    the i-th due, at ``boundaries[i]`` (its ready sample + 1); listens due at one boundary keep
    their planning order. One queue is shared by every unit that plans the same listens (the
    concurrent schedule: every unit decodes every code), so a unit holds a cursor into it, not
    an object per (unit, code) (issue 23)."""

    listens: tuple[Listen, ...]
    boundaries: tuple[int, ...]
    order: tuple[int, ...]

    @classmethod
    def of(cls, listens: Sequence[Listen]) -> ListenQueue:
        order = sorted(range(len(listens)), key=lambda i: listens[i].ready_sample)  # stable
        return cls(
            tuple(listens),
            tuple(listens[i].ready_sample + 1 for i in order),
            tuple(order),
        )


@dataclass
class Actions:
    """What a protocol event asks of its unit: transmit ``sends``, decode ``listens`` when their
    samples are in, set the resonators back to rest before each sample of ``quench`` (a turn's
    start: the paper's b = −0.1 rings for ~10 s, longer than any guard, and leftovers of the
    last turn could cancel or fake the next ID), when ``deadline`` is set, after that sample
    check that the current turn's ID spike came (threshold attention: ``check_deadline``) or
    attend to its ID (confirmed attention: ``on_attention``), and lay out the ``repairs``
    blocks."""

    sends: list[Send] = field(default_factory=list)
    listens: Sequence[Listen] = field(default_factory=list)
    quench: list[int] = field(default_factory=list)
    deadline: int | None = None
    queue: ListenQueue | None = None  # ``listens`` in the order they fall due, when shared
    repairs: list[RepairBlock] = field(default_factory=list)  # repair blocks now known

    def __bool__(self) -> bool:
        return bool(
            self.sends or self.listens or self.quench or self.deadline is not None or self.repairs
        )


NEVER = 2**63 - 1  # "no such sample": a promise of silence for the rest of the run


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
        k = round((payload_start + tail + guard) / tau)
        out.append((round(payload_start / tau), k))
    return tuple(out)


NOTHING = Actions()  # what a spike the protocol ignores asks for (shared: never changed)


class Plan:
    """What every unit knows of a run's schedule before it starts (the same for every unit,
    so one read-only object serves all: ``plan_of``): the turns, each unit's period, for each
    sender the other units (a payload's possible channels) and the slowest of their periods
    (a payload is read as far as that one's code could reach), each turn's payload length."""

    def __init__(
        self,
        units: tuple[str, ...],
        omegas: tuple[tuple[str, float], ...],
        tau: float,
        pulses: int,
        reaction_delay: float,
        guard: float,
        search: int,
        kind: str = "serial",
        start: float = 0.001,
        influence_rounds: int = 1,
        repair_rounds: int = 0,
        read_margin: int = 0,
    ) -> None:
        if kind not in SCHEDULES:
            raise RgtbusError(f"unknown schedule {kind!r} (schedules: {', '.join(SCHEDULES)})")
        self.units, self.tau, self.pulses = units, tau, pulses
        self.reaction_delay, self.guard, self.search = reaction_delay, guard, search
        self.kind, self.start = kind, start
        self.omegas = dict(omegas)
        self.influence_rounds = influence_rounds
        self.repair_rounds = repair_rounds  # repair blocks after each phase (0: none)
        # samples a read reaches past its last instant (a timed channel's two-sample reads)
        self.read_margin = read_margin
        self.rounds = (
            tuple(tuple(r) for r in rounds(units, influence_rounds)) if kind == "concurrent" else ()
        )
        serial = kind != "concurrent"
        self.schedule = (
            tuple(turns(units, influence_rounds))
            if serial
            else tuple(t for r in self.rounds for t in r)
        )
        self.periods = {u: 2 * math.pi / w for u, w in omegas}
        self.others = {s: tuple(u for u in units if u != s) for s in units}
        self.longest = {
            s: max((self.periods[u] for u in o), default=0.0) for s, o in self.others.items()
        }
        self.tails = tuple((pulses - 1) * self.periods[t.addressee] for t in self.schedule)
        self._reactions: dict[tuple[int, float, int], Reaction] = {}
        self._timing: tuple[RoundTiming, ...] | None = None
        self._listens: ListenQueue | None = None

    def timing(self) -> tuple[RoundTiming, ...]:
        """The concurrent schedule's rounds, placed (once for every unit)."""
        if self._timing is None:
            self._timing = place_rounds(self)
        return self._timing

    def concurrent_listens(self) -> ListenQueue:
        """Every decode of the concurrent schedule, the same for every unit (each unit decodes
        every turn's ID and payload, its own too), worked out once for all of them."""
        if self._listens is None:
            listens: list[Listen] = []
            for rnd in self.timing():
                for p in rnd.placed:
                    t = p.turn
                    kind = "relation" if t.phase == "relations" else "influence"
                    listens.append(
                        Listen(t.index, "id", t.sender, t.addressee, (t.sender,), p.id_start,
                               p.id_samples[-1])
                    )  # fmt: skip
                    listens.append(
                        Listen(t.index, kind, t.sender, t.addressee, (t.addressee,),
                               p.payload_start, p.payload_samples[-1] + self.search)
                    )  # fmt: skip
            self._listens = ListenQueue.of(listens)
        return self._listens

    def reaction(self, turn: int, turn_start: float, sample: int) -> Reaction:
        """What follows from turn ``turn`` (started at ``turn_start``) having its ID spike at
        ``sample``: the payload, what to decode when, and the next turn's start (worked out
        once for every unit that reacts to the same spike)."""
        key = (turn, turn_start, sample)
        got = self._reactions.get(key)
        if got is None:
            if len(self._reactions) >= 4096:  # past turns are not asked again
                self._reactions.clear()
            got = self._reactions[key] = self._react(turn, turn_start, sample)
        return got

    def _react(self, turn: int, turn_start: float, sample: int) -> Reaction:
        t = self.schedule[turn]
        tau = self.tau
        ids = code_samples(turn_start, self.omegas[t.sender], self.pulses, tau)
        # An attention spike can come before the ID's last pulse (long codes build up faster):
        # the reaction counts from the later of the two, so a payload never overlaps its ID.
        payload_start = max(sample, ids[-1]) * tau + self.reaction_delay
        payload = code_samples(payload_start, self.omegas[t.addressee], self.pulses, tau)
        kind = "relation" if t.phase == "relations" else "influence"
        longest = self.longest[t.sender] * (self.pulses - 1)
        ready = round((payload_start + longest) / tau) + self.search + self.read_margin
        listens = (
            Listen(
                t.index,
                "id",
                t.sender,
                t.addressee,
                (t.sender,),
                turn_start,
                max(ids[-1], sample) + self.read_margin,
            ),
            Listen(
                t.index, kind, t.sender, t.addressee, self.others[t.sender], payload_start, ready
            ),
        )
        next_start = payload_start + (self.pulses - 1) * self.periods[t.addressee] + self.guard
        repairs: tuple[RepairBlock, ...] = ()
        if self.repair_rounds and self._ends_phase(turn):
            phase_turns = [u for u in self.schedule if (u.phase, u.round) == (t.phase, t.round)]
            phase = phases(self.influence_rounds).index((t.phase, t.round))
            # one code at a time: the phase's last payload pulse is this turn's
            repairs = repair_blocks(self, phase_turns, phase, ready, payload[-1] * tau)
            next_start = repairs[-1].end + self.guard
        return Reaction(
            payload_start, payload, listens, next_start, round(next_start / tau), repairs
        )

    def _ends_phase(self, turn: int) -> bool:
        """Whether turn ``turn`` is its phase's last (serial: the next is of another phase)."""
        if turn + 1 == len(self.schedule):
            return True
        t, nxt = self.schedule[turn], self.schedule[turn + 1]
        return (nxt.phase, nxt.round) != (t.phase, t.round)


@dataclass(frozen=True, slots=True)
class Placed:
    """One turn of a concurrent round, placed: its ID and its payload, start and samples."""

    turn: Turn
    id_start: float
    id_samples: tuple[int, ...]
    payload_start: float
    payload_samples: tuple[int, ...]


@dataclass(frozen=True)
class RoundTiming:
    start: float
    quench: int  # the round's first sample: resonators to rest before it
    placed: tuple[Placed, ...]
    end: float  # the last payload pulse
    repairs: tuple[RepairBlock, ...] = ()  # after a phase's last round (``repair_blocks``)


@dataclass(frozen=True, slots=True)
class RepairSlot:
    """One payload of a phase in a repair block: where a unit unsure of it asks for it again
    (the ID-code on the sender's channel, ``request``) and where its sender repeats it, if
    it heard the request (the same code on the addressee's channel, ``repeat``)."""

    turn: int
    sender: str
    addressee: str
    request_start: float
    request: tuple[int, ...]
    repeat_start: float
    repeat: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class RepairBlock:
    """Repair block ``number`` (1..K) after phase ``phase`` (an index into ``phases``): a slot
    for every payload of the phase, at fixed samples, whether or not anybody asks (so every
    unit agrees on the timing whatever it heard; docs/protocol.md, "Repair").

    A unit chooses its requests from what it decoded before ``request_choice``, a sender its
    repeats from the samples before ``repeat_choice`` (each one reaction delay before the
    first pulse it may send), and a requester reads the copies after ``ready``."""

    phase: int
    number: int
    request_choice: int
    repeat_choice: int
    ready: int
    slots: tuple[RepairSlot, ...]
    start: float  # the first request pulse's time
    end: float  # the last repeat pulse's time
    phase_end: float  # the phase's last payload pulse's time (the blocks add ``end`` - it)

    @property
    def first_request(self) -> int:
        return min(s.request[0] for s in self.slots)

    @property
    def first_repeat(self) -> int:
        return min(s.repeat[0] for s in self.slots)


def repair_blocks(
    plan: Plan, phase_turns: Sequence[Turn], phase: int, ready: int, phase_end: float
) -> tuple[RepairBlock, ...]:
    """The ``plan.repair_rounds`` repair blocks after a phase whose last payload pulse is at
    ``phase_end`` and whose last decode is ready at sample ``ready``. Each block: the
    requests, placed from ``reaction_delay + guard`` after the last sample anything of the
    block depends on, one ID-code a payload on its sender's channel; then, as far after the
    last request, the repeats, each payload on its addressee's channel. Codes are moved later
    by whole samples until no two pulses share a sample (as a concurrent round's), so a
    request and a repeat are each read alone. Pure: every unit lays out the same blocks."""
    tau, pulses, delay, guard = plan.tau, plan.pulses, plan.reaction_delay, plan.guard

    def after(sample: int) -> float:
        """A part's start: a guard and a reaction delay after the sample it depends on."""
        return (sample + 1) * tau + guard + delay

    def place_all(start: float, what: str) -> list[tuple[float, tuple[int, ...]]]:
        """A code for every payload of the phase from ``start``, each on its sender's channel
        (requests) or its addressee's (repeats), none sharing a sample with another."""
        used = _Occupied(round(start / tau) - 1)
        hints: dict[tuple[float, float], int] = {}
        return [
            _place(used, hints, start,
                   plan.omegas[t.sender if what == "request" else t.addressee], pulses, tau,
                   f"repair block {number}: the {what} of {t.sender} -> {t.addressee}")
            for t in phase_turns
        ]  # fmt: skip

    out: list[RepairBlock] = []
    last = ready
    for number in range(1, plan.repair_rounds + 1):
        q = after(last)
        requests = place_all(q, "request")
        r0 = after(max(r[-1] for _, r in requests))
        repeats = place_all(r0, "repeat")
        slots = tuple(
            RepairSlot(t.index, t.sender, t.addressee, qs, qk, rs, rk)
            for t, (qs, qk), (rs, rk) in zip(phase_turns, requests, repeats, strict=True)
        )
        last = max(r[-1] for _, r in repeats)
        out.append(
            RepairBlock(
                phase,
                number,
                choice_sample(q, delay, tau),
                choice_sample(r0, delay, tau),
                last,
                slots,
                min(qs for qs, _ in requests),
                last * tau,
                phase_end,
            )
        )
    return tuple(out)


class _Occupied:
    """The samples a round's codes use, as a boolean array from ``origin`` on (grown as
    needed; no code of the round starts before its origin)."""

    def __init__(self, origin: int) -> None:
        self.origin = origin
        self.used = np.zeros(4096, dtype=bool)

    def reach(self, last: int) -> np.ndarray:
        """The array, grown to hold sample ``last``."""
        need = last - self.origin + 1
        if need > self.used.size:
            grown = np.zeros(max(2 * self.used.size, need), dtype=bool)
            grown[: self.used.size] = self.used
            self.used = grown
        return self.used

    def free(self, samples: tuple[int, ...]) -> bool:
        """None of these samples (ascending) is taken."""
        used, o = self.reach(samples[-1]), self.origin
        return not any(used[k - o] for k in samples)

    def take(self, samples: tuple[int, ...]) -> None:
        used, o = self.reach(samples[-1]), self.origin
        for k in samples:
            used[k - o] = True


_SHIFTS = np.arange(64)  # a block of shifts screened at once (``place_rounds``)


def _place(
    used: _Occupied,
    hints: dict[tuple[float, float], int],
    start: float,
    omega: float,
    pulses: int,
    tau: float,
    what: str,
) -> tuple[float, tuple[int, ...]]:
    """The first start, ``start`` moved later by whole samples, at which a code on ω has
    none of its pulses on a sample ``used`` already holds; taken. Moving a code by j samples
    moves its pulses by about j: shifts are screened 64 at a time on the occupancy array,
    and a screened one is confirmed with the exact instants (a rounding tie can move one
    pulse a sample further). A block only takes samples, so a shift refused to a code stays
    refused to the next with the same start and ω (``hints``): the search goes on from there."""
    first_samples = code_samples(start, omega, pulses, tau)
    base = np.asarray(first_samples, dtype=np.int64)[:, None] - used.origin
    first = hints.get((start, omega), 0)
    for lo in range(first, MAX_STAGGER + 1, 64):
        hi = min(lo + 64, MAX_STAGGER + 1)
        occupied = used.reach(first_samples[-1] + hi - 1)
        free = ~occupied[base + _SHIFTS[: hi - lo] + lo].any(axis=0)
        for j in (np.flatnonzero(free) + lo).tolist():
            s = start + j * tau
            samples = code_samples(s, omega, pulses, tau)
            if len(set(samples)) == len(samples) and used.free(samples):
                used.take(samples)
                hints[(start, omega)] = j + 1
                return s, samples
    raise RgtbusError(
        f"{what} finds no free samples within {MAX_STAGGER} samples of its place (too many "
        "codes for the sample rate)"
    )


def place_rounds(plan: Plan) -> tuple[RoundTiming, ...]:
    """Every round of a concurrent schedule, timed (docs/protocol.md, "Concurrent schedule").

    In a round every unit sends its ID-code on its own channel from the round's start; the
    payloads follow together, ``reaction_delay`` after the last ID's last pulse, each on its
    addressee's channel; the next round starts ``guard`` after the last payload pulse. A code
    is moved later by whole samples (at most ``MAX_STAGGER``), IDs in unit order and then
    payloads in sender order, until none of its pulses falls on a sample another code of the
    round already uses: the medium then never adds two pulses, and each unit reads every code
    alone (the readout at a sample is what the medium carried there). Pure and the same for
    every unit, so every unit knows every code's samples before the run."""
    tau, pulses = plan.tau, plan.pulses
    out: list[RoundTiming] = []
    t0 = plan.start

    hints: dict[tuple[float, float], int] = {}  # (start, ω) -> the first shift not refused

    def place(
        used: _Occupied, start: float, omega: float, what: str
    ) -> tuple[float, tuple[int, ...]]:
        return _place(used, hints, start, omega, pulses, tau, f"concurrent schedule: {what}")

    per_phase = max(1, len(plan.units) - 1)  # rounds a phase
    for i, turns_of_round in enumerate(plan.rounds):
        used = _Occupied(round(t0 / tau) - 1)
        hints.clear()  # a round's samples of its own
        ids = [
            place(used, t0, plan.omegas[t.sender], f"the ID of {t.sender}") for t in turns_of_round
        ]
        payload_at = max(s[-1] for _, s in ids) * tau + plan.reaction_delay
        placed = []
        for t, (id_start, id_samples) in zip(turns_of_round, ids, strict=True):
            p_start, p_samples = place(
                used,
                payload_at,
                plan.omegas[t.addressee],
                f"the code of {t.sender} to {t.addressee}",
            )
            placed.append(Placed(t, id_start, id_samples, p_start, p_samples))
        last = max(p.payload_samples[-1] for p in placed)
        end = last * tau
        repairs: tuple[RepairBlock, ...] = ()
        if plan.repair_rounds and (i + 1) % per_phase == 0:  # the phase's last round
            phase_turns = [t for r in plan.rounds[i + 1 - per_phase : i + 1] for t in r]
            repairs = repair_blocks(plan, phase_turns, i // per_phase, last + plan.search, end)
        out.append(RoundTiming(t0, round(t0 / tau), tuple(placed), end, repairs))
        t0 = (repairs[-1].end if repairs else end) + plan.guard
    return tuple(out)


@dataclass(frozen=True)
class Reaction:
    payload_start: float
    payload: tuple[int, ...]
    listens: tuple[Listen, Listen]
    next_start: float
    next_quench: int  # the next turn's start as a sample: resonators to rest before it
    repairs: tuple[RepairBlock, ...] = ()  # after the phase this turn ends (``repair_blocks``)


# One Plan for every unit of a run: the constructor, cached on its (hashable) arguments.
plan_of = functools.lru_cache(maxsize=64)(Plan)


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
            raise RgtbusError(f"unknown anchor {self.anchor!r} (anchors: {', '.join(ANCHORS)})")
        if self.attention not in ATTENTIONS:
            raise RgtbusError(
                f"unknown attention {self.attention!r} (attentions: {', '.join(ATTENTIONS)})"
            )
        if self.kind == "concurrent" and self.anchor != "schedule":
            raise RgtbusError(
                "the concurrent schedule is timed by the schedule (anchor schedule): every "
                "round is known before the run"
            )
        if self.repair_rounds and self.anchor != "schedule":
            raise RgtbusError(
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
        self._own_turns = [t.index for t in self.schedule if t.sender == self.me]
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
        for i, rnd in enumerate(self.plan.timing()):
            if i:
                acts.quench.append(rnd.quench)
                self.turn_starts.append(rnd.start)
            acts.repairs.extend(rnd.repairs)
            for p in rnd.placed:
                t = p.turn
                if t.sender == self.me:
                    acts.sends.append(
                        Send(t.index, "id", t.sender, "id", p.id_start, p.id_samples, t.sender,
                             t.addressee)
                    )  # fmt: skip
                    acts.sends.append(
                        Send(t.index, "payload", t.addressee, self._codes[t.phase][t.addressee],
                             p.payload_start, p.payload_samples, t.sender, t.addressee)
                    )  # fmt: skip
        acts.queue = self.plan.concurrent_listens()
        acts.listens = acts.queue.listens
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
