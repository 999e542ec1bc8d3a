"""Steering (issue 14's core): a subject's own influence on a target, chosen by the inverse
task given what it has heard; checked against brute force on small random groups."""

from __future__ import annotations

import random

import pytest

from rgtbus.errors import RgtbusError
from rgtbus.rgt import (
    Universe,
    decision_function,
    parse_polynomial,
    random_polynomial,
    solve_brute_force,
    steer,
)

AB = Universe(("alpha", "beta"))
ONE = Universe(("go",))


def _brute_counts(df, universe, me, target, lo, hi, mode, heard):
    """For each v of me: completions of the unheard influences that reach the goal."""
    return {
        v: len(solve_brute_force(df, universe, target, lo, hi, mode, {**heard, me: v}))
        for v in universe
    }


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
    n = rng.randint(2, 4)
    universe = AB if rng.random() < 0.6 else ONE
    names = [f"s{i}" for i in range(n)]
    df = decision_function(random_polynomial(names, rng), names)
    me, target = rng.sample(names, 2)
    lo = rng.choice(list(universe))
    hi = lo | rng.choice(list(universe))
    mode = rng.choice(["exact", "contains"])
    others = [s for s in names if s not in (me, target)]
    heard = {s: rng.choice(list(universe)) for s in others if rng.random() < 0.5}
    counts = _brute_counts(df, universe, me, target, lo, hi, mode, heard)
    total = len(universe) ** (len(others) - len(heard))
    got = steer(df, universe, me, target, lo, hi, mode, heard)
    assert got.of == total
    robust = [v for v in universe if counts[v] == total]
    if robust:  # every goal brute force says is reachable for sure is reached
        assert (got.value, got.robust, got.reached) == (min(robust), True, total)
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
