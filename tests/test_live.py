"""The live view: a real Foxglove WebSocket client gets what the MCAP log gets."""

from __future__ import annotations

import queue
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


def test_watch_serves_a_cross_process_run_as_an_observer(procs, tmp_path):
    """Three `rgtbus unit` processes and a watcher they connect to: a WebSocket client of the
    watcher gets every message the units log (their MCAP files), and the run is the same."""
    from rgtbus.cli.proc_cmds import free_ports

    scenario = str(ROOT / "scenarios" / "example2.toml")
    units = ["a", "b", "c"]
    ports = free_ports(len(units) + 1)
    watch_ep = f"tcp/127.0.0.1:{ports[-1]}"
    watcher = procs(
        "watch", "-l", watch_ep, "--run", "watched", "--live", "127.0.0.1:0",
        "--idle-exit", "5",
    )  # fmt: skip
    lines: queue.Queue[str] = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(x) for x in watcher.stderr], daemon=True)
    reader.start()
    line = lines.get(timeout=60)
    url = re.search(r"ws://[\w.:\[\]]+", line)
    assert url, line
    result: dict = {}
    client = threading.Thread(
        target=lambda: result.setdefault(
            "r", collect_sync(url.group(0), until_topic=None, timeout=180)
        )
    )
    client.start()
    line = lines.get(timeout=60)  # the client's subscriptions, settled
    assert "channel subscriptions" in line, line
    started = []
    for i, name in enumerate(units):
        net = ["--listen", f"tcp/127.0.0.1:{ports[i]}", "--connect", watch_ep]
        for j in range(i):
            net += ["--connect", f"tcp/127.0.0.1:{ports[j]}"]
        log = str(tmp_path / f"{name}.mcap")
        started.append(procs("unit", name, scenario, *net, "--log", log, "--run-id", "watched"))
    for p in started:
        _, err = p.communicate(timeout=180)
        assert p.returncode == 0, err
    assert watcher.wait(timeout=120) == 0
    reader.join(timeout=30)
    err = "".join(lines.get() for _ in range(lines.qsize()))
    client.join(timeout=60)
    got = sorted((topic, t, data) for topic, t, data, _ in result["r"].messages)
    logged = sorted(m for u in units for m in _mcap(tmp_path / f"{u}.mcap")[0])
    assert got == logged and len(got) > 100
    assert "from run(s) watched" in err


def test_telemetry_frames_round_trip_and_garbage_is_refused():
    from rgtbus.bus.payload import decode_telemetry, encode_telemetry

    frame = encode_telemetry("/rx/decode", "rgtbus.Decode", b'{"unit": "\\u00e9"}', 2**63 + 5)
    assert decode_telemetry(frame) == (
        "/rx/decode",
        "rgtbus.Decode",
        b'{"unit": "\\u00e9"}',
        2**63 + 5,
    )
    for bad in (b"", b"RGT1", b"XXXX" + frame[4:], frame[:20], frame[:16] + b"\xff" * 30):
        with pytest.raises(ValueError):
            decode_telemetry(bad)


def test_a_watcher_drops_what_is_not_telemetry():
    """Frames on the telemetry keys that are garbage, or name a topic under a foreign schema,
    never reach the live view."""
    import zenoh

    from rgtbus.bus.payload import encode_telemetry
    from rgtbus.bus.watch import Watcher
    from rgtbus.bus.zenoh import make_config

    class Sink:
        def __init__(self) -> None:
            self.got: list[tuple] = []

        def put(self, *a) -> None:
            self.got.append(a)

    from rgtbus.cli.proc_cmds import free_ports

    ep = f"tcp/127.0.0.1:{free_ports(1)[0]}"
    sink = Sink()
    with Watcher(sink, run_id="r1", listen=[ep]) as w:
        s = zenoh.open(make_config(connect=[ep]))
        try:
            deadline = time.monotonic() + 30
            good = encode_telemetry("/log", "foxglove.Log", b"{}", 7)
            while not w.heard.is_set() and time.monotonic() < deadline:
                s.put("rgtbus/r1/telemetry/a", good)  # until the subscription has arrived
                time.sleep(0.05)
            for bad in (
                b"garbage",
                encode_telemetry("/log", "rgtbus.Decode", b"{}", 8),  # the wrong schema
                encode_telemetry("/nope", "foxglove.Log", b"{}", 9),  # no such topic
            ):
                s.put("rgtbus/r1/telemetry/a", bad)
            s.put("rgtbus/r2/telemetry/a", good)  # another run
            s.put("rgtbus/r1/telemetry/a", encode_telemetry("/run", "rgtbus.RunSummary", b"{}", 10))
            while (w.dropped < 3 or not any(g[0] == "/run" for g in sink.got)) and (
                time.monotonic() < deadline
            ):
                time.sleep(0.02)
        finally:
            s.close()
    assert w.dropped == 3
    assert {g[0] for g in sink.got} == {"/log", "/run"} and w.runs == {"r1"}
