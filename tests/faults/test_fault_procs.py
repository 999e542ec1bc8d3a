"""Faults of cross-process runs: units killed, stopped or forged, the launcher interrupted.

Each test starts a real launch (one OS process per unit, zenoh on loopback, multicast off) or
real ``rgtbus unit`` processes. Every wait is bounded and generous; every process is reaped by
``procs`` (or by the launcher, whose own reaping is under test) even when a test fails.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from cut_logs import assert_prefix_is_whole
from rgtbus.units.group import run_group
from rgtbus.units.launch import free_ports
from same_run import plain

from rgtbus.bus.auth import tag
from rgtbus.bus.config import make_config
from rgtbus.bus.hello import Hello, encode_hello
from rgtbus.bus.payload import FINAL, NEVER, Frame, encode
from rgtbus.errors import RgtbusError
from rgtbus.scenario import load_scenario
from rgtbus.telemetry import MemoryRecorder, read_log, scan_log
from rgtbus.telemetry.pulse_blocks import pulse_rows
from rgtbus.telemetry.record_rows import decodes_per_row, pulses_per_row, spikes_per_unit

ROOT = Path(__file__).parent.parent.parent
GATE = str(ROOT / "scenarios" / "gate.toml")
EXE = [sys.executable, "-m", "rgtbus"]
KEY = b"k" * 32


def logged(path: Path) -> int:
    """How many messages the unit's log (written as it goes) holds on disk so far."""
    if not path.exists():
        return 0
    try:
        return len(read_log(path)[0])
    except RgtbusError:
        return 0


def has_pulse(path: Path) -> bool:
    """The run is under way: the unit's log (written as it goes) holds a pulse."""
    if not path.exists():
        return False
    try:
        return any(t == "/tx/pulse" for t, _, _ in read_log(path)[0])
    except RgtbusError:
        return False


def wait_until(pred, what: str, timeout: float = 60.0, alive=()) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        for p in alive:
            assert p.poll() is None, f"ended before {what}: {p.communicate(timeout=30)}"
        if time.monotonic() > deadline:
            pytest.fail(f"not {what} within {timeout:g} s")
        time.sleep(0.1)


def unit_pids(launcher: subprocess.Popen, log_dir: Path, units: list[str]) -> dict[str, int]:
    """The launcher's unit processes, told apart by the log file each holds open."""
    found: dict[str, int] = {}

    def look() -> bool:
        kids = Path(f"/proc/{launcher.pid}/task/{launcher.pid}/children").read_text().split()
        for pid in kids:
            with contextlib.suppress(OSError):
                for fd in Path(f"/proc/{pid}/fd").iterdir():
                    target = os.readlink(fd)
                    for u in units:
                        if target == str(log_dir / f"{u}.mcap"):
                            found[u] = int(pid)
        return len(found) == len(units)

    wait_until(look, "every unit's log open", alive=[launcher])
    return found


def launch(procs, log_dir: Path, *extra: str) -> subprocess.Popen:
    return procs(
        "launch", GATE, "--log-dir", str(log_dir), "--realtime", "20", "--timeout", "3", *extra
    )


def verify_code(path: Path) -> int:
    argv = [*EXE, "replay", str(path), "--verify", "--json"]
    return subprocess.run(argv, capture_output=True, text=True, timeout=120).returncode


@pytest.mark.slow  # one of the longest waits: CI's slow pass runs it
def test_a_unit_killed_outright_is_named_and_nothing_is_lost(procs, tmp_path):
    la = launch(procs, tmp_path)
    pids = unit_pids(la, tmp_path, list("abcd"))
    wait_until(lambda: has_pulse(tmp_path / "a.mcap"), "under way", alive=[la])
    # b has run a while and flushed what it wrote: no sleep that hopes it has
    wait_until(lambda: logged(tmp_path / "b.mcap") > 10, "b's log written", alive=[la])
    os.kill(pids["b"], signal.SIGKILL)
    t0 = time.monotonic()
    _out, err = la.communicate(timeout=60)
    took = time.monotonic() - t0
    assert la.returncode == 1, err
    first = err.strip().splitlines()[0]
    assert first.startswith("launch: unit b died (killed by SIGKILL) in window "), err
    assert took < 3 + 20  # --timeout 3, then a few seconds (generous for a loaded machine)
    assert scan_log(tmp_path / "b.mcap").truncated  # killed: no footer, read to its cut
    b_messages = read_log(tmp_path / "b.mcap")[0]
    assert len(b_messages) > 10  # written as it went
    messages, _metadata = read_log(tmp_path / "run.mcap")
    run = [m for t, _, m in messages if t == "/run"]
    assert len(run) == 1 and run[0]["error"] == first.removeprefix("launch: ")
    # every record of b's is in the merge: a block of spikes b heard alike with others, or of
    # decodes b made alike with them, is in their one record, and b's pulses in its block of
    # time with theirs (the merge joins them), so those are compared one row a unit
    def rows(msgs):
        return {
            (t, ns, json.dumps(m, sort_keys=True, default=plain))
            for t, ns, m in pulses_per_row(decodes_per_row(spikes_per_unit(msgs)))
        }

    assert rows(b_messages) <= rows(messages)
    assert verify_code(tmp_path / "run.mcap") == 3  # ends early: verified only that far


@pytest.mark.slow  # waits out the stall timeout
def test_a_stopped_unit_is_named_and_the_launch_ends(procs, tmp_path):
    la = launch(procs, tmp_path)
    pids = unit_pids(la, tmp_path, list("abcd"))
    wait_until(lambda: has_pulse(tmp_path / "a.mcap"), "under way", alive=[la])
    os.kill(pids["c"], signal.SIGSTOP)
    t0 = time.monotonic()
    _, err = la.communicate(timeout=90)
    took = time.monotonic() - t0
    assert la.returncode == 1, err
    assert err.startswith("launch: unit c stalled in window "), err
    assert "c promised nothing past sample" in err  # the others say why they stopped
    assert took < 3 + 5 + 25  # --timeout, the launcher's few seconds, and slack for load
    with contextlib.suppress(ProcessLookupError):  # reaped: gone, not left stopped
        os.kill(pids["c"], 0)
        pytest.fail("the stalled unit was left behind")
    assert read_log(tmp_path / "c.mcap")  # stopped with SIGTERM + SIGCONT: finished its log
    assert verify_code(tmp_path / "run.mcap") == 3
    assert_prefix_is_whole(tmp_path / "run.mcap", Path(GATE))  # cut by --timeout: right


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_an_interrupted_launch_stops_its_units_and_still_merges(procs, tmp_path, sig):
    la = launch(procs, tmp_path)
    pids = unit_pids(la, tmp_path, list("abcd"))
    wait_until(lambda: has_pulse(tmp_path / "a.mcap"), "under way", alive=[la])
    la.send_signal(sig)
    _out, err = la.communicate(timeout=60)
    assert la.returncode == 130, err
    assert "Traceback" not in err
    assert "interrupted" in err.splitlines()[0]
    for pid in pids.values():
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, 0)
            pytest.fail("a unit was left running")
    messages, _ = read_log(tmp_path / "run.mcap")
    assert next(m["error"] for t, _, m in messages if t == "/run").startswith("launch interrupted")
    assert verify_code(tmp_path / "run.mcap") == 3


def test_a_clean_launch_and_its_hand_merge_verify(procs, tmp_path):
    la = procs("launch", GATE, "--log-dir", str(tmp_path), "--json")
    _out, err = la.communicate(timeout=120)
    assert la.returncode == 0, err
    assert verify_code(tmp_path / "run.mcap") == 0
    hand = tmp_path / "hand.mcap"
    merge = [*EXE, "merge", *(str(tmp_path / f"{u}.mcap") for u in "abcd"), "-o", str(hand)]
    assert subprocess.run(merge, capture_output=True, timeout=60).returncode == 0
    assert verify_code(hand) == 0  # no launcher, no /run: every unit ended done
    # A hand merge that leaves a unit out is no whole run.
    part = tmp_path / "part.mcap"
    merge = [*EXE, "merge", *(str(tmp_path / f"{u}.mcap") for u in "abc"), "-o", str(part)]
    assert subprocess.run(merge, capture_output=True, timeout=60).returncode == 0
    assert verify_code(part) == 1


def single(name: str):
    sc = load_scenario(ROOT / "scenarios" / f"{name}.toml")
    return run_group(sc, "memory", MemoryRecorder()).summary


@pytest.mark.slow  # one of the longest waits: CI's slow pass runs it
def test_a_keyed_launch_refuses_forged_frames_and_equals_the_single_run(procs, tmp_path):
    key_file = tmp_path / "key"
    key_file.write_bytes(KEY + b"\n")
    ports = free_ports(4)
    started = {}
    for i, name in enumerate("abcd"):
        net = ["--listen", f"tcp/127.0.0.1:{ports[i]}"]
        for j in range(i):
            net += ["--connect", f"tcp/127.0.0.1:{ports[j]}"]
        started[name] = procs(
            "unit", name, GATE, *net, "--log", str(tmp_path / f"{name}.mcap"), "--json",
            "--run-id", "k1", "--key-file", str(key_file), "--realtime", "40",
        )  # fmt: skip
    stop = threading.Event()
    body = Frame(1, NEVER, np.zeros(0, dtype=np.int64), np.zeros(0), FINAL, 0)
    forged = [
        encode(body, 200.0),  # unsigned: the attack that used to end a run with exit 0
        encode(body, 200.0, sign=lambda b: tag(b"x" * 32, "frame", "k1", "a", b"\0" * 16, b)),
    ]

    unsigned_hello = encode_hello(Hello("c", "0" * 64, b"\0" * 16), "k1", None)

    def mallory() -> None:
        session = zenoh.open(make_config(mode="peer", connect=[f"tcp/127.0.0.1:{ports[0]}"]))
        try:
            while not stop.wait(0.02):
                for u in "abcd":
                    for data in forged:
                        session.put(f"rgtbus/k1/tx/{u}", data)
                session.put("rgtbus/k1/hello/a", b'{"heard": [[1]]}')
                session.put("rgtbus/k1/hello/b", b"[" * 60_000)  # nested past the recursion limit
                session.put("rgtbus/k1/hello/c", unsigned_hello)
        finally:
            session.close()

    thread = threading.Thread(target=mallory, daemon=True)
    thread.start()
    try:
        outs = {}
        for name, p in started.items():
            out, err = p.communicate(timeout=90)
            assert p.returncode == 0, err
            outs[name] = json.loads(out)
    finally:
        stop.set()
        thread.join(timeout=15)
    ref = single("gate")
    for name, out in outs.items():
        assert out["report"]["result"] == ref["units"][name]
        assert out["bus"]["dropped_unauthenticated"] > 0
        messages, metadata = read_log(tmp_path / f"{name}.mcap")
        assert metadata["run"]["auth"] == "hmac-sha256"
        assert KEY.decode() not in json.dumps(metadata)  # the key itself is never logged
        assert any("not authenticated" in m.get("message", "") for t, _, m in messages)


@pytest.mark.slow  # a few seconds: CI's slow pass (the fast suite stays near 3 min)
def test_a_unit_without_the_key_cannot_join_and_says_so_in_its_log(procs, tmp_path):
    key_file = tmp_path / "key"
    key_file.write_bytes(KEY)
    ports = free_ports(2)
    common = ["--run-id", "k2", "--join-timeout", "4"]
    a = procs(
        "unit", "a", GATE, "--listen", f"tcp/127.0.0.1:{ports[0]}", "--log",
        str(tmp_path / "a.mcap"), "--key-file", str(key_file), *common,
    )  # fmt: skip
    b = procs(
        "unit", "b", GATE, "--connect", f"tcp/127.0.0.1:{ports[0]}", "--log",
        str(tmp_path / "b.mcap"), *common,
    )  # fmt: skip
    _, err_a = a.communicate(timeout=60)
    _, err_b = b.communicate(timeout=60)
    assert a.returncode != 0 and b.returncode != 0
    assert "joining run 'k2' timed out" in err_a and "joining run 'k2' timed out" in err_b
    messages, metadata = read_log(tmp_path / "a.mcap")
    lines = [m["message"] for t, _, m in messages if t == "/log"]
    assert any("join failed" in x for x in lines), lines
    assert any("hello of 'b' not authenticated" in x for x in lines), lines
    assert metadata["end.a"]["status"] == "ended early"


def own_records(path: Path, unit: str) -> list[str]:
    """The topics of what ``unit`` logged of its own (not the medium logged ahead; a block of
    pulses holding one of its)."""
    return [
        t
        for t, _, m in read_log(path)[0]
        if t != "/medium"
        and (
            m.get("unit") == unit
            or (t == "/tx/pulse" and any(p["unit"] == unit for p in pulse_rows(m)))
        )
    ]


@pytest.mark.slow  # ten unit processes, paced
def test_a_killed_unit_of_a_paced_crowd_loses_little_and_the_survivors_report(procs, tmp_path):
    """crowd10 at --realtime 25, one unit killed outright once it has logged its own pulses:
    its log keeps its own records (flushed by wall time, not held back by the medium written
    ahead), the launcher names it first, keeps the nine survivors' results, and the merged
    log reads as truncated with everything before the cut agreeing."""
    sc = load_scenario(ROOT / "scenarios" / "crowd10.toml")
    victim = sc.units[7]
    la = procs(
        "launch", str(ROOT / "scenarios" / "crowd10.toml"), "--log-dir", str(tmp_path),
        "--realtime", "25", "--timeout", "3", "--json",
    )  # fmt: skip
    pids = unit_pids(la, tmp_path, list(sc.units))
    log = tmp_path / f"{victim}.mcap"

    def victim_sent() -> bool:
        with contextlib.suppress(RgtbusError, OSError):
            return "/tx/pulse" in own_records(log, victim)
        return False

    wait_until(victim_sent, f"{victim} has logged a pulse of its own", alive=[la])
    os.kill(pids[victim], signal.SIGKILL)
    out, err = la.communicate(timeout=180)
    assert la.returncode == 1, err
    summary = json.loads(out)
    assert summary["error"].startswith(f"unit {victim} died (killed by SIGKILL)"), summary
    assert err.strip().splitlines()[0] == f"launch: {summary['error']}"
    survivors = sorted(u for u in sc.units if u != victim)
    assert sorted(summary["units"]) == survivors, (summary["error"], err)
    assert "/tx/pulse" in own_records(log, victim)  # its own records were not lost
    assert verify_code(tmp_path / "run.mcap") == 3


@pytest.mark.slow  # a stop of a few seconds, and the others' timeout
def test_a_unit_stopped_and_resumed_names_itself_the_late_one(procs, tmp_path):
    """SIGSTOP of unit b for longer than the others' timeout, then SIGCONT: the others give up
    on b, and b, resumed, names itself as the late one (its process did not run), not the
    others; the launcher names b first and keeps every unit's result."""
    la = launch(procs, tmp_path, "--json")
    pids = unit_pids(la, tmp_path, list("abcd"))
    wait_until(lambda: has_pulse(tmp_path / "a.mcap"), "under way", alive=[la])
    os.kill(pids["b"], signal.SIGSTOP)
    time.sleep(3 + 2)  # --timeout 3: the others have given up by then
    os.kill(pids["b"], signal.SIGCONT)
    out, err = la.communicate(timeout=90)
    assert la.returncode == 1, err
    summary = json.loads(out)
    assert summary["error"].startswith("unit b: its process did not run for "), summary["error"]
    assert "the late one" in summary["error"]
    assert sorted(summary["units"]) == ["a", "b", "c", "d"]
    lines = err.strip().splitlines()
    assert lines[0] == f"launch: {summary['error']}"
    others = [ln for ln in lines[1:] if ln.startswith(("launch: unit a", "launch: unit c"))]
    assert others and all("b promised nothing past sample" in ln for ln in others), err


@pytest.mark.slow  # three paced launches
@pytest.mark.parametrize("after", [1, 3, 5])
def test_every_healthy_unit_is_kept_whenever_one_is_killed(procs, tmp_path, after):
    """kill -9 of one unit of a paced concurrent launch at different moments: the launcher
    names it (and only it) as the cause, and every other unit's result is in the summary."""
    text = (ROOT / "scenarios" / "crowd10.toml").read_text()
    sc = load_scenario(ROOT / "scenarios" / "crowd10.toml")
    victim = sc.units[3]
    path = tmp_path / "crowd.toml"
    path.write_text(text)
    logs = tmp_path / "logs"
    la = procs("launch", str(path), "--log-dir", str(logs), "--realtime", "25", "--timeout", "3",
               "--json")  # fmt: skip
    pids = unit_pids(la, logs, list(sc.units))
    wait_until(lambda: has_pulse(logs / f"{victim}.mcap"), "under way", alive=[la])
    time.sleep(after)
    if la.poll() is not None:
        pytest.skip("the run ended before the kill: nothing to test at this moment")
    os.kill(pids[victim], signal.SIGKILL)
    out, err = la.communicate(timeout=180)
    summary = json.loads(out)
    if la.returncode == 0:  # it had already finished: every result is there anyway
        assert sorted(summary["units"]) == sorted(sc.units)
        return
    assert summary["error"].startswith(f"unit {victim} died (killed by SIGKILL)"), summary
    assert sorted(summary["units"]) == sorted(u for u in sc.units if u != victim), err
    lines = err.strip().splitlines()
    assert lines[0] == f"launch: {summary['error']}", err
    # every other unit names the victim: it left (its session ended), or it fell silent
    assert all(f": {victim} left run " in ln or f": {victim} did not say it was done" in ln
               or f": {victim} promised" in ln for ln in lines[1:]), err  # fmt: skip
    # the merged log reads as truncated, and what came before the cut agrees with a re-run
    argv = [*EXE, "replay", str(logs / "run.mcap"), "--verify", "--json"]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    report = json.loads(done.stdout)
    assert done.returncode == 3 and report["truncated"], report
    assert not report["mismatches"], report
    # no further than the victim's log goes (a unit killed before its first flush of
    # decodes verifies nothing past the start: its records are complete only that far)
    victim_end = max(t for _, t, _ in read_log(logs / f"{victim}.mcap")[0]) / 1e9
    assert 0 <= report["until"] <= victim_end, (report["until"], victim_end)
    # and right: every unit's pulses, spikes and decodes before it are there, within a few
    # seconds of the last spikes logged (not back at the start)
    assert assert_prefix_is_whole(logs / "run.mcap", path) == report["until"]


@pytest.mark.slow  # five unit processes and a router, twice
@pytest.mark.parametrize("gap", [0.1, 1.0])
def test_a_second_process_claiming_a_unit_never_takes_its_place(procs, tmp_path, gap):
    """Units a, c, d and b of a keyed run through a router, and ``gap`` seconds after b a
    second process that says it is b (it has the run key): the real b is never refused in
    favour of it. Either both claimants (and everyone who heard both) stop the join with one
    line naming b and both, or the real b runs and the later one is refused as too late."""
    key = tmp_path / "key"
    key.write_bytes(os.urandom(32))
    ep = f"tcp/127.0.0.1:{free_ports(1)[0]}"
    router = procs("router", "-l", ep)
    assert router.stdout.readline().startswith("router listening")
    common = ["--mode", "client", "-e", ep, "--key-file", str(key), "--run-id", "claims",
              "--realtime", "40", "--timeout", "5", "--join-timeout", "20"]  # fmt: skip

    def unit(name: str, log: str) -> subprocess.Popen:
        return procs("unit", name, GATE, "--log", str(tmp_path / log), *common)

    ps = {u: unit(u, f"{u}.mcap") for u in "acd"}
    ps["b"] = unit("b", "b.mcap")
    time.sleep(gap)
    ps["b2"] = unit("b", "b2.mcap")
    said = {n: (p.wait(timeout=120), p.communicate(timeout=30)[1]) for n, p in ps.items()}
    conflict = "two processes claim unit 'b' of run 'claims': "
    late = "'b' joined too late"
    (b_code, b_err), (b2_code, b2_err) = said["b"], said["b2"]
    assert late not in b_err, said  # the real b is never the one refused as late
    if conflict in b_err:
        # b2 stops too: it heard both claims, or a member that had already started (which
        # finished its join with the real b before b2 spoke) refused it as late
        assert b_code == 2 and b2_code == 2 and (conflict in b2_err or late in b2_err), said
        # and nobody started without b: every member stopped its join, naming the conflict
        # (or, ready before it came, timed out waiting for b, naming it too)
        assert all(said[u][0] == 2 and conflict in said[u][1] for u in "acd"), said
    else:
        assert b_code == 0 and b2_code == 2 and (late in b2_err or conflict in b2_err), said
        assert all(said[u][0] == 0 for u in "acd"), said
