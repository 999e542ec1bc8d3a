"""``GroupLog``: the records the units of one process share (telemetry/group_log.py)."""

from __future__ import annotations

from typing import Any

import numpy as np

from rgtbus.telemetry import records
from rgtbus.telemetry.blocks import DECODE, encode_record
from rgtbus.telemetry.group_log import GroupLog
from rgtbus.telemetry.pulse_blocks import pulse_rows

TAU = 0.005
SPAN = 1000  # samples a 5 s block at TAU
TABLES = (("a", "b", "c"), ("id", "payload"), ("alliance", "id"))


class Sink:
    def __init__(self) -> None:
        self.written: list[tuple[str, int, Any]] = []

    def write(self, topic: str, message: Any, t_ns: int) -> None:
        self.written.append((topic, t_ns, message))


def piece(margins: list[float], *, wide: bool = False, t0: float = 1.0) -> list[Any]:
    """A block's decodes as a unit hands them (``records.DECODE_COLUMNS``)."""
    n = len(margins)
    ints = np.int64 if wide else np.int32
    return [
        np.arange(n, dtype=ints),  # turn
        np.zeros(n, dtype=ints),  # sender
        np.ones(n, dtype=ints),  # addressee
        np.ones(n, dtype=ints),  # channel
        np.zeros(n, dtype=ints),  # kind
        np.ones(n, dtype=ints),  # code
        np.asarray(margins),
        t0 + np.arange(n) * 0.5,  # times
        np.ones(n, dtype=bool),
    ]


def test_decodes_units_made_alike_are_one_record_naming_them_once_every_unit_is_past():
    sink = Sink()
    group = GroupLog(sink, TAU, ["c", "a", "b"])
    group.decodes(0, 0, piece([0.5, 0.25]), TABLES)
    group.decodes(1, 0, piece([0.5, 0.25], wide=True), TABLES)  # the same numbers
    group.decodes(2, 0, piece([0.5, -0.0]), TABLES)  # another margin: its own record
    for member in (0, 1):
        group.decoded_to(member, 1)
    assert sink.written == []  # b is not past block 0 yet
    group.decoded_to(2, 1)
    got = [m for _, _, m in sink.written]
    assert [m.get("units") or m["unit"] for m in got] == [["a", "c"], "b"]
    assert all(t == round(m["t"] * 1e9) for _, t, m in sink.written)
    # the bytes after the units are a function of the decodes alone: what merge compares
    one = encode_record(DECODE, got[0])
    alone = encode_record(DECODE, records.decodes_of_columns("a", piece([0.5, 0.25]), TABLES))
    assert one.endswith(alone[len(b"\x0a\x01a") :])


def test_a_process_s_pulses_of_a_block_are_one_record_once_every_sender_is_past_it():
    sink = Sink()
    group = GroupLog(sink, TAU, ["a", "b"])
    for sender, samples in (("b", (40, 140, 1040)), ("a", (50, 60, 70))):
        ref = records.message_ref(0, "id", "id", sender, "a")
        group.pulses.add_send(samples, (0.5, 0.4, 0.3), "a", 6.28, ref)
    group.pulses_passed(0, 2 * SPAN)
    assert sink.written == []  # b's clock is not past the first block
    group.pulses_passed(1, SPAN)
    (topic, t_ns, block), = sink.written
    rows = pulse_rows(block)
    assert topic == "/tx/pulse" and t_ns == round(140 * TAU * 1e9)
    assert [(p["sample"], p["unit"]) for p in rows] == [
        (40, "b"), (50, "a"), (60, "a"), (70, "a"), (140, "b")
    ]  # fmt: skip
    group.end(1)  # b is done: its pulse of the next block goes out with it
    assert [p["sample"] for p in pulse_rows(sink.written[-1][2])] == [1040]
