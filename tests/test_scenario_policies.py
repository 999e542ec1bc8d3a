"""Scenario policies that write a large group in a few lines: relationship policy ``cograph``
(a seeded random decomposable group) and influence policies ``uniform`` and ``random``."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
from rgtbus.units.group import run_group

from rgtbus.errors import RgtbusError
from rgtbus.mind import choose_influences, choose_relations, cograph_relations
from rgtbus.rgt import graph_to_polynomial, install_relations
from rgtbus.rgt.polynomial import polynomial_text
from rgtbus.scenario import parse_scenario
from rgtbus.telemetry import MemoryRecorder

GATE = (Path(__file__).parent.parent / "scenarios" / "gate.toml").read_text()
HEAD = GATE.split("[relations]")[0]  # units, frequencies, timing, channel of the gate


def scenario(relations: str, influences: str):
    return parse_scenario(f"{HEAD}[relations]\n{relations}\n[influences]\n{influences}\n")


@pytest.mark.parametrize(("n", "seed"), list(itertools.product([2, 5, 12, 40], range(6))))
def test_a_cograph_group_is_decomposable_and_the_same_for_every_unit(n, seed):
    units = tuple(f"u{i}" for i in range(n))
    group = cograph_relations(units, seed)
    assert set(group) == {(a, b) for a in units for b in units if a != b}
    assert all(group[(a, b)] == group[(b, a)] for a, b in group)  # both sides send alike
    graph_to_polynomial(install_relations(units, group))  # no induced P4: raises otherwise
    for me in units:  # what each unit sends is its side of the one group
        sent = choose_relations(me, units, seed=seed, fixed={}, draws={}, p=0.5, policy="cograph")
        assert sent == {r: "alliance" if group[(me, r)] else "conflict" for r in units if r != me}


def test_cograph_groups_differ_by_seed():
    units = tuple(f"u{i}" for i in range(10))
    shapes = {
        str(graph_to_polynomial(install_relations(units, cograph_relations(units, s))))
        for s in range(20)
    }
    assert len(shapes) > 10


def test_uniform_influences_with_an_override():
    sc = scenario('policy = "cograph"', 'policy = "uniform"\nvalue = "1"\n"d>a" = "0"')
    got = {
        me: choose_influences(
            me,
            sc.units,
            sc.influences.pairs,
            sc.universe,
            policy="uniform",
            value=sc.influences.value,
        )
        for me in sc.units
    }
    assert got["d"] == {"a": "0", "b": "1", "c": "1"}
    assert all(v == "1" for me in "abc" for v in got[me].values())


def test_random_influences_are_seeded_weighted_and_overrides_shift_nothing():
    units = tuple(f"u{i}" for i in range(30))
    sc = scenario('policy = "cograph"', 'policy = "random"')
    universe = sc.universe  # one action: alternatives 0 and 1

    def draw(me, overrides=None, weights=None, seed=7):
        return choose_influences(
            me, units, overrides or {}, universe, policy="random", weights=weights, seed=seed
        )

    a = draw("u0")
    assert a == draw("u0") and a != draw("u0", seed=8)  # seeded
    assert set(a.values()) == {"0", "1"}  # 29 draws over two alternatives
    over = draw("u0", {("u0", "u5"): 1})
    assert over["u5"] == "1" and {k: v for k, v in over.items() if k != "u5"} == {
        k: v for k, v in a.items() if k != "u5"
    }
    only_one = draw("u0", weights={1: 1.0, 0: 0.0})
    assert set(only_one.values()) == {"1"}


def test_a_run_with_cograph_and_random_influences_agrees_and_decides():
    sc = scenario(
        'policy = "cograph"',
        'policy = "random"\n"a>b" = "1"\n[influences.weights]\n"1" = 3\n"0" = 1',
    )
    for seed in range(3):
        s = sc.with_seed(seed)
        out = run_group(s, "memory", MemoryRecorder()).summary
        assert out["error"] is None and out["agree"] and out["decode_errors"]["misread"] == 0
        group = cograph_relations(s.units, seed)
        assert out["relations"] == {
            f"{a}-{b}": "alliance" if group[(a, b)] else "conflict"
            for a, b in itertools.combinations(s.units, 2)
        }
        want = graph_to_polynomial(install_relations(s.units, group))
        assert out["polynomial"] == polynomial_text(want)
        assert all(v["decided"] for v in out["units"].values())


@pytest.mark.parametrize(
    ("relations", "influences", "pattern"),
    [
        ('policy = "cograph"\np = 0.5', 'policy = "uniform"\nvalue = 1', r"relations\.p: not with"),
        (
            'policy = "cograph"\n[relations.fixed]\n"a>b" = "alliance"',
            'policy = "uniform"\nvalue = 1',
            r"relations\.fixed: not with policy cograph",
        ),
        ('policy = "cliques"', 'policy = "uniform"\nvalue = 1', r"relations\.policy: unknown"),
        ('policy = "cograph"', 'policy = "uniform"', r"influences\.policy: uniform needs a value"),
        ('policy = "cograph"', 'policy = "whim"', r"influences\.policy: unknown policy 'whim'"),
        ('policy = "cograph"', 'value = "1"', r"influences\.value: only with policy uniform"),
        ('policy = "cograph"', 'policy = "uniform"\nvalue = "{fly}"', r"influences\.value: "),
        (
            'policy = "cograph"',
            'policy = "uniform"\nvalue = 1\n[influences.weights]\n"1" = 1',
            r"influences\.weights: only with policy random",
        ),
        (
            'policy = "cograph"',
            'policy = "random"\n[influences.weights]\n"1" = -1',
            r"influences\.weights\.1: weight must be within \[0, 1e9\]",
        ),
        (
            'policy = "cograph"',
            'policy = "random"\n[influences.weights]\n"1" = 1\n"{open}" = 2',
            r"influences\.weights\.\{open\}: names the same alternative as '1'",
        ),
        (
            'policy = "cograph"',
            'polcy = "uniform"\nvalue = 1',
            r"influences\.polcy: unknown key",
        ),
        (
            'policy = "cograph"',
            'policy = "random"\n[influences.weights]\n"1" = 0\n"0" = 0',
            r"influences\.weights: at least one weight must be > 0",
        ),
        ('policy = "cograph"', '"a>b" = "1"', r"influences: no influence for a>c \(list every"),
    ],
)
def test_policy_mistakes_are_refused_by_key(relations, influences, pattern):
    with pytest.raises(RgtbusError, match=pattern):
        scenario(relations, influences)


def test_a_custom_codebook_without_a_conflict_word_is_refused_at_load():
    text = GATE.replace(
        'codebook = "paper"',
        "codebook = { pulses = 3, id = [0.4, 0.4, 0.4], relation = { alliance = [0.4, 0.4, -0.4] },"
        ' alternative = { "0" = [-0.4, 0.4, 0.4], "1" = [0.4, -0.4, 0.4] } }',
    )
    with pytest.raises(
        RgtbusError, match=r"gate\.toml:\d+: codebook: no word for relationship conflict"
    ):
        parse_scenario(text, "gate.toml")


def test_without_a_codebook_three_actions_get_the_shortest_generated_one():
    text = HEAD.replace('actions = ["open"]', 'actions = ["go", "stay", "wait"]')
    text = text.replace('codebook = "paper"\n', "").replace('mode = "paper"\n', "")
    text += '[relations]\npolicy = "cograph"\n[influences]\npolicy = "uniform"\nvalue = "1"\n'
    sc = parse_scenario(text)
    assert sc.codebook.pulses == 4 and len(sc.codebook.alternatives) == 8
    out = run_group(sc, "memory", MemoryRecorder()).summary
    assert out["error"] is None and out["decode_errors"]["misread"] == 0 and out["agree"]
