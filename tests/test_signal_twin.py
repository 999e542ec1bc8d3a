"""The compiled receiver and its NumPy twin (rgtbus.signal.walk_numpy) give the same bits: the
kernels on random input, and whole runs, every logged message compared."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from rgtbus.signal import _walk
from rgtbus.signal import walk_numpy as twin

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = sorted(p.stem for p in (ROOT / "scenarios").glob("*.toml"))
FAST = {"example2"}  # the rest: CI's slow pass (a twin's run: up to 20x the compiled one)


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as f:  # the run's own summary says its wall time: left out
        return sorted(
            (c.topic, m.log_time, bytes(m.data))
            for _, c, m in make_reader(f).iter_messages()
            if c.topic != "/run"
        )


def _run(scenario: str, log: Path, walk: str, *extra: str) -> None:
    env = dict(os.environ, RGTBUS_WALK=walk)
    cmd = [sys.executable, "-m", "rgtbus", "run", str(ROOT / "scenarios" / f"{scenario}.toml")]
    cmd += ["--bus", "memory", "--log", str(log), "--quiet", *extra]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode in (0, 1), done.stderr  # 1: a run that ends as its scenario expects


@pytest.mark.parametrize(
    "scenario",
    [pytest.param(s, marks=[] if s in FAST else [pytest.mark.slow]) for s in SCENARIOS],
)
def test_a_run_on_the_twin_logs_what_the_compiled_run_logs(scenario, tmp_path):
    _run(scenario, tmp_path / "c.mcap", "compiled")
    _run(scenario, tmp_path / "n.mcap", "numpy")
    compiled = _messages(tmp_path / "c.mcap")
    assert compiled and _messages(tmp_path / "n.mcap") == compiled


@pytest.mark.slow
def test_a_traced_run_on_the_twin_records_the_same_states(tmp_path):
    _run("example1", tmp_path / "c.mcap", "compiled", "--traces")
    _run("example1", tmp_path / "n.mcap", "numpy", "--traces")
    compiled = _messages(tmp_path / "c.mcap")
    assert any(t.startswith("/trace/") for t, _, _ in compiled)
    assert _messages(tmp_path / "n.mcap") == compiled


def test_the_score_the_timings_and_the_rows_are_the_compiled_bits():
    rng = np.random.default_rng(7)
    for _ in range(300):
        M, W, N = rng.integers(1, 6), rng.integers(1, 9), rng.integers(1, 7)
        mat = np.round(rng.normal(size=(W, N)), int(rng.integers(0, 3)))  # rounded: ties
        if rng.random() < 0.3:
            mat[-1] = mat[0]  # a word under two names
        vals = np.round(rng.normal(size=(M, N)), int(rng.integers(0, 3)))
        if rng.random() < 0.2:
            mat[int(rng.integers(0, W))] = 0.0  # silence among the words
        rank = rng.permutation(W).astype(np.int64)
        assert twin.score(vals, mat, rank) == _walk.score(vals, mat, rank)
        assert twin.score_matched(vals, mat, rank) == _walk.score_matched(vals, mat, rank)
    for _ in range(200):
        C = int(rng.integers(1, 5))
        omegas = rng.uniform(0.5, 20.0, size=C)
        chans = rng.permutation(8)[:C].astype(np.int64)
        args = (float(rng.uniform(-0.2, 30.0)), int(rng.integers(1, 6)), 0.005,
                int(rng.integers(0, 6)))  # fmt: skip
        got, want = twin.timings(chans, omegas, *args), _walk.timings(chans, omegas, *args)
        for a, b in zip(got, want, strict=True):
            assert a.shape == b.shape and (a == b).all()
    rows = np.unique(rng.integers(0, 400, size=60)).astype(np.int64)
    vals = rng.normal(size=(rows.size, 3, 5))
    idx = rng.integers(0, 420, size=(7, 4)).astype(np.int64)
    idx[0, 0] = rows[0]
    chans = rng.integers(0, 5, size=7).astype(np.int64)
    assert (twin.read_rows(rows, vals, idx, chans) == _walk.read_rows(rows, vals, idx, chans)).all()


def test_many_decodes_at_once_are_the_bits_of_the_rule_and_of_one_at_a_time():
    """``_walk.score_many`` (the nearest rule's many decodes, compiled) against the rule's
    NumPy statement (``nearest_words``) and against its twin, a decode at a time: rows,
    words, distances, margins, separations, ties and words under two names included."""
    from rgtbus.signal.nearest import nearest_words
    from rgtbus.signal.rules import NEAREST

    rng = np.random.default_rng(11)
    for _ in range(200):
        D, M = int(rng.integers(1, 40)), int(rng.integers(1, 6))
        W, N = int(rng.integers(1, 9)), int(rng.integers(1, 7))
        mat = np.round(rng.normal(size=(W, N)), int(rng.integers(0, 3)))  # rounded: ties
        if rng.random() < 0.3:
            mat[-1] = mat[0]  # a word under two names
        if rng.random() < 0.2:
            mat[int(rng.integers(0, W))] = 0.0
        vals = np.round(rng.normal(size=(D, M, N)), int(rng.integers(0, 3)))
        rank = rng.permutation(W).astype(np.int64)
        got = _walk.score_many(vals, mat, rank)
        for a, b, c, d in zip(
            got, nearest_words(vals, mat, rank), twin.score_many(vals, mat, rank),
            NEAREST.many(vals, mat, rank), strict=True,
        ):  # fmt: skip
            assert a.dtype == b.dtype and np.array_equal(a, b) and np.array_equal(a, c)
            assert np.array_equal(a, d)


def test_without_the_compiled_module_the_twin_runs_and_says_so_once(tmp_path):
    code = (
        "import sys; sys.modules['rgtbus.signal._walk'] = None\n"
        "from rgtbus.cli import main\n"
        "sys.exit(main(['run', 'example2', '--bus', 'memory', '--log', sys.argv[1], '--quiet']))"
    )
    env = {k: v for k, v in os.environ.items() if k != "RGTBUS_WALK"}
    done = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / "n.mcap")],
        env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stderr.count("NumPy twin") == 1, done.stderr
    _run("example2", tmp_path / "c.mcap", "compiled")
    assert _messages(tmp_path / "n.mcap") == _messages(tmp_path / "c.mcap")


def test_a_bad_choice_of_walk_is_one_line():
    env = dict(os.environ, RGTBUS_WALK="fortran")
    done = subprocess.run(
        [sys.executable, "-m", "rgtbus", "run", "gate", "--bus", "memory", "--no-log"],
        env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2 and "RGTBUS_WALK='fortran'" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr
