"""One suite for both buses (memory and zenoh), plus the payload codec and zenoh-only paths.

Every wait has a short timeout and every bus is closed by its fixture, even on failure.
"""

from __future__ import annotations

import socket
import struct
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from rgtbus.bus import STAT_KEYS, Bus, MemoryBus, decode, encode, open_bus, tx_key
from rgtbus.bus.payload import HEADER_SIZE
from rgtbus.errors import RgtbusError

RATE = 200.0
WLEN = 20
SHORT = 0.2  # seconds: long enough for in-process zenoh, short enough to keep the suite fast


@pytest.fixture(params=["memory", "zenoh"])
def kind(request):
    return request.param


@pytest.fixture
def make_bus(kind):
    opened = []

    def make(members=("a", "b", "c"), run_id="r1", **options):
        bus = open_bus(kind, run_id, members, RATE, WLEN, **options)
        opened.append(bus)
        return bus

    try:
        yield make
    finally:
        for bus in opened:
            bus.close()


def units(n):
    return tuple(f"u{i}" for i in range(n))


def window_samples(rng, n):
    # Mix in values whose bits are easy to mangle: -0.0, subnormals, extremes.
    x = rng.normal(size=n) * 10.0 ** rng.integers(-300, 300, size=n)
    x[0] = -0.0
    x[-1] = 5e-324
    return x


def same_bits(a, b):
    return a.dtype == np.float64 and np.array_equal(a.view(np.uint64), b.view(np.uint64))


# -- shared suite: both buses --------------------------------------------------------------


@pytest.mark.parametrize("n", [3, 10])
def test_publish_gather_several_windows_bit_identical(make_bus, n):
    members = units(n)
    bus = make_bus(members)
    assert isinstance(bus, Bus)
    assert bus.members == members and bus.run_id == "r1"
    rng = np.random.default_rng(n)
    for w in range(5):
        sent = {u: window_samples(rng, WLEN) for u in members}
        for u in reversed(members):  # arrival order must not matter
            bus.publish(u, w, sent[u])
        got = bus.gather(w, timeout=2.0)
        assert list(got) == list(members)
        for u in members:
            assert same_bits(got[u], sent[u]), (u, w)
            assert got[u].flags.writeable
    s = bus.stats()
    assert s["published"] == s["received"] == s["accepted"] == 5 * n
    assert s["gathered"] == 5 and s["buffered"] == 0
    assert all(s[k] == 0 for k in STAT_KEYS if k.startswith("dropped"))


def test_early_windows_are_buffered(make_bus):
    bus = make_bus()
    vals = [np.full(WLEN, w + 1.0) for w in range(3)]
    bus.publish("a", 0, vals[0])
    for u in "bc":  # b and c run ahead: windows 1 and 2 arrive before window 0 is complete
        for w in range(3):
            bus.publish(u, w, vals[w])
    # a's window 1 overtakes nothing but arrives raw, as from another process
    bus.put_raw(tx_key("r1", "a"), encode(1, RATE, vals[1]))
    assert all(np.array_equal(v, vals[0]) for v in bus.gather(0, timeout=2.0).values())
    assert bus.stats()["buffered"] == 2
    assert all(np.array_equal(v, vals[1]) for v in bus.gather(1, timeout=2.0).values())
    bus.publish("a", 2, vals[2])
    assert all(np.array_equal(v, vals[2]) for v in bus.gather(2, timeout=2.0).values())
    assert bus.stats()["buffered"] == 0 and bus.stats()["accepted"] == 9


def test_gather_timeout_names_missing_units_and_window(make_bus):
    bus = make_bus(("a", "b", "c", "d"))
    bus.publish("a", 0, np.zeros(WLEN))
    bus.publish("c", 0, np.zeros(WLEN))
    t0 = time.monotonic()
    with pytest.raises(RgtbusError, match=r"window 0 missing unit\(s\) b, d$") as err:
        bus.gather(0, timeout=SHORT)
    assert SHORT <= time.monotonic() - t0 < SHORT + 1.0
    assert "\n" not in str(err.value) and "'r1'" in str(err.value)
    # The partial window is kept: the stragglers can still complete it.
    bus.publish("b", 0, np.zeros(WLEN))
    bus.publish("d", 0, np.zeros(WLEN))
    assert set(bus.gather(0, timeout=2.0)) == {"a", "b", "c", "d"}


def test_gather_of_a_gathered_window_is_refused(make_bus):
    bus = make_bus(("a",))
    bus.publish("a", 0, np.zeros(WLEN))
    bus.gather(0, timeout=2.0)
    with pytest.raises(RgtbusError, match="window 0 already gathered"):
        bus.gather(0, timeout=SHORT)


def test_skipped_windows_are_dropped_as_late(make_bus):
    bus = make_bus(("a", "b"))
    bus.publish("a", 0, np.zeros(WLEN))  # window 0 never completes
    for u in "ab":
        bus.publish(u, 1, np.ones(WLEN))
    bus.gather(1, timeout=2.0)
    assert bus.stats()["dropped_late"] == 1 and bus.stats()["buffered"] == 0
    bus.put_raw(tx_key("r1", "b"), encode(0, RATE, np.zeros(WLEN)))  # straggler for window 0
    bus.publish("a", 2, np.zeros(WLEN))
    bus.publish("b", 2, np.zeros(WLEN))
    bus.gather(2, timeout=2.0)
    assert bus.stats()["dropped_late"] == 2


def test_publish_refuses_bad_input(make_bus):
    bus = make_bus()
    with pytest.raises(
        RgtbusError, match=r"unit 'z' is not a member of run 'r1' \(members: a, b, c\)"
    ):
        bus.publish("z", 0, np.zeros(WLEN))
    with pytest.raises(RgtbusError, match=r"samples shape \(19,\), expected \(20,\)"):
        bus.publish("a", 0, np.zeros(WLEN - 1))
    with pytest.raises(RgtbusError, match=r"shape \(2, 20\)"):
        bus.publish("a", 0, np.zeros((2, WLEN)))
    with pytest.raises(RgtbusError, match="window must be an int >= 0, got -1"):
        bus.publish("a", -1, np.zeros(WLEN))
    with pytest.raises(RgtbusError, match=r"window must be an int >= 0, got 1\.0"):
        bus.publish("a", 1.0, np.zeros(WLEN))
    bad = np.zeros(WLEN)
    bad[3] = np.nan
    with pytest.raises(RgtbusError, match="sample 3 is not finite"):
        bus.publish("a", 0, bad)
    bus.publish("a", 4, np.zeros(WLEN))
    with pytest.raises(RgtbusError, match="already published window 4; window 4 is not later"):
        bus.publish("a", 4, np.zeros(WLEN))
    assert bus.stats()["published"] == 1


def test_local_units_only(make_bus):
    bus = make_bus(local=("b",))
    bus.publish("b", 0, np.zeros(WLEN))
    with pytest.raises(RgtbusError, match=r"'a' is not published from this bus \(local: b\)"):
        bus.publish("a", 0, np.zeros(WLEN))
    with pytest.raises(RgtbusError, match="missing unit\\(s\\) a, c"):
        bus.gather(0, timeout=SHORT)


def test_close_is_idempotent_and_final(make_bus, kind):
    bus = make_bus()
    bus.publish("a", 0, np.zeros(WLEN))
    bus.close()
    bus.close()
    assert bus.closed
    with pytest.raises(RgtbusError, match=f"publish on closed {kind} bus of run 'r1'"):
        bus.publish("b", 0, np.zeros(WLEN))
    with pytest.raises(RgtbusError, match="gather on closed"):
        bus.gather(0, timeout=SHORT)
    assert bus.stats()["published"] == 1  # stats survive close


def test_context_manager_closes(kind):
    with open_bus(kind, "ctx", ["a"], RATE, WLEN) as bus:
        bus.publish("a", 0, np.arange(WLEN, dtype=float))
        assert np.array_equal(bus.gather(0, timeout=2.0)["a"], np.arange(WLEN))
    assert bus.closed


def test_foreign_and_malformed_payloads_are_dropped_and_counted(make_bus):
    bus = make_bus()
    good = np.linspace(-1, 1, WLEN)
    bad_payloads = {
        "short": b"RGTB",
        "magic": b"XXXX" + encode(0, RATE, good)[4:],
        "version": encode(0, RATE, good)[:4] + b"\x02" + encode(0, RATE, good)[5:],
        "length": encode(0, RATE, good) + b"\0",
        "float32": encode(0, RATE, good)[:HEADER_SIZE] + good.astype("<f4").tobytes(),
        "rate": encode(0, RATE * 2, good),
        "count": encode(0, RATE, good[:-1]),
    }
    bus.put_raw(tx_key("other-run", "a"), encode(0, RATE, good + 100))  # another run id
    bus.put_raw(tx_key("r1", "mallory"), encode(0, RATE, good + 100))  # not a member
    bus.put_raw("rgtbus/r1/tx/a/extra", encode(0, RATE, good + 100))  # outside the key space
    for data in bad_payloads.values():
        bus.put_raw(tx_key("r1", "a"), data)
    for u in "abc":
        bus.publish(u, 0, good)
    bus.put_raw(tx_key("r1", "b"), encode(1, RATE, good + 7))  # early: kept
    bus.put_raw(tx_key("r1", "b"), encode(1, RATE, good + 9))  # duplicate of an early one
    got = bus.gather(0, timeout=2.0)
    assert all(same_bits(v, good) for v in got.values())
    s = bus.stats()
    assert s["dropped_foreign"] == 2  # the nested key never reaches the subscriber
    assert s["dropped_malformed"] == len(bad_payloads)
    assert s["dropped_duplicate"] == 1
    assert s["received"] == 2 + len(bad_payloads) + 3 + 2
    assert s["accepted"] == 4 and s["buffered"] == 1
    notes = bus.drop_notes()
    assert len(notes) == 2 + len(bad_payloads) + 1 and bus.drop_notes() == []
    assert any("not run 'r1'" in n for n in notes)
    assert any("'mallory' is not a member" in n for n in notes)
    assert any("sample rate 400, run has 200" in n for n in notes)
    assert any("has 19 samples, run has 20" in n for n in notes)
    bus.publish("a", 1, good)
    bus.publish("c", 1, good)
    assert same_bits(bus.gather(1, timeout=2.0)["b"], good + 7)


def test_windows_too_far_ahead_are_dropped(make_bus):
    bus = make_bus(("a",), max_ahead=4)
    bus.put_raw(tx_key("r1", "a"), encode(4, RATE, np.zeros(WLEN)))
    bus.put_raw(tx_key("r1", "a"), encode(3, RATE, np.ones(WLEN)))
    bus.publish("a", 0, np.zeros(WLEN))
    bus.gather(0, timeout=2.0)
    assert bus.stats()["dropped_ahead"] == 1 and bus.stats()["buffered"] == 1


def test_count_foreign_off_never_sees_other_runs(make_bus):
    bus = make_bus(count_foreign=False)
    bus.put_raw(tx_key("other", "a"), encode(0, RATE, np.zeros(WLEN)))
    for u in "abc":
        bus.publish(u, 0, np.zeros(WLEN))
    bus.gather(0, timeout=2.0)
    assert bus.stats()["received"] == 3 and bus.stats()["dropped_foreign"] == 0


def test_bad_bus_parameters(kind):
    for args, msg in [
        (("r/1", ["a"], RATE, WLEN), r"bad run id 'r/1'"),
        (("r1", ["a", "b*"], RATE, WLEN), r"bad unit name 'b\*'"),
        (("r1", ["a", "b", "a"], RATE, WLEN), "duplicate member"),
        (("r1", [], RATE, WLEN), "has no members"),
        (("r1", "abc", RATE, WLEN), "got the string 'abc'"),
        (("r1", ["a"], 0.0, WLEN), "sample rate must be finite and > 0, got 0.0"),
        (("r1", ["a"], RATE, 0), "window length must be an int >= 1, got 0"),
    ]:
        with pytest.raises(RgtbusError, match=msg):
            open_bus(kind, *args).close()
    with pytest.raises(RgtbusError, match=r"unknown option\(s\) colour for the " + kind):
        open_bus(kind, "r1", ["a"], RATE, WLEN, colour="red")
    with pytest.raises(RgtbusError, match=r"unit 'x' is not a member"):
        open_bus(kind, "r1", ["a"], RATE, WLEN, local=["x"])


def test_unknown_bus_kind():
    with pytest.raises(
        RgtbusError, match=r"unknown bus kind 'carrier-pigeon' \(use zenoh, memory\)"
    ):
        open_bus("carrier-pigeon", "r1", ["a"], RATE, WLEN)


# -- zenoh only ----------------------------------------------------------------------------


zenoh = pytest.importorskip("zenoh")


def test_zenoh_two_runs_sharing_a_session_count_each_other_as_foreign():
    from rgtbus.bus.zenoh import ZenohBus, make_config

    session = zenoh.open(make_config())
    try:
        with (
            ZenohBus("run-a", ["a", "b"], RATE, WLEN, session=session) as bus_a,
            ZenohBus("run-b", ["a", "b"], RATE, WLEN, session=session) as bus_b,
        ):
            for u in "ab":
                bus_a.publish(u, 0, np.ones(WLEN))
                bus_b.publish(u, 0, np.full(WLEN, 2.0))
            assert all((v == 1).all() for v in bus_a.gather(0, timeout=2.0).values())
            assert all((v == 2).all() for v in bus_b.gather(0, timeout=2.0).values())
            for bus in (bus_a, bus_b):
                # The other run's samples may still be in flight when gather returns.
                deadline = time.monotonic() + 2.0
                while bus.stats()["dropped_foreign"] < 2 and time.monotonic() < deadline:
                    time.sleep(0.01)
                assert bus.stats()["dropped_foreign"] == 2
                assert bus.stats()["accepted"] == 2
        assert not session.is_closed()  # a borrowed session is left to its owner
    finally:
        session.close()


def test_zenoh_options_refused_with_a_session():
    from rgtbus.bus.zenoh import ZenohBus, make_config

    session = zenoh.open(make_config())
    try:
        with pytest.raises(RgtbusError, match="either a session or session options"):
            ZenohBus("r1", ["a"], RATE, WLEN, session=session, mode="peer")
    finally:
        session.close()


def test_zenoh_bad_mode_and_endpoints():
    with pytest.raises(RgtbusError, match="zenoh mode 'hub' unknown"):
        open_bus("zenoh", "r1", ["a"], RATE, WLEN, mode="hub")
    with pytest.raises(RgtbusError, match="must be a list, got the string"):
        open_bus("zenoh", "r1", ["a"], RATE, WLEN, connect="tcp/127.0.0.1:1")
    with pytest.raises(RgtbusError, match="zenoh listen endpoint 'nonsense': Endpoints must"):
        open_bus("zenoh", "r1", ["a"], RATE, WLEN, listen=["nonsense"])


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_zenoh_two_sessions_over_loopback():
    """The cross-process shape in one process: each bus publishes its own unit only."""
    ep = f"tcp/127.0.0.1:{_free_port()}"
    with (
        open_bus("zenoh", "lo", ["a", "b"], RATE, WLEN, listen=[ep], local=["a"]) as bus_a,
        open_bus("zenoh", "lo", ["a", "b"], RATE, WLEN, connect=[ep], local=["b"]) as bus_b,
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
        for w in range(3):
            bus_a.publish("a", w, np.full(WLEN, w + 0.5))
            bus_b.publish("b", w, np.full(WLEN, -w - 0.5))
            for bus in (bus_a, bus_b):
                got = bus.gather(w, timeout=2.0)
                assert (got["a"] == w + 0.5).all() and (got["b"] == -w - 0.5).all()


# -- payload codec -------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    window=st.integers(0, 2**64 - 1),
    rate=st.floats(1e-3, 1e9),
    samples=hnp.arrays(
        np.float64, st.integers(0, 64), elements=st.floats(allow_nan=False, allow_infinity=False)
    ),
)
def test_payload_round_trip(window, rate, samples):
    data = encode(window, rate, samples)
    assert len(data) == HEADER_SIZE + 8 * samples.size
    w, r, s = decode(data)
    assert (w, r) == (window, rate) and same_bits(s, samples)
    assert decode(bytearray(data))[0] == window


def test_payload_header_layout():
    data = encode(7, 200.0, np.array([1.5]))
    assert data[:4] == b"RGTB" and data[4] == 1 and data[5:6] == b"d" and data[6:12] == bytes(6)
    assert struct.unpack_from("<QdI", data, 12) == (7, 200.0, 1)
    assert struct.unpack_from("<d", data, 32) == (1.5,)


def _patch(data, offset, new):
    return data[:offset] + new + data[offset + len(new) :]


GOOD = encode(3, 200.0, np.arange(4, dtype=float))


@pytest.mark.parametrize(
    ("data", "msg"),
    [
        (b"", r"too short: 0 bytes, header needs 32"),
        (GOOD[:31], r"too short: 31 bytes"),
        (_patch(GOOD, 0, b"RGTC"), r"bad magic b'RGTC', expected b'RGTB'"),
        (_patch(GOOD, 4, b"\x02"), r"version 2 unsupported, expected 1"),
        (_patch(GOOD, 5, b"f"), r"dtype code b'f' unsupported"),
        (_patch(GOOD, 8, b"\x01"), r"reserved bytes not zero: 0001000000"),
        (_patch(GOOD, 6, b"\x04"), r"payload flags 0x04 hold unknown bits"),
        (_patch(GOOD, 20, struct.pack("<d", float("nan"))), r"sample rate nan not finite"),
        (_patch(GOOD, 20, struct.pack("<d", -1.0)), r"sample rate -1.0 not finite and > 0"),
        (GOOD[:-1], r"length 63 bytes does not match count 4 \(expected 64\)"),
        (GOOD + b"\0" * 8, r"length 72 bytes does not match count 4"),
        (_patch(GOOD, 28, struct.pack("<I", 2**32 - 1)), r"does not match count 4294967295"),
        (_patch(GOOD, 40, struct.pack("<d", float("inf"))), r"sample 1 is not finite: inf"),
        ("RGTB", r"payload must be bytes, got str"),
    ],
)
def test_payload_malformed(data, msg):
    with pytest.raises(RgtbusError, match=msg) as err:
        decode(data)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("args", "msg"),
    [
        ((-1, 200.0, np.zeros(2)), "window -1 out of range"),
        ((2**64, 200.0, np.zeros(2)), "out of range"),
        ((True, 200.0, np.zeros(2)), "window must be an int, got True"),
        ((1, float("inf"), np.zeros(2)), "sample rate must be finite and > 0, got inf"),
        ((1, 200.0, np.zeros((2, 2))), r"1-D, got shape \(2, 2\)"),
        ((1, 200.0, np.zeros(2, dtype=np.float32)), "float64, got float32"),
        ((1, 200.0, np.array([0.0, -np.inf])), "sample 1 is not finite: -inf"),
    ],
)
def test_payload_encode_refuses(args, msg):
    with pytest.raises(RgtbusError, match=msg):
        encode(*args)


def test_memory_bus_is_a_bus():
    with MemoryBus("m", ["a"], RATE, WLEN) as bus:
        assert isinstance(bus, Bus) and "MemoryBus run='m'" in repr(bus)


def test_zenoh_bus_left_open_does_not_hang_the_interpreter_at_exit():
    import subprocess
    import sys

    code = (
        "from rgtbus.bus import open_bus\n"
        "bus = open_bus('zenoh', 'left-open', ['a'], 200.0, 20)\n"
        "bus.publish('a', 0, [0.0] * 20)\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=20)
    assert out.returncode == 0 and out.stdout == "ok\n", out.stderr


def test_flags_travel_with_the_window(make_bus):
    from rgtbus.bus.payload import FAILED, FINAL, decode_frame

    bus = make_bus()
    for w, flags in enumerate([{"a": 0, "b": FINAL, "c": FAILED}, {"a": FINAL, "b": 0, "c": 0}]):
        for u in "abc":
            bus.publish(u, w, np.zeros(WLEN), flags=flags[u])
        bus.gather(w, timeout=2.0)
        assert bus.last_flags == flags
    assert decode_frame(encode(0, RATE, np.zeros(2), FINAL | FAILED))[3] == 3
    with pytest.raises(RgtbusError, match="only FINAL"):
        encode(0, RATE, np.zeros(2), 4)


def test_log_bus_serves_logged_windows_and_ends():
    from rgtbus.bus.logbus import LogBus, LogEnded
    from rgtbus.bus.payload import FINAL

    windows = [np.full(WLEN, float(w)) for w in range(3)]
    bus = LogBus("replay", ["a", "b", "c"], windows, local=["a", "b"])
    bus.publish("a", 0, np.zeros(WLEN), FINAL)
    got = bus.gather(0)
    assert (got["a"] == 0.0).all() and (got["b"] == 0).all() and set(got) == {"a", "b", "c"}
    assert bus.last_flags == {"a": FINAL, "b": 0, "c": FINAL}  # c is not re-run: finished
    assert (bus.gather(2)["a"] == 2.0).all()
    with pytest.raises(LogEnded, match="ends after window 2"):
        bus.gather(3)
