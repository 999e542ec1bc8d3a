"""The live view: a real Foxglove WebSocket client gets what the MCAP log gets."""

from __future__ import annotations

import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from rgtbus.cli import main
from rgtbus.errors import RgtbusError
from rgtbus.telemetry.live import LiveView, parse_address

sys.path.insert(0, str(Path(__file__).parent))
from live_client import collect_sync

ROOT = Path(__file__).resolve().parent.parent


def _mcap(path: Path) -> tuple[list[tuple[str, int, bytes]], dict[str, tuple[str, bytes]]]:
    with open(path, "rb") as f:
        reader = make_reader(f)
        msgs = []
        schemas = {}
        for schema, channel, m in reader.iter_messages():
            msgs.append((channel.topic, m.log_time, bytes(m.data)))
            schemas[channel.topic] = (schema.name, bytes(schema.data))
    return sorted(msgs), schemas


def _live_run(tmp_path: Path, *extra: str, scenario: str = "gate") -> tuple:
    log = tmp_path / "run.mcap"
    cmd = [sys.executable, "-m", "rgtbus", "run", f"scenarios/{scenario}.toml", "--bus", "memory"]
    cmd += ["--log", str(log), "--live", "127.0.0.1:0", "--live-wait", "60", "--quiet", *extra]
    proc = subprocess.Popen(
        cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        line = proc.stderr.readline()
        url = re.search(r"ws://\S+", line)
        assert url, line + proc.stderr.read()
        got = collect_sync(url.group(0), timeout=180)
        _, err = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
    assert proc.returncode == 0, err
    return got, log


@pytest.mark.parametrize("pace", [[], ["--realtime", "400"]], ids=["unpaced", "paced"])
def test_a_client_gets_every_message_of_the_log(tmp_path, pace):
    got, log = _live_run(tmp_path, *pace)
    messages, schemas = _mcap(log)
    assert sorted((topic, t, data) for topic, t, data, _ in got.messages) == messages
    # every topic under the same schema as in the file
    live = {c["topic"]: (c["schemaName"], c["schema"].encode()) for c in got.channels.values()}
    for topic, schema in schemas.items():
        assert live[topic] == schema
    # simulated time as the server's time: never going back, within the run
    assert got.times and got.times == sorted(got.times)
    assert got.times[-1] <= max(t for _, t, _ in messages) + 10**9


def test_traces_are_served_too(tmp_path):
    got, log = _live_run(tmp_path, "--traces", "--realtime", "1000", scenario="example1")
    messages, _ = _mcap(log)
    assert any(topic.startswith("/trace/") for topic, _, _ in messages)
    assert sorted((topic, t, data) for topic, t, data, _ in got.messages) == messages


def test_a_paced_message_is_never_sent_before_it_is_due():
    with LiveView("127.0.0.1", 0, realtime=10.0, linger=5.0) as live:
        live.advertise([("/log", "foxglove.Log"), ("/run", "rgtbus.RunSummary")])
        result = {}
        client = threading.Thread(
            target=lambda: result.setdefault(
                "r", collect_sync(live.url, until_topic="/run", timeout=60)
            )
        )
        client.start()
        assert live.wait_for_client(30)
        live.begin()
        start = time.monotonic()
        for t_s in (0.0, 1.0, 2.0):  # due 0, 0.1 and 0.2 s after begin
            live.put("/log", "foxglove.Log", b"{}", int(t_s * 1e9))
        live.put("/run", "rgtbus.RunSummary", b"{}", int(3e9))
        client.join(timeout=60)
    r = result["r"]
    assert [t for _, t, _, _ in r.messages] == [0, 1_000_000_000, 2_000_000_000, 3_000_000_000]
    for _, t, _, received in r.messages:
        assert received - start >= t / 1e9 / 10.0 - 0.002  # late is possible, early never


@pytest.mark.parametrize(
    "text, says",
    [
        ("8765", "expected HOST:PORT"),
        ("localhost:http", "not a number"),
        ("127.0.0.1:70000", "not in 0..65535"),
        (":8765", "expected HOST:PORT"),
    ],
)
def test_bad_live_addresses(text, says):
    with pytest.raises(RgtbusError, match=says):
        parse_address(text)
    assert parse_address("[::1]:9000") == ("::1", 9000)


def test_live_cli_errors_are_one_line(tmp_path, capsys):
    gate = str(ROOT / "scenarios" / "gate.toml")
    log = str(tmp_path / "x.mcap")
    assert main(["run", gate, "--bus", "memory", "--log", log, "--live-wait", "3"]) == 2
    assert "--live-wait goes with --live" in capsys.readouterr().err
    assert main(["run", gate, "--bus", "memory", "--log", log, "--live", "nope"]) == 2
    assert "--live 'nope': expected HOST:PORT" in capsys.readouterr().err
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code = main(["run", gate, "--bus", "memory", "--log", log, "--live", f"127.0.0.1:{port}"])
    err = capsys.readouterr().err
    assert code == 2 and f"127.0.0.1:{port}: cannot listen" in err and err.count("\n") == 1
