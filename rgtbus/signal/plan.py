"""Frequency plans (docs/model.md): which ω each unit owns, and the rules a plan must keep.

Rules checked by :func:`check_plan` (each refusal names its rule):

1. *positive*: every ω > 0 and finite, no two equal.
2. *nyquist*: ω well below Nyquist — at least ``MIN_SAMPLES_PER_PERIOD`` samples a period
   (ω ≤ 2π / (16τ)), so pulse instants rounded to samples stay in phase.
3. *euler*: in paper mode every ω inside Euler's stable band, ω < √(−2b/τ − b²) (≈ 6.32 rad/s);
   beyond it only exact mode decays.
4. *octave*: max ω < 2·min ω — a pulse train on ω also excites 2ω (its harmonic).
5. *spacing*: neighbours (sorted) at least 0.3/N apart relatively, (ω₂ − ω₁)/ω₁ ≥ 0.3/N for N
   pulses a code (the paper's ω_a, ω_c are 11 % apart at N = 3: the limit, with crosstalk).
6. *decay*: b < 0 and the resonator's memory 1/|b| at least the longest message,
   (N − 1)·2π/min ω seconds, so a code's first pulse still counts at its last.

Rules 4–6 are about *attention*: a resonator must spike on its own channel's ID and not on a
neighbour's. The serial schedule is timed by those spikes, so it keeps all six. The concurrent
schedule is timed by the schedule and decodes by reading the medium at each code's pulse
instants (no two codes share a sample), so only rules 1–3 bind it; rules 4–6 become *margins*
that :func:`make_plan` reports (spikes are still logged, and may then cross-fire).
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rgtbus.errors import BadInput, RgtbusError
from rgtbus.signal.resonator import PAPER_B, PAPER_TAU, euler_limit

PI = math.pi
# The paper's units a, b, c and the gate's fourth unit d (docs/model.md).
PAPER_OMEGAS = (3 * PI / 2, 4 * PI / 3, 5 * PI / 3, 7 * PI / 6)
PAPER_OMEGA_TEXT = ("3pi/2", "4pi/3", "5pi/3", "7pi/6")
MIN_SAMPLES_PER_PERIOD = 16
SPACING_FACTOR = 0.3

_NUM = r"(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?"
_OMEGA_RE = re.compile(rf"^\s*({_NUM})?\s*\*?\s*(pi|π)?\s*(?:/\s*({_NUM}))?\s*$")


def parse_omega(text: str, where: str = "omega") -> float:
    """Parse ``3pi/2``, ``1.5pi``, ``pi``, ``7π/6``, ``2*pi/3``, ``4.71`` into rad/s (no eval).

    Refuses (``RgtbusError`` naming the token and ``where``) anything else, zero or negative.
    """
    s = str(text)
    m = _OMEGA_RE.match(s)
    if not m or not (m.group(1) or m.group(2)):
        raise BadInput(
            f"{where}: cannot read {s!r} as a frequency; write e.g. 3pi/2, 1.5pi or 4.71 (rad/s)"
        )
    value = float(m.group(1)) if m.group(1) else 1.0
    if m.group(2):
        value *= PI
    if m.group(3):
        den = float(m.group(3))
        if den == 0:
            raise BadInput(f"{where}: {s!r} divides by zero")
        value /= den
    if not math.isfinite(value) or value <= 0:
        raise BadInput(f"{where}: {s!r} is not a positive frequency")
    return value


def message_length(omega_min: float, pulses: int) -> float:
    """Seconds from a code's first to its last pulse on the slowest channel."""
    return (pulses - 1) * 2 * PI / omega_min


def check_plan(
    omegas: Sequence[float],
    *,
    pulses: int = 3,
    mode: str = "paper",
    tau: float = PAPER_TAU,
    b: float = PAPER_B,
    schedule: str = "serial",
) -> None:
    """Refuse (``RgtbusError`` naming the rule) a plan that breaks a rule of the module doc
    (the concurrent schedule: rules 1–3 only)."""
    if mode not in ("paper", "exact"):
        raise BadInput(f"mode {mode!r} is not one of paper, exact")
    if not isinstance(pulses, int) or pulses < 1:
        raise BadInput(f"pulses = {pulses!r} must be a positive integer")
    if not omegas:
        raise BadInput("rule positive: a plan needs at least one frequency")
    ws = [float(w) for w in omegas]
    for j, w in enumerate(ws):
        if not math.isfinite(w) or w <= 0:
            raise BadInput(f"rule positive: omega[{j}] = {w!r} is not a positive frequency")
    s = sorted(ws)
    for lo, hi in itertools.pairwise(s):
        if hi == lo:
            raise BadInput(f"rule positive: frequency {lo:.6g} rad/s is used twice")
    nyq = 2 * PI / (MIN_SAMPLES_PER_PERIOD * tau)
    if s[-1] > nyq:
        raise BadInput(
            f"rule nyquist: omega {s[-1]:.6g} rad/s leaves fewer than {MIN_SAMPLES_PER_PERIOD} "
            f"samples a period at tau = {tau:g} s (limit {nyq:.6g} rad/s)"
        )
    if mode == "paper":
        lim = euler_limit(tau, b)
        if s[-1] >= lim:
            raise BadInput(
                f"rule euler: omega {s[-1]:.6g} rad/s is beyond Euler's stable band "
                f"({lim:.4g} rad/s at b = {b:g}, tau = {tau:g}); use mode exact"
            )
    if b >= 0:
        raise BadInput(f"rule decay: b = {b:g} must be negative (resonators must forget)")
    if schedule == "concurrent":
        return  # attention rules are margins there (the module docstring)
    if s[-1] >= 2 * s[0]:
        raise BadInput(
            f"rule octave: {s[-1]:.6g} rad/s is not below twice {s[0]:.6g} rad/s "
            "(a pulse train on ω also excites 2ω)"
        )
    need = SPACING_FACTOR / pulses
    for lo, hi in itertools.pairwise(s):
        if (hi - lo) / lo < need * (1 - 1e-9):
            raise BadInput(
                f"rule spacing: {lo:.6g} and {hi:.6g} rad/s are {100 * (hi - lo) / lo:.1f} % "
                f"apart, below 0.3/N = {100 * need:.1f} % for N = {pulses} pulses"
            )
    length = message_length(s[0], pulses)
    if 1 / abs(b) < length:
        raise BadInput(
            f"rule decay: memory 1/|b| = {1 / abs(b):.4g} s is shorter than the longest message "
            f"({pulses} pulses on {s[0]:.6g} rad/s: {length:.4g} s)"
        )


def max_units(pulses: int = 3) -> int:
    """Most channels one octave holds at relative spacing 0.3/N."""
    step = 1 + SPACING_FACTOR / pulses
    return 1 + math.floor(math.log(2) / math.log(step) - 1e-9)


MAX_PLAN_PULSES = 10_000  # beyond, a code outlasts any resonator's memory (rule decay)


def pulses_for(n: int) -> int | None:
    """The fewest pulses a code (from 3) whose 0.3/N spacing fits n channels in one octave;
    None when no N up to ``MAX_PLAN_PULSES`` does (max_units grows about as 2.3·N)."""
    if max_units(MAX_PLAN_PULSES) < n:
        return None
    lo, hi = 3, MAX_PLAN_PULSES  # max_units is non-decreasing in N: bisect
    while lo < hi:
        mid = (lo + hi) // 2
        if max_units(mid) >= n:
            hi = mid
        else:
            lo = mid + 1
    return lo


def check_tau(tau: float) -> None:
    """A sample period a plan can use: positive and finite (1/inf samples a second is 0)."""
    if (
        isinstance(tau, bool)
        or not isinstance(tau, int | float)
        or not (math.isfinite(tau) and tau > 0)
    ):
        raise BadInput(f"tau = {tau!r} s: the sample period must be positive and finite")


def crosstalk_size(omegas: Sequence[float], pulses: int, tau: float) -> float:
    """The work of ``crosstalk_peak`` before it starts: n² resonators (a receiver per
    channel, each with every channel) through the longest ID plus one period, in samples."""
    slowest = min(omegas)
    length = (pulses - 1) * 2 * PI / slowest / tau + 2 * PI / slowest / tau + 3
    return float(len(omegas)) ** 2 * length


def auto_plan(
    n: int,
    *,
    pulses: int = 3,
    mode: str = "paper",
    tau: float = PAPER_TAU,
    b: float = PAPER_B,
    omega_min: float | None = None,
    schedule: str = "serial",
) -> list[float]:
    """Frequencies (rad/s) for n units, in unit order.

    n ≤ 4 with the paper's settings (3 pulses, paper mode, τ, b): the paper's ω_a, ω_b, ω_c and
    the gate's ω_d, in that order.  Otherwise a geometric ladder ω_j = ω_min·(1 + 0.3/N)^j — the
    tightest spacing the rules allow, so the most units fit in an octave — placed as high as the
    band allows (paper mode: just under Euler's limit; exact mode: from ``omega_min``, by default
    2π rad/s or the lowest ω whose longest message fits 1/|b|),
    then checked by :func:`check_plan`.  Refused when n units cannot fit (the rule is named, with
    the pulse count that would fit).

    The concurrent schedule is bound by rules 1–3 only: beyond what an octave holds at 0.3/N,
    its ladder is squeezed into one octave (ratio 2^(1/n)), any n, the spacing then a margin.
    """
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise BadInput(f"number of units {n!r} must be a positive integer")
    paper_settings = (
        pulses == 3 and mode == "paper" and tau == PAPER_TAU and b == PAPER_B and omega_min is None
    )
    if paper_settings and n <= len(PAPER_OMEGAS):
        return list(PAPER_OMEGAS[:n])
    squeeze = schedule == "concurrent" and n > max_units(pulses)
    if n > max_units(pulses) and not squeeze:
        more = pulses_for(n)
        use = f"use at least {more} pulses" if more else "use the concurrent schedule"
        raise BadInput(
            f"rule octave/spacing: {n} units do not fit one octave at 0.3/N spacing with "
            f"N = {pulses} pulses (at most {max_units(pulses)}); {use}"
        )
    ratio = 2 ** (1 / n) if squeeze else 1 + SPACING_FACTOR / pulses
    if omega_min is None:
        if mode == "paper":
            top = 0.98 * euler_limit(tau, b)
            omega_min = top / ratio ** (n - 1)
        else:  # 1 Hz, or higher so the longest message fits the resonator's memory 1/|b|
            omega_min = max(2 * PI, 1.05 * (pulses - 1) * 2 * PI * abs(b))
    plan = [omega_min * ratio**j for j in range(n)]
    check_plan(plan, pulses=pulses, mode=mode, tau=tau, b=b, schedule=schedule)
    return plan


@dataclass(frozen=True)
class Margin:
    """One figure of a plan against its rule: ``ok`` when it keeps the rule, ``binding`` when
    the schedule needs it (a margin that is not binding is reported, not refused)."""

    rule: str
    value: float
    limit: float
    ok: bool
    binding: bool
    text: str


@dataclass(frozen=True)
class FrequencyPlan:
    """What ``make_plan`` chose for n units on a schedule, and how close to each rule it is."""

    n: int
    schedule: str
    mode: str
    pulses: int
    tau: float
    b: float
    omegas: tuple[float, ...]
    codebook: str  # "paper" (3 pulses) or "generated"
    margins: tuple[Margin, ...] = field(default_factory=tuple)

    def to_json(self) -> dict[str, Any]:
        """The plan as JSON-ready values, the band and every margin included."""
        return {
            "n": self.n,
            "schedule": self.schedule,
            "mode": self.mode,
            "pulses": self.pulses,
            "tau": self.tau,
            "b": self.b,
            "codebook": self.codebook,
            "omegas": list(self.omegas),
            "band": [min(self.omegas), max(self.omegas)],
            "margins": [m.__dict__ for m in self.margins],
        }


def crosstalk_peak(
    omegas: Sequence[float], pulses: int, mode: str, tau: float, b: float
) -> tuple[float, float]:
    """(the highest y any resonator reaches on another channel's ID-code, the lowest its own
    channel's ID reaches), as fractions of the threshold: every channel's ID {0.4, ...} fed
    alone to a bank of every channel, one receiver per channel, ``CROSSTALK_BATCH`` receivers a
    run (the recorded states of all n² resonators at once grow as n² × samples)."""
    from rgtbus.signal.resonator import ResonatorBank  # numpy-heavy: only when asked
    from rgtbus.signal.waveform import pulse_instants

    n = len(omegas)
    longest = int(pulse_instants(min(omegas), 0.0, pulses, tau)[-1]) + 1
    length = longest + int(2 * PI / min(omegas) / tau) + 2
    cross, own = 0.0, math.inf
    for first in range(0, n, CROSSTALK_BATCH):
        fed = range(first, min(n, first + CROSSTALK_BATCH))
        u = np.zeros((length, len(fed)))
        for r, v in enumerate(fed):
            u[pulse_instants(omegas[v], 0.0, pulses, tau), r] = 0.4
        bank = ResonatorBank(list(omegas), mode=mode, tau=tau, b=b, n_receivers=len(fed))
        res = bank.feed(u, record=True)
        assert res.y is not None  # record=True; a spike records spike_value (above threshold)
        peak = np.abs(res.y).max(axis=0) / bank.threshold  # (receivers = fed channels, channels)
        rows = np.arange(len(fed))
        own = min(own, float(peak[rows, list(fed)].min()))
        peak[rows, list(fed)] = 0.0
        cross = max(cross, float(peak.max()))
    return cross, own


CROSSTALK_BATCH = 16


def make_plan(
    n: int,
    *,
    schedule: str = "serial",
    pulses: int | None = None,
    mode: str | None = None,
    tau: float = PAPER_TAU,
    b: float = PAPER_B,
    crosstalk: bool = True,
) -> FrequencyPlan:
    """The plan for n units on ``schedule``: the pulses a code (given, or the fewest that fit:
    serial needs the octave at 0.3/N spacing, concurrent takes the paper's 3), the mode (given,
    or paper unless Euler's band cannot hold the plan: then exact), the frequencies
    (:func:`auto_plan`) and every margin. RgtbusError naming the rule it cannot keep."""
    if schedule not in ("serial", "concurrent"):
        raise BadInput(f"unknown schedule {schedule!r} (serial or concurrent)")
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise BadInput(f"number of units {n!r} must be a positive integer")
    check_tau(tau)
    if pulses is None:
        pulses = _fewest_pulses(n, schedule)
    chosen, omegas = _first_mode_that_fits(n, schedule, pulses, mode, tau, b)
    s = sorted(omegas)
    attention = schedule == "serial"
    margins = _rule_margins(s, pulses, tau, b, attention)
    if chosen == "paper":
        lim = euler_limit(tau, b)
        margins.append(
            Margin("euler", s[-1], lim, s[-1] < lim, True,
                   f"top {s[-1]:.4g} rad/s, Euler's stable band ends at {lim:.4g} rad/s")
        )  # fmt: skip
    if crosstalk:
        margins.extend(_attention_margins(s, pulses, chosen, tau, b, attention))
    return FrequencyPlan(
        n=n,
        schedule=schedule,
        mode=chosen,
        pulses=pulses,
        tau=tau,
        b=b,
        omegas=tuple(omegas),
        codebook="paper" if pulses == 3 else "generated",
        margins=tuple(margins),
    )


def _fewest_pulses(n: int, schedule: str) -> int:
    """The pulses a code of n units' plan needs: the paper's 3 on the concurrent schedule;
    on the serial, the fewest whose 0.3/N spacing fits them in one octave."""
    fit = 3 if schedule == "concurrent" else pulses_for(n)
    if fit is None:
        raise BadInput(
            f"no plan for {n} units (serial): no code of up to {MAX_PLAN_PULSES} pulses "
            "fits them in one octave; use the concurrent schedule"
        )
    return fit


def _first_mode_that_fits(
    n: int, schedule: str, pulses: int, mode: str | None, tau: float, b: float
) -> tuple[str, list[float]]:
    """The mode (``mode``, or paper, else exact) whose :func:`auto_plan` holds n units, and
    its frequencies; refused with every mode's reason."""
    errors = []
    for m in [mode] if mode is not None else ["paper", "exact"]:
        try:
            return m, auto_plan(n, pulses=pulses, mode=m, tau=tau, b=b, schedule=schedule)
        except RgtbusError as e:
            errors.append(str(e))
    raise BadInput(f"no plan for {n} units ({schedule}): " + "; ".join(errors))


def _rule_margins(
    s: list[float], pulses: int, tau: float, b: float, attention: bool
) -> list[Margin]:
    """The margins of the sorted frequencies ``s`` to the rules spacing, octave, decay
    (binding when the schedule is timed by ``attention``) and nyquist."""
    need = SPACING_FACTOR / pulses
    spacing = min(((hi - lo) / lo for lo, hi in itertools.pairwise(s)), default=math.inf)
    length = message_length(s[0], pulses)
    return [
        Margin(
            "spacing", spacing, need, spacing >= need * (1 - 1e-9), attention,
            f"neighbours {100 * spacing:.2f} % apart (rule: at least 0.3/N = {100 * need:.2f} %)",
        ),
        Margin(
            "octave", s[-1] / s[0], 2.0, s[-1] < 2 * s[0], attention,
            f"band {s[0]:.4g}–{s[-1]:.4g} rad/s, ratio {s[-1] / s[0]:.3f} (rule: below 2)",
        ),
        Margin(
            "decay", 1 / abs(b), length, 1 / abs(b) >= length, attention,
            f"resonator memory {1 / abs(b):.3g} s, longest message {length:.3g} s",
        ),
        Margin(
            "nyquist", s[-1], 2 * PI / (MIN_SAMPLES_PER_PERIOD * tau), True, True,
            f"{2 * PI / (s[-1] * tau):.1f} samples a period at the top "
            f"(rule: at least {MIN_SAMPLES_PER_PERIOD})",
        ),
    ]  # fmt: skip


def _attention_margins(
    s: list[float], pulses: int, mode: str, tau: float, b: float, attention: bool
) -> list[Margin]:
    """How far every resonator's own ID and other channels' IDs drive it, against the
    threshold (``crosstalk_peak``)."""
    cross, own = crosstalk_peak(s, pulses, mode, tau, b)
    return [
        Margin("attention", own, 1.0, own >= 1.0, attention,
               f"its own ID drives every resonator to at least {own:.2f} of its threshold "
               "(at 1 it spikes; the serial schedule is timed by that spike)"),
        Margin("crosstalk", cross, 1.0, cross < 1.0, False,
               f"another channel's ID drives a resonator to at most {cross:.2f} of its "
               "threshold (at 1 it spikes: logged, never acted on)"),
    ]  # fmt: skip
