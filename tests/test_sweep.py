"""Sweeps: sweep files, the results table, resume, errors as rows, Dask, plots."""

from __future__ import annotations

import json
import re
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from rgtbus.units import sweep as sweep_mod
from rgtbus.units.sweep import load_sweep, run_sweep, table_rows
from rgtbus.units.sweep_spec import TABLES_VERSION

from rgtbus.cli import main
from rgtbus.errors import RgtbusError

ROOT = Path(__file__).resolve().parent.parent

SWEEP = """
name = "tiny"
scenario = "{scenario}"
seeds = "0..2"
[grid]
n = [3, 4]
"relations.p" = [0.61]
"""


def write_sweep(tmp_path: Path, body: str = SWEEP) -> Path:
    path = tmp_path / "tiny.toml"
    path.write_text(body.replace("{scenario}", str(ROOT / "scenarios" / "random_group.toml")))
    return path


def table(out: Path) -> list[dict]:
    """A sweep's results, less what differs between two runs of one sweep (wall time) or
    between two sweep files of the same runs (the sweep's id in its name)."""
    rows = table_rows(pq.read_table(out / "results.parquet"))
    for r in rows:
        for key in ("wall_seconds", "sweep", "run_id"):
            r.pop(key)
    return rows


def test_a_sweep_gives_one_row_per_run_in_parquet_and_csv(tmp_path, capsys):
    path = write_sweep(tmp_path)
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out), "--workers", "2", "--quiet"]) == 0
    assert "6 runs (0 ended with an error)" in capsys.readouterr().out
    rows = table(out)
    assert [(r["n"], r["seed"]) for r in rows] == [(3, 0), (3, 1), (3, 2), (4, 0), (4, 1), (4, 2)]
    r = rows[0]
    for col in (
        "relations.p",
        "digest",
        "engine",
        "schedule",
        "decomposable",
        "p4",
        "agree",
        "polynomial",
        "frustrated",
        "error",
        "decode_errors",
        "units",
        "outcome",
    ):
        assert col in r
    assert r["engine"] == "event" and r["schedule"] == "concurrent" and r["error"] is None
    assert [u["unit"] for u in r["units"]] == ["u1", "u2", "u3"]
    assert (out / "results.csv").read_text().count("\n") == 7
    assert json.loads((out / "sweep.json").read_text())["runs"] == 6
    assert (out / "sweep.toml").read_text() == path.read_text()
    # each row is the run of the same scenario and seed on its own
    assert main(["sweep", str(path), "--out", str(out), "--quiet"]) == 2  # no silent overwrite
    assert "--resume" in capsys.readouterr().err


def test_a_sweep_killed_halfway_resumes_with_only_what_is_missing(tmp_path):
    path = write_sweep(tmp_path)
    sw = load_sweep(path)
    full, part = tmp_path / "full", tmp_path / "part"
    with ThreadPoolExecutor(1) as ex:
        run_sweep(sw, full, executor=ex, workers=1)
        run_sweep(sw, part, executor=ex, workers=1)
    lines = (part / "rows.jsonl").read_text().splitlines()
    (part / "rows.jsonl").write_text("\n".join(lines[:2]) + "\n" + lines[2][:30])  # cut mid-line
    (part / "results.parquet").unlink()
    ran = []
    real = sweep_mod.run_row
    with ThreadPoolExecutor(1) as ex:
        sweep_mod.run_row = lambda s, t, d=None: ran.append(t.index) or real(s, t, d)
        try:
            run_sweep(sw, part, executor=ex, workers=1, resume=True)
        finally:
            sweep_mod.run_row = real
    assert ran == [2, 3, 4, 5]
    assert table(part) == table(full)


def test_a_run_that_raises_is_a_row_with_its_error(tmp_path, monkeypatch):
    import rgtbus.units.group

    calls = []

    def boom(sc, *a, **k):
        calls.append(sc.seed)
        if sc.seed == 1:
            raise ZeroDivisionError("division by zero")
        return real(sc, *a, **k)

    real = rgtbus.units.group.run_group
    monkeypatch.setattr(rgtbus.units.group, "run_group", boom)
    with ThreadPoolExecutor(1) as ex:
        rows = run_sweep(load_sweep(write_sweep(tmp_path)), tmp_path / "o", executor=ex, workers=1)
    assert len(rows) == 6 and sorted(calls) == [0, 0, 1, 1, 2, 2]
    bad = [r for r in rows if r["failed"]]
    assert [r["seed"] for r in bad] == [1, 1]
    assert bad[0]["error"].startswith("ZeroDivisionError: division by zero (at test_sweep.py:")


def test_runs_that_fail_are_rows_too(tmp_path, capsys):
    body = SWEEP.replace('"relations.p" = [0.61]', '"timing.stop" = [2.0]')
    out = tmp_path / "o"
    assert main(["sweep", str(write_sweep(tmp_path, body)), "--out", str(out), "--quiet"]) == 0
    rows = table(out)
    assert len(rows) == 6 and all(r["failed"] for r in rows)
    assert all("timing.stop" in r["error"] for r in rows)


@pytest.mark.parametrize(
    "body, where, says",
    [
        ('scenario = "{scenario}"\nsedes = "0..3"\n', ":2: sedes: unknown key", "allowed"),
        ('scenario = "{scenario}"\nseeds = "5..1"\n', ":2: seeds: empty range", "LAST < FIRST"),
        ('scenario = "{scenario}"\nseeds = [1, -2]\n', ":2: seeds:", "-2"),
        ('scenario = "nowhere.toml"\n', ":1: scenario: cannot read", "nowhere.toml"),
        (
            'scenario = "{scenario}"\n[grid]\n"relations.p" = [0.5, 1.5]\n',
            ":3: relations.p:",
            "value 1.5",
        ),
        ('scenario = "{scenario}"\n[grid]\nn = [3, 0]\n', ":3: n: value 0", "1..200"),
        ('scenario = "{scenario}"\n[grid]\nengine = ["fast"]\n', ":3: engine:", "'fast'"),
        (
            'scenario = "{scenario}"\n[grid]\n"relations.q" = [1]\n',
            ":3: relations.q:",
            "unknown key",
        ),
        ('scenario = "{scenario}"\n[grid]\nn = 3\n', ":3: n: must be a non-empty list", "3"),
        ('scenario = "{scenario}"\nseeds = \n', ":2: not valid TOML", ""),
        ('scenario = "{scenario}"\n[grid]\nseed = [1, 2]\n', ":3: seed:", "seeds key"),
        ('scenario = "/"\n', ":1: scenario: cannot read scenario '/'", "is a directory"),
    ],
)
def test_bad_sweep_files_are_refused_with_file_line_and_key(tmp_path, capsys, body, where, says):
    path = write_sweep(tmp_path, body)
    assert main(["sweep", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path}{where}" in err and says in err
    assert not (tmp_path / "o").exists()


@pytest.mark.slow  # a local cluster starts in 2 s: CI's slow pass
def test_the_same_table_on_a_dask_local_cluster(tmp_path, capsys):
    distributed = pytest.importorskip("distributed")
    path = write_sweep(tmp_path)
    main(["sweep", str(path), "--out", str(tmp_path / "pool"), "--workers", "2", "--quiet"])
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        code = main(
            [
                "sweep",
                str(path),
                "--out",
                str(tmp_path / "dask"),
                "--quiet",
                "--scheduler",
                cluster.scheduler_address,
            ]
        )
    assert code == 0
    assert table(tmp_path / "dask") == table(tmp_path / "pool")


def test_sweep_plot_draws_a_metric_with_intervals(tmp_path, capsys):
    out = tmp_path / "o"
    main(["sweep", str(write_sweep(tmp_path)), "--out", str(out), "--quiet"])
    capsys.readouterr()
    png = tmp_path / "d.png"
    args = ["sweep-plot", str(out), "--x", "n", "--y", "decomposable", "--by", "relations.p"]
    assert main([*args, "--exact", "cograph", "-o", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["sweep-plot", str(out), "--x", "n", "--y", "decode_error_count"]) == 0
    assert (out / "decode_error_count-vs-n.png").exists()
    capsys.readouterr()
    assert main(["sweep-plot", str(out), "--x", "n", "--y", "nope"]) == 2
    assert "no column 'nope'" in capsys.readouterr().err
    assert main(["sweep-plot", str(out), "--x", "n", "--y", "polynomial"]) == 2
    assert "polynomial=VALUE" in capsys.readouterr().err


def test_wilson_interval():
    from rgtbus.stats import wilson

    p, lo, hi = wilson(0, 10)
    assert p == 0 and lo == 0 and 0.27 < hi < 0.28
    p, lo, hi = wilson(5, 10)
    assert p == 0.5 and abs((0.5 - lo) - (hi - 0.5)) < 1e-12 and 0.23 < lo < 0.24


CASES = """
name = "cases"
scenario = "{scenario}"
seeds = [4, 9]
[cases]
"serial, schedule anchor" = { "protocol.schedule" = "serial", "timing.anchor" = "schedule" }
concurrent = { protocol = { schedule = "concurrent" } }
[grid]
n = [3]
"channel.noise" = [0.0, 0.003]
"""


def test_cases_are_named_sets_of_keys_crossed_with_the_grid(tmp_path):
    sw = load_sweep(write_sweep(tmp_path, CASES))
    assert sw.keys == ["case", "n", "channel.noise"]
    with ThreadPoolExecutor(1) as ex:
        rows = run_sweep(sw, tmp_path / "o", executor=ex, workers=1)
    got = [(r["case"], r["channel.noise"], r["seed"], r["schedule"]) for r in rows]
    assert got == [
        ("serial, schedule anchor", 0.0, 4, "serial"),
        ("serial, schedule anchor", 0.0, 9, "serial"),
        ("serial, schedule anchor", 0.003, 4, "serial"),
        ("serial, schedule anchor", 0.003, 9, "serial"),
        ("concurrent", 0.0, 4, "concurrent"),
        ("concurrent", 0.0, 9, "concurrent"),
        ("concurrent", 0.003, 4, "concurrent"),
        ("concurrent", 0.003, 9, "concurrent"),
    ]
    assert not any(r["failed"] for r in rows)
    # the run of a case is the base scenario with the case's keys set, nothing else
    from rgtbus.units.sweep import scenario_for

    sc = scenario_for(sw, (("case", "serial, schedule anchor"), ("n", 3)), 4)
    got = (sc.protocol.schedule, sc.timing.anchor, sc.units)
    assert got == ("serial", "schedule", ("u1", "u2", "u3"))


@pytest.mark.parametrize(
    "cases, line, says",
    [
        ("[cases]\nx = 3\n", ":4: x:", "non-empty table"),
        ("[cases]\nx = {}\n", ":4: x:", "non-empty table"),
        ("[cases]\nx = { n = 4 }\n", ":4: x:", "'n': not a case key"),
        ('[cases]\nx = { "channel.noise" = 0.1 }\n', ":4: x:", "set by the grid"),
        ('[cases]\nx = { engine = "fast" }\n', ":4: x:", "unknown engine 'fast'"),
        ('[cases]\nbad = { "timing.anchor" = "later" }\n', ":4: bad:", "later"),
        ("cases = 3\n", ":3: cases:", "must be a table"),
    ],
)
def test_bad_cases_are_refused_naming_the_case(tmp_path, capsys, cases, line, says):
    body = 'scenario = "{scenario}"\nseeds = "0..1"\n' + cases + '[grid]\n"channel.noise" = [0.0]\n'
    path = write_sweep(tmp_path, body)
    assert main(["sweep", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path}{line}" in err and says in err, err


def test_case_is_no_grid_key(tmp_path, capsys):
    path = write_sweep(tmp_path, 'scenario = "{scenario}"\n[grid]\ncase = ["a"]\n')
    assert main(["sweep", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert f"{path}:3: case:" in capsys.readouterr().err


def test_sweep_plot_draws_several_metrics_side_by_side(tmp_path, capsys):
    out = tmp_path / "o"
    with ThreadPoolExecutor(1) as ex:
        run_sweep(load_sweep(write_sweep(tmp_path, CASES)), out, executor=ex, workers=1)
    args = ["sweep-plot", str(out), "--x", "channel.noise", "--by", "case"]
    ys = ["--y", "decode_error_rate", "--y", "wrong_decision_rate", "--y", "failed"]
    assert main([*args, *ys]) == 0
    png = out / "decode_error_rate+wrong_decision_rate+failed-vs-channel.noise.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    capsys.readouterr()
    assert main([*args, "--y", "failed", "--y", "nope", "-o", str(tmp_path / "x.png")]) == 2
    assert "no column 'nope'" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()  # every metric checked before anything is drawn


@pytest.mark.slow
def test_a_sweep_killed_by_a_signal_resumes_to_the_same_table(tmp_path):
    """A real kill: the whole process group of a running `rgtbus sweep` (the CLI and its pool
    workers) gets SIGKILL once some rows are on disk; --resume finishes it."""
    import os
    import signal
    import subprocess
    import sys
    import time

    body = SWEEP.replace('seeds = "0..2"', 'seeds = "0..149"')  # 300 runs: seconds to kill in
    path = write_sweep(tmp_path, body)
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "rgtbus", "sweep", str(path), "--workers", "2", "--quiet"]
    proc = subprocess.Popen(
        [*cmd, "--out", str(out)],
        cwd=ROOT,
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    rows_file = out / "rows.jsonl"
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if rows_file.exists() and rows_file.read_text().count("\n") >= 1:
                break
            time.sleep(0.05)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=60)
    err = proc.stderr.read().decode() if proc.stderr else ""
    if proc.stderr:
        proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL, err  # killed, not finished
    assert 1 <= rows_file.read_text().count("\n") < 300
    resumed = subprocess.run(
        [*cmd, "--out", str(out), "--resume"], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert resumed.returncode == 0, resumed.stderr
    full = tmp_path / "full"
    with ThreadPoolExecutor(1) as ex:
        run_sweep(load_sweep(path), full, executor=ex, workers=1)
    assert table(out) == table(full)


def test_a_goal_sweep_has_goal_columns_and_where_selects_runs(tmp_path, capsys):
    """The steering study's shape (issue 14): goal columns per run, and --where to plot one
    value of a grid key."""
    body = f"""
name = "steer"
scenario = "{ROOT / "scenarios" / "steering.toml"}"
seeds = "0..2"
[grid]
n = [3]
"goals.u1.u2" = ["1", "[0,1]"]
"""
    path = tmp_path / "steer.toml"
    path.write_text(body)
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out), "--quiet"]) == 0
    rows = table(out)
    assert len(rows) == 6
    for r in rows:
        assert r["goal_count"] == 1 and r["failed"] is False
        assert isinstance(r["goal_reached"], bool) and isinstance(r["goal_reachable"], bool)
        assert 0 <= r["goal_share_mean"] <= 1
        assert r["rounds_state"] == "fixed point"  # the steering base has two rounds
        assert r["goals"][0]["reached"] == r["goal_reached"]
    capsys.readouterr()
    png = tmp_path / "s.png"
    args = ["sweep-plot", str(out), "--x", "n", "--y", "goal_reached", "-o", str(png)]
    assert main([*args, "--where", "goals.u1.u2=1"]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    capsys.readouterr()
    assert main([*args, "--where", "goals.u1.u2=0"]) == 2
    assert "no run has goals.u1.u2 = 0" in capsys.readouterr().err
    assert main([*args, "--where", "nope"]) == 2
    assert "KEY=VALUE" in capsys.readouterr().err


# -- the library function, native tables, decisions, old directories (issue 21) ----------------

RANDOM = str(ROOT / "scenarios" / "random_group.toml")


def test_the_library_sweep_returns_what_the_parquet_holds(tmp_path):
    import pandas as pd
    from rgtbus.units.sweep import read_sweep, sweep

    out = tmp_path / "lib"
    df = sweep(RANDOM, grid={"n": [3, 4], "relations.p": [0.61]}, seeds=2, workers=1, out=out)
    pd.testing.assert_frame_equal(df, read_sweep(out).results)
    # what pd.read_parquet reads, in forms pandas can hash: lists as tuples, maps as dicts
    raw = pd.read_parquet(out / "results.parquet")
    assert list(df.columns) == list(raw.columns) and len(df) == len(raw)
    for column in df.columns:  # pandas groups, sorts, dedupes and merges on every one
        df.groupby([column], dropna=False).size()
        df.sort_values([column])
        df.drop_duplicates([column])
        df[[column]].drop_duplicates().merge(df, on=column)
    assert list(zip(df["n"], df["seed"], strict=True)) == [(3, 0), (3, 1), (4, 0), (4, 1)]
    assert df["relations.p"].dtype == "float64" and df["n"].dtype == "int64"
    # native types: no json.loads
    assert {u["unit"] for u in df["units"][0]} == {"u1", "u2", "u3"}
    assert dict(df["relations"][0]).keys() == {"u1-u2", "u1-u3", "u2-u3"}
    info = json.loads((out / "sweep.json").read_text())
    assert info["executor"] == "in-process" and info["workers"] == 1
    assert info["scheduler"] is None and info["tables"] == TABLES_VERSION == 5
    # the directory holds a sweep file that re-runs it as is (scenario.toml beside it)
    again = load_sweep(out / "sweep.toml")
    assert again.digest != "" and again.seeds == (0, 1) and again.keys == ["n", "relations.p"]
    # one row per run, unit and round: "how often does a unit choose y" is one groupby
    results, decisions = read_sweep(out)
    assert len(decisions) == results["decided_count"].sum() > 0  # one round each
    assert list(decisions.columns) == [
        "sweep",
        "run_id",
        "run",
        "n",
        "relations.p",
        "seed",
        "unit",
        "round",
        "low",
        "high",
        "choice",
        "frustrated",
        "wrong",
        "t",
    ]
    assert decisions["wrong"].dtype == bool and not decisions["wrong"].any()
    alpha = decisions["choice"].map(lambda c: c is not None and "alpha" in c)  # None: frustrated
    chose = decisions.assign(alpha=alpha)
    assert chose.groupby("n")["alpha"].mean().index.tolist() == [3, 4]
    # out=None: nothing kept on disk, the same table
    again_df = sweep(RANDOM, grid={"n": [3, 4], "relations.p": [0.61]}, seeds=[0, 1], workers=1)
    cols = [c for c in df.columns if c != "wall_seconds"]
    pd.testing.assert_frame_equal(again_df[cols], df[cols])


@pytest.mark.slow
def test_the_json_lines_parquet_and_csv_hold_the_same_tables(tmp_path):
    """results.jsonl and decisions.jsonl (what the core reads, no pyarrow) are the Parquet
    tables' rows value for value; the frames read from either agree; the CSV has the same
    columns with nested ones as JSON text, a null as an empty cell."""
    import csv

    import pandas as pd
    from rgtbus.units.sweep import sweep

    from rgtbus.telemetry import sweep_read as sr

    out = tmp_path / "both"
    grid = {"n": [3, 4], "relations.p": [0.3, 0.9], "engine": ["event"]}
    sweep(RANDOM, grid=grid, seeds=2, workers=1, out=out)
    for name in ("results", "decisions"):
        jsonl = [json.loads(line) for line in (out / f"{name}.jsonl").read_text().splitlines()]
        assert jsonl == table_rows(pq.read_table(out / f"{name}.parquet")), name
        from_json = sr.frame_of(jsonl, sr.table_columns(out, name))
        from_parquet = sr.read_table(out / f"{name}.parquet")
        pd.testing.assert_frame_equal(from_json, from_parquet)  # dtypes too
        # bare rows (no columns.json: pandas chooses the dtypes): the same values where a
        # column holds any (an all-null column is None there, NaN in pandas' string dtype)
        bare = sr.frame_of(jsonl)
        held = [c for c in from_parquet.columns if from_parquet[c].notna().any()]
        pd.testing.assert_frame_equal(bare[held], from_parquet[held], check_dtype=False)
    results = table_rows(pq.read_table(out / "results.parquet"))
    with open(out / "results.csv", newline="", encoding="utf-8") as f:
        cells = list(csv.DictReader(f))
    assert [list(c) for c in cells] == [list(r) for r in results]
    for row, cell in zip(results, cells, strict=True):
        for key, value in row.items():
            if value is None:
                assert cell[key] == ""
            elif isinstance(value, dict | list):
                assert json.loads(cell[key]) == value
            elif isinstance(value, bool):
                assert cell[key] == ("true" if value else "false")
            else:
                assert type(value)(cell[key]) == value, key


def test_rows_plain_equal_the_arrow_tables_for_every_shape_of_row():
    """``results_rows`` (no Arrow) gives what the Arrow table gives back, on rows with every
    nested column filled, emptied and missing (an older rgtbus's JSON text too)."""
    from rgtbus.telemetry import sweep_tables as st

    axes = [("n", [3, 4]), ("channel.noise", [0.0, 0.5]), ("case", ["x"])]
    full = {
        "run": 0, "n": 3, "channel.noise": 0, "case": "x", "seed": 1, "relations": {"a-b": "x"},
        "influences": {"a>b": ["go"]}, "units": {"a": {"interval": [[], ["go"]], "choice": []}},
        "goals": [{"unit": "a", "want": [[], ["go"]], "share": 1, "extra": "gone"}],
        "rounds": {"count": 2, "influences": [{"a>b": []}]}, "sim_seconds": 3,
        "repair": {"mode": "arq", "seconds": 1, "requests": 2},
        "_decisions": [{"unit": "a", "round": 1, "low": [], "t": 2}],
    }  # fmt: skip
    rows = [full, {"run": 1, "n": 4, "seed": 2}, {**full, "run": 2, "units": json.dumps({})}]
    for make_rows, make_table in (
        (st.results_rows, st.results_table),
        (st.decisions_rows, st.decisions_table),
    ):
        assert make_rows(axes, rows, "s") == table_rows(make_table(axes, rows, "s"))


def test_a_directory_of_parquet_only_reads_with_pyarrow_or_says_which_extra(tmp_path):
    """A sweep an older rgtbus wrote (Parquet, no JSON Lines) reads from its Parquet; without
    pyarrow, reading it names the extra in one line."""
    import subprocess
    import sys

    from rgtbus.units.sweep import read_sweep, sweep

    out = tmp_path / "old"
    df = sweep(RANDOM, grid={"n": [3]}, seeds=2, workers=1, out=out)
    for name in ("results.jsonl", "decisions.jsonl"):
        (out / name).unlink()
    results, decisions = read_sweep(out)
    assert len(results) == len(df) == 2 and len(decisions) > 0
    code = (
        "import sys; sys.modules['pyarrow'] = None\n"
        "from rgtbus.errors import RgtbusError\n"
        "from rgtbus.units.sweep import read_sweep\n"
        "try:\n    read_sweep(sys.argv[1])\nexcept RgtbusError as e:\n    print(e)\n"
    )
    done = subprocess.run([sys.executable, "-c", code, str(out)], capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    said = done.stdout.strip()
    assert "pip install 'rgtbus[parquet]'" in said and "results.parquet" in said, done


def test_a_damaged_sweep_directory_is_one_line_naming_its_file(tmp_path):
    """What the core reads of a sweep (its JSON Lines and columns.json), damaged or not fitting
    each other, is refused in one line naming the file (and line, or column)."""
    import shutil

    from rgtbus.units.sweep import read_sweep, sweep

    good = tmp_path / "good"
    sweep(RANDOM, grid={"n": [3]}, seeds=2, workers=1, out=good)
    columns = json.loads((good / "columns.json").read_text())
    columns["results"] = [[n, "int" if n == "scenario" else k] for n, k in columns["results"]]
    cases = [
        ("columns.json", "{not json", "columns.json'?: not a sweep's columns"),
        ("columns.json", '{"results": [[1]]}', "columns.json'?: not a sweep's columns"),
        ("columns.json", json.dumps(columns), "results.jsonl: column 'scenario' holds"),
        ("results.jsonl", '{"run": 0}\n[1, 2]\n', "results.jsonl:2: not a row"),
        ("decisions.jsonl", "\x00\xff", "decisions.jsonl:1: not a row"),
    ]
    for i, (name, text, says) in enumerate(cases):
        bad = tmp_path / f"bad{i}"
        shutil.copytree(good, bad)
        (bad / name).write_text(text, encoding="latin-1")
        with pytest.raises(RgtbusError) as err:
            read_sweep(bad)
        msg = str(err.value)
        assert re.search(says, msg) and "\n" not in msg and str(bad) in msg, (name, msg)


def test_the_cli_and_the_library_give_the_same_table(tmp_path, capsys):
    from rgtbus.units.sweep import sweep

    path = write_sweep(tmp_path)
    args = ["sweep", str(path), "--out", str(tmp_path / "cli"), "--workers", "2", "--quiet"]
    assert main([*args, "--json"]) == 0
    printed = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(printed) == 6 and printed[0]["units"][0]["unit"] == "u1"
    # in this process (one worker) and on the command's pool of two: the same table
    grid = {"n": [3, 4], "relations.p": [0.61]}
    sweep(RANDOM, grid=grid, seeds=3, workers=1, out=tmp_path / "lib")
    assert table(tmp_path / "lib") == table(tmp_path / "cli")
    assert json.loads((tmp_path / "cli" / "sweep.json").read_text())["executor"] == "process-pool"


@pytest.mark.parametrize("how", ["script", "module"])
def test_a_sweep_from_a_script_without_a_main_guard_uses_worker_processes(tmp_path, how):
    """No `if __name__ == "__main__"`: the spawned workers must not run the script again (they
    would start the sweep again, and the pool would break)."""
    import subprocess
    import sys

    out, marker = tmp_path / "out", tmp_path / "ran"
    (tmp_path / "noguard.py").write_text(
        "from rgtbus.units.sweep import sweep\n"
        f"open({str(marker)!r}, 'a').write('x')\n"
        f"df = sweep({RANDOM!r}, grid={{'n': [2, 3]}}, seeds=2, workers=2, out={str(out)!r})\n"
        "print('ROWS', len(df), int(df['failed'].sum()))\n"
    )
    cmd = [sys.executable, "noguard.py"] if how == "script" else [sys.executable, "-m", "noguard"]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["ROWS 4 0"], done.stdout
    assert marker.read_text() == "x"  # the script ran once: in this process, not in the workers
    assert done.stderr == "", done.stderr  # no fallback line, no traceback
    info = json.loads((out / "sweep.json").read_text())
    assert (info["executor"], info["workers"], info["start_method"]) == ("process-pool", 2, "spawn")


def test_a_pool_that_cannot_start_falls_back_to_this_process_in_one_line(tmp_path, capsys):
    from concurrent.futures import Executor, Future
    from concurrent.futures.process import BrokenProcessPool

    class Broken(Executor):
        def submit(self, fn, /, *args, **kwargs):
            f: Future = Future()
            f.set_exception(BrokenProcessPool("A child process terminated abruptly"))
            return f

    out = tmp_path / "o"
    rows = run_sweep(load_sweep(write_sweep(tmp_path)), out, executor=Broken(), workers=2)
    assert len(rows) == 6 and not any(r["failed"] for r in rows)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "running 6 runs in this process" in err
    assert "Traceback" not in err
    info = json.loads((out / "sweep.json").read_text())
    assert info["executor"] == "in-process" and "BrokenProcessPool" in info["fallback"]


def test_tables_have_one_schema_whatever_the_data(tmp_path):
    """A column whose runs are all empty keeps its type, so two sweeps concatenate."""
    import pandas as pd
    import pyarrow as pa
    from rgtbus.units.sweep import sweep

    grid = {"channel.noise": [0.0]}
    a = sweep(RANDOM, grid=grid, seeds=1, workers=1, out=tmp_path / "a")  # no [outcome]
    b = sweep(str(ROOT / "scenarios" / "gate.toml"), grid=grid, seeds=1, out=tmp_path / "b")
    ta = pq.read_table(tmp_path / "a" / "results.parquet")
    tb = pq.read_table(tmp_path / "b" / "results.parquet")
    assert a["outcome"].isna().all() and b["outcome"][0] == "gate: open"
    assert ta.schema.equals(tb.schema)
    s = ta.schema
    assert s.field("outcome").type == pa.string() and s.field("error").type == pa.string()
    assert s.field("goal_reached").type == pa.bool_()  # no goals: all empty, still bool
    assert s.field("p4").type == pa.list_(pa.string())
    assert s.field("relations").type == pa.map_(pa.string(), pa.string())
    assert pa.types.is_struct(s.field("rounds").type)
    assert pa.types.is_struct(s.field("units").type.value_type)
    assert pa.types.is_struct(s.field("decode_errors").type)
    both = pa.concat_tables([ta, tb])
    assert both.num_rows == 2
    assert len(pd.concat([a, b], ignore_index=True)) == 2
    da = pq.read_table(tmp_path / "a" / "decisions.parquet")
    db = pq.read_table(tmp_path / "b" / "decisions.parquet")
    assert pa.concat_tables([da, db]).num_rows == da.num_rows + db.num_rows == 3 + 4
    # a failed run (no summary at all) has the same columns and types
    c = sweep(RANDOM, grid={"timing.stop": [2.0]}, seeds=1, out=tmp_path / "c")
    tc = pq.read_table(tmp_path / "c" / "results.parquet")
    assert bool(c["failed"][0]) and tc.schema.field("units").type == s.field("units").type
    assert pq.read_table(tmp_path / "c" / "decisions.parquet").num_rows == 0


def test_sweep_refuses_bad_arguments_in_one_line(tmp_path):
    from rgtbus.units.sweep import sweep

    from rgtbus.errors import RgtbusError

    with pytest.raises(RgtbusError, match=r"sweep: relations.p: value 1.5"):
        sweep(RANDOM, grid={"relations.p": [0.5, 1.5]}, seeds=1)
    with pytest.raises(RgtbusError, match=r"sweep: n: must be a non-empty list"):
        sweep(RANDOM, grid={"n": 3}, seeds=1)
    with pytest.raises(RgtbusError, match=r"sweep seeds: N must be"):
        sweep(RANDOM, grid={}, seeds=0)
    with pytest.raises(RgtbusError, match=r"needs out="):
        sweep(RANDOM, grid={}, seeds=1, logs=True)


def _as_old(out: Path) -> None:
    """Make ``out`` look written by the rgtbus before native tables: nested columns as JSON
    text in rows.jsonl, no decisions, no tables version, no decisions.parquet."""
    lines = []
    for line in (out / "rows.jsonl").read_text().splitlines():
        row = json.loads(line)
        row.pop("_decisions", None)
        row.pop("_hmac", None)  # nor seals
        for k in ("relations", "influences", "units", "goals", "rounds", "decode_errors", "p4"):
            if k in row:
                row[k] = json.dumps(row[k])
        lines.append(json.dumps(row))
    (out / "rows.jsonl").write_text("\n".join(lines[:3]) + "\n")
    info = json.loads((out / "sweep.json").read_text())
    info.pop("tables")
    info.pop("rows")
    (out / "sweep.json").write_text(json.dumps(info))
    (out / "decisions.parquet").unlink()


def test_an_old_sweep_directory_resumes_into_the_native_tables(tmp_path, capsys):
    path = write_sweep(tmp_path)
    full, old = tmp_path / "full", tmp_path / "old"
    with ThreadPoolExecutor(1) as ex:
        run_sweep(load_sweep(path), full, executor=ex, workers=1)
        run_sweep(load_sweep(path), old, executor=ex, workers=1)
    _as_old(old)
    assert main(["sweep", str(path), "--out", str(old), "--resume", "--quiet"]) == 0
    assert table(old) == table(full)
    decisions = pq.read_table(old / "decisions.parquet").to_pylist()
    every = pq.read_table(full / "decisions.parquet").to_pylist()
    assert decisions == [d for d in every if d["run"] >= 3] != []  # the old rows had none


def test_an_old_sweep_directory_that_does_not_fit_is_refused_in_one_line(tmp_path, capsys):
    path = write_sweep(tmp_path)
    out = tmp_path / "old"
    with ThreadPoolExecutor(1) as ex:
        run_sweep(load_sweep(path), out, executor=ex, workers=1)
    _as_old(out)
    rows = (out / "rows.jsonl").read_text().splitlines()
    bad = json.loads(rows[0])
    bad["units"] = "u1 decided, u2 did not"  # neither JSON nor a table of units
    (out / "rows.jsonl").write_text("\n".join([json.dumps(bad), *rows[1:]]) + "\n")
    capsys.readouterr()
    assert main(["sweep", str(path), "--out", str(out), "--resume", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(out) in err and "cannot resume" in err, err


def test_sweep_plot_reads_native_tables_and_names_nested_columns(tmp_path, capsys):
    out = tmp_path / "o"
    main(["sweep", str(write_sweep(tmp_path)), "--out", str(out), "--quiet"])
    capsys.readouterr()
    png = tmp_path / "a.png"
    args = ["sweep-plot", str(out), "--x", "n", "-o", str(png)]
    assert main([*args, "--y", "alliance_share", "--where", "relations.p=0.61"]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    capsys.readouterr()
    assert main([*args, "--y", "units"]) == 2
    assert "holds lists or tables" in capsys.readouterr().err


def test_shipped_sweeps_by_name_and_every_row_named_across_sweeps(tmp_path, capsys, monkeypatch):
    """``rgtbus sweeps`` lists the shipped sweeps and a sweep is found by name wherever the
    command runs; a sweep file may name a shipped scenario; every row carries its sweep's id
    (name and content) and a run id no other sweep's row has."""
    import pandas as pd

    from rgtbus.scenario.shipped import shipped_sweeps

    monkeypatch.chdir(tmp_path)  # no scenarios/ here: found as shipped
    names = [s.name for s in shipped_sweeps()]
    assert {"noise", "decomposable", "repair"} <= set(names)
    assert main(["sweeps", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert [s["name"] for s in listed] == names and all(s["description"] for s in listed)
    assert load_sweep("decomposable").path.endswith("decomposable.toml")
    tables = []
    for n in (3, 4):  # two sweeps of one shipped scenario, named, not a path
        path = tmp_path / f"by_name_{n}.toml"
        path.write_text(f'name = "by_name"\nscenario = "random_group"\nseeds = "0..1"\n'
                        f"[grid]\nn = [{n}]\n")  # fmt: skip
        assert main(["sweep", str(path), "--out", str(tmp_path / f"out{n}"), "--workers", "1",
                     "--quiet"]) == 0  # fmt: skip
        tables.append(pd.read_parquet(tmp_path / f"out{n}" / "results.parquet"))
    both = pd.concat(tables, ignore_index=True)
    assert set(both["run"]) == {0, 1}  # a run's place in its own sweep: repeats
    assert both["run_id"].is_unique and both["sweep"].nunique() == 2
    assert all(s.startswith("by_name-") for s in both["sweep"])
    named = zip(both["sweep"], both["run_id"], both["run"], strict=True)
    assert all(r == f"{s}/{k}" for s, r, k in named)
    decisions = pd.read_parquet(tmp_path / "out3" / "decisions.parquet")
    assert set(decisions["run_id"]) <= set(tables[0]["run_id"]) and len(decisions)


def test_the_id_noise_study_counts_misread_ids_and_those_a_repair_set_right():
    """The ID-noise study's columns (scenarios/sweeps/id_noise.toml, docs/protocol.md): a run
    whose unit misreads an ID ends there without the repair (one misread, left wrong); with
    the repair the same ID read wrong is set right and the run goes on; a clean channel
    misreads nothing. ``id_decodes`` counts every ID the units decoded."""
    from rgtbus.units.sweep import sweep

    study = load_sweep(ROOT / "scenarios" / "sweeps" / "id_noise.toml")
    cases = {c: dict(study.case(c)) for c in ("schedule", "schedule, arq")}
    df = sweep(
        ROOT / "scenarios" / "random_group.toml", grid={"n": [3], "channel.noise": [0.0, 0.05]},
        cases=cases, seeds=[3], workers=1,
    )  # fmt: skip
    got = {
        (r["case"], r["channel.noise"]): (
            r["id_misread_count"],
            r["id_misreads_left"],
            r["failed"],
            r["id_decodes"] > 0,
        )
        for _, r in df.iterrows()
    }
    assert got[("schedule", 0.0)] == (0, 0, False, True)
    assert got[("schedule", 0.05)] == (1, 1, True, True)
    assert got[("schedule, arq", 0.05)][1:3] == (0, False)
    assert got[("schedule, arq", 0.05)][0] >= 1
    assert (df["id_misread_rate"] == df["id_misread_count"] / df["id_decodes"]).all()
