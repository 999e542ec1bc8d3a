"""Sweeps: sweep files, the results table, resume, errors as rows, Dask, plots."""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from rgtbus.cli import main
from units import sweep as sweep_mod
from units.sweep import load_sweep, run_sweep

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
    path.write_text(body.format(scenario=ROOT / "scenarios" / "random_group.toml"))
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
    import units.group

    calls = []

    def boom(sc, *a, **k):
        calls.append(sc.seed)
        if sc.seed == 1:
            raise ZeroDivisionError("division by zero")
        return real(sc, *a, **k)

    real = units.group.run_group
    monkeypatch.setattr(units.group, "run_group", boom)
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
