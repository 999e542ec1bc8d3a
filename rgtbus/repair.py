"""What one unit's repair knows (``[protocol] repair = "arq"``; docs/protocol.md, "Repair"):
pure, no SimPy, bus or log. The unit reads the medium and sends; this book says which payloads
it is unsure of, which to ask for, what a copy makes of them, and what it learns.

- **Unsure**: a payload read off its addressee's channel, with a margin below
  ``margin × d_min`` (d_min: the smallest distance between two words of its family), or read
  as another word at exactly the schedule's instants than the timing search found.
- **Copies**: every read of an unsure payload (the first at its instants, then each copy) is
  added up; the mean is decoded, ``nearest(Σ reads / k, family)``: white noise of σ per read
  falls to σ/√k (chase combining). Sure once its margin reaches the bound.
- **Silence**: a copy slot that reads nearer the all-zero word than any word of the family
  carried nothing (the request was not heard): it is not added.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from rgtbus.protocol import Listen, RepairBlock, RepairSlot
from rgtbus.signal.codebook import Codebook
from rgtbus.signal.decoder import Decision, WordSet, nearest
from rgtbus.signal.rules import NEAREST, Rule

SILENCE = "(silence)"  # the word of nothing sent (a copy or a request that did not come)
FAMILIES = ("relation", "alternative")


def family_of(listen: Listen) -> str:
    """The family of words a payload listen reads."""
    return "relation" if listen.kind == "relation" else "alternative"


@dataclass
class Held:
    """A payload a unit is not sure of: the sum of what it read at the payload's instants and
    at each copy's, how many reads, and its best reading so far."""

    listen: Listen
    channel: int  # the expected addressee's channel (index)
    family: str
    total: np.ndarray
    reads: int
    best: str


class RepairBook:
    """One unit's repair: the payloads it holds, what it asked for in the current block, and
    its counts (``/unit/report`` ``repair``)."""

    def __init__(self, cb: Codebook, margin: float, blocks: int, rule: Rule = NEAREST) -> None:
        """``rule``: what its codes are read by (``rgtbus.signal.rules``)."""
        zeros = (0.0,) * cb.pulses
        self.blocks = blocks  # repair blocks after each phase
        self.families = {f: WordSet.of(cb.family(f), rule=rule) for f in FAMILIES}
        self.below = {f: margin * cb.family_min_distance(f) for f in FAMILIES}
        self.request_words = WordSet.of({"request": cb.id_word, SILENCE: zeros}, rule=rule)
        self.copy_words = {
            f: WordSet.of({**cb.family(f), SILENCE: zeros}, rule=rule) for f in FAMILIES
        }
        self.held: dict[int, Held] = {}  # turn -> what it read of a payload it is unsure of
        self.asked: set[int] = set()  # turns asked for in the current block
        self.counts: dict[str, Any] = {
            "requests": 0, "repeats": 0, "copies": 0, "missing": 0, "resolved": 0,
            "unresolved": 0, "seconds": 0.0,
        }  # fmt: skip

    def sure(self, family: str, code: str, accepted: bool, margin: float, exact: Decision) -> bool:
        """Whether a payload decoded as ``code`` (found on its addressee's channel:
        ``accepted``; with ``margin``) and read ``exact`` at the schedule's instants is sure."""
        below = self.below[family]
        return accepted and margin >= below and exact.name == code and exact.margin >= below

    def hold(self, listen: Listen, channel: int, exact: Decision) -> None:
        """Hold a payload it is unsure of, with its read at the schedule's instants."""
        family = family_of(listen)
        self.held[listen.turn] = Held(
            listen, channel, family, np.array(exact.values), 1, exact.name
        )

    def requests(self, block: RepairBlock) -> list[RepairSlot]:
        """The slots of ``block`` it asks in: every payload of the block's phase it holds."""
        slots = [s for s in block.slots if s.turn in self.held]
        self.asked = {s.turn for s in slots}
        self.counts["requests"] += len(slots)
        return slots

    def asked_for(self, asked: Decision) -> bool:
        """Whether a request slot's read (``request_words``) says somebody asked."""
        return asked.name != SILENCE

    def awaited(self, block: RepairBlock) -> list[tuple[RepairSlot, Held]]:
        """The slots of ``block`` whose copy it asked for, with what it holds of each."""
        return [(s, self.held[s.turn]) for s in block.slots if s.turn in self.asked]

    def copy(self, slot: RepairSlot, held: Held, read: Decision) -> Decision | None:
        """A copy read in its slot (``copy_words``): silence adds nothing (None); a copy adds
        to the reads, and the mean is decoded. Sure now, the payload leaves the book (the
        unit learns it)."""
        if read.name == SILENCE:
            self.counts["missing"] += 1
            return None
        self.counts["copies"] += 1
        held.total = held.total + np.array(read.values)
        held.reads += 1
        best = nearest(held.total / held.reads, self.families[held.family])
        held.best = best.name
        if best.margin >= self.below[held.family]:
            del self.held[slot.turn]
            self.counts["resolved"] += 1
        return best

    def last(self, block: RepairBlock) -> list[Held]:
        """After the phase's last block: what is still held of its payloads leaves the book,
        to be learned as it reads best."""
        if block.number < self.blocks:
            return []
        out = [self.held.pop(s.turn) for s in block.slots if s.turn in self.held]
        self.counts["unresolved"] += len(out)
        return out

    def add_seconds(self, block: RepairBlock) -> None:
        """The time a phase's blocks add to the run, counted at its last block."""
        if block.number == self.blocks:
            self.counts["seconds"] = round(self.counts["seconds"] + block.end - block.phase_end, 9)

    def report(self) -> Mapping[str, Any]:
        return dict(self.counts)
