"""Serving a big log (``rgtbus replay LOG --serve``) in bounded memory.

    python -m benchmarks.bench_serve [--mb 300] [--log PATH] [--play 8] [--full]

The log: a traced gate run (about 6 MB, 162 simulated s, 130 k messages), written again and
again one after another in log time (each copy shifted by the run's length, foxglove-sdk's
writer, zstd, 1 MiB chunks as ``rgtbus run`` writes them) until the file holds ``--mb`` MB:
what a long traced run looks like. ``--log PATH``: that file instead (made there first if it
does not exist). Every measurement runs in a fresh Python process; its peak RSS is its
``VmHWM`` (Linux; imports included: the first row is the imports alone).

1. ``iter_log``: every message of the log read as the server reads it (chunk indexes, a chunk
   at a time, the time-overlapping ones merged): MB of file a second, messages a second.
2. ``LogServer`` with a Foxglove client (the ``websockets`` library, in a process of its own,
   subscribed to every topic, counting what it gets) at 100x: seeks to the start, a third, two
   thirds and near the end of the log, playing ``--play`` wall seconds from each;
   ``--full``: played from the start to the end instead (a 300 MB log: about 80 s at 100x).

Goal: a 300 MB log served in under 300 MB of RSS (memory bounded by the chunks it needs).
Measured (``--full``, 2 cores): a 299 MB log, 7.4 M messages; the imports alone 43 MB;
``iter_log`` 53 MB, 25 MB/s (620 k messages/s); served whole at 100x in 93 s, the client
getting every message: 61 MB.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rgtbus.telemetry.serve import LogIndex

ROOT = Path(__file__).resolve().parent.parent

# The peak RSS: VmHWM, which starts afresh at exec (``ru_maxrss`` is carried over from the
# parent that forked the child: this one's, once it has made the big log).
_RSS = (
    "rss = int(next(line.split()[1] for line in open('/proc/self/status')\n"
    "               if line.startswith('VmHWM:'))) / 1024\n"
)

_IMPORTS = "import rgtbus.telemetry.serve\n" + _RSS + "print(json.dumps({'rss_mb': rss}))"

_ITER = (
    "import time\n"
    "from rgtbus.telemetry.serve import iter_log\n"
    "t0 = time.perf_counter(); n = 0\n"
    "for _ in iter_log(path): n += 1\n"
    "wall = time.perf_counter() - t0\n"
    + _RSS
    + "print(json.dumps({'rss_mb': rss, 'messages': n, 'seconds': wall}))"
)

_SERVE = (
    "import subprocess, sys, time\n"
    "from rgtbus.telemetry.serve import LogServer\n"
    "server = LogServer(path, port=0, autoplay=False, speed=100, say=lambda s: None)\n"
    "client = subprocess.Popen([sys.executable, '-c', CLIENT, server.url],\n"
    "                          stdout=subprocess.PIPE, text=True)\n"
    "assert server.wait_for_client(60)\n"
    "time.sleep(0.5)\n"
    "t0 = time.perf_counter()\n"
    "ix = server.index\n"
    "if full:\n"
    "    server.play(); server.wait_ended()\n"
    "else:\n"
    "    span = ix.end_ns - ix.start_ns\n"
    "    for k in range(4):\n"
    "        at = ix.start_ns + span * k // 3 - (100 * 10**9 if k == 3 else 0)\n"
    "        server.seek(at / 1e9); server.play(); time.sleep(play); server.pause()\n"
    "wall = time.perf_counter() - t0\n"
    "sent = server.sent\n"
    "time.sleep(1.0)\n"
    "client.terminate(); got = int(client.communicate(timeout=30)[0].split()[-1])\n"
    "server.close()\n" + _RSS + "print(json.dumps({'rss_mb': rss, 'sent': sent, 'got': got, "
    "'seconds': wall, 'ended': server.state()['status'] == 'ended'}))"
)

# The client: every advertised channel subscribed; the count of messages printed at the end.
_CLIENT = """
import asyncio, json, signal, sys
import websockets

count = 0

async def main(url):
    global count
    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"], max_size=None) as ws:
        async for m in ws:
            if isinstance(m, str):
                d = json.loads(m)
                if d["op"] == "advertise":
                    chs = d["channels"]
                    subs = [{"id": i + 1, "channelId": c["id"]} for i, c in enumerate(chs)]
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            elif m[0] == 1:
                count += 1

signal.signal(signal.SIGTERM, lambda *_: (print(count, flush=True), sys.exit(0)))
try:
    asyncio.run(main(sys.argv[1]))
finally:
    print(count, flush=True)
"""


def make_big_log(path: Path, mb: float) -> None:
    """A traced gate run written again and again, one copy after another in log time, into
    ``path`` until it holds ``mb`` MB (see the module docstring)."""
    import rgtbus
    from rgtbus.telemetry.serve import index_log, iter_log

    with tempfile.TemporaryDirectory() as tmp:
        source = Path(tmp) / "gate.mcap"
        rgtbus.run("gate", log=source, traces=True)
        index = index_log(source)
        messages = list(iter_log(index))
        one = Path(tmp) / "one.mcap"
        _write_copies(one, index, messages, 1)  # how big a copy is, as written here
        copies = max(1, round(mb * 1e6 / one.stat().st_size))
    part = path.with_name(path.name + ".part")
    _write_copies(part, index, messages, copies)
    os.replace(part, path)


def _write_copies(
    path: Path, index: LogIndex, messages: list[tuple[str, int, bytes]], copies: int
) -> None:
    import foxglove
    from foxglove.mcap import MCAPCompression, MCAPWriteOptions

    ctx = foxglove.Context()
    channels = {}
    for ch in index.channels.values():
        sc = index.schemas.get(ch.schema_id)
        schema = (
            foxglove.Schema(name=sc.name, encoding=sc.encoding, data=bytes(sc.data)) if sc else None
        )
        channels[ch.topic] = foxglove.Channel(
            ch.topic, message_encoding=ch.message_encoding, schema=schema, context=ctx
        )
    options = MCAPWriteOptions(
        compression=MCAPCompression.Zstd, compression_level=1, chunk_size=1 << 20
    )
    length = index.end_ns - index.start_ns + 10**9  # one copy after another, 1 s apart
    with foxglove.open_mcap(path, context=ctx, writer_options=options, allow_overwrite=True):
        for k in range(copies):
            for topic, t, data in messages:
                channels[topic].log(data, log_time=t + k * length)


def child(code: str, path: Path, **names: object) -> dict:
    """``code`` in a fresh interpreter (``path`` and ``names`` defined); its JSON line."""
    head = f"import json\npath = {str(path)!r}\n" + "".join(
        f"{k} = {v!r}\n" for k, v in names.items()
    )
    done = subprocess.run(
        [sys.executable, "-c", head + code], capture_output=True, text=True, cwd=ROOT, check=False
    )
    if done.returncode != 0:
        raise SystemExit(f"bench_serve: a child failed:\n{done.stderr}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mb", type=float, default=300.0, help="size of the log made (MB)")
    ap.add_argument("--log", type=Path, help="the big log (made there if it does not exist)")
    ap.add_argument("--play", type=float, default=8.0, help="wall s played from each seek")
    ap.add_argument("--full", action="store_true", help="play the whole log at 100x instead")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        log = args.log or Path(tmp) / "big.mcap"
        if not log.exists():
            t0 = time.perf_counter()
            make_big_log(log, args.mb)
            print(f"made {log}: {log.stat().st_size / 1e6:.0f} MB in "
                  f"{time.perf_counter() - t0:.0f} s")  # fmt: skip
        size_mb = log.stat().st_size / 1e6
        base = child(_IMPORTS, log)
        print(f"log {size_mb:.0f} MB; imports alone: {base['rss_mb']:.1f} MB RSS")
        it = child(_ITER, log)
        print(
            f"iter_log: {it['messages']} messages in {it['seconds']:.1f} s "
            f"({size_mb / it['seconds']:.0f} MB/s, {it['messages'] / it['seconds'] / 1e3:.0f} k "
            f"messages/s); peak RSS {it['rss_mb']:.1f} MB"
        )
        sv = child(_SERVE, log, CLIENT=_CLIENT, full=args.full, play=args.play)
        how = "the whole log" if args.full else f"4 seeks, {args.play:g} s of play each"
        print(
            f"LogServer at 100x, a client subscribed to every topic ({how}): "
            f"{sv['sent']} messages sent in {sv['seconds']:.1f} s, the client got {sv['got']}"
            f"{', played to the end' if sv['ended'] else ''}; peak RSS {sv['rss_mb']:.1f} MB "
            f"(goal: under 300 MB for a 300 MB log)"
        )


if __name__ == "__main__":
    main()
