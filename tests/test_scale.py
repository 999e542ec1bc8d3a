"""Large groups on the concurrent schedule: every unit decodes everything and each decision is
the forward task's on the group and influences the scenario draws (computed here directly)."""

from __future__ import annotations

from pathlib import Path

import pytest
from rgtbus.units.group import run_group

from rgtbus.mind import choose_influences, cograph_relations
from rgtbus.rgt import (
    InfluenceMatrix,
    decision_function,
    forward,
    graph_to_polynomial,
    install_relations,
)
from rgtbus.rgt.polynomial import polynomial_text
from rgtbus.scenario import load_scenario
from rgtbus.telemetry import NullRecorder

ROOT = Path(__file__).parent.parent


def expected(sc):
    """The forward task on what the scenario says every unit will send, without any run."""
    group = cograph_relations(sc.units, sc.seed)
    poly = graph_to_polynomial(install_relations(sc.units, group))
    matrix = InfluenceMatrix(sc.units, sc.universe)
    for me in sc.units:
        sent = choose_influences(
            me, sc.units, sc.influences.pairs, sc.universe, policy=sc.influences.policy,
            value=sc.influences.value, weights=sc.influences.weights, seed=sc.seed,
        )  # fmt: skip
        for r, text in sent.items():
            matrix.set(me, r, sc.universe.parse_alternative(text))
    return polynomial_text(poly), forward(decision_function(poly, sc.units), sc.universe, matrix)


def check(name: str) -> None:
    sc = load_scenario(ROOT / "scenarios" / f"{name}.toml")
    assert sc.protocol.schedule == "concurrent"
    out = run_group(sc, "memory", NullRecorder()).summary
    assert out["error"] is None and out["decode_errors"]["misread"] == 0 and out["agree"]
    poly, results = expected(sc)
    assert out["polynomial"] == poly
    u = sc.universe
    for name_, res in results.items():
        got = out["units"][name_]
        assert got["decided"] and got["frustrated"] == res.frustrated
        if not res.frustrated:
            assert got["interval"] == [u.to_list(res.B), u.to_list(res.A)]


def test_twenty_units_concurrent_decide_as_the_forward_task():
    check("group20")


@pytest.mark.slow
def test_fifty_units_concurrent_decide_as_the_forward_task():
    check("group50")
