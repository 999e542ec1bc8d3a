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
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Sequence

from rgtbus.errors import RgtbusError
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
        raise RgtbusError(
            f"{where}: cannot read {s!r} as a frequency; write e.g. 3pi/2, 1.5pi or 4.71 (rad/s)"
        )
    value = float(m.group(1)) if m.group(1) else 1.0
    if m.group(2):
        value *= PI
    if m.group(3):
        den = float(m.group(3))
        if den == 0:
            raise RgtbusError(f"{where}: {s!r} divides by zero")
        value /= den
    if not math.isfinite(value) or value <= 0:
        raise RgtbusError(f"{where}: {s!r} is not a positive frequency")
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
) -> None:
    """Refuse (``RgtbusError`` naming the rule) a plan that breaks a rule of the module doc."""
    if mode not in ("paper", "exact"):
        raise RgtbusError(f"mode {mode!r} is not one of paper, exact")
    if not isinstance(pulses, int) or pulses < 1:
        raise RgtbusError(f"pulses = {pulses!r} must be a positive integer")
    if not omegas:
        raise RgtbusError("rule positive: a plan needs at least one frequency")
    ws = [float(w) for w in omegas]
    for j, w in enumerate(ws):
        if not math.isfinite(w) or w <= 0:
            raise RgtbusError(f"rule positive: omega[{j}] = {w!r} is not a positive frequency")
    s = sorted(ws)
    for lo, hi in itertools.pairwise(s):
        if hi == lo:
            raise RgtbusError(f"rule positive: frequency {lo:.6g} rad/s is used twice")
    nyq = 2 * PI / (MIN_SAMPLES_PER_PERIOD * tau)
    if s[-1] > nyq:
        raise RgtbusError(
            f"rule nyquist: omega {s[-1]:.6g} rad/s leaves fewer than {MIN_SAMPLES_PER_PERIOD} "
            f"samples a period at tau = {tau:g} s (limit {nyq:.6g} rad/s)"
        )
    if mode == "paper":
        lim = euler_limit(tau, b)
        if s[-1] >= lim:
            raise RgtbusError(
                f"rule euler: omega {s[-1]:.6g} rad/s is beyond Euler's stable band "
                f"({lim:.4g} rad/s at b = {b:g}, tau = {tau:g}); use mode exact"
            )
    if s[-1] >= 2 * s[0]:
        raise RgtbusError(
            f"rule octave: {s[-1]:.6g} rad/s is not below twice {s[0]:.6g} rad/s "
            "(a pulse train on ω also excites 2ω)"
        )
    need = SPACING_FACTOR / pulses
    for lo, hi in itertools.pairwise(s):
        if (hi - lo) / lo < need * (1 - 1e-9):
            raise RgtbusError(
                f"rule spacing: {lo:.6g} and {hi:.6g} rad/s are {100 * (hi - lo) / lo:.1f} % "
                f"apart, below 0.3/N = {100 * need:.1f} % for N = {pulses} pulses"
            )
    if b >= 0:
        raise RgtbusError(f"rule decay: b = {b:g} must be negative (resonators must forget)")
    length = message_length(s[0], pulses)
    if 1 / abs(b) < length:
        raise RgtbusError(
            f"rule decay: memory 1/|b| = {1 / abs(b):.4g} s is shorter than the longest message "
            f"({pulses} pulses on {s[0]:.6g} rad/s: {length:.4g} s)"
        )


def max_units(pulses: int = 3) -> int:
    """Most channels one octave holds at relative spacing 0.3/N."""
    step = 1 + SPACING_FACTOR / pulses
    return 1 + math.floor(math.log(2) / math.log(step) - 1e-9)


def auto_plan(
    n: int,
    *,
    pulses: int = 3,
    mode: str = "paper",
    tau: float = PAPER_TAU,
    b: float = PAPER_B,
    omega_min: float | None = None,
) -> list[float]:
    """Frequencies (rad/s) for n units, in unit order.

    n ≤ 4 with the paper's settings (3 pulses, paper mode, τ, b): the paper's ω_a, ω_b, ω_c and
    the gate's ω_d, in that order.  Otherwise a geometric ladder ω_j = ω_min·(1 + 0.3/N)^j — the
    tightest spacing the rules allow, so the most units fit in an octave — placed as high as the
    band allows (paper mode: just under Euler's limit; exact mode: from ``omega_min``, by default
    2π rad/s or the lowest ω whose longest message fits 1/|b|),
    then checked by :func:`check_plan`.  Refused when n units cannot fit (the rule is named, with
    the pulse count that would fit).
    """
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise RgtbusError(f"number of units {n!r} must be a positive integer")
    paper_settings = (
        pulses == 3 and mode == "paper" and tau == PAPER_TAU and b == PAPER_B and omega_min is None
    )
    if paper_settings and n <= len(PAPER_OMEGAS):
        return list(PAPER_OMEGAS[:n])
    if n > max_units(pulses):
        more = next(p for p in range(pulses, 10_000) if max_units(p) >= n)
        raise RgtbusError(
            f"rule octave/spacing: {n} units do not fit one octave at 0.3/N spacing with "
            f"N = {pulses} pulses (at most {max_units(pulses)}); use at least {more} pulses"
        )
    ratio = 1 + SPACING_FACTOR / pulses
    if omega_min is None:
        if mode == "paper":
            top = 0.98 * euler_limit(tau, b)
            omega_min = top / ratio ** (n - 1)
        else:  # 1 Hz, or higher so the longest message fits the resonator's memory 1/|b|
            omega_min = max(2 * PI, 1.05 * (pulses - 1) * 2 * PI * abs(b))
    plan = [omega_min * ratio**j for j in range(n)]
    check_plan(plan, pulses=pulses, mode=mode, tau=tau, b=b)
    return plan
