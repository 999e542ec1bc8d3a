"""Floods across processes: a keyless process on a routed keyed run cannot stop or sway it.

A real ``rgtbus router``, four real ``rgtbus unit`` processes of scenario gate as its clients
(one shared key file, paced so a flood lasts the whole run) and a real
``benchmarks.flooder`` without the key (issue 50): first the clean run, then the same run
flooded. Every unit must end ok, decide as in the clean run, count the junk and accept none of
it. The harness (benchmarks/bench_flood.py) bounds every run and kills every process it
started, even when a run hangs or fails.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

PACE = 25  # --realtime: the gate's 162 simulated seconds take about 6.5 s of wall time
RUN_TIMEOUT = 300.0  # one run, generous: the machine may be loaded


def failures(case: dict[str, Any]) -> dict[str, str]:
    """Each unit that did not end ok, with its error line."""
    return {u: f"exit {d['rc']}: {d['error']}" for u, d in case["units"].items() if not d["ok"]}


@pytest.mark.slow  # two routed runs of four unit processes each, one of them flooded
@pytest.mark.parametrize("mode", ["mixed", "near", "replay"])
def test_a_routed_keyed_run_flooded_by_a_keyless_process_decides_as_the_clean_run(
    tmp_path: Path, mode: str
) -> None:
    """mixed: 256 KB and 4 KB frames with a wrong tag on every member's key; replay: the
    run's own frames, captured as they go by and put again and again. Every unit ends ok,
    decides as in the clean run (its whole report), has dropped frames (counted) and accepted
    exactly what it accepted in the clean run."""
    from benchmarks.bench_flood import MEMBERS, bus, decisions, dropped, run_case

    clean = run_case(tmp_path / "clean", None, realtime=PACE, run_timeout=RUN_TIMEOUT)
    assert not clean["timed_out"], clean["wall_s"]
    assert not failures(clean), failures(clean)

    dirty = run_case(tmp_path / mode, mode, realtime=PACE, run_timeout=RUN_TIMEOUT)
    flooder = dirty["flooder"]
    assert flooder is not None and flooder["matched"], (dirty["flooder_rc"], dirty["flooder_err"])
    assert flooder["frames"] > 0, flooder  # the flood went out
    assert not dirty["timed_out"], (dirty["wall_s"], failures(dirty))
    assert not failures(dirty), failures(dirty)
    for u in MEMBERS:
        got, ref = dirty["units"][u]["summary"], clean["units"][u]["summary"]
        assert decisions(got) == decisions(ref), u
        stats = bus(dirty, u)
        assert dropped(dirty, u), (u, stats)  # the junk reached it and was counted
        assert stats["accepted"] == bus(clean, u)["accepted"], (u, stats, bus(clean, u))
