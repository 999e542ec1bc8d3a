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


# -- plans for large groups (make_plan, rgtbus plan) -------------------------------------------


def test_make_plan_chooses_pulses_and_mode_per_schedule():
    from rgtbus.signal.plan import make_plan

    serial = make_plan(16, crosstalk=False)
    assert (serial.mode, serial.pulses, serial.codebook) == ("exact", 7, "generated")
    assert all(m.ok for m in serial.margins if m.binding)
    conc = make_plan(50, schedule="concurrent")
    assert (conc.mode, conc.pulses, conc.codebook) == ("paper", 3, "paper")
    assert len(set(conc.omegas)) == 50 and max(conc.omegas) < 2 * min(conc.omegas)
    by_rule = {m.rule: m for m in conc.margins}
    assert by_rule["euler"].ok and by_rule["euler"].binding and by_rule["nyquist"].binding
    # attention rules are margins for the concurrent schedule: reported, not enforced
    assert not by_rule["spacing"].ok and not by_rule["spacing"].binding
    assert not by_rule["crosstalk"].binding and by_rule["attention"].value >= 1.0
    assert make_plan(4).omegas == tuple(PAPER_OMEGAS)  # the paper's own four


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"n": 20, "pulses": 3}, r"rule octave/spacing: 20 units do not fit .* use at least"),
        ({"n": 5, "schedule": "concurrent", "tau": 0.2, "mode": "exact"}, r"rule nyquist"),
        ({"n": 0}, r"number of units 0"),
        ({"n": 4, "schedule": "round-robin"}, r"unknown schedule 'round-robin'"),
    ],
)
def test_make_plan_refuses_by_rule(kwargs, pattern):
    from rgtbus.signal.plan import make_plan

    with pytest.raises(RgtbusError, match=pattern):
        make_plan(crosstalk=False, **kwargs)


def test_plan_cli_prints_margins_and_rounds(capsys):
    import json
    import re

    from rgtbus.cli import main

    assert main(["plan", "12", "--schedule", "concurrent", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n"] == 12 and out["rounds"] == 22 and len(out["omegas"]) == 12
    assert {m["rule"] for m in out["margins"]} >= {"spacing", "decay", "euler", "crosstalk"}
    assert main(["plan", "16"]) == 0
    text = capsys.readouterr().out
    assert "mode exact, 7 pulses a code" in text
    assert re.search(r"^  ok +spacing +\(rule\)", text, re.M)
    assert main(["plan", "30", "--pulses", "3"]) == 2
    assert "rule octave/spacing" in capsys.readouterr().err


def test_crosstalk_in_batches_equals_one_run(monkeypatch):
    from rgtbus.signal import plan as plan_mod

    omegas = plan_mod.auto_plan(12, pulses=5)
    whole = plan_mod.crosstalk_peak(omegas, 5, "paper", 0.005, -0.1)
    monkeypatch.setattr(plan_mod, "CROSSTALK_BATCH", 5)  # 5 + 5 + 2 receivers
    assert plan_mod.crosstalk_peak(omegas, 5, "paper", 0.005, -0.1) == whole
