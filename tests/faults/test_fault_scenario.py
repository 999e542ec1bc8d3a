"""Bad scenario files are refused at load, before any simulation, in one line that names the
file, the line and the key (issue #10, item 1)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from rgtbus.cli import main
from rgtbus.errors import RgtbusError
from rgtbus.scenario import load_scenario, parse_scenario

ROOT = Path(__file__).resolve().parent.parent.parent
GATE = ROOT / "scenarios" / "gate.toml"
OVERVIEW = ROOT / "scenarios" / "overview.toml"


def edit(path: Path, old: str, new: str) -> str:
    text = path.read_text()
    assert old in text, old
    return text.replace(old, new, 1)


def refused(text: str, name: str = "scenarios/x.toml") -> str:
    with pytest.raises(RgtbusError) as err:
        parse_scenario(text, name)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(name), msg
    return msg


def line_of(text: str, needle: str) -> int:
    return next(i for i, t in enumerate(text.splitlines(), 1) if needle in t)


# -- the file itself -------------------------------------------------------------------------


def test_non_utf8_file_names_the_byte_and_line(tmp_path, capsys):
    path = tmp_path / "latin1.toml"
    path.write_bytes(GATE.read_bytes().replace(b'"gate"', b'"g\xe2te"', 1))
    with pytest.raises(RgtbusError) as err:
        load_scenario(path)
    line = line_of(GATE.read_text(), 'name = "gate"')
    assert str(err.value) == (
        f"{path}:{line}: not a UTF-8 text file (byte 0xe2 at line {line}, column 10)"
    )
    assert main(["run", str(path), "--bus", "memory"]) == 2
    out, errtext = capsys.readouterr()
    assert out == "" and errtext.count("\n") == 1 and "Traceback" not in errtext


def test_binary_file_is_refused(tmp_path):
    path = tmp_path / "bin.toml"
    path.write_bytes(b"\x7fELF\x02\x01\x01\x00\x00\x00\x00\x80\n\x81")
    with pytest.raises(RgtbusError, match=r"bin\.toml:1: not a UTF-8 text file \(byte 0x80 at"):
        load_scenario(path)
    path.write_bytes(b'name = "x"\n\x00\x00\x00')  # valid UTF-8, but NULs: binary
    with pytest.raises(RgtbusError, match=r"bin\.toml:2: a binary file, not a scenario"):
        load_scenario(path)


def test_directory_and_device_are_refused(tmp_path):
    with pytest.raises(RgtbusError, match=r"^cannot read scenario '.*': is a directory$"):
        load_scenario(tmp_path)
    with pytest.raises(RgtbusError, match=r"embedded null byte"):
        load_scenario("gate\0.toml")
    if Path("/dev/zero").exists():  # endless: must be refused before reading
        with pytest.raises(RgtbusError, match=r"'/dev/zero': not a regular file$"):
            load_scenario("/dev/zero")


def test_invalid_toml_names_its_line():
    text = edit(GATE, "seed = 3", "seed = = 3")
    msg = refused(text)
    assert msg.startswith(f"scenarios/x.toml:{line_of(text, 'seed = = 3')}: not valid TOML")


# -- [timing]: each key blamed by its own name -------------------------------------------------

TIMING = [
    ("reaction_delay = 0.5", "reaction_delay = -0.5", "reaction_delay: must be positive, got -0.5"),
    ("reaction_delay = 0.5", "reaction_delay = inf", "reaction_delay: must be a finite number"),
    ("reaction_delay = 0.5", "reaction_delay = nan", "reaction_delay: must be a finite number"),
    ("reaction_delay = 0.5", 'reaction_delay = "1s"', "reaction_delay: must be a finite number"),
    ("guard = 0.5", "guard = 0", "guard: must be positive, got 0: the next ID's first pulse"),
    ("guard = 0.5", "guard = 0.001", "guard: guard 0.001 s is shorter than one sample"),
    ("start = 0.001", "start = -1", "start: must not be negative, got -1"),
    ("sample_rate = 200", "sample_rate = 0", "sample_rate: must be positive, got 0"),
    ("sample_rate = 200", "sample_rate = true", "sample_rate: must be a finite number"),
    ("window = 0.1", "window = 0", "window: must be positive, got 0"),
    ("window = 0.1", "window = 0.6", "window: 0.6 s exceeds the reaction delay 0.5 s"),
    ("window = 0.1", "window = 1e308", "window: must be a positive whole number of samples"),
    ("guard = 0.5", "guard = 0.5\nmax_seconds = 0", "max_seconds: must be positive, got 0"),
    ("guard = 0.5", "guard = 0.5\nmax_seconds = -inf", "max_seconds: must be a finite number"),
]


@pytest.mark.parametrize(("old", "new", "expect"), TIMING, ids=[t[1] for t in TIMING])
def test_each_timing_key_is_checked_on_its_own(old, new, expect):
    text = edit(GATE, old, new)
    msg = refused(text)
    bad_line = new.splitlines()[-1]
    assert f"x.toml:{line_of(text, bad_line)}: timing.{expect}" in msg, msg


def test_cross_key_timing_rules_blame_a_key_the_file_sets():
    # reaction_delay below the default window: the file never set the window, so blame the delay
    text = edit(GATE, "window = 0.1            # 20 samples", "#")
    text = text.replace("reaction_delay = 0.5", "reaction_delay = 0.05")
    assert "timing.reaction_delay: 0.05 s is shorter than the window 0.1 s (default" in refused(
        text
    )
    # a sample rate that makes the default window a fraction of a sample
    text = edit(GATE, "window = 0.1            # 20 samples", "#").replace(
        "sample_rate = 200", "sample_rate = 333"
    )
    assert "timing.sample_rate: 333 samples/s makes the window 0.1 s (default)" in refused(text)
    msg = refused(edit(GATE, "start = 0.001", "start = 10\nmax_seconds = 5"))
    assert "timing.start: start 10 s is not before max_seconds 5 s" in msg


def test_guard_of_one_sample_still_loads():
    sc = parse_scenario(edit(GATE, "guard = 0.5", "guard = 0.005"))
    assert sc.timing.guard == sc.timing.tau == 0.005


# -- [channel] -------------------------------------------------------------------------------

NOISE = "channel.noise: must be a standard deviation >= 0 and finite (at most 1000), got"
GAIN = "channel.gain.a>b: gain must be a finite number > 0 (at most 1000), got"
CHANNEL = [
    ("noise = inf", f"{NOISE} inf"),
    ("noise = nan", f"{NOISE} nan"),
    ("noise = -0.1", f"{NOISE} -0.1"),
    ("noise = 1e200", f"{NOISE} 1e+200"),  # finite, but overflows the resonators mid-run
    ('noise = "loud"', f"{NOISE} 'loud'"),
    ('noise = 0.0\n[channel.gain]\n"a>b" = inf', f"{GAIN} inf"),
    ('noise = 0.0\n[channel.gain]\n"a>b" = nan', f"{GAIN} nan"),
    ('noise = 0.0\n[channel.gain]\n"a>b" = -1', f"{GAIN} -1"),
    ('noise = 0.0\n[channel.gain]\n"a>b" = 1e200', f"{GAIN} 1e+200"),
    ('noise = 0.0\n[channel.gain]\n"a>b" = "x"', f"{GAIN} 'x'"),
]


@pytest.mark.parametrize(("new", "expect"), CHANNEL, ids=[c[0].split("\n")[-1] for c in CHANNEL])
def test_channel_values_name_file_line_and_key(new, expect):
    text = edit(GATE, "noise = 0.0", new)
    msg = refused(text)
    assert msg == f"scenarios/x.toml:{line_of(text, new.splitlines()[-1])}: {expect}"


# -- fixed relations forming an induced P4 ---------------------------------------------------


def test_fixed_relations_with_an_induced_p4_are_refused_at_load(tmp_path, capsys):
    # alliances a-b, b-c, c-d only (both ways); every other pair in conflict
    allied = {("a", "b"), ("b", "c"), ("c", "d")}
    text = GATE.read_text().replace('polynomial = "abc+d"\n', "")
    for s in "abcd":
        for r in "abcd":
            if s != r:
                rel = "alliance" if (min(s, r), max(s, r)) in allied else "conflict"
                text = re.sub(rf'^"{s}>{r}" = "\w+"$', f'"{s}>{r}" = "{rel}"', text, flags=re.M)
    path = tmp_path / "p4.toml"
    path.write_text(text)
    with pytest.raises(RgtbusError) as err:
        load_scenario(path)
    assert str(err.value) == (
        f"{path}:{line_of(text, '[relations.fixed]')}: relations.fixed: policy fixed: "
        "relationship graph is not decomposable: induced P4 a-b-c-d "
        "(alliances a-b, b-c, c-d; conflicts a-c, a-d, b-d)"
    )
    # refused before any simulation: no log is written
    log = tmp_path / "p4.mcap"
    assert main(["run", str(path), "--bus", "memory", "--log", str(log)]) == 2
    assert not log.exists() and "induced P4 a-b-c-d" in capsys.readouterr().err


# -- [expect] --------------------------------------------------------------------------------

FRUSTRATED = "[expect.frustrated]"


def rel(line: str) -> str:
    """An [expect.relations] table with one line, before [expect.frustrated]."""
    return f"[expect.relations]\n{line}\n{FRUSTRATED}"


EXPECT = [
    (GATE, 'a = "[1,1]"', 'a = "[2,1]"', "expect.intervals.a: bad alternative '2'"),
    (GATE, 'a = "[1,1]"', 'a = "[1,0]"', "expect.intervals.a: empty interval '[1,0]'"),
    (GATE, 'a = "[1,1]"', 'a = "[1,1"', "expect.intervals.a: bad alternative '[1,1'"),
    (GATE, 'a = "[1,1]"', "a = 1", 'expect.intervals.a: must be a string ("[LOW,HIGH]"), got 1'),
    (GATE, 'a = "[1,1]"', 'z = "[1,1]"', "expect.intervals.z: unknown unit 'z'"),
    (GATE, 'a = "1"', 'a = "{fly}"', "expect.choices.a: unknown action 'fly'"),
    (GATE, 'a = "1"', "a = true", "expect.choices.a: must be a string (an alternative), got True"),
    (GATE, "agree = true", 'agree = "yes"', "expect.agree: must be true or false, got 'yes'"),
    (GATE, 'polynomial = "abc+d"', 'polynomial = "ab(c+d"', "expect.polynomial: missing ')'"),
    (GATE, 'polynomial = "abc+d"', 'polynomial = "abc+e"', "expect.polynomial: subjects"),
    (GATE, 'polynomial = "abc+d"', 'polynomial = "abc"', "expect.polynomial: subjects"),
    (GATE, 'polynomial = "abc+d"', "polynomial = 4", "expect.polynomial: must be a string"),
    (GATE, 'outcome = "gate: open"', "outcome = 1", "expect.outcome: must be a string, got 1"),
    (GATE, 'outcome = "gate: open"', 'outcome = "ajar"', "expect.outcome: 'ajar' is not an"),
    (OVERVIEW, "a = true", 'a = "yes"', "expect.frustrated.a: must be true or false, got 'yes'"),
    (OVERVIEW, "a = true", "a = 1", "expect.frustrated.a: must be true or false, got 1"),
    (OVERVIEW, "a = true", "x = true", "expect.frustrated.x: unknown unit 'x'"),
    (OVERVIEW, FRUSTRATED, rel('"a-b" = "allied"'),
     "expect.relations.a-b: must be \"alliance\" or \"conflict\", got 'allied'"),
    (OVERVIEW, FRUSTRATED, rel('"a+b" = "alliance"'), "expect.relations.a+b: write the pair as"),
    (OVERVIEW, FRUSTRATED, rel('"a-q" = "alliance"'), "expect.relations.a-q: unknown unit 'q'"),
    (OVERVIEW, FRUSTRATED, rel('"a-a" = "alliance"'), "expect.relations.a-a: a unit has no rel"),
    (OVERVIEW, "agree = true", 'agree = true\noutcome = "gate: open"',
     "expect.outcome: the scenario has no [outcome] rule"),
]  # fmt: skip


@pytest.mark.parametrize(("path", "old", "new", "expect"), EXPECT, ids=[e[2] for e in EXPECT])
def test_expect_is_validated_at_load(path, old, new, expect):
    text = edit(path, old, new)
    msg = refused(text)
    bad = new.splitlines()[1 if new.startswith("[") else -1]
    assert f"x.toml:{line_of(text, bad)}: {expect}" in msg, msg


def test_expect_polynomial_and_pairs_are_stored_as_a_run_prints_them():
    text = edit(GATE, 'polynomial = "abc+d"', 'polynomial = "d + c(ba)"')
    text += '[expect.relations]\n"b-a" = "alliance"\n"d-c" = "conflict"\n'
    sc = parse_scenario(text)
    assert sc.expect["polynomial"] == "abc+d"
    assert sc.expect["relations"] == {"a-b": "alliance", "c-d": "conflict"}
    msg = refused(text + '"a-b" = "conflict"\n')
    assert "expect.relations.a-b: the pair a-b is given twice" in msg


# -- what the fuzzer found -------------------------------------------------------------------

FOUND = [
    ('"d>a" = "1"', '"d>a" = [[]]', "influences.d>a: bad alternative [[]]: a list of action names"),
    ('codebook = "paper"', 'codebook = {kind = "generated", seed = "x"}', "codebook.seed: must"),
    ('codebook = "paper"', 'codebook = {kind = "generated", seed = -1}', "codebook.seed: must"),
    ('codebook = "paper"', 'codebook = {kind = "generated", min_distance = "x"}', "codebook.min"),
    ('codebook = "paper"', 'codebook = {kind = "generated", pulses = 9999999999}', "codebook.puls"),
    ('codebook = "paper"', 'codebook = {kind = "paper", names = 3}', "codebook.names: must be"),
    ('codebook = "paper"', 'codebook = {kind = "paper", colour = 3}', "codebook.colour: unknown"),
]  # fmt: skip


@pytest.mark.parametrize(("old", "new", "expect"), FOUND, ids=[f[1] for f in FOUND])
def test_fuzzer_findings_are_refused_by_key(old, new, expect):
    text = edit(GATE, old, new)
    assert f"x.toml:{line_of(text, new)}: {expect}" in refused(text)


def test_generated_codebook_counts_before_it_enumerates():
    # N = 200 once enumerated 2**199 candidates (the step was sized on another grid): a hang
    code = (
        "from rgtbus.errors import RgtbusError\n"
        "from rgtbus.signal.codebook import generate_codebook\n"
        "try:\n    generate_codebook(['alpha', 'beta'], pulses=200)\n"
        "except RgtbusError as e:\n    print(e)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert proc.stdout.startswith("codebook generator: ") and proc.stderr == ""
