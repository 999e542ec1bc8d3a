"""A fuzzer for scenario files: whatever the bytes, loading returns a ``Scenario`` or raises
``RgtbusError`` with one line naming the file; no other exception may escape (issue #10)."""

from __future__ import annotations

import json
import math
import tempfile
import tomllib
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rgtbus.errors import RgtbusError
from rgtbus.scenario import (
    CHANNEL_KEYS,
    DECISION_KEYS,
    EXPECT_KEYS,
    OUTCOME_KEYS,
    RELATION_KEYS,
    TIMING_KEYS,
    TOP_KEYS,
    Scenario,
    load_scenario,
    parse_scenario,
)

ROOT = Path(__file__).resolve().parent.parent.parent
SHIPPED = {p.stem: p.read_text() for p in sorted((ROOT / "scenarios").glob("*.toml"))}
NAME = "fuzz/scenario.toml"
FUZZ = settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


def check(text: str) -> None:
    """The property: a Scenario, or an RgtbusError in one line that names the file."""
    try:
        sc = parse_scenario(text, NAME)
    except RgtbusError as exc:
        msg = str(exc)
        assert msg and "\n" not in msg and "\r" not in msg, repr(msg)
        assert msg.startswith(NAME), msg
        return
    assert isinstance(sc, Scenario)


# -- random bytes, through the file reader -----------------------------------------------------


@FUZZ
@given(data=st.one_of(st.binary(max_size=400), st.text(max_size=300).map(str.encode)))
def test_random_bytes(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "scenario.toml"
        path.write_bytes(data)
        try:
            sc = load_scenario(path)
        except RgtbusError as exc:
            msg = str(exc)
            assert "\n" not in msg and "\r" not in msg and str(path) in msg, repr(msg)
            return
        assert isinstance(sc, Scenario)


# -- shipped scenarios, mutated as text ----------------------------------------------------

TOKENS = st.sampled_from(
    [
        "=",
        "[",
        "]",
        "[[",
        '"',
        "'",
        "{",
        "}",
        ",",
        "#",
        "\n",
        "inf",
        "-inf",
        "nan",
        "0",
        "-1",
        "1e309",
        "true",
        '"auto"',
        "[timing]",
        "[expect.intervals]",
        '"a>a"',
        '"a>b"',
        "{}",
        "[]",
        "\\u0000",
        "\\",
        "\t",
        "é",
        "\x00",
    ]
)


@st.composite
def mutated(draw: st.DrawFn) -> str:
    lines = draw(st.sampled_from(sorted(SHIPPED))).split("\n")
    hit = lines[:]  # keep the index valid as lines come and go
    for _ in range(draw(st.integers(1, 4))):
        if not hit:
            hit = ['name = "x"']
        i = draw(st.integers(0, len(hit) - 1))
        op = draw(st.sampled_from(["delete", "duplicate", "value", "insert", "cut", "swap"]))
        if op == "delete":
            del hit[i]
        elif op == "duplicate":
            hit.insert(i, hit[i])
        elif op == "value" and "=" in hit[i]:
            key = hit[i].split("=", 1)[0]
            hit[i] = key + "= " + draw(st.one_of(TOKENS, st.text(max_size=12)))
        elif op == "insert":
            pos = draw(st.integers(0, len(hit[i])))
            hit[i] = hit[i][:pos] + draw(st.one_of(TOKENS, st.text(max_size=6))) + hit[i][pos:]
        elif op == "cut":
            hit[i] = hit[i][: draw(st.integers(0, len(hit[i])))]
        else:
            j = draw(st.integers(0, len(hit) - 1))
            hit[i], hit[j] = hit[j], hit[i]
    return "\n".join(hit)


@FUZZ
@given(text=mutated())
def test_mutated_shipped_scenarios(text: str) -> None:
    check(text)


# -- every known key given a random value ----------------------------------------------------

SCALARS = st.one_of(
    st.integers(-(2**63), 2**63 - 1),
    st.sampled_from([0, 1, 2, -1, 3, 20, 200, 1000]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 0.005, 0.1, 0.5, 1e-300, 1e300, math.inf, -math.inf, math.nan]),
    st.booleans(),
    st.text(max_size=10),
    st.sampled_from(
        [
            "auto",
            "paper",
            "exact",
            "fixed",
            "random",
            "max",
            "min",
            "seeded-random",
            "spike",
            "schedule",
            "1",
            "0",
            "{}",
            "{alpha}",
            "{open}",
            "[0,1]",
            "[1,0]",
            "3pi/2",
            "0pi",
            "alliance",
            "conflict",
            "generated",
            "custom",
            "a+b",
            "ab+c",
            "a>b",
            "gate: open",
            "",
        ]
    ),
)
NAMES = st.lists(st.sampled_from(["a", "b", "c", "d", "e", "alpha", "beta", "open", "a b"]))
VALUES = st.recursive(
    st.one_of(SCALARS, NAMES),
    lambda inner: st.one_of(
        st.lists(inner, max_size=4),
        st.dictionaries(st.sampled_from(["a", "b", "a>b", "b>a", "a-b", "x", "kind"]), inner),
    ),
    max_leaves=8,
)
SECTIONS = {
    "timing": TIMING_KEYS,
    "channel": CHANNEL_KEYS,
    "relations": RELATION_KEYS,
    "decision": DECISION_KEYS,
    "outcome": OUTCOME_KEYS,
    "expect": EXPECT_KEYS,
    "codebook": {"kind", "names", "pulses", "min_distance", "seed", "id", "relation"},
    "frequencies": {"a", "b", "c", "d"},
    "influences": {"a>b", "b>a", "a>a", "c>d"},
}
KEY_PATHS = sorted([(k,) for k in TOP_KEYS] + [(s, k) for s, ks in SECTIONS.items() for k in ks])


def toml_string(s: str) -> str:
    # JSON escapes are TOML escapes; TOML also wants DEL escaped
    return json.dumps(s, ensure_ascii=False).replace("\x7f", "\\u007f")


def toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return toml_string(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return "{" + ", ".join(f"{toml_string(k)} = {toml_value(x)}" for k, x in v.items()) + "}"


def to_toml(data: dict[str, Any]) -> str:
    """Scalars and lists at the top, then one [table] per dict (nested dicts inline)."""
    out = [
        f"{toml_string(k)} = {toml_value(v)}" for k, v in data.items() if not isinstance(v, dict)
    ]
    for k, v in data.items():
        if isinstance(v, dict):
            out.append(f"[{toml_string(k)}]")
            out += [f"{toml_string(kk)} = {toml_value(vv)}" for kk, vv in v.items()]
    return "\n".join(out) + "\n"


@st.composite
def with_random_values(draw: st.DrawFn) -> str:
    data = tomllib.loads(SHIPPED[draw(st.sampled_from(sorted(SHIPPED)))])
    for path in draw(st.lists(st.sampled_from(KEY_PATHS), min_size=1, max_size=3)):
        value = draw(VALUES)
        if len(path) == 1:
            data[path[0]] = value
        else:
            section = data.get(path[0])
            if not isinstance(section, dict):
                section = data[path[0]] = {}
            section[path[1]] = value
    return to_toml(data)


def test_the_toml_writer_round_trips_the_shipped_scenarios():
    for text in SHIPPED.values():
        data = tomllib.loads(text)
        assert tomllib.loads(to_toml(data)) == data
        assert isinstance(parse_scenario(to_toml(data), NAME), Scenario)


@FUZZ
@given(text=with_random_values())
def test_random_values_for_every_known_key(text: str) -> None:
    check(text)
