"""A live run steered from Foxglove's side (issue 55): the official Foxglove WebSocket client
(@foxglove/ws-protocol, tests/js/steer_client.mjs) sets a parameter and injects influences
into a paced ``rgtbus run --live --control``; the units decide as the forward task says, the
changes are in the log, and ``replay --verify`` re-runs the steered log to agreement. On a
keyed run an unkeyed client's calls are refused, and logged."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from rgtbus.units.rerun import verify_log

from rgtbus.telemetry.read import load_replay

JS = Path(__file__).parent / "js"
NODE = shutil.which("node")
pytestmark = pytest.mark.skipif(
    NODE is None or not (JS / "node_modules" / "@foxglove" / "ws-protocol").is_dir(),
    reason="no Node.js, or no npm ci --prefix tests/js (where .ci/run installs the client)",
)
WAIT = 120.0  # s: a bound, never a pace


def steered_run(tmp_path: Path, steps: list[dict], *extra: str) -> tuple[dict, list[dict], Path]:
    """Run gate paced, steered by the client taking ``steps``: (the run's --json summary, what
    the client printed, the log)."""
    log = tmp_path / "steered.mcap"
    run = subprocess.Popen(
        [sys.executable, "-m", "rgtbus", "run", "gate", "--log", str(log), "--live",
         "127.0.0.1:0", "--realtime", "40", "--control", "--live-wait", str(WAIT), "--json",
         *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    try:
        url, seen = None, []
        deadline = time.monotonic() + WAIT
        assert run.stderr is not None
        while url is None and time.monotonic() < deadline:
            line = run.stderr.readline()
            if not line:
                break
            seen.append(line)
            m = re.search(r"ws://[0-9.]+:\d+", line)
            url = m.group(0) if m else None
        assert url, "".join(seen)
        rest: list[str] = []
        drain = threading.Thread(target=lambda: rest.extend(run.stderr), daemon=True)  # type: ignore[arg-type]
        drain.start()
        (tmp_path / "steps.json").write_text(json.dumps(steps))
        client = subprocess.run(
            [NODE, "steer_client.mjs", url, str(tmp_path / "steps.json")],  # type: ignore[list-item]
            cwd=JS, capture_output=True, text=True, timeout=WAIT,
        )  # fmt: skip
        assert client.returncode == 0, client.stderr
        out, _ = run.communicate(timeout=WAIT)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    printed = [json.loads(line) for line in client.stdout.splitlines()]
    assert {"op": "timeout"} not in printed, printed
    return json.loads(out), printed, log


def listening(port: int) -> None:
    """Wait (bounded) until something accepts TCP connections on ``port`` of the loopback."""
    import socket

    deadline = time.monotonic() + WAIT
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
            return
        except OSError:
            assert time.monotonic() < deadline, f"nothing listens on port {port}"
            time.sleep(0.05)


def logged(log: Path, topic: str) -> list[dict]:
    return [m for _, m in load_replay(str(log)).by_topic[topic]]


def test_a_live_run_is_steered_by_the_official_client_and_verified(tmp_path):
    steps = [
        {"get": ["channel.noise", "channel.gains.d>a", "pace"]},
        {"call": "/control/influence", "request": {"influence": "d>a=0"}},
        {"call": "/control/influence", "request": {"influence": "d>b=0"}},
        {"set": {"channel.noise": 0.02}},
        {"call": "/control/influence", "request": {"influence": "q>a=0"}},
        {"call": "/control/mark", "request": {"label": "steered"}},
    ]
    summary, printed, log = steered_run(tmp_path, steps)
    info = next(p["info"] for p in printed if p["op"] == "serverInfo")
    assert {"parameters", "services", "time"} <= set(info["capabilities"])
    got = next(p for p in printed if p["op"] == "parameters" and p["id"] == "get-1")
    assert {p["name"]: p["value"] for p in got["parameters"]} == {
        "channel.noise": 0, "channel.gains.d>a": 1, "pace": 40,
    }  # fmt: skip
    answers = [p for p in printed if p["op"] in ("answer", "failure")]
    assert [a["op"] for a in answers] == ["answer", "answer", "failure", "answer"]
    assert "unknown unit 'q'" in answers[2]["message"]
    # the units decided as the forward task says on what was injected
    assert summary["error"] is None
    assert summary["outcome"] == "gate: closed"
    assert summary["units"]["a"]["choice"] == [] and summary["units"]["c"]["choice"] == ["open"]
    assert summary["wrong_decisions"] == [] and summary["steered"]["influences"] == 2
    # in the log, as the client saw them live
    services = logged(log, "/control/service")
    params = logged(log, "/control/parameter")
    assert [(s["service"], s["applied"]) for s in services] == [
        ("influence", True), ("influence", True), ("influence", False), *[("mark", True)] * 4,
    ]  # fmt: skip
    assert [(p["name"], p["from"], p["to"], p["applied"]) for p in params] == [
        ("channel.noise", 0, 0.02, True)
    ]
    streamed = [p["message"] for p in printed if p["op"] == "control"]
    assert sorted(m["seq"] for m in streamed) == sorted(m["seq"] for m in services + params)
    assert all(s["who"] == services[0]["who"] for s in services)
    report = verify_log(log)
    assert report.ok, report.verdict()
    verify = subprocess.run(
        [sys.executable, "-m", "rgtbus", "replay", str(log), "--verify"],
        capture_output=True, text=True, timeout=WAIT,
    )  # fmt: skip
    assert verify.returncode == 0, verify.stdout + verify.stderr


def test_on_a_keyed_run_an_unkeyed_clients_calls_are_refused_and_logged(tmp_path):
    key = "a-test-key-of-thirty-two-bytes!!"
    (tmp_path / "run.key").write_text(key + "\n")
    steps = [
        {"call": "/control/influence", "request": {"influence": "d>a=0"}},
        {"set": {"channel.noise": 0.05}},
        {"auth": "00" * 32},
        {"auth_key": key},
        {"call": "/control/mark", "request": {"label": "after auth"}},
    ]
    summary, printed, log = steered_run(tmp_path, steps, "--key-file", str(tmp_path / "run.key"))
    answers = [p for p in printed if p["op"] in ("answer", "failure")]
    assert [a["op"] for a in answers] == ["failure", "failure", "answer", "answer"]
    assert "not allowed" in answers[0]["message"]
    assert "wrong proof" in answers[1]["message"]
    noise = next(p for p in printed if p["op"] == "parameters")
    assert {p["name"]: p["value"] for p in noise["parameters"]}["channel.noise"] == 0
    assert summary["outcome"] == "gate: open" and summary["steered"]["influences"] == 0
    services = logged(log, "/control/service")
    params = logged(log, "/control/parameter")
    assert [(s["service"], s["applied"]) for s in services] == [
        ("influence", False), ("auth", False), ("auth", True), *[("mark", True)] * 4,
    ]  # fmt: skip
    assert services[0]["text"].startswith("refused: not allowed: this run is keyed")
    assert params[0]["applied"] is False and params[0]["text"].startswith("refused: not allowed")
    assert not re.search(r"[0-9a-f]{64}", json.dumps(services))  # a proof is never logged
    assert verify_log(log).ok


@pytest.mark.slow  # it sleeps to watch the clock stand still (CI's slow pass runs it)
def test_pause_step_and_resume_hold_the_live_clock(tmp_path):
    steps = [
        {"call": "/control/pause"},
        {"sleep": 800},
        {"sleep": 500},  # paused: the server's time stands still
        {"call": "/control/step", "request": {"by": "window"}},
        {"sleep": 500},  # one window on, paused again
        {"call": "/control/resume"},
    ]
    summary, printed, log = steered_run(tmp_path, steps)
    assert summary["error"] is None and summary["outcome"] == "gate: open"
    t1, t2, t3 = (int(p["time"]) for p in printed if p["op"] == "time")
    assert t1 == t2 < t3
    pause, step, resume = logged(log, "/control/service")
    assert [pause["service"], step["service"], resume["service"]] == ["pause", "step", "resume"]
    assert pause["applied"] and step["applied"] and resume["applied"]
    assert step["sample"] == pause["sample"] and step["until"] == pause["sample"] + 20
    assert resume["sample"] == step["until"]
    at = round(pause["t"] * 1e9)
    assert at - 100_000_000 <= t2 <= at  # the view's clock stood at the pause, not past it
    assert verify_log(log).ok


@pytest.mark.slow  # a router, a watcher and a launch of two processes (CI's slow pass runs it)
def test_a_launch_is_steered_through_the_watcher_at_one_instant_in_every_process(tmp_path):
    """The official client steers a launch of two processes through `rgtbus watch --control`:
    both processes apply each change at the same sample, the units decide as the forward task
    says, and the merged log holds what one process would have logged for the same changes at
    that sample, and verifies."""
    import queue

    from rgtbus.units.launch import free_ports

    import rgtbus
    from rgtbus.engine.steering import RequestSource
    from rgtbus.steering import Request

    (port,) = free_ports(1)
    router_ep = f"tcp/127.0.0.1:{port}"
    exe = [sys.executable, "-m", "rgtbus"]
    spawned: list[subprocess.Popen] = []

    def spawn(*argv: str) -> subprocess.Popen:
        p = subprocess.Popen([*exe, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             stdin=subprocess.DEVNULL, text=True)  # fmt: skip
        spawned.append(p)
        return p

    try:
        spawn("router", "-l", router_ep)
        listening(port)  # the watcher, a client, opens only once the router listens
        watcher = spawn(
            "watch", "-m", "client", "-e", router_ep, "--control", "--scenario", "gate",
            "--live", "127.0.0.1:0", "--idle-exit", "5",
        )  # fmt: skip
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(
            target=lambda: [lines.put(x) for x in watcher.stderr],
            daemon=True,  # type: ignore[union-attr]
        ).start()
        url, said = None, []
        deadline = time.monotonic() + WAIT
        while url is None:
            assert time.monotonic() < deadline, "".join(said)
            try:
                said.append(lines.get(timeout=1.0))
            except queue.Empty:
                assert watcher.poll() is None, "".join(said)  # it ended, saying why
                continue
            m = re.search(r"ws://[0-9.]+:\d+", said[-1])
            url = m.group(0) if m else None
        run_dir = tmp_path / "run"
        launch = spawn(
            "launch", "gate", "--procs", "2", "-m", "client", "-e", router_ep, "--control",
            "--realtime", "20", "--log-dir", str(run_dir), "--json",
        )  # fmt: skip
        steps = [
            {"sleep": 1000},
            {"call": "/control/influence", "request": {"influence": "d>a=0"}},
            {"call": "/control/influence", "request": {"influence": "d>b=0"}},
            {"set": {"channel.noise": 0.02}},
        ]
        (tmp_path / "steps.json").write_text(json.dumps(steps))
        client = subprocess.run(
            [NODE, "steer_client.mjs", url, str(tmp_path / "steps.json")],  # type: ignore[list-item]
            cwd=JS, capture_output=True, text=True, timeout=WAIT * 2,
        )  # fmt: skip
        assert client.returncode == 0, client.stderr
        out, err = launch.communicate(timeout=WAIT * 2)
        assert launch.returncode == 0, err
    finally:
        for p in spawned:
            if p.poll() is None:
                p.terminate()
        for p in spawned:
            try:
                p.wait(timeout=WAIT)
            except subprocess.TimeoutExpired:
                p.kill()
    summary = json.loads(out)
    assert summary["outcome"] == "gate: closed" and summary["wrong_decisions"] == []
    assert summary["steered"] == {"influences": 2, "relations": 0}
    # every process applied the noise at the same sample
    samples = {
        m["sample"]
        for log in run_dir.glob("proc-*.mcap")
        for m in logged(log, "/control/parameter")
    }
    assert len(samples) == 1 and len(list(run_dir.glob("proc-*.mcap"))) == 2
    merged = run_dir / "run.mcap"
    assert verify_log(merged).ok
    # the same changes at the same sample in one process: the same records
    (sample,) = samples
    requests = [
        Request("service", "influence", {"influence": "d>a=0"}, "client 1"),
        Request("service", "influence", {"influence": "d>b=0"}, "client 1"),
        Request("parameter", "channel.noise", 0.02, "client 1"),
    ]

    class Placed(RequestSource):
        def __init__(self) -> None:
            self.requests = [r.placed(sample, k) for k, r in enumerate(requests)]

        def take(self) -> list[Request]:
            out, self.requests = self.requests, []
            return out

    one = rgtbus.run("gate", log=tmp_path / "one.mcap", control=Placed())
    assert one.summary["units"] == summary["units"]
    for topic in ("/control/service", "/control/parameter"):
        got = sorted(json.dumps(m, sort_keys=True) for m in logged(merged, topic))
        want = sorted(json.dumps(m, sort_keys=True) for m in logged(tmp_path / "one.mcap", topic))
        assert got == want, topic
    # and message for message, as an unsteered launch's (tests/same_run.py)
    from same_run import content

    from rgtbus.telemetry import read_log

    assert content(read_log(merged)[0]) == content(read_log(tmp_path / "one.mcap")[0])
