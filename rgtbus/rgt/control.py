"""The inverse task (reflexive control).

Given a controlled subject x and a target, find every joint tuple of the other subjects'
influences on x such that

* mode ``exact``:    the interval is exactly the target: ``A = hi`` and ``B = lo``;
* mode ``contains``: the target lies within the interval: ``B ⊆ lo`` and ``hi ⊆ A``;
* mode ``largest``:  the interval's largest alternative is the target: ``A = hi``, ``B ⊆ A``
  (what a subject deciding by ``max`` chooses; ``lo = hi``);
* mode ``smallest``: its smallest is the target: ``B = lo``, ``B ⊆ A`` (a ``min`` subject's
  choice; ``lo = hi``);

where the target is one alternative (``lo = hi``) or an interval ``[lo, hi]``. Some influences
may be fixed in advance. ``meets`` is the condition on (A, B), the one rule every solver uses.

**Per-action solving.** Every operation is bitwise, so the condition splits over the k actions:
action j only sees bit j of every influence. Per action the question is which assignments of the
others' bits (2^(n-1)) satisfy the condition at bit j; the full solution set is the Cartesian
product of the k per-action sets. With F's truth table T as a 2^n-bit integer, all assignments
are tested at once by shifts and masks (``A_j = T|x=1``, ``B_j = T|x=0`` aligned on x=0 indexes),
so a count costs a handful of big-integer operations instead of (2^k)^(n-1) evaluations.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from fractions import Fraction
from math import prod

from rgtbus.errors import BadInput
from rgtbus.rgt.algebra import Universe
from rgtbus.rgt.diagonal import DecisionFunction
from rgtbus.rgt.expr import variable_table

MODES = ("exact", "contains", "largest", "smallest")
SINGLE_MODES = ("largest", "smallest")  # a target of one alternative only


def meets(a: int, b: int, lo: int, hi: int, mode: str) -> bool:
    """Whether a subject with ``A = a``, ``B = b`` meets the target ``[lo, hi]`` in ``mode``
    (see the module docstring; bitwise, so it holds per action too)."""
    if mode == "exact":
        return a == hi and b == lo
    if mode == "contains":
        return not b & ~lo and not hi & ~a
    if mode == "largest":
        return a == hi and not b & ~a
    if mode == "smallest":
        return b == lo and not b & ~a
    raise BadInput(f"unknown mode {mode!r} (modes: {', '.join(MODES)})")


@dataclass(frozen=True)
class ControlProblem:
    """One inverse task: steer ``subject`` into [``lo``, ``hi``] by ``mode``, the influences in
    ``fixed`` given in advance."""

    subject: str
    lo: int
    hi: int
    mode: str
    fixed: tuple[tuple[str, int], ...]


def _check(
    df: DecisionFunction,
    universe: Universe,
    subject: str,
    lo: int,
    hi: int,
    mode: str,
    fixed: Mapping[str, int],
) -> ControlProblem:
    df.index(subject)
    if mode not in MODES:
        raise BadInput(f"unknown mode {mode!r} (modes: {', '.join(MODES)})")
    universe.check(lo)
    universe.check(hi)
    if mode in SINGLE_MODES and lo != hi:
        raise BadInput(
            f"mode {mode} wants one alternative, got the interval "
            f"[{universe.format(lo)}, {universe.format(hi)}]"
        )
    if lo & ~hi:
        raise BadInput(
            f"target interval [{universe.format(lo)}, {universe.format(hi)}] is empty: "
            "its lower end is not within its upper end"
        )
    for s, v in fixed.items():
        if s == subject:
            raise BadInput(f"influence {s}>{subject}: a subject does not influence itself")
        df.index(s)
        universe.check(v)
    return ControlProblem(subject, lo, hi, mode, tuple(sorted(fixed.items())))


class ControlResult:
    """Solutions as a product of per-action sets; counted without listing."""

    def __init__(
        self,
        problem: ControlProblem,
        df: DecisionFunction,
        others: tuple[str, ...],
        free: tuple[str, ...],
        tables: tuple[int, ...],
    ) -> None:
        self.problem = problem
        self.others = others  # every subject except the controlled one, in F's order
        self.free = free  # the others whose influence is not fixed
        self._df = df
        self._tables = tables  # per action j: truth-table bits of the valid assignments
        self._per_action: tuple[tuple[int, ...], ...] | None = None

    @property
    def count(self) -> int:
        """How many joint influence tuples solve the task (the product of the per-action counts)."""
        return prod(t.bit_count() for t in self._tables)

    @property
    def per_action(self) -> tuple[tuple[int, ...], ...]:
        """Per action j: the valid assignments of the free subjects' bits (bit i = free[i])."""
        if self._per_action is None:
            positions = [self._df.index(s) for s in self.free]
            done: dict[int, tuple[int, ...]] = {}
            out = []
            for t in self._tables:
                if t not in done:
                    done[t] = _compress(_bits(t), positions)
                out.append(done[t])
            self._per_action = tuple(out)
        return self._per_action

    def solutions(self, limit: int | None = None) -> Iterator[dict[str, int]]:
        """Joint influence tuples ``{src: mask}`` (fixed ones included), at most ``limit``."""
        fixed = dict(self.problem.fixed)
        combos: Iterator[tuple[int, ...]] = itertools.product(*self.per_action)
        if limit is not None:
            combos = itertools.islice(combos, limit)
        slot = {s: i for i, s in enumerate(self.free)}
        for choice in combos:
            out = {}
            for s in self.others:
                if s in fixed:
                    out[s] = fixed[s]
                else:
                    i = slot[s]
                    out[s] = sum(((a >> i) & 1) << j for j, a in enumerate(choice))
            yield out


def solve_per_action(
    df: DecisionFunction,
    universe: Universe,
    subject: str,
    lo: int,
    hi: int,
    mode: str = "exact",
    fixed: Mapping[str, int] | None = None,
) -> ControlResult:
    """Inverse task, split per action (see the module docstring)."""
    fixed = dict(fixed or {})
    problem = _check(df, universe, subject, lo, hi, mode, fixed)
    n = df.n
    x = df.index(subject)
    others = tuple(s for s in df.order if s != subject)
    free = tuple(s for s in others if s not in fixed)
    full = (1 << (1 << n)) - 1
    x_table = variable_table(x, n)
    x0 = full ^ x_table  # indexes with x = 0
    a_aligned = (df.table & x_table) >> (1 << x)  # bit at idx (x=0) = F(x=1, rest of idx)
    b_aligned = df.table & x0
    not_a = x0 & ~a_aligned
    not_b = x0 & ~b_aligned

    cache: dict[tuple[int, int, tuple[int, ...]], int] = {}
    tables = []
    for j in range(universe.k):
        lo_j, hi_j = lo >> j & 1, hi >> j & 1
        fixed_bits = tuple(fixed[s] >> j & 1 for s in others if s in fixed)
        key = (lo_j, hi_j, fixed_bits)
        if key not in cache:
            # ``meets`` per action, as truth tables over the x = 0 indexes
            if mode == "exact":
                ok = (a_aligned if hi_j else not_a) & (b_aligned if lo_j else not_b)
            elif mode == "contains":  # B_j <= lo_j and hi_j <= A_j
                ok = x0
                if not lo_j:
                    ok &= not_b
                if hi_j:
                    ok &= a_aligned
            elif mode == "largest":  # A_j = hi_j and B_j <= A_j
                ok = a_aligned if hi_j else not_a & not_b
            else:  # smallest: B_j = lo_j and B_j <= A_j
                ok = b_aligned & a_aligned if lo_j else not_b
            for s in others:
                if s in fixed:
                    v = variable_table(df.index(s), n)
                    ok &= v if fixed[s] >> j & 1 else full ^ v
            cache[key] = ok
        tables.append(cache[key])
    return ControlResult(problem, df, others, free, tuple(tables))


def _bits(value: int) -> list[int]:
    """Positions of the set bits of ``value``, ascending."""
    digits = bin(value)[:1:-1]
    return [i for i, ch in enumerate(digits) if ch == "1"]


def _compress(indexes: list[int], positions: list[int]) -> tuple[int, ...]:
    """Map full assignment indexes to assignments of the free subjects (bit i = free[i])."""
    out = []
    for idx in indexes:
        a = 0
        for i, p in enumerate(positions):
            a |= ((idx >> p) & 1) << i
        out.append(a)
    return tuple(sorted(out))


def brute_force_count(df: DecisionFunction, universe: Universe) -> int:
    """How many evaluations brute force needs per controlled subject: (2^k)^(n-1)."""
    count: int = (1 << universe.k) ** (df.n - 1)
    return count


def solve_brute_force(
    df: DecisionFunction,
    universe: Universe,
    subject: str,
    lo: int,
    hi: int,
    mode: str = "exact",
    fixed: Mapping[str, int] | None = None,
    max_evaluations: int = 5_000_000,
) -> list[dict[str, int]]:
    """Inverse task by evaluating F on every joint tuple of whole alternatives (cross-check)."""
    fixed = dict(fixed or {})
    _check(df, universe, subject, lo, hi, mode, fixed)
    others = [s for s in df.order if s != subject]
    free = [s for s in others if s not in fixed]
    total = len(universe) ** len(free)
    if total > max_evaluations:
        raise BadInput(
            f"brute force needs {total} evaluations (limit {max_evaluations}); use per-action"
        )
    f = df.mask_function(universe.full)
    x = df.index(subject)
    positions = [df.index(s) for s in free]
    args = [0] * df.n
    for s, v in fixed.items():
        args[df.index(s)] = v
    out = []
    for combo in itertools.product(range(len(universe)), repeat=len(free)):
        for p, v in zip(positions, combo, strict=True):
            args[p] = v
        args[x] = universe.full
        a = f(*args)
        args[x] = 0
        b = f(*args)
        if meets(a, b, lo, hi, mode):
            out.append({s: args[df.index(s)] for s in others})
    return out


# -- steering: one subject's own influence on a target, given what it has heard ------------------

STEER_RULES = ("robust", "predicted", "most completions", "unreachable")


@dataclass(frozen=True)
class SteeringChoice:
    """How subject ``me`` steers ``target`` by its own influence (``steer``).

    ``value``: the influence to send (None: no influence of its own can reach the goal);
    ``robust``: it reaches the goal whatever the influences not heard yet; ``reached`` of ``of``:
    the completions of those influences with which it does; ``rule``: one of ``STEER_RULES``;
    ``solutions``: how many joint influences on ``target`` (its own free, the heard ones fixed)
    meet the goal at all."""

    target: str
    value: int | None
    robust: bool
    reached: int
    of: int
    rule: str
    solutions: int = 0


def steer(
    df: DecisionFunction,
    universe: Universe,
    me: str,
    target: str,
    lo: int,
    hi: int,
    mode: str = "exact",
    heard: Mapping[str, int] | None = None,
    predicted: Mapping[str, int] | None = None,
) -> SteeringChoice:
    """Choose ``me``'s influence on ``target`` so that ``target`` meets ``[lo, hi]`` in ``mode``,
    knowing the influences on ``target`` in ``heard`` (source -> alternative) and not the
    others', of which ``predicted`` may hold a guess (e.g. what they sent last round).

    Rule (one place, docs/goals.md): for each alternative v of ``me``, ascending, count the
    completions c of the unheard influences with which the goal is met for
    ``heard ∪ {me: v} ∪ c`` (``solve_per_action`` with those fixed: a count, no listing).

    1. **robust**: the smallest v that works for every completion;
    2. **predicted**: else, among the v that work when the unheard influences are as
       ``predicted`` (those without a prediction still counted over), the one that works for
       the most completions (ties: the smallest);
    3. **most completions**: else the v that works for the most completions (ties: the
       smallest): the best chance when every unheard influence is equally likely;
    4. **unreachable**: every count is 0: no influence of ``me`` can meet the goal.
    """
    if me == target:
        raise BadInput(f"influence {me}>{target}: a subject does not influence itself")
    heard = dict(heard or {})
    if me in heard:
        raise BadInput(f"influence {me}>{target}: {me}'s own influence is what is chosen")
    df.index(me)
    unheard = [s for s in df.order if s not in (target, me) and s not in heard]
    guess = {s: v for s, v in (predicted or {}).items() if s in unheard}
    total = len(universe) ** len(unheard)
    solutions = solve_per_action(df, universe, target, lo, hi, mode, heard).count
    counts = {
        v: solve_per_action(df, universe, target, lo, hi, mode, {**heard, me: v}).count
        for v in universe
    }

    def choice(v: int | None, rule: str) -> SteeringChoice:
        reached = 0 if v is None else counts[v]
        return SteeringChoice(
            target, v, rule == "robust", reached, total, rule, solutions
        )  # fmt: skip

    for v in universe:
        if counts[v] == total:
            return choice(v, "robust")
    if guess:
        fits = [
            v
            for v in universe
            if counts[v]
            and solve_per_action(
                df, universe, target, lo, hi, mode, {**heard, **guess, me: v}
            ).count
        ]
        if fits:
            return choice(max(fits, key=lambda v: (counts[v], -v)), "predicted")
    best = max(universe, key=lambda v: (counts[v], -v))
    return choice(best, "most completions") if counts[best] else choice(None, "unreachable")


def steerable_share(
    df: DecisionFunction, universe: Universe, me: str, target: str, lo: int, hi: int, mode: str
) -> Fraction:
    """The share of the other subjects' joint influences on ``target`` (every one but ``me``'s,
    all equally likely) for which some influence of ``me`` meets the goal: per action, the
    valid assignments with ``me``'s bit projected out (exists), counted; the product over
    actions (the inverse task's answer to "how often can ``me`` steer ``target`` alone")."""
    if me == target:
        raise BadInput(f"influence {me}>{target}: a subject does not influence itself")
    res = solve_per_action(df, universe, target, lo, hi, mode)
    n = df.n
    full = (1 << (1 << n)) - 1
    x, m = df.index(target), df.index(me)
    keep = (full ^ variable_table(x, n)) & (full ^ variable_table(m, n))
    share = Fraction(1)
    for t in res._tables:
        share *= Fraction(((t | (t >> (1 << m))) & keep).bit_count(), 1 << (n - 2))
    return share
