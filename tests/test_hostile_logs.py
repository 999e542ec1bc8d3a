"""No log can trick a reader (issue 50, item 3): logs with valid CRCs (written with mcap's own
writer) whose messages nest deeper than any reader walks (JSON, or protobuf groups in a hot
topic's block, which is flat), whose text holds terminal escapes, controls and bidi
overrides, whose Statistics record lies, or that hold two ``/run`` records. Every reader
answers in one line naming the file, topic and time (exit 2), or reads the log; nothing it
prints holds a character a terminal acts on; what a log contradicts about itself is said,
in ``log_info``'s ``problems`` and in ``rgtbus info``'s text.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import struct
import tomllib
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import orjson
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

import rgtbus
from rgtbus.cli import main
from rgtbus.errors import RgtbusError
from rgtbus.telemetry.log_check import verified_by_crcs
from rgtbus.telemetry.logtools import log_info, stored_scenario
from rgtbus.telemetry.untrusted import MAX_DEPTH, depth_error, printable, text_depth

ROOT = Path(__file__).resolve().parent.parent
BIDI = set("\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069\u200e\u200f\u061c")
HOSTILE = "x\x1b[2J\x1b]0;pwned\x07\rFAKE LINE\b\u202eevil\x9b\x85\x7f\ty"
Held = tuple[str, int, bytes]  # topic, log time, data


@pytest.fixture(scope="module")
def gate(tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("hostile") / "gate.mcap"
    rgtbus.run(ROOT / "scenarios" / "gate.toml", log=path)
    return path.read_bytes()


def rebuilt(
    src: bytes,
    edit: Callable[[list[Held], list[tuple[str, dict[str, str]]]], None] = lambda h, m: None,
    stats: Callable[[Any], None] | None = None,
) -> bytes:
    """``src`` with its messages and metadata changed by ``edit`` (in place), written anew
    with mcap's writer (CRCs valid); ``stats`` changes the Statistics record it writes."""
    reader = make_reader(io.BytesIO(src))
    summary = reader.get_summary()
    held = [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages()]
    metadata = [(r.name, dict(r.metadata)) for r in reader.iter_metadata()]
    edit(held, metadata)
    out = io.BytesIO()
    writer = Writer(out, compression=CompressionType.ZSTD)
    writer.start(profile="", library="hostile")
    schemas = {sid: writer.register_schema(s.name, s.encoding, s.data)
               for sid, s in summary.schemas.items()}  # fmt: skip
    channels = {c.topic: writer.register_channel(c.topic, c.message_encoding,
                                                 schemas[c.schema_id], c.metadata)
                for c in summary.channels.values()}  # fmt: skip
    for topic, t, data in held:
        if topic not in channels:
            channels[topic] = writer.register_channel(topic, "json", 0, {})
        writer.add_message(channels[topic], t, data, t)
    for name, values in metadata:
        writer.add_metadata(name, values)
    if stats is not None:
        stats(writer._Writer__statistics)  # type: ignore[attr-defined]  # the record it writes
    writer.finish()
    return with_crcs(out.getvalue())


def with_crcs(data: bytes) -> bytes:
    """``data`` (an MCAP file) with its data-section and summary CRCs written, as rgtbus's
    writer writes them (mcap's Python writer leaves the first 0): its summary is then read
    as vouched for, not scanned past."""
    out = bytearray(data)
    footer_at = len(out) - 8 - 29
    summary_start = struct.unpack_from("<Q", out, footer_at + 9)[0]
    data_end_at = (summary_start or footer_at) - 13
    assert out[data_end_at] == 0x0F  # DataEnd: opcode, length, CRC
    struct.pack_into("<I", out, data_end_at + 9, zlib.crc32(out[:data_end_at]))
    struct.pack_into("<I", out, footer_at + 25, zlib.crc32(out[data_end_at + 13 : footer_at + 25]))
    assert verified_by_crcs(io.BytesIO(bytes(out)))
    return bytes(out)


def replaced(topic: str, data: bytes) -> Callable[[list[Held], Any], None]:
    def edit(held: list[Held], metadata: Any) -> None:
        i = next(i for i, m in enumerate(held) if m[0] == topic)
        held[i] = (topic, held[i][1], data)

    return edit


def nested(n: int) -> bytes:
    return b"[" * n + b"]" * n


def run_cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))  # a traceback would fail the test here
    return code, out.getvalue(), err.getvalue()


def unsafe(text: str) -> list[str]:
    """Every character of ``text`` a terminal acts on (newlines and tabs aside)."""
    return [
        repr(c)
        for c in text
        if (ord(c) < 32 and c not in "\n\t") or 0x7F <= ord(c) <= 0x9F or c in BIDI
    ]


READERS: list[list[str]] = [
    ["info"], ["info", "--json"], ["cat"], ["scenario"], ["replay"], ["replay", "--json"],
    ["replay", "--verify"],
]  # fmt: skip


def groups(n: int) -> bytes:
    """A protobuf message of ``n`` groups opened one inside the other (field 100, wire type 3:
    proto2's nesting, which no block uses), never closed."""
    return bytes([0xA3, 0x06]) * n


@pytest.mark.parametrize(
    "topic, data, says",
    [
        ("/unit/decision", nested(100_000), "is not JSON: depth limit exceeded"),  # > orjson's
        ("/run", nested(100_000), "is not JSON: depth limit exceeded"),
        ("/log", nested(1020), f"nests deeper than {MAX_DEPTH} levels"),  # orjson reads it
        ("/run", nested(1020), f"nests deeper than {MAX_DEPTH} levels"),  # (Python can't)
        # a hot topic's block is flat: nesting in it is refused at its first level, unwalked
        ("/tx/pulse", groups(100_000),
         "rgtbus.PulseBlock: unknown field 100: wire type 3, which no block uses"),
        ("/rx/decodes", groups(100_000),
         "rgtbus.DecodeBlock: unknown field 100: wire type 3, which no block uses"),
        # JSON where a block belongs (a '[' is a group's tag too, of field 11)
        ("/tx/pulse", nested(100_000),
         "rgtbus.PulseBlock: field 'message': wire type 3, a column is packed (2)"),
    ],
    ids=["decision-json", "run-json", "log-depth", "run-depth", "pulse-groups",
         "decodes-groups", "pulse-json"],
)  # fmt: skip
def test_deep_nesting_is_refused_in_one_line_by_every_reader(gate, tmp_path, topic, data, says):
    path = tmp_path / "deep.mcap"
    path.write_bytes(rebuilt(gate, replaced(topic, data)))
    refused = 0
    for reader in READERS:
        code, out, err = run_cli(reader[0], str(path), *reader[1:])
        if code == 2:
            refused += 1
            assert err.count("\n") == 1 and str(path) in err and f"on {topic} at t = " in err, err
            assert says in err, err
            assert out == "" or reader == ["cat"]  # cat streams: the messages before it
        else:  # a reader that needs no such message reads the log
            assert code == 0 and reader[0] in ("info", "scenario", "replay"), (reader, err)
    # info needs /run, cat prints every message, replay --verify compares every one
    assert refused >= (4 if topic == "/run" else 2)
    # the API refuses it as the CLI does, when it reads the topic (a frame built from it, or
    # its messages: a log line or a decision record no frame needs is read when asked for)
    with pytest.raises(RgtbusError, match=re.escape(says)):
        log = rgtbus.open_log(path)
        log.summary(), log.transmissions(), log.decodes(), log.messages(topic)


def test_a_nested_value_within_the_limit_reads():
    deep = json.loads(nested(MAX_DEPTH))
    assert depth_error(deep) is None
    assert depth_error([deep]) == f"nests deeper than {MAX_DEPTH} levels"
    assert depth_error({"a": {"b": [1, {"c": []}]}}, limit=5) is None  # 5 levels
    assert depth_error({"a": {"b": [1, {"c": []}]}}, limit=4) is not None


def _walked_depth(value) -> int:
    if isinstance(value, dict | list):
        children = value.values() if isinstance(value, dict) else value
        return 1 + max((_walked_depth(v) for v in children), default=0)
    return 0


_JSON = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**62), 2**62) | st.text(alphabet='ab"\\[]{}\né'),
    lambda inner: st.lists(inner) | st.dictionaries(st.text(alphabet='k"\\[{}'), inner),
    max_leaves=30,
)


@settings(max_examples=300, deadline=None)
@given(_JSON)
def test_a_json_text_s_depth_from_its_bytes_is_its_depth(value):
    """``text_depth`` counts brackets outside strings (escaped quotes and backslashes in them,
    brackets in keys and values): what a walk of the decoded value finds, in any layout."""
    for data in (orjson.dumps(value), json.dumps(value, indent=1).encode(),
                 json.dumps(value, ensure_ascii=False).encode()):  # fmt: skip
        assert text_depth(data) == _walked_depth(value), data
    assert text_depth(nested(MAX_DEPTH + 1)) == MAX_DEPTH + 1


def test_printable_escapes_what_a_terminal_acts_on_and_keeps_letters():
    assert printable("Zürich 東京 αβγ café") == "Zürich 東京 αβγ café"
    text = printable(HOSTILE + "\n\u2028")
    assert unsafe(text) == [] and "\n" not in text and "\t" not in text
    assert "\\x1b[2J" in text and "\\u202e" in text and "\\r" in text and "\\x9b" in text


def hostile_text(held: list[Held], metadata: list[tuple[str, dict[str, str]]]) -> None:
    """Control characters in every string a reader prints: the run id, version, bus and
    scenario name; a frequencies key (a unit name to ``info`` without a scenario's units);
    the stored scenario's comments and strings; a log line, the run's error, a topic."""
    for name, values in metadata:
        if name == "run":
            values.update(run_id=HOSTILE, version=HOSTILE, bus=HOSTILE)
        elif name == "scenario":
            values["name"] = HOSTILE
            # TOML takes C1 controls and bidi overrides as they are in comments and strings
            text = values["text"].replace("\n", "\n# \u202eevil\x9b[2J\x85\n", 1)
            values["text"] = text.replace('name = "gate"', f'name = "gate{chr(0x9B)}\u202e"', 1)
            tomllib.loads(values["text"])  # still a scenario's TOML
    for i, (topic, t, data) in enumerate(held):
        if topic == "/log":
            m = json.loads(data)
            m["message"] = HOSTILE
            held[i] = (topic, t, json.dumps(m).encode())
        elif topic == "/run":
            m = json.loads(data)
            m["error"] = HOSTILE
            held[i] = (topic, t, json.dumps(m).encode())
    held.append((f"/zz/{HOSTILE}", 10**9, b'{"a": "\\u001b[2J\\u202e"}'))


def test_no_reader_prints_a_control_character(gate, tmp_path):
    path = tmp_path / "text.mcap"
    path.write_bytes(rebuilt(gate, hostile_text))
    for reader in [*READERS, ["cat", "--unit", "zz"], ["cat", "--topic", "/nope"]]:
        code, out, err = run_cli(reader[0], str(path), *reader[1:])
        assert unsafe(out) == [] and unsafe(err) == [], (reader, unsafe(out), unsafe(err))
        assert code in (0, 1, 2), (reader, err)
        if code == 2:
            assert err.count("\n") == 1, (reader, err)
    code, out, _ = run_cli("info", str(path))
    assert "\\x1b[2J" in out and "\\u202e" in out  # escaped, not dropped
    # the scenario printed still parses to the stored one (its seed the run's)
    stored = stored_scenario(path)
    assert unsafe(stored) == []
    assert tomllib.loads(stored)["name"] == "gate\x9b\u202e"
    code, out, _ = run_cli("cat", str(path), "--topic", f"/zz/{HOSTILE}")
    assert code == 0 and json.loads(out)["message"]["a"] == "\x1b[2J\u202e"


def _lying(stats: Any) -> None:
    stats.message_count = 2**64 - 1  # the most the record holds
    stats.message_start_time, stats.message_end_time = 10**19, 5
    first = min(stats.channel_message_counts)
    stats.channel_message_counts[first] += 1000


def test_lying_statistics_are_named_and_the_measured_figures_given(gate, tmp_path):
    path = tmp_path / "stats.mcap"
    path.write_bytes(rebuilt(gate, stats=_lying))
    truth = log_info(_honest(gate, tmp_path))
    info = log_info(path)
    assert info["problems"] and info["problems"][0].startswith(
        "statistics disagree with the file: says 18446744073709551615 messages, it holds "
        f"{truth['messages']}"
    )
    assert "start at 1e+10 s, after they end at 5e-09 s" in info["problems"][0]
    assert "1000" not in json.dumps(info["topics"])
    assert (info["messages"], info["topics"]) == (truth["messages"], truth["topics"])
    assert (info["start"], info["end"]) == (truth["start"], truth["end"]) and info["duration"] > 0
    code, out, _ = run_cli("info", str(path))
    assert code == 0 and "problem:     statistics disagree with the file" in out
    assert f"messages:    {truth['messages']}" in out
    assert all("18446744073709551615" not in line for line in out.splitlines()[2:])
    assert truth["problems"] == []


def _honest(gate: bytes, tmp_path: Path) -> Path:
    path = tmp_path / "honest.mcap"
    path.write_bytes(rebuilt(gate))
    return path


def test_statistics_whose_counts_do_not_add_up_are_named(gate, tmp_path):
    moved: list[int] = []

    def off(stats: Any) -> None:
        cid = min(stats.channel_message_counts)
        moved[:] = [cid, stats.channel_message_counts[cid]]
        stats.channel_message_counts[cid] -= 1
        stats.channel_message_counts[cid + 100] = 1  # a channel the log has not

    path = tmp_path / "counts.mcap"
    path.write_bytes(rebuilt(gate, stats=off))
    summary = make_reader(io.BytesIO(rebuilt(gate))).get_summary()
    assert summary is not None
    cid, held = moved
    topic = summary.channels[cid].topic
    (problem,) = log_info(path)["problems"]
    assert "its counts per channel add up to" not in problem  # they do: one moved
    assert problem.endswith(
        f"says {held - 1} on {topic}, it holds {held}, 1 on channel {cid + 100}, it holds 0"
    )


def test_two_run_records_are_a_contradiction(gate, tmp_path):
    def twice(held: list[Held], metadata: Any) -> None:
        topic, t, data = next(m for m in held if m[0] == "/run")
        other = {**json.loads(data), "outcome": "gate: shut"}
        held.append((topic, t + 1, json.dumps(other).encode()))

    path = tmp_path / "two.mcap"
    path.write_bytes(rebuilt(gate, twice))
    info = log_info(path)
    assert info["run_records"] == 2 and info["outcome"] is None
    assert "2 /run records (a run writes one)" in info["problems"][0]
    code, out, _ = run_cli("info", str(path))
    assert code == 0 and "outcome:     (not known: the log holds 2 /run records" in out
    assert "gate: open" not in out and "gate: shut" not in out


def test_a_metadata_record_written_twice_is_named(gate, tmp_path):
    def twice(held: Any, metadata: list[tuple[str, dict[str, str]]]) -> None:
        run = next(v for n, v in metadata if n == "run")
        metadata.append(("run", {**run, "run_id": "another"}))

    path = tmp_path / "meta.mcap"
    path.write_bytes(rebuilt(gate, twice))
    assert log_info(path)["problems"] == [
        "metadata record 'run' written 2 times (a log writes each once)"
    ]


def test_deep_metadata_values_are_read_without_recursion(gate, tmp_path):
    def deep(held: Any, metadata: list[tuple[str, dict[str, str]]]) -> None:
        metadata.append(("merge", {"truncated": nested(5000).decode()}))
        metadata.append(("codebook", {"name": nested(5000).decode()}))

    path = tmp_path / "meta.mcap"
    path.write_bytes(rebuilt(gate, deep))
    for reader in (["info"], ["replay"], ["replay", "--json"]):
        code, _, err = run_cli(reader[0], str(path), *reader[1:])
        # replay: a merge record that does not parse is read as a cut log's (info reads none)
        assert code == (0 if reader == ["info"] else 3), (reader, err)
    assert "a merge record that does not parse" in err
