"""The launcher's parts that need no process of their own: who is late, what a log keeps of
a unit whose process said nothing, whether a process is stopped."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import time

import pytest
from rgtbus.units.group import run_group
from rgtbus.units.launch import LaunchProcesses, _is_stopped, default_timeout, recovered
from rgtbus.units.process import PauseWatch, join_seconds, lateness

from rgtbus.scenario import load_scenario
from rgtbus.telemetry import McapRecorder

GATE = load_scenario("gate")


def test_a_process_that_did_not_run_for_half_the_timeout_is_the_late_one():
    assert lateness(["b"], GATE, ["a"], paused=0.4, timeout=10) is None  # a is the cause
    late = lateness(["b"], GATE, ["a"], paused=6.0, timeout=10)
    assert late is not None and late.startswith("unit b: its process did not run for 6.0 s")
    assert lateness(["b"], GATE, [], paused=60.0, timeout=10) is None  # nobody given up on


def test_a_process_that_hears_nobody_is_cut_off_itself():
    late = lateness(["b"], GATE, ["a", "c", "d"], paused=0.0, timeout=10)
    assert late is not None and "cut off" in late and late.startswith("unit b:")
    assert lateness(["b"], GATE, ["a", "c"], paused=0.0, timeout=10) is None  # d still spoke
    two = lateness(["a", "b"], GATE, ["c", "d"], paused=0.0, timeout=10)
    assert two is not None and two.startswith("units a, b:")


def test_the_pause_watch_sees_a_process_that_did_not_run():
    with PauseWatch() as watch:
        time.sleep(0.5)
    assert watch.longest < 0.4  # ran all along (generous: a loaded machine)


def test_a_stopped_process_is_seen_stopped():
    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        assert not _is_stopped(p.pid)
        p.send_signal(signal.SIGSTOP)
        deadline = time.monotonic() + 10
        while not _is_stopped(p.pid):
            assert time.monotonic() < deadline, "never seen stopped"
            time.sleep(0.01)
        p.send_signal(signal.SIGCONT)
    finally:
        p.kill()
        p.wait(timeout=30)
    assert not _is_stopped(None)


def test_a_units_part_is_recovered_from_its_log_only_when_it_holds_its_report(tmp_path):
    buf = io.BytesIO()
    rec = McapRecorder(buf)
    out = run_group(GATE, "memory", rec)
    rec.close()
    log = tmp_path / "gate.mcap"
    log.write_bytes(buf.getvalue())
    part = recovered("b", log)
    assert part is not None and part["from_log"] and part["error"] is None
    assert part["report"]["result"] == out.summary["units"]["b"]
    assert len(part["report"]["decodes"]) == len(out.units[1].decoded)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(buf.getvalue()[: len(buf.getvalue()) // 3])  # before any report
    assert recovered("b", cut) is None
    assert recovered("b", tmp_path / "missing.mcap") is None


def test_the_join_allowance_grows_with_the_members():
    assert join_seconds(4) < join_seconds(100) and join_seconds(100) >= 100


def _beating_child(conn, steps, then):
    """A stand-in for a unit process: beats ``steps`` (0.05 s apart), then says ``then``
    (None: says nothing more, and lives on)."""
    for s in steps:
        conn.send({"beat": s})
        time.sleep(0.05)
    if then is not None:
        conn.send(then)
    time.sleep(60)


def _start(processes, name, steps, then):
    reader, writer = processes._mp.Pipe(duplex=False)
    proc = processes._mp.Process(target=_beating_child, args=(writer, steps, then), daemon=True)
    proc.start()
    writer.close()
    processes.procs[name] = proc
    processes._results[name] = reader


@pytest.mark.slow  # 3 s of waiting: CI's slow pass (the fast suite stays near 3 min)
def test_the_launcher_waits_while_a_world_moves_and_calls_stalled_one_that_stopped_moving():
    """No wall-clock limit on a run: a process whose world moves (its beats) is waited for as
    long as it moves; one whose world stopped moving for ``stall_after`` is stalled (absent
    from the results); a beat is never taken for a result."""
    processes = LaunchProcesses(fork=True)
    try:
        _start(processes, "moving", list(range(40)), {"units": {"a": {"report": 1}}})  # ~2 s
        _start(processes, "stuck", [1, 2, 2, 2, 2], None)  # stops moving at once
        t0 = time.monotonic()
        out = processes.collect(first=30.0, stall_after=1.5, timeout=10.0)
        took = time.monotonic() - t0
    finally:
        processes.reap()
    assert out == {"moving": {"units": {"a": {"report": 1}}}}, out
    assert 1.5 <= took < 25, took  # the stuck one: 1.5 s after its last move, not `first`


def test_a_launch_waits_longer_when_its_processes_outnumber_the_cores():
    cores = len(os.sched_getaffinity(0))
    assert default_timeout(1) == 10.0
    assert default_timeout(cores) == 10.0
    assert default_timeout(10 * cores) == 100.0
