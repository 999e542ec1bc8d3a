"""Readers survive any log (issue 35): logs with valid CRCs and hostile content, made from a
real run's log by a generator, never make a reader raise. Each message of each topic is
mutated one way at a time (not JSON, a list for an object, a field missing, a string, a null,
a huge or negative number, a nested or empty list, an unknown unit), the file rewritten whole
with mcap's own writer, and every reader run on it in this process: ``info``, ``cat``,
``scenario``, ``merge``, ``replay`` (text and ``--json``), ``replay --verify`` and
``rgtbus.open_log`` with its tables. Each answers with its result (exit 0, 3 for a cut log,
1 when ``--verify`` finds the tampered message disagrees with a re-run) or one line naming the
message (exit 2; the API raises ``RgtbusError``); none raises anything else. A chunk that
claims more than any chunk may hold is refused before it is decompressed.
"""

from __future__ import annotations

import contextlib
import io
import json
import random
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

import rgtbus
from rgtbus.cli import main
from rgtbus.errors import RgtbusError
from rgtbus.telemetry.scan import MAX_CHUNK_BYTES, scan_log

ROOT = Path(__file__).parent.parent.parent
UNITS_FIELDS = ("unit", "sender", "addressee", "name", "subject")


@pytest.fixture(scope="module")
def gate_log(tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("hostile") / "gate.mcap"
    rgtbus.run(ROOT / "scenarios" / "gate.toml", log=path)
    return path.read_bytes()


def mutations(message: Any) -> Iterator[tuple[str, Any]]:
    """(what, the message changed one way: a value, or raw bytes)."""
    yield "not JSON", b"{not json"
    yield "a list", [1, 2, 3]
    if not isinstance(message, dict):
        return
    for key, value in message.items():
        for what, new in (("missing", None), ("a string", "x"), ("null", None),
                          ("huge", 10**30), ("negative", -7)):  # fmt: skip
            changed = dict(message)
            if what == "missing":
                del changed[key]
            else:
                changed[key] = new
            yield f"{key} {what}", changed
        if isinstance(value, list):
            yield f"{key} nested", {**message, key: [value, value]}
            yield f"{key} empty", {**message, key: []}
        if key in UNITS_FIELDS:
            yield f"{key} unknown", {**message, key: "zz_nobody"}


def rewritten(src: bytes, topic: str, payload: Any) -> bytes:
    """``src`` with the first message on ``topic`` replaced by ``payload``, written anew (its
    CRCs valid)."""
    reader = make_reader(io.BytesIO(src))
    summary = reader.get_summary()
    assert summary is not None
    out = io.BytesIO()
    writer = Writer(out, compression=CompressionType.ZSTD)
    writer.start(profile="", library="hostile")
    schemas = {sid: writer.register_schema(s.name, s.encoding, s.data)
               for sid, s in summary.schemas.items()}  # fmt: skip
    channels = {cid: writer.register_channel(c.topic, c.message_encoding,
                                             schemas.get(c.schema_id, 0), c.metadata)
                for cid, c in summary.channels.items()}  # fmt: skip
    done = False
    for _, channel, message in reader.iter_messages(log_time_order=False):
        data = message.data
        if channel.topic == topic and not done:
            data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
            done = True
        writer.add_message(channels[channel.id], message.log_time, data, message.publish_time)
    for record in reader.iter_metadata():
        writer.add_metadata(record.name, record.metadata)
    writer.finish()
    return out.getvalue()


READERS = (["info"], ["cat"], ["scenario"], ["replay"], ["replay", "--json"],
           ["replay", "--verify"], ["merge"], ["open_log"])  # fmt: skip


def read_every_way(path: Path, out_dir: Path) -> list[str]:
    """Every reader on ``path``; what each did that it must not (a raise, an exit code other
    than 0, 2 and 3, or an exit 2 with more than one line)."""
    wrong = []
    for reader in READERS:
        err = io.StringIO()
        try:
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
                if reader == ["open_log"]:
                    with contextlib.suppress(RgtbusError):
                        log = rgtbus.open_log(path)
                        log.summary(), log.decisions(), log.decodes(), log.spikes()
                        log.transmissions(), log.medium()
                    continue
                args = [reader[0], str(path), *reader[1:]]
                if reader == ["merge"]:
                    args += ["-o", str(out_dir / "merged.mcap")]
                code = main(args)
        except Exception as exc:  # the point of the test: nothing may get here
            wrong.append(f"{' '.join(reader)}: {type(exc).__name__}: {exc}")
            continue
        lines = err.getvalue().strip().splitlines()
        # 1: --verify found the tampered message disagrees with a re-run (its answer)
        allowed = (0, 1, 2, 3) if "--verify" in reader else (0, 2, 3)
        if code not in allowed or (code == 2 and len(lines) != 1):
            wrong.append(f"{' '.join(reader)}: exit {code}: {lines[-3:]}")
    return wrong


def first_messages(src: bytes) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for _, channel, message in make_reader(io.BytesIO(src)).iter_messages():
        out.setdefault(channel.topic, json.loads(message.data))
    return out


@pytest.mark.slow  # every topic's every mutation through eight readers: a few minutes
def test_no_hostile_message_makes_a_reader_raise(gate_log, tmp_path):
    wrong: dict[str, list[str]] = {}
    for topic, message in first_messages(gate_log).items():
        for what, payload in mutations(message):
            path = tmp_path / "hostile.mcap"
            path.write_bytes(rewritten(gate_log, topic, payload))
            for line in read_every_way(path, tmp_path):
                wrong.setdefault(line, []).append(f"{topic}: {what}")
    assert not wrong, {k: v[:3] for k, v in wrong.items()}


def test_a_sample_of_hostile_messages_makes_no_reader_raise(gate_log, tmp_path):
    """The fast suite's share of the generator: 24 mutations drawn with a fixed seed."""
    cases = [(topic, what, payload) for topic, message in first_messages(gate_log).items()
             for what, payload in mutations(message)]  # fmt: skip
    wrong: dict[str, list[str]] = {}
    for topic, what, payload in random.Random(35).sample(cases, 24):
        path = tmp_path / "hostile.mcap"
        path.write_bytes(rewritten(gate_log, topic, payload))
        for line in read_every_way(path, tmp_path):
            wrong.setdefault(line, []).append(f"{topic}: {what}")
    assert not wrong, {k: v[:3] for k, v in wrong.items()}


def test_a_chunk_claiming_gigabytes_is_refused_before_it_is_decompressed(gate_log, tmp_path):
    """A chunk's uncompressed size patched to 1 GiB (a bomb): every reader refuses it in one
    line naming the chunk, without allocating it."""
    data = bytearray(gate_log)
    at = 8  # after the magic: walk the records (opcode, u64 length, body) to the first chunk
    while data[at] != 0x06:
        at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
    # Chunk: opcode, length, message_start_time, message_end_time, uncompressed_size
    struct.pack_into("<Q", data, at + 9 + 16, 1 << 30)
    assert MAX_CHUNK_BYTES < 1 << 30
    path = tmp_path / "bomb.mcap"
    path.write_bytes(bytes(data))
    raw = scan_log(path)
    assert raw.corrupt and "claims 1073741824 bytes once decompressed" in raw.corruption
    assert read_every_way(path, tmp_path) == []
