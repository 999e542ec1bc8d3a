"""Every output readable (issue 13): ``rgtbus unit`` prints a decision as ``rgtbus run`` does,
through the one rule ``rgtbus.cli.run_cmd.decision_text``."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest
import rgtbus.units.process
from hypothesis import given, settings
from hypothesis import strategies as st
from rgtbus.units.group import run_group
from rgtbus.units.launch import free_ports

from rgtbus.cli import main
from rgtbus.cli.run_cmd import decision_text
from rgtbus.scenario import load_scenario
from rgtbus.telemetry import MemoryRecorder

ROOT = Path(__file__).parent.parent
EXAMPLE2 = ROOT / "scenarios" / "example2.toml"


@pytest.fixture(scope="module")
def example2():
    """example2 run on the memory bus, and the decision lines ``rgtbus run`` prints for it."""
    sc = load_scenario(EXAMPLE2)
    summary = run_group(sc, "memory", MemoryRecorder()).summary
    return sc, summary


def words(text: str) -> str:
    """``text`` with every run of blanks as one space: ``run`` sets a decision's parts in the
    columns of a table, ``unit`` prints one on a line."""
    return " ".join(text.split())


def run_lines(capsys, sc, summary) -> dict[str, str]:
    """What ``rgtbus run``'s summary prints after each unit's canonical form, by unit, blanks
    as one space (``run`` sets the decisions in columns; ``unit`` prints one)."""
    from rgtbus.cli.run_cmd import print_summary

    print_summary(sc, {**summary, "log": "x"})
    text = capsys.readouterr().out
    block = text.split("decisions:\n")[1].split("outcome:")[0].split("decode errors")[0]
    lines = [line.strip() for line in block.splitlines() if line.strip()]
    out = {}
    for name in sc.units:
        canonical = summary["units"][name]["canonical"]
        line = next(x for x in lines if x.startswith(canonical))
        out[name] = words(line)
    return out


@pytest.mark.parametrize(
    ("fields", "expected"),
    [
        ({"decided": False, "frustrated": False}, "no decision"),
        ({"decided": True, "frustrated": True, "interval": None}, "frustrated: no decision"),
        (
            {"decided": True, "frustrated": False, "interval": [["alpha"], ["alpha"]]},
            "b = {alpha}  choice {alpha}",
        ),
        (
            {"decided": True, "frustrated": False, "interval": [[], ["alpha", "beta"]]},
            "1 ⊇ b ⊇ 0  choice {alpha}",
        ),
    ],
)
def test_decision_text_uses_set_notation(fields, expected):
    u = load_scenario(EXAMPLE2).universe
    v = {"choice": ["alpha"], "canonical": "b = b", **fields}
    assert decision_text(u, "b", v) == expected


def test_unit_prints_the_decision_line_of_run(example2, capsys, monkeypatch, tmp_path):
    """``rgtbus unit``'s own code path, its zenoh run replaced by the memory run's report."""
    sc, summary = example2
    expected = run_lines(capsys, sc, summary)
    previous = signal.getsignal(signal.SIGTERM)  # run_unit_cmd installs its own handler
    try:
        for name in sc.units:
            result = {
                "report": {"result": summary["units"][name], "polynomial": "a+bc", "p4": None},
                "steps": 1,
                "sim_seconds": 76.0,
                "wall_seconds": 0.1,
                "error": None,
            }
            monkeypatch.setattr(
                rgtbus.units.process,
                "run_units",
                lambda *a, _n=name, _r=result, **k: {_n: _r},
            )
            code = main(["unit", name, str(EXAMPLE2), "--log", str(tmp_path / f"{name}.mcap")])
            text = capsys.readouterr().out
            assert code == 0
            first, second = text.splitlines()
            assert words(first) == f"unit {name}: {expected[name]}"
            assert second.startswith("  polynomial a+bc; 1 steps")
            assert "['" not in text and "[[" not in text and "None" not in text
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_unit_over_zenoh_prints_like_run(example2, capsys, procs, tmp_path):
    """Three ``rgtbus unit`` processes on loopback: each prints run's decision line."""
    sc, summary = example2
    expected = run_lines(capsys, sc, summary)
    ports = free_ports(len(sc.units))
    started = {}
    for i, name in enumerate(sc.units):
        net = ["--listen", f"tcp/127.0.0.1:{ports[i]}"]
        for j in range(i):
            net += ["--connect", f"tcp/127.0.0.1:{ports[j]}"]
        started[name] = procs(
            "unit", name, str(EXAMPLE2), *net, "--log", str(tmp_path / f"{name}.mcap"),
            "--run-id", "outputs",
        )  # fmt: skip
    for name, p in started.items():
        out, err = p.communicate(timeout=120)
        assert p.returncode == 0, err
        first = out.splitlines()[0]
        assert words(first) == f"unit {name}: {expected[name]}"
        assert "['" not in out and "[[" not in out, out


# -- issue 21, item 6: what a new user saw -------------------------------------------------------

GATE = ROOT / "scenarios" / "gate.toml"


def _robots(n: int = 12) -> str:
    """A group of ``n`` units with names longer than the relation column (``Robo_10``)."""
    names = ", ".join(f'"Robo_{i}"' for i in range(1, n + 1))
    return f"""name = "robots"
seed = 5
units = [{names}]
actions = ["alpha", "beta"]
codebook = {{ kind = "generated", pulses = 4 }}
frequencies = "auto"

[protocol]
schedule = "concurrent"

[relations]
policy = "cograph"

[influences]
policy = "random"
"""


@pytest.fixture(scope="module")
def robots():
    from rgtbus.scenario import parse_scenario
    from rgtbus.telemetry import NullRecorder

    sc = parse_scenario(_robots(), "robots.toml")
    return sc, {**run_group(sc, "memory", NullRecorder()).summary, "log": "x"}


def test_readme_examples_name_one_log_not_a_glob():
    """``rgtbus info logs/gate-*.mcap`` fails once two gate logs exist: the README's commands
    name the log they wrote with ``--log``."""
    import re

    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```sh\n(.*?)```", text, re.S)
    commands = [line for b in blocks for line in b.splitlines() if line.startswith("rgtbus ")]
    assert commands
    for line in commands:
        args = line.split("#")[0].split()
        assert not [a for a in args if "*" in a and a.endswith(".mcap")], line
    logs = {a for line in commands for a in line.split() if a.startswith("logs/") and ".mcap" in a}
    written = {line.split("--log ")[1].split()[0] for line in commands if "--log " in line}
    assert logs <= written, logs - written  # every log read is one a command wrote


@pytest.mark.parametrize("command", [["cat"], ["replay"], ["info"], ["cat", "--topic", "/log"]])
def test_a_reader_that_stops_early_ends_the_command_quietly(tmp_path, command):
    """``rgtbus cat LOG | head -1``: exit 0, nothing on stderr (no traceback, no "Exception
    ignored" at exit), as ``git log | head`` does."""
    import subprocess
    import sys

    log = tmp_path / "gate.mcap"
    assert main(["run", str(GATE), "--bus", "memory", "--log", str(log), "--quiet"]) == 0
    proc = subprocess.Popen(
        [sys.executable, "-m", "rgtbus", command[0], str(log), *command[1:]],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None and proc.stderr is not None
    first = proc.stdout.readline()
    proc.stdout.close()  # the reader goes away, as head does after its line
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 0, err
    assert first and err == ""


def test_broken_pipe_in_process_returns_0(tmp_path, monkeypatch):
    """The same rule inside ``main``: a BrokenPipeError while printing is exit 0."""
    import io
    import sys

    log = tmp_path / "gate.mcap"
    assert main(["run", str(GATE), "--bus", "memory", "--log", str(log), "--quiet"]) == 0

    class Gone(io.StringIO):
        def write(self, s: str) -> int:
            raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(sys, "stdout", Gone())
    assert main(["cat", str(log)]) == 0
    assert main(["replay", str(log)]) == 0


def test_relations_table_aligns_long_names_and_fits_the_terminal(robots, capsys, monkeypatch):
    """12 units named ``Robo_N``: no name runs into its first cell (``Robo_1alliance``), no
    line of the summary is wider than the terminal: the 66 pairs become one line each."""
    from rgtbus.cli.run_cmd import print_summary

    sc, summary = robots
    monkeypatch.setenv("COLUMNS", "80")
    print_summary(sc, summary)
    out = capsys.readouterr().out
    assert "Robo_1alliance" not in out and "Robo_1conflict" not in out
    block = out.split("relationships decoded by each unit:\n")[1].split("  all units agree")[0]
    lines = block.splitlines()
    assert "one line a pair" in lines[0]
    assert len(lines) == 1 + 66 and all(len(line) <= 80 for line in lines)
    rel = summary["relations"]
    for line in lines[1:]:
        pair, value = line.split()[:2]
        assert rel[pair] == value  # every unit agrees: the relation alone
    assert all(len(line) <= 80 for line in out.split("influences")[1].splitlines()[:40])
    # canonical forms longer than the terminal: no column padding pushes the verdicts away
    decisions = out.split("decisions:\n")[1].split("decode errors")[0].splitlines()
    assert len(decisions) == 12 and not any("    " in line.strip() for line in decisions)

    monkeypatch.setenv("COLUMNS", "2000")  # wide enough: one row a unit, aligned
    print_summary(sc, summary)
    out = capsys.readouterr().out
    block = out.split("relationships decoded by each unit:\n")[1].split("  all units agree")[0]
    header, *rows = block.splitlines()
    assert len(rows) == 12
    col = header.index("Robo_1-Robo_2")
    for row, name in zip(rows, sc.units, strict=True):
        assert row.startswith(f"  {name} ") and row[col - 2 : col] == "  "
        assert row[col:].split()[0] in ("alliance", "conflict")


def test_relations_lines_name_the_units_that_differ():
    from rgtbus.cli.tables import relations_lines

    tables = {"a": {"a-b": "alliance", "a-c": "conflict", "b-c": "alliance"}, "b": None}
    tables["c"] = {**tables["a"], "a-b": "conflict"}
    wide = relations_lines(["a", "b", "c"], tables, missing="no report", width=200)
    assert wide[0].split() == ["a-b", "a-c", "b-c"]
    assert wide[2] == "  b  (no report)"
    narrow = relations_lines(["a", "b", "c"], tables, missing="no report", width=20)
    assert "  a-b  alliance: a; conflict: c" in narrow and "  b: (no report)" in narrow
    assert "  a-c  conflict" in narrow


def test_wide_matrix_is_cut_into_blocks_that_fit():
    from rgtbus.cli.tables import wrapped_table_lines

    names = [f"unit_{i:02d}" for i in range(12)]
    rows = [[a, *("{alpha,beta}" for _ in names)] for a in names]
    lines = wrapped_table_lines(rows, ["", *names], width=80)
    assert all(len(line) <= 80 for line in lines) and "" in lines
    blocks = "\n".join(lines).split("\n\n")
    assert len(blocks) > 1 and all(len(b.splitlines()) == 13 for b in blocks)
    shown = [h for b in blocks for h in b.splitlines()[0].split()]
    assert shown == names  # every column once, in order


_CELLS = st.text(alphabet=st.sampled_from(list("ab -*=()\n")), max_size=7)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.lists(_CELLS, min_size=1, max_size=5), min_size=1, max_size=4), st.booleans())
def test_plain_width_is_the_rendered_width_without_rendering(rows, with_headers):
    """What ``plain_width`` says is never wider than the table ``table_lines`` renders (so a
    table it finds too wide is), and is its width exactly for cells of one line each."""
    from rgtbus.cli.tables import plain_width, table_lines

    ncols = max(len(r) for r in rows)
    headers = [f"h{i}" for i in range(ncols)] if with_headers else []
    rows = [r + [""] * (ncols - len(r)) for r in rows] if with_headers else rows
    rendered = max((len(line) for line in table_lines(rows, headers)), default=0)
    assert plain_width(rows, headers) <= rendered
    if not any("\n" in c for r in rows for c in r):
        assert plain_width(rows, headers) == rendered


def test_a_table_that_cannot_fit_is_not_rendered(monkeypatch):
    """50 units: their relationship table (1,225 pairs) is one line a pair without being laid
    out first (it was, twice, only to be found too wide: a second of a run's summary), and the
    matrix is cut into blocks without laying out each trial block."""
    import rgtbus.cli.tables as tables

    rendered: list[int] = []
    real = tables.table_lines
    monkeypatch.setattr(
        tables,
        "table_lines",
        lambda rows, headers=(), **kw: rendered.append(len(rows)) or real(rows, headers, **kw),
    )
    units = [f"u{i:03d}" for i in range(50)]
    pairs = [f"{a}-{b}" for i, a in enumerate(units) for b in units[i + 1 :]]
    held = {u: dict.fromkeys(pairs, "alliance") for u in units}
    lines = tables.relations_lines(units, held, missing="no report", width=80)
    assert "  u000-u001  alliance" in lines and len(lines) == 1 + len(pairs)
    assert rendered == [len(pairs)]  # only the one-line-a-pair table
    rendered.clear()
    rows = [[a, *("{alpha,beta}" for _ in units)] for a in units]
    blocks = "\n".join(tables.wrapped_table_lines(rows, ["", *units], width=80)).split("\n\n")
    assert len(rendered) == len(blocks) > 1  # each block laid out once, nothing more


def test_plan_says_what_a_margin_not_met_means(capsys):
    """``over spacing`` said nothing: the word is gone, and each margin the plan does not keep
    says what that means and why the schedule allows it."""
    assert main(["plan", "12", "--schedule", "concurrent", "--no-crosstalk"]) == 0
    out = capsys.readouterr().out
    assert "over" not in out.replace("octave", "")
    lines = out.splitlines()
    at = next(i for i, line in enumerate(lines) if line.split()[:3] == ["not", "met", "spacing"])
    assert "(margin)" in lines[at]
    assert "margin not met, allowed" in lines[at + 1]
    assert "reads each code at its own pulse instants" in lines[at + 1]
    assert "rule: this schedule needs" in out or "the schedule needs them" in out
    assert main(["plan", "12"]) == 0  # serial: crosstalk spikes, logged and never acted on
    out = capsys.readouterr().out
    assert "crosstalk spikes" in out and "never acted on" in out


def _cut_gate(tmp_path: Path) -> Path:
    """The gate, stopped by ``timing.stop`` after its tables are complete: a failed run whose
    polynomial and agreement happen to be what ``[expect]`` says."""
    text = GATE.read_text().replace("guard = 0.5", 'guard = 0.5\nanchor = "schedule"')
    path = tmp_path / "cut.toml"
    path.write_text(text.replace("[timing]", "[timing]\nstop = 100", 1))
    return path


def test_check_after_a_failed_run_judges_nothing(tmp_path, capsys):
    import json

    path, log = _cut_gate(tmp_path), str(tmp_path / "cut.mcap")
    assert main(["run", str(path), "--bus", "memory", "--log", log, "--check"]) == 1
    out, err = capsys.readouterr()
    assert "all units agree: yes" in out  # the run got that far
    assert "ok   agree" not in out and "ok   polynomial" not in out and "FAIL" not in out
    assert "checks: not judged: the run failed (" in out and "run failed:" in err
    assert main(["run", str(path), "--bus", "memory", "--log", log, "--check", "--json"]) == 1
    checks = json.loads(capsys.readouterr().out)["checks"]
    assert checks and all(c["ok"] is None and "not judged" in c["detail"] for c in checks)
    assert main(["run", str(path), "--bus", "memory", "--log", log, "--check", "-q"]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.startswith("run failed:") and "check failed" not in err


# Every command that prints progress or results, and has --quiet (cat and scenario print the
# data they are asked for: that is no progress to silence; sweep and sweep-plot: their own).
QUIET = (
    "solve", "control", "run", "resonate", "figures", "plan", "replay", "merge", "info",
    "unit", "launch", "router", "watch",
)  # fmt: skip


def test_quiet_is_on_every_command_that_prints():
    from rgtbus.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for name in QUIET:
        p = sub.choices[name]
        assert any("--quiet" in a.option_strings for a in p._actions), name
        assert p.get_default("quiet_holds_stdout") is True, name


def test_quiet_prints_nothing_but_errors_and_json(tmp_path, capsys):
    import json

    log = str(tmp_path / "g.mcap")
    assert main(["run", str(GATE), "--bus", "memory", "--log", log, "--check", "--quiet"]) == 0
    assert capsys.readouterr() == ("", "")
    for argv in (
        ["info", log],
        ["replay", log],
        ["replay", log, "--verify"],
        ["replay", log, "--csv", str(tmp_path / "csv")],
        ["merge", log, "-o", str(tmp_path / "m.mcap")],
        ["plan", "5", "--no-crosstalk"],
        ["solve", "ab+c", "--actions", "x", "--symbolic"],
        ["resonate"],
    ):
        assert main([*argv, "--quiet"]) == 0, argv
        assert capsys.readouterr() == ("", ""), argv
    assert (tmp_path / "csv" / "decodes.csv").exists() and (tmp_path / "m.mcap").exists()
    assert main(["info", log, "--json", "--quiet"]) == 0
    assert json.loads(capsys.readouterr().out)["scenario"] == "gate"
    assert main(["info", str(tmp_path / "none.mcap"), "--quiet"]) == 2
    assert "No such file" in capsys.readouterr().err  # errors still say what went wrong


def test_run_quiet_prints_only_the_failed_checks(tmp_path, capsys):
    text = GATE.read_text().replace('outcome = "gate: open"', 'outcome = "gate: closed"')
    path = tmp_path / "g.toml"
    path.write_text(text)
    log = str(tmp_path / "g.mcap")
    assert main(["run", str(path), "--bus", "memory", "--log", log, "--check", "--quiet"]) == 1
    out, err = capsys.readouterr()
    assert out == ""
    assert err == "check failed: outcome: got 'gate: open', expected 'gate: closed'\n"


def test_run_progress_is_tqdm_on_a_terminal_only(tmp_path, monkeypatch, capsys):
    """The progress line is a tqdm counter on stderr, drawn when stderr is a terminal, and
    never with --quiet or --json."""
    import sys

    from rgtbus.cli import run_cmd

    shown = []
    real = run_cmd.Progress

    def spy(show: bool) -> run_cmd.Progress:
        shown.append(show)
        return real(show)

    monkeypatch.setattr(run_cmd, "Progress", spy)
    log = str(tmp_path / "g.mcap")
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    for extra, want in (([], True), (["--quiet"], False), (["--json"], False)):
        assert main(["run", str(GATE), "--bus", "memory", "--log", log, *extra]) == 0
        assert shown.pop() is want, extra
    monkeypatch.setattr(sys.stderr, "isatty", lambda: False)
    assert main(["run", str(GATE), "--bus", "memory", "--log", log]) == 0
    assert shown.pop() is False
    capsys.readouterr()

    bar = real(True)
    from tqdm import tqdm

    assert isinstance(bar.bar, tqdm) and not bar.bar.disable
    bar.bar.delay = 0.0
    bar.bar.mininterval = 0.0
    bar(12.5, 40)
    bar(20.0, 70)
    bar.done()
    err = capsys.readouterr().err
    assert "t = 20.0 s simulated, step 70" in err and err.endswith("\n")
    quiet = real(False)
    quiet(1.0, 1)
    quiet.done()
    assert capsys.readouterr().err == ""


def test_tables_stay_plain_in_a_pipe(tmp_path, capsys):
    """No colour codes, no trailing blanks, columns where the header puts them."""
    log = str(tmp_path / "g.mcap")
    assert main(["run", str(GATE), "--bus", "memory", "--log", log]) == 0
    outs = [capsys.readouterr().out]
    for argv in (["info", log], ["replay", log], ["plan", "6", "--no-crosstalk"], ["resonate"]):
        assert main(argv) == 0
        outs.append(capsys.readouterr().out)
    for out in outs:
        assert "\x1b[" not in out
        assert all(line == line.rstrip() for line in out.splitlines())
    info = outs[1].split("messages:")[1].splitlines()[1:]
    ends = {len(line.split("  rgtbus.")[0].split("  foxglove.")[0]) for line in info}
    assert len(ends) == 1  # message counts right-aligned in one column
