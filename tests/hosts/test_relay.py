"""The test-only relay of tests/hosts (relay.py): every byte through, in order each way, each
chunk late by the delay ± the jitter. On loopback: no namespace, no root needed."""

from __future__ import annotations

import select
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

RELAY = Path(__file__).with_name("relay.py")


def echo_server() -> tuple[socket.socket, threading.Thread]:
    """A one-connection echo server on a free loopback port; it half-closes after the input."""
    srv = socket.create_server(("127.0.0.1", 0))
    srv.settimeout(60)

    def serve() -> None:
        conn, _ = srv.accept()
        with conn:
            conn.settimeout(60)
            while data := conn.recv(65536):
                conn.sendall(data)
            conn.shutdown(socket.SHUT_WR)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return srv, thread


@pytest.mark.slow  # timed delays: CI's slow pass (the fast suite stays near 3 min)
def test_the_relay_delays_every_chunk_and_keeps_the_order(tmp_path):
    srv, thread = echo_server()
    port = srv.getsockname()[1]
    argv = [sys.executable, str(RELAY), "--listen", "127.0.0.1:0", "--to", f"127.0.0.1:{port}",
            "--delay", "0.05", "--jitter", "0.01", "--seed", "1"]  # fmt: skip
    relay = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ready, _, _ = select.select([relay.stdout], [], [], 60)
        line = relay.stdout.readline() if ready else ""  # a line, or the relay ended
        assert line.startswith("relay listening on 127.0.0.1:"), (line, relay.poll())
        relay_port = int(line.rsplit(":", 1)[1])
        with socket.create_connection(("127.0.0.1", relay_port), timeout=60) as s:
            sent, got, trips = b"", b"", []
            for i in range(20):
                msg = f"{i:04d}".encode() * 100  # 400 bytes, numbered
                t0 = time.monotonic()
                s.sendall(msg)
                sent += msg
                back = b""
                while len(back) < len(msg):
                    back += s.recv(65536)
                trips.append(time.monotonic() - t0)
                got += back
            # the rest of a stream in flight: many chunks queued at once keep their order
            burst = b"".join(f"{i:06d}".encode() for i in range(20_000))
            s.sendall(burst)
            s.shutdown(socket.SHUT_WR)
            while data := s.recv(65536):
                got += data
        assert got == sent + burst
        # each round trip crosses the relay twice: at least 2 x (50 - 10) ms
        assert min(trips) >= 0.08, trips
        assert sorted(trips)[len(trips) // 2] < 5.0, trips  # not stuck (generous: loaded CI)
    finally:
        relay.terminate()
        relay.communicate(timeout=30)
        srv.close()
        thread.join(timeout=30)
