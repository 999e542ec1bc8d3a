"""A frame lost is a frame asked for again (docs/engine.md, "A frame lost is asked for again"),
and a member is judged by what it proved to say (rgtbus.bus.base).

Two zenoh buses in this process, joined over loopback, one losing chosen frames of the other at
its gate (as a full queue, a link's hiccup or the rate gate would): the loser holds what comes
after the gap, asks, and the sender sends the frames again while it waits, or, finished, while it
lingers. A bus's own frames lost on their way back are taken from what it sent. Two different
frames under one number from an identified member name it at once; a flood of wrongly tagged
frames costs a bounded number of tag checks. Every wait is bounded; every bus closed.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest

from rgtbus.bus import FINAL, NEVER, MemoryBus, open_bus
from rgtbus.bus.auth import tag
from rgtbus.bus.base import CHECKS_PER_S, REPAIR_QUIET
from rgtbus.bus.payload import Frame, check_header, encode
from rgtbus.errors import MembersSilent

RATE = 200.0
KEY = bytes(range(7, 39))
DIGEST = "cd" * 32


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def joined_pair(run_id: str, key: bytes | None = KEY) -> Iterator[tuple]:
    """Buses of members a and b, a listening, b connecting, both joined."""
    ep = f"tcp/127.0.0.1:{_free_port()}"
    members = ("a", "b")
    with (
        open_bus("zenoh", run_id, members, RATE, local=["a"], key=key, listen=[ep]) as a,
        open_bus("zenoh", run_id, members, RATE, local=["b"], key=key, connect=[ep]) as b,
    ):
        errors: list[BaseException] = []

        def join_b() -> None:
            try:
                b.join("b", DIGEST, timeout=30)
            except BaseException as e:  # reported below
                errors.append(e)

        t = threading.Thread(target=join_b)
        t.start()
        a.join("a", DIGEST, timeout=30)
        t.join(timeout=40)
        assert not t.is_alive() and not errors, errors
        yield a, b


def lose(bus, unit: str, seqs: set[int]) -> list[int]:
    """``bus`` loses ``unit``'s frames numbered ``seqs`` the first time each arrives; the list
    of those it lost."""
    lost: list[int] = []
    real = bus._gate
    suffix = f"/tx/{unit}"

    def gate(key: str, payload) -> None:
        if key.endswith(suffix):
            seq = check_header(payload.to_bytes()).seq
            if seq in seqs and seq not in lost:
                lost.append(seq)
                return
        real(key, payload)

    bus._gate = gate
    return lost


class Waiting:
    """``bus.wait(beyond)`` in a thread (a member waiting answers requests meanwhile)."""

    def __init__(self, bus, beyond: int) -> None:
        self.out: list[object] = []
        self.thread = threading.Thread(target=self._wait, args=(bus, beyond))
        self.thread.start()

    def _wait(self, bus, beyond: int) -> None:
        try:
            self.out.append(bus.wait(beyond, timeout=30))
        except BaseException as e:
            self.out.append(e)

    def result(self) -> object:
        self.thread.join(timeout=40)
        assert not self.thread.is_alive()
        return self.out[0]


@pytest.mark.parametrize("key", [KEY, None], ids=["keyed", "open"])
@pytest.mark.parametrize("lost_seqs", [{2}, {4}, {1, 3}], ids=["middle", "last", "two"])
def test_a_lost_frame_is_asked_for_and_sent_again(key, lost_seqs):
    """b loses some of a's frames (in the middle: a gap before frames b holds; the last: no
    frame after it shows the gap, a's quiet does): b asks, a (waiting on b) sends them again,
    and b's wait ends with every pulse of a, in order, as if nothing was lost."""
    with joined_pair(f"lost-{len(lost_seqs)}-{min(lost_seqs)}", key) as (a, b):
        lost = lose(b, "a", lost_seqs)
        b.publish("b", [], [], promise=42)
        for k in range(1, 5):
            a.publish("a", [10 * k], [0.25 * k], promise=10 * k + 5)
        waiting = Waiting(a, 43)  # a waits for b to promise past 43: it answers meanwhile
        assert b.wait(40, timeout=30) == 42  # b holds the horizon; of a, only frame 4 is past 40
        assert b.status()["a"].seq == 4
        b.publish("b", [], [], promise=200)
        assert waiting.result() == 45
        assert sorted(lost) == sorted(lost_seqs)
        samples, values = b.known(NEVER)["a"]  # every pulse of a, in order
        assert samples.tolist() == [10, 20, 30, 40] and values.tolist() == [0.25, 0.5, 0.75, 1.0]
        # a's 4 frames, and b's own 2 as zenoh hands them back (its last maybe not yet: a
        # bounded, generous wait for it, not a race on a busy machine)
        deadline = time.monotonic() + 20
        while (sb := b.stats())["accepted"] < 6 and time.monotonic() < deadline:
            time.sleep(0.01)
        sa = a.stats()
        assert sb["resend_asked"] >= 1 and sa["resent"] >= len(lost_seqs), (sa, sb)
        assert sb["held"] == 0 and sb["accepted"] >= 6, sb


def test_a_finished_member_answers_for_its_last_frame_while_it_lingers():
    """a's final frame (FINAL, silent for good) is lost on its way to b after a is done: a,
    lingering before it closes, sends it again when b asks."""
    with joined_pair("linger") as (a, b):
        lose(b, "a", {2})
        b.publish("b", [], [], promise=NEVER, flags=FINAL, done_at=10)
        a.publish("a", [3], [0.5], promise=10)
        a.publish("a", [], [], promise=NEVER, flags=FINAL, done_at=10)
        assert a.wait(NEVER, timeout=30) == NEVER  # a knows everyone is done
        lingering = threading.Thread(target=a.linger, kwargs={"at_most": 60.0})
        lingering.start()
        try:
            assert b.wait(NEVER, timeout=30) == NEVER
            assert b.status()["a"].flags == FINAL
        finally:
            b.close()  # b has all it needed and leaves: a stops lingering
            lingering.join(timeout=30)
        assert not lingering.is_alive() and a.stats()["resent"] >= 1


def test_a_bus_s_own_frame_lost_on_its_way_back_is_taken_from_what_it_sent():
    bus = MemoryBus("own", ("a", "b"), RATE)
    try:
        lost = lose(bus, "a", {1})
        bus.publish("a", [4], [0.5], promise=10)
        bus.publish("b", [], [], promise=20)
        t0 = time.monotonic()
        assert bus.wait(5, timeout=30) == 10
        assert lost == [1] and time.monotonic() - t0 >= REPAIR_QUIET * 0.9
        assert bus.take(10)["a"][0].tolist() == [4]
    finally:
        bus.close()


def _signed(bus, unit: str, seq: int, promise: int, samples=(), values=()) -> bytes:
    def sign(body: bytes) -> bytes:
        return tag(KEY, "frame", bus.run_id, unit, bus.nonce, body)

    frame = Frame(seq, promise, np.array(samples, dtype=np.int64), np.array(values, float))
    return encode(frame, RATE, sign=sign)


def test_two_different_frames_under_one_number_name_their_member_at_once():
    """An identified member (its frames tagged) that says two things as frame 1 is not trusted:
    the next wait names it in one line, at once, not at the timeout. The same frame again is
    a duplicate only."""
    bus = MemoryBus("twice", ("a", "b"), RATE, key=KEY)
    try:
        bus.put_raw("rgtbus/twice/tx/a", _signed(bus, "a", 1, 10, [3], [0.5]))
        bus.put_raw("rgtbus/twice/tx/a", _signed(bus, "a", 1, 10, [3], [0.5]))  # a copy
        assert bus.stats()["dropped_duplicate"] == 1
        bus.publish("b", [], [], promise=5)
        assert bus.wait(4, timeout=5) == 5
        bus.put_raw("rgtbus/twice/tx/a", _signed(bus, "a", 1, 99, [7], [0.5]))  # another
        t0 = time.monotonic()
        with pytest.raises(MembersSilent, match=r"^a is not trusted in run 'twice': .*two "
                           r"different frames numbered 1") as e:  # fmt: skip
            bus.wait(20, timeout=30)
        assert e.value.silent == ("a",) and time.monotonic() - t0 < 5
        assert "\n" not in str(e.value)
    finally:
        bus.close()


def test_an_open_run_counts_a_bad_frame_and_names_it_when_it_stalls():
    """On an open run anyone can send anything on a member's key: a bad frame is dropped and
    counted, not a reason to stop; the stall that follows names what was bad."""
    bus = MemoryBus("open", ("a", "b"), RATE)
    try:
        bus.put_raw("rgtbus/open/tx/a", encode(Frame(1, 10), RATE))
        bus.put_raw("rgtbus/open/tx/a", encode(Frame(2, 9), RATE))  # promise going back
        bus.publish("b", [], [], promise=50)
        with pytest.raises(MembersSilent, match=r"a sent 1 bad frame \(last: promise 9 goes back"):
            bus.wait(20, timeout=0.5)
    finally:
        bus.close()


def test_a_flood_of_wrong_tags_costs_a_bounded_number_of_checks_and_the_run_goes_on():
    """Frames under the size bound with wrong tags, as fast as a thread can put them on a
    member's key: at most CHECKS_PER_S tags a second fail (and a burst of twice that), the
    rest are dropped unchecked (dropped_rate), but for those under the number due next;
    the member's own frames still arrive and the wait ends."""
    bus = MemoryBus("flood", ("a", "b"), RATE, key=KEY)
    try:
        bus.publish("b", [], [], promise=NEVER)
        # numbered 2 while 1 is due (the number due next is always checked: see below)
        junk = bytearray(_signed(bus, "a", 2, 10, list(range(200)), [0.1] * 200))
        junk[-1] ^= 0xFF  # a wrong tag
        t0 = time.monotonic()
        for _ in range(20000):
            bus.put_raw("rgtbus/flood/tx/a", bytes(junk))
        bus.publish("a", [5], [0.5], promise=30)  # crowded out too, maybe
        elapsed = time.monotonic() - t0
        assert bus.wait(20, timeout=30) == 30
        st = bus.stats()
        assert st["dropped_rate"] > 0, st
        assert st["dropped_unauthenticated"] <= 2 * CHECKS_PER_S + CHECKS_PER_S * elapsed + 1, st
        assert st["accepted"] == 2 and bus.take(30)["a"][0].tolist() == [5]
        # junk under the number due next is checked whatever the budget: the frame a run
        # waits for is never dropped unchecked
        due = bytearray(_signed(bus, "a", 2, 40))
        due[-1] ^= 0xFF
        for _ in range(3 * int(CHECKS_PER_S)):
            bus.put_raw("rgtbus/flood/tx/a", bytes(due))
        after = bus.stats()
        assert after["dropped_rate"] == st["dropped_rate"], after
        assert after["dropped_unauthenticated"] == st["dropped_unauthenticated"] + 3 * CHECKS_PER_S
    finally:
        bus.close()


def test_a_replayed_frame_costs_no_tag_check(monkeypatch):
    """Copies of a member's frames, queued or lately accepted, replayed as fast as a thread
    can put them: each a duplicate found by a look-up (and a digest), never an HMAC (a replay
    flood slowed a keyed run 5x, every copy of the frame due next checked); another frame
    under a queued number is still checked."""
    import rgtbus.bus.base as base

    checks = []
    real = base.check_tag
    monkeypatch.setattr(base, "check_tag", lambda *a: (checks.append(a[4]), real(*a))[1])
    bus = MemoryBus("replay", ("a", "b"), RATE, key=KEY)
    try:
        bus.publish("b", [], [], promise=NEVER)
        first, second = _signed(bus, "a", 1, 10, [3], [0.5]), _signed(bus, "a", 2, 20)
        bus.put_raw("rgtbus/replay/tx/a", first)
        assert bus.wait(9, timeout=5) == 10  # accepted: a recent frame
        bus.put_raw("rgtbus/replay/tx/a", second)  # queued, not yet read
        done = len(checks)  # each frame checked once (b's own too)
        for _ in range(500):
            bus.put_raw("rgtbus/replay/tx/a", first)
            bus.put_raw("rgtbus/replay/tx/a", second)
        assert len(checks) == done and bus.stats()["dropped_duplicate"] == 1000
        other = bytearray(_signed(bus, "a", 2, 25))  # another frame 2, wrongly tagged
        other[-1] ^= 0xFF
        bus.put_raw("rgtbus/replay/tx/a", bytes(other))
        assert len(checks) == done + 1 and bus.stats()["dropped_unauthenticated"] == 1
        assert bus.wait(19, timeout=5) == 20
    finally:
        bus.close()
