"""Inverse task: the paper's example, modes, fixed influences, and per-action vs brute force."""

import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rgtbus.errors import RgtbusError
from rgtbus.rgt import (
    Universe,
    decision_function,
    parse_polynomial,
    random_polynomial,
    solve_brute_force,
    solve_per_action,
)

AB = Universe(("alpha", "beta"))


def listed(universe, solutions):
    return sorted(tuple((s, universe.format(v)) for s, v in sol.items()) for sol in solutions)


def test_paper_inverse_task_ab_plus_c():
    df = decision_function(parse_polynomial("ab+c"))
    alpha = AB.parse_alternative("{alpha}")
    res = solve_per_action(df, AB, "a", alpha, alpha, "exact")
    assert res.count == 2
    # docs/errata.md: (b, c) = ({α}, {α}) and (0, {α}); the paper prints the second transposed.
    assert listed(AB, res.solutions()) == [
        (("b", "0"), ("c", "{alpha}")),
        (("b", "{alpha}"), ("c", "{alpha}")),
    ]
    assert listed(AB, solve_brute_force(df, AB, "a", alpha, alpha)) == listed(AB, res.solutions())


def test_contains_mode_and_interval_target():
    df = decision_function(parse_polynomial("ab+c"))
    beta = AB.parse_alternative("{beta}")
    # a's interval is [c, b+c]: {β} lies in it iff c ⊆ {β} and {β} ⊆ b+c.
    res = solve_per_action(df, AB, "a", beta, beta, "contains")
    expect = [{"b": b, "c": c} for b in AB for c in AB if not c & ~beta and not beta & ~(b | c)]
    assert listed(AB, res.solutions()) == listed(AB, expect)
    # Interval target [0, 1] exactly: c = 0 and b + c = 1.
    res = solve_per_action(df, AB, "a", 0, AB.full, "exact")
    assert listed(AB, res.solutions()) == [(("b", "1"), ("c", "0"))]


def test_fixed_influences_restrict_the_solutions():
    df = decision_function(parse_polynomial("abc+d"))
    gate = Universe(("open",))
    # Robots b, c (fixed at 0) cannot open a's decision; only d's influence decides it.
    res = solve_per_action(df, gate, "a", 1, 1, "exact", fixed={"b": 0, "c": 0})
    assert listed(gate, res.solutions()) == [(("b", "0"), ("c", "0"), ("d", "1"))]
    assert res.count == 1


def test_count_without_listing_for_a_huge_solution_set():
    order = [f"s{i}" for i in range(16)]
    df = decision_function(parse_polynomial("*".join(order[:8]) + "+" + "+".join(order[8:])))
    u = Universe(("p", "q", "r", "s"))
    # s8 sits in the sum, so A = 1 whatever the others do: every tuple contains the target 1.
    res = solve_per_action(df, u, "s8", u.full, u.full, "contains")
    assert res.count == (1 << 4) ** 15
    # s0: B = s8+...+s15 must be 0 and A = s1...s7 + B must be 1: exactly one tuple.
    assert solve_per_action(df, u, "s0", 0, u.full, "contains").count == 1
    assert len(list(res.solutions(limit=3))) == 3


def test_unreachable_target_has_no_solution():
    df = decision_function(parse_polynomial("a(b+c)"))
    res = solve_per_action(df, AB, "a", AB.full, AB.full, "exact")
    # For a: B = 1 always, A = b+c: a = 1 needs b+c = 1.
    assert res.count == sum(1 for b in AB for c in AB if b | c == AB.full)
    res = solve_per_action(df, AB, "a", 0, 0, "exact")
    assert res.count == 0 and list(res.solutions()) == []


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"subject": "z"}, "unknown subject 'z'"),
        ({"mode": "roughly"}, "unknown mode"),
        ({"lo": 0b01, "hi": 0b10}, "is empty"),
        ({"fixed": {"a": 1}}, "does not influence itself"),
        ({"fixed": {"z": 1}}, "unknown subject 'z'"),
        ({"fixed": {"b": 9}}, "outside the algebra"),
    ],
)
def test_control_errors(kwargs, needle):
    df = decision_function(parse_polynomial("ab+c"))
    args = {"subject": "a", "lo": 1, "hi": 1, "mode": "exact", "fixed": None} | kwargs
    with pytest.raises(RgtbusError, match=needle):
        solve_per_action(
            df, AB, args["subject"], args["lo"], args["hi"], args["mode"], args["fixed"]
        )


def test_brute_force_refuses_hopeless_sizes():
    order = [chr(97 + i) for i in range(12)]
    df = decision_function(parse_polynomial("".join(order)))
    u = Universe(("p", "q", "r"))
    with pytest.raises(RgtbusError, match="brute force needs"):
        solve_brute_force(df, u, "a", 0, 0)


@settings(max_examples=150, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 5),
    k=st.integers(1, 2),
    mode=st.sampled_from(["exact", "contains"]),
    data=st.data(),
)
def test_per_action_equals_brute_force(seed, n, k, mode, data):
    rng = random.Random(seed)
    order = [chr(97 + i) for i in range(n)]
    df = decision_function(random_polynomial(order, rng), order)
    u = Universe(tuple(f"x{j}" for j in range(k)))
    subject = data.draw(st.sampled_from(order))
    hi = data.draw(st.integers(0, u.full))
    lo = data.draw(st.integers(0, u.full)) & hi
    others = [s for s in order if s != subject]
    fixed_names = data.draw(st.lists(st.sampled_from(others), unique=True)) if others else []
    fixed = {s: data.draw(st.integers(0, u.full)) for s in fixed_names}
    fast = solve_per_action(df, u, subject, lo, hi, mode, fixed)
    slow = solve_brute_force(df, u, subject, lo, hi, mode, fixed)
    assert fast.count == len(slow)
    assert listed(u, fast.solutions()) == listed(u, slow)
