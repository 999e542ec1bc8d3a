"""Fixtures shared by the bus suites and the cross-process suites."""

from __future__ import annotations

import contextlib
import functools
import io
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from unittest import mock

import numpy as np
import pytest

from rgtbus.bus import open_bus
from rgtbus.bus.registry import BUS_KINDS

EXE = [sys.executable, "-m", "rgtbus"]
RATE = 200.0


@pytest.fixture(autouse=True)
def _no_zenoh_config_from_the_shell(monkeypatch):
    """A ``ZENOH_CONFIG`` set in the shell that runs the tests would be every zenoh session's
    base (rgtbus.bus.config), here and in the processes the tests start: not in a test."""
    monkeypatch.delenv("ZENOH_CONFIG", raising=False)


@contextlib.contextmanager
def small_chunk_logs(size: int = 1024) -> Iterator[None]:
    """Logs written meanwhile in chunks of ``size`` bytes: a short run's log then has many
    chunks to cut and flip, as a long run's has (the default 1 MiB makes one of a gate's)."""
    from rgtbus.telemetry import mcap_recorder

    small = functools.partial(mcap_recorder.McapRecorder, chunk_size=size)
    with mock.patch.object(mcap_recorder, "McapRecorder", small):
        yield


@pytest.fixture
def procs():
    """``spawn(*argv)`` starts ``python -m rgtbus *argv``; every process is reaped at the end,
    even a stopped (SIGSTOP) one, even when the test fails."""
    spawned: list[subprocess.Popen] = []

    def spawn(*argv: str) -> subprocess.Popen:
        p = subprocess.Popen(
            [*EXE, *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            stdin=subprocess.DEVNULL,
            text=True,
        )
        spawned.append(p)
        return p

    try:
        yield spawn
    finally:
        for p in spawned:
            with contextlib.suppress(ProcessLookupError):
                os.kill(p.pid, signal.SIGCONT)
            if p.poll() is None:
                p.kill()
            p.communicate(timeout=30)


def _logged_run(sc, engine: str = "event") -> tuple[dict, bytes]:
    from rgtbus.units.group import run_group

    from rgtbus.telemetry import McapRecorder

    buf = io.BytesIO()
    rec = McapRecorder(buf)
    out = run_group(sc, "memory", rec, engine=engine)
    rec.close()
    return out.summary, buf.getvalue()


@pytest.fixture
def logged_run():
    """``logged_run(scenario, engine="event")``: run it on the memory bus with its full log;
    (the run's summary, the MCAP bytes)."""
    return _logged_run


@pytest.fixture(params=sorted(BUS_KINDS))
def kind(request):
    """Every suite of a live transport runs on every kind of bus the registry names (memory,
    zenoh): a new kind is run here as soon as it is registered."""
    return request.param


@pytest.fixture
def make_bus(kind):
    """``make(members, run_id, **options)``: a bus of ``kind``, closed at the end."""
    opened = []

    def make(members=("a", "b", "c"), run_id="r1", **options):
        bus = open_bus(kind, run_id, members, RATE, **options)
        opened.append(bus)
        return bus

    try:
        yield make
    finally:
        for bus in opened:
            bus.close()


@pytest.fixture(params=["memory", "zenoh", "log"])
def any_kind(request):
    """The bus contract holds on every bus: the live ones and the log-replay twin."""
    return request.param


@pytest.fixture
def open_any(any_kind):
    """``open(run_id, members, *, local=None, medium=None, end=NEVER)``: a bus of ``any_kind``
    serving ``medium`` (``{member: (samples, magnitudes)}``), closed at the end. The log bus is
    given ``medium`` and ``end`` (what its log holds); on a live bus, when ``medium`` is given
    (even empty), each local member publishes its part of it with a promise of ``end`` (the
    horizon, once every member has)."""
    from rgtbus.bus.logbus import LogBus
    from rgtbus.bus.payload import NEVER

    opened = []

    def open_(run_id, members, *, local=None, medium=None, end=NEVER):
        pulses = {u: (np.asarray(k, dtype=np.int64), np.asarray(v, dtype=float))
                  for u, (k, v) in (medium or {}).items()}  # fmt: skip
        if any_kind == "log":
            bus = LogBus(run_id, members, pulses, local=local, end=end)
        else:
            bus = open_bus(any_kind, run_id, members, RATE, local=local)
        opened.append(bus)
        if any_kind != "log" and medium is not None:
            for u in bus.local:
                k, v = pulses.get(u, ((), ()))
                bus.publish(u, k, v, promise=end)
        return bus

    try:
        yield open_
    finally:
        for bus in opened:
            bus.close()
