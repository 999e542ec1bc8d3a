"""The buses' tests. One suite of the bus contract runs on every bus (memory, zenoh and the
log-replay twin, ``LogBus``): the same medium served, the same assertions. Then what only a live
transport does (memory and zenoh: frames published one by one, promises, foreign, malformed,
late and replayed frames, the gate's bounds, keys, queues), what only the log bus does, the
zenoh-only paths and the frame codec.

Every wait has a short timeout and every bus is closed by its fixture, even on failure.
"""

from __future__ import annotations

import inspect
import socket
import struct
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from rgtbus.bus import (
    FAILED,
    FINAL,
    NEVER,
    STAT_KEYS,
    Bus,
    Frame,
    MemoryBus,
    decode,
    encode,
    open_bus,
)
from rgtbus.bus.base import AHEAD_WINDOW
from rgtbus.bus.logbus import LogBus, LogEnded
from rgtbus.bus.payload import HEADER_SIZE, MAX_MAGNITUDE
from rgtbus.errors import PeerSilent, RgtbusError

RATE = 200.0
SHORT = 0.3  # seconds: long enough for in-process zenoh, short enough to keep the suite fast


def units(n):
    return tuple(f"u{i}" for i in range(n))


def magnitudes(rng, n):
    # Values whose bits are easy to mangle: -0.0, subnormals, extremes within the bound.
    x = rng.normal(size=n) * 10.0 ** rng.integers(-300, 6, size=n)
    x[0] = -0.0
    x[-1] = 5e-324
    return x


def same_bits(a, b):
    return a.dtype == np.float64 and np.array_equal(a.view(np.uint64), b.view(np.uint64))


def wait_for(pred, timeout=2.0):
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.005)


# -- the bus contract: every bus, the log-replay twin included -------------------------------------

# One medium for every bus: a live bus's members publish it with a promise of END, the log bus
# is given it. Pulses past END are on their way (known, not yet taken); magnitudes whose bits
# are easy to mangle, and one sample twice (its magnitudes in the order sent).
MEDIUM = {
    "a": ([3, 40, 40, 90], [0.25, -0.0, 5e-324, 1.5]),
    "b": ([7, 41], [-1e-17, 2.0]),
    "c": ([], []),
}
END = 41
DIGEST = "0" * 64  # a scenario digest, as a hello carries it


def _pulses(unit):
    k, v = MEDIUM[unit]
    return np.asarray(k, dtype=np.int64), np.asarray(v, dtype=float)


def test_every_bus_keeps_the_bus_protocol(open_any):
    bus = open_any("r1", ("a", "b", "c"), local=["a", "b"])
    assert isinstance(bus, Bus)
    assert (bus.run_id, bus.members, bus.local) == ("r1", ("a", "b", "c"), ("a", "b"))
    assert bus.close_problem is None and not bus.closed
    # the world calls these by the protocol's names (publish's promise, wait's timeout, ...)
    for name in ("publish", "wait", "take", "known", "status", "join", "stats", "drop_notes"):
        want = inspect.signature(getattr(Bus, name)).parameters.values()
        got = inspect.signature(getattr(type(bus), name)).parameters.values()
        assert [(p.name, p.kind) for p in got] == [(p.name, p.kind) for p in want], name


def test_the_medium_is_served_bit_identical_up_to_the_horizon(open_any):
    bus = open_any("r1", ("a", "b", "c"), medium=MEDIUM, end=END)
    assert bus.wait(0, timeout=2.0) == END  # the horizon: every member promised END
    assert {u: s.promise for u, s in bus.status().items()} == dict.fromkeys("abc", END)
    ahead = bus.known(100)  # on its way, past the horizon too; nothing is handed out
    for u in "abc":
        k, v = _pulses(u)
        assert np.array_equal(ahead[u][0], k) and same_bits(ahead[u][1], v)
    got = bus.take(END)
    assert list(got) == ["a", "b", "c"]
    for u in "abc":
        k, v = _pulses(u)
        now = k < END
        assert np.array_equal(got[u][0], k[now]) and same_bits(got[u][1], v[now])
    assert all(p[0].size == 0 for p in bus.take(END).values())  # handed out once
    later = bus.known(100)
    assert later["a"][0].tolist() == [90] and later["b"][0].tolist() == [41]
    assert same_bits(later["a"][1], np.array([1.5]))
    assert bus.drop_notes() == []


def test_take_is_bounded_by_the_horizon(open_any):
    bus = open_any("r1", ("a",), medium={"a": ([3], [0.5])}, end=10)
    assert bus.wait(0, timeout=2.0) == 10
    with pytest.raises(RgtbusError, match="take up to sample 11: only samples before 10 are final"):
        bus.take(11)
    assert bus.take(10)["a"][0].tolist() == [3]


def test_waiting_past_every_promise_fails_naming_the_sample(open_any):
    """A live member silent past its promise, a log cut short: RgtbusError, in one line."""
    bus = open_any("r1", ("a", "b"), medium={}, end=END)
    assert bus.wait(END - 1, timeout=2.0) == END
    t0 = time.monotonic()
    with pytest.raises(RgtbusError, match=f"sample {END}") as err:
        bus.wait(END, timeout=SHORT)
    assert time.monotonic() - t0 < 3.0 and "\n" not in str(err.value)


def test_flags_and_done_at_reach_the_status(open_any):
    bus = open_any("r1", ("a", "b", "c"), medium={}, end=END)
    assert bus.wait(0, timeout=2.0) == END
    published = bus.stats()["published"]
    bus.publish("a", [], [], promise=END, flags=FINAL, done_at=12)
    bus.publish("b", [], [], promise=END, flags=FAILED, done_at=30)
    assert bus.stats()["published"] == published + 2
    wait_for(lambda: bus.status()["a"].flags and bus.status()["b"].flags)  # live: in flight
    st_ = bus.status()
    assert (st_["a"].flags, st_["a"].done_at) == (FINAL, 12)
    assert (st_["b"].flags, st_["b"].done_at) == (FAILED, 30)
    assert (st_["c"].flags, st_["c"].done_at) == (0, 0)


def test_only_a_local_member_publishes(open_any):
    bus = open_any("r1", ("a", "b", "c"), local=["b"])
    assert bus.local == ("b",)
    stranger = r"unit 'zz' is not a member of run 'r1' \(members: a, b, c\)"
    with pytest.raises(RgtbusError, match=stranger):
        bus.publish("zz", [], [], promise=1)
    with pytest.raises(RgtbusError, match=r"unit 'a' is not published from this bus \(local: b\)"):
        bus.publish("a", [], [], promise=1)
    bus.publish("b", [], [], promise=1)
    with pytest.raises(RgtbusError, match="unit 'zz' is not a member of run 'r2'"):
        open_any("r2", ("a", "b"), local=["zz"])


def test_join_as_every_member_but_never_as_a_stranger(open_any):
    bus = open_any("r1", ("a", "b"))
    with pytest.raises(RgtbusError, match="unit 'zz' is not a member"):
        bus.join(["a", "zz"], DIGEST, timeout=1.0)
    bus.join(["a", "b"], DIGEST, timeout=2.0)  # every member in this process: nobody to wait for


def test_close_is_idempotent_and_final(open_any, any_kind):
    bus = open_any("r1", ("a", "b"), medium={}, end=END)
    bus.close()
    bus.close()
    assert bus.closed
    refused = {
        "publish": lambda: bus.publish("a", [], [], promise=END),
        "wait": lambda: bus.wait(0, timeout=0.1),
        "take": lambda: bus.take(0),
    }
    for what, call in refused.items():
        with pytest.raises(RgtbusError, match=f"{what} on closed {any_kind} bus of run 'r1'"):
            call()
    assert set(bus.status()) == {"a", "b"} and set(bus.known(END)) == {"a", "b"}  # still said


def test_the_context_manager_closes(open_any):
    with open_any("ctx", ("a",)) as bus:
        assert not bus.closed
    assert bus.closed
    with pytest.raises(RuntimeError, match="in the block"), open_any("ctx2", ("a",)) as failed:
        raise RuntimeError("in the block")  # the block's own error is the one reported
    assert failed.closed


@pytest.mark.parametrize(
    ("run_id", "members", "msg"),
    [
        ("a/b", ["a"], "bad run id 'a/b'"),
        ("r", ["a*"], r"bad unit name 'a\*'"),
        ("r", [], "run 'r' has no members"),
        ("r", ["a", "a"], r"duplicate member\(s\) a in run 'r'"),
        ("r", "ab", "members must be a sequence of unit names, got the string 'ab'"),
    ],
)
def test_bad_bus_parameters(open_any, run_id, members, msg):
    with pytest.raises(RgtbusError, match=msg):
        open_any(run_id, members)


@pytest.fixture(scope="module")
def gate_runs(tmp_path_factory):
    """The gate over the memory bus (logged to a file) and over zenoh."""
    from pathlib import Path
    from types import SimpleNamespace

    from rgtbus.units.group import run_group

    from rgtbus.scenario import load_scenario
    from rgtbus.telemetry import McapRecorder, MemoryRecorder

    sc = load_scenario(Path(__file__).parent.parent / "scenarios" / "gate.toml")
    out = {}
    path = tmp_path_factory.mktemp("gate") / "memory.mcap"
    with open(path, "wb") as f:
        rec = McapRecorder(f)
        mem = run_group(sc, "memory", rec)
        rec.close()
    for kind in ("memory", "zenoh"):
        rec = MemoryRecorder()
        res = run_group(sc, kind, rec)
        out[kind] = SimpleNamespace(summary=res.summary, messages=rec.read()[0], path=path)
    assert mem.summary["outcome"] == out["memory"].summary["outcome"]
    return out


def test_a_run_is_identical_over_every_bus(gate_runs):
    """Memory, zenoh, and a re-run of the memory run's log over the log bus: the same
    decisions, tables and unit messages."""
    from rgtbus.units.rerun import rerun_replay

    from rgtbus.telemetry.message_json import message_bytes
    from rgtbus.telemetry.read import load_replay

    mem, zen = gate_runs["memory"], gate_runs["zenoh"]
    replayed = rerun_replay(load_replay(mem.path))
    for other in (zen.summary, replayed.summary):
        for key in ("polynomial", "relations", "influences", "units", "outcome", "sim_seconds"):
            assert other[key] == mem.summary[key], key

    def logged(messages):  # as the log holds them (a hot topic's block)
        return [(tp, t, message_bytes(tp, m)) for tp, t, m in messages]

    assert logged(zen.messages) == logged(mem.messages)


# -- live transports only (memory and zenoh): frames, promises, what arrives -----------------------


@pytest.mark.parametrize("n", [3, 10])
def test_pulses_and_promises_round_trip_bit_identical(make_bus, n):
    members = units(n)
    bus = make_bus(members)
    assert isinstance(bus, Bus)
    assert bus.members == members and bus.run_id == "r1"
    rng = np.random.default_rng(n)
    promised = dict.fromkeys(members, 0)
    sent = {u: (np.zeros(0, dtype=np.int64), np.zeros(0)) for u in members}
    for _ in range(4):
        for i, u in enumerate(reversed(members)):  # arrival order must not matter
            k = np.sort(rng.integers(promised[u], promised[u] + 500, size=5))
            v = magnitudes(rng, 5)
            promised[u] += 100 + i
            bus.publish(u, k, v, promise=promised[u])
            both = np.concatenate([sent[u][0], k]), np.concatenate([sent[u][1], v])
            order = np.argsort(both[0], kind="stable")
            sent[u] = both[0][order], both[1][order]
        # past everything promised now: returns once every member's latest frame is in
        h = bus.wait(min(promised.values()) - 1, timeout=2.0)
        assert h == min(promised.values())  # the horizon: the smallest promise
        got = bus.take(h)
        assert list(got) == list(members)
        for u in members:
            now = sent[u][0] < h
            assert np.array_equal(got[u][0], sent[u][0][now])
            assert same_bits(got[u][1], sent[u][1][now])
            sent[u] = sent[u][0][~now], sent[u][1][~now]


def test_one_samples_magnitudes_keep_their_order(make_bus):
    bus = make_bus(("a",))
    bus.publish("a", [10, 10], [0.1, 0.7], promise=5)
    bus.publish("a", [10], [1e-17], promise=6)
    # past the first frame's promise: over zenoh the two frames may arrive apart
    assert bus.wait(5, timeout=2.0) == 6
    bus.publish("a", [], [], promise=20)
    bus.wait(6, timeout=2.0)
    k, v = bus.take(20)["a"]
    assert k.tolist() == [10, 10, 10] and v.tolist() == [0.1, 0.7, 1e-17]


def test_wait_timeout_names_the_silent_members(make_bus):
    bus = make_bus()
    bus.publish("a", [], [], promise=100)
    bus.publish("c", [], [], promise=100)
    t0 = time.monotonic()
    with pytest.raises(RgtbusError) as err:
        bus.wait(0, timeout=SHORT)
    assert time.monotonic() - t0 < 3.0
    msg = str(err.value)
    assert "no news for 0.3 s" in msg and "'r1'" in msg and ": b promised nothing past" in msg
    assert "\n" not in msg


def test_once_everyone_promised_silence_wait_is_for_the_done_flags(make_bus):
    bus = make_bus(("a", "b"))
    bus.publish("a", [], [], promise=NEVER, flags=FINAL, done_at=70)
    bus.publish("b", [], [], promise=NEVER)
    assert bus.wait(0, timeout=2.0) == NEVER
    with pytest.raises(RgtbusError, match="b did not say it was done"):
        bus.wait(NEVER, timeout=SHORT)
    bus.publish("b", [], [], promise=NEVER, flags=FAILED, done_at=90)
    assert bus.wait(NEVER, timeout=2.0) == NEVER
    st_ = bus.status()
    assert (st_["a"].flags, st_["a"].done_at) == (FINAL, 70)
    assert (st_["b"].flags, st_["b"].done_at) == (FAILED, 90)


def test_publish_refuses_bad_input(make_bus):
    bus = make_bus()
    bus.publish("a", [5], [0.4], promise=10)
    with pytest.raises(RgtbusError, match="before its earlier promise"):
        bus.publish("a", [9], [0.4], promise=20)
    with pytest.raises(RgtbusError, match="goes back from 10"):
        bus.publish("a", [], [], promise=9)
    with pytest.raises(RgtbusError, match="not finite or beyond"):
        bus.publish("b", [3], [np.nan], promise=4)
    with pytest.raises(RgtbusError, match="not finite or beyond"):
        bus.publish("b", [3], [1e308], promise=4)
    with pytest.raises(RgtbusError, match="not in order"):
        bus.publish("b", [4, 3], [0.1, 0.1], promise=5)
    with pytest.raises(RgtbusError, match="4 sample indexes for 3 values"):
        bus.publish("b", [1, 2, 3, 4], [0.1, 0.1, 0.1], promise=5)


def test_put_raw_on_a_closed_bus(make_bus):
    bus = make_bus()
    bus.close()
    with pytest.raises(RgtbusError, match="put_raw on closed"):
        bus.put_raw("rgtbus/r1/tx/a", b"x")


def _frame(seq, promise, samples=(), values=(), flags=0, done_at=0, rate=RATE):
    return encode(
        Frame(seq, promise, np.array(samples, dtype=np.int64), np.array(values), flags, done_at),
        rate,
    )


def test_foreign_malformed_replayed_and_late_frames_are_dropped_and_counted(make_bus):
    bus = make_bus(("a", "b"))
    good = _frame(1, 10, [3], [0.4])
    bus.put_raw("rgtbus/other-run/tx/a", good)  # another run
    bus.put_raw("rgtbus/r1/tx/zz", good)  # not a member
    bus.put_raw("rgtbus/r1/tx/a", b"garbage")  # not a frame
    bus.put_raw("rgtbus/r1/tx/a", _frame(1, 10, rate=100.0))  # another sample rate
    bus.put_raw("rgtbus/r1/tx/a", good)  # accepted
    bus.put_raw("rgtbus/r1/tx/a", good)  # replayed
    bus.put_raw("rgtbus/r1/tx/a", _frame(3, 30))  # a frame missing before it: held
    bus.put_raw("rgtbus/r1/tx/a", _frame(2, 9))  # promise going back
    bus.put_raw("rgtbus/r1/tx/a", _frame(2, 12, [5], [0.1]))  # pulse before its promise
    bus.put_raw("rgtbus/r1/tx/a", _frame(3 + AHEAD_WINDOW, 30))  # far ahead: dropped unread
    bus.put_raw("rgtbus/r1/tx/b", _frame(1, 12, flags=FINAL, done_at=4))
    bus.put_raw("rgtbus/r1/tx/b", _frame(2, 13, flags=FAILED, done_at=4))  # done flags change
    wait_for(lambda: bus.stats()["received"] == 12)
    st_ = bus.stats()
    assert set(st_) == set(STAT_KEYS)
    assert st_["dropped_foreign"] == 2
    assert st_["dropped_malformed"] == 4  # garbage, rate, promise back, flags changed
    assert st_["dropped_duplicate"] == 1
    assert st_["dropped_ahead"] == 1
    assert st_["held"] == 1  # frame 3, until a good frame 2 comes
    assert st_["dropped_late"] == 1
    assert st_["accepted"] == 2
    notes = bus.drop_notes()
    assert any("'zz' is not a member" in n for n in notes)
    assert any("not run 'r1'" in n for n in notes)
    assert any("received twice" in n for n in notes)
    assert all("\n" not in n for n in notes)
    assert bus.drop_notes() == []
    assert bus.wait(0, timeout=2.0) == 10
    assert bus.take(10)["a"][0].tolist() == [3]


# -- the gate: what a bus receives is bounded ------------------------------------------------------

KEY = bytes(range(1, 33))


def _signed(bus, unit, seq, promise, samples=(), values=()):
    """A frame of ``unit`` signed as the bus's own process would sign it."""
    from rgtbus.bus.auth import tag

    def sign(body: bytes) -> bytes:
        return tag(KEY, "frame", bus.run_id, unit, bus.nonce, body)

    frame = Frame(seq, promise, np.array(samples, dtype=np.int64), np.array(values, float))
    return encode(frame, RATE, sign=sign)


@pytest.mark.parametrize("keyed", [False, True], ids=["open", "keyed"])
def test_frames_over_the_runs_bound_are_dropped_unread(make_bus, keyed):
    bus = make_bus(("a", "b"), key=KEY if keyed else None)
    assert bus.max_pulses == 4096 and bus.max_frame == HEADER_SIZE + 16 * 4096 + 32 * keyed
    assert make_bus(units(100)).max_pulses == 25600  # scales with the run
    n = bus.max_pulses + 3  # over the bound in bytes, tag or not
    big = _frame(1, 10, list(range(n)), [0.5] * n)  # a valid frame, a few pulses too many
    for _ in range(30):
        bus.put_raw("rgtbus/r1/tx/a", big)
    bus.put_raw("rgtbus/r1/tx/a", b"x" * (16 << 20))
    wait_for(lambda: bus.stats()["received"] == 31)
    st_ = bus.stats()
    assert st_["dropped_oversize"] == 31 and st_["accepted"] == 0, st_
    notes = bus.drop_notes()  # at most 20 a reason, then how many more
    assert len(notes) == 21 and notes[-1] == "... and 11 more dropped_oversize (counted)"
    assert "the run's bound is" in notes[0]
    # and a bus refuses to send what its peers would drop
    with pytest.raises(RgtbusError, match="carries at most 4096"):
        bus.publish("a", np.arange(4097), np.ones(4097), promise=5000)
    bus.publish("a", np.arange(4096), np.ones(4096), promise=5000)  # the bound itself is fine
    wait_for(lambda: bus.stats()["accepted"] == 1)


def test_an_open_runs_receive_queue_is_bounded_per_member():
    from rgtbus.bus.base import INBOX_BYTES_OPEN

    bus = MemoryBus("r1", ("a", "b"), RATE)
    try:
        n = 4000
        frame = _frame(1, 10, list(range(n)), [0.5] * n)  # 64 KB: under the frame bound
        fits = INBOX_BYTES_OPEN // len(frame)
        for _ in range(fits + 40):
            bus.put_raw("rgtbus/r1/tx/a", frame)  # nothing drains in between
        bus.put_raw("rgtbus/r1/tx/b", _frame(1, 10))  # another member's queue is its own
        assert sum(bus._queued_bytes.values()) <= INBOX_BYTES_OPEN + len(frame)
        st_ = bus.stats()
        assert st_["dropped_overflow"] == 40 and st_["received"] == fits + 41, st_
        assert st_["accepted"] == 2 and st_["dropped_duplicate"] == fits - 1, st_
        assert sum(bus._queued_bytes.values()) == 0  # drained
    finally:
        bus.close()


def test_a_keyed_bus_queues_each_signed_frame_once(make_bus):
    """A frame seen on the network and replayed many times costs one queue place: the gate
    checks its tag and drops every further copy of its sequence number at once."""
    bus = make_bus(("a", "b"), key=KEY)
    good = _signed(bus, "a", 1, 10, [3], [0.25])
    for _ in range(50):
        bus.put_raw("rgtbus/r1/tx/a", good)
    wait_for(lambda: bus.stats()["received"] == 50)
    st_ = bus.stats()
    assert st_["accepted"] == 1 and st_["dropped_duplicate"] == 49, st_
    for _ in range(5):  # once accepted, a copy is a duplicate too
        bus.put_raw("rgtbus/r1/tx/a", good)
    wait_for(lambda: bus.stats()["received"] == 55)
    assert bus.stats()["dropped_duplicate"] == 54


def test_the_gate_never_raises_into_the_transport():
    bus = MemoryBus("r1", ("a",), RATE)
    try:

        class Broken:
            def __len__(self) -> int:
                return 100

            def to_bytes(self) -> bytes:
                raise RuntimeError("boom")

        bus._deliver("rgtbus/r1/tx/a", Broken())  # a transport's payload that fails
        st_ = bus.stats()
        assert st_["dropped_malformed"] == 1 and st_["received"] == 1
        assert "RuntimeError: boom" in bus.drop_notes()[0]
    finally:
        bus.close()


def test_count_foreign_off_never_sees_other_runs(make_bus):
    bus = make_bus(("a",), count_foreign=False)
    bus.put_raw("rgtbus/other/tx/a", _frame(1, 10))
    bus.publish("a", [], [], promise=5)
    bus.wait(0, timeout=2.0)
    assert bus.stats()["dropped_foreign"] == 0


def test_bad_live_bus_parameters(kind):
    with pytest.raises(RgtbusError, match="sample rate"):
        open_bus(kind, "r", ["a"], float("nan"))
    with pytest.raises(RgtbusError, match="unknown option"):
        open_bus(kind, "r", ["a"], RATE, window=20)


def test_unknown_bus_kind():
    with pytest.raises(RgtbusError, match="unknown bus kind 'carrier-pigeon'"):
        open_bus("carrier-pigeon", "r", ["a"], RATE)


def test_memory_bus_says_what_it_is():
    with MemoryBus("m", ["a"], RATE) as bus:
        assert "MemoryBus run='m'" in repr(bus) and "open" in repr(bus)
    assert "closed" in repr(bus)


# -- the log bus only: members not re-run, and the end of the log ----------------------------------


def test_log_bus_members_not_re_run_are_done_and_a_cut_log_ends():
    k = np.array([3, 40, 41], dtype=np.int64)
    v = np.array([0.4, 0.5, 0.6])
    bus = LogBus("replay", ["a", "b", "c"], {"a": (k, v)}, local=["a", "b"], end=41)
    assert bus.wait(0) == 41
    st_ = bus.status()
    assert st_["c"].flags == FINAL  # c is not re-run: done
    assert st_["a"].flags == st_["b"].flags == 0
    bus.publish("a", [7], [9.0], promise=NEVER, flags=FINAL, done_at=12)  # the log's medium stays
    assert bus.status()["a"].promise == 41 and bus.known(41)["a"][0].tolist() == [3, 40]
    with pytest.raises(LogEnded, match="the log ends at sample 41"):
        bus.wait(41)
    whole = LogBus("replay", ["a"], {"a": (k, v)})
    assert whole.wait(NEVER) == NEVER  # a complete log never ends a run early


# -- zenoh only ------------------------------------------------------------------------------------


zenoh = pytest.importorskip("zenoh")


def test_zenoh_two_runs_sharing_a_session_count_each_other_as_foreign():
    from rgtbus.bus.config import make_config
    from rgtbus.bus.zenoh import ZenohBus

    session = zenoh.open(make_config())
    try:
        with (
            ZenohBus("run-a", ["a", "b"], RATE, session=session) as bus_a,
            ZenohBus("run-b", ["a", "b"], RATE, session=session) as bus_b,
        ):
            for u in "ab":
                bus_a.publish(u, [1], [1.0], promise=5)
                bus_b.publish(u, [1], [2.0], promise=5)
            assert bus_a.wait(0, timeout=2.0) == 5 and bus_b.wait(0, timeout=2.0) == 5
            assert all(p[1].tolist() == [1.0] for p in bus_a.take(5).values())
            assert all(p[1].tolist() == [2.0] for p in bus_b.take(5).values())
            for bus in (bus_a, bus_b):
                # The other run's frames may still be in flight when wait returns.
                wait_for(lambda bus=bus: bus.stats()["dropped_foreign"] >= 2)
                assert bus.stats()["dropped_foreign"] == 2
                assert bus.stats()["accepted"] == 2
        assert not session.is_closed()  # a borrowed session is left to its owner
    finally:
        session.close()


def test_zenoh_options_refused_with_a_session():
    from rgtbus.bus.config import make_config
    from rgtbus.bus.zenoh import ZenohBus

    session = zenoh.open(make_config())
    try:
        with pytest.raises(RgtbusError, match="either a session or session options"):
            ZenohBus("r1", ["a"], RATE, session=session, mode="peer")
    finally:
        session.close()


def test_zenoh_bad_mode_and_endpoints():
    with pytest.raises(RgtbusError, match="zenoh mode 'hub' unknown"):
        open_bus("zenoh", "r1", ["a"], RATE, mode="hub")
    with pytest.raises(RgtbusError, match="must be a list, got the string"):
        open_bus("zenoh", "r1", ["a"], RATE, connect="tcp/127.0.0.1:1")
    with pytest.raises(RgtbusError, match="zenoh listen endpoint 'nonsense': Endpoints must"):
        open_bus("zenoh", "r1", ["a"], RATE, listen=["nonsense"])


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_zenoh_two_sessions_over_loopback():
    """The cross-process shape in one process: each bus publishes its own unit only."""
    ep = f"tcp/127.0.0.1:{_free_port()}"
    with (
        open_bus("zenoh", "lo", ["a", "b"], RATE, listen=[ep], local=["a"]) as bus_a,
        open_bus("zenoh", "lo", ["a", "b"], RATE, connect=[ep], local=["b"]) as bus_b,
    ):
        # A publisher always matches its own session's subscriber, so matching_status says
        # nothing about the peer: wait until each side hears a probe from the other.
        deadline = time.monotonic() + 5.0
        heard = {"a": False, "b": False}
        while not all(heard.values()):
            assert time.monotonic() < deadline, "sessions did not connect"
            bus_a.put_raw("rgtbus/lo/tx/probe-a", b"")
            bus_b.put_raw("rgtbus/lo/tx/probe-b", b"")
            time.sleep(0.01)
            heard["a"] |= any("probe-b" in n for n in bus_a.drop_notes())
            heard["b"] |= any("probe-a" in n for n in bus_b.drop_notes())
        for step in range(3):
            h = 100 * (step + 1)
            bus_a.publish("a", [h - 50], [step + 0.5], promise=h)
            bus_b.publish("b", [h - 40], [-step - 0.5], promise=h)
            for bus in (bus_a, bus_b):
                assert bus.wait(h - 100, timeout=2.0) == h
                got = bus.take(h)
                assert got["a"][1].tolist() == [step + 0.5]
                assert got["b"][1].tolist() == [-step - 0.5]


def test_zenoh_a_member_whose_session_ends_is_named_at_once():
    """b's session ends (its process killed, its link lost) while a waits on it: a's wait ends
    within a few seconds naming b as the one that left, not at a's timeout."""
    from rgtbus.errors import MembersSilent

    ep = f"tcp/127.0.0.1:{_free_port()}"
    with open_bus("zenoh", "gone", ["a", "b"], RATE, listen=[ep], local=["a"]) as bus_a:
        bus_b = open_bus("zenoh", "gone", ["a", "b"], RATE, connect=[ep], local=["b"])
        try:
            joined = threading.Thread(
                target=bus_b.join, args=("b", "0" * 64), kwargs={"timeout": 30}
            )
            joined.start()
            bus_a.join("a", "0" * 64, timeout=30)
            joined.join(30)
            bus_a.publish("a", [], [], promise=100)
            bus_b.publish("b", [], [], promise=10)
            assert bus_a.wait(0, timeout=30) == 10
        finally:
            bus_b.close()
        t0 = time.monotonic()
        with pytest.raises(MembersSilent, match=r"^b left run 'gone' before it was done") as e:
            bus_a.wait(10, timeout=60)
        assert e.value.silent == ("b",) and time.monotonic() - t0 < 30


def test_zenoh_bus_left_open_does_not_hang_the_interpreter_at_exit():
    import subprocess
    import sys

    code = (
        "from rgtbus.bus import open_bus\n"
        "bus = open_bus('zenoh', 'left-open', ['a'], 200.0)\n"
        "bus.publish('a', [1], [0.5], promise=3)\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=20)
    assert out.returncode == 0 and out.stdout == "ok\n", out.stderr


# -- frame codec -----------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    seq=st.integers(0, NEVER),
    promise=st.integers(0, NEVER),
    done_at=st.integers(0, NEVER),
    flags=st.sampled_from([0, FINAL, FAILED, FINAL | FAILED]),
    rate=st.floats(1e-3, 1e9),
    values=hnp.arrays(
        np.float64,
        st.integers(0, 64),
        elements=st.floats(-MAX_MAGNITUDE, MAX_MAGNITUDE, allow_nan=False),
    ),
    data=st.data(),
)
def test_frame_round_trip(seq, promise, done_at, flags, rate, values, data):
    samples = np.sort(data.draw(hnp.arrays(np.int64, values.size, elements=st.integers(0, NEVER))))
    raw = encode(Frame(seq, promise, samples, values, flags, done_at), rate)
    assert len(raw) == HEADER_SIZE + 16 * values.size
    frame, r = decode(raw)
    assert (frame.seq, frame.promise, frame.flags, frame.done_at, r) == (
        seq,
        promise,
        flags,
        done_at,
        rate,
    )
    assert np.array_equal(frame.samples, samples) and same_bits(frame.values, values)
    assert decode(bytearray(raw))[0].seq == seq


def test_frame_header_layout():
    data = _frame(7, 90, [5], [1.5], flags=FINAL, done_at=4)
    assert data[:4] == b"RGTB" and data[4] == 2 and data[5] == FINAL and data[6:8] == bytes(2)
    assert struct.unpack_from("<QQQdII", data, 8) == (7, 90, 4, 200.0, 1, 0)
    assert struct.unpack_from("<Qd", data, 48) == (5, 1.5)


def _patch(data, offset, new):
    return data[:offset] + new + data[offset + len(new) :]


GOOD = _frame(3, 40, [1, 2, 3, 4], [0.1, 0.2, 0.3, 0.4])


@pytest.mark.parametrize(
    ("data", "msg"),
    [
        (b"", r"too short: 0 bytes, header needs 48"),
        (GOOD[:47], r"too short: 47 bytes"),
        (_patch(GOOD, 0, b"RGTC"), r"bad magic b'RGTC', expected b'RGTB'"),
        (_patch(GOOD, 4, b"\x01"), r"version 1 unsupported, expected 2"),
        (_patch(GOOD, 5, b"\x08"), r"flags 0x08 hold unknown bits"),
        (_patch(GOOD, 5, b"\x04"), r"does not match count 4 \(expected 144\)"),
        (_patch(GOOD, 6, b"\x01"), r"reserved fields not zero"),
        (_patch(GOOD, 44, b"\x01"), r"reserved fields not zero"),
        (_patch(GOOD, 16, struct.pack("<Q", 2**63)), r"promise .* out of range"),
        (_patch(GOOD, 32, struct.pack("<d", float("nan"))), r"sample rate nan not finite"),
        (_patch(GOOD, 32, struct.pack("<d", -1.0)), r"sample rate -1.0 not finite and > 0"),
        (GOOD[:-1], r"length 111 bytes does not match count 4 \(expected 112\)"),
        (GOOD + b"\0" * 8, r"length 120 bytes does not match count 4"),
        (_patch(GOOD, 40, struct.pack("<I", 2**32 - 1)), r"does not match count 4294967295"),
        (_patch(GOOD, 48, struct.pack("<Q", 9)), r"sample indexes are not in order"),
        (_patch(GOOD, 48, struct.pack("<Q", 2**64 - 1)), r"sample index out of range"),
        (_patch(GOOD, 88, struct.pack("<d", float("inf"))), r"magnitude inf at sample 2"),
        (_patch(GOOD, 88, struct.pack("<d", 1e308)), r"not finite or beyond"),
        ("RGTB", r"frame must be bytes, got str"),
    ],
)
def test_frame_malformed(data, msg):
    with pytest.raises(RgtbusError, match=msg) as err:
        decode(data)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("frame", "msg"),
    [
        (Frame(-1, 0), "sequence number -1 out of range"),
        (Frame(0, 2**63), "promise 9223372036854775808 out of range"),
        (Frame(True, 0), "sequence number must be an int, got True"),
        (Frame(0, 0, flags=4), "only FINAL"),
        (Frame(0, 0, np.zeros((2, 1), dtype=np.int64), np.zeros((2, 1))), "1-D"),
        (Frame(0, 0, np.array([1.5]), np.array([0.1])), "must be integers"),
        (Frame(0, 0, np.array([1]), np.array([0.1], dtype=np.float32)), "float64, got float32"),
        (Frame(0, 0, np.array([1]), np.array([-np.inf])), "not finite"),
    ],
)
def test_frame_encode_refuses(frame, msg):
    with pytest.raises(RgtbusError, match=msg):
        encode(frame, RATE)
    with pytest.raises(RgtbusError, match="sample rate must be finite"):
        encode(Frame(0, 0), float("inf"))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 30), max_size=20), st.booleans())
def test_sample_rows_is_unique_with_inverse(samples, ordered):
    from rgtbus.signal.pulses import sample_rows

    a = np.array(sorted(samples) if ordered else samples, dtype=np.int64)
    rows, at = sample_rows(a)
    want_rows, want_at = np.unique(a, return_inverse=True)
    assert np.array_equal(rows, want_rows) and np.array_equal(at, want_at.reshape(-1))


def test_the_first_hellos_come_soon_then_every_period():
    """A hello said before a peer's subscription reaches the session is lost (the first ones
    of a run are): the next unprompted ones come 50, 100, 200 ms ... apart, then every period."""
    from rgtbus.bus.join import hello_gap, hello_period

    period = hello_period(100)
    assert period == pytest.approx(1.0) and hello_period(2) == pytest.approx(0.05)
    gaps = [hello_gap(period, k) for k in range(7)]
    assert gaps == pytest.approx([0.05, 0.1, 0.2, 0.4, 0.8, 1.0, 1.0])
    assert hello_gap(period, 10**6) == pytest.approx(period)  # no overflow however long


@pytest.mark.parametrize("repeated", [True, False], ids=["repeating", "silent"])
def test_a_claimant_saying_its_hello_again_unread_keeps_its_claim(repeated):
    """The gate reads a hello said again unchanged no more, but notes when it came: the claim
    of a unit's first claimant stays alive while it repeats itself, so a second claimant
    heard later than ``claim_silence`` after the first one was read is still a conflict.
    A claimant that fell silent (died, or was replaced) no longer counts."""
    from types import SimpleNamespace

    from rgtbus.bus.hello import Hello
    from rgtbus.bus.join import JoinBarrier, claim_silence

    digest = "0" * 64
    bus = SimpleNamespace(members=("a", "b"), nonce=b"A" * 16, process="host:1", run_id="r",
                          repeated_at={})  # fmt: skip
    barrier = JoinBarrier(bus, ["a"], digest, 0.05)  # type: ignore[arg-type]
    first = Hello("b", digest, b"1" * 16, process="host:2")
    barrier.claim(first, time.monotonic())
    barrier.nonces["b"] = first.nonce  # read: the latest claimant on b's key
    # read longer ago than a claimant may go unheard
    barrier.claims["b"][first.nonce] = ("host:2", time.monotonic() - claim_silence(0.05) - 0.1)
    if repeated:
        bus.repeated_at["b"] = time.monotonic()  # said again, unchanged: not read
    barrier.claim(Hello("b", digest, b"2" * 16, process="host:3"), time.monotonic())
    if repeated:
        assert barrier.conflict is not None
        assert "host:2" in barrier.conflict and "host:3" in barrier.conflict
    else:
        assert barrier.conflict is None


def test_a_join_that_hears_nobody_says_how_units_reach_each_other():
    """A unit whose join hears no other member at all (connected only to a watcher, or to
    nothing) times out naming the missing members and how units reach each other."""
    from rgtbus.bus import open_bus

    bus = open_bus("zenoh", "alone", ("a", "b"), RATE, local=["a"])
    try:
        with pytest.raises(RgtbusError) as timed_out:
            bus.join(["a"], DIGEST, timeout=1.0)
    finally:
        bus.close()
    said = str(timed_out.value)
    assert isinstance(timed_out.value, PeerSilent) and isinstance(timed_out.value, TimeoutError)
    assert "timed out after 1 s: no answer from b; no other unit was heard at all" in said
    assert "rgtbus router" in said and "a watcher (rgtbus watch) relays nothing" in said


def _committed_barrier(heard: float | None = None):
    """A barrier of a (local), b and c that has said it is ready: b and c hold its view, b is
    ready and c not yet (their hellos heard at ``heard``, monotonic: now by default). The
    barrier, its view, and b's and c's nonces."""
    from types import SimpleNamespace

    from rgtbus.bus.hello import Hello, view_digest
    from rgtbus.bus.join import JoinBarrier

    said: list[tuple[str, bytes, bool]] = []
    accepted: dict[str, bytes] = {}
    bus = SimpleNamespace(
        members=("a", "b", "c"), nonce=b"A" * 16, process="host:1", run_id="r",
        repeated_at={}, accept=accepted.__setitem__,
        say_hello=lambda u, d, view, *, ready: said.append((u, view, ready)),
    )  # fmt: skip
    barrier = JoinBarrier(bus, ["a"], DIGEST, 0.05)  # type: ignore[arg-type]
    nb, nc = b"B" * 16, b"C" * 16
    view = view_digest("r", DIGEST, {"a": bus.nonce, "b": nb, "c": nc})
    now = time.monotonic() if heard is None else heard
    assert not barrier.hear(Hello("b", DIGEST, nb, view, ready=True, process="host:2"), now)
    assert not barrier.hear(Hello("c", DIGEST, nc, view, process="host:3"), now)
    barrier.say()
    assert said == [("a", view, True)] and barrier.committed == view
    return barrier, view, nb, nc


def test_a_ready_member_takes_a_later_claimant_as_late_and_still_opens():
    """Once a member said it is ready, another may open with its view: a second claimant of b
    heard after that changes nothing there (no conflict, b's nonce kept), and the barrier
    opens when c says it is ready too."""
    from rgtbus.bus.hello import Hello

    barrier, view, nb, nc = _committed_barrier()
    rival = Hello("b", DIGEST, b"2" * 16, process="host:4")
    assert not barrier.hear(rival, time.monotonic())
    assert barrier.late(rival) and barrier.conflict is None
    assert barrier.nonces["b"] == nb and barrier.view() == view
    assert barrier.rival is not None and "host:2" in barrier.rival and "host:4" in barrier.rival
    assert barrier.hear(
        Hello("c", DIGEST, nc, view, ready=True, process="host:3"), time.monotonic()
    )


def test_a_ready_member_stops_when_a_member_of_its_view_heard_the_rival_first():
    """c heard the second claimant of b before it was ready: its view moves, so nobody can open
    with the view a promised; a's promise ends and it stops for the conflict it kept, naming
    b and both claimants (it does not run on alone while c stops)."""
    from rgtbus.bus.hello import Hello, view_digest

    barrier, _view, _nb, nc = _committed_barrier()
    n2 = b"2" * 16
    barrier.hear(Hello("b", DIGEST, n2, process="host:4"), time.monotonic())
    moved = view_digest("r", DIGEST, {"a": b"A" * 16, "b": n2, "c": nc})
    assert not barrier.hear(Hello("c", DIGEST, nc, moved, process="host:3"), time.monotonic())
    assert barrier.committed == b"" and not barrier.done()
    said = barrier.conflict
    assert said is not None and said.startswith("two processes claim unit 'b' of run 'r': ")
    assert "host:2" in said and "host:4" in said


def test_a_ready_member_follows_a_claimant_that_replaced_a_silent_one():
    """b's first process fell silent (died) after a was ready, and a new one claims b: no
    conflict. When c's view moves to the new b, a's promise ends without a conflict and a
    takes up the join with the new b's nonce."""
    from rgtbus.bus.hello import Hello, view_digest
    from rgtbus.bus.join import claim_silence

    barrier, _view, nb, nc = _committed_barrier(heard=time.monotonic() - claim_silence(0.05) - 0.1)
    n2 = b"2" * 16  # the first b was last heard longer ago than a claimant may be silent
    new_b = Hello("b", DIGEST, n2, process="host:4")
    assert not barrier.hear(new_b, time.monotonic())
    assert barrier.rival is None and barrier.nonces["b"] == nb  # late while a's promise holds
    moved = view_digest("r", DIGEST, {"a": b"A" * 16, "b": n2, "c": nc})
    barrier.hear(Hello("c", DIGEST, nc, moved, process="host:3"), time.monotonic())
    assert barrier.committed == b"" and barrier.conflict is None
    barrier.hear(new_b, time.monotonic())
    assert barrier.nonces["b"] == n2 and barrier.view() == moved


def test_a_member_stopping_for_a_conflict_never_says_it_is_ready():
    """The join says its hello on for a while after a conflict, so that everyone hears it:
    never as ready, or another member could open with a member that is about to stop."""
    barrier, view, _nb, _nc = _committed_barrier()
    barrier.committed = b""  # as before its promise
    barrier.conflict = "two processes claim unit 'b' of run 'r': ..."
    said: list[tuple[str, bytes, bool]] = []
    barrier.bus.say_hello = lambda u, d, v, *, ready: said.append((u, v, ready))
    barrier.say()
    assert said == [("a", view, False)] and barrier.committed == b""


class LoopbackBus(MemoryBus):
    """A new transport, as far as the house can tell: the memory bus under another name."""

    kind = "loopback"


def test_a_bus_kind_is_its_adapter_and_one_registry_line(monkeypatch):
    """One line in ``rgtbus.bus.registry`` and a bus kind opens (``open_bus``), runs a
    scenario (``rgtbus.run``) with the memory bus's results and is a choice of ``rgtbus run
    --bus``; the shared suite's ``kind`` fixture reads the same registry."""
    import rgtbus
    from rgtbus.bus import open_bus, registry
    from rgtbus.cli import build_parser

    line = registry.BusKind("loopback", __name__, "LoopbackBus", False, "a test's twin")
    monkeypatch.setitem(registry.BUS_KINDS, "loopback", line)
    with open_bus("loopback", "r1", ("a", "b"), RATE) as bus:
        assert isinstance(bus, LoopbackBus)
    runs = [rgtbus.run("gate", seed=3, bus=kind).summary for kind in ("memory", "loopback")]
    for s in runs:
        s.pop("wall_seconds"), s.pop("bus", None), s.pop("sync", None)
    assert runs[0] == runs[1] and runs[0]["outcome"] == "gate: open"
    assert build_parser("run").parse_args(["run", "gate", "--bus", "loopback"]).bus == "loopback"
    with pytest.raises(RgtbusError, match=r"unknown bus kind 'nope' \(use zenoh, memory, loop"):
        open_bus("nope", "r1", ("a",), RATE)
    assert registry.cross_process_kind() == "zenoh"
