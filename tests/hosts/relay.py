"""A test-only TCP relay that adds latency: it listens on one address, forwards every
connection to another, and delivers each chunk it reads ``delay`` ± ``jitter`` seconds later,
in order within each direction (a chunk is never delivered before the one read before it).

    python tests/hosts/relay.py --listen 0.0.0.0:7448 --to 127.0.0.1:7447 --delay 0.05 --jitter 0.01

It prints one line ``relay listening on HOST:PORT`` once it accepts (the port it got, for
``--listen HOST:0``), and runs until killed (SIGTERM or SIGINT). Only the standard library:
it runs in any namespace the tests make.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import random
import signal
import sys


def host_port(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    return host, int(port)


async def carry(
    reader: asyncio.StreamReader,
    writer: asyncio.StreamWriter,
    delay: float,
    jitter: float,
    rng: random.Random,
) -> None:
    """Copy ``reader`` to ``writer``, each chunk due ``delay`` ± ``jitter`` s after it was
    read, never before the chunk read before it (order kept). The end of the input is passed
    on (half-close) once everything before it was delivered."""
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue[tuple[float, bytes | None]] = asyncio.Queue()

    async def deliver() -> None:
        while True:
            due, data = await queue.get()
            wait = due - loop.time()
            if wait > 0:
                await asyncio.sleep(wait)
            if data is None:
                if writer.can_write_eof():
                    writer.write_eof()
                return
            writer.write(data)
            await writer.drain()

    sender = asyncio.create_task(deliver())
    last = 0.0
    try:
        while True:
            data = await reader.read(65536)
            due = max(loop.time() + delay + rng.uniform(-jitter, jitter), last)
            last = due
            queue.put_nowait((due, data or None))
            if not data:
                break
        await sender
    finally:
        sender.cancel()


async def serve(listen: str, to: str, delay: float, jitter: float, seed: int | None) -> None:
    rng = random.Random(seed)
    target_host, target_port = host_port(to)

    async def on_client(c_reader: asyncio.StreamReader, c_writer: asyncio.StreamWriter) -> None:
        try:
            t_reader, t_writer = await asyncio.open_connection(target_host, target_port)
        except OSError:
            c_writer.close()
            return
        both = [
            asyncio.create_task(carry(c_reader, t_writer, delay, jitter, rng)),
            asyncio.create_task(carry(t_reader, c_writer, delay, jitter, rng)),
        ]
        try:
            # one direction failing (a reset) ends the connection both ways
            await asyncio.wait(both, return_when=asyncio.FIRST_EXCEPTION)
        finally:
            for task in both:
                task.cancel()
            for w in (c_writer, t_writer):
                with contextlib.suppress(Exception):
                    w.close()

    host, port = host_port(listen)
    server = await asyncio.start_server(on_client, host, port)
    bound = server.sockets[0].getsockname()
    print(f"relay listening on {bound[0]}:{bound[1]}", flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    async with server:
        await stop.wait()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--listen", required=True, help="HOST:PORT to accept on")
    ap.add_argument("--to", required=True, help="HOST:PORT to forward each connection to")
    ap.add_argument("--delay", type=float, default=0.05, help="seconds added to each chunk")
    ap.add_argument("--jitter", type=float, default=0.01, help="± seconds, uniform")
    ap.add_argument("--seed", type=int, default=None)
    args = ap.parse_args(argv)
    if not 0 <= args.jitter <= args.delay:
        ap.error("--jitter must be between 0 and --delay")
    asyncio.run(serve(args.listen, args.to, args.delay, args.jitter, args.seed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
