"""Codebooks as data: the paper's, TOML-like dicts, the generator, and every refusal."""

import itertools
import math

import pytest

from rgtbus.errors import RgtbusError
from rgtbus.signal.codebook import (
    Codebook,
    alternative_names,
    generate_codebook,
    paper_codebook,
)


def test_paper_codebook_matches_spec():
    cb = paper_codebook()
    assert cb.pulses == 3 and cb.id_word == (0.4, 0.4, 0.4)
    assert cb.relations == {"alliance": (0.4, 0.4, 0.4), "conflict": (-0.4, -0.4, -0.4)}
    assert cb.alternatives == {
        "1": (0.2, 0.3, 0.7),
        "0": (0.7, 0.3, 0.2),
        "{alpha}": (0.5, 0.2, 0.5),
        "{beta}": (0.3, 0.6, 0.3),
    }
    assert cb.family_min_distance("alternative") == pytest.approx(math.sqrt(0.14))
    assert list(cb.distinct_words()) == ["id", "conflict", "1", "0", "{alpha}", "{beta}"]


def test_paper_codebook_renames():
    cb = paper_codebook(("open", "shut"), names={"1": "0", "0": "1"})
    assert cb.alternatives["0"] == (0.2, 0.3, 0.7) and "{open}" in cb.alternatives
    with pytest.raises(RgtbusError, match="no alternative named 'x'"):
        paper_codebook(names={"x": "y"})
    with pytest.raises(RgtbusError, match="share a name"):
        paper_codebook(names={"1": "0"})
    with pytest.raises(RgtbusError, match="k = 1 or 2"):
        paper_codebook(("a", "b", "c"))
    with pytest.raises(RgtbusError, match="k = 1 or 2"):
        paper_codebook(("a", "a"))


def test_paper_codebook_for_one_action_has_the_unit_and_zero_codes():
    cb = paper_codebook(("open",))  # Example 3: 1 = open the gate, 0 = don't
    assert dict(cb.alternatives) == {"1": (0.2, 0.3, 0.7), "0": (0.7, 0.3, 0.2)}
    assert cb.actions == ("open",)


def test_dict_round_trip():
    cb = paper_codebook()
    assert Codebook.from_dict(cb.to_dict()) == cb


def base():
    return paper_codebook().to_dict()


@pytest.mark.parametrize(
    "patch, needle",
    [
        (lambda d: d["alternative"].update({"1": [0.3, 0.6, 0.3]}), "same pulses"),
        (lambda d: d["alternative"].update({"1": [0.31, 0.6, 0.3]}), "closer than min_distance"),
        (lambda d: d["alternative"].update({"1": [0.2, 0.3]}), "has 2 pulses, expected 3"),
        (lambda d: d.update(id=[0.4, 0.4]), "id word 'id' has 2 pulses"),
        (lambda d: d["relation"].update(conflict=[0.4, 0.4, 0.4]), "relation words"),
        (lambda d: d["alternative"].update({"0": [0.45, 0.4, 0.4]}), "from the ID-code"),
        (lambda d: d.update(colour="red"), "unknown key 'colour'"),
        (lambda d: d.pop("relation"), "missing key 'relation'"),
        (lambda d: d.update(pulses=0), "codebook.pulses"),
        (lambda d: d.update(pulses=True), "codebook.pulses"),
        (lambda d: d["alternative"].update({"1": [0.2, "x", 0.7]}), "'x' is not a number"),
        (lambda d: d["alternative"].update({"1": "0.2,0.3"}), "not a list"),
        (lambda d: d["alternative"].update({"1": [0.2, math.inf, 0.7]}), "not finite"),
        (lambda d: d.update(relation={}), "non-empty table"),
        (lambda d: d.update(min_distance=-1), "min_distance"),
        (lambda d: d.update(actions="ab"), "actions"),
    ],
)
def test_invalid_codebooks_refused(patch, needle):
    d = base()
    patch(d)
    with pytest.raises(RgtbusError) as e:
        Codebook.from_dict(d)
    assert needle in str(e.value)


def test_from_dict_not_a_table():
    with pytest.raises(RgtbusError, match="must be a table"):
        Codebook.from_dict([1, 2])


def test_alternative_names():
    assert alternative_names(["alpha", "beta"]) == ["0", "{alpha}", "{beta}", "1"]
    assert alternative_names(["x"]) == ["0", "1"]
    assert alternative_names(["a", "b", "c"])[3] == "{a,b}"


@pytest.mark.parametrize("k, pulses, dmin", [(1, 3, 0.3), (2, 3, 0.4), (3, 4, 0.4), (4, 5, 0.4)])
def test_generator_min_distance_and_determinism(k, pulses, dmin):
    acts = [f"x{i}" for i in range(k)]
    cb = generate_codebook(acts, pulses=pulses, min_distance=dmin, seed=5)
    assert len(cb.alternatives) == 2**k and cb.pulses == pulses
    words = list(cb.alternatives.values())
    assert min(math.dist(a, b) for a, b in itertools.combinations(words, 2)) >= dmin
    assert all(abs(sum(w) - 0.4 * pulses) < 1e-9 and max(w) <= 0.7 + 1e-9 for w in words)
    assert generate_codebook(acts, pulses=pulses, min_distance=dmin, seed=5) == cb
    assert set(cb.alternatives) == set(alternative_names(acts))


def test_generator_refusals():
    with pytest.raises(RgtbusError, match="use more pulses"):
        generate_codebook(["a", "b", "c"], pulses=3, min_distance=0.3)
    with pytest.raises(RgtbusError, match="distinct"):
        generate_codebook(["a", "a"])
    with pytest.raises(RgtbusError, match="pulses"):
        generate_codebook(["a"], pulses=0)
    with pytest.raises(RgtbusError, match="step"):
        generate_codebook(["a"], step=-0.1)
    with pytest.raises(RgtbusError, match="family 'x'"):
        paper_codebook().family("x")
