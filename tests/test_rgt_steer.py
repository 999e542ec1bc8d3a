"""Steering (issue 14's core): a subject's own influence on a target, chosen by the inverse
task given what it has heard; checked against brute force on small random groups."""

from __future__ import annotations

import itertools
import random
from fractions import Fraction

import pytest

from rgtbus.errors import RgtbusError
from rgtbus.rgt import (
    Universe,
    decision_function,
    meets,
    parse_polynomial,
    random_polynomial,
    solve_brute_force,
    steer,
    steerable_share,
)

AB = Universe(("alpha", "beta"))
ONE = Universe(("go",))


def _brute_counts(df, universe, me, target, lo, hi, mode, heard):
    """For each v of me: completions of the unheard influences that reach the goal."""
    return {
        v: len(solve_brute_force(df, universe, target, lo, hi, mode, {**heard, me: v}))
        for v in universe
    }


def _random_goal(rng: random.Random, two_actions: float):
    """A random group of 2-4 subjects, a steering subject, a target and a goal in any mode."""
    n = rng.randint(2, 4)
    universe = AB if rng.random() < two_actions else ONE
    names = [f"s{i}" for i in range(n)]
    df = decision_function(random_polynomial(names, rng), names)
    me, target = rng.sample(names, 2)
    mode = rng.choice(["exact", "contains", "largest", "smallest"])
    lo = rng.choice(list(universe))
    hi = lo if mode in ("largest", "smallest") else lo | rng.choice(list(universe))
    return universe, names, df, me, target, mode, lo, hi


def test_the_gate_robot_d_finds_the_influence_1_itself():
    """Example 3 (abc+d): d wants a to choose 1 while b and c urge 0 on a."""
    df = decision_function(parse_polynomial("abc+d"))
    heard = {"b": 0, "c": 0}
    got = steer(df, ONE, "d", "a", ONE.full, ONE.full, "exact", heard)
    assert (got.value, got.robust, got.rule) == (ONE.full, True, "robust")
    # with nothing heard, 1 still works whatever b and c send
    assert steer(df, ONE, "d", "a", ONE.full, ONE.full).value == ONE.full


@pytest.mark.parametrize("seed", range(60))
def test_steering_follows_its_rule_against_brute_force(seed):
    rng = random.Random(seed)
    universe, names, df, me, target, mode, lo, hi = _random_goal(rng, two_actions=0.6)
    others = [s for s in names if s not in (me, target)]
    heard = {s: rng.choice(list(universe)) for s in others if rng.random() < 0.5}
    predicted = {s: rng.choice(list(universe)) for s in others if s not in heard}
    if rng.random() < 0.3:
        predicted = {}
    counts = _brute_counts(df, universe, me, target, lo, hi, mode, heard)
    total = len(universe) ** (len(others) - len(heard))
    got = steer(df, universe, me, target, lo, hi, mode, heard, predicted)
    assert got.of == total
    assert got.solutions == sum(counts.values())
    robust = [v for v in universe if counts[v] == total]
    fits = [
        v
        for v in universe
        if solve_brute_force(df, universe, target, lo, hi, mode, {**heard, **predicted, me: v})
    ]
    if robust:  # every goal brute force says is reachable for sure is reached
        assert (got.value, got.robust, got.reached) == (min(robust), True, total)
    elif fits and predicted:  # else what works if the others do as predicted
        best = max(counts[v] for v in fits)
        assert got.value == min(v for v in fits if counts[v] == best)
        assert (got.robust, got.rule) == (False, "predicted")
    elif any(counts.values()):
        best = max(counts.values())
        assert got.value == min(v for v in universe if counts[v] == best)
        assert (got.robust, got.reached, got.rule) == (False, best, "most completions")
    else:  # unreachable by its own influence: said so
        assert (got.value, got.rule, got.reached) == (None, "unreachable", 0)


def test_steering_refuses_nonsense():
    df = decision_function(parse_polynomial("ab+c"))
    with pytest.raises(RgtbusError, match="does not influence itself"):
        steer(df, AB, "a", "a", 0, 0)
    with pytest.raises(RgtbusError, match="own influence is what is chosen"):
        steer(df, AB, "b", "a", 0, 0, heard={"b": 1})
    with pytest.raises(RgtbusError):
        steer(df, AB, "z", "a", 0, 0)


@pytest.mark.parametrize("seed", range(40))
def test_steerable_share_is_the_brute_force_share(seed):
    """How often one subject can steer another alone, over every joint influence of the rest."""
    rng = random.Random(1000 + seed)
    universe, names, df, me, target, mode, lo, hi = _random_goal(rng, two_actions=0.5)
    rest = [s for s in names if s not in (me, target)]
    hits = 0
    for combo in itertools.product(list(universe), repeat=len(rest)):
        fixed = dict(zip(rest, combo, strict=True))
        if any(
            solve_brute_force(df, universe, target, lo, hi, mode, {**fixed, me: v})
            for v in universe
        ):
            hits += 1
    assert steerable_share(df, universe, me, target, lo, hi, mode) == Fraction(
        hits, len(universe) ** len(rest)
    )


def test_choice_modes_are_what_max_and_min_subjects_choose():
    for a in range(4):
        for b in range(4):
            for v in range(4):
                ok = not b & ~a
                assert meets(a, b, v, v, "largest") == (ok and a == v)
                assert meets(a, b, v, v, "smallest") == (ok and b == v)
    df = decision_function(parse_polynomial("ab+c"))
    with pytest.raises(RgtbusError, match="wants one alternative"):
        steer(df, AB, "b", "a", 0, AB.full, "largest")
