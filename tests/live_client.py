"""A minimal Foxglove WebSocket client for tests and benchmarks (the `websockets` library):
connects with foxglove-sdk's subprotocol, subscribes to every advertised channel, and collects
(topic, log_time, payload, receive time) until a topic's message arrives or the server closes."""

from __future__ import annotations

import asyncio
import json
import struct
import time
from dataclasses import dataclass, field

SUBPROTOCOLS = ["foxglove.sdk.v1"]


@dataclass
class Received:
    messages: list[tuple[str, int, bytes, float]] = field(default_factory=list)
    times: list[int] = field(default_factory=list)  # server time broadcasts, ns
    channels: dict[int, dict] = field(default_factory=dict)
    server_info: dict | None = None


async def collect(
    url: str, *, until_topic: str | None = "/run", timeout: float = 120.0
) -> Received:
    import websockets

    out = Received()
    sub_topic: dict[int, str] = {}
    async with (
        asyncio.timeout(timeout),
        websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws,
    ):
        async for m in ws:
            if isinstance(m, str):
                d = json.loads(m)
                if d["op"] == "serverInfo":
                    out.server_info = d
                elif d["op"] == "advertise":
                    subs = []
                    for c in d["channels"]:
                        out.channels[c["id"]] = c
                        sid = len(sub_topic) + 1
                        sub_topic[sid] = c["topic"]
                        subs.append({"id": sid, "channelId": c["id"]})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                continue
            now = time.monotonic()
            if m[0] == 1:
                sid, t = struct.unpack_from("<IQ", m, 1)
                topic = sub_topic[sid]
                out.messages.append((topic, t, bytes(m[13:]), now))
                if topic == until_topic:
                    break
            elif m[0] == 2:
                out.times.append(struct.unpack_from("<Q", m, 1)[0])
    return out


def collect_sync(url: str, **kw) -> Received:
    return asyncio.run(collect(url, **kw))
