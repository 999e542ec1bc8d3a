"""Sweeps: sweep files, the results table, resume, errors as rows, Dask, plots."""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from rgtbus.units import sweep as sweep_mod
from rgtbus.units.sweep import load_sweep, run_sweep

from rgtbus.cli import main

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
    rows = pq.read_table(out / "results.parquet").to_pylist()
    for r in rows:
        r.pop("wall_seconds")
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
    assert json.loads(r["units"]).keys() == {"u1", "u2", "u3"}
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
    body = SWEEP.replace('"relations.p" = [0.61]', '"timing.max_seconds" = [2.0]')
    out = tmp_path / "o"
    assert main(["sweep", str(write_sweep(tmp_path, body)), "--out", str(out), "--quiet"]) == 0
    rows = table(out)
    assert len(rows) == 6 and all(r["failed"] for r in rows)
    assert all("timing.max_seconds" in r["error"] for r in rows)


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
    from rgtbus.telemetry.sweep_plot import wilson

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
    assert (sc.schedule, sc.timing.anchor, sc.units) == ("serial", "schedule", ("u1", "u2", "u3"))


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
        goals = json.loads(r["goals"])
        assert goals[0]["reached"] == r["goal_reached"]
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
