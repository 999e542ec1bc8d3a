"""What a scenario file becomes: a validated, typed ``Scenario`` and its parts."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import rgtbus.checks as checks
from rgtbus.pairs import ordered_pairs
from rgtbus.rgt import Universe
from rgtbus.scenario.influences import Influences
from rgtbus.scenario.relations import Relations
from rgtbus.scenario.schedule import ProtocolSection
from rgtbus.signal.channel import Channel
from rgtbus.signal.codebook import Codebook


@dataclass(frozen=True)
class Timing:
    """``[timing]``: the sample rate and the schedule's times, in seconds."""

    sample_rate: float = 200.0  # samples per second (tau = 5 ms)
    window: float = 0.1  # seconds per bus window; at most the reaction delay (the lookahead)
    start: float = 0.001  # first transmission, seconds after onset (the paper's 1 ms)
    reaction_delay: float = 0.5  # from the ID spike to the addressed code
    guard: float = 0.5  # silence between one transmission's end and the next ID
    # a run that has not finished by then fails: by default the schedule's nominal end with a
    # margin, at least an hour (``rgtbus.scenario.timing.fit_to_schedule``)
    max_seconds: float = 3600.0
    stop: float | None = None  # a deliberate cut: the run ends here, finished or not
    anchor: str = "spike"  # reactions count from the ID spike (paper) or the ID's last pulse
    # the spike anchor's attention: "confirmed" by the ID decode with a timing search, or the
    # paper's "threshold" crossing alone (docs/protocol.md, "Attention")
    attention: str = "confirmed"
    # samples of timing search either way of where a code is expected (decodes, attention)
    search: int = 2

    @property
    def tau(self) -> float:
        """The sample period, 1 / sample_rate."""
        return 1.0 / self.sample_rate

    @property
    def window_samples(self) -> int:
        """A bus window in samples, window × sample_rate rounded."""
        return round(self.window * self.sample_rate)


@dataclass(frozen=True)
class Outcome:
    """``name: then`` when every unit of ``all_of`` chooses ``choose``, else ``name: else``."""

    name: str
    all_of: tuple[str, ...]
    choose: int
    then: str
    otherwise: str


@dataclass(frozen=True)
class Goal:
    """Unit ``unit`` wants subject ``target`` to meet ``[lo, hi]`` in ``mode`` (one of
    ``rgtbus.rgt.control.MODES``; a scenario's ``choice`` is resolved to the mode that is the
    target's choice under its decision policy: ``max`` -> ``largest``, ``min`` ->
    ``smallest``, any other -> ``exact``, the one interval that leaves no choice)."""

    unit: str
    target: str
    lo: int
    hi: int
    mode: str


@dataclass(frozen=True)
class Scenario:
    """A scenario as loaded: its group (name, seed, units, universe), frequencies, codebook and
    resonator mode, and one field for each remaining section of the file, typed as the loader
    builds it: ``timing``, ``channel``, ``relations``, ``influences``, ``decisions``,
    ``outcome``, ``goals``, ``protocol``, ``expect``. A variation is a replaced section:
    ``replace(sc, channel=replace(sc.channel, noise=0.02))`` (docs/api.md)."""

    name: str
    path: str
    text: str
    seed: int
    units: tuple[str, ...]
    universe: Universe
    frequencies: dict[str, float]
    frequency_text: dict[str, str]
    codebook: Codebook
    mode: str
    timing: Timing
    # [channel]: noise, every link's gain (path loss included), positions, bursts, the speed
    # of propagation and the clocks (``rgtbus.signal.channel.Channel``)
    channel: Channel
    relations: Relations
    influences: Influences
    decisions: dict[str, str]
    outcome: Outcome | None
    protocol: ProtocolSection = field(default_factory=ProtocolSection)
    goals: tuple[Goal, ...] = ()  # [goals.UNIT]: influences chosen by the inverse task
    decoding: str = "nearest"  # the rule a code's word is read by (rgtbus.signal.rules)
    expect: dict[str, Any] = field(default_factory=dict)
    description: str = ""

    def goals_of(self, unit: str) -> dict[str, Goal]:
        """Unit ``unit``'s goals by target (empty: it keeps its influence policy)."""
        return {g.target: g for g in self.goals if g.unit == unit}

    def pairs(self) -> list[tuple[str, str]]:
        """Every ordered pair of distinct units, sender-major in unit order."""
        return ordered_pairs(self.units)

    def with_seed(self, seed: int, name: str = "seed") -> Scenario:
        """This scenario under another seed (``name``: where the seed came from, for the error
        a bad one raises)."""
        return replace(self, seed=checks.seed(seed, name))
