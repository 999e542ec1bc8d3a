"""A run's merged log is the same whatever the split of its units into processes (issue 51,
item 3): the messages (topic, log time, bytes) of one process's log merged, of a launch in
three processes and of a launch of one process a unit are equal, byte for byte. What differed
was ``/rx/spike``: units of one process write a block they heard alike once, naming them all;
the merge makes the records of one block from several processes one record so
(``rgtbus.telemetry.merge.shared_blocks``)."""

from __future__ import annotations

import io
import subprocess
import sys
from collections import Counter
from pathlib import Path

import orjson
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from rgtbus.telemetry.blocks import SPIKE, descriptor, encode_record, units_head, units_head_bytes
from rgtbus.telemetry.merge import MergeResult, merge_logs, shared_blocks
from rgtbus.telemetry.records import RX_SPIKE, spikes
from rgtbus.telemetry.scan import scan_log
from rgtbus.telemetry.version import FORMAT_RECORD, format_metadata

ROOT = Path(__file__).parent.parent
EXE = [sys.executable, "-m", "rgtbus"]

# odd names, not in sorted order: the one-process log's shared records name them sorted
UNITS = ["zulu", "Alpha", "mike_2", "b_c", "x9", "echo"]


def _scenario(folder: Path) -> Path:
    path = folder / "odd.toml"
    path.write_text(
        f"""name = "odd"
seed = 11
units = {orjson.dumps(UNITS).decode()}
actions = ["go", "stay"]
codebook = {{ kind = "generated", pulses = 4 }}
frequencies = "auto"
[protocol]
schedule = "concurrent"
[relations]
policy = "cograph"
[influences]
policy = "random"
"""
    )
    return path


def messages(path: Path) -> Counter[tuple[str, int, bytes]]:
    """A log's messages as (topic, log time, bytes), read by the standard reader."""
    out: Counter[tuple[str, int, bytes]] = Counter()
    with open(path, "rb") as f:
        for _, channel, m in make_reader(f).iter_messages():
            out[channel.topic, m.log_time, bytes(m.data)] += 1
    return out


def merged(path: Path, *inputs: Path) -> Path:
    with open(path, "wb") as out:
        merge_logs([scan_log(p) for p in inputs], out)
    return path


def _rgtbus(*args: str) -> None:
    proc = subprocess.run([*EXE, *args], capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stderr


def test_one_process_three_and_one_a_unit_merge_to_the_same_messages(tmp_path):
    scenario = _scenario(tmp_path)
    one = tmp_path / "one.mcap"
    _rgtbus("run", str(scenario), "--log", str(one), "--quiet")
    logs = {"one process": messages(merged(tmp_path / "one-merged.mcap", one))}
    for procs in ("3", "6"):
        folder = tmp_path / f"procs{procs}"
        _rgtbus("launch", str(scenario), "--procs", procs, "--log-dir", str(folder), "-q")
        logs[f"{procs} processes"] = messages(folder / "run.mcap")
    reference = logs.pop("one process")
    heads = [units_head(m[2]) for m in reference if m[0] == RX_SPIKE]
    assert None not in heads  # every spike block as rgtbus writes it
    shared = [units for units, _ in heads if len(units) > 1]
    assert shared, "no block heard alike: the test shows nothing"
    assert all(units == ["Alpha", "b_c", "echo", "mike_2", "x9", "zulu"] for units in shared)
    for layout, got in logs.items():
        assert got == reference, (layout, _differences(got, reference))
    # the one-process log itself differs at most by records of its units' last blocks,
    # each cut where its unit was done: alike parts one a unit, one record once merged
    direct = messages(one)
    assert {k for k in direct if k[0] != RX_SPIKE} == {k for k in reference if k[0] != RX_SPIKE}


def _differences(got: Counter, want: Counter) -> dict[str, int]:
    return {
        topic: sum(((got - want) + (want - got)).get(k, 0) for k in (got | want) if k[0] == topic)
        for topic in {k[0] for k in got | want}
        if any(k[0] == topic for k in (got - want) + (want - got))
    }


def _entry(t: int, source: int, cid: int, data: bytes) -> tuple[int, int, int, int, int, bytes]:
    return (t, source, 0, cid, t, data)


def _spike(unit: str | list[str], samples: list[int], names: list[str]) -> bytes:
    import numpy as np

    record = spikes(unit, 0.005, np.array(samples), np.arange(len(samples)), names)
    return encode_record(SPIKE, record)


# a block of spikes not as rgtbus writes it: one unit under ``units`` (two or more go there)
_ONE_OF_UNITS = units_head_bytes(["a"], one=False) + units_head(_spike("a", [1], ["x"]))[1]


@pytest.mark.parametrize("names", [["a", "b", "c", "d"], ['q"],"', "b\\", "]", "ü,"]])
def test_records_of_one_block_from_several_processes_are_one_record(names):
    a, b, c, d = names
    block = ([3, 5], ["x", "y"])
    entries = [
        _entry(10, 0, 1, _spike(a, *block)),
        _entry(10, 1, 1, _spike([c, b], *block)),  # another process's shared record
        _entry(10, 1, 2, b'{"unit":"a","t":1}'),  # another topic's channel: left alone
        _entry(10, 2, 1, _spike(d, [3, 6], ["x", "y"])),  # other spikes: its own record
        _entry(10, 2, 1, _spike(a, *block)),  # the same record twice: its unit once
        _entry(11, 2, 1, _spike(b, *block)),  # another time: its own record
        _entry(12, 0, 1, b"\n\x05a"),  # no block (a unit's name past its end): as it is
        _entry(12, 1, 1, _ONE_OF_UNITS),  # not as rgtbus writes it: as it is
        _entry(12, 1, 1, _ONE_OF_UNITS),
    ]
    res = MergeResult()
    out = list(shared_blocks(entries, {1}, res))
    assert res.joined == 2
    assert [e[5] for e in out] == [
        _spike(sorted([a, b, c]), *block),
        b'{"unit":"a","t":1}',
        _spike(d, [3, 6], ["x", "y"]),
        _spike(b, *block),
        b"\n\x05a",
        _ONE_OF_UNITS,
        _ONE_OF_UNITS,
    ]
    assert out[0][:4] == entries[0][:4] and out[1] == entries[2]  # where the first one was


def test_a_merge_of_hand_written_spike_records_reads_back():
    """Through merge_logs: two inputs' records of one block are one record, which every
    reader reads as the spikes of both units."""
    inputs = []
    for unit in ("b", "a"):
        buf = io.BytesIO()
        w = Writer(buf)
        w.start()
        w.add_metadata(FORMAT_RECORD, format_metadata())
        sid = w.register_schema(SPIKE.name, "protobuf", descriptor(SPIKE.name))
        cid = w.register_channel(RX_SPIKE, "protobuf", sid)
        w.add_message(cid, 5_000_000, _spike(unit, [1], ["x"]), 5_000_000)
        w.finish()
        buf.seek(0)
        inputs.append(scan_log(buf))
    out = io.BytesIO()
    res = merge_logs(inputs, out)
    assert (res.messages, res.joined) == (1, 1)
    out.seek(0)
    (_, _, m), *rest = make_reader(out).iter_messages()
    assert not rest and m.data == _spike(["a", "b"], [1], ["x"])
