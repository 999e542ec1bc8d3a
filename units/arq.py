"""A unit's side of repair (``[protocol] repair = "arq"``; docs/protocol.md, "Repair").

After each phase come repair blocks, each in three steps, each a timer of the unit: choose
the requests (the ID-code on a payload's sender's channel, in the payload's request slot, for
every payload it is unsure of), choose the repeats (each payload of its own it hears asked
for: the request slot reads nearer the ID-code than silence), and read the copies it asked
for (each combined read a decode of its turn; sure now, it learns the payload; after the
phase's last block what is still unsure is learned as it reads best). The book of what is
unsure, asked for and learned is ``rgtbus.repair.RepairBook`` (pure).
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Mapping

from rgtbus.units.timers import REPAIR_STEPS

from rgtbus.protocol import Listen, RepairBlock, Send, code_samples
from rgtbus.repair import RepairBook, family_of
from rgtbus.scenario import Scenario
from rgtbus.signal.decoder import Decision, WordSet
from rgtbus.telemetry.unit_log import UnitLog
from rgtbus.timebase import time_of

Schedule = Callable[[int, int, str], int]  # (boundary, at, kind) -> the timer's seq
Read = Callable[[tuple[int, ...], int, WordSet], Decision]  # samples, channel, words
# listen, addressee, code, margin, t, accepted, channel
Record = Callable[[Listen, str, str, float, float, bool, str], None]
Learn = Callable[[Listen, str, float], None]  # listen, code, t


class Arq:
    """Unit ``name``'s repair side (see the module docstring). Given: its ``book``; the code
    of each payload the unit sent, by turn (``payload_codes``, its transmitter's); and the
    unit's ``schedule`` (sets a timer), ``emit`` (plans a send), ``record`` (a decode, for
    the summary and the log), ``learn`` (what a payload said) and its ``log``. ``read`` (a
    code off the unit's readout) comes with the ears, at ``begin``."""

    def __init__(
        self,
        name: str,
        scenario: Scenario,
        book: RepairBook,
        *,
        payload_codes: Mapping[int, str],
        schedule: Schedule,
        emit: Callable[[Send], None],
        record: Record,
        learn: Learn,
        log: UnitLog,
    ) -> None:
        self.name = name
        self.units = scenario.units
        self.index_of = {u: i for i, u in enumerate(self.units)}
        self.omegas = [scenario.frequencies[u] for u in self.units]
        self.pulses = scenario.codebook.pulses
        self.tau = scenario.timing.tau
        self.blocks = scenario.protocol.repairs_per_phase
        self.budget = self.blocks  # blocks after each phase it still asks in (a steered run's)
        self.book = book
        self.payload_codes = payload_codes
        self.schedule, self.emit, self.record, self.learn, self.log = (
            schedule, emit, record, learn, log,
        )  # fmt: skip
        self.read: Read | None = None
        self._block_of: dict[int, RepairBlock] = {}  # a repair timer's seq -> its block
        self._first: list[tuple[int, int]] = []  # (first sample it may send, seq)
        self.left = 0  # repair timers not yet run: the unit is not finished before

    def begin(self, read: Read) -> None:
        """How it reads a code off its readout, once it hears."""
        self.read = read

    @property
    def first_send(self) -> int | None:
        """The first sample at which a step not yet run may send (None: none may)."""
        return self._first[0][0] if self._first else None

    def plan(self, block: RepairBlock) -> None:
        """A repair block's three steps as timers, each after the decodes due at its sample;
        until a step that may send has run, nothing of this unit goes out after its first
        pulse unplanned (the unit's promise)."""
        for step, boundary in zip(
            REPAIR_STEPS, (block.request_choice, block.repeat_choice, block.ready + 1), strict=True
        ):
            seq = self.schedule(boundary, boundary - 1, step)
            self._block_of[seq] = block
            self.left += 1
            if step != "copies":
                first = block.first_request if step == "request" else block.first_repeat
                heapq.heappush(self._first, (first, seq))
        self.book.add_seconds(block)

    def step(self, kind: str, seq: int, at: int, failed: bool) -> None:
        """One step of a repair block (``REPAIR_STEPS``), timer ``seq`` at sample ``at``; a
        unit that ``failed`` does nothing more."""
        block = self._block_of.pop(seq)
        self.left -= 1
        self._first = [e for e in self._first if e[1] != seq]
        heapq.heapify(self._first)
        if failed:
            return
        if kind == "request":
            self._request(block)
        elif kind == "repeat":
            self._repeat(block)
        else:
            self._read_copies(block, at)

    def give_up(self) -> None:
        """The unit failed: it asks for nothing and repeats nothing."""
        self._first = []

    def hold(self, listen: Listen, code: str, accepted: bool, margin: float) -> bool:
        """Hold a payload this unit is not sure of (``RepairBook.sure``: found off its
        addressee's channel, a small margin, or read otherwise at the instants the schedule
        gives it, where the timing search found a better fit a sample or two off: other
        codes' pulses, on a noisy medium): it asks for it again in the next repair block.
        Returns whether it was held."""
        assert self.read is not None
        family = family_of(listen)
        ch = self.index_of[listen.expected_addressee]
        samples = code_samples(listen.start, self.omegas[ch], self.pulses, self.tau)
        exact = self.read(samples, ch, self.book.families[family])
        if self.book.sure(family, code, accepted, margin, exact):
            return False
        self.book.hold(listen, ch, exact)
        return True

    def _request(self, block: RepairBlock) -> None:
        """Ask for every payload of the block's phase it is still unsure of: the ID-code on
        the payload's sender's channel, in the payload's request slot (none beyond its
        budget)."""
        if block.number > self.budget:
            return
        for slot in self.book.requests(block):
            self.emit(
                Send(slot.turn, "request", slot.sender, "id", slot.request_start,
                     slot.request, self.name, slot.sender, block.number)
            )  # fmt: skip

    def _repeat(self, block: RepairBlock) -> None:
        """Repeat each payload of its own it hears asked for (the request slot reads nearer
        the ID-code than silence on its channel; any number of requesters add up there)."""
        assert self.read is not None
        book, me = self.book, self.index_of[self.name]
        for slot in block.slots:
            code = self.payload_codes.get(slot.turn)
            if slot.sender != self.name or code is None:
                continue
            if not book.asked_for(self.read(slot.request, me, book.request_words)):
                continue
            book.counts["repeats"] += 1
            self.emit(
                Send(slot.turn, "repeat", slot.addressee, code, slot.repeat_start, slot.repeat,
                     self.name, slot.addressee, block.number)
            )  # fmt: skip

    def _read_copies(self, block: RepairBlock, at: int) -> None:
        """Read the copies it asked for (``RepairBook.copy``): each combined read is a decode
        of its turn; sure now, it learns the payload. After the phase's last block, what is
        still unsure is learned as it reads best."""
        assert self.read is not None
        book, t = self.book, time_of(at, self.tau)
        for slot, held in book.awaited(block):
            read = self.read(slot.repeat, held.channel, book.copy_words[held.family])
            best = book.copy(slot, held, read)
            if best is None:  # its request was not heard (or not answered)
                continue
            addressee = self.units[held.channel]
            self.record(held.listen, addressee, best.name, best.margin, t, True, addressee)
            if slot.turn not in book.held:
                self.learn(held.listen, best.name, t)
        for held in book.last(block):
            self.log.log(
                "warning",
                f"{self.name}: turn {held.listen.turn}: still unsure after {self.blocks} repair "
                f"blocks, taken as {held.best!r}",
                t,
            )
            self.learn(held.listen, held.best, t)
