"""Every kind of file rgtbus writes passes a reader no one here wrote: ``pymcap-cli doctor``
(the MCAP container specification, checked record by record). A run's log, each unit's log and
the merged ``run.mcap`` of a launch, a log cut by ``kill -9``, and ``recover``'s, ``merge``'s
and ``convert``'s outputs. An error fails; so does a warning (none is expected:
docs/foxglove.md, "Checked by other readers"). Infos (messages out of log-time order inside a
chunk, no attachments, a cut log without a summary) are the file as the specification allows
it."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest
from cut_logs import EXE, ROOT, paced_run
from format1 import format1_log

GATE = ROOT / "scenarios" / "gate.toml"
DOCTOR = shutil.which("pymcap-cli", path=str(Path(sys.executable).parent)) or shutil.which(
    "pymcap-cli"
)


def doctor(path: Path) -> Counter[tuple[str, str]]:
    """``pymcap-cli doctor``'s findings for ``path``: (severity, code) -> count. Its exit status
    must agree (0 with no error)."""
    assert DOCTOR, "pymcap-cli is a test dependency (pyproject.toml [test])"
    out = subprocess.run([DOCTOR, "doctor", str(path), "--format", "jsonl"], capture_output=True,
                         text=True, timeout=120)  # fmt: skip
    found: Counter[tuple[str, str]] = Counter()
    for line in out.stdout.splitlines():
        record = json.loads(line)
        if record.get("type") == "finding":
            found[(record["severity"], record["code"])] += 1
    errors = sum(n for (severity, _), n in found.items() if severity == "error")
    assert (out.returncode == 0) == (errors == 0), (out.returncode, found, out.stderr)
    return found


def unordered_chunks(path: Path) -> dict[str, int]:
    """Per topic, the chunks (in file order) that hold a message earlier in log time than one
    of an earlier chunk of that topic: what ``rerun mcap check`` reports as "unordered chunks
    on message_log_time" (readers that index a file by its chunks' times, Foxglove's player
    among them, then read a topic's chunks out of order)."""
    from mcap.records import Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk

    latest: dict[int, int] = {}
    bad: Counter[int] = Counter()
    topics: dict[int, str] = {}
    with open(path, "rb") as f:
        for record in StreamReader(f, emit_chunks=True).records:
            if not isinstance(record, Chunk):
                continue
            first: dict[int, int] = {}
            last: dict[int, int] = {}
            for inner in breakup_chunk(record, validate_crc=True):
                if isinstance(inner, Message):
                    cid, t = inner.channel_id, inner.log_time
                    first[cid] = min(first.get(cid, t), t)
                    last[cid] = max(last.get(cid, t), t)
                elif hasattr(inner, "topic"):
                    topics[inner.id] = inner.topic
            for cid, t in first.items():
                if t < latest.get(cid, -1):
                    bad[cid] += 1
                latest[cid] = max(latest.get(cid, -1), last[cid])
    return {topics.get(cid, str(cid)): n for cid, n in bad.items()}


RERUN = os.environ.get("RGTBUS_RERUN") or shutil.which("rerun")


def rerun_problems(path: Path) -> list[str]:
    """The topics ``rerun mcap check`` (rerun-sdk) reports a problem with, as its lines. A
    cut log has no summary (as the specification allows): rerun reads it with ``--recover``,
    as it asks."""
    assert RERUN
    argv = [RERUN, "mcap", "check", str(path)]
    out = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    if out.returncode and "summary is missing" in out.stderr:
        out = subprocess.run([*argv, "--recover"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return [line for line in out.stdout.splitlines() if line.startswith("PROBLEM")]


def _rgtbus(*argv: str) -> None:
    done = subprocess.run([*EXE, *argv], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One file of each kind, by what wrote it."""
    tmp = tmp_path_factory.mktemp("doctor")
    files = {"run": tmp / "run.mcap"}
    _rgtbus("run", str(GATE), "--log", str(files["run"]), "--quiet")
    launched = tmp / "launch"
    _rgtbus("launch", str(GATE), "--procs", "2", "--log-dir", str(launched))
    merged = ("run.mcap", "launch.mcap")
    unit_logs = sorted(p for p in launched.glob("*.mcap") if p.name not in merged)
    assert unit_logs
    files["unit"] = unit_logs[0]
    files["launch's merge"] = launched / "run.mcap"
    files["launcher's own"] = launched / "launch.mcap"
    files["cut by kill -9"] = tmp / "killed.mcap"
    with paced_run(files["cut by kill -9"], 100) as proc:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    files["recover of a killed log"] = tmp / "recovered.mcap"
    _rgtbus("recover", str(files["cut by kill -9"]), "-o", str(files["recover of a killed log"]))
    # a file cut mid-record, with nothing whole in it: recover writes a file with no message
    headless = tmp / "headless.mcap"
    headless.write_bytes(files["run"].read_bytes()[:3000])
    files["recover of a file with no message"] = tmp / "recovered-empty.mcap"
    _rgtbus("recover", str(headless), "-o", str(files["recover of a file with no message"]))
    files["merge"] = tmp / "merged.mcap"
    _rgtbus("merge", *map(str, unit_logs), "-o", str(files["merge"]))
    files["merge of a cut and a whole log"] = tmp / "merged-cut.mcap"
    _rgtbus("merge", str(files["cut by kill -9"]), str(files["run"]), "-o",
            str(files["merge of a cut and a whole log"]))  # fmt: skip
    old = format1_log("crowd10", tmp / "format1.mcap")
    files["convert of a format-1 log"] = tmp / "converted.mcap"
    _rgtbus("convert", str(old), "-o", str(files["convert of a format-1 log"]))
    cut = tmp / "cut-format1.mcap"
    cut.write_bytes(old.read_bytes()[:-2000])  # its summary cut
    files["convert of a cut format-1 log"] = tmp / "converted-cut.mcap"
    _rgtbus("convert", str(cut), "-o", str(files["convert of a cut format-1 log"]))
    return files


KINDS = [
    "run",
    "unit",
    "launch's merge",
    "launcher's own",
    "cut by kill -9",
    "recover of a killed log",
    "recover of a file with no message",
    "merge",
    "merge of a cut and a whole log",
    "convert of a format-1 log",
    "convert of a cut format-1 log",
]


@pytest.mark.slow  # a run, a launch, a paced run killed, merges: ~9 s (CI's slow pass runs it)
@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_of_written_file_passes_doctor(written, kind):
    found = doctor(written[kind])
    bad = {key: n for key, n in found.items() if key[0] in ("error", "warning")}
    assert not bad, f"{kind}: {bad}"


@pytest.mark.slow  # the files above (CI's slow pass runs it)
@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_of_written_file_has_each_topic_s_chunks_in_time_order(written, kind):
    assert unordered_chunks(written[kind]) == {}, kind


@pytest.mark.slow  # the files above (CI's slow pass runs it, rerun-sdk installed by .ci/run)
@pytest.mark.skipif(RERUN is None, reason="no rerun (rerun-sdk): .ci/run installs one for CI")
@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_of_written_file_passes_rerun_s_check(written, kind):
    assert rerun_problems(written[kind]) == [], kind


@pytest.mark.parametrize("name", ["group20", "gate_repair", "tug_of_war"])
def test_a_run_s_log_has_each_topic_s_chunks_in_time_order(tmp_path, name):
    """Units plan sends ahead and tell spikes late; the recorder holds what comes early and
    writes each topic in log-time order (``Recorder.advance``), chunk after chunk (a
    20-unit run's /log and /rx/spike had chunks out of order before). Chunks of a message
    each find any disorder."""
    from rgtbus.units.group import run_group

    from rgtbus.scenario import load_scenario
    from rgtbus.telemetry import McapRecorder

    path = tmp_path / f"{name}.mcap"
    with open(path, "wb") as f:
        rec = McapRecorder(f, chunk_size=4096)
        run_group(load_scenario(ROOT / "scenarios" / f"{name}.toml"), "memory", rec)
        rec.close()
    assert unordered_chunks(path) == {}


def test_the_chunk_order_check_can_fail(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "late.mcap"
    with open(path, "wb") as f:
        writer = Writer(f, chunk_size=10)
        writer.start()
        writer.register_schema("s", "jsonschema", b"{}")
        cid = writer.register_channel("/t", "json", 1)
        for t in (5, 9, 7):  # the third chunk starts before the second ended
            writer.add_message(cid, t, b"{}", t)
        writer.finish()
    assert unordered_chunks(path) == {"/t": 1}


def test_doctor_sees_what_merge_once_wrote(tmp_path):
    """The check can fail: mcap's writer left as it was (a summary offset for every kind it
    indexes, attachments included, with none written) is the file doctor rejected."""
    from mcap.writer import Writer

    path = tmp_path / "offsets.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        writer.add_metadata("m", {"k": "v"})
        writer.finish()
    assert ("error", "SUMMARY_OFFSET_WITHOUT_GROUP") in doctor(path)


def _library_message(schema, cache: dict):
    """The protobuf library's class for a channel's schema, from its FileDescriptorSet alone
    (what Foxglove does, with protobufjs)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    if schema.id not in cache:
        fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
        pool = descriptor_pool.DescriptorPool()
        for f in fds.file:
            pool.Add(f)
        cache[schema.id] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
    return cache[schema.id]


@pytest.mark.slow  # the files above (CI's slow pass runs it)
@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_of_written_file_reads_whole_in_the_python_readers(written, kind):
    """Python ``mcap``'s seeking and streaming readers read every message, CRCs checked, in
    the same order; the protobuf library decodes every block from the file's own schema to the
    values rgtbus reads (``blocks.decode_record``); every JSON message is JSON."""
    import io

    import numpy as np
    from mcap.reader import NonSeekingReader, make_reader

    from rgtbus.telemetry import blocks

    data = written[kind].read_bytes()
    seeking = list(make_reader(io.BytesIO(data), validate_crcs=True).iter_messages())
    streaming = list(NonSeekingReader(io.BytesIO(data), validate_crcs=True).iter_messages())
    assert [(c.topic, m.log_time, m.data) for _, c, m in seeking] == [
        (c.topic, m.log_time, m.data) for _, c, m in streaming
    ]
    classes: dict = {}
    hot = 0
    for schema, channel, message in seeking:
        if channel.message_encoding == "json":
            json.loads(message.data)
            continue
        assert channel.message_encoding == "protobuf" and schema.encoding == "protobuf"
        theirs = _library_message(schema, classes).FromString(message.data)
        ours = blocks.decode_record(blocks.SCHEMAS[schema.name], message.data, channel.topic)
        for field in blocks.SCHEMAS[schema.name].fields:
            mine, got = ours.get(field.name), getattr(theirs, field.name)
            if field.repeated and field.kind != "string":
                assert np.array_equal(np.asarray(mine), np.asarray(list(got))), field.name
            elif field.name in ours:
                assert mine == (list(got) if field.repeated else got), field.name
        hot += 1
    assert hot or kind in ("launcher's own", "recover of a file with no message"), kind


NODE = shutil.which("node")
JS = Path(__file__).parent / "js"


def _camel(name: str) -> str:
    head, *rest = name.split("_")
    return head + "".join(part[:1].upper() + part[1:] for part in rest)


@pytest.mark.slow  # the files above (CI's slow pass runs it, after npm ci --prefix tests/js)
@pytest.mark.skipif(
    NODE is None or shutil.which("npm") is None,
    reason="no Node.js and npm on this machine (where they are, .ci/run installs the readers)",
)
@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_of_written_file_reads_whole_in_foxglove_s_readers(written, kind):
    """@mcap/core reads the file whole, CRCs checked, and protobufjs decodes every block from
    the file's own schema (what Foxglove does) to the values rgtbus reads; JSON to its JSON."""
    import numpy as np
    from mcap.reader import make_reader

    from rgtbus.telemetry import blocks

    assert (JS / "node_modules").is_dir(), "npm ci --prefix tests/js (as .ci/run does)"
    done = subprocess.run([NODE, str(JS / "check.mjs"), str(written[kind])],
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    theirs = [json.loads(line) for line in done.stdout.splitlines()]
    for m in theirs:  # a block's defaults (empty columns too), as left out below
        if blocks.schema_of(m["topic"]) is not None:
            m["value"] = {k: v for k, v in m["value"].items() if v not in ("", 0, False, [])}
    with open(written[kind], "rb") as f:
        ours = [(s, c, m) for s, c, m in make_reader(f).iter_messages(log_time_order=False)]
    assert len(theirs) == len(ours)
    by_time = sorted(_norm(m) for m in theirs)
    mine = []
    for schema, channel, message in ours:
        if channel.message_encoding == "json":
            value = json.loads(message.data)
        else:
            block = blocks.SCHEMAS[schema.name]
            record = blocks.decode_record(block, message.data, channel.topic)
            value = {}
            for f in block.fields:  # as protobufjs gives it: defaults left out, names in camel
                v = record.get(f.name)
                v = v.tolist() if isinstance(v, np.ndarray) else v
                if v not in (None, "", 0, 0.0, False, []):
                    value[_camel(f.name)] = v
        mine.append({"topic": channel.topic, "log_time": message.log_time, "value": value})
    assert by_time == sorted(_norm(m) for m in mine)


def _norm(message: dict) -> tuple[int, str, str]:
    """A message as (log time, topic, its value as canonical JSON, every number a float):
    JavaScript writes 200 where Python writes 200.0, and orders keys as it read them."""

    def floats(v):
        if isinstance(v, dict):
            return {k: floats(x) for k, x in v.items()}
        if isinstance(v, list):
            return [floats(x) for x in v]
        return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else v

    value = json.dumps(floats(message["value"]), sort_keys=True)
    return message["log_time"], message["topic"], value
