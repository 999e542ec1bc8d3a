"""Faults and fuzzing for the bus layer: the frame codec, hellos, keys, and the one receive path
of the live buses (memory, zenoh).

Whatever arrives (random bytes, mangled or forged frames, hostile hellos), the only exception
that may leave the bus layer is RgtbusError, and a bus drops and counts what it refuses: nothing
unchecked reaches ``take``, the horizon or the join barrier. Every wait is short and bounded;
every bus is closed by a fixture or a ``with``.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import struct
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rgtbus.bus import FAILED, FINAL, NEVER, STAT_KEYS, Frame, decode, encode, open_bus
from rgtbus.bus.auth import AuthError, check_key, check_tag, load_key, tag
from rgtbus.bus.hello import MAX_HELLO, Hello, encode_hello, read_hello
from rgtbus.bus.payload import MAGIC, MAX_MAGNITUDE, TAGGED, VERSION
from rgtbus.errors import RgtbusError

RATE = 200.0
RUN = "r1"
TX_A = f"rgtbus/{RUN}/tx/a"
KEY = bytes(range(1, 33))
OTHER_KEY = b"\xa5" * 32
NONCE = bytes(range(100, 116))  # a nonce no bus drew
SHORT = 0.3  # seconds: long enough for in-process zenoh, short enough to keep the suite fast
DROPS = tuple(k for k in STAT_KEYS if k.startswith("dropped_"))
FUZZ = settings(
    max_examples=300,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
BUS_EXAMPLES = {"memory": 80, "zenoh": 40}  # a bus per example; zenoh's cost a session each

# The documented header layout, written out here (not taken from payload.py) so a test can break
# every rule encode() refuses to break.
HEADER = struct.Struct("<4sBBHQQQdII")


def delivered(bus, n, timeout=2.0):
    """The stats once ``n`` payloads were received (zenoh delivers on its own thread)."""
    deadline = time.monotonic() + timeout
    while True:
        stats = bus.stats()
        if stats["received"] >= n:
            return stats
        assert time.monotonic() < deadline, f"{n} payloads not received in time: {stats}"
        time.sleep(0.002)


def one_line(exc: BaseException) -> str:
    msg = str(exc)
    assert msg and "\n" not in msg and "\r" not in msg, repr(msg)
    return msg


def signer(key=KEY, run_id=RUN, unit="a", nonce=NONCE, kind="frame"):
    def sign(body: bytes) -> bytes:
        return tag(key, kind, run_id, unit, nonce, body)

    return sign


def raw_frame(
    seq=1,
    promise=10,
    samples=(),
    values=(),
    *,
    flags=0,
    done_at=0,
    rate=RATE,
    magic=MAGIC,
    version=VERSION,
    res1=0,
    res2=0,
    count=None,
    sign=None,
):
    """A frame's bytes from any field values, valid or not (``encode`` refuses the invalid)."""
    n = len(samples) if count is None else count
    if sign is not None:
        flags |= TAGGED
    header = HEADER.pack(magic, version, flags, res1, seq, promise, done_at, rate, n, res2)
    body = (
        header
        + struct.pack(f"<{len(samples)}Q", *samples)
        + struct.pack(f"<{len(values)}d", *values)
    )
    return body if sign is None else body + sign(body)


# -- 1. the frame codec, fuzzed ------------------------------------------------------------------

U64_EDGES = [0, 1, NEVER - 1, NEVER, NEVER + 1, 2**64 - 1]


def u64(small: int) -> st.SearchStrategy[int]:
    return st.one_of(st.integers(0, small), st.sampled_from(U64_EDGES), st.integers(0, 2**64 - 1))


BAD_FLOATS = [
    math.nan,
    -math.nan,
    math.inf,
    -math.inf,
    1e308,
    -1e308,
    MAX_MAGNITUDE,
    -MAX_MAGNITUDE,
    math.nextafter(MAX_MAGNITUDE, math.inf),
    5e-324,
    -0.0,
]
# Mostly in range, so a frame of several pulses gets through now and then.
MAGNITUDES = st.one_of(
    st.floats(-2, 2), st.floats(-2, 2), st.floats(-2, 2), st.sampled_from(BAD_FLOATS), st.floats()
)
SIGN_MODES = ["none", "good", "other_key", "other_nonce", "other_unit", "random"]
MUTATIONS = st.one_of(
    st.tuples(st.just("flip"), st.integers(0, 10**6), st.integers(0, 7)),
    st.tuples(st.just("cut"), st.integers(0, 10**6)),
    st.tuples(st.just("extend"), st.binary(min_size=1, max_size=40)),
    st.tuples(
        st.just("overwrite"),
        # Header fields first: a random count, rate, flags, sequence number...
        st.sampled_from([0, 4, 5, 6, 8, 16, 24, 32, 40, 44]) | st.integers(0, 10**6),
        st.binary(min_size=1, max_size=8),
    ),
)


@st.composite
def recipes(draw):
    """A frame to build. A third are plausible (in range, a right or no tag, unmangled), so the
    bus's checks behind the codec see frames too; the rest have a mangled header, pulses that may
    be unsorted or out of range, a tag from a wrong signer, then a few byte-level mutations."""
    n = draw(st.integers(0, 5))
    r = {
        "flags": draw(st.sampled_from([0, 0, 0, FINAL, FAILED, FINAL | FAILED])),
        "magic": MAGIC,
        "version": VERSION,
        "res1": 0,
        "res2": 0,
        "rate": RATE,
        "count": None,
    }
    if draw(st.integers(0, 2)) == 0:
        return r | {
            "samples": sorted(draw(st.lists(st.integers(0, 300), min_size=n, max_size=n))),
            "values": draw(st.lists(st.floats(-2, 2), min_size=n, max_size=n)),
            "seq": draw(st.integers(1, 3)),
            "promise": draw(st.integers(0, 300) | st.just(NEVER)),
            "done_at": draw(st.integers(0, 300)),
            "sign": draw(st.sampled_from(["none", "good"])),
            "mutations": [],
        }
    samples = draw(st.lists(st.integers(0, 300) | u64(300), min_size=n, max_size=n))
    if draw(st.booleans()):  # half the time sorted: so the magnitudes get checked too
        samples.sort()
    r |= {
        "samples": samples,
        "values": draw(st.lists(MAGNITUDES, min_size=n, max_size=n)),
        "seq": draw(u64(4)),
        "promise": draw(u64(300)),
        "done_at": draw(u64(300)),
        "sign": draw(st.sampled_from(SIGN_MODES)),
        "mutations": draw(st.lists(MUTATIONS, max_size=2)),
    }
    if draw(st.booleans()):  # a mangled header (rarely all valid by chance)
        r["magic"] = draw(st.just(MAGIC) | st.binary(min_size=4, max_size=4))
        r["version"] = draw(st.just(VERSION) | st.integers(0, 255))
        r["flags"] = draw(st.just(r["flags"]) | st.integers(0, 255))
        r["res1"] = draw(st.just(0) | st.integers(0, 2**16 - 1))
        r["res2"] = draw(st.just(0) | st.integers(0, 2**32 - 1))
        r["rate"] = draw(st.sampled_from([RATE, 0.0, -RATE, math.nan, math.inf]) | st.floats())
        r["count"] = draw(
            st.none()
            | st.sampled_from([0, n + 1, 2**24, 2**24 + 1, 2**32 - 1])
            | st.integers(0, 2**32 - 1)
        )
    return r


def mode_signer(mode, nonce):
    """The signer for a recipe's sign mode, as seen by a receiver of unit "a" (``nonce``)."""
    if mode == "none":
        return None
    if mode == "random":
        return lambda body: hashlib.sha256(body).digest()  # a tag's size, no key's
    return signer(
        key=OTHER_KEY if mode == "other_key" else KEY,
        unit="b" if mode == "other_unit" else "a",
        nonce=bytes(16) if mode == "other_nonce" else nonce,
    )


def mutate(data: bytes, mutations) -> bytes:
    b = bytearray(data)
    for m in mutations:
        if m[0] == "flip" and b:
            b[m[1] % len(b)] ^= 1 << m[2]
        elif m[0] == "cut":
            del b[m[1] % (len(b) + 1) :]
        elif m[0] == "extend":
            b += m[1]
        elif m[0] == "overwrite" and b:
            at = m[1] % len(b)
            b[at : at + len(m[2])] = m[2]
    return bytes(b)


def render(r, nonce=NONCE) -> bytes:
    data = raw_frame(
        r["seq"],
        r["promise"],
        r["samples"],
        r["values"],
        flags=r["flags"],
        done_at=r["done_at"],
        rate=r["rate"],
        magic=r["magic"],
        version=r["version"],
        res1=r["res1"],
        res2=r["res2"],
        count=r["count"],
        sign=mode_signer(r["sign"], nonce),
    )
    return mutate(data, r["mutations"])


def check_pulses(samples, values, below=None):
    assert samples.dtype == np.int64 and values.dtype == np.float64
    assert samples.shape == values.shape and samples.ndim == 1
    assert np.isfinite(values).all() and (np.abs(values) <= MAX_MAGNITUDE).all()
    assert (samples >= 0).all() and (samples <= NEVER).all()
    assert (samples[1:] >= samples[:-1]).all()
    if below is not None:
        assert (samples < below).all()


def decoded(data, check=None):
    """The property: a sane frame, or RgtbusError in one line; nothing else escapes."""
    try:
        frame, rate = decode(data, check=check)
    except RgtbusError as e:
        one_line(e)
        return None
    check_pulses(frame.samples, frame.values)
    assert frame.samples.flags.writeable and frame.values.flags.writeable
    assert all(0 <= x <= NEVER for x in (frame.seq, frame.promise, frame.done_at))
    assert frame.flags in (0, FINAL, FAILED, FINAL | FAILED)
    assert math.isfinite(rate) and rate > 0
    return frame, rate


def good_check(body: bytes, got: bytes) -> None:
    check_tag(KEY, "frame", RUN, "a", NONCE, body, got)


FRAME_BYTES = st.one_of(
    st.binary(max_size=200),
    # Past the magic and version: the checks behind them get fuzzed too.
    st.binary(max_size=150).map(lambda b: MAGIC + bytes([VERSION]) + b),
    recipes().map(render),
    recipes().map(render),
)


@FUZZ
@given(data=FRAME_BYTES, keyed=st.booleans())
def test_decode_returns_a_sane_frame_or_raises_rgtbus_error(data, keyed):
    got = decoded(data, check=good_check if keyed else None)
    if got is not None:
        # Whatever decodes is canonical: re-encoding gives the same bytes, tag included.
        frame, rate = got
        assert encode(frame, rate, sign=signer() if keyed else None) == data


def test_decode_refuses_out_of_range_frames_that_encode_would_refuse():
    # Hand-picked corners the fuzzer reaches only by luck; each must be refused, not decoded.
    cases = {
        "nan": raw_frame(samples=[1], values=[math.nan]),
        "inf": raw_frame(samples=[1], values=[-math.inf]),
        "1e308": raw_frame(samples=[1], values=[1e308]),
        "just above the bound": raw_frame(
            samples=[1], values=[math.nextafter(MAX_MAGNITUDE, math.inf)]
        ),
        "unsorted": raw_frame(samples=[5, 4], values=[0.0, 0.0]),
        "sample above 2**63-1": raw_frame(samples=[NEVER + 1], values=[0.0]),
        "seq above 2**63-1": raw_frame(seq=NEVER + 1),
        "huge count": raw_frame(count=2**32 - 1),
        "count one short": raw_frame(samples=[1, 2], values=[0.0, 0.0], count=1),
        "nan rate": raw_frame(rate=math.nan),
        "negative rate": raw_frame(rate=-RATE),
        "unknown flag": raw_frame(flags=0x08),
        "reserved": raw_frame(res1=1),
    }
    for name, data in cases.items():
        with pytest.raises(RgtbusError) as info:
            decode(data)
        one_line(info.value)
        assert decoded(data, check=None) is None, name
    # The bound itself is in range.
    frame, _ = decode(raw_frame(samples=[1, 1], values=[MAX_MAGNITUDE, -MAX_MAGNITUDE]))
    assert frame.values.tolist() == [MAX_MAGNITUDE, -MAX_MAGNITUDE]


def test_decode_auth_errors_are_auth_errors():
    good = raw_frame(samples=[1], values=[0.5], sign=signer())
    assert decode(good, check=good_check)[0].values.tolist() == [0.5]
    with pytest.raises(AuthError, match="no tag"):
        decode(raw_frame(), check=good_check)
    with pytest.raises(AuthError, match="does not have"):
        decode(good)  # signed, on a run without a key
    for sign in (
        signer(key=OTHER_KEY),
        signer(run_id="r2"),
        signer(unit="b"),
        signer(nonce=bytes(16)),
    ):
        with pytest.raises(AuthError, match="bad authentication tag"):
            decode(raw_frame(samples=[1], values=[0.5], sign=sign), check=good_check)
    # The tag is checked before the pulses: a forged frame learns nothing from its values.
    with pytest.raises(AuthError):
        decode(
            raw_frame(samples=[1], values=[math.nan], sign=signer(key=OTHER_KEY)), check=good_check
        )


# -- 2. the receive path of the live buses, fuzzed -----------------------------------------------

PAYLOADS = st.one_of(recipes(), recipes(), st.binary(max_size=120))
BATCHES = st.lists(
    st.tuples(
        # Mostly our member's key; sometimes another run's or a non-member's.
        st.just(TX_A) | st.just(TX_A) | st.sampled_from(["rgtbus/r2/tx/a", f"rgtbus/{RUN}/tx/zz"]),
        PAYLOADS,
    ),
    min_size=1,
    max_size=4,
)


@pytest.mark.parametrize("keyed", [False, True], ids=["open", "keyed"])
@pytest.mark.parametrize("bus_kind", ["memory", "zenoh"])
def test_anything_on_the_wire_is_accepted_or_dropped_and_counted_once(bus_kind, keyed):
    @settings(FUZZ, max_examples=BUS_EXAMPLES[bus_kind])
    @given(batch=BATCHES)
    def run(batch):
        with open_bus(bus_kind, RUN, ("a",), RATE, key=KEY if keyed else None) as bus:
            horizon = bus.horizon()
            for i, (key, item) in enumerate(batch, 1):
                data = render(item, bus.nonce) if isinstance(item, dict) else item
                before = bus.stats()
                bus.put_raw(key, data)
                after = delivered(bus, i)
                # Exactly one payload more has an outcome: accepted, one reason to drop, or held
                # after a gap (a frame filling a gap lets those held after it be read too).
                moved = {k: after[k] - before[k] for k in ("accepted", *DROPS, "held")}
                assert sum(moved.values()) == 1, moved
                assert all(v >= 0 for k, v in moved.items() if k != "held"), moved
                if moved["accepted"]:
                    assert key == TX_A
                    if keyed:  # nothing but our own signature gets in
                        assert isinstance(item, dict) and item["sign"] == "good"
                assert bus.horizon() >= horizon  # promises never go back
                horizon = bus.horizon()
            stats = bus.stats()
            dropped = sum(stats[k] for k in DROPS)
            assert stats["received"] == len(batch) == stats["accepted"] + dropped + stats["held"]
            check_pulses(*bus.known(NEVER)["a"])
            try:
                h = bus.wait(0, timeout=0.01)
            except RgtbusError as e:
                why = one_line(e)
                if "is not trusted" in why:  # a signed frame no healthy member sends (two
                    assert keyed and "speaks with its identity" in why  # under one number, a
                    # promise going back, ...): its member is named
                else:
                    assert "no news" in why
                    assert horizon == 0
            else:
                assert h == horizon >= 1
                check_pulses(*bus.take(h)["a"], below=h)
            notes = bus.drop_notes()
            assert len(notes) == dropped  # one note per drop, each one line
            assert all(isinstance(n, str) and "\n" not in n for n in notes)

    run()


# -- 3. hellos, fuzzed ---------------------------------------------------------------------------

MEMBERS = frozenset({"a", "b", "c"})
VIEW = bytes(range(32))
HEX = "0123456789abcdef"
NAMES = st.from_regex(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,7}", fullmatch=True)
# Hex-like strings of about the right lengths, to get past the first checks.
HEXISH = st.one_of(
    st.text(HEX + "ABCDEF g-\n", max_size=70),
    st.text(HEX, min_size=32, max_size=32),
    st.text(HEX, min_size=64, max_size=64),
    st.text(HEX + "A \n", min_size=31, max_size=33),
    st.text(HEX + "A \n", min_size=63, max_size=65),
)
LEAVES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(),
    st.sampled_from([NEVER, NEVER + 1, -1, 2**64, 0.0, 1.0]),
    st.floats(),
    st.text(max_size=12),
    HEXISH,
    st.sampled_from(sorted(MEMBERS)),
)
JSON = st.recursive(
    LEAVES,
    lambda inner: (
        st.lists(inner, max_size=4)
        | st.dictionaries(st.text(max_size=6) | st.sampled_from(sorted(MEMBERS)), inner, max_size=4)
    ),
    max_leaves=12,
)
FIELDS = [
    "unit", "digest", "nonce", "view", "ready", "started", "sample", "process", "to", "tag",
    "extra", "",
]  # fmt: skip


@st.composite
def hellos(draw, members=None):
    members = members or sorted(draw(st.sets(NAMES, min_size=1, max_size=4)))
    one = st.sampled_from(sorted(members))
    return Hello(
        unit=draw(one),
        digest=draw(st.text(HEX, min_size=64, max_size=64)),
        nonce=draw(st.binary(min_size=16, max_size=16)),
        view=draw(st.just(b"") | st.binary(min_size=32, max_size=32)),
        started=draw(st.booleans()),
        sample=draw(st.integers(0, NEVER)),
        ready=draw(st.booleans()),
        process=draw(st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=40)),
        to=draw(st.just(b"") | st.binary(min_size=16, max_size=16)),
    )


EDITS = st.lists(
    st.one_of(
        st.tuples(st.just("set"), st.sampled_from(FIELDS), JSON),
        st.tuples(st.just("del"), st.sampled_from(FIELDS)),
        st.tuples(st.just("set"), st.sampled_from(["view", "to", "nonce"]), HEXISH),
        st.tuples(st.just("set"), st.just("process"), st.text(max_size=200)),
    ),
    min_size=1,
    max_size=4,
)


def edit(obj: dict, edits) -> dict:
    for e in edits:
        if e[0] == "set":
            obj[e[1]] = e[2]
        elif e[0] == "del":
            obj.pop(e[1], None)
    return obj


def read(raw, key=None, members=MEMBERS):
    """The property: a Hello whose every field is in range, or RgtbusError in one line."""
    try:
        h = read_hello(raw, RUN, members, key)
    except RgtbusError as e:
        one_line(e)
        return None
    assert isinstance(h, Hello) and h.unit in members
    assert re.fullmatch(r"[0-9a-f]{64}", h.digest), h.digest
    assert isinstance(h.nonce, bytes) and len(h.nonce) == 16
    assert isinstance(h.view, bytes) and len(h.view) in (0, 32)
    assert isinstance(h.to, bytes) and len(h.to) in (0, 16)
    assert isinstance(h.process, str) and len(h.process) <= 128 and h.process.isprintable()
    assert isinstance(h.started, bool) and isinstance(h.ready, bool)
    assert type(h.sample) is int and 0 <= h.sample <= NEVER
    return h


@FUZZ
@given(raw=st.binary(max_size=300) | JSON.map(lambda v: json.dumps(v).encode()))
def test_read_hello_on_arbitrary_bytes_and_json(raw):
    read(raw)
    read(raw, key=KEY)


@FUZZ
@given(h=hellos(members=sorted(MEMBERS)), edits=EDITS, keyed=st.booleans())
def test_read_hello_on_valid_hellos_with_fields_replaced(h, edits, keyed):
    key = KEY if keyed else None
    raw = json.dumps(edit(json.loads(encode_hello(h, RUN, key)), edits)).encode()
    got = read(raw, key=key)
    if got is not None and keyed:
        assert got == h  # with a key, whatever gets through is what was signed: no forgery


HOSTILE = {
    "deep list, over the size limit": b"[" * 100_000,
    "deep list": b"[" * 60_000,
    "deep objects": b'{"a":' * 13_000,
    "deep unit": b'{"unit":' + b"[" * 30_000 + b"]" * 30_000 + b"}",
    "shallow nesting": b"[" * 500 + b"]" * 500,
    "all spaces, over the limit": b" " * (64 * 1024 + 1),
    "empty": b"",
    "huge integer": b'{"sample": ' + b"9" * 5_000 + b"}",
    "not UTF-8": b"\xff\xfe{}",
    "BOM": b"\xef\xbb\xbf{}",
    "lone surrogate": b'{"unit": "\\ud800"}',
    "NaN": b"NaN",
    "view list": b'{"view": [[1]]}',
    "null": b"null",
}


@pytest.mark.parametrize("raw", list(HOSTILE.values()), ids=list(HOSTILE))
@pytest.mark.parametrize("key", [None, KEY], ids=["open", "keyed"])
def test_read_hello_refuses_hostile_input(raw, key):
    with pytest.raises(RgtbusError) as info:
        read_hello(raw, RUN, MEMBERS, key)
    one_line(info.value)


def test_read_hello_refuses_non_bytes_and_deep_fields_of_a_valid_hello():
    for raw in (None, "{}", 42, memoryview(b"{}")):
        with pytest.raises(RgtbusError, match="must be bytes"):
            read_hello(raw, RUN, MEMBERS, None)
    base = json.loads(encode_hello(Hello("a", "0" * 64, NONCE), RUN, None))
    for name in ("unit", "view", "sample", "nonce", "digest", "process", "to"):
        for depth in (1, 50, 400):  # parses fine, but no field may be a nested list
            obj = dict(base, **{name: json.loads("[" * depth + "]" * depth)})
            with pytest.raises(RgtbusError):
                read_hello(json.dumps(obj).encode(), RUN, MEMBERS, None)


BAD_FIELDS = [
    ("unit", "zz"),
    ("unit", None),
    ("unit", ["a"]),
    ("digest", "0" * 63),
    ("digest", "0" * 65),
    ("digest", "A" * 64),
    ("digest", 0),
    ("nonce", "0" * 31),
    ("nonce", "0" * 34),
    ("nonce", "AB" * 16),
    ("nonce", "0" * 30 + " 0"),
    ("nonce", None),
    ("view", "0" * 62),
    ("view", "0" * 32),
    ("view", "AB" * 32),
    ("view", None),
    ("view", {"b": "0" * 64}),
    ("to", "0" * 30),
    ("to", "0" * 64),
    ("to", None),
    ("process", 7),
    ("process", None),
    ("process", "x" * 129),
    ("process", "line\nbreak"),
    ("ready", 1),
    ("ready", "true"),
    ("started", None),
    ("sample", -1),
    ("sample", NEVER + 1),
    ("sample", 2**64),
    ("sample", True),
    ("sample", 1.0),
    ("sample", "1"),
    ("sample", math.nan),
    ("tag", "0" * 63),
    ("tag", "A" * 64),
    ("tag", 0),
    ("extra", 0),
]


@pytest.mark.parametrize(
    ("name", "value"), BAD_FIELDS, ids=[f"{n}={v!r:.20}" for n, v in BAD_FIELDS]
)
@pytest.mark.parametrize("key", [None, KEY], ids=["open", "keyed"])
def test_read_hello_refuses_each_bad_field(name, value, key):
    # One field off at a time, every other field right (and, keyed, a tag over the bad field
    # itself: the field check must refuse it, not only the tag).
    obj = json.loads(encode_hello(Hello("a", "0" * 64, NONCE, VIEW, to=NONCE), RUN, None))
    obj[name] = value
    if key is not None and name != "tag":
        body = {k: v for k, v in obj.items() if k != "tag"}
        canonical = json.dumps(body, sort_keys=True, separators=(",", ":")).encode()
        obj["tag"] = tag(key, "hello", RUN, "a", NONCE, canonical).hex()
    with pytest.raises(RgtbusError) as info:
        read_hello(json.dumps(obj).encode(), RUN, MEMBERS, key)
    one_line(info.value)


def test_read_hello_edges_that_are_fine():
    obj = json.loads(encode_hello(Hello("a", "0" * 64, NONCE), RUN, None))
    for name, value in (("sample", NEVER), ("sample", 0), ("unit", "c"), ("process", "")):
        h = read_hello(json.dumps(dict(obj, **{name: value})).encode(), RUN, MEMBERS, None)
        assert getattr(h, name) == value
    for name in ("view", "to"):  # empty: no view yet, an answer to nobody
        h = read_hello(json.dumps(dict(obj, **{name: ""})).encode(), RUN, MEMBERS, None)
        assert getattr(h, name) == b""


def test_hello_size_limit_is_exact():
    assert MAX_HELLO == 4 * 1024  # the documented wire limit
    raw = encode_hello(Hello("a", "0" * 64, NONCE, VIEW, process="x" * 128), RUN, KEY)
    assert len(raw) < 1024  # the largest a member says, whatever the roster
    padded = raw + b" " * (4 * 1024 - len(raw))  # JSON whitespace: still the same hello
    assert read_hello(padded, RUN, MEMBERS, KEY).unit == "a"
    with pytest.raises(RgtbusError, match="at most"):
        read_hello(padded + b" ", RUN, MEMBERS, KEY)


@FUZZ
@given(data=st.data(), keyed=st.booleans())
def test_hello_round_trip(data, keyed):
    members = sorted(data.draw(st.sets(NAMES, min_size=1, max_size=4)))
    h = data.draw(hellos(members=members))
    key = KEY if keyed else None
    assert read_hello(encode_hello(h, RUN, key), RUN, members, key) == h


def test_hello_authentication():
    h = Hello("a", "1" * 64, NONCE, VIEW, sample=7, process="h:1")
    signed = encode_hello(h, RUN, KEY)
    assert read_hello(signed, RUN, MEMBERS, KEY) == h
    with pytest.raises(AuthError, match="bad authentication tag"):
        read_hello(signed, RUN, MEMBERS, OTHER_KEY)  # another key
    with pytest.raises(AuthError, match="bad authentication tag"):
        read_hello(encode_hello(h, "r2", KEY), RUN, MEMBERS, KEY)  # another run's tag
    with pytest.raises(AuthError, match="does not have"):
        read_hello(signed, RUN, MEMBERS, None)  # signed, on an open run
    with pytest.raises(AuthError, match="no tag"):
        read_hello(encode_hello(h, RUN, None), RUN, MEMBERS, KEY)  # unsigned, on a keyed run
    # Any signed field changed after signing: the tag no longer fits.
    for name, value in (("sample", 8), ("ready", True), ("unit", "b"), ("view", ""),
                        ("process", "h:2"), ("to", "0" * 32)):  # fmt: skip
        obj = json.loads(signed)
        obj[name] = value
        with pytest.raises(AuthError, match="bad authentication tag"):
            read_hello(json.dumps(obj).encode(), RUN, MEMBERS, KEY)
    # A frame's tag over the same bytes is not a hello's (the kind is in the tag).
    obj = json.loads(signed)
    del obj["tag"]
    body = json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()
    obj["tag"] = tag(KEY, "frame", RUN, "a", NONCE, body).hex()
    with pytest.raises(AuthError):
        read_hello(json.dumps(obj).encode(), RUN, MEMBERS, KEY)


@pytest.mark.parametrize(
    "field",
    ["nonce", "view", "to", "tag", "digest"],
)
def test_hex_field_with_a_trailing_newline_is_refused(field):
    # A fuzzer's find: "^...$" matched before a trailing newline, and bytes.fromhex then raised
    # a bare ValueError out of read_hello (fullmatch now).
    # Keyed: the hex fields are read before the tag is checked, so no key is needed to get
    # there. The digest on an open run (on a keyed one the tag catches it).
    key = None if field == "digest" else KEY
    obj = json.loads(encode_hello(Hello("a", "0" * 64, NONCE, VIEW, to=NONCE), RUN, key))
    size = 64 if field in ("tag", "digest", "view") else 32
    obj[field] = "0" * (size - 1) + "\n"
    with pytest.raises(RgtbusError):
        read_hello(json.dumps(obj).encode(), RUN, MEMBERS, key)


# -- 4. the zenoh bus's hello reader -------------------------------------------------------------


@pytest.fixture
def zbus():
    with open_bus("zenoh", RUN, ("a", "b"), RATE, key=KEY) as bus:
        yield bus


def test_zenoh_read_hello_drops_and_counts(zbus):
    good = Hello("b", "0" * 64, NONCE, VIEW)
    base = json.loads(encode_hello(good, RUN, KEY))
    malformed = [
        b"",
        b"{",
        b"[]",
        b"[" * 60_000,
        b" " * (MAX_HELLO + 1),
        b"\xff" * 100,
        json.dumps({k: v for k, v in base.items() if k != "sample"}).encode(),
        json.dumps(dict(base, view="zz")).encode(),
        json.dumps(dict(base, unit="zz")).encode(),
        json.dumps(dict(base, sample=-1)).encode(),
    ]
    unauthenticated = [
        encode_hello(good, RUN, None),
        encode_hello(good, RUN, OTHER_KEY),
        encode_hello(good, "r2", KEY),
        json.dumps(dict(base, sample=5)).encode(),  # tampered after signing
        json.dumps(dict(base, tag="0" * 64)).encode(),
    ]
    for raw in malformed + unauthenticated:
        assert zbus._read_hello(raw) is None, raw[:60]
    stats = zbus.stats()
    assert stats["dropped_malformed"] == len(malformed)
    assert stats["dropped_unauthenticated"] == len(unauthenticated)
    notes = zbus.drop_notes()
    assert len(notes) == len(malformed) + len(unauthenticated)
    assert all(n.startswith("hello: ") and "\n" not in n and len(n) < 400 for n in notes)
    assert zbus._read_hello(encode_hello(good, RUN, KEY)) == good
    assert sum(zbus.stats()[k] for k in DROPS) == len(notes)


def test_zenoh_read_hello_on_an_open_run_refuses_signed_hellos():
    with open_bus("zenoh", RUN, ("a", "b"), RATE) as bus:
        h = Hello("b", "0" * 64, NONCE)
        assert bus._read_hello(encode_hello(h, RUN, KEY)) is None
        assert bus.stats()["dropped_unauthenticated"] == 1
        assert bus._read_hello(encode_hello(h, RUN, None)) == h


def test_zenoh_read_hello_fuzzed(zbus):
    @settings(FUZZ, max_examples=150)
    @given(
        raw=st.binary(max_size=200)
        | JSON.map(lambda v: json.dumps(v).encode())
        | st.tuples(hellos(members=["a", "b"]), EDITS).map(
            lambda he: json.dumps(edit(json.loads(encode_hello(he[0], RUN, KEY)), he[1])).encode()
        )
    )
    def run(raw):
        before = zbus.stats()
        h = zbus._read_hello(raw)  # never raises
        after = zbus.stats()
        moved = {k: after[k] - before[k] for k in DROPS if after[k] != before[k]}
        # A refused hello is counted once, as malformed or unauthenticated; a read one not at all.
        if h is None:
            assert list(moved.values()) == [1], moved
            assert set(moved) <= {"dropped_malformed", "dropped_unauthenticated"}, moved
        else:
            assert moved == {}, moved

    run()


def test_an_outsiders_hello_cannot_crash_a_keyed_runs_wait():
    # A hello put by anyone on the network, without the key (the nonce is read before the tag
    # is checked), must not make wait() raise on a joined member.
    with open_bus("zenoh", RUN, ("a",), RATE, key=KEY) as bus:
        bus.join("a", "0" * 64, timeout=2.0)  # alone in the run: returns at once
        obj = json.loads(encode_hello(Hello("a", "0" * 64, NONCE), RUN, None))
        obj["nonce"] = "0" * 31 + "\n"
        bus.session.put(bus.hello_key("a"), json.dumps(obj).encode())
        deadline = time.monotonic() + 2.0
        while bus._hellos.empty():
            assert time.monotonic() < deadline, "hello not received in time"
            time.sleep(0.002)
        with pytest.raises(RgtbusError, match="no news"):
            bus.wait(0, timeout=0.05)
        assert bus.stats()["dropped_malformed"] == 1


# -- 5. authentication on the live buses ---------------------------------------------------------


def test_keyed_bus_accepts_its_own_frames(make_bus):
    bus = make_bus(("a", "b"), key=KEY)
    bus.publish("a", np.array([1, 2]), np.array([0.5, -0.5]), promise=10)
    bus.publish("b", np.zeros(0, dtype=np.int64), np.zeros(0), promise=20)
    assert bus.wait(5, timeout=SHORT) == 10
    got = bus.take(10)
    assert got["a"][0].tolist() == [1, 2] and got["a"][1].tolist() == [0.5, -0.5]
    stats = bus.stats()
    assert stats["accepted"] == 2 and all(stats[k] == 0 for k in DROPS), stats


def test_forged_frames_are_dropped_as_unauthenticated(make_bus):
    bus = make_bus(("a", "b"), key=KEY)
    bus.publish("a", np.array([3]), np.array([0.25]), promise=10)
    bus.publish("b", np.zeros(0, dtype=np.int64), np.zeros(0), promise=1000)
    assert bus.wait(5, timeout=SHORT) == 10
    mine = signer(nonce=bus.nonce)
    good = encode(Frame(2, 50, np.array([20]), np.array([1.0])), RATE, sign=mine)
    assert good == raw_frame(
        2, 50, [20], [1.0], sign=mine
    )  # the forgeries below differ only where said
    # Each of these would be a's next frame (seq 2, promise 50) if it were believed.
    forged = {
        "unsigned": raw_frame(2, 50, [20], [1.0]),
        "another key": raw_frame(2, 50, [20], [1.0], sign=signer(OTHER_KEY, nonce=bus.nonce)),
        "another run": raw_frame(2, 50, [20], [1.0], sign=signer(run_id="r2", nonce=bus.nonce)),
        "another unit": raw_frame(2, 50, [20], [1.0], sign=signer(unit="b", nonce=bus.nonce)),
        "another nonce": raw_frame(2, 50, [20], [1.0], sign=signer(nonce=NONCE)),
        "a hello's tag": raw_frame(2, 50, [20], [1.0], sign=signer(nonce=bus.nonce, kind="hello")),
        "tag flipped": good[:-1] + bytes([good[-1] ^ 1]),
        "value flipped": mutate(good, [("flip", len(good) - 40, 0)]),  # a magnitude's low bit
        "promise raised": mutate(good, [("overwrite", 16, struct.pack("<Q", 999))]),
        "forged NaN": raw_frame(2, 50, [20], [math.nan], sign=signer(OTHER_KEY, nonce=bus.nonce)),
    }
    for data in forged.values():
        bus.put_raw(TX_A, data)
    stats = delivered(bus, 2 + len(forged))
    assert stats["dropped_unauthenticated"] == len(forged), (stats, bus.drop_notes())
    assert stats["accepted"] == 2
    assert bus.horizon() == 10 and bus.status()["a"].promise == 10
    assert bus.known(NEVER)["a"][0].tolist() == [3]
    assert len(bus.drop_notes()) == len(forged)
    # The genuine article gets in; the same bytes again are a replay.
    bus.put_raw(TX_A, good)
    bus.put_raw(TX_A, good)
    stats = delivered(bus, 4 + len(forged))
    assert stats["accepted"] == 3 and stats["dropped_duplicate"] == 1
    assert bus.wait(10, timeout=SHORT) == 50
    assert bus.take(50)["a"][0].tolist() == [3, 20]


def test_frames_of_a_remote_member_before_its_hello_are_unauthenticated(make_bus):
    bus = make_bus(("a", "b"), key=KEY, local=("a",))
    # Even signed with our own nonce: we have heard no hello from b, so no nonce to check with.
    bus.put_raw(f"rgtbus/{RUN}/tx/b", raw_frame(1, 50, sign=signer(unit="b", nonce=bus.nonce)))
    stats = delivered(bus, 1)
    assert stats["dropped_unauthenticated"] == 1 and stats["accepted"] == 0
    assert any("no hello heard from 'b'" in n for n in bus.drop_notes())
    assert bus.status()["b"].promise == 0


@pytest.mark.parametrize("keyed", [False, True], ids=["open", "keyed"])
@pytest.mark.parametrize("value", [1e308, -1e308, math.nan, math.inf, -math.inf, 2 * MAX_MAGNITUDE])
def test_out_of_range_magnitudes_never_reach_take(make_bus, keyed, value):
    bus = make_bus(("a",), key=KEY if keyed else None)
    sign = signer(nonce=bus.nonce) if keyed else None
    bus.put_raw(TX_A, raw_frame(1, 10, [2, 3], [0.5, value], sign=sign))  # correctly signed
    stats = delivered(bus, 1)
    assert stats["dropped_malformed"] == 1 and stats["accepted"] == 0
    with pytest.raises(RgtbusError, match="no news"):
        bus.wait(0, timeout=0.05)
    bus.put_raw(TX_A, raw_frame(1, 10, [2], [0.5], sign=sign))
    assert bus.wait(0, timeout=SHORT) == 10
    s, v = bus.take(10)["a"]
    assert s.tolist() == [2] and v.tolist() == [0.5]


def test_open_bus_drops_tagged_frames_as_unauthenticated(make_bus):
    bus = make_bus(("a",))
    bus.put_raw(TX_A, raw_frame(1, 10, [2], [0.5], sign=signer()))
    stats = delivered(bus, 1)
    assert stats["dropped_unauthenticated"] == 1 and stats["accepted"] == 0
    assert bus.horizon() == 0


# -- 6. keys --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "content", "match"),
    [
        ("missing", None, "No such file"),
        ("dir", "dir", "directory"),
        ("empty", b"", "0 bytes of key"),
        ("short", b"k" * 15, "15 bytes of key"),
        ("blank", b" \n\t\r\n", "0 bytes of key"),
        ("short-after-strip", b"k" * 15 + b"\n", "15 bytes of key"),
        ("huge", b"k" * 4097, "more than 4096 bytes"),
    ],
)
def test_load_key_refuses_bad_files(tmp_path, name, content, match):
    path = tmp_path / name
    if content == "dir":
        path.mkdir()
    elif content is not None:
        path.write_bytes(content)
    with pytest.raises(RgtbusError, match=match) as info:
        load_key(path)
    assert str(path) in one_line(info.value)


def test_load_key_reads_the_key_without_trailing_whitespace(tmp_path):
    key = bytes(range(65, 97))  # 32 bytes, none of them whitespace
    path = tmp_path / "key"
    path.write_bytes(key + b"\n")
    assert load_key(path) == key
    path.write_bytes(key + b" \r\n")
    assert load_key(path) == key
    path.write_bytes(b"k" * 4096)  # the limit itself is a key
    assert load_key(str(path)) == b"k" * 4096
    path.write_bytes(b"k" * 16)
    assert load_key(path) == b"k" * 16


def test_check_key():
    assert check_key(None) is None
    assert check_key(bytearray(KEY)) == KEY
    for bad in (b"k" * 15, "k" * 32, 42, b""):
        with pytest.raises(RgtbusError, match="at least 16 bytes"):
            check_key(bad)
    for kind_ in ("memory", "zenoh"):
        with pytest.raises(RgtbusError, match="at least 16 bytes"):
            open_bus(kind_, RUN, ("a",), RATE, key=b"short")


def _join_hearing(bus, unit: str, hellos: list[Hello], timeout: float = 10.0) -> str:
    """``bus`` joins as ``unit`` while ``hellos`` (from other processes, unsigned) arrive at
    its hello gate, again and again as a process repeats its hello; what the join ended
    with: "joined" or its error."""
    import threading

    out: list[str] = []

    def join() -> None:
        try:
            bus.join(unit, "0" * 64, timeout=timeout)
            out.append("joined")
        except RgtbusError as e:
            out.append(str(e))

    t = threading.Thread(target=join)
    t.start()
    while t.is_alive():
        for h in hellos:
            bus._hello_gate(bus.hello_key(h.unit), encode_hello(h, RUN, None))
        time.sleep(0.02)
    t.join()
    return out[0]


def test_two_processes_claiming_a_member_stop_the_join_naming_both():
    """Member b said by two live processes (two nonces, each repeating its hello): the join
    stops with one line naming b and both claimants, whichever it heard first."""
    other = bytes([7]) * 16
    with open_bus("zenoh", RUN, ("a", "b"), RATE, local=["a"]) as bus:
        claims = [
            Hello("b", "0" * 64, NONCE, VIEW, process="host-1:11"),
            Hello("b", "0" * 64, other, VIEW, process="host-2:22"),
        ]
        said = _join_hearing(bus, "a", claims)
    assert said.startswith(f"two processes claim unit 'b' of run '{RUN}': "), said
    assert "host-1:11 (nonce " + NONCE.hex()[:8] in said and "host-2:22 (nonce 07070707" in said
    assert said.endswith("the join stops for both") and "\n" not in said


def test_a_process_hearing_another_claim_its_own_unit_stops_naming_both():
    """A unit's own process hears another process say it is that unit: it stops too."""
    with open_bus("zenoh", RUN, ("a", "b"), RATE, local=["b"]) as bus:
        rival = Hello("b", "0" * 64, NONCE, process="elsewhere:7")
        said = _join_hearing(bus, "b", [rival])
    assert said.startswith(f"two processes claim unit 'b' of run '{RUN}': "), said
    assert bus.process in said and "elsewhere:7" in said


def test_a_claimant_that_fell_silent_is_no_conflict():
    """A process that said it is b, then fell silent (died, restarted): once it has been
    unheard longer than ``claim_silence``, a new claimant of b is no conflict; the join goes
    on (and times out here, b never answering a's nonce)."""
    from rgtbus.bus.join import claim_silence, hello_period

    with open_bus("zenoh", RUN, ("a", "b"), RATE, local=["a"]) as bus:
        gone = Hello("b", "0" * 64, bytes([9]) * 16, process="old:1")
        bus._hello_gate(bus.hello_key("b"), encode_hello(gone, RUN, None))
        time.sleep(claim_silence(hello_period(2)) + 0.1)  # it fell silent before the join
        new = Hello("b", "0" * 64, NONCE, process="new:2")
        said = _join_hearing(bus, "a", [new], timeout=1.0)
    assert said.startswith("joining run") and "timed out" in said, said


def test_a_ready_member_left_waiting_names_the_claim_it_heard_once_ready():
    """a has heard b and c with its view and said it is ready; c never says it is ready (it
    stopped: it heard a second claimant of b before it was ready). A second claimant of b
    heard after a was ready is late to a, but when a's join times out waiting for c, its
    line names that claim too: why c never came."""
    import threading

    from rgtbus.bus.hello import view_digest

    nb, nc, n2 = bytes([1]) * 16, bytes([2]) * 16, bytes([3]) * 16
    digest = "0" * 64
    with open_bus("zenoh", RUN, ("a", "b", "c"), RATE, local=["a"]) as bus:
        view = view_digest(RUN, digest, {"a": bus.nonce, "b": nb, "c": nc})
        ready = [
            Hello("b", digest, nb, view, ready=True, process="host-b:1"),
            Hello("c", digest, nc, view, process="host-c:2"),  # never ready
        ]
        out: list[str] = []

        def join() -> None:
            try:
                bus.join("a", digest, timeout=1.5)
                out.append("joined")
            except RgtbusError as e:
                out.append(str(e))

        t = threading.Thread(target=join)
        t.start()
        started = time.monotonic()
        while t.is_alive():
            hellos = list(ready)
            if time.monotonic() - started > 0.5:  # a has long said it is ready
                hellos.append(Hello("b", digest, n2, process="host-x:3"))
            for h in hellos:
                bus._hello_gate(bus.hello_key(h.unit), encode_hello(h, RUN, None))
            time.sleep(0.02)
        t.join()
    said = out[0]
    assert said.startswith(f"joining run '{RUN}' timed out after 1.5 s: no answer from c; "), said
    assert f"heard once ready: two processes claim unit 'b' of run '{RUN}': " in said
    assert "host-b:1" in said and "host-x:3" in said and "\n" not in said
