"""Damaged, foreign and empty MCAP logs: corruption is reported as
corruption (never as truncation), and ``replay``/``merge`` refuse it with exit 2 naming the
file; a log that merely ends early still reads up to its cut, and ``replay`` exits 3."""

from __future__ import annotations

import io
import json
import struct
from functools import cache
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from rgtbus.cli import main
from rgtbus.errors import RgtbusError
from rgtbus.telemetry import (
    McapRecorder,
    blocks,
    read_log,
    require_run_log,
    scan_log,
    schema_for,
    topics,
)
from rgtbus.telemetry.codec import encode
from rgtbus.telemetry.merge import merge_logs
from rgtbus.telemetry.message_json import log_message
from rgtbus.telemetry.recorder import MCAP_MAGIC
from rgtbus.telemetry.version import FORMAT_RECORD, format_metadata

ROOT = Path(__file__).resolve().parent.parent.parent
SCENARIO = (ROOT / "scenarios" / "example2.toml").read_text()


@cache
def rgtbus_log(compression: str = "none") -> bytes:
    """A small rgtbus log: the run metadata, 300 medium windows in ~10 chunks, a log line."""
    buf = io.BytesIO()
    with McapRecorder(buf, compression=compression, chunk_size=4096) as rec:
        rec.metadata("scenario", {"name": "example2", "path": "example2.toml", "text": SCENARIO})
        rec.metadata("run", {"seed": "2", "version": "0.1.0", "bus": "memory"})
        for i in range(300):
            samples = [round(0.001 * ((i * 20 + k) % 97), 6) for k in range(20)]
            rec.write(
                "/medium",
                {"window": i, "t": i * 0.1, "sample_rate": 200.0, "samples": samples},
                i * 100_000_000,
            )
        rec.log("info", "done", 300 * 100_000_000)
    return buf.getvalue()


def chunk_offsets(data: bytes) -> list[tuple[int, int]]:
    """(start, length) of every chunk record, from the file's own index."""
    summary = make_reader(io.BytesIO(data)).get_summary()
    assert summary is not None
    return [(c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes]


def flip(data: bytes, at: int) -> bytes:
    return data[:at] + bytes([data[at] ^ 0x01]) + data[at + 1 :]


def cli(capsys, *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def write(tmp_path: Path, data: bytes, name: str) -> Path:
    path = tmp_path / name
    path.write_bytes(data)
    return path


def refused_by_replay_and_merge(tmp_path: Path, capsys, data: bytes, needle: str) -> str:
    """replay (every mode) and merge exit 2 with one line naming the file and the damage."""
    path = write(tmp_path, data, "bad.mcap")
    for extra in ([], ["--json"], ["--verify"]):
        code, out, err = cli(capsys, "replay", path, *extra)
        assert code == 2 and out == "", (extra, err)
        assert err.count("\n") == 1 and str(path) in err and needle in err, err
    good = write(tmp_path, rgtbus_log(), "good.mcap")
    merged = tmp_path / "merged.mcap"
    code, out, err = cli(capsys, "merge", good, path, "-o", merged)
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert str(path) in err and needle in err, err
    assert not merged.exists() and not (tmp_path / "merged.mcap.part").exists()
    return err


# -- the clean log -------------------------------------------------------------------------


def test_clean_log_scans_clean_with_crcs_written():
    data = rgtbus_log()
    raw = scan_log(io.BytesIO(data))
    assert not raw.corrupt and not raw.truncated and raw.library.startswith("foxglove-sdk")
    assert len(raw.messages) == 301 and len(chunk_offsets(data)) > 5
    # a data section CRC is written (it covers the metadata, which no chunk CRC does)
    data_end = data.rindex(b"\x0f\x04\x00\x00\x00\x00\x00\x00\x00")  # DataEnd, length 4
    assert struct.unpack_from("<I", data, data_end + 9)[0] != 0


# -- corruption ------------------------------------------------------------------------------


def test_flipped_byte_in_a_chunk_is_a_crc_mismatch(tmp_path, capsys):
    data = rgtbus_log()
    start, length = chunk_offsets(data)[3]
    bad = flip(data, start + length - 40)  # inside the records, uncompressed
    raw = scan_log(io.BytesIO(bad))
    assert raw.corrupt and not raw.truncated
    assert raw.corruption.startswith(f"<stream>: corrupt log: chunk at byte {start} (log time ")
    assert "CRC mismatch (stored 0x" in raw.corruption
    assert 0 < len(raw.messages) < 301  # read up to the damage
    with pytest.raises(RgtbusError, match="corrupt log: chunk at byte"):
        read_log(io.BytesIO(bad))
    err = refused_by_replay_and_merge(tmp_path, capsys, bad, f"chunk at byte {start}")
    assert "CRC mismatch" in err and "not merged" in err


def test_flipped_byte_in_a_compressed_chunk_is_corruption():
    data = rgtbus_log("zstd")
    start, length = chunk_offsets(data)[2]
    raw = scan_log(io.BytesIO(flip(data, start + length // 2)))
    assert raw.corrupt and not raw.truncated and f"chunk at byte {start}" in raw.corruption


def test_flipped_byte_in_the_metadata_is_a_data_section_crc_mismatch(tmp_path, capsys):
    data = rgtbus_log()
    at = data.index(b"Example 2: transmitted influences")
    bad = data[:at] + b"Example 3" + data[at + 9 :]  # the scenario text, outside any chunk
    raw = scan_log(io.BytesIO(bad))
    assert raw.corrupt and "data section CRC mismatch" in raw.corruption
    refused_by_replay_and_merge(tmp_path, capsys, bad, "data section CRC mismatch")


def test_flipped_byte_in_the_summary_is_a_summary_crc_mismatch():
    data = rgtbus_log()
    summary_start = struct.unpack_from("<Q", data, len(data) - 8 - 29 + 9)[0]
    raw = scan_log(io.BytesIO(flip(data, summary_start + 30)))
    assert raw.corrupt and not raw.truncated
    assert f"summary section (from byte {summary_start}): CRC mismatch" in raw.corruption


def test_trailing_garbage_after_the_footer(tmp_path, capsys):
    bad = rgtbus_log() + b"garbage!!"
    raw = scan_log(io.BytesIO(bad))
    assert raw.corruption == (
        "<stream>: corrupt log: 9 bytes of trailing garbage after the footer "
        "(the log itself is complete)"
    )
    assert len(raw.messages) == 301 and not raw.truncated
    refused_by_replay_and_merge(tmp_path, capsys, bad, "9 bytes of trailing garbage")


def test_bad_closing_magic_is_not_truncation():
    data = rgtbus_log()
    raw = scan_log(io.BytesIO(data[:-8] + b"NOTMAGIC"))
    assert raw.corrupt and "bad magic after the footer" in raw.corruption


def test_damaged_record_length_in_a_finished_file_is_not_truncation():
    data = rgtbus_log()
    header_len = struct.unpack_from("<Q", data, 9)[0]
    second = 8 + 9 + header_len  # the record after the header (the first metadata)
    bad = data[: second + 1] + struct.pack("<Q", len(data) * 4) + data[second + 9 :]
    raw = scan_log(io.BytesIO(bad))
    assert raw.corruption == (
        f"<stream>: corrupt log: record at byte {second} runs past the end of a file that ends "
        "with MCAP's closing magic (a damaged record length)"
    )


# -- truncation stays truncation -------------------------------------------------------------


def test_truncated_log_reads_to_its_cut_and_replay_exits_3(tmp_path, capsys):
    data = rgtbus_log()
    cut = data[: len(data) // 2]
    raw = scan_log(io.BytesIO(cut))
    assert raw.truncated and not raw.corrupt and 0 < len(raw.messages) < 301
    path = write(tmp_path, cut, "cut.mcap")
    code, out, err = cli(capsys, "replay", path)
    assert code == 3 and "NOTE:" in out and "log truncated" in out
    code, out, err = cli(capsys, "replay", path, "--json")
    assert code == 3 and json.loads(out)["truncated"] and "log truncated" in err
    code, _, err = cli(capsys, "merge", path, "-o", tmp_path / "m.mcap")
    assert code == 0 and "warning" in err and "truncated" in err


class _Snapshots(io.BytesIO):
    """A file as a killed writer leaves it after each of its writes (seeks included)."""

    def __init__(self) -> None:
        super().__init__()
        self.after_each_write: list[bytes] = []

    def write(self, data) -> int:  # type: ignore[no-untyped-def, override]
        n = super().write(data)
        self.after_each_write.append(self.getvalue())
        return n


def test_a_writer_killed_after_any_of_its_writes_leaves_a_cut_log_never_a_corrupt_one():
    """foxglove-sdk's writer streams a chunk and patches its lengths when it finishes it: a
    unit killed in between left a chunk whose length was the placeholder, which rgtbus read as
    cut and every other reader refused (``RecordLengthLimitExceeded``). Now the file grows only
    at a flush, by finished chunks and a trailer the next flush overwrites: every state a
    killed writer can leave reads as cut (rgtbus) and as a whole file (mcap's readers)."""
    stream = _Snapshots()
    with McapRecorder(stream, compression="zstd", chunk_size=4096, flush_wall=3600.0) as rec:
        rec.metadata("scenario", {"name": "example2", "path": "example2.toml", "text": SCENARIO})
        for i in range(120):
            rec.write("/medium", {"window": i, "t": i * 0.1, "sample_rate": 200.0,
                                  "samples": [0.001 * i] * 20}, i * 100_000_000)  # fmt: skip
            if i % 7 == 6:
                rec.flush()
    states = stream.after_each_write[:-1]  # the last is the finished file
    assert len(states) > 15
    read = 0
    for k, data in enumerate(states):
        raw = scan_log(io.BytesIO(data))
        assert not raw.corrupt, (k, raw.corruption)
        assert raw.truncated, k
        assert len(raw.messages) >= read, k  # nothing read before is lost by a later write
        read = len(raw.messages)
        standard = list(make_reader(io.BytesIO(data)).iter_messages())  # no error
        assert len(standard) == len(raw.messages), k
    assert read >= 119


# -- not an rgtbus run log ---------------------------------------------------------------------


def foreign_log() -> bytes:
    buf = io.BytesIO()
    w = Writer(buf, compression=CompressionType.NONE)
    w.start(profile="ros1", library="someone-else 2.0")
    sid = w.register_schema("std_msgs/String", "ros1msg", b"string data")
    cid = w.register_channel("/chatter", "ros1", sid)
    for i in range(5):
        w.add_message(cid, i * 1000, b"\x05\x00\x00\x00hello", i * 1000)
    w.add_metadata("calibration", {"k": "v"})
    w.finish()
    return buf.getvalue()


def test_foreign_mcap_is_refused(tmp_path, capsys):
    data = foreign_log()
    raw = scan_log(io.BytesIO(data))
    assert not raw.corrupt and not raw.truncated and raw.library == "someone-else 2.0"
    err = refused_by_replay_and_merge(tmp_path, capsys, data, "not an rgtbus run log")
    assert err.endswith(
        "not an rgtbus run log: no scenario or run metadata (written by 'someone-else 2.0')"
        "; not merged\n"
    )


def test_header_only_mcap_is_refused(tmp_path, capsys):
    buf = io.BytesIO()
    w = Writer(buf)
    w.start(library="rgtbus 0.1.0")
    only_header = buf.getvalue()  # what a writer killed at once leaves
    w.finish()
    for data in (only_header, buf.getvalue()):
        raw = scan_log(io.BytesIO(data))
        assert raw.header_only and not raw.corrupt
        with pytest.raises(RgtbusError, match="holds only an MCAP header"):
            require_run_log(raw)
        refused_by_replay_and_merge(
            tmp_path, capsys, data, "holds only an MCAP header (written by 'rgtbus 0.1.0')"
        )


def test_merge_logs_refuses_a_corrupt_input_in_the_library_too():
    good = scan_log(io.BytesIO(rgtbus_log()))
    bad = scan_log(io.BytesIO(rgtbus_log() + b"x"))
    with pytest.raises(RgtbusError, match=r"trailing garbage .*; not merged$"):
        merge_logs([good, bad], io.BytesIO())


def test_not_mcap_at_all_is_still_not_mcap():
    for data in (b"", b"\x89MC", b"hello world, no mcap here", MCAP_MAGIC):
        with pytest.raises(RgtbusError, match="not an MCAP file"):
            scan_log(io.BytesIO(data))


@pytest.mark.slow  # a few seconds: CI's slow pass (the fast suite stays near 3 min)
def test_no_flipped_byte_reads_as_clean_or_as_truncation():
    # CRCs cover every byte of an rgtbus log: chunks, the data section (header, metadata,
    # indexes), the summary and footer; the magic is checked. (All 23k positions pass; this
    # samples the middle to stay quick and takes both ends whole.)
    data = rgtbus_log("zstd")
    positions = [*range(120), *range(120, len(data) - 400, 29), *range(len(data) - 400, len(data))]
    for at in positions:
        try:
            raw = scan_log(io.BytesIO(flip(data, at)))
        except RgtbusError as e:  # nothing read: the magic, or the header itself
            want = "not an MCAP file (bad magic)" if at < 8 else "header record is damaged"
            assert want in str(e), (at, e)
            continue
        assert raw.corrupt and not raw.truncated, at


def test_a_log_whose_first_record_is_no_header_is_corrupt():
    buf = io.BytesIO()
    w = Writer(buf, enable_crcs=False)  # no CRC to catch it: the structure must
    w.start(library="rgtbus 0.1.0")
    w.add_metadata("run", {"seed": "1"})
    w.finish()
    data = buf.getvalue()
    raw = scan_log(io.BytesIO(data[:8] + b"\x00" + data[9:]))  # the header's opcode: unknown
    assert raw.corruption == (
        "<stream>: corrupt log: record at byte 8: the first record is not a Header"
    )


def test_a_log_is_written_as_the_run_goes():
    """A process killed outright loses at most 4096 messages, or ``flush_seconds`` of log time
    when asked (wall time: ``test_a_log_is_flushed_by_wall_time_too``): what the recorder was
    given before that is on the stream, readable, without close(). By default simulated time
    finishes no chunk (a long run would flush a chunk a second)."""
    for flush_seconds, least in ((1.0, 40 - 11), (None, 0)):
        buf = io.BytesIO()
        rec = McapRecorder(buf, flush_seconds=flush_seconds, flush_wall=3600)
        for k in range(40):  # one message every 0.1 s of log time
            t = k * 100_000_000
            rec.write("/log", log_message("info", f"line {k}", t, "a"), t)
        got = read_log(io.BytesIO(buf.getvalue()))  # never closed: read as truncated
        assert got.truncated
        if flush_seconds is None:
            assert got.messages == []  # all in the chunk in progress
        else:
            assert len(got.messages) >= least
    buf2 = io.BytesIO()
    rec2 = McapRecorder(buf2, flush_wall=3600)
    for k in range(5000):  # all at one instant: the message count bounds what is held back
        rec2.write("/log", log_message("info", f"line {k}", 0, "a"), 0)
    assert len(read_log(io.BytesIO(buf2.getvalue())).messages) >= 5000 - 4096


@pytest.mark.parametrize("extra", [[], ["--verify"], ["--json"], ["--csv", "CSV"]])
def test_messages_that_break_their_schema_are_named_not_a_traceback(tmp_path, capsys, extra):
    """Whole CRCs, but messages written by hand without their fields (a JSON record, and a
    block, which rgtbus's recorder would refuse to write): exit 2, one line."""
    path = tmp_path / "hand.mcap"
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="", library="by hand")
        w.add_metadata(FORMAT_RECORD, format_metadata())
        w.add_metadata("scenario", {"name": "example2", "path": "example2.toml", "text": SCENARIO})
        w.add_metadata("run", {"seed": "2", "version": "0.1.0", "bus": "memory"})
        for topic, t_ns, data in (
            ("/rx/decode", 1_500_000_000, b'{"unit": "a"}'),
            ("/tx/pulse", 2_000_000_000, encode(blocks.PULSE, {"t": 2.0})),
        ):
            name = schema_for(topic)
            if blocks.schema_of(topic) is None:
                sid = w.register_schema(name, "jsonschema", topics.schema_bytes(name))
                cid = w.register_channel(topic, "json", sid)
            else:
                sid = w.register_schema(name, "protobuf", blocks.descriptor(name))
                cid = w.register_channel(topic, "protobuf", sid)
            w.add_message(cid, t_ns, data, t_ns)
        w.finish()
    argv = [str(tmp_path / "CSV") if a == "CSV" else a for a in extra]
    code, _out, err = cli(capsys, "replay", path, *argv)
    assert code == 2 and "Traceback" not in err and err.count("\n") == 1, err
    # each topic is checked as a reader first takes it: either bad message may be named (a
    # /tx/pulse block's missing fields read as their defaults: its sample period is 0)
    named = ("message on /rx/decode at t = 1.500 s breaks rgtbus.Decode",
             "message on /tx/pulse at t = 2.000 s: rgtbus.PulseBlock: tau 0.0 is not a "
             "sample period")  # fmt: skip
    assert any(n in err for n in named), err
