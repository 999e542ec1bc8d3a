"""Whether the time a cut log is verified to is right (issue 35, item 4): the shared check of
the crash tests (tests/test_crash_consistency.py) and the process faults
(tests/faults/test_fault_procs.py)."""

from __future__ import annotations

import contextlib
import functools
import io
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mcap.reader import NonSeekingReader, make_reader
from rgtbus.units.rerun import verify_log

import rgtbus
from rgtbus.telemetry.read import Replay, load_replay
from rgtbus.timebase import ns

ROOT = Path(__file__).parent.parent
CROWD10 = ROOT / "scenarios" / "crowd10.toml"
EXE = [sys.executable, "-m", "rgtbus"]

# how far behind a cut log's last block of spikes its verified time may stay: a decode block
# (5 s, unit_log.DECODE_BLOCK_SECONDS), twice where a record cuts one, and a block of spikes.
# 60 s decode blocks left a paced run killed at 95 s verified to 60 s.
SLACK_SECONDS = 12.0


@functools.cache
def _whole(scenario: str, text: str) -> Replay:
    buf = io.BytesIO()
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "whole.mcap"
        rgtbus.run(Path(scenario), log=log)
        buf.write(log.read_bytes())
    buf.seek(0)
    return load_replay(buf)


def whole_run(scenario: Path) -> Replay:
    """``scenario`` run to its end (unpaced, memory bus), once a scenario text: what a cut
    run's log is part of. Read whole into memory (a stream: nothing read from a file later)."""
    return _whole(str(scenario), scenario.read_text())


def what_units_did(rp: Replay, until: float) -> Counter[tuple[Any, ...]]:
    """Every pulse sent, spike heard and code decoded before ``until`` seconds, one entry each
    however the log grouped them into records."""
    did: Counter[tuple[Any, ...]] = Counter()
    for p in rp.pulses():  # each pulse at its own time (a block holds a sender's 5 s)
        if ns(p["t"]) < ns(until):
            did["pulse", p["unit"], p["sample"], p["magnitude"]] += 1
    for s in rp.spikes.rows(rp.spikes.t < until):
        did["spike", s["unit"], s["sample"], s["channel"]] += 1
    for t_ns, d in rp.decode_records:
        if t_ns < ns(until):
            did["decode", d["unit"], t_ns, d["sender"], d["kind"], d["code"]] += 1
    return did


def assert_prefix_is_whole(log: Path, scenario: Path) -> float:
    """The time a cut log of a run of ``scenario`` is verified to (``VerifyReport.until``) is
    right: before it, every pulse, spike and decode of every unit of the run to its end is in
    the log, and none more; and it reaches to within ``SLACK_SECONDS`` of the last spikes of
    the unit whose log ends first, not back to the start. Returns it."""
    report = verify_log(log)
    assert report.truncated and not report.mismatches and report.until is not None, (
        report.verdict()
    )
    cut = load_replay(log)
    assert what_units_did(cut, report.until) == what_units_did(whole_run(scenario), report.until)
    # the unit whose log ends first bounds it (the others of a launch may run to the end)
    table = cut.spikes
    last = {u: float(table.t[table.unit == i].max(initial=0.0)) for i, u in enumerate(table.units)}
    first_to_end = min(last.values(), default=0.0)
    assert report.until >= first_to_end - SLACK_SECONDS, (report.until, last)
    return report.until


def standard_read(data: bytes) -> list[int]:
    """The log times every standard reader finds (seeking and not, in log-time order: the
    default), which must agree; any error fails the test."""
    seeking = [m.log_time for _, _, m in make_reader(io.BytesIO(data)).iter_messages()]
    streaming = [m.log_time for _, _, m in NonSeekingReader(io.BytesIO(data)).iter_messages()]
    assert seeking == streaming
    return seeking


def _bytes(log: Path) -> bytes:
    """What ``log`` holds now: nothing if it is not there yet."""
    try:
        return log.read_bytes()
    except FileNotFoundError:
        return b""


@contextlib.contextmanager
def paced_run(log: Path, grown: int) -> Iterator[subprocess.Popen[str]]:
    """A paced crowd10 ``rgtbus run`` logging to ``log``, handed over once its log holds more
    than ``grown`` messages to the standard readers (bounded wait); killed if still running."""
    argv = [*EXE, "run", str(CROWD10), "--realtime", "25",
            "--log", str(log), "--quiet"]  # fmt: skip
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        # the file is created empty before its writer's first flush (the header and the
        # run's records): empty is not begun; any other state must be whole to every reader
        while not ((data := _bytes(log)) and len(standard_read(data)) > grown):
            assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
            assert time.monotonic() < deadline, f"the log never grew past {grown} messages"
            time.sleep(0.2)
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
