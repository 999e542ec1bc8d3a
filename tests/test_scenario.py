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
    assert sc.influences.pairs[("d", "a")] == 1 and sc.influences.pairs[("a", "d")] == 0
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


PAIR_SECTIONS = [
    ('"d>a" = "1"', '"{key}" = "1"', "influences"),
    ('"a>b" = "alliance"', '"{key}" = "alliance"', "relations.fixed"),
    ("[outcome]", '[channel.gain]\n"{key}" = 0.9\n\n[outcome]', "channel.gain"),
    ("[expect.intervals]", '[expect.influences]\n"{key}" = "1"\n\n[expect.intervals]', None),
]
BAD_PAIRS = [
    ("a>b>c", 'write the pair as SENDER>ADDRESSEE, e.g. "a>b"'),
    ("ab", 'write the pair as SENDER>ADDRESSEE, e.g. "a>b"'),
    ("a>z", "unknown unit 'z' (units: a, b, c, d)"),
    ("b>b", "a unit does not address itself"),
]


@pytest.mark.parametrize(("key", "says"), BAD_PAIRS, ids=[k for k, _ in BAD_PAIRS])
@pytest.mark.parametrize(("old", "new", "section"), PAIR_SECTIONS, ids=lambda v: str(v)[:12])
def test_every_pair_key_is_read_one_way(old, new, section, key, says):
    """Every section keyed by "SENDER>ADDRESSEE" reads the key the same way and refuses a bad
    one in the same words, naming file, line and key ([influences] takes a key without ">"
    for a misspelt setting of its own)."""
    section = section or "expect.influences"
    if section == "influences" and ">" not in key:
        says = 'unknown key (allowed: policy, value, weights, or a pair "a>b")'
    text = mutate(old, new.format(key=key))
    line = next(i for i, t in enumerate(text.splitlines(), 1) if t.startswith(f'"{key}"'))
    with pytest.raises(RgtbusError) as err:
        parse_scenario(text, "scenarios/gate.toml")
    assert str(err.value) == f"scenarios/gate.toml:{line}: {section}.{key}: {says}"
