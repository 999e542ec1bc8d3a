"""What every unit knows of a run's schedule before it starts (``Plan``): the turns, the
reaction to each turn's ID spike, the concurrent schedule's rounds placed on the samples, and
the repair blocks after each phase, all laid out alike by every unit. Pure."""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rgtbus.errors import BadInput
from rgtbus.protocol.turns import (
    SCHEDULES,
    Listen,
    ListenQueue,
    RepairBlock,
    RepairSlot,
    Turn,
    choice_sample,
    code_samples,
    phases,
    rounds,
    turns,
)
from rgtbus.timebase import sample_of

# Samples a code may be moved to miss every pulse already placed in its round: codes on nearby
# channels start on nearly the same samples, so the i-th is moved about i samples (200 units of
# 3 pulses: a few hundred).
MAX_STAGGER = 4096


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
            raise BadInput(f"unknown schedule {kind!r} (schedules: {', '.join(SCHEDULES)})")
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
        self._sent_by: dict[str, tuple[int, ...]] | None = None
        self._placed_by: dict[str, tuple[Placed, ...]] | None = None
        self._rounds_at: (
            tuple[tuple[int, ...], tuple[float, ...], tuple[RepairBlock, ...]] | None
        ) = None
        self._repair_reach: float | None = None

    def timing(self) -> tuple[RoundTiming, ...]:
        """The concurrent schedule's rounds, placed (once for every unit)."""
        if self._timing is None:
            self._timing = place_rounds(self)
        return self._timing

    def rounds_at(self) -> tuple[tuple[int, ...], tuple[float, ...], tuple[RepairBlock, ...]]:
        """The concurrent schedule's rounds as every unit begins them (once for all of them):
        the first sample of each round but the first (a quench there), each one's start, and
        every repair block, in order."""
        if self._rounds_at is None:
            timing = self.timing()
            self._rounds_at = (
                tuple(r.quench for r in timing[1:]),
                tuple(r.start for r in timing[1:]),
                tuple(b for r in timing for b in r.repairs),
            )
        return self._rounds_at

    def repair_reach(self) -> float:
        """How far back, in seconds, a repair block of the concurrent schedule reads: from the
        earliest payload of its phase to the block's last repeat (0 without repair, or on the
        serial schedule, whose reads are taken as each turn ends). A unit keeps its readout at
        least this long: a phase of a large group outlasts the default history."""
        if self.kind != "concurrent" or not self.repair_rounds:
            return 0.0
        if self._repair_reach is None:  # once for every unit (the plan is shared)
            start = {p.turn.index: p.payload_start for r in self.timing() for p in r.placed}
            reach = 0.0
            for rnd in self.timing():
                for block in rnd.repairs:
                    first = min(start[s.turn] for s in block.slots)
                    reach = max(reach, block.end - first)
            self._repair_reach = reach
        return self._repair_reach

    def turns_sent_by(self, sender: str) -> tuple[int, ...]:
        """The indexes of the turns ``sender`` sends, ascending (once for every unit: a unit
        looking through all n(n−1) turns for its own made n³ steps in a run)."""
        if self._sent_by is None:
            by: dict[str, list[int]] = {u: [] for u in self.units}
            for t in self.schedule:
                by[t.sender].append(t.index)
            self._sent_by = {u: tuple(ts) for u, ts in by.items()}
        return self._sent_by.get(sender, ())

    def placed_by(self, sender: str) -> tuple[Placed, ...]:
        """The concurrent schedule's placed turns that ``sender`` sends, in round order."""
        if self._placed_by is None:
            by: dict[str, list[Placed]] = {u: [] for u in self.units}
            for rnd in self.timing():
                for p in rnd.placed:
                    by[p.turn.sender].append(p)
            self._placed_by = {u: tuple(ps) for u, ps in by.items()}
        return self._placed_by.get(sender, ())

    def concurrent_listens(self) -> ListenQueue:
        """Every decode of the concurrent schedule, the same for every unit (each unit decodes
        every turn's ID and payload, its own too), worked out once for all of them."""
        if self._listens is None:
            index = {u: i for i, u in enumerate(self.units)}
            turn: list[int] = []
            kind: list[int] = []
            sender: list[int] = []
            addressee: list[int] = []
            channel: list[int] = []
            start: list[float] = []
            ready: list[int] = []
            for rnd in self.timing():
                for p in rnd.placed:
                    t = p.turn
                    s, a = index[t.sender], index[t.addressee]
                    payload = 1 if t.phase == "relations" else 2  # LISTEN_KINDS
                    turn += (t.index, t.index)
                    kind += (0, payload)
                    sender += (s, s)
                    addressee += (a, a)
                    channel += (s, a)  # the ID on its sender's channel, the payload on a's
                    start += (p.id_start, p.payload_start)
                    ready += (p.id_samples[-1], p.payload_samples[-1] + self.search)
            self._listens = ListenQueue.of_columns(
                self.units, turn, kind, sender, addressee, channel, start, ready
            )
        return self._listens

    def nominal_end(self) -> float:
        """When the schedule's last transmission ends, in seconds, every ID's spike taken at its
        last pulse (the earliest a reaction counts from: a run never ends before this). The
        concurrent schedule's rounds are placed (and kept for the run); the serial one's turns
        are chained as each unit's reactions chain them, repair blocks included."""
        if self.kind == "concurrent":
            last = self.timing()[-1]
            return last.repairs[-1].end if last.repairs else last.end
        start, end, tau = self.start, self.start, self.tau
        for turn in range(len(self.schedule)):
            t = self.schedule[turn]
            ids = code_samples(start, self.omegas[t.sender], self.pulses, tau)
            r = self._react(turn, start, ids[-1])
            end = r.repairs[-1].end if r.repairs else r.payload[-1] * tau
            start = r.next_start
        return end

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
        ready = sample_of(payload_start + longest, tau) + self.search + self.read_margin
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
            payload_start, payload, listens, next_start, sample_of(next_start, tau), repairs
        )

    def _ends_phase(self, turn: int) -> bool:
        """Whether turn ``turn`` is its phase's last (serial: the next is of another phase)."""
        if turn + 1 == len(self.schedule):
            return True
        t, nxt = self.schedule[turn], self.schedule[turn + 1]
        return (nxt.phase, nxt.round) != (t.phase, t.round)


@dataclass(frozen=True)
class Reaction:
    payload_start: float
    payload: tuple[int, ...]
    listens: tuple[Listen, Listen]
    next_start: float
    next_quench: int  # the next turn's start as a sample: resonators to rest before it
    repairs: tuple[RepairBlock, ...] = ()  # after the phase this turn ends (``repair_blocks``)


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
        used = _Occupied(sample_of(start, tau) - 1)
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


# shifts screened at once (``place_rounds``): at 64, a 200-unit plan screened 2.9 blocks a code
_SCREEN = 256


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
    moves its pulses by about j: shifts are screened ``_SCREEN`` at a time on the occupancy array,
    and a screened one is confirmed with the exact instants (a rounding tie can move one
    pulse a sample further). A block only takes samples, so a shift refused to a code stays
    refused to the next with the same start and ω (``hints``): the search goes on from there."""
    first_samples = code_samples(start, omega, pulses, tau)
    offsets = [k - used.origin for k in first_samples]
    first = hints.get((start, omega), 0)
    for lo in range(first, MAX_STAGGER + 1, _SCREEN):
        hi = min(lo + _SCREEN, MAX_STAGGER + 1)
        occupied = used.reach(first_samples[-1] + hi - 1)
        busy = occupied[offsets[0] + lo : offsets[0] + hi].copy()  # shift j: a pulse's
        for k in offsets[1:]:  # sample taken, for j in [lo, hi)
            busy |= occupied[k + lo : k + hi]
        for j in (np.flatnonzero(~busy) + lo).tolist():
            s = start + j * tau
            samples = code_samples(s, omega, pulses, tau)
            if len(set(samples)) == len(samples) and used.free(samples):
                used.take(samples)
                hints[(start, omega)] = j + 1
                return s, samples
    raise BadInput(
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
        used = _Occupied(sample_of(t0, tau) - 1)
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
        out.append(RoundTiming(t0, sample_of(t0, tau), tuple(placed), end, repairs))
        t0 = (repairs[-1].end if repairs else end) + plan.guard
    return tuple(out)


# One Plan for every unit of a run: the constructor, cached on its (hashable) arguments.
plan_of = functools.lru_cache(maxsize=64)(Plan)
