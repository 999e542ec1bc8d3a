"""The noise-free forward task (what a perfect medium would have each unit decide) and the
wrong-decision count built on it."""

from __future__ import annotations

from pathlib import Path

import pytest
from rgtbus.units.group import run_group

from rgtbus.mind import intents
from rgtbus.scenario import load_scenario, parse_scenario
from rgtbus.summary import wrong_decisions
from rgtbus.telemetry import NullRecorder
from rgtbus.truth import noise_free

ROOT = Path(__file__).resolve().parent.parent


FIVE = '\nunits = ["u1", "u2", "u3", "u4", "u5"]\n[decision]\npolicy = "seeded-random"\n'


def _random5(seed: int):
    """random_group with five units deciding at random within their intervals."""
    base = (ROOT / "scenarios" / "random_group.toml").read_text()
    text = base.replace("seed = 0", f"seed = {seed}", 1).replace(
        'units = ["u1", "u2", "u3"]', FIVE.split("\n")[1]
    )
    return parse_scenario(text + "\n".join(FIVE.split("\n")[2:]), f"random5 seed {seed}")


@pytest.mark.parametrize("name", ["gate", "example1", "example2", "group20"])
def test_a_clean_run_decides_exactly_as_the_noise_free_task(name):
    sc = load_scenario(str(ROOT / "scenarios" / f"{name}.toml"))
    out = run_group(sc, "memory", NullRecorder())
    assert out.summary["units"] == noise_free(sc)
    assert out.summary["wrong_decisions"] == []


@pytest.mark.parametrize("seed", [4, 5, 7])
def test_random_decisions_too(seed):
    sc = _random5(seed)
    out = run_group(sc, "memory", NullRecorder())
    assert out.summary["decomposable"] is True
    assert out.summary["units"] == noise_free(sc)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_group_with_an_induced_p4_has_no_noise_free_decision(seed):
    sc = _random5(seed)
    out = run_group(sc, "memory", NullRecorder())
    assert out.summary["decomposable"] is False
    truth = noise_free(sc)
    assert out.summary["units"] == truth and not any(r["decided"] for r in truth.values())


def test_intents_are_what_each_unit_sends():
    sc = load_scenario(str(ROOT / "scenarios" / "gate.toml"))
    relations, influences = intents(sc, "d")
    assert set(relations) == set(influences) == {"a", "b", "c"}
    assert set(relations.values()) <= {"alliance", "conflict"}


def test_wrong_decisions_names_units_that_decided_otherwise():
    truth = {
        "a": {"decided": True, "interval": [[], ["x"]], "frustrated": False, "choice": ["x"]},
        "b": {"decided": True, "interval": None, "frustrated": True, "choice": None},
        "c": {"decided": False, "interval": None, "frustrated": False, "choice": None},
    }
    same = {u: dict(r) for u, r in truth.items()}
    assert wrong_decisions(same, truth) == []
    other = {u: dict(r) for u, r in truth.items()}
    other["a"]["choice"] = []  # another choice in the same interval
    other["b"] = {"decided": True, "interval": [[], []], "frustrated": False, "choice": []}
    other["c"] = {"decided": True, "interval": [[], []], "frustrated": False, "choice": []}
    assert wrong_decisions(other, truth) == ["a", "b", "c"]  # c decided where none exists
    undecided = {"a": {"decided": False}}
    assert wrong_decisions(undecided, truth) == []  # no decision is no wrong decision


def test_minds_with_equal_tables_share_one_copy_of_what_they_derive_from_them():
    """The tables a report holds (relation codes, pairs installed, influences) are built once
    for every mind whose table is equal, and afresh once a table changes."""
    from rgtbus.mind import mind_of
    from rgtbus.pairs import SharedTable

    sc = load_scenario(ROOT / "scenarios" / "gate.toml")
    a, b = mind_of(sc, sc.units[0]), mind_of(sc, sc.units[1])
    pairs = [(s, r) for s in sc.units for r in sc.units if s != r]
    for i, p in enumerate(pairs):
        a.sent[p] = b.sent[p] = i % 3 == 0
    assert a.sent_table() is b.sent_table() and a.installed() is b.installed()
    assert type(a.sent_table()) is SharedTable  # read, never changed: its JSON written once
    assert a.sent_table() == {
        f"{s}>{r}": "alliance" if i % 3 == 0 else "conflict"
        for i, (s, r) in sorted(enumerate(pairs), key=lambda x: x[1])
    }
    before = a.sent_table()
    b.sent[pairs[1]] = True
    assert b.sent_table()[f"{pairs[1][0]}>{pairs[1][1]}"] == "alliance"
    assert a.sent_table() is before and before[f"{pairs[1][0]}>{pairs[1][1]}"] == "conflict"
    for m in (a, b):
        for i, p in enumerate(pairs):
            m.hear_influence(1, p, i % 2)
    assert a.influence_table() is b.influence_table()


def test_minds_that_decoded_alike_share_the_forward_task_and_still_choose_their_own():
    """The forward task is a function of the relations and influences a unit decoded: two
    minds that decoded the same share one result; a changed influence gives its own."""
    from rgtbus.mind import mind_of

    sc = load_scenario(ROOT / "scenarios" / "gate.toml")
    minds = [mind_of(sc, u) for u in sc.units[:2]]
    pairs = [(s, r) for s in sc.units for r in sc.units if s != r]
    for m in minds:
        for i, p in enumerate(pairs):
            m.sent[p] = i % 2 == 0
        m.build_group()
        for i, p in enumerate(pairs):
            m.hear_influence(1, p, i % 2)
    a, b = minds
    assert a.results is not None and a.results is b.results
    assert a.choice is not None and b.choice is not None  # each its own choice, from it
    other = mind_of(sc, sc.units[2])
    for i, p in enumerate(pairs):
        other.sent[p] = i % 2 == 0
    other.build_group()
    for i, p in enumerate(pairs):
        other.hear_influence(1, p, (i + 1) % 2)
    assert other.results is not None and other.results is not a.results
    apart = mind_of(sc, sc.units[3])  # other relations, the same influences: its own group
    for i, p in enumerate(pairs):
        apart.sent[p] = i % 3 == 0
    apart.build_group()
    for i, p in enumerate(pairs):
        apart.hear_influence(1, p, i % 2)
    assert apart.polynomial != a.polynomial and apart.results is not a.results


@pytest.mark.parametrize("seed", range(12))
def test_tables_read_as_arrays_give_what_the_pair_by_pair_reading_gives(seed):
    """A mind's tables (relation codes, pairs installed, influences) and the installed graph
    read from a ``PairTable`` as arrays equal the same read pair by pair from a dict, with
    codes missing, units of any names, and the same refusal of a missing code."""
    import random
    import re

    from rgtbus.mind import mind_of
    from rgtbus.pairs import PairTable
    from rgtbus.rgt.polynomial import install_relations

    rng = random.Random(seed)
    names = rng.sample(["zed", "a1", "B", "m_2", "q", "aa", "c9", "x"], rng.randint(2, 8))
    text = (ROOT / "scenarios" / "gate.toml").read_text()
    sc = parse_scenario(text)  # a mind of gate's, given tables of other names
    table = PairTable(names, boolean=True)
    missing = rng.random() < 0.5
    for s in names:
        for r in names:
            if s != r and not (missing and rng.random() < 0.1):
                table[(s, r)] = rng.random() < 0.6
    plain = dict(table.items())
    fast, slow = mind_of(sc, sc.units[0]), mind_of(sc, sc.units[0])
    fast.units = slow.units = tuple(names)
    fast.sent, slow.sent = table, plain
    assert fast._installed() == slow._installed()
    assert list(fast._sent_table().items()) == list(slow._sent_table().items())
    infl = PairTable(names)
    for p in plain:
        infl[p] = rng.randrange(4)
    fast.influences, slow.influences = infl, dict(infl.items())
    assert list(fast._influence_table().items()) == list(slow._influence_table().items())
    try:
        want = install_relations(names, plain)
    except Exception as exc:  # the refusal itself is compared
        with pytest.raises(type(exc), match=re.escape(str(exc))):
            install_relations(names, table)
    else:
        assert install_relations(names, table) == want
