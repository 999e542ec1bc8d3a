"""The protocol's vocabulary: turns and schedules, the samples of a code, and what a protocol
event asks of its unit (``Send``, ``Listen``, ``ListenQueue``, ``Actions``). Pure."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from rgtbus.errors import BadInput
from rgtbus.signal.waveform import pulse_samples
from rgtbus.timebase import sample_of

PHASES = ("relations", "influences")
ANCHORS = ("spike", "schedule")
# How a spike-anchored unit attends to an ID (docs/protocol.md, "Attention"): the ID decode
# with a timing search confirms it and times the reaction, or the paper's threshold crossing
ATTENTIONS = ("confirmed", "threshold")
SCHEDULES = ("serial", "concurrent")
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
        raise BadInput(
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
    return sample_of(payload_start - reaction_delay, tau)


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


LISTEN_KINDS = ("id", "relation", "influence")  # a ListenQueue's kinds, by index


@dataclass(frozen=True, eq=False)
class ListenQueue:
    """Listens as columns, in planning order, each read on one channel; ``order[i]`` is the
    i-th to fall due, at ``boundaries[i]`` (its ready sample + 1); listens due at one
    boundary keep their planning order. One queue is shared by every unit that plans the
    same listens (the concurrent schedule: every unit decodes every code), so a unit holds a
    cursor into it, not an object per (unit, code); and the queue holds about 50 bytes a
    listen, not a ``Listen`` object each (``listen(n)`` makes one when it is asked for)."""

    units: tuple[str, ...]  # the group, as the unit columns index it
    turn: np.ndarray  # int64
    kind: np.ndarray  # int8: an index into LISTEN_KINDS
    sender: np.ndarray  # int32: a unit index
    addressee: np.ndarray  # int32: the expected addressee's unit index
    channel: np.ndarray  # int32: the unit index of the one channel it reads
    start: np.ndarray  # float64, s
    ready: np.ndarray  # int64: its ready sample
    order: np.ndarray  # int64
    boundaries: np.ndarray  # int64

    @classmethod
    def of(cls, listens: Sequence[Listen], units: Sequence[str]) -> ListenQueue:
        """The queue of ``listens`` (each on one channel) over the group ``units``."""
        index = {u: i for i, u in enumerate(units)}
        for li in listens:
            if len(li.channels) != 1:
                raise BadInput(f"a listen queue reads one channel a listen, not {li.channels}")
        return cls.of_columns(
            units,
            [li.turn for li in listens],
            [LISTEN_KINDS.index(li.kind) for li in listens],
            [index[li.sender] for li in listens],
            [index[li.expected_addressee] for li in listens],
            [index[li.channels[0]] for li in listens],
            [li.start for li in listens],
            [li.ready_sample for li in listens],
        )

    @classmethod
    def of_columns(
        cls,
        units: Sequence[str],
        turn: Sequence[int],
        kind: Sequence[int],
        sender: Sequence[int],
        addressee: Sequence[int],
        channel: Sequence[int],
        start: Sequence[float],
        ready: Sequence[int],
    ) -> ListenQueue:
        """The queue of listens given as columns (unit columns index ``units``)."""
        ready_ = np.array(ready, dtype=np.int64)
        order = np.argsort(ready_, kind="stable")
        columns = (
            np.array(turn, dtype=np.int64),
            np.array(kind, dtype=np.int8),
            np.array(sender, dtype=np.int32),
            np.array(addressee, dtype=np.int32),
            np.array(channel, dtype=np.int32),
            np.array(start, dtype=np.float64),
            ready_,
            order.astype(np.int64),
            ready_[order] + 1,
        )
        for col in columns:
            col.flags.writeable = False
        return cls(tuple(units), *columns)

    def __len__(self) -> int:
        return int(self.turn.size)

    def listen(self, n: int) -> Listen:
        """The ``n``-th listen planned, as a ``Listen``."""
        u = self.units
        return Listen(
            int(self.turn[n]),
            LISTEN_KINDS[int(self.kind[n])],
            u[int(self.sender[n])],
            u[int(self.addressee[n])],
            (u[int(self.channel[n])],),
            float(self.start[n]),
            int(self.ready[n]),
        )

    @property
    def listens(self) -> tuple[Listen, ...]:
        """Every listen, in planning order (made anew: for a reader of a small group)."""
        return tuple(self.listen(n) for n in range(len(self)))


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
    # the listens as a shared queue (the concurrent schedule; ``listens`` then holds none)
    queue: ListenQueue | None = None
    repairs: list[RepairBlock] = field(default_factory=list)  # repair blocks now known

    def __bool__(self) -> bool:
        return bool(
            self.sends
            or self.listens
            or self.queue is not None
            or self.quench
            or self.deadline is not None
            or self.repairs
        )


NEVER = 2**63 - 1  # "no such sample": a promise of silence for the rest of the run


NOTHING = Actions()  # what a spike the protocol ignores asks for (shared: never changed)
