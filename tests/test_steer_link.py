"""Steering across processes on zenoh (``rgtbus.bus.steer_link``): a watcher's requests reach
the steering process (the roster's first unit's), its changes reach every other process with
their sample and order, receipts come back; what is forged, unreadable or too large is
dropped and counted. Two processes' links share one in-process zenoh session here (a
session's own puts reach its own subscribers); tests/test_steer_live.py runs real ones."""

from __future__ import annotations

import time

import pytest
import zenoh

from rgtbus.bus.config import make_config
from rgtbus.bus.steer_link import MAX_MESSAGE, Signer, SteerLink, request_payload, steer_key
from rgtbus.steering import Request

UNITS = ("a", "b", "c", "d")
WAIT = 30.0  # s: a bound, never a pace


@pytest.fixture
def session():
    s = zenoh.open(make_config())
    yield s
    s.close()


def links(session, key=None, run="r1"):
    lead = SteerLink(session, run, ["a", "b"], UNITS, key)
    follow = SteerLink(session, run, ["c", "d"], UNITS, key)
    return lead, follow


def taken(link, n=1):
    """What ``link`` hands its run, waiting (bounded) for ``n`` requests."""
    got: list[Request] = []
    deadline = time.monotonic() + WAIT
    while len(got) < n and time.monotonic() < deadline:
        link.wait(0.1)
        got += link.take()
    return got


def test_a_request_reaches_the_steering_process_and_its_change_every_other(session):
    lead, follow = links(session)
    assert lead.leading and not follow.leading
    req = Request("service", "influence", {"influence": "d>a=0"}, "client 1")
    session.put(steer_key("r1"), request_payload(req, Signer(None, "r1")))
    (got,) = taken(lead)
    assert (got.name, got.value, got.who, got.at, got.seq) == (
        "influence", {"influence": "d>a=0"}, "client 1", None, None,
    )  # fmt: skip
    assert follow.take() == []  # a follower hears no request, only changes
    placed = got.placed(2000, 7)
    lead.announce(placed)
    (change,) = taken(follow)
    assert change == placed
    assert lead.settle([7], WAIT) == []  # the follower's receipt came
    lead.close(), follow.close()
    lead.undeclare(), follow.undeclare()


def test_a_change_not_acknowledged_is_announced_again_and_named(session):
    lead = SteerLink(session, "r2", ["a"], UNITS)  # b, c, d: no process of theirs here
    lead.announce(Request("parameter", "channel.noise", 0.1, "x").placed(40, 0))
    t0 = time.monotonic()
    assert lead.settle([0], 0.6) == ["b", "c", "d"]
    assert time.monotonic() - t0 >= 0.6
    lead.undeclare()


def test_a_keyed_run_takes_only_what_its_key_signed(session):
    key = b"k" * 32
    lead, follow = links(session, key, run="r3")
    req = Request("service", "pause", {}, "client 2")
    session.put(steer_key("r3"), request_payload(req, Signer(None, "r3")))  # unsigned
    session.put(steer_key("r3"), request_payload(req, Signer(b"x" * 32, "r3")))  # another key
    session.put(steer_key("r3"), request_payload(req, Signer(key, "r4")))  # another run's
    session.put(steer_key("r3"), request_payload(req, Signer(key, "r3")))
    (got,) = taken(lead)
    assert got.name == "pause" and lead.take() == []
    assert lead.dropped["auth"] == 3
    lead.announce(got.placed(100, 0))
    assert taken(follow)[0].at == 100
    assert lead.settle([0], WAIT) == []
    lead.close(), follow.close()
    lead.undeclare(), follow.undeclare()


def test_what_is_not_a_request_is_dropped_and_counted(session):
    lead = SteerLink(session, "r5", ["a"], UNITS)
    key = steer_key("r5")
    for junk in (b"", b"{", b"[1]", b'{"kind": "parameter"}', b'{"kind": "x", "name": "y"}'):
        session.put(key, junk)
    session.put(key, b"{" + b" " * MAX_MESSAGE + b"}")
    good = request_payload(Request("parameter", "pace", 2.0, "c"), Signer(None, "r5"))
    session.put(key, good)
    assert [r.name for r in taken(lead)] == ["pace"]
    assert lead.dropped["oversize"] == 1 and lead.dropped["unreadable"] == 5
    lead.undeclare()
