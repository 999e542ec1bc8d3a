"""Frequency plans: the paper's, generated ones, each rule's refusal, omega expressions."""

import math

import pytest

from rgtbus.errors import RgtbusError
from rgtbus.signal.plan import (
    PAPER_OMEGAS,
    auto_plan,
    check_plan,
    max_units,
    parse_omega,
)

PI = math.pi


def test_paper_plan():
    assert auto_plan(3) == [3 * PI / 2, 4 * PI / 3, 5 * PI / 3]
    assert auto_plan(4)[3] == 7 * PI / 6
    check_plan(PAPER_OMEGAS)  # passes every rule


@pytest.mark.parametrize("n", [5, 6, 8])
def test_generated_paper_mode_plans(n):
    plan = auto_plan(n)
    assert len(plan) == n
    check_plan(plan)
    assert max(plan) < 2 * min(plan)


def test_generated_exact_mode_plan_for_a_larger_group():
    plan = auto_plan(20, pulses=12, mode="exact")
    check_plan(plan, pulses=12, mode="exact")
    with pytest.raises(RgtbusError, match="rule euler"):
        check_plan(plan, pulses=12, mode="paper")


def test_too_many_units_names_rule_and_fix():
    assert max_units(3) == 8
    with pytest.raises(RgtbusError, match=r"rule octave/spacing: 9 units .* at least 4 pulses"):
        auto_plan(9)
    with pytest.raises(RgtbusError, match="number of units"):
        auto_plan(0)


@pytest.mark.parametrize(
    "omegas, kw, rule",
    [
        ([3.0, -1.0], {}, "rule positive"),
        ([3.0, 3.0], {}, "rule positive"),
        ([], {}, "rule positive"),
        ([3.0, 100.0], {"mode": "exact"}, "rule nyquist"),
        ([4.0, 6.5], {}, "rule euler"),
        ([3.0, 6.0], {}, "rule octave"),
        ([4.0, 4.3], {}, "rule spacing"),
        ([1.0, 1.5], {}, "rule decay"),
        ([4.0, 5.0], {"b": 0.0, "mode": "exact"}, "rule decay"),
    ],
)
def test_rule_refusals(omegas, kw, rule):
    with pytest.raises(RgtbusError) as e:
        check_plan(omegas, **kw)
    assert str(e.value).startswith(rule)


def test_check_plan_argument_refusals():
    with pytest.raises(RgtbusError, match="mode"):
        check_plan([3.0], mode="x")
    with pytest.raises(RgtbusError, match="pulses"):
        check_plan([3.0], pulses=0)


@pytest.mark.parametrize(
    "text, value",
    [
        ("3pi/2", 3 * PI / 2),
        ("1.5pi", 1.5 * PI),
        ("4.71", 4.71),
        ("pi", PI),
        ("7π/6", 7 * PI / 6),
        ("2*pi/3", 2 * PI / 3),
        (" 5pi / 3 ", 5 * PI / 3),
        ("1e1", 10.0),
        ("pi/2", PI / 2),
    ],
)
def test_parse_omega(text, value):
    assert parse_omega(text) == pytest.approx(value)


@pytest.mark.parametrize(
    "text, needle",
    [
        ("3pi/x", "'3pi/x'"),
        ("", "''"),
        ("pi/0", "zero"),
        ("0", "positive"),
        ("__import__('os')", "cannot read"),
        ("-3pi/2", "cannot read"),
        ("/2", "cannot read"),
    ],
)
def test_parse_omega_refusals(text, needle):
    with pytest.raises(RgtbusError) as e:
        parse_omega(text, where="--omega")
    assert needle in str(e.value) and str(e.value).startswith("--omega")
