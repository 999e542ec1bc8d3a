"""``timing.max_seconds`` follows the schedule (issue 38, item 3): its default is what the
plan needs with a margin (at least an hour), a value the file sets that is too short for the
schedule is refused at load naming what it needs, and ``timing.stop`` cuts a run short on
purpose."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from rgtbus.units.group import run_group
from rgtbus.units.unit import protocol_of

from rgtbus.errors import RgtbusError
from rgtbus.scenario import load_scenario, parse_scenario
from rgtbus.scenario.timing import DEFAULT_MAX_SECONDS, default_max_seconds
from rgtbus.telemetry import NullRecorder

ROOT = Path(__file__).resolve().parent.parent
GATE = (ROOT / "scenarios" / "gate.toml").read_text()


def gate(extra: str) -> str:
    return GATE.replace("guard = 0.5", f"guard = 0.5\n{extra}", 1)


def needed(sc) -> float:
    return protocol_of(sc, sc.units[0]).plan.nominal_end()


def test_every_shipped_scenario_keeps_an_hour_and_ends_within_its_schedule():
    for path in sorted((ROOT / "scenarios").glob("*.toml")):
        sc = load_scenario(path)
        assert sc.timing.max_seconds == DEFAULT_MAX_SECONDS > needed(sc), path.name


def test_a_long_schedule_gets_a_default_that_fits_it_and_finishes():
    # a guard of 150 s between codes: 24 turns need about an hour
    sc = parse_scenario(GATE.replace("guard = 0.5", "guard = 150"), "slow_gate.toml")
    need = needed(sc)
    assert need > DEFAULT_MAX_SECONDS / 1.25
    assert sc.timing.max_seconds == default_max_seconds(need) > DEFAULT_MAX_SECONDS
    s = run_group(sc, "memory", NullRecorder()).summary
    assert s["error"] is None and need <= s["sim_seconds"] < sc.timing.max_seconds


def test_a_max_seconds_too_short_for_the_schedule_is_refused_at_load():
    with pytest.raises(RgtbusError) as err:
        parse_scenario(gate("max_seconds = 100"), "g.toml")
    msg = str(err.value)
    assert msg.startswith("g.toml:") and ": timing.max_seconds: 100 s is shorter than the " in msg
    assert "ends at 161.4 s at the earliest" in msg and "timing.stop" in msg and "\n" not in msg
    sc = parse_scenario(gate("max_seconds = 170"), "g.toml")  # enough: the run finishes
    assert run_group(sc, "memory", NullRecorder()).summary["error"] is None


def test_stop_cuts_a_run_on_purpose_and_must_come_after_the_start():
    sc = parse_scenario(gate("stop = 100"), "g.toml")
    s = run_group(sc, "memory", NullRecorder()).summary
    assert s["error"] == "a: stopped at 100 s of simulated time, not finished (timing.stop)"
    assert 100.0 <= s["sim_seconds"] < 110.0  # the units stop at 100 s; the world soon after
    with pytest.raises(RgtbusError, match=r"timing\.stop: stop 0.0005 s is not after start"):
        parse_scenario(gate("stop = 0.0005"), "g.toml")


@pytest.mark.slow
def test_200_units_load_by_default_with_time_for_their_schedule(monkeypatch):
    """The group of the issue: 200 units on the concurrent schedule, written with the
    defaults, load without an override and get the time their schedule needs."""
    from rgtbus.scenario import limits

    monkeypatch.delenv(limits.BUDGET_ENV, raising=False)
    monkeypatch.setattr(limits, "free_memory_mb", lambda: 8192.0)
    sys.path.insert(0, str(ROOT))
    from benchmarks.bench_scale import scale_toml

    text = scale_toml(200, "concurrent").replace("max_seconds = 100000.0\n", "")
    sc = parse_scenario(text, "scale200.toml")
    need = needed(sc)
    assert need > DEFAULT_MAX_SECONDS  # the hour the default was, and the run failed on
    assert sc.timing.max_seconds == default_max_seconds(need)
