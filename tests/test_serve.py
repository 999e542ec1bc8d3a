"""``rgtbus replay LOG --serve``: a log played back to Foxglove over its WebSocket protocol, with
play, pause, seek and speed (rgtbus.telemetry.serve). The acceptance test drives the served log
with the official client, @foxglove/ws-protocol (tests/js/serve_client.mjs)."""

from __future__ import annotations

import base64
import json
import os
import selectors
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

import rgtbus
from rgtbus.cli import main
from rgtbus.errors import BadInput, BadLog
from rgtbus.telemetry.scan import scan_log
from rgtbus.telemetry.serve import (
    MAX_SPEED,
    MIN_SPEED,
    LogServer,
    clamp_speed,
    index_log,
    iter_log,
)
from rgtbus.timebase import ns

JS = Path(__file__).parent / "js"
NODE = shutil.which("node")
SEEK = 130.0  # s: the gate's last 32 s of log time (87 messages), 3.2 s of wall at 10x


@pytest.fixture(scope="module")
def gate_log(tmp_path_factory) -> Path:
    """The gate's log (162 simulated s, 346 messages) in small chunks: 19 of them, overlapping
    in log time (the medium is written ahead), so playing merges several at once."""
    from conftest import small_chunk_logs

    log = tmp_path_factory.mktemp("serve") / "gate.mcap"
    with small_chunk_logs(4096):
        rgtbus.run("gate", seed=5, log=log)
    return log


def _messages(log: Path, start: float = 0.0) -> list[tuple[str, int, bytes]]:
    """The log's own messages from ``start`` on, read by mcap: (topic, log time, bytes), in
    log-time order (file order on ties)."""
    with open(log, "rb") as f:
        every = [
            (c.topic, m.log_time, bytes(m.data))
            for _, c, m in make_reader(f).iter_messages(log_time_order=False)
        ]
    every.sort(key=lambda m: m[1])
    return [m for m in every if m[1] >= ns(start)]


def test_the_log_is_read_in_log_time_order_from_any_time(gate_log):
    index = index_log(gate_log)
    assert index.indexed_by == "summary" and index.note == ""
    assert len(index.spans) > 5 and index.messages == len(_messages(gate_log))
    overlapping = sum(a.end > b.start for a, b in zip(index.spans, index.spans[1:], strict=False))
    assert overlapping  # what the merge is for
    for start in (0.0, 41.3, SEEK, index.end_ns / 1e9, 1e4):
        assert list(iter_log(index, start)) == _messages(gate_log, start), start


def test_a_cut_log_is_read_to_its_cut_and_a_damaged_one_to_its_damage(gate_log, tmp_path):
    data = gate_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    index = index_log(cut)  # no summary: scanned, a chunk at a time
    assert index.indexed_by == "scan" and "truncated" in index.note
    raw = scan_log(cut)  # what the log's reader reads of it, in log-time order
    read = [(raw.channels[c].topic, t, bytes(data)) for c, t, _, _, data in raw.messages]
    read.sort(key=lambda m: m[1])
    assert list(iter_log(index)) == read and 0 < len(read) == index.messages

    damaged = tmp_path / "damaged.mcap"
    flipped = bytearray(data)
    flipped[index.spans[-1].offset + 200] ^= 0xFF  # inside a chunk the cut log still holds
    damaged.write_bytes(bytes(flipped))
    with pytest.raises(BadLog, match=r"damaged\.mcap: .*cannot be read .*nothing served from"):
        list(iter_log(damaged))

    empty = tmp_path / "header.mcap"
    empty.write_bytes(data[:8] + b"\x01")  # the magic, then a record cut in its header
    with pytest.raises(BadLog, match=r"header\.mcap"):
        index_log(empty)


def test_the_library_plays_seeks_and_clamps_the_speed(gate_log):
    assert (clamp_speed(1000.0), clamp_speed(0.0), clamp_speed(float("nan"), 3.0)) == (
        MAX_SPEED,
        MIN_SPEED,
        3.0,
    )
    with LogServer(gate_log, port=0, autoplay=False) as server:
        assert server.url == f"ws://127.0.0.1:{server.port}" and server.port > 0
        assert server.state() == {"status": "paused", "time": 0.0, "speed": 1.0}
        assert server.set_speed(1000) == MAX_SPEED and server.set_speed(0.001) == MIN_SPEED
        server.set_speed(MAX_SPEED)
        server.seek(150.0)
        assert not server.wait_ended(0.2) and server.sent == 0  # paused: nothing goes out
        server.play()
        assert server.wait_ended(30)
        assert server.sent == len(_messages(gate_log, 150.0)) and server.seeks == 1
        assert server.state()["status"] == "ended" and server.problem == ""
        with pytest.raises(BadInput, match="cannot listen"):
            LogServer(gate_log, port=server.port)  # the port is taken


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--serve", "nowhere"], "--serve 'nowhere': expected HOST:PORT, e.g. 127.0.0.1:8765"),
        (["--serve", "127.0.0.1:70000"], "--serve '127.0.0.1:70000': port 70000 is not in"),
        (["--serve", "--speed", "0"], "--speed 0.0: must be a factor from 0.1 to 100"),
        (["--serve", "--speed", "1000"], "--speed 1000.0: must be a factor from 0.1 to 100"),
        (["--serve", "--speed", "nan"], "--speed nan: must be a factor from 0.1 to 100"),
        (["--serve", "--speed", "fast"], "--speed 'fast': not a number"),
        (["--speed", "2"], "--speed goes with --serve"),
        (["--exit-at-end"], "--exit-at-end goes with --serve"),
        (["--serve", "--verify"], "--serve goes alone (not with --verify)"),
    ],
)
def test_bad_serve_options_are_one_line_and_exit_2(gate_log, capsys, args, says):
    capsys.readouterr()
    assert main(["replay", str(gate_log), *args]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert err.startswith(f"rgtbus replay: error: {says}")


async def _take_all(url: str, count: int) -> list[tuple[str, int, bytes]]:
    """A client (the ``websockets`` library) subscribed to every channel: the messages it
    gets, once it has ``count`` of them and the server has said the log has ended; it leaves
    then. Bounded: 60 s."""
    import asyncio
    import struct

    import websockets

    got: list[tuple[str, int, bytes]] = []
    topics: dict[int, str] = {}
    ended = False
    async with (
        asyncio.timeout(60),
        websockets.connect(url, subprotocols=["foxglove.sdk.v1"], max_size=None) as ws,
    ):
        async for m in ws:
            if isinstance(m, str):
                d = json.loads(m)
                if d["op"] == "advertise":
                    subs = [{"id": c["id"], "channelId": c["id"]} for c in d["channels"]]
                    topics.update((c["id"], c["topic"]) for c in d["channels"])
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            elif m[0] == 1:  # a message: subscription id, log time, data
                sid, t = struct.unpack_from("<IQ", m, 1)
                got.append((topics[sid], t, bytes(m[13:])))
            elif m[0] == 5:  # a PlaybackState: status 3 is Ended
                ended = ended or m[1] == 3
            if ended and len(got) >= count:
                break
    return got


def test_a_cut_log_is_served_to_its_cut_and_exit_at_end_stops(gate_log, tmp_path, procs):
    """A log cut short (no summary: scanned) plays once a client subscribes, to its cut;
    --exit-at-end stops the server once the client has it all and left; exit 3, as replay's
    for a cut log."""
    import asyncio

    data = gate_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    raw = scan_log(cut)
    read = [(raw.channels[c].topic, t, bytes(data)) for c, t, _, _, data in raw.messages]
    read.sort(key=lambda m: m[1])
    server = procs("replay", str(cut), "--serve", "127.0.0.1:0", "--speed", "100",
                   "--exit-at-end", "--json")  # fmt: skip
    first = _first_line(server, 60)
    assert first.startswith("serving "), first
    got = asyncio.run(_take_all(first.split(" on ", 1)[1].split()[0], len(read)))
    out, err = server.communicate(timeout=60)
    err = first + err
    assert got == read
    assert server.returncode == 3, err
    assert "note: " in err and "truncated" in err
    result = json.loads(out)
    assert result["ended"] and result["sent"] == len(read) and "truncated" in result["note"]


def _first_line(p: subprocess.Popen, timeout: float) -> str:
    """What the process writes to stderr up to the end of its first line (and any more
    that came with it), waited for ``timeout`` s at most."""
    assert p.stderr is not None
    sel = selectors.DefaultSelector()
    sel.register(p.stderr, selectors.EVENT_READ)
    line = ""
    deadline = time.monotonic() + timeout
    while "\n" not in line and time.monotonic() < deadline:
        if sel.select(max(0.0, deadline - time.monotonic())):
            chunk = os.read(p.stderr.fileno(), 4096).decode()
            if not chunk:
                break
            line += chunk
    return line


@pytest.mark.skipif(
    NODE is None or not (JS / "node_modules").is_dir(),
    reason="no Node.js, or no tests/js/node_modules (npm ci --prefix tests/js, as .ci/run does)",
)
def test_a_foxglove_client_seeks_plays_pauses_and_sets_the_speed(gate_log, procs):
    """Through the official client: a seek then a play at 10x gets every message from the
    seek time on, once, in log-time order, to the end; a pause stops the flow and a play goes
    on from there (every message of the log once, across the pause); speeds are clamped."""
    server = procs("replay", str(gate_log), "--serve", "127.0.0.1:0", "--paused", "--json")
    first = _first_line(server, 60)
    assert first.startswith("serving "), first
    url = first.split(" on ", 1)[1].split()[0]
    whole, tail = _messages(gate_log), _messages(gate_log, SEEK)
    plan = [
        {"play": True, "speed": 10, "seek": ns(SEEK), "until": {"ended": len(tail)}},
        {"play": False, "speed": 0.01, "seek": 0, "until": "state"},
        {"play": True, "speed": 10, "until": {"messages": 20}},
        {"play": False, "speed": 10, "until": "state"},
        {"play": False, "speed": 10, "until": {"wait_ms": 1000}},
        {"play": True, "speed": 1000, "until": {"ended": len(whole), "since": 2}},
        {"play": False, "speed": 100, "until": {"wait_ms": 300}},  # nothing more comes
    ]
    t0 = time.monotonic()
    client = subprocess.run(
        [NODE, str(JS / "serve_client.mjs"), url, json.dumps(plan)],
        capture_output=True, text=True, timeout=180,
    )  # fmt: skip
    wall = time.monotonic() - t0
    server.send_signal(signal.SIGINT)
    out, err = server.communicate(timeout=30)
    assert client.returncode == 0, client.stderr + err
    assert server.returncode == 0, err
    events = [json.loads(line) for line in client.stdout.splitlines()]
    assert events[-1] == {"ev": "done"}
    advertised = next(e["topics"] for e in events if e["ev"] == "advertise")
    with open(gate_log, "rb") as f:
        summary = make_reader(f).get_summary()
    assert sorted(advertised) == sorted(c.topic for c in summary.channels.values())

    def messages(steps: set[int]) -> list[tuple[str, int, bytes]]:
        return [(e["topic"], int(e["t"]), base64.b64decode(e["data"]))
                for e in events if e["ev"] == "message" and e["step"] in steps]  # fmt: skip

    states = {e["requestId"]: e for e in events if e["ev"] == "state" and e["requestId"]}
    # the seek, played at 10x to the end: every message from the seek time on, once, in order
    assert states["step0"]["didSeek"] and states["step0"]["status"] == "playing"
    assert states["step0"]["speed"] == 10 and int(states["step0"]["time"]) == ns(SEEK)
    assert messages({0}) == tail and messages({1}) == []
    assert wall < 60  # 3.2 s of the log's time at 10x, then 1.6 s at 100x, and a pause
    # a seek while paused stays paused; 0.01x is taken as the slowest speed
    assert states["step1"]["status"] == "paused" and states["step1"]["didSeek"]
    assert abs(states["step1"]["speed"] - MIN_SPEED) < 1e-6 and states["step1"]["time"] == "0"
    # paused at P: nothing after P goes out until the play, which goes on from P
    paused = int(states["step3"]["time"])
    assert states["step3"]["status"] == "paused" and 0 < paused < ns(SEEK)
    during = [m for m in messages({3, 4}) if m[1] > paused]
    assert during == []
    assert states["step5"]["speed"] == MAX_SPEED and states["step5"]["status"] == "playing"
    assert messages({2, 3, 4, 5, 6}) == whole  # across the pause: each once, in order
    ended = [e for e in events if e["ev"] == "state" and e["status"] == "ended"
             and not e["requestId"]]  # fmt: skip
    assert [e["step"] for e in ended] == [0, 5]
    result = json.loads(out)
    assert result["url"] == url and result["ended"] is True and result["problem"] == ""
    assert result["seeks"] == 2
    assert result["sent"] == len(tail) + len(whole)
