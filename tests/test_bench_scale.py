"""The scale benchmark's "records built, none written" cell (issue 38): a recorder that is on
and keeps nothing, so a run does all of a logged run's work and writes no byte."""

from __future__ import annotations

from typing import Any

from rgtbus.units.group import run_group

from rgtbus.scenario import parse_scenario
from rgtbus.telemetry import NullRecorder, records
from rgtbus.telemetry.recorder import Recorder


def test_a_discarding_recorder_runs_the_logged_path_and_keeps_nothing(monkeypatch):
    from benchmarks.bench_scale import DiscardingRecorder, scale_toml

    rec = DiscardingRecorder()
    assert isinstance(rec, Recorder) and rec.enabled
    built_for: list[str] = []  # whose decode records were built (and handed on)
    real = records.decodes_of_columns

    def decodes_of_columns(unit: str | list[str], *args: Any, **kwargs: Any) -> Any:
        built_for.extend([unit] if isinstance(unit, str) else unit)
        return real(unit, *args, **kwargs)

    monkeypatch.setattr(records, "decodes_of_columns", decodes_of_columns)
    sc = parse_scenario(scale_toml(8, "concurrent"), "<scale8>")
    built = run_group(sc, "memory", rec).summary
    assert set(built_for) == set(sc.units)
    built_for.clear()
    plain = run_group(sc, "memory", NullRecorder()).summary
    assert not built_for  # without a log, none is built
    for key in ("decisions", "unit_relations", "decode_errors", "sim_seconds", "error"):
        assert built[key] == plain[key], key
