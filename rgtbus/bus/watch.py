"""A watcher of a cross-process run: it joins the run's zenoh network and hears what every unit
process logs (``rgtbus/<run>/telemetry/<unit>``, rgtbus.bus.payload telemetry frames).

A watcher is never a member: it declares no hello, token or publisher, so the lockstep neither
waits for it nor notices it leave. Frames that are not telemetry, or name a topic under another
schema than the recorder's, are counted and dropped (a hostile or broken peer cannot put
anything else into a live view). The zenoh callback never blocks: it decodes and hands the
message to ``sink.put`` (a LiveView sends without waiting for clients).
"""

from __future__ import annotations

import threading
import time
from typing import Any

import zenoh

from rgtbus.bus import keys
from rgtbus.bus.payload import decode_telemetry
from rgtbus.bus.zenoh import close_session, make_config, zenoh_reason
from rgtbus.errors import RgtbusError
from rgtbus.telemetry import topics
from rgtbus.telemetry.recorder import LiveSink

MAX_FRAME = 64 << 20  # bytes: no logged message comes near it


class Watcher:
    """Subscribes to the telemetry of run ``run_id`` (every run: ``*``) and passes it on."""

    def __init__(self, sink: LiveSink, *, run_id: str = "*", **zenoh_options: Any) -> None:
        if not run_id or any(c in run_id for c in "/?#$") or (run_id != "*" and "*" in run_id):
            raise RgtbusError(f"--run {run_id!r}: not a run id")
        self.sink = sink
        self.received = 0
        self.dropped = 0
        self.last_heard = time.monotonic()
        self.heard = threading.Event()  # set at the first message
        self.runs: set[str] = set()
        config = make_config(**zenoh_options)  # its own errors are one line already
        try:
            self.session = zenoh.open(config)
        except Exception as e:
            raise RgtbusError(f"cannot open zenoh session: {zenoh_reason(e)}") from None
        self._sub = self.session.declare_subscriber(
            keys.every_unit(keys.TELEMETRY, run_id), self._on_sample
        )

    def _on_sample(self, sample: Any) -> None:
        payload = sample.payload.to_bytes()
        try:
            if len(payload) > MAX_FRAME:
                raise ValueError("too large")
            topic, schema, data, t_ns = decode_telemetry(payload)
            if topics.schema_for(topic) != schema:
                raise ValueError(f"{topic} is not under {schema}")
        except (ValueError, RgtbusError):
            self.dropped += 1
            return
        self.runs.add(str(sample.key_expr).split("/")[1])
        self.sink.put(topic, schema, data, t_ns)
        self.received += 1
        self.last_heard = time.monotonic()
        self.heard.set()

    def close(self, timeout: float = 5.0) -> str | None:
        """Undeclare and close; what went wrong closing, or None."""
        try:
            self._sub.undeclare()
        except Exception as e:  # zenoh's ZError
            return zenoh_reason(e)
        return close_session(self.session, timeout)

    def __enter__(self) -> Watcher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
