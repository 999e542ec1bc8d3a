"""A keyless zenoh process that floods a keyed run's frame keys (issue 50's attacker).

    python -m benchmarks.flooder --connect tcp/HOST:PORT --run RUN_ID --members a,b,c,d
        [--mode oversize|small|mixed|near|replay] [--seconds S] [--max-frames N] [--report FILE]
        [--session-mode client|peer]

It opens a zenoh session without the run's key, declares a publisher on every member's
``rgtbus/<run>/tx/<unit>`` (congestion control DROP: it never waits on a slow reader), waits
(bounded) until each publisher matches a subscriber (the run's units are up), prints ``open``
on stdout, then puts frames in a loop until ``--seconds`` or ``--max-frames`` is up or it is
sent SIGTERM / SIGINT:

- ``oversize``: 256 KB well-formed frames (header, pulses) with a wrong tag: far over the
  run's frame bound, dropped unread (``dropped_oversize``) by a gated receiver;
- ``small``: 4 KB such frames, under the bound: each costs a receiver an HMAC
  (``dropped_unauthenticated``) unless it is rate-gated first;
- ``mixed``: both, one big to four small on each key in turn (as the in-process flood test,
  tests/faults/test_fault_flood.py);
- ``near``: 4 KB such frames numbered 1 to 64 over and over, where the run's own frames
  are: none is ruled out by its header, each costs a tag check up to the receiver's rate
  gate (``dropped_unauthenticated``, then ``dropped_rate``), and the run's own frames share
  that gate with them (one crowded out is asked for again);
- ``replay``: it listens to the run's own frames as they go by (keeping at most
  ``MAX_CAPTURE``) and puts every captured frame again and again on its own key: frames with a
  valid tag, heard before (``dropped_duplicate`` / ``dropped_late``).

On exit it writes a JSON report (frames sent by kind, bytes, seconds, how it stopped) to
``--report`` (if given) and closes its session. Exit status 0, or 2 when the run's
subscribers never matched within ``--match-timeout``.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import struct
import sys
import threading
import time
from pathlib import Path
from typing import Any

import zenoh

from rgtbus.bus.auth import TAG_SIZE
from rgtbus.bus.config import make_config
from rgtbus.bus.payload import HEADER_SIZE, MAGIC, TAGGED, VERSION

BIG = 256 * 1024  # far over any run's frame bound
SMALL = 4 * 1024  # under the bound: a receiver must check its tag (or gate it first)
SMALL_PER_BIG = 4  # mixed: 1 big to 4 small on each key
MAX_CAPTURE = 20000  # replay: the most frames of the run it keeps
RATE = 200.0  # the sample rate the junk claims (a receiver checks the tag before it)
# The header as rgtbus.bus.payload lays it out (its struct is private): magic, version, flags,
# reserved, seq, promise, done_at, rate, count, reserved.
HEADER = struct.Struct("<4sBBHQQQdII")
assert HEADER.size == HEADER_SIZE, "rgtbus.bus.payload's header changed: update HEADER"
MODES = ("oversize", "small", "mixed", "near", "replay")
NEAR = 64  # near: small junk numbered 1..64 over and over, where a run's own frames are


def junk_parts(size: int) -> tuple[int, bytes]:
    """(pulse count, zeroed pulse arrays) of a junk frame of about ``size`` bytes."""
    n = max(0, (size - HEADER_SIZE - TAG_SIZE) // 16)
    return n, bytes(16 * n)


def junk(size: int, seq: int = 1, parts: tuple[int, bytes] | None = None) -> bytes:
    """A well-formed frame (header, ``n`` zero pulses at sample 0, the TAGGED flag) with a
    random tag: what a peer without the key can send. A fresh object each call."""
    n, body = parts if parts is not None else junk_parts(size)
    head = HEADER.pack(MAGIC, VERSION, TAGGED, 0, seq, 10, 0, RATE, n, 0)
    return head + body + os.urandom(TAG_SIZE)


class Capture:
    """The run's own frames as they go by (``replay``): (key, bytes), at most ``limit``."""

    def __init__(self, limit: int = MAX_CAPTURE) -> None:
        self.limit = limit
        self.frames: list[tuple[str, bytes]] = []
        self.heard = 0  # every frame heard, kept or not
        self._lock = threading.Lock()

    def __call__(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.heard += 1
            if len(self.frames) < self.limit:
                self.frames.append((str(sample.key_expr), sample.payload.to_bytes()))

    def snapshot(self) -> list[tuple[str, bytes]]:
        with self._lock:
            return list(self.frames)


class Flood:
    """Counts of what was put, by kind, and how the flood stopped."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.sent: dict[str, int] = {"big": 0, "small": 0, "replay": 0}
        self.bytes = 0
        self.put_errors = 0
        self.last_error: str | None = None
        self.stopped_by = "running"
        self.matched = False
        self.match_seconds: float | None = None
        self.t0 = time.monotonic()
        self.flood_t0: float | None = None
        self.flood_seconds = 0.0
        self.captured = 0
        self.heard = 0
        self.stop = False

    @property
    def frames(self) -> int:
        return sum(self.sent.values())

    def put(self, pub: zenoh.Publisher, data: bytes, kind: str) -> None:
        try:
            pub.put(data)
        except zenoh.ZError as e:  # the session is going: count, and stop after a few
            self.put_errors += 1
            self.last_error = str(e)
            if self.put_errors >= 100:
                self.stop, self.stopped_by = True, "put errors"
            return
        self.sent[kind] += 1
        self.bytes += len(data)

    def report(self) -> dict[str, Any]:
        a = self.args
        return {
            "mode": a.mode,
            "run": a.run,
            "members": a.members,
            "connect": a.connect,
            "matched": self.matched,
            "match_seconds": self.match_seconds,
            "sent": dict(self.sent),
            "frames": self.frames,
            "bytes": self.bytes,
            "seconds": round(self.flood_seconds, 3),
            "frames_per_second": round(self.frames / self.flood_seconds, 1)
            if self.flood_seconds > 0
            else 0.0,
            "captured": self.captured,
            "heard": self.heard,
            "put_errors": self.put_errors,
            "last_error": self.last_error,
            "stopped_by": self.stopped_by,
        }


def parse(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--connect",
        "-e",
        required=True,
        action="append",
        metavar="ENDPOINT",
        help="zenoh endpoint (the run's router), e.g. tcp/127.0.0.1:7447",
    )
    ap.add_argument("--run", required=True, metavar="RUN_ID", help="the run's id on the bus")
    ap.add_argument("--members", required=True, help="the run's units, e.g. a,b,c,d")
    ap.add_argument("--mode", choices=MODES, default="mixed")
    ap.add_argument(
        "--session-mode",
        choices=("client", "peer"),
        default="client",
        help="zenoh mode of this session (default client: through the router)",
    )
    ap.add_argument("--seconds", type=float, default=600.0, help="flood at most S seconds")
    ap.add_argument("--max-frames", type=int, default=None, help="put at most N frames")
    ap.add_argument(
        "--match-timeout",
        type=float,
        default=60.0,
        help="give up when the run's subscribers are not matched within S seconds",
    )
    ap.add_argument("--report", metavar="FILE", help="write the JSON report here on exit")
    args = ap.parse_args(argv)
    args.members = [m for m in args.members.split(",") if m]
    if not args.members:
        ap.error("--members: at least one unit")
    return args


def wait_matched(pubs: list[zenoh.Publisher], flood: Flood, timeout: float) -> bool:
    """Until every publisher matches a subscriber (the run's units are up), bounded."""
    deadline = time.monotonic() + timeout
    while not all(p.matching_status.matching for p in pubs):
        if flood.stop or time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def flood_junk(pubs: list[zenoh.Publisher], flood: Flood, end: float) -> None:
    """oversize / small / mixed: round robin over every member's key."""
    mode, cap = flood.args.mode, flood.args.max_frames
    big_parts, small_parts = junk_parts(BIG), junk_parts(SMALL)
    seq = 0
    while not flood.stop:
        if time.monotonic() >= end:
            flood.stopped_by = "time"
            return
        for pub in pubs:
            seq += 1
            if mode == "near":  # every one passes the header's checks: a tag check each
                flood.put(pub, junk(SMALL, seq % NEAR + 1, small_parts), "small")
            if mode in ("oversize", "mixed"):
                flood.put(pub, junk(BIG, seq, big_parts), "big")
            if mode in ("small", "mixed"):
                for _ in range(SMALL_PER_BIG if mode == "mixed" else 1):
                    flood.put(pub, junk(SMALL, seq, small_parts), "small")
            if cap is not None and flood.frames >= cap:
                flood.stopped_by = "count"
                return
        time.sleep(0)  # let the signal handler and zenoh's threads in


def flood_replay(session: zenoh.Session, flood: Flood, end: float) -> None:
    """replay: every captured frame of the run, again and again, on its own key."""
    cap = flood.args.max_frames
    capture = Capture()
    sub = session.declare_subscriber(
        f"rgtbus/{flood.args.run}/tx/*", capture, allowed_origin=zenoh.Locality.REMOTE
    )
    pubs: dict[str, zenoh.Publisher] = {}
    try:
        while not flood.stop:
            frames = capture.snapshot()
            flood.captured, flood.heard = len(frames), capture.heard
            if not frames:
                if time.monotonic() >= end:
                    flood.stopped_by = "time"
                    return
                time.sleep(0.005)
                continue
            for key, data in frames:
                if flood.stop:
                    return
                pub = pubs.get(key)
                if pub is None:
                    pub = pubs[key] = session.declare_publisher(
                        key,
                        congestion_control=zenoh.CongestionControl.DROP,
                        allowed_destination=zenoh.Locality.REMOTE,
                    )
                flood.put(pub, data, "replay")
                if cap is not None and flood.frames >= cap:
                    flood.stopped_by = "count"
                    return
                if flood.sent["replay"] % 256 == 0:
                    if time.monotonic() >= end:
                        flood.stopped_by = "time"
                        return
                    time.sleep(0)
    finally:
        flood.captured, flood.heard = len(capture.frames), capture.heard
        for pub in pubs.values():
            pub.undeclare()
        sub.undeclare()


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    flood = Flood(args)

    def stop(signum: int, _frame: object) -> None:
        flood.stop = True
        flood.stopped_by = signal.Signals(signum).name

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    code = 0
    session = zenoh.open(make_config(connect=args.connect, mode=args.session_mode))
    try:
        pubs = [
            session.declare_publisher(
                f"rgtbus/{args.run}/tx/{u}",
                congestion_control=zenoh.CongestionControl.DROP,
                allowed_destination=zenoh.Locality.REMOTE,
            )
            for u in args.members
        ]
        flood.matched = wait_matched(pubs, flood, args.match_timeout)
        flood.match_seconds = round(time.monotonic() - flood.t0, 3)
        if not flood.matched:
            if not flood.stop:
                flood.stopped_by = "never matched"
                print(
                    f"flooder: the run's subscribers never matched within {args.match_timeout:g} s",
                    file=sys.stderr,
                )
                code = 2
        else:
            print("open", flush=True)
            flood.flood_t0 = time.monotonic()
            end = flood.flood_t0 + args.seconds
            if args.mode == "replay":
                flood_replay(session, flood, end)
            else:
                flood_junk(pubs, flood, end)
            flood.flood_seconds = time.monotonic() - flood.flood_t0
        for pub in pubs:
            pub.undeclare()
    finally:
        if flood.flood_t0 is not None and not flood.flood_seconds:
            flood.flood_seconds = time.monotonic() - flood.flood_t0
        if args.report:
            Path(args.report).write_text(json.dumps(flood.report()) + "\n")
        session.close()
    return code


if __name__ == "__main__":
    sys.exit(main())
