"""One suite for the recorders (MCAP on a BytesIO, MCAP on a file, memory), plus the schema
files, the topic table, the validator, truncated logs and docs/topics.md."""

from __future__ import annotations

import io
import json
import math
import re
from pathlib import Path

import numpy as np
import orjson
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from rgtbus.errors import RgtbusError
from rgtbus.telemetry import (
    TOPIC_PATTERNS,
    TOPICS,
    McapRecorder,
    MemoryRecorder,
    NullRecorder,
    Recorder,
    blocks,
    read_log,
    records,
    schema_for,
    topics_markdown,
)
from rgtbus.telemetry import topics as topics_mod
from rgtbus.telemetry import validate as validate_mod
from rgtbus.telemetry.record_rows import decode_rows
from rgtbus.telemetry.recorder import LogContents
from rgtbus.telemetry.scene import scene_update
from rgtbus.telemetry.version import FORMAT_RECORD, format_metadata

SCHEMA_DIR = Path(topics_mod.__file__).parent / "schemas"
DOCS = Path(__file__).resolve().parent.parent / "docs" / "topics.md"

# One valid message per topic (the /trace family by one member).
SAMPLES: dict[str, dict] = {
    "/medium": {"window": 3, "t": 0.3, "sample_rate": 200.0, "samples": [0.0, 0.4, -0.4]},
    "/tx/pulse": {
        "t": 1.25,
        "tau": 0.005,
        "channels": ["c"],
        "omegas": [5 * math.pi / 3],
        "names": ["a", "c"],
        "kinds": ["relation"],
        "codes": ["conflict"],
        "sample": [250],
        "channel": [0],
        "magnitude": [-0.4],
        "message": [7],
        "kind": [0],
        "code": [0],
        "sender": [0],
        "addressee": [1],
        "block": [0],
    },
    "/rx/spike": {
        "unit": "b",
        "t": 1.3,
        "sample": 260,
        "samples": [260, 260, 262],
        "channel": [0, 1, 1],
        "names": ["a", "c"],
    },
    "/rx/decode": {
        "unit": "b",
        "turn": 1,
        "sender": "a",
        "addressee": "c",
        "kind": "relation",
        "code": "conflict",
        "value": "conflict",
        "margin": 0.31,
        "t": 2.0,
        "accepted": True,
    },
    "/rx/decodes": {
        "unit": "b",
        "t": 2.0,
        "turn": [1, 1],
        "sender": ["a", "a"],
        "addressee": ["c", "c"],
        "channel": ["a", "c"],
        "kind": ["id", "relation"],
        "code": ["id", "conflict"],
        "margin": [0.5, 0.31],
        "times": [1.5, 2.0],
        "accepted": [True, True],
    },
    "/unit/relations": {
        "unit": "c",
        "t": 4.0,
        "sent": {"a>b": "alliance", "b>a": "alliance", "a>c": "conflict"},
        "installed": {"a-b": "alliance"},
        "polynomial": None,
    },
    "/unit/influences": {
        "unit": "c",
        "t": 6.0,
        "influences": {"a>b": ["alpha"], "a>c": [], "b>a": ["alpha", "beta"]},
    },
    "/unit/decision": {
        "unit": "a",
        "subject": "b",
        "t": 7.0,
        "A": ["alpha", "beta"],
        "B": ["beta"],
        "interval": [["beta"], ["alpha", "beta"]],
        "frustrated": False,
        "choice": ["alpha", "beta"],
        "canonical": "b = 1 b + {beta} not(b)",
        "round": 2,
    },
    "/unit/goal": {
        "unit": "d",
        "t": 90.5,
        "round": 1,
        "turn": 21,
        "target": "a",
        "want": [["go"], ["go"]],
        "mode": "exact",
        "heard": {"b": [], "c": []},
        "predicted": {},
        "rule": "robust",
        "solutions": 1,
        "reached": 1,
        "of": 1,
        "value": ["go"],
        "sent": ["go"],
        "reason": "a: exactly 1: 1 meets it whatever the 1 completions of the unheard",
    },
    "/unit/report": {
        "unit": "a",
        "installed": {"a-b": "alliance"},
        "polynomial": "ab",
        "p4": None,
        "sent_relations": {"a>b": "alliance", "b>a": "alliance"},
        "influences": {"a>b": ["go"], "b>a": []},
        "result": {
            "interval": [[], ["go"]],
            "frustrated": False,
            "choice": ["go"],
            "canonical": "a = a + not(a)",
            "A": ["go"],
            "B": [],
            "decided": True,
        },
        "decisions": [
            {
                "round": 1,
                "unit": "a",
                "low": [],
                "high": ["go"],
                "choice": ["go"],
                "frustrated": False,
                "t": 40.5,
            }
        ],
        "sends": [[0, "id", "b", "id"], [0, "payload", "b", "alliance"]],
        "sent_influences": [{"b": "{go}"}],
        "failure": None,
        "failed_at": None,
        "done_at": 8100,
        "mind_error": None,
    },
    "/log": {
        "timestamp": {"sec": 1, "nsec": 5},
        "level": 2,
        "message": "hello",
        "name": "rgtbus",
        "file": "",
        "line": 0,
    },
    "/scene": scene_update(
        "a", 1.5, {"a": [0.0, 0.0], "b": [3.0, 4.0]}, {"a-b": "alliance"}
    ),
    "/trace/a": {
        "unit": "a",
        "sample": 3,
        "t": 0.015,
        "y": [0.0, 0.1],
        "x": [1.0, 0.9],
    },
    "/run": {
        "scenario": "gate",
        "seed": 1,
        "outcome": {"gate": "open"},
        "agree": True,
        "sim_seconds": 12.5,
        "error": None,
    },
    "/control/parameter": {
        "t": 3.2,
        "sample": 640,
        "seq": 0,
        "who": "client 1",
        "name": "channel.noise",
        "value": 0.02,
        "from": 0.0,
        "to": 0.02,
        "applied": True,
        "text": "channel.noise: 0 -> 0.02 at t = 3.200 s",
    },
    "/control/service": {
        "t": 3.2,
        "sample": 640,
        "seq": 1,
        "who": "client 1",
        "service": "pause",
        "request": {"now": 1},
        "applied": False,
        "text": "refused: pause: unknown key 'now' (allowed: none)",
        "round": None,
        "turn": None,
        "value": None,
        "until": None,
        "state": None,
    },
}


def _t_ns(i: int) -> int:
    return 1_000_000_000 + 37 * i


# -- the shared suite: three recorders, one read-back ---------------------------------------


class Harness:
    """A recorder plus how to finish it and read back what it holds."""

    def __init__(self, kind: str, tmp_path: Path, **kw):
        self.kind = kind
        self.path = tmp_path / "run.mcap"
        self._file = None
        if kind == "mcap-bytes":
            self.buf = io.BytesIO()
            self.rec = McapRecorder(self.buf, validate=True, **kw)
        elif kind == "mcap-file":
            self._file = open(self.path, "wb")  # noqa: SIM115  closed in finish()
            self.rec = McapRecorder(self._file, validate=True, **kw)
        else:
            self.rec = MemoryRecorder(**kw)

    def finish(self):
        self.rec.close()
        if self._file is not None and not self._file.closed:
            self._file.close()

    def read(self):
        """What the recorder holds, as read back: block columns as lists, the format record
        every file begins with left out (``test_every_file_says_its_format``)."""
        self.finish()
        if self.kind == "mcap-bytes":
            got = read_log(io.BytesIO(self.buf.getvalue()))
        elif self.kind == "mcap-file":
            got = read_log(self.path)
        else:
            got = self.rec.read()
        messages = [(tp, t, _plain(tp, m)) for tp, t, m in got.messages]
        metadata = {k: v for k, v in got.metadata.items() if k != FORMAT_RECORD}
        return LogContents(messages, metadata, got.truncated, got.note)


def is_block_topic(topic: str) -> bool:
    return blocks.schema_of(topic) is not None


def _plain(topic, message):
    """A record as read, its columns (NumPy arrays) as lists; a block of decodes as the
    records of one decode each (its names held as names or as indexes into its tables)."""
    if not isinstance(message, dict):
        return message
    if topic == "/rx/decodes":
        return [dict(r) for r in decode_rows(message)]
    return {k: v.tolist() if hasattr(v, "tolist") else v for k, v in message.items()}


def test_every_file_says_its_format(harness):
    harness.finish()
    if harness.kind == "memory":
        metadata = harness.rec.read().metadata
    else:
        bytes_ = harness.kind == "mcap-bytes"
        source = io.BytesIO(harness.buf.getvalue()) if bytes_ else harness.path
        metadata = read_log(source).metadata
    assert metadata[FORMAT_RECORD] == {"name": "rgtbus", "version": "2"}


@pytest.fixture(params=["mcap-bytes", "mcap-file", "memory"])
def harness(request, tmp_path):
    h = Harness(request.param, tmp_path)
    try:
        yield h
    finally:
        h.finish()


def _write_all(rec) -> list[tuple[str, int, dict]]:
    """Write every sample, out of time order; return the expected read-back."""
    order = list(SAMPLES.items())
    expected = []
    for i, (topic, msg) in reversed(list(enumerate(order))):
        rec.write(topic, msg, _t_ns(i))
        expected.append((topic, _t_ns(i), _plain(topic, msg)))
    rec.write("/medium", {**SAMPLES["/medium"], "samples": np.array([1.5, -2.0])}, _t_ns(0))
    expected.append(("/medium", _t_ns(0), {**SAMPLES["/medium"], "samples": [1.5, -2.0]}))
    # sorted by time; the two /medium at the same time keep write order
    return sorted(expected, key=lambda m: m[1])


def test_read_back_is_identical_on_every_recorder(harness):
    expected = _write_all(harness.rec)
    harness.rec.metadata("scenario", {"name": "gate", "text": "units = ['a']\n"})
    messages, metadata = harness.read()
    assert messages == expected
    assert metadata == {"scenario": {"name": "gate", "text": "units = ['a']\n"}}
    assert not harness.read().truncated  # reading twice is fine too


def test_metadata_round_trip(harness):
    harness.rec.metadata("run", {"seed": "7", "version": "0.1.0"})
    harness.rec.metadata("codebook", {"alliance": "[.4,.4,.4]", "ω": "3π/2"})
    harness.rec.metadata("run", {"seed": "8"})  # a repeated name: the last wins
    harness.rec.metadata("empty", {})  # no values: not recorded, by either recorder
    _, metadata = harness.read()
    assert metadata == {
        "run": {"seed": "8"},
        "codebook": {"alliance": "[.4,.4,.4]", "ω": "3π/2"},
    }


def test_foxglove_log_fields_and_levels(harness):
    for i, level in enumerate(["debug", "info", "warning", "error", "fatal"]):
        harness.rec.log(level, f"line {i}", 2_000_000_123 + i, name="unit-a")
    harness.rec.log("info", "where", 5, file="units/unit.py", line=42)
    messages, _ = harness.read()
    assert [m[0] for m in messages] == ["/log"] * 6
    assert messages[0] == (
        "/log",
        5,
        {
            "timestamp": {"sec": 0, "nsec": 5},
            "level": 2,
            "message": "where",
            "name": "rgtbus",
            "file": "units/unit.py",
            "line": 42,
        },
    )
    assert [m[2]["level"] for m in messages[1:]] == [1, 2, 3, 4, 5]
    assert messages[1][2]["timestamp"] == {"sec": 2, "nsec": 123}
    assert messages[5][2]["timestamp"] == {"sec": 2, "nsec": 127}
    assert {m[2]["name"] for m in messages[1:]} == {"unit-a"}


def test_refusals(harness):
    rec = harness.rec
    for topic in ["/nope", "/trace/", "/trace/a/b", "medium", "/trace/*"]:
        with pytest.raises(
            RgtbusError, match=re.escape(f"unknown telemetry topic '{topic}' (known: /medium,")
        ):
            rec.write(topic, {}, 0)
    with pytest.raises(RgtbusError, match="unknown log level 'loud'"):
        rec.log("loud", "x", 0)
    for bad in [1.0, -1, True, 2**64, "5"]:
        with pytest.raises(RgtbusError, match="t_ns"):
            rec.write("/medium", SAMPLES["/medium"], bad)
    with pytest.raises(RgtbusError, match="must be a dict, got list"):
        rec.write("/medium", [], 0)
    with pytest.raises(RgtbusError, match=r"message on /medium at t_ns=0: .*nan is not a finite"):
        rec.write("/medium", {**SAMPLES["/medium"], "samples": [math.nan]}, 0)
    with pytest.raises(RgtbusError, match=r"message on /medium at t_ns=0: .*samples"):
        rec.write("/medium", {**SAMPLES["/medium"], "samples": {1, 2}}, 0)
    with pytest.raises(RgtbusError, match="is not JSON"):
        rec.write("/run", {**SAMPLES["/run"], "sim_seconds": math.nan}, 0)
    with pytest.raises(RgtbusError, match=r"metadata 'm': 'k': 1 is not a string to a string"):
        rec.metadata("m", {"k": 1})
    rec.write("/trace/unit_7.b-c", SAMPLES["/trace/a"], np.int64(3))  # numpy ints are fine
    messages, _ = harness.read()
    assert messages == [("/trace/unit_7.b-c", 3, SAMPLES["/trace/a"])]


@pytest.mark.parametrize(
    ("topic", "change", "msg"),
    [
        ("/medium", {"window": None}, r"MediumBlock: window: None is not an integer"),
        ("/medium", {"window": True}, r"MediumBlock: window: True is not an integer"),
        ("/medium", {"samples": [1, "x"]}, r"MediumBlock: samples: could not convert"),
        ("/medium", {"samples": [1, math.inf]}, r"MediumBlock: samples: inf is not a finite"),
        ("/medium", {"extra": 1}, r"MediumBlock: unexpected field 'extra'"),
        ("/tx/pulse", {"sample": [1.5]}, r"PulseBlock: column 'sample': float64 values for a"),
        ("/tx/pulse", {"tau": "x"}, r"PulseBlock: tau: 'x' is not a number"),
        ("/unit/relations", {"sent": {"a>b": "truce"}}, r"'truce' not one of"),
        ("/unit/relations", {"sent": {"ab": "alliance"}}, r"key 'ab'.* does not match"),
        ("/unit/decision", {"interval": [["a"]]}, r"1 items, at least 2 needed"),
        ("/log", {"level": 6}, r"matches 0 of the oneOf alternatives"),
        ("/log", {"timestamp": {"sec": 1, "nsec": 10**9}}, r"above maximum 999999999"),
        ("/run", {"sim_seconds": -1.0}, r"below minimum 0"),
    ],
)
def test_validation_catches_bad_messages(harness, topic, change, msg):
    with pytest.raises(RgtbusError, match=msg):
        harness.rec.write(topic, {**SAMPLES[topic], **change}, 0)


def test_validation_catches_a_missing_field(harness):
    msg = dict(SAMPLES["/rx/decode"])
    del msg["margin"]
    with pytest.raises(
        RgtbusError,
        match=r"message on /rx/decode breaks rgtbus.Decode: \$: missing required field 'margin'",
    ):
        harness.rec.write("/rx/decode", msg, 0)
    assert harness.read()[0] == []  # nothing half-written


def test_close_is_idempotent_and_final(harness):
    harness.rec.write("/medium", SAMPLES["/medium"], 1)
    harness.rec.close()
    harness.rec.close()
    assert harness.rec.closed
    with pytest.raises(RgtbusError, match="write to '/medium' on a closed recorder"):
        harness.rec.write("/medium", SAMPLES["/medium"], 2)
    with pytest.raises(RgtbusError, match="on a closed recorder"):
        harness.rec.log("info", "late", 2)
    with pytest.raises(RgtbusError, match="metadata 'x' on a closed recorder"):
        harness.rec.metadata("x", {})
    assert len(harness.read()[0]) == 1


def test_closed_after_an_exception_the_log_is_readable(harness):
    with pytest.raises(ZeroDivisionError), harness.rec as rec:
        rec.metadata("run", {"seed": "1"})
        rec.write("/medium", SAMPLES["/medium"], 10)
        rec.log("error", "about to fail", 11)
        _ = 1 / 0
    assert harness.rec.closed
    messages, metadata = harness.read()
    assert [m[0] for m in messages] == ["/medium", "/log"] and metadata == {"run": {"seed": "1"}}


# -- MCAP specifics ---------------------------------------------------------------------------


def _mcap_bytes(n=400, **kw) -> bytes:
    buf = io.BytesIO()
    with McapRecorder(buf, **kw) as rec:
        rec.metadata("run", {"seed": "1"})
        for i in range(n):
            samples = np.sin(np.arange(20) * 0.1 + i)
            rec.write(
                "/medium",
                {"window": i, "t": i * 0.1, "sample_rate": 200.0, "samples": samples},
                i * 100_000_000,
            )
        rec.log("info", "done", n * 100_000_000)
    return buf.getvalue()


def test_mcap_log_time_publish_time_and_encodings():
    buf = io.BytesIO(_mcap_bytes(5))
    reader = make_reader(buf)
    seen = [
        (ch.topic, msg.log_time, msg.publish_time, sc.name, sc.encoding, ch.message_encoding)
        for sc, ch, msg in reader.iter_messages()
    ]
    assert [s[1] for s in seen] == [
        0,
        100_000_000,
        200_000_000,
        300_000_000,
        400_000_000,
        500_000_000,
    ]
    assert all(s[1] == s[2] for s in seen)
    assert {(s[0], s[3], s[4], s[5]) for s in seen} == {
        ("/medium", "rgtbus.MediumBlock", "protobuf", "protobuf"),
        ("/log", "foxglove.Log", "jsonschema", "json"),
    }
    summary = reader.get_summary()
    schema = next(s for s in summary.schemas.values() if s.name == "foxglove.Log")
    assert json.loads(schema.data)["title"] == "foxglove.Log"
    assert len(summary.channels) == 2  # channels are registered once per topic


def test_one_schema_record_for_a_topic_family():
    buf = io.BytesIO()
    with McapRecorder(buf) as rec:
        for u in "abc":
            rec.write(f"/trace/{u}", {**SAMPLES["/trace/a"], "unit": u}, 0)
    summary = make_reader(io.BytesIO(buf.getvalue())).get_summary()
    assert len(summary.channels) == 3 and len(summary.schemas) == 1


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_compressions_read_back(compression):
    messages, _ = read_log(io.BytesIO(_mcap_bytes(30, compression=compression)))
    assert len(messages) == 31


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_the_scan_splits_chunks_as_mcap_does(compression, tmp_path):
    """``scan_log`` splits chunks with a loop of its own (mcap's is ~8 MB/s): every message
    as mcap's reader gives it, and a topic left in the file (deferred) found where it is."""
    from rgtbus.telemetry.scan import scan_log

    data = _mcap_bytes(300, compression=compression, chunk_size=2048)
    want = [
        (ch.id, m.log_time, m.publish_time, m.sequence, bytes(m.data))
        for _, ch, m in make_reader(io.BytesIO(data)).iter_messages(log_time_order=False)
    ]
    raw = scan_log(io.BytesIO(data))
    assert [(*m[:4], bytes(m[4])) for m in raw.messages] == want and len(want) == 301
    path = tmp_path / "log.mcap"
    path.write_bytes(data)
    kept = scan_log(path, defer=lambda topic: topic == "/medium")
    assert kept.deferred is not None and kept.deferred.held() == {"/medium": 300}
    medium = [(w[1], w[4]) for w in want if raw.channels[w[0]].topic == "/medium"]
    assert kept.deferred.read("/medium") == medium and len(kept.messages) == 1
    assert len(kept.deferred.crcs) > 10  # many chunks, each found again by its offset


def test_unknown_compression():
    with pytest.raises(
        RgtbusError, match=r"unknown MCAP compression 'brotli' \(use zstd, lz4, none\)"
    ):
        McapRecorder(io.BytesIO(), compression="brotli")


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_every_compression_level_reads_back_the_same_and_a_bad_one_is_refused(compression):
    """The level trades the writer's time for bytes; the messages are the same at each."""
    got = {}
    for level in (0, 1, 9):
        data = _mcap_bytes(60, compression=compression, compression_level=level)
        got[level] = read_log(io.BytesIO(data))
    same = [[(tp, t, _plain(tp, m)) for tp, t, m in got[k].messages] for k in (0, 1, 9)]
    assert same[0] == same[1] == same[2] and len(got[1].messages) == 61
    for bad in (-1, 20, 1.5, "1", True):
        with pytest.raises(RgtbusError, match=f"compression level {bad!r} is not an integer"):
            McapRecorder(io.BytesIO(), compression=compression, compression_level=bad)


def test_truncated_log_is_read_as_far_as_it_goes():
    data = _mcap_bytes(400, chunk_size=4096)
    full = read_log(io.BytesIO(data))

    def plain(messages):
        return [(tp, t, _plain(tp, m)) for tp, t, m in messages]

    assert not full.truncated and full.note == "" and len(full.messages) == 401
    assert full.end_ns == 400 * 100_000_000
    counts = []
    for cut in [len(data) - 1, len(data) - 200, len(data) * 2 // 3, len(data) // 3, 200]:
        part = read_log(io.BytesIO(data[:cut]))
        assert part.truncated and "log truncated" in part.note and "\n" not in part.note
        assert plain(part.messages) == plain(full.messages[: len(part.messages)])
        assert part.metadata == {"run": {"seed": "1"}, FORMAT_RECORD: format_metadata()}
        counts.append(len(part.messages))
    assert counts[0] == 401 and "all messages present" in read_log(io.BytesIO(data[:-1])).note
    assert counts == sorted(counts, reverse=True) and 0 < counts[3] < counts[2] < 401
    assert f"after {counts[3]} messages" in read_log(io.BytesIO(data[: len(data) // 3])).note


def test_truncated_file_on_disk(tmp_path):
    path = tmp_path / "cut.mcap"
    data = _mcap_bytes(400, chunk_size=4096)
    path.write_bytes(data[: len(data) // 2])
    res = read_log(path)
    assert res.truncated and str(path) in res.note and 0 < len(res.messages) < 401


def test_not_an_mcap_file(tmp_path):
    for data in [b"", b"\x89MC", b"hello world, this is not an mcap file"]:
        with pytest.raises(RgtbusError, match="not an MCAP file"):
            read_log(io.BytesIO(data))
    with pytest.raises(RgtbusError, match=r"cannot read log .*missing\.mcap"):
        read_log(tmp_path / "missing.mcap")


def test_null_recorder():
    rec = NullRecorder()
    assert isinstance(rec, Recorder) and not rec.enabled
    rec.write("/anything", {}, -1)
    rec.log("whatever", "x", 0)
    rec.metadata("m", {})
    rec.close()
    rec.close()
    assert isinstance(McapRecorder(io.BytesIO()), Recorder) and MemoryRecorder().enabled


def test_memory_recorder_keeps_logs_and_copies():
    rec = MemoryRecorder()
    msg = {**SAMPLES["/medium"], "samples": [1.0]}
    rec.write("/medium", msg, 1)
    msg["samples"].append(2.0)  # the recorder holds its own copy
    rec.log("warning", "careful", 2)
    assert rec.messages[0][2]["samples"] == [1.0]
    assert rec.logs == [rec.messages[1][2]] and rec.logs[0]["level"] == 3
    assert rec.counts == {"/medium": 1, "/log": 1}


# -- schema files, topic table, docs -------------------------------------------------------------


def test_every_schema_file_is_a_json_object_schema_the_validator_understands():
    files = sorted(SCHEMA_DIR.glob("*.json"))
    assert files
    for f in files:
        schema = json.loads(f.read_text())
        assert schema["type"] == "object", f.name
        assert schema["title"] == f.stem, f.name
        assert set(schema["required"]) <= set(schema["properties"]), f.name
        validate_mod.check_schema(schema, f.name)


def test_topic_table_and_schema_files_agree():
    used = {s for s in topics_mod.schema_names() if not topics_mod.is_block_schema(s)}
    on_disk = {f.stem for f in SCHEMA_DIR.glob("*.json")}
    assert used == on_disk  # every JSON topic's schema exists, and no orphan schema
    for topic, (schema, _) in TOPICS.items():
        assert schema_for(topic) == schema
    assert schema_for("/trace/a") == TOPIC_PATTERNS[0][2]
    # every topic has a sample message above, and it is valid
    assert set(SAMPLES) == set(TOPICS) | {"/trace/a"}
    for topic, msg in SAMPLES.items():
        if is_block_topic(topic):  # a block: what its codec writes and reads back
            block = blocks.schema_of(topic)
            back = blocks.decode_record(block, blocks.encode_record(block, msg), topic)
            assert _plain(topic, back) == _plain(topic, msg), topic
            continue
        assert validate_mod.errors(msg, topics_mod.load_schema(schema_for(topic))) == [], topic


def test_validator_refuses_unknown_keywords():
    with pytest.raises(RgtbusError, match=r"x\.properties\.a: unsupported keyword\(s\) format"):
        validate_mod.check_schema({"type": "object", "properties": {"a": {"format": "date"}}}, "x")


@pytest.mark.parametrize(
    ("schema", "says"),
    [
        ({"type": "strng"}, r"x\.type: not a valid JSON Schema: 'strng' is not valid"),
        ({"type": "array", "minItems": -1}, r"x\.minItems: not a valid JSON Schema"),
        ({"properties": {"a": {"enum": "x"}}}, r"x\.properties\.a\.enum: not a valid JSON"),
    ],
)
def test_validator_refuses_what_is_no_json_schema(schema, says):
    """A schema that JSON Schema (draft 2020-12) would not take is refused, naming where."""
    with pytest.raises(RgtbusError, match=says):
        validate_mod.check_schema(schema, "x")


def test_validation_names_every_error_in_the_messages_order():
    """fastjsonschema says a message breaks its schema; jsonschema then names every way, in
    the project's words, in the order the message has its fields. JSON Schema's types: a
    whole float is an integer, a boolean is no number."""
    schema = {  # the medium's JSON Schema of format 1
        "type": "object",
        "properties": {
            "window": {"type": "integer", "minimum": 0},
            "t": {"type": "number"},
            "sample_rate": {"type": "number", "minimum": 0},
            "samples": {"type": "array", "items": {"type": "number"}},
        },
        "required": ["window", "t", "sample_rate", "samples"],
        "additionalProperties": False,
    }
    msg = {**SAMPLES["/medium"], "window": "3", "samples": [0.0, None, True], "extra": 1}
    assert validate_mod.errors(msg, schema) == [
        "$: unexpected field 'extra'",
        "$.window: expected integer, got string",
        "$.samples[1]: expected number, got null",
        "$.samples[2]: expected number, got boolean",
    ]
    assert validate_mod.errors({**SAMPLES["/medium"], "window": 3.0}, schema) == []
    assert validate_mod.errors(SAMPLES["/medium"], schema) == []


def test_docs_topics_md_is_generated():
    assert DOCS.read_text() == topics_markdown(), (
        'docs/topics.md is stale: regenerate with python -c "from rgtbus.telemetry import '
        "topics_markdown; open('docs/topics.md','w').write(topics_markdown())\""
    )


def test_spike_rows_read_blocks_records_of_one_sample_and_logs_of_one_spike_alike():
    from rgtbus.telemetry.read import spike_table

    def spike_rows(records, frequencies, tau=None):
        return list(spike_table(records, frequencies, tau).rows())

    columns = {  # one entry a spike (this version)
        "unit": "b",
        "t": 1.3,
        "sample": 260,
        "samples": [260, 263, 263],
        "channel": [1, 1, 0],
        "names": ["c", "a"],
    }
    block = {  # a list of names a sample (the version before)
        "unit": "b",
        "t": 1.3,
        "sample": 260,
        "samples": [260, 263],
        "channels": [["a"], ["a", "c"]],
    }
    for form in (columns, block):
        assert spike_rows([form], {"a": 4.7, "c": 5.2}, 0.005) == [
            {"unit": "b", "channel": "a", "omega": 4.7, "t": 1.3, "sample": 260},
            {"unit": "b", "channel": "a", "omega": 4.7, "t": 263 * 0.005, "sample": 263},
            {"unit": "b", "channel": "c", "omega": 5.2, "t": 263 * 0.005, "sample": 263},
        ], form
        assert spike_rows([form], {})[2]["t"] == 1.3 / 260 * 263  # no τ: the record's own
    for bad, why in [({"channel": [1, 2, 0]}, "channel 2 is not one of its 2 names"),
                     ({"channel": [1, 0]}, "3 samples but 2 channels")]:  # fmt: skip
        with pytest.raises(RgtbusError, match=why):
            spike_rows([{**columns, **bad}], {})
    new = {"unit": "b", "t": 1.3, "sample": 260, "channels": ["a", "c"]}
    old = {"unit": "b", "channel": "a", "omega": 4.7, "t": 1.3, "sample": 260}
    rows = spike_rows([new, old], {"a": 4.7, "c": 5.2})
    assert rows == [
        {"unit": "b", "channel": "a", "omega": 4.7, "t": 1.3, "sample": 260},
        {"unit": "b", "channel": "c", "omega": 5.2, "t": 1.3, "sample": 260},
        old,
    ]
    assert spike_rows([new], {})[0]["omega"] is None  # a log without frequencies


# -- plots: the activity figure (rgtbus.telemetry.plots) ------------------------------------


@pytest.fixture(scope="module")
def example2_log(tmp_path_factory):
    """example2 run on the memory bus with traces, logged to an MCAP file."""
    from rgtbus.units.group import run_group

    from rgtbus.scenario import load_scenario

    path = tmp_path_factory.mktemp("plots") / "example2.mcap"
    sc = load_scenario(Path(__file__).resolve().parent.parent / "scenarios" / "example2.toml")
    with open(path, "wb") as f:
        rec = McapRecorder(f)
        run_group(sc, "memory", rec, traces=True)
        rec.close()
    return path


@pytest.mark.parametrize(
    ("t_from", "t_to", "expected"),
    [
        (None, None, (0.0, 162.1)),
        (10, None, (10.0, 162.1)),
        (None, 40, (0.0, 40.0)),
        (-5, 3, (-5.0, 3.0)),  # overlaps the run in part: kept as asked
        (100, 500, (100.0, 500.0)),
    ],
)
def test_check_time_range_keeps_a_range_that_holds_some_of_the_run(t_from, t_to, expected):
    from rgtbus.telemetry.log_cat import check_time_range

    assert check_time_range(t_from, t_to, 0.0, 162.1) == expected


@pytest.mark.parametrize(
    ("t_from", "t_to", "message"),
    [
        (500, 600, "--from 500 --to 600: outside the run (0 to 162.1 s)"),
        (162.1, None, "--from 162.1: outside the run (0 to 162.1 s)"),
        (None, 0, "--to 0: outside the run (0 to 162.1 s)"),
        (-10, -1, "--from -10 --to -1: outside the run (0 to 162.1 s)"),
        (5, 5, "--from 5 --to 5: empty time range (the run is 0 to 162.1 s)"),
        (40, 10, "--from 40 --to 10: empty time range (the run is 0 to 162.1 s)"),
        (math.nan, None, "--from nan: not a time (the run is 0 to 162.1 s)"),
        (None, math.inf, "--to inf: not a time (the run is 0 to 162.1 s)"),
    ],
)
def test_check_time_range_refuses_a_range_outside_the_run(t_from, t_to, message):
    from rgtbus.telemetry.log_cat import check_time_range

    with pytest.raises(RgtbusError) as e:
        check_time_range(t_from, t_to, 0.0, 162.1)
    assert str(e.value) == message


@pytest.mark.parametrize(
    ("t_from", "t_to", "held"),
    [(None, None, True), (0, None, True), (None, 0.005, True), (0, 1, True), (0.006, None, False),
     (None, 0.004, False)],
)  # fmt: skip
def test_check_time_range_on_a_run_of_one_instant(t_from, t_to, held):
    """A log whose records are all at one time (a unit whose join failed writes its lines at
    0 s, or at its first sample): no range, or one holding that instant, keeps it."""
    from rgtbus.telemetry.log_cat import check_time_range

    if held:
        lo, hi = check_time_range(t_from, t_to, 0.005, 0.005)
        assert lo <= 0.005 <= hi
    else:
        with pytest.raises(RgtbusError, match=r"outside the run \(0.005 to 0.005 s\)"):
            check_time_range(t_from, t_to, 0.005, 0.005)



def test_plots_module_imports_no_matplotlib():
    import subprocess
    import sys

    code = "import sys, rgtbus.telemetry.plots; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_replay_plot_refuses_a_range_past_the_end_in_one_line(example2_log, tmp_path, capsys):
    from rgtbus.cli import main

    png = tmp_path / "x.png"
    code = main(["replay", str(example2_log), "--plot", str(png), "--from", "500", "--to", "600"])
    err = capsys.readouterr().err
    assert code == 2 and not png.exists()
    # one line naming the value and the run's span (76.04 s)
    assert len(err.splitlines()) == 1 and "--from 500" in err and "76.04 s" in err


def test_attention_spikes_are_the_spikes_of_accepted_ids(example2_log):
    from rgtbus.telemetry.plots import attention_spikes
    from rgtbus.telemetry.read import load_replay

    rp = load_replay(example2_log)
    mine = {(s["channel"], s["t"]) for s in rp.spikes if s["unit"] == "a"}
    ids = [d for d in rp.decodes if d.unit == "a" and d.kind == "id" and d.accepted]
    got = attention_spikes(rp, "a")
    assert len(ids) == 12 and got <= mine
    # One a turn: the spike anchor reacts at the spike, on the sender's channel (its ID at 3
    # pulses fires at its last pulse, so the decode is due then).
    assert got == {(d.sender, d.t) for d in ids}
    assert mine - got  # crosstalk: spikes on a channel that are no accepted attention spike
    ids[0].accepted = False  # an ID the unit refused gives no attention spike
    assert attention_spikes(rp, "a") == got - {(ids[0].sender, ids[0].t)}


def test_activity_figure_draws_attention_and_other_spikes_apart(example2_log):
    from rgtbus.units.rerun import traces_for

    from rgtbus.telemetry.plots import FONT, activity_figure, attention_spikes
    from rgtbus.telemetry.read import load_replay

    rp = load_replay(example2_log)
    fig = activity_figure(rp, "a", traces_for(rp, "a"))
    attention = attention_spikes(rp, "a")
    filled, hollow = [], []
    for ax in fig.axes[:3]:
        for line in ax.get_lines():
            if line.get_marker() == "v":
                xs = list(line.get_xdata())
                (hollow if line.get_markerfacecolor() == "none" else filled).extend(xs)
    spikes = [s for s in rp.spikes if s["unit"] == "a"]
    assert sorted(filled) == sorted(t for _, t in attention)
    assert len(filled) + len(hollow) == len(spikes) and hollow
    labels = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert "attention spike (accepted ID)" in labels
    assert "other spike (crosstalk, noise)" in labels
    # readable: no text below the base font (labels of transmissions are a notch smaller)
    sizes = {t.get_fontsize() for t in fig.findobj(lambda o: hasattr(o, "get_fontsize"))}
    assert min(sizes) >= FONT - 1


def test_a_log_is_flushed_by_wall_time_too(tmp_path):
    """A run that writes little (paced, or waiting) still has its records on disk within
    about ``flush_wall`` seconds: what a process killed outright keeps."""
    import time

    from rgtbus.telemetry import McapRecorder, scan_log

    path = tmp_path / "slow.mcap"
    with open(path, "wb") as f:
        rec = McapRecorder(f, flush_wall=0.2)
        rec.write("/log", SAMPLES["/log"], 1_000)
        deadline = time.monotonic() + 30  # generous: the flusher runs every 0.1 s
        while not scan_log(path).messages and time.monotonic() < deadline:
            time.sleep(0.05)
        assert [m[1] for m in scan_log(path).messages] == [1_000]
        rec.close()


def test_records_told_late_do_not_finish_a_chunk(tmp_path):
    """A unit logs its spikes when it wakes, after records of later times: a chunk is due by
    how far the present has moved, not by how old its oldest record is."""
    from rgtbus.telemetry import McapRecorder, scan_log

    path = tmp_path / "late.mcap"
    second = 1_000_000_000
    with open(path, "wb") as f:
        # no flush by the clock in this test; a chunk a simulated second
        rec = McapRecorder(f, flush_wall=3600, flush_seconds=1.0)
        rec.write("/log", SAMPLES["/log"], 5 * second)  # the present
        for k in range(50):  # told late: earlier than the present
            rec.write("/log", SAMPLES["/log"], k * second // 100)
        rec.write("/log", SAMPLES["/log"], 5 * second + second // 2)
        rec.write("/medium", SAMPLES["/medium"], 90 * second)  # ahead: finishes nothing
        assert scan_log(path).messages == []
        rec.write("/log", SAMPLES["/log"], 6 * second)  # one span on: due
        assert len(scan_log(path).messages) == 54  # the medium and all 53 records
        rec.close()


def test_a_message_written_ahead_does_not_hold_the_others_back(tmp_path):
    """The medium is logged ahead of the units' records: a chunk is flushed once it spans
    ``flush_seconds`` from its oldest message, not from its first."""
    from rgtbus.telemetry import McapRecorder, scan_log

    path = tmp_path / "ahead.mcap"
    second = 1_000_000_000
    with open(path, "wb") as f:
        # no flush by the clock in this test; a chunk a simulated second
        rec = McapRecorder(f, flush_wall=3600, flush_seconds=1.0)
        rec.write("/medium", SAMPLES["/medium"], 50 * second)  # far ahead
        rec.write("/log", SAMPLES["/log"], 0)  # the records of now
        rec.write("/log", SAMPLES["/log"], 2 * second)  # two seconds on: due
        assert len(scan_log(path).messages) == 3
        rec.close()


_LEAF = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**40), 2**40),
    st.floats(),  # NaN and infinities among them
    st.text(max_size=6),  # "null" in a string is no null
    st.lists(st.floats(), max_size=4).map(np.array),
)
_NESTED = st.recursive(
    _LEAF,
    lambda kids: st.one_of(
        st.lists(kids, max_size=4),
        st.tuples(kids, kids),
        st.dictionaries(st.text(max_size=4), kids, max_size=4),
    ),
    max_leaves=20,
)


_COLUMN = st.one_of(
    st.lists(st.floats(), max_size=300).map(np.array),  # NaN and infinities among them
    st.lists(st.integers(-(2**40), 2**40), max_size=300).map(np.array),
    st.lists(st.booleans(), max_size=300).map(lambda v: np.array(v, dtype=bool)),
    st.lists(st.text(max_size=6), max_size=300),
    st.lists(st.one_of(st.text(max_size=3), st.floats()), max_size=300),
)


@given(_NESTED, st.booleans(), st.dictionaries(st.sampled_from("abcdef"), _COLUMN, max_size=4))
@settings(max_examples=300, deadline=None)
def test_encode_json_refuses_exactly_the_values_strict_json_refuses(value, large, columns):
    """orjson writes NaN and infinity as null, as it writes None: the encoder looks into the
    parts that hold a null and refuses a non-finite number wherever it is, as the standard
    library's strict encoder does, and otherwise writes what orjson wrote. A large message
    (``large``: past ``_LOOK_BEFORE_SCAN``) whose values show by their types that they are
    finite is not looked into: columns of numbers or names, beside any value."""
    from rgtbus.telemetry.message_json import encode_json

    message = {"m": value, "none": None, **columns}
    if large:
        message["pad"] = "null " * 1000
    strict = json.JSONEncoder(allow_nan=False, default=lambda o: o.tolist())
    try:
        want = json.loads(strict.encode(message))
    except ValueError:
        with pytest.raises(ValueError, match="not JSON compliant"):
            encode_json(message)
        return
    assert json.loads(encode_json(message)) == want


@pytest.mark.parametrize(
    "message, t_ns",
    [
        ({"level": 2, "message": float("nan")}, 5),  # NaN: orjson writes null
        ({"level": 2, "message": [1, float("inf")]}, 5),
        ({"level": 2, "message": object()}, 5),  # not JSON at all
        ({"level": 2, "message": 2**70}, 5),  # beyond 64 bits
        (["not", "a", "dict"], 5),
        (SAMPLES["/log"], -1),
        (SAMPLES["/log"], 2**64),
        (SAMPLES["/log"], 1.5),
        (SAMPLES["/log"], True),
    ],
)
def test_a_bad_record_on_an_open_topic_is_refused_as_on_a_new_one(message, t_ns, tmp_path):
    """The recorder's inline way for topics already written (a run's millions of records)
    refuses what the checked way refuses, with the same words; and writes on after it."""
    from rgtbus.telemetry import McapRecorder, scan_log

    said = []
    for opened in (False, True):
        path = tmp_path / f"bad{opened}.mcap"
        with open(path, "wb") as f:
            rec = McapRecorder(f)
            if opened:
                rec.write("/log", SAMPLES["/log"], 1)
            with pytest.raises(RgtbusError) as e:
                rec.write("/log", message, t_ns)  # type: ignore[arg-type]
            said.append(str(e.value))
            rec.write("/log", SAMPLES["/log"], 7)
            rec.close()
        assert rec.counts["/log"] == 1 + opened
        assert len(scan_log(path).messages) == 1 + opened
    assert said[0] == said[1]


_JUNK = st.one_of(
    st.none(), st.booleans(), st.integers(-3, 3), st.floats(-2, 2, allow_nan=False),
    st.text(max_size=3), st.lists(st.integers(0, 2), max_size=3), st.just({"x": 1}),
)  # fmt: skip


@settings(max_examples=300, deadline=None)
@given(topic=st.sampled_from(sorted(t for t in SAMPLES if not is_block_topic(t))), data=st.data())
def test_the_error_walk_agrees_with_the_validator(topic, data):
    """One library validates (fastjsonschema); the walk that names the errors finds one
    exactly when it says a message breaks its schema, on messages with fields replaced,
    removed or added at random."""
    schema = topics_mod.load_schema(schema_for(topic))
    msg = json.loads(json.dumps(SAMPLES[topic]))
    for _ in range(data.draw(st.integers(1, 3))):
        what = data.draw(st.sampled_from(["replace", "drop", "add", "inner"]))
        keys = sorted(msg)
        if what == "replace" and keys:
            msg[data.draw(st.sampled_from(keys))] = data.draw(_JUNK)
        elif what == "drop" and keys:
            msg.pop(data.draw(st.sampled_from(keys)))
        elif what == "add":
            msg[data.draw(st.text(min_size=1, max_size=4))] = data.draw(_JUNK)
        else:
            lists = [k for k in keys if isinstance(msg[k], list) and msg[k]]
            if lists:
                k = data.draw(st.sampled_from(lists))
                msg[k][data.draw(st.integers(0, len(msg[k]) - 1))] = data.draw(_JUNK)
    valid = validate_mod.errors(msg, schema) == []
    walked = list(validate_mod._errors(msg, schema, "$"))
    assert (walked == []) == valid, (msg, walked)


def test_a_shared_table_is_encoded_once_and_as_the_plain_table():
    """A table the units share (``SharedTable``) is written as the dict it holds, wherever it
    sits in a record, its JSON worked out once for every record that holds it; a NaN in one
    is refused as in a plain table; other subclasses of plain types write as those types."""
    import collections
    import enum

    import orjson

    from rgtbus.pairs import SharedTable
    from rgtbus.telemetry.message_json import _shared_json, encode_json

    plain = {"a>b": "alliance", "b>a": ["alpha", "beta"]}
    table = SharedTable(plain)
    assert encode_json({"unit": "a", "sent": table}) == orjson.dumps({"unit": "a", "sent": plain})
    nested = {"r": [{"x": table}], "p": None}
    assert encode_json(nested) == orjson.dumps({"r": [{"x": plain}], "p": None})
    assert _shared_json(table) is _shared_json(table)
    assert _shared_json(SharedTable(plain)) is not _shared_json(table)  # another object
    # the cache keeps the JSON while the table lives, never the table itself
    import weakref

    from rgtbus.telemetry import message_json as recorder_mod

    passing = SharedTable({"x>y": "conflict"})
    _shared_json(passing)
    key, gone = id(passing), weakref.ref(passing)
    assert key in recorder_mod._SHARED
    del passing
    assert gone() is None and key not in recorder_mod._SHARED
    with pytest.raises(ValueError, match="not JSON compliant"):
        encode_json({"t": SharedTable({"a>b": float("nan")})})
    with pytest.raises(TypeError, match="not JSON serializable: object"):
        encode_json({"t": SharedTable({"a>b": object()})})

    class Level(enum.IntEnum):
        INFO = 2

    class Name(str):
        def __str__(self) -> str:
            return "not the value"

    odd = {"c": collections.Counter(x=2), "l": Level.INFO, "n": Name("u1"), "np": np.str_("v")}
    assert orjson.loads(encode_json(odd)) == {"c": {"x": 2}, "l": 2, "n": "u1", "np": "v"}


def test_a_shared_table_cannot_be_changed_and_pickles_as_a_dict():
    """A shared table is read, never changed (every unit holding it would see the change);
    pickled (a unit process's report) it is the plain dict it holds."""
    import pickle

    from rgtbus.pairs import SharedTable

    table = SharedTable({"a>b": "alliance"})
    for change in (
        lambda: table.__setitem__("b>a", "conflict"),
        lambda: table.pop("a>b"),
        lambda: table.update({"x": 1}),
        lambda: table.setdefault("x", 1),
        lambda: table.clear(),
        lambda: table.popitem(),
        lambda: table.__delitem__("a>b"),
    ):
        with pytest.raises(TypeError, match="shared"):
            change()
    with pytest.raises(TypeError, match="shared"):
        table |= {"x": 1}
    assert table == {"a>b": "alliance"} and json.loads(json.dumps(table)) == table
    back = pickle.loads(pickle.dumps(table))
    assert type(back) is dict and back == table


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
@pytest.mark.parametrize(
    "where",
    ["float column", "float32 column", "top float", "list of floats", "list of names and a float",
     "nested", "column of objects"],
)  # fmt: skip
def test_a_large_message_is_refused_wherever_a_non_finite_number_hides(bad, where):
    """A large message is written without a scan for null when its values' types show that
    none is a NaN or infinity (``_finite_by_type``): a non-finite number anywhere still
    refuses it, and a finite one writes what orjson writes."""
    import orjson

    from rgtbus.telemetry.message_json import _LOOK_BEFORE_SCAN, encode_json

    names = [f"u{i:03d}" for i in range(_LOOK_BEFORE_SCAN // 4)]
    good = {"unit": "u1", "t": 1.5, "none": None, "turn": np.arange(9), "ok": np.ones(3, bool),
            "margin": np.linspace(0, 1, 9), "names": names, "n": 3}  # fmt: skip
    assert encode_json(good) == orjson.dumps(good, option=orjson.OPT_SERIALIZE_NUMPY)
    value = {
        "float column": np.array([0.5, bad]),
        "float32 column": np.array([0.5, bad], dtype=np.float32),
        "top float": bad,
        "list of floats": [0.5, bad],
        "list of names and a float": ["a", bad],
        "nested": {"x": [bad]},
        "column of objects": np.array([0.5, bad], dtype=object),
    }[where]
    with pytest.raises(ValueError, match="not JSON compliant"):
        encode_json({**good, "bad": value})


def _spike_block(unit, sample: int) -> dict:

    return records.spikes(unit, 0.005, np.array([sample]), np.array([0]), ["a"])


@pytest.mark.parametrize("kind", ["mcap", "memory"])
def test_records_held_until_the_run_passes_them_go_out_in_time_order(kind):
    """``advance``: records at or after the point the run has come to are held, and written in
    log-time order (then arrival) as it moves on; a record told late goes out at once; blocks
    of spikes of one time that hold the same spikes become one naming their units, as
    ``merge`` joins them; ``close`` writes what is still held. Both recorders alike."""
    from rgtbus.telemetry import MemoryRecorder
    from rgtbus.telemetry.blocks import SPIKE, decode_record
    from rgtbus.telemetry.message_json import log_message

    buf = io.BytesIO()
    rec = McapRecorder(buf) if kind == "mcap" else MemoryRecorder()
    rec.write(records.LOG, log_message("info", "before any advance", 5, "u"), 5)
    rec.advance(10)
    rec.log("info", "planned ahead", 300, name="u")
    rec.log("info", "now", 20, name="u")
    rec.write(records.RX_SPIKE, _spike_block("b", 3), 20)
    rec.write(records.RX_SPIKE, _spike_block("a", 3), 20)
    rec.write(records.RX_SPIKE, _spike_block("c", 4), 20)  # other spikes: a record of its own
    rec.log("info", "told late", 8, name="u")
    rec.advance(100)
    rec.log("info", "after", 150, name="u")
    rec.close()
    if kind == "mcap":
        in_file = make_reader(io.BytesIO(buf.getvalue())).iter_messages(log_time_order=False)
        got = [(c.topic, m.log_time, m.data) for _, c, m in in_file]
    else:
        got = [(t, n, m) for t, n, m in rec.messages]
    order = [(topic, t) for topic, t, _ in got]
    assert order == [
        ("/log", 5), ("/log", 8), ("/log", 20), ("/rx/spike", 20), ("/rx/spike", 20),
        ("/log", 150), ("/log", 300),
    ]  # fmt: skip
    spikes = [m for topic, _, m in got if topic == "/rx/spike"]
    if kind == "mcap":
        spikes = [decode_record(SPIKE, m, "test") for m in spikes]
    assert [s.get("units") or s.get("unit") for s in spikes] == [["a", "b"], "c"]
    assert rec.counts["/rx/spike"] == 2


def test_large_tables_units_hold_alike_are_checked_once_and_held_once():
    """A reader decoding a topic keeps the large tables its messages hold alike once (the n²
    pairs every unit installed), each message still checked whole: one that breaks its
    schema elsewhere, or holds another table, is refused as before."""
    from rgtbus.telemetry.topics import SharedTables, checked_message

    sent = {f"u{i}>u{j}": "alliance" for i in range(9) for j in range(9) if i != j}
    pairs = {f"u{i}-u{j}": "alliance" for i in range(12) for j in range(i + 1, 12)}
    tables = SharedTables()

    def read(record):
        data = orjson.dumps(record)
        return checked_message(records.UNIT_RELATIONS, 5, data, "<log>", True, tables)

    a = read(records.relations("u0", 1.0, sent, pairs, "u0*u1", None))
    b = read(records.relations("u1", 2.0, dict(sent), dict(pairs), "u0*u1", None))
    assert b["installed"] is a["installed"] and b["sent"] is a["sent"] and b["unit"] == "u1"
    with pytest.raises(RgtbusError, match=r"polynomial"):
        read({**records.relations("u2", 3.0, sent, pairs, None, None), "polynomial": 5})
    other = {**pairs, "u0-u1": "maybe"}
    with pytest.raises(RgtbusError, match=r"installed"):
        read(records.relations("u3", 4.0, sent, other, None, None))


@pytest.mark.parametrize("seed", range(6))
def test_runs_of_equal_messages_split_as_the_loop_splits_them(seed, monkeypatch):
    """A run of messages of one length is split as arrays (``chunks._equal_run``): on chunks
    of runs of every length, several channels within a run, channel records between, and
    channels kept, deferred (counted with their last time) or filtered out, the same rows,
    counts and records as the record-at-a-time loop."""
    from mcap.data_stream import RecordBuilder
    from mcap.records import Channel, Message

    from rgtbus.telemetry import chunks

    rng = np.random.default_rng(seed)
    out = RecordBuilder()

    def channel(cid: int) -> None:
        Channel(id=cid, topic=f"/t{cid}", message_encoding="json", schema_id=0, metadata={}).write(
            out
        )

    for cid in range(1, 5):
        channel(cid)
    seq = 0
    for _ in range(40):
        size = int(rng.integers(0, 12))
        for _ in range(int(rng.choice([1, 2, 3, 15, 16, 17, 70, 400]))):
            cid = int(rng.integers(1, 5)) if rng.random() < 0.5 else 2
            seq += 1
            body = rng.integers(0, 256, size).astype(np.uint8).tobytes()
            t = int(rng.integers(0, 2**40))
            message = Message(
                channel_id=cid, sequence=seq, log_time=t, publish_time=t + 1, data=body
            )
            message.write(out)
        if rng.random() < 0.2:
            channel(9)
    data = out.end()

    def split(only):
        records: list = []
        rows, seen = chunks.split_chunk(data, records.append, later={2, 3}, only=only)
        return rows, seen, [r.id for r in records]

    for only in (None, {1}, {4, 9}):
        fast = split(only)
        monkeypatch.setattr(chunks, "_RUN_LEAST", 10**9)  # every record through the loop
        slow = split(only)
        monkeypatch.undo()
        assert fast == slow
        assert sum(n for n, _ in fast[1].values()) > 200 and len(fast[2]) >= 4
