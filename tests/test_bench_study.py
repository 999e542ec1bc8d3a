"""benchmarks/bench_study.py runs, its three ways agree on every run, and it prints its table."""

from __future__ import annotations

import sys


def test_the_study_benchmark_runs_and_its_ways_agree(capsys, monkeypatch):
    from benchmarks import bench_study

    monkeypatch.setattr(sys, "argv", ["bench_study", "--runs", "6", "--repeat", "1"])
    bench_study.main()  # asserts the loop and both studies steered the same runs
    out = capsys.readouterr().out
    assert "| loop over rgtbus.run | 6 |" in out and "| study, 1 worker | 6 |" in out
