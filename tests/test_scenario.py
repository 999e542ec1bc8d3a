"""Scenario files: the shipped ones load; bad ones are refused with file, line, key and reason."""

from pathlib import Path

import pytest

from rgtbus.errors import RgtbusError
from rgtbus.scenario import load_scenario, parse_scenario

SCENARIOS = sorted(Path(__file__).parent.parent.joinpath("scenarios").glob("*.toml"))
GATE = Path(__file__).parent.parent / "scenarios" / "gate.toml"


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_shipped_scenarios_load(path):
    sc = load_scenario(path)
    assert sc.name == path.stem
    assert len(sc.pairs()) == len(sc.units) * (len(sc.units) - 1)
    assert sc.timing.window_samples * sc.timing.tau <= sc.timing.reaction_delay


def test_gate_contents():
    sc = load_scenario(GATE)
    assert sc.units == ("a", "b", "c", "d") and sc.universe.actions == ("open",)
    assert sc.influences[("d", "a")] == 1 and sc.influences[("a", "d")] == 0
    assert sc.outcome.all_of == ("a", "b", "c")
    assert sc.timing.window_samples == 20


def mutate(old: str, new: str) -> str:
    text = GATE.read_text()
    assert old in text, old
    return text.replace(old, new, 1)


BAD = [
    ("seed = 3", 'seed = 3\ncolour = "red"', r"gate\.toml:\d+: colour: unknown key"),
    ("window = 0.1 ", "window = 0.1\nwobble = 1 ", r"timing\.wobble: unknown key"),
    ('"a>b" = "alliance"', '"a>z" = "alliance"', r"relations\.fixed\.a>z: unknown unit 'z'"),
    ('"d>a" = "1"', '"d>a" = "{fly}"', r":\d+: influences\.d>a: unknown action 'fly'"),
    ('d = "7pi/6"', 'd = "3pi/2"', r"frequencies\.d: frequency clash: d and a"),
    ('d = "7pi/6"', 'd = "seven"', r"frequencies\.d: frequency: cannot read 'seven'"),
    ('d = "7pi/6"', "", r"frequencies: no frequency for unit 'd'"),
    ("noise = 0.0", "noise = -0.1", r"channel\.noise: must be a standard deviation >= 0"),
    ('policy = "fixed"', 'policy = "random"\np = 1.5', r"relations\.p: .*within \[0, 1\]"),
    ("window = 0.1 ", "window = 0.6 ", r"timing\.window: 0\.6 s exceeds the reaction delay"),
    ("window = 0.1 ", "window = 0.0123 ", r"whole number of samples"),
    ('"d>c" = "1"', "", r"influences: no influence for d>c"),
    ('"d>c" = "conflict"', "", r"relations\.fixed: policy fixed: no relation for d>c"),
    ('policy = "max"', 'policy = "greedy"', r"decision\.policy: unknown decision policy"),
    ('"a>b" = "0"', '"a>a" = "0"', r"influences\.a>a: a unit does not address itself"),
    ('units = ["a", "b", "c", "d"]', 'units = ["a", "b", "c", "d", "a"]', r"listed twice"),
    ('mode = "paper"', 'mode = "analog"', r"mode: unknown resonator mode 'analog'"),
    (
        "guard = 0.5",
        'guard = 0.5\nanchor = "whenever"',
        r"timing\.anchor: unknown anchor 'whenever'",
    ),
    ('all_of = ["a", "b", "c"]', 'all_of = ["a", "x"]', r"outcome\.all_of: unknown unit 'x'"),
    ('name = "gate"', 'name = "gate"\nname = "twice"', r"not valid TOML"),
]


@pytest.mark.parametrize(("old", "new", "pattern"), BAD, ids=[b[2][:40] for b in BAD])
def test_bad_scenarios(old, new, pattern):
    with pytest.raises(RgtbusError, match=pattern) as err:
        parse_scenario(mutate(old, new), "scenarios/gate.toml")
    assert "\n" not in str(err.value)
    assert str(err.value).startswith("scenarios/gate.toml")


def test_error_names_the_line():
    text = mutate('"d>a" = "1"', '"d>a" = "{fly}"')
    line = next(i for i, t in enumerate(text.splitlines(), 1) if "{fly}" in t)
    with pytest.raises(RgtbusError, match=rf"^scenarios/gate\.toml:{line}: influences\.d>a"):
        parse_scenario(text, "scenarios/gate.toml")


def test_missing_file():
    with pytest.raises(RgtbusError, match=r"cannot read scenario 'nope\.toml'"):
        load_scenario("nope.toml")
