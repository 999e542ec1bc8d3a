"""The hot topics' blocks (rgtbus.telemetry.blocks): each topic's record to its block's bytes
and back, the bytes the protobuf library reads from the block's own descriptor, canonical
pulse blocks whatever order the pulses came in, and hostile blocks refused in one line."""

from __future__ import annotations

import random

import numpy as np
import pytest
from google.protobuf import json_format

from rgtbus.errors import RgtbusError
from rgtbus.telemetry import blocks, pulse_blocks, records
from rgtbus.telemetry.codec import encode
from rgtbus.telemetry.record_rows import decode_rows
from tests.test_codec import library_class

TAU = 1e-3


def _pulses() -> list[records.PulseRecord]:
    out = []
    for turn, (sender, to, kind, code) in enumerate(
        [("a", "b", "id", "ID-a"), ("a", "c", "payload", "AL"), ("a", "b", "request", "R1")]
    ):
        ref = records.message_ref(turn, kind, code, sender, to, 2 if kind == "request" else 0)
        for j, k in enumerate(range(100 * turn, 100 * turn + 3)):
            omega = {"b": 6.28, "c": 12.56}[to]  # a channel's own
            out.append(records.pulse("a", f"ch-{to}", omega, 0.5 + j, TAU, k, ref))
    return out


def _decodes() -> dict:
    rows = [
        (0, "a", "b", "b", "id", "ID-a", 0.5, 0.01, True),
        (1, "c", "b", "b", "payload", "AL", 0.25, 0.02, False),
    ]
    return dict(records.decodes("b", rows))


def test_every_hot_topic_has_its_block() -> None:
    for topic in (records.TX_PULSE, records.RX_SPIKE, records.RX_DECODES, records.MEDIUM):
        assert blocks.schema_of(topic) is not None
    assert blocks.schema_of(records.trace_topic("u-1")) is blocks.TRACE
    assert blocks.schema_of(records.UNIT_DECISION) is None


def test_a_pulse_block_holds_each_pulse_as_sent() -> None:
    pulses = _pulses()
    record = pulse_blocks.pulse_block_of(pulses, TAU)
    data = blocks.encode_record(blocks.PULSE, record)
    back = blocks.decode_record(blocks.PULSE, data, "test")
    assert pulse_blocks.pulse_rows(back) == pulses
    assert back["t"] == pulses[-1]["t"]


def test_a_pulse_block_is_canonical_whatever_order_its_pulses_came_in() -> None:
    pulses = _pulses()
    want = blocks.encode_record(blocks.PULSE, pulse_blocks.pulse_block_of(pulses, TAU))
    for seed in range(5):
        shuffled = list(pulses)
        random.Random(seed).shuffle(shuffled)
        record = pulse_blocks.pulse_block_of(shuffled, TAU)
        assert blocks.encode_record(blocks.PULSE, record) == want


def test_decodes_spikes_medium_and_trace_round_trip() -> None:
    decodes = _decodes()
    back = blocks.decode_record(blocks.DECODE, blocks.encode_record(blocks.DECODE, decodes), "t")
    assert [dict(r) for r in decode_rows(back)] == [
        dict(r) for r in decode_rows(decodes)
    ]
    spikes = records.spikes(["b", "a"], TAU, np.array([3, 3, 7]), np.array([0, 1, 0]), ["x", "y"])
    back = blocks.decode_record(blocks.SPIKE, blocks.encode_record(blocks.SPIKE, spikes), "t")
    assert back["units"] == ["a", "b"] and "unit" not in back
    assert back["samples"].tolist() == [3, 3, 7] and back["names"] == ["x", "y"]
    medium = records.medium_window(4, 0.4, 1e3, [0.0, 1.5, -2.0])
    back = blocks.decode_record(blocks.MEDIUM, blocks.encode_record(blocks.MEDIUM, medium), "t")
    assert back["window"] == 4 and back["samples"].tolist() == [0.0, 1.5, -2.0]
    trace = records.trace("a", 12, 0.012, [0.1, 0.2], [0.3, 0.4])
    back = blocks.decode_record(blocks.TRACE, blocks.encode_record(blocks.TRACE, trace), "t")
    assert back["y"].tolist() == [0.1, 0.2] and back["sample"] == 12


def test_the_protobuf_library_reads_each_block_from_its_descriptor() -> None:
    """What Foxglove does: the message class from the channel's schema data alone."""
    record = pulse_blocks.pulse_block_of(_pulses(), TAU)
    data = blocks.encode_record(blocks.PULSE, record)
    message = library_class(blocks.PULSE).FromString(data)
    assert list(message.sample) == list(record["sample"])
    assert list(message.codes) == record["codes"]
    assert message.SerializeToString() == data  # the library writes the same bytes
    decoded = library_class(blocks.DECODE).FromString(
        blocks.encode_record(blocks.DECODE, _decodes())
    )
    as_json = json_format.MessageToDict(decoded)
    assert as_json["unit"] == "b" and as_json["accepted"] == [True, False]


@pytest.mark.parametrize(
    ("schema", "block", "error"),
    [
        (blocks.DECODE, {"unit": "b", "names": ["a"], "sender": np.array([0, 5], "u4"),
                         "addressee": np.array([0, 0], "u4"), "channel": np.array([0, 0], "u4"),
                         "kind": np.array([0, 0], "u4"), "code": np.array([0, 0], "u4"),
                         "kinds": ["id"], "codes": ["x"], "turn": np.array([0, 0], "i4"),
                         "margin": np.zeros(2), "times": np.zeros(2),
                         "accepted": np.zeros(2, bool)},
         "sender 5 is no index into its 1 names"),
        (blocks.SPIKE, {"unit": "a", "units": ["a", "b"]}, "not two or more unit names alone"),
        (blocks.SPIKE, {"units": ["a", "a"]}, "not two or more unit names alone"),
        (blocks.SPIKE, {"samples": np.array([1], "i8"), "channel": np.array([0], "u4"),
                        "names": ["x"]}, "no unit"),
        (blocks.PULSE, {"tau": -1.0}, "tau -1.0 is not a sample period"),
        (blocks.DECODE, {"units": ["a"]}, "not two or more unit names alone"),
        (blocks.DECODE, {"unit": "a", "units": ["a", "b"]}, "not two or more unit names alone"),
        (blocks.DECODE, {"unit": "b", "turn": np.array([1], "i4")}, "table 'rows'"),
    ],
)  # fmt: skip
def test_a_hostile_block_is_one_line_naming_its_field(schema, block, error) -> None:
    with pytest.raises(RgtbusError, match=f"^log: message on x: {schema.name}: ") as e:
        blocks.decode_record(schema, encode(schema, block), "log: message on x")
    assert error in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize(
    ("schema", "block", "error"),
    [
        (blocks.MEDIUM, {"samples": np.array([1.0, np.nan])}, "samples holds a value that is not"),
        (blocks.DECODE, {"unit": "b", "t": np.inf}, "t holds a value that is not a finite"),
        (blocks.DECODE, {"unit": "b", "t": 1e12}, "t holds a time outside"),
        (blocks.SPIKE, {"unit": "b", "samples": np.array([-1], "i8"),
                        "channel": np.zeros(1, "u4"), "names": ["x"]}, "samples holds an index"),
        (blocks.PULSE, {"tau": 1e300}, "tau 1e+300 is not a sample period"),
        (blocks.PULSE, {"tau": 0.5, "channels": ["x"], "omegas": np.ones(1),
                        "names": ["a"], "kinds": ["id"], "codes": ["id"],
                        **{c: np.zeros(1, "u4") for c in ("channel", "kind", "code", "sender",
                                                          "addressee", "block")},
                        "sample": np.array([2**52], "i8"), "magnitude": np.ones(1),
                        "message": np.zeros(1, "i8")}, "is beyond"),
    ],
)  # fmt: skip
def test_a_block_out_of_every_reader_s_range_is_refused(schema, block, error) -> None:
    """Numbers no run writes, and past which a reader's arithmetic (times to integer ns,
    samples to times) would overflow or lose exactness: refused as the block is read."""
    with pytest.raises(RgtbusError, match=f"^x: {schema.name}: ") as e:
        blocks.decode_record(schema, encode(schema, block), "x")
    assert error in str(e.value), e.value


def test_a_record_of_names_that_are_not_names_is_refused_when_written() -> None:
    for units in ("ab", [1, 2]):
        record = {"units": units, "t": 0.0, "sample": 0, "samples": [0], "channel": [0],
                  "names": ["x"]}  # fmt: skip
        with pytest.raises(RgtbusError, match=r"units: .* is not a list of names"):
            blocks.encode_record(blocks.SPIKE, record)
    with pytest.raises(RgtbusError, match="unit 7 is not a name"):
        blocks.encode_record(blocks.TRACE, records.trace(7, 1, 0.1, [0.0], [0.0]))  # type: ignore[arg-type]


def test_a_block_claiming_more_rows_than_any_run_writes_is_refused_unread() -> None:
    # a packed column announcing 2^24 + 1 doubles, with the bytes behind it missing
    data = b"\x62" + bytes([0x88, 0x80, 0x80, 0x40]) + b"\0" * 8
    with pytest.raises(RgtbusError, match=r"announced|more than"):
        blocks.decode_record(blocks.DECODE, data, "x")


def test_a_record_the_block_cannot_hold_is_refused_when_written() -> None:
    with pytest.raises(RgtbusError, match=r"rgtbus\.MediumBlock"):
        blocks.encode_record(blocks.MEDIUM, {"window": 1, "t": 0.0, "sample_rate": 1.0})
    with pytest.raises(RgtbusError, match="samples"):
        blocks.encode_record(
            blocks.MEDIUM, {"window": 1, "t": 0.0, "sample_rate": 1.0, "samples": ["x"]}
        )


def test_which_pulses_a_block_holds_does_not_depend_on_the_order_they_were_logged_in() -> None:
    """A sender plans a late choice before sends it planned earlier (logged as planned), or
    logs each pulse as it goes on air: the same blocks either way, each let go once the
    sender's own records are past it."""

    def pulse(k: int) -> records.PulseRecord:
        ref = records.message_ref(k // 100, "id", "id", "u1", "u2")
        return records.pulse("u1", "u2", 10.0, 0.4, 0.005, k, ref)

    got = []
    for order in ((5261, 7094, 5517, 5817), (5261, 5517, 5817, 7094)):
        held = pulse_blocks.PulseBlocks(0.005, 1000)
        for k in order:
            held.add(pulse(k))
        out = held.before(6000) + held.end()  # a record of u1's at sample 6000, then its end
        got.append([list(b["sample"]) for b in out])
    assert got[0] == got[1] == [[5261, 5517, 5817], [7094]]
