"""What a scenario file becomes: a validated, typed ``Scenario`` and its parts."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import rgtbus.checks as checks
from rgtbus.pairs import ordered_pairs
from rgtbus.rgt import Universe
from rgtbus.signal.channel import Burst, Channel, Clock
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
    """A scenario as loaded: its group, channel, codebook, frequencies, timing, relations,
    influences, decisions, goals, outcome and expectations."""

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
    noise: float
    gains: dict[tuple[str, str], float]  # every link's, path loss included (Channel.gains)
    relation_policy: str
    alliance_p: float
    fixed_relations: dict[tuple[str, str], bool]
    draws: dict[tuple[str, str], float]
    influences: dict[tuple[str, str], int]
    decisions: dict[str, str]
    outcome: Outcome | None
    expect: dict[str, Any] = field(default_factory=dict)
    description: str = ""
    # How influences not listed per pair are chosen (rgtbus.mind.choose_influences).
    schedule: str = (
        "serial"  # [protocol] schedule: one code at a time, or rounds (docs/protocol.md)
    )
    influence_policy: str = "fixed"
    influence_value: int | None = None  # policy uniform
    influence_weights: dict[int, float] = field(default_factory=dict)  # policy random
    influence_rounds: int = 1  # [protocol] influence_rounds: influence phases (the paper: 1)
    goals: tuple[Goal, ...] = ()  # [goals.UNIT]: influences chosen by the inverse task
    # [channel] positions (metres, x y z), path_loss and reference_distance (Channel)
    positions: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    path_loss: float = 0.0
    reference_distance: float = 1.0
    burst: Burst | None = None  # [channel.burst]: noise in bursts (Gilbert–Elliott)
    speed: float | None = None  # [channel] speed: m/s pulses travel (None: instantly)
    clocks: dict[str, Clock] = field(default_factory=dict)  # [channel.clock] by unit
    # [protocol] repair: "none" (the paper) or "arq" (docs/protocol.md, "Repair"); its blocks
    # after each phase and the margin (a fraction of a family's smallest word distance) below
    # which a decode is unsure
    repair: str = "none"
    repair_rounds: int = 3
    repair_margin: float = 0.65

    @property
    def repairs_per_phase(self) -> int:
        """Repair blocks after each phase (0: no repair)."""
        return self.repair_rounds if self.repair == "arq" else 0

    def goals_of(self, unit: str) -> dict[str, Goal]:
        """Unit ``unit``'s goals by target (empty: it keeps its influence policy)."""
        return {g.target: g for g in self.goals if g.unit == unit}

    @property
    def channel(self) -> Channel:
        """What each receiver hears from each sender (``rgtbus.signal.channel``)."""
        return Channel(
            self.noise,
            self.gains,
            self.positions,
            self.path_loss,
            self.reference_distance,
            self.burst,
            self.speed,
            self.clocks,
        )

    def pairs(self) -> list[tuple[str, str]]:
        """Every ordered pair of distinct units, sender-major in unit order."""
        return ordered_pairs(self.units)

    def with_seed(self, seed: int, name: str = "seed") -> Scenario:
        """This scenario under another seed (``name``: where the seed came from, for the error
        a bad one raises)."""
        return replace(self, seed=checks.seed(seed, name))
