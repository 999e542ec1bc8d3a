"""The live view: a real Foxglove WebSocket client gets what the MCAP log gets."""

from __future__ import annotations

import base64
import json
import queue
import re
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import pytest
from mcap.reader import make_reader

from rgtbus import api
from rgtbus.cli import main
from rgtbus.errors import RgtbusError
from rgtbus.telemetry.blocks import DECODE, PULSE, TRACE, decode_record, encode_record
from rgtbus.telemetry.live import LiveView, parse_address
from rgtbus.telemetry.pulse_blocks import pulse_rows
from rgtbus.telemetry.record_rows import decode_rows
from rgtbus.telemetry.records import RX_DECODE, RX_DECODES, TX_PULSE
from rgtbus.timebase import ns

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


def _split_live(
    got, messages: list[tuple[str, int, bytes]]
) -> tuple[list[tuple[str, int, bytes]], list[tuple[int, str]], list[tuple[int, str]]]:
    """What a live client got: the log's messages (``messages``, sorted, as far as it got
    them), the decodes offered to the view alone as they were made (``/rx/decode``, sorted
    (time, JSON)), and the rest: each pulse offered alone as it was made (a ``/tx/pulse``
    block of one, beside the log's blocks), sorted (time, JSON of its row); anything else
    the client got stays as it came (it matches no pulse)."""
    rest = Counter((topic, t, data) for topic, t, data, _ in got.messages if topic != RX_DECODE)
    alone = rest - Counter(messages)
    logged = sorted((rest - alone).elements())
    offered = sorted(
        (t, json.dumps(json.loads(data), sort_keys=True))
        for topic, t, data, _ in got.messages
        if topic == RX_DECODE
    )
    pulses = []
    for topic, t, data in alone.elements():
        rows = pulse_rows(decode_record(PULSE, data, topic)) if topic == TX_PULSE else []
        one = len(rows) == 1
        pulses.append((t, json.dumps(rows[0], sort_keys=True) if one else repr((topic, data))))
    return logged, offered, sorted(pulses)


def _decodes_of(messages: list[tuple[str, int, bytes]]) -> list[tuple[int, str]]:
    """The log's decode blocks, one decode a row at its own time (what ``cat`` prints)."""
    return sorted(
        (ns(row["t"]), json.dumps(row, sort_keys=True))
        for topic, _, data in messages
        if topic == RX_DECODES
        for row in decode_rows(decode_record(DECODE, data, topic))
    )


def _pulses_of(messages: list[tuple[str, int, bytes]]) -> list[tuple[int, str]]:
    """The log's pulse blocks, one pulse a row at its own time."""
    return sorted(
        (ns(row["t"]), json.dumps(row, sort_keys=True))
        for topic, _, data in messages
        if topic == TX_PULSE
        for row in pulse_rows(decode_record(PULSE, data, topic))
    )


def _live_of(messages: list[tuple[str, int, bytes]]) -> tuple:
    """What a client watching from the start gets of a run that logs ``messages``
    (``_split_live``): every message of the log, each decode and each pulse alone besides."""
    return messages, _decodes_of(messages), _pulses_of(messages)


def _schema_data(channel: dict) -> bytes:
    """A WebSocket channel's schema as its bytes: a protobuf one is base64 text."""
    if channel.get("schemaEncoding") == "protobuf":
        return base64.b64decode(channel["schema"], validate=True)
    return channel["schema"].encode()


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
def test_a_client_gets_every_message_of_the_log(tmp_path, pace, monkeypatch):
    got, log = _live_run(tmp_path, *pace)
    messages, schemas = _mcap(log)
    logged, offered, pulses = _split_live(got, messages)
    assert logged == messages
    # and each decode as it was made: the log's blocks, one decode a message
    assert offered == _decodes_of(messages) and len(offered) > 100
    # and each pulse as it was made: the log's blocks, one pulse a message
    assert pulses == _pulses_of(messages) and len(pulses) > 100
    # the log is the one a run with no viewer writes (docs/foxglove.md)
    alone = tmp_path / "alone.mcap"
    monkeypatch.chdir(ROOT)
    assert main(["run", "scenarios/gate.toml", "--log", str(alone), "--quiet"]) == 0
    assert _mcap(alone)[0] == messages
    # every topic under the same schema as in the file (a binary one, a hot topic's protobuf
    # FileDescriptorSet, base64 in the WebSocket protocol's text)
    live = {c["topic"]: (c["schemaName"], _schema_data(c)) for c in got.channels.values()}
    for topic, schema in schemas.items():
        assert live[topic] == schema
    # simulated time as the server's time: never going back, within the run
    assert got.times and got.times == sorted(got.times)
    assert got.times[-1] <= max(t for _, t, _ in messages) + 10**9


class _Looking:
    """A live sink that is always looking, and keeps what it is offered."""

    def __init__(self) -> None:
        self.messages: list[tuple[str, int, bytes, None]] = []

    def begin(self) -> None:
        pass

    def close(self) -> None:
        pass

    def watched(self) -> bool:
        return True

    def put(self, topic: str, schema: str, data: bytes, t_ns: int) -> None:
        self.messages.append((topic, t_ns, bytes(data), None))


@pytest.mark.parametrize("scenario", ["gate_repair", "crowd10", "coalition10", "group6"])
def test_a_watched_run_logs_what_nobody_watching_logs(tmp_path, scenario):
    """Watched, units wake for each thing they do and take no batch of decodes; the log holds
    the same messages all the same, and the view gets them and each decode as it was made."""
    path = str(ROOT / "scenarios" / f"{scenario}.toml")
    alone, watched = tmp_path / "alone.mcap", tmp_path / "watched.mcap"
    api.run(path, log=alone)
    view = _Looking()
    api.run(path, log=watched, live=view)  # type: ignore[arg-type]
    messages = _mcap(alone)[0]
    assert _mcap(watched)[0] == messages
    got = type("Got", (), {"messages": view.messages})
    assert _split_live(got, messages) == _live_of(messages)


@pytest.mark.slow  # a traced run served live: ~2.5 s (CI's slow pass)
def test_traces_are_served_too(tmp_path):
    # paced so that a client on a loaded machine keeps up: the server keeps a bounded backlog
    got, log = _live_run(tmp_path, "--traces", "--realtime", "200", scenario="example1")
    messages, _ = _mcap(log)
    assert any(topic.startswith("/trace/") for topic, _, _ in messages)
    assert _split_live(got, messages) == _live_of(messages)


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
        for t_s in (0.0, 1.0, 2.0):  # due 0, 0.1 and 0.2 s after begin
            live.put("/log", "foxglove.Log", b"{}", int(t_s * 1e9))
        live.put("/run", "rgtbus.RunSummary", b"{}", int(3e9))
        client.join(timeout=60)
    r = result["r"]
    assert [t for _, t, _, _ in r.messages] == [0, 1_000_000_000, 2_000_000_000, 3_000_000_000]
    for _, t, _, received in r.messages:
        # Against the view's own origin (begin()), the clock the pacing uses: a time read
        # after begin() is late by however long the test thread was descheduled in between.
        # The client's receipt and due_wall are both time.monotonic() (one clock on Linux).
        assert received >= live.due_wall(t)  # late is possible, early never


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


@pytest.mark.slow  # one of the longest waits: CI's slow pass runs it
def test_watch_serves_a_cross_process_run_as_an_observer(procs, tmp_path):
    """Three `rgtbus unit` processes and a watcher they connect to: a WebSocket client of the
    watcher gets every message the units log (their MCAP files), and the run is the same."""
    from rgtbus.units.launch import free_ports

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
    logged = sorted(m for u in units for m in _mcap(tmp_path / f"{u}.mcap")[0])
    got, decodes, pulses = _split_live(result["r"], logged)
    assert (got, decodes) == (logged, _decodes_of(logged)) and len(logged) > 100
    # and the pulses each unit made once it knew it was watched, each alone as it was made
    assert pulses and not Counter(pulses) - Counter(_pulses_of(logged))
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

    from rgtbus.bus.config import make_config
    from rgtbus.bus.payload import encode_telemetry
    from rgtbus.telemetry.watch import Watcher

    class Sink:
        def __init__(self) -> None:
            self.got: list[tuple] = []

        def put(self, *a) -> None:
            self.got.append(a)

    from rgtbus.units.launch import free_ports

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


# -- bounded whatever the clients and the network do -----------------------------------------------


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


async def _stuck_client(url: str):
    """A Foxglove client that subscribes to every channel, then never reads again (a tiny
    receive buffer, no keepalive: nothing on its side ever closes the connection)."""
    import json

    import websockets

    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    host, port = url.removeprefix("ws://").rsplit(":", 1)
    sock.connect((host, int(port)))
    sock.setblocking(False)
    ws = await websockets.connect(
        url, sock=sock, subprotocols=["foxglove.sdk.v1"], max_size=None, max_queue=1,
        ping_interval=None, proxy=None, compression=None,
    )  # fmt: skip
    while True:
        d = json.loads(await ws.recv())
        if d["op"] == "advertise":
            subs = [{"id": i + 1, "channelId": c["id"]} for i, c in enumerate(d["channels"])]
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            return ws


@pytest.mark.slow  # a few seconds: CI's slow pass (the fast suite stays near 3 min)
def test_clients_that_never_read_cost_a_bounded_backlog_and_never_hold_the_run():
    """Three clients subscribe and never read. 60 MB of messages each (far over what the
    sockets hold) go to the server without put() ever waiting for them, the process grows by
    a bounded amount (each client's backlog, the view's queue), and close() returns within its
    bounds although the SDK's stop now waits for them forever (and says so)."""
    import asyncio

    from rgtbus.telemetry import live as live_mod

    said: list[str] = []
    live = LiveView("127.0.0.1", 0, backlog=256, linger=0.5, queue_bytes=2 << 20, say=said.append)
    loop = asyncio.new_event_loop()
    runner = threading.Thread(target=loop.run_forever, daemon=True)
    runner.start()
    clients: list = []
    try:
        live.advertise([("/trace/a", "rgtbus.TraceBlock"), ("/log", "foxglove.Log")])

        async def connect_all():
            return await asyncio.gather(*(_stuck_client(live.url) for _ in range(3)))

        clients = asyncio.run_coroutine_threadsafe(connect_all(), loop).result(timeout=60)
        assert live.wait_for_client(30) and len(live.subscriptions.pairs) == 6
        base = _rss_mb()
        y = [0.123456789] * 30 + [0.0] * 30
        payload = encode_record(TRACE, {"unit": "a", "sample": 1, "t": 0.005, "y": y, "x": y})
        assert 900 < len(payload) < 1100  # ~1 KB
        put_time = grew = 0.0
        deadline = time.monotonic() + 60
        for chunk in range(200):
            t0 = time.monotonic()
            for i in range(300):
                live.put("/trace/a", "rgtbus.TraceBlock", payload, (chunk * 300 + i) * 1000)
            put_time = max(put_time, time.monotonic() - t0)
            while live._queued:  # every message handed to the server (none dropped here)
                assert time.monotonic() < deadline, "the view's thread is stuck"
                time.sleep(0.001)
            grew = max(grew, _rss_mb() - base)
        closer = threading.Thread(target=live.close, daemon=True)
        t0 = time.monotonic()
        closer.start()
        bound = live_mod.FLUSH_TIMEOUT + live.linger + live_mod.STOP_TIMEOUT
        closer.join(timeout=bound + 20)
        assert not closer.is_alive(), "close() waited for clients that do not read"
        took = time.monotonic() - t0
    finally:
        for ws in clients:
            loop.call_soon_threadsafe(ws.transport.abort)
        loop.call_soon_threadsafe(loop.stop)
        runner.join(timeout=30)
    assert put_time < 2, put_time  # 300 messages: put only queues
    assert grew < 100, grew  # 3 x 256 messages in the server, at most 2 MiB queued here
    assert took < bound + 5, took
    assert live.sent == 60_000 and live.dropped == 0
    # the server was stuck on the clients: said, not waited for
    assert live.stop_problem and said and "did not stop" in said[0], said


def test_the_view_refuses_topics_beyond_its_bound():
    said: list[str] = []
    with LiveView("127.0.0.1", 0, max_channels=3, linger=0, say=said.append) as live:
        for i in range(10):
            live.put(f"/trace/u{i}", "rgtbus.TraceBlock", b"{}", i)
    assert len(live._channels) == 3 and live.refused == 7 and live.sent == 3
    assert any("7 refused" in s for s in said), said


class _Sink:
    def __init__(self) -> None:
        self.got: list[tuple] = []

    def put(self, *a) -> None:
        self.got.append(a)


def _heard(w, s, key: str, frame: bytes) -> None:
    """Put ``frame`` until the watcher has heard something (its subscription has arrived)."""
    deadline = time.monotonic() + 30
    while not w.heard.is_set():
        assert time.monotonic() < deadline, "watcher heard nothing"
        s.put(key, frame)
        time.sleep(0.05)


def _settle(w, n: int) -> None:
    deadline = time.monotonic() + 30
    while w.received + w.dropped < n:
        assert time.monotonic() < deadline, (w.received, w.drops)
        time.sleep(0.02)


def test_a_keyed_runs_telemetry_is_signed_and_a_watcher_with_the_key_shows_only_that():
    """A keyed bus signs its units' telemetry; a watcher given the key shows it and drops
    (counting each reason) unsigned frames, frames signed with another key or for another
    unit, and replays; a keyless watcher shows none of the signed ones."""
    import zenoh
    from rgtbus.units.launch import free_ports

    from rgtbus.bus import open_bus
    from rgtbus.bus.auth import tag
    from rgtbus.bus.config import make_config
    from rgtbus.bus.payload import encode_telemetry, is_signed_telemetry, sign_telemetry
    from rgtbus.telemetry.watch import Watcher

    key, other = bytes(range(1, 33)), b"\xa5" * 32
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(3)]  # the watchers', the bus's
    keyed, keyless = _Sink(), _Sink()
    with (
        Watcher(keyed, run_id="rt", key=key, listen=[eps[0]]) as w,
        Watcher(keyless, run_id="rt", listen=[eps[1]]) as w0,
        open_bus(
            "zenoh",
            "rt",
            ("a", "b"),
            200.0,
            local=["a"],
            key=key,
            connect=eps[:2],
            listen=eps[2:],
        ) as bus,
    ):
        feed = bus.telemetry_feed("a")
        sent: list[bytes] = []
        spy = zenoh.open(make_config(connect=eps))  # keyless, loopback: the forger (peers
        # do not route for each other: it connects to every one)
        try:
            sub = spy.declare_subscriber("rgtbus/rt/telemetry/a", lambda s: sent.append(
                s.payload.to_bytes()))  # fmt: skip
            deadline = time.monotonic() + 30
            while not (w.heard.is_set() and w0.drops["signed"] and sent):
                assert time.monotonic() < deadline, (w.drops, w0.drops)
                feed.put("/log", "foxglove.Log", b'{"m": 1}', 1)
                time.sleep(0.05)
            assert all(is_signed_telemetry(f) for f in sent)
            n0, d0 = w.received + w.dropped, w0.dropped
            feed.put("/run", "rgtbus.RunSummary", b"{}", 5)  # shown
            frame = encode_telemetry("/run", "rgtbus.RunSummary", b'{"forged": 1}', 6)
            nonce = bus.nonce

            def signed(secret, unit="a", seq=10**6):
                return sign_telemetry(
                    frame, nonce, seq, lambda b: tag(secret, "telemetry", "rt", unit, nonce, b)
                )

            spy.put("rgtbus/rt/telemetry/a", frame)  # unsigned
            spy.put("rgtbus/rt/telemetry/a", signed(other))  # another key
            spy.put("rgtbus/rt/telemetry/a", signed(key, unit="b"))  # b's tag on a's key
            spy.put("rgtbus/rt/telemetry/a", sent[0])  # a replay of a's first frame
            _settle(w, n0 + 5)
            sub.undeclare()
        finally:
            spy.close()
        deadline = time.monotonic() + 30
        while w0.dropped < d0 + 4 or not keyless.got:  # the keyless watcher: signed dropped
            assert time.monotonic() < deadline, w0.drops
            time.sleep(0.02)
    assert w.drops["unauthenticated"] == 3 and w.drops["duplicate"] == 1, w.drops
    assert [g[0] for g in keyed.got][-1] == "/run" and b"forged" not in keyed.got[-1][2]
    assert all(g[2] != b'{"forged": 1}' for g in keyed.got)
    # without the key a watcher cannot tell: it shows no signed frame, and what is unsigned
    # (here only the forger's) as on an open run
    assert [g[2] for g in keyless.got] == [b'{"forged": 1}']
    assert w0.drops["signed"] == w0.dropped, w0.drops


def test_a_watcher_bounds_its_topics():
    """/trace/<unit> only from that unit's own key, and at most MAX_TRACES of them: forged
    topics never become channels (each would cost the watch memory in the server)."""
    import zenoh
    from rgtbus.units.launch import free_ports

    from rgtbus.bus.config import make_config
    from rgtbus.bus.payload import encode_telemetry
    from rgtbus.telemetry import watch
    from rgtbus.telemetry.watch import Watcher

    ep = f"tcp/127.0.0.1:{free_ports(1)[0]}"
    sink = _Sink()
    old = watch.MAX_TRACES
    watch.MAX_TRACES = 5
    try:
        with Watcher(sink, listen=[ep]) as w:
            s = zenoh.open(make_config(connect=[ep]))
            try:
                _heard(
                    w,
                    s,
                    "rgtbus/r1/telemetry/a",
                    encode_telemetry("/log", "foxglove.Log", b"{}", 1),
                )
                n0 = w.received + w.dropped
                trace = "rgtbus.TraceBlock"
                s.put("rgtbus/r1/telemetry/a", encode_telemetry("/trace/b", trace, b"{}", 2))
                for i in range(20):  # 20 units, of as many runs: 5 traces served
                    s.put(
                        f"rgtbus/x{i}/telemetry/u{i}",
                        encode_telemetry(f"/trace/u{i}", trace, b"{}", 3),
                    )
                _settle(w, n0 + 21)
            finally:
                s.close()
    finally:
        watch.MAX_TRACES = old
    traces = {g[0] for g in sink.got if g[0].startswith("/trace/")}
    assert len(traces) == 5 and "/trace/b" not in traces
    assert w.drops["topic"] == 16, w.drops


def test_a_unit_process_s_telemetry_says_whether_a_watcher_subscribes():
    """``TelemetryFeed.watched``: False while nobody subscribes to the unit's telemetry key
    (its units may batch their decodes, and the feed puts nothing), True once a watcher does,
    False again once it has gone (as zenoh's routing learns it: every wait bounded)."""
    from rgtbus.units.launch import free_ports

    from rgtbus.bus import open_bus
    from rgtbus.telemetry.watch import Watcher

    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(2)]  # the watcher's, the bus's

    def until(want: bool, feed) -> None:
        deadline = time.monotonic() + 30
        while feed.watched() is not want:
            assert time.monotonic() < deadline, f"watched() never became {want}"
            time.sleep(0.02)

    class Counting:  # the feed's publisher, counting what it is asked to put
        def __init__(self, publisher) -> None:
            self.publisher, self.puts = publisher, 0

        def put(self, frame: bytes) -> None:
            self.puts += 1
            self.publisher.put(frame)

    with open_bus("zenoh", "wt", ("a", "b"), 200.0, local=["a"], listen=eps[1:]) as bus:
        feed = bus.telemetry_feed("a")
        counting = feed.publisher = Counting(feed.publisher)
        assert feed.watched() is False
        feed.put("/log", "rgtbus.Log", b"{}", 1)
        assert counting.puts == 0  # nobody watches: nothing encoded, signed or put
        with Watcher(_Sink(), run_id="wt", connect=eps[1:]):
            until(True, feed)
            feed.put("/log", "rgtbus.Log", b"{}", 2)
            assert counting.puts == 1
        until(False, feed)
        feed.put("/log", "rgtbus.Log", b"{}", 3)
        assert counting.puts == 1
        feed.publisher = counting.publisher  # the bus undeclares its own
        feed.closed = True
        assert feed.watched() is False
