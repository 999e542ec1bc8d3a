"""Work is bounded before it starts (issue 22, item 6): the scenario loader and ``rgtbus plan``
estimate a run's size and refuse, naming the key and the estimate, what is beyond its budget
(docs/scenarios.md, "Budgets"); TOML nesting is bounded before tomllib recurses; scenario and
sweep files must be regular files; an ``[expect] dynamics`` the rounds cannot show is refused.

Each case below was a crash, a hang or gigabytes before (the numbers in each case). None of
them is run here: the expensive step is replaced by one that fails the test if it is reached,
so each refusal is shown to come before the work, whatever the machine's speed."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from rgtbus.units.sweep_spec import load_sweep

from rgtbus.cli import main
from rgtbus.errors import RgtbusError
from rgtbus.scenario import limits as limits_mod
from rgtbus.scenario import load, load_scenario, parse_scenario

ROOT = Path(__file__).resolve().parent.parent.parent
GATE = (ROOT / "scenarios" / "gate.toml").read_text()
EXE = [sys.executable, "-m", "rgtbus"]
NAME = "big.toml"
FREE_MB = 8192.0  # the free memory these tests give the machine (the loader asks the OS)


def reached(what: str):
    def fail(*args, **kwargs):
        raise AssertionError(f"{what} was reached: the refusal must come first")

    return fail


@pytest.fixture
def nothing_costly(monkeypatch):
    """The loader's costly steps (codebook search, frequency plan, groups) and any run fail
    the test if reached."""
    monkeypatch.delenv(limits_mod.BUDGET_ENV, raising=False)
    monkeypatch.setattr(limits_mod, "free_memory_mb", lambda: FREE_MB)
    for name in ("codebook_of", "frequencies_of", "relations_of"):
        monkeypatch.setattr(load, name, reached(name))
    import rgtbus.units.group

    monkeypatch.setattr(rgtbus.units.group, "run_group", reached("run_group"))


def group(n: int, extra: str = "", actions: str = '["go"]') -> str:
    units = json.dumps([f"u{i}" for i in range(n)])
    return (
        f'name = "big"\nunits = {units}\nactions = {actions}\n{extra}\n'
        '[relations]\npolicy = "cograph"\n[influences]\npolicy = "random"\n'
    )


def refused(text: str) -> str:
    with pytest.raises(RgtbusError) as err:
        parse_scenario(text, NAME)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{NAME}:"), msg
    return msg


def line_of(text: str, needle: str) -> int:
    return next(i for i, line in enumerate(text.splitlines(), 1) if needle in line)


def gate_with(old: str, new: str) -> str:
    assert old in GATE
    return GATE.replace(old, new, 1)


# -- the scenario loader -----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "key", "says"),
    [
        # SIGSEGV in encode_json within 5 s
        (
            gate_with("sample_rate = 200 ", "sample_rate = 1e9 "),
            "timing.sample_rate",
            "about 3.6e+12 samples (max_seconds × sample_rate), beyond the budget of 1e+09",
        ),
        # one window of 1e6 samples (at a short max_seconds): one bus frame, one /medium record
        (
            gate_with("sample_rate = 200 ", "sample_rate = 1e7 ").replace(
                "guard = 0.5", "guard = 0.5\nmax_seconds = 10", 1
            ),
            "timing.sample_rate",
            "about 1e+06 samples a bus window (window × sample_rate), beyond the budget of 1e+05",
        ),
        # beyond the free memory and the hour (where 16 units x 1000 rounds, and 100 units x
        # 1000 rounds in 40 min, now fit)
        (
            group(200, '[protocol]\nschedule = "concurrent"\ninfluence_rounds = 1000'),
            "protocol.influence_rounds",
            "1000 rounds of 200 units: about ",  # the figures: below
        ),
        (
            group(200, '[protocol]\nschedule = "concurrent"\ninfluence_rounds = 1000'),
            "protocol.influence_rounds",
            "of wall time (1.59e+10 decodes), more than the memory this machine has free "
            "(8,192 MB)",
        ),
        # MemoryError after 27 s
        (
            group(10_000),
            "units",
            "h of wall time (4e+12 decodes), more than the memory this machine has free (8,192 MB) "
            "and more than an hour",
        ),
        # 7.7 GB and rising before; 1,000 units would now take 7.8 GB and 80 min
        (
            group(1000, '[protocol]\nschedule = "concurrent"'),
            "units",
            "1000 units, 1 influence round(s): about ",
        ),
        # a hang beyond 120 s at load
        (
            group(
                2,
                'codebook = { kind = "generated", pulses = 8 }',
                json.dumps([f"a{i}" for i in range(14)]),
            ),
            "codebook",
            "generated for 14 actions at N = 8: about 1.35e+10 word comparisons",
        ),
    ],
    ids=[
        "sample_rate-1e9", "window", "rounds-1000", "rounds-figures", "cograph-10000", "n1000",
        "codebook-14",
    ],
)
def test_a_run_beyond_its_budget_is_refused_before_anything_is_built(
    nothing_costly, monkeypatch, text, key, says
):
    if key == "codebook":  # the codebook is read, its search is not started
        import rgtbus.scenario.codebook_section as cbs

        monkeypatch.setattr(load, "codebook_of", cbs.codebook_of)
        monkeypatch.setattr(cbs, "generate_codebook", reached("generate_codebook"))
    msg = refused(text)
    needle = {
        "timing.sample_rate": "sample_rate = ",
        "units": "units = ",
        "protocol.influence_rounds": "influence_rounds",
        "codebook": "codebook",
    }[key]
    assert msg.startswith(f"{NAME}:{line_of(text, needle)}: {key}: "), msg
    assert says in msg and "RGTBUS_BUDGET=large" in msg, msg


def test_the_cli_refuses_it_in_one_line_exit_2(nothing_costly, tmp_path, capsys):
    path = tmp_path / "big.toml"
    path.write_text(group(1000, '[protocol]\nschedule = "concurrent"'))
    code = main(["run", str(path), "--bus", "memory"])
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and err.count("\n") == 1
    assert err.startswith(f"rgtbus run: error: {path}:2: units: 1000 units"), err


def test_a_group_is_refused_only_beyond_the_free_memory_or_an_hour(monkeypatch):
    """The budget is the machine's: 200 and 300 units load by default where the memory is
    free, and the same group is refused on a machine without it, naming both figures."""
    monkeypatch.delenv(limits_mod.BUDGET_ENV, raising=False)
    monkeypatch.setattr(limits_mod, "free_memory_mb", lambda: FREE_MB)
    for n in (200, 300):
        est = limits_mod.run_estimate(n, 1)
        assert est.memory_mb < 1500 and est.seconds < 600, est
        assert limits_mod.over_run_budget(n, 1) is None
    monkeypatch.setattr(limits_mod, "free_memory_mb", lambda: 400.0)
    why = limits_mod.over_run_budget(300, 1)
    assert why is not None and "more than the memory this machine has free (400 MB)" in why
    assert "RGTBUS_BUDGET=large" in why and "min of wall time" in why
    monkeypatch.setattr(limits_mod, "free_memory_mb", lambda: None)  # unknown: the hour only
    assert limits_mod.over_run_budget(300, 1) is None
    assert "more than an hour" in (limits_mod.over_run_budget(1000, 1) or "")


@pytest.mark.parametrize(
    "channel",
    [
        "[channel]\nnoise = 0.01",
        '[channel]\ngain = { "u0>u1" = 0.5 }',
        "[channel.burst]\nnoise = 0.5\nevery = 10.0\nlength = 0.1",
    ],
    ids=["noise", "gain", "burst"],
)
def test_a_group_its_receivers_hear_differently_is_estimated_apart(
    nothing_costly, monkeypatch, channel
):
    """No receiver shares another's work on such a medium (a noisy 200-unit group took 10.2
    min and 1.5 GB with its log, where a clean one takes 16 s and 0.4 GB): its estimate is
    its own, and it is refused where that does not fit, saying why; the same group on a
    clean medium still loads."""
    monkeypatch.setattr(limits_mod, "free_memory_mb", lambda: 1000.0)
    differ = limits_mod.run_estimate(200, 1, alike=False)
    alike = limits_mod.run_estimate(200, 1)
    assert differ.memory_mb > 3 * alike.memory_mb and differ.seconds > 15 * alike.seconds
    text = group(200, '[protocol]\nschedule = "concurrent"', '["go", "stay"]') + channel
    msg = refused(text)
    assert msg.startswith(f"{NAME}:{line_of(text, 'units = ')}: units: 200 units, "), msg
    assert "about 1,469 MB at its peak and 12 min of wall time" in msg, msg
    assert "decodes, on a medium its receivers hear differently), more than the memory" in msg
    monkeypatch.setattr(load, "codebook_of", reached("codebook_of (the clean group loads)"))
    with pytest.raises(AssertionError, match="the clean group loads"):
        parse_scenario(text.replace(channel, ""), NAME)


def test_a_huge_group_with_positions_is_refused_before_its_link_gains_are_built(
    nothing_costly, monkeypatch
):
    """The channel's link gains are n² entries (10⁸ at 10,000 units): a group too large on
    any medium is refused before the channel is built."""
    import rgtbus.scenario.channel as channel_section

    monkeypatch.setattr(channel_section, "link_gains", reached("link_gains"))
    n = 10_000
    positions = "\n".join(f"u{i} = [{i}, 0]" for i in range(n))
    text = group(n) + f"[channel]\npath_loss = 2\n[channel.positions]\n{positions}\n"
    msg = refused(text)
    assert msg.startswith(f"{NAME}:{line_of(text, 'units = ')}: units: 10000 units"), msg


def test_a_channel_says_whether_its_receivers_hear_alike():
    from rgtbus.signal.channel import Burst, Channel, Clock

    assert Channel().alike and Channel(gains={("a", "b"): 1.0}).alike
    assert not Channel(noise=0.001).alike
    assert not Channel(burst=Burst(0.5, 10.0, 0.1)).alike
    assert not Channel(gains={("a", "b"): 0.5}).alike
    assert not Channel(speed=343.0, positions={"a": (0, 0, 0), "b": (1, 0, 0)}).alike
    assert not Channel(clocks={"a": Clock(0.1, 1.0)}).alike


def test_a_large_budget_is_asked_for_by_name(monkeypatch):
    monkeypatch.setattr(limits_mod, "free_memory_mb", lambda: FREE_MB)
    text = group(16, '[protocol]\nschedule = "concurrent"\ninfluence_rounds = 1000')
    monkeypatch.setenv("RGTBUS_BUDGET", "large")
    assert limits_mod.over_run_budget(100, 1000) is None  # within 100 × the budget
    why = limits_mod.over_run_budget(16, 10**9) or ""
    assert "(7.68e+12 decodes)" in why and "100 × the memory this machine has free" in why, why
    assert "more than 100 hours (beyond RGTBUS_BUDGET=large too" in why, why
    sc = parse_scenario(text.replace("1000", "2"), NAME)
    assert sc.protocol.influence_rounds == 2 and len(sc.units) == 16
    assert "beyond RGTBUS_BUDGET=large too" in refused(group(10_000))
    monkeypatch.setenv("RGTBUS_BUDGET", "huge")
    assert "RGTBUS_BUDGET='huge': unknown budget (default or large)" in refused(GATE)


@pytest.mark.parametrize("key", ["max_seconds", "guard", "reaction_delay", "start"])
def test_absurd_timing_values_are_refused_by_key(key):
    # max_seconds = 1e308 was an OverflowError (seconds -> nanoseconds)
    text = GATE.replace(f"\n{key} = ", f"\n# {key} = ", 1)  # the gate's own, if it sets it
    text = text.replace("[timing]\n", f"[timing]\n{key} = 1e308\n", 1)
    msg = refused(text)
    assert f"timing.{key}: must be at most 1e+09 s, got 1e+308" in msg, msg
    assert msg.startswith(f"{NAME}:{line_of(text, f'{key} = 1e308')}:"), msg


# -- TOML nesting and files --------------------------------------------------------------------


def test_nesting_is_bounded_before_tomllib_reads_it():
    # 5,000 nested [ was a RecursionError
    text = 'name = "x"\nunits = ["a", "b"]\nactions = ["go"]\nx = ' + "[" * 5000 + "]" * 5000
    assert refused(text) == f"{NAME}:4: nesting deeper than 32 (brackets and braces)"
    braces = 'name = "x"\nx = ' + "{a = " * 40 + "1" + "}" * 40
    assert refused(braces) == f"{NAME}:2: nesting deeper than 32 (brackets and braces)"
    dotted = 'name = "x"\nunits = ["a", "b"]\n' + "x" + ".a" * 3000 + " = 1\n"
    assert refused(dotted) == f"{NAME}:3: nesting deeper than 32 (a dotted key or table name)"
    # brackets in strings and comments are no nesting; a shipped-like depth loads
    fine = gate_with('description = "', 'description = "' + "[" * 100)
    fine = fine.replace('name = "gate"', 'name = "gate"  # ' + "{" * 100, 1)
    assert parse_scenario(fine, NAME).name == "gate"


def test_a_sweep_file_is_bounded_too(tmp_path):
    sweep = tmp_path / "deep.toml"
    sweep.write_text(
        f'name = "s"\nscenario = "{ROOT / "scenarios" / "gate.toml"}"\n[grid]\n'
        + "x = "
        + "[" * 5000
        + "]" * 5000
        + "\n"
    )
    with pytest.raises(RgtbusError, match=r"deep\.toml:4: nesting deeper than 32"):
        load_sweep(sweep)
    sweep.write_text(
        f'name = "s"\nscenario = "{ROOT / "scenarios" / "gate.toml"}"\n[grid]\n'
        + "a." * 3000
        + "b = [1]\n"
    )
    with pytest.raises(RgtbusError, match=r"deep\.toml:4: nesting deeper than 32"):
        load_sweep(sweep)


def test_fifos_are_refused_before_they_are_read(tmp_path):
    """A FIFO as a sweep's scenario hung for ever. Each case runs as its own process with a
    bound on its wait, so a regression fails the test instead of hanging it."""
    fifo = tmp_path / "fifo.toml"
    import os

    os.mkfifo(fifo)
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(f'name = "s"\nscenario = "{fifo}"\n[grid]\nn = [3]\n')
    cases = [
        (["sweep", str(sweep)], f"{sweep}:2: scenario: cannot read scenario '{fifo}': a FIFO"),
        (["sweep", str(fifo)], f"cannot read sweep '{fifo}': a FIFO, not a regular file"),
        (["run", str(fifo)], f"cannot read scenario '{fifo}': a FIFO, not a regular file"),
    ]
    for argv, says in cases:
        proc = subprocess.run([*EXE, *argv], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2 and proc.stdout == "", (argv, proc.stderr)
        assert proc.stderr.count("\n") == 1 and says in proc.stderr, proc.stderr


# -- [expect] dynamics -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("dynamics", "rounds", "needs"),
    [("cycle", 1, 3), ("cycle", 2, 3), ("fixed point", 1, 2), ("neither", 1, 2)],
)
def test_expected_dynamics_the_rounds_cannot_show_are_refused(dynamics, rounds, needs):
    text = gate_with("[timing]", f"[protocol]\ninfluence_rounds = {rounds}\n\n[timing]")
    text = text.replace("[expect]\n", f'[expect]\ndynamics = "{dynamics}"\n', 1)
    msg = refused(text)
    assert msg == (
        f"{NAME}:{line_of(text, 'dynamics =')}: expect.dynamics: {dynamics!r} shows only from "
        f"{needs} influence rounds, and the run has {rounds} (protocol.influence_rounds)"
    )
    enough = text.replace(f"influence_rounds = {rounds}", f"influence_rounds = {needs}")
    assert parse_scenario(enough, NAME).expect["dynamics"] == dynamics


# -- rgtbus plan -------------------------------------------------------------------------------


@pytest.fixture
def no_plan_work(monkeypatch):
    import rgtbus.signal.plan as plan_mod

    monkeypatch.delenv(limits_mod.BUDGET_ENV, raising=False)
    monkeypatch.setattr(limits_mod, "free_memory_mb", lambda: FREE_MB)
    monkeypatch.setattr(plan_mod, "crosstalk_peak", reached("crosstalk_peak"))
    return plan_mod


@pytest.mark.parametrize(
    ("args", "says"),
    [
        # 14 GB in 20 s
        (["4", "--sample-rate", "1e12"], "--sample-rate 1e+12: a run of this plan: about 3.6e+15"),
        # 9.6 GB after 10 minutes (and the concurrent schedule's placement, n³)
        (["10000"], "N = 10000: a run of this plan: about 654 GB at its peak"),
        (["10000", "--schedule", "concurrent"], "(4e+12 decodes), more than the memory this"),
        # StopIteration
        (["1000000"], "N = 1000000: a run of this plan: about 4.53e+06 GB at its peak"),
        # ZeroDivisionError
        (["4", "--sample-rate", "inf"], "--sample-rate inf: must be a positive finite number"),
        (["4", "--sample-rate", "nan"], "--sample-rate nan: must be a positive finite number"),
        (["4", "--pulses", "100000"], "--pulses 100000: must be an integer 1..10000"),
    ],
    ids=["rate-1e12", "n-10000", "n-10000-concurrent", "n-1e6", "rate-inf", "rate-nan", "pulses"],
)
def test_plan_refuses_before_it_plans(no_plan_work, monkeypatch, capsys, args, says):
    monkeypatch.setattr(no_plan_work, "make_plan", reached("make_plan"))
    code = main(["plan", *args])
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert err.startswith("rgtbus plan: error: ") and says in err, err


def test_plan_counts_its_crosstalk_simulation_first(no_plan_work, capsys):
    code = main(["plan", "100", "--schedule", "concurrent", "--sample-rate", "2e5"])
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert "the crosstalk simulation: about" in err and "--no-crosstalk" in err, err


def test_make_plan_refuses_what_it_cannot_plan():
    from rgtbus.signal.plan import make_plan

    with pytest.raises(RgtbusError, match="no code of up to 10000 pulses fits them"):
        make_plan(1_000_000, crosstalk=False)  # was StopIteration
    for tau in (0.0, float("inf"), float("nan"), -1.0):
        with pytest.raises(RgtbusError, match="the sample period must be positive and finite"):
            make_plan(4, tau=tau, crosstalk=False)


# -- what must still load ----------------------------------------------------------------------


def test_every_shipped_scenario_and_sweep_loads_within_the_budgets(monkeypatch):
    monkeypatch.delenv(limits_mod.BUDGET_ENV, raising=False)
    for path in sorted((ROOT / "scenarios").glob("*.toml")):
        assert load_scenario(path).name == path.stem
    for path in sorted((ROOT / "scenarios" / "sweeps").glob("*.toml")):
        assert load_sweep(path).runs > 0
    # the benchmarks' largest: 100 units on the concurrent schedule, 1e5 s at 200 samples/s
    bench = group(100, '[protocol]\nschedule = "concurrent"\n[timing]\nmax_seconds = 100000.0')
    assert len(parse_scenario(bench, NAME).units) == 100
    assert main(["plan", "50", "--schedule", "concurrent", "--json"]) == 0
