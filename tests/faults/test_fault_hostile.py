"""Readers survive any log (issue 35): logs with valid CRCs and hostile content, made from a
real run's log by a generator, never make a reader raise. Each message of each topic is
mutated one way at a time (not JSON, a list for an object, a field missing, a string, a null,
a huge or negative number, a nested or empty list, an unknown unit; a hot topic's protobuf
block cut short, or a field of it missing, of another wire type, huge, negative, not a number,
doubled, empty or an unknown name), the file rewritten whole with mcap's own writer, and
every reader run on it in this process: ``info``, ``cat``, ``scenario``, ``merge``,
``replay`` (text and ``--json``), ``replay --verify`` and ``rgtbus.open_log`` with its
tables. Each answers with its result (exit 0, 3 for a cut log,
1 when ``--verify`` finds the tampered message disagrees with a re-run) or one line naming the
message (exit 2; the API raises ``RgtbusError``); none raises anything else. A chunk that
claims more than any chunk may hold is refused before it is decompressed.
"""

from __future__ import annotations

import contextlib
import functools
import io
import json
import random
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

import rgtbus
from rgtbus.cli import main
from rgtbus.errors import RgtbusError
from rgtbus.telemetry import blocks
from rgtbus.telemetry.chunks import MAX_CHUNK_BYTES
from rgtbus.telemetry.codec import BlockSchema, Field, decode, encode
from rgtbus.telemetry.scan import scan_log

ROOT = Path(__file__).parent.parent.parent
UNITS_FIELDS = ("unit", "sender", "addressee", "name", "subject")


@pytest.fixture(scope="module")
def gate_log(tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("hostile") / "gate.mcap"
    rgtbus.run(ROOT / "scenarios" / "gate.toml", log=path)
    return path.read_bytes()


def mutations(topic: str, data: bytes) -> Iterator[tuple[str, Any]]:
    """(what, the message ``data`` on ``topic`` changed one way: a value, or raw bytes)."""
    yield "not JSON", b"{not json"
    yield "a list", [1, 2, 3]
    schema = blocks.schema_of(topic)
    if schema is not None:
        yield from block_mutations(schema, data)
        return
    message = json.loads(data)
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


_MISSING, _WIRE = object(), object()  # a field left out; a field of another wire type


def block_mutations(schema: BlockSchema, data: bytes) -> Iterator[tuple[str, bytes]]:
    """(what, a hot topic's block ``data`` changed one way): cut short, a length past its
    end, an unknown field; each field missing, of another wire type, huge, negative, not a
    number, doubled, empty or an unknown name, as a hostile writer may write it (past every
    check of rgtbus's own recorder)."""
    yield "cut short", data[: len(data) // 2]
    yield "a length past the end", data + b"\x0a\xff\xff\x03"  # field 1: 65535 bytes
    yield "an unknown field", data + b"\xa2\x06\x01x"  # field 100, 1 byte: skipped
    fields = decode(schema, data, max_rows=blocks.MAX_ROWS)
    for f in schema.fields:
        for what, new in _field_mutations(f, fields[f.name]):
            if new is _WIRE:
                other = Field(f.name, f.number, "double" if f.kind == "string" else "string",
                              repeated=f.repeated)  # fmt: skip
                changed = BlockSchema(schema.name, tuple(other if g is f else g
                                                         for g in schema.fields))  # fmt: skip
                value: Any = ("x" if f.kind != "string" else 1.5) if not f.repeated else (
                    ["x"] if f.kind != "string" else np.array([1.5]))  # fmt: skip
                out = encode(changed, {**fields, f.name: value})
            else:
                rest = {k: v for k, v in fields.items() if k != f.name}
                out = encode(schema, rest if new is _MISSING else {**rest, f.name: new})
            if out != data:  # (a change that writes the same bytes is none)
                yield f"{f.name} {what}", out


def _field_mutations(f: Field, value: Any) -> Iterator[tuple[str, Any]]:
    yield "missing", _MISSING
    yield "of another wire type", _WIRE
    if f.kind == "string":
        names = value if f.repeated else [value]
        unknown = [f"zz_nobody{i}" for i in range(len(names))]
        yield "unknown", unknown if f.repeated else unknown[0]
        yield "huge", ["x" * 70_000] if f.repeated else "x" * 70_000  # > a text's bound
        if f.repeated:
            yield "doubled", [*value, *value]
            yield "empty", []
        return
    dtype = f.dtype
    extremes: list[tuple[str, Any]] = []
    if f.kind != "bool":
        top = np.finfo(dtype).max if dtype.kind == "f" else np.iinfo(dtype).max
        extremes.append(("huge", top))
        if dtype.kind in "if":
            extremes.append(("negative", -7))
        if dtype.kind == "f":
            extremes += [("not a number", np.nan), ("infinite", -np.inf)]
    for what, x in extremes:
        yield what, np.full(len(value), x, dtype=dtype) if f.repeated else dtype.type(x).item()
    if f.repeated:
        yield "doubled", np.concatenate([value, value])
        yield "empty", np.empty(0, dtype=np.bool_ if f.kind == "bool" else dtype)


# A message as a log holds it: (topic, log time, publish time, data).
Held = tuple[str, int, int, bytes]
Edit = tuple[list[Held], list[tuple[str, dict[str, str]]]]


def rebuilt(src: bytes, edit: Any) -> bytes:
    """``src`` with its messages and metadata records changed by ``edit(messages, metadata)``
    (each a list, changed in place or returned anew), written anew with mcap's own writer (its
    CRCs valid). A message on a topic ``src`` has no channel for gets one (schema-less)."""
    reader = make_reader(io.BytesIO(src))
    summary = reader.get_summary()
    assert summary is not None
    held: list[Held] = [(c.topic, m.log_time, m.publish_time, m.data)
                        for _, c, m in reader.iter_messages(log_time_order=False)]  # fmt: skip
    metadata = [(r.name, dict(r.metadata)) for r in reader.iter_metadata()]
    held, metadata = edit(held, metadata) or (held, metadata)
    out = io.BytesIO()
    writer = Writer(out, compression=CompressionType.ZSTD)
    writer.start(profile="", library="hostile")
    schemas = {sid: writer.register_schema(s.name, s.encoding, s.data)
               for sid, s in summary.schemas.items()}  # fmt: skip
    channels = {c.topic: writer.register_channel(c.topic, c.message_encoding,
                                                 schemas.get(c.schema_id, 0), c.metadata)
                for c in summary.channels.values()}  # fmt: skip
    for topic, log_time, publish_time, data in held:
        if topic not in channels:
            channels[topic] = writer.register_channel(topic, "json", 0, {})
        writer.add_message(channels[topic], log_time, data, publish_time)
    for name, values in metadata:
        writer.add_metadata(name, values)
    writer.finish()
    return out.getvalue()


def rewritten(src: bytes, topic: str, payload: Any, index: int = 0) -> bytes:
    """``src`` with the ``index``-th message on ``topic`` replaced by ``payload``."""

    def edit(held: list[Held], metadata: Any) -> None:
        at = [i for i, m in enumerate(held) if m[0] == topic][index]
        data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
        held[at] = (*held[at][:3], data)

    return rebuilt(src, edit)


def order_and_count_edits(src: bytes) -> Iterator[tuple[str, Any]]:
    """(what, edit) for records out of order, twice, or on a topic of someone else's; and
    metadata records damaged: each an ``edit`` for ``rebuilt``."""
    topics = sorted({c.topic for _, c, _ in make_reader(io.BytesIO(src)).iter_messages()})

    def first(held: list[Held], topic: str) -> int:
        return next(i for i, m in enumerate(held) if m[0] == topic)

    for topic in topics:
        def late(held: list[Held], md: Any, topic: str = topic) -> None:  # after everything
            i = first(held, topic)
            end = max(m[1] for m in held)
            held[i] = (topic, end + 10**9, end + 10**9, held[i][3])

        def early(held: list[Held], md: Any, topic: str = topic) -> None:  # the last, at 0
            i = max(i for i, m in enumerate(held) if m[0] == topic)
            held[i] = (topic, 0, 0, held[i][3])

        def twice(held: list[Held], md: Any, topic: str = topic) -> None:
            held.insert(first(held, topic), held[first(held, topic)])

        def swapped(held: list[Held], md: Any, topic: str = topic) -> None:  # contents swapped
            at = [i for i, m in enumerate(held) if m[0] == topic][:2]
            if len(at) == 2:
                a, b = at
                held[a], held[b] = (*held[a][:3], held[b][3]), (*held[b][:3], held[a][3])

        def dropped(held: list[Held], md: Any, topic: str = topic) -> None:
            del held[first(held, topic)]

        for what, edit in (("after the end", late), ("at time 0", early), ("twice", twice),
                           ("swapped", swapped), ("dropped", dropped)):  # fmt: skip
            yield f"{topic} {what}", edit

    def foreign(held: list[Held], md: Any) -> None:
        held.append(("/zz/other", 10**9, 10**9, b'{"unit": 1}'))
        held.append(("/zz/other", 2 * 10**9, 2 * 10**9, b"\x00\xff not json"))

    yield "a topic of someone else's", foreign
    names = [r.name for r in make_reader(io.BytesIO(src)).iter_metadata()]
    for name in dict.fromkeys(names):
        def gone(held: Any, md: list[tuple[str, dict[str, str]]], name: str = name) -> None:
            md[:] = [r for r in md if r[0] != name]

        yield f"metadata {name} gone", gone
        for bad in ("", "x", "1e400", "-1", "[1, 2]", "{}", "\u0000"):
            def damaged(held: Any, md: list[tuple[str, dict[str, str]]], name: str = name,
                        bad: str = bad) -> None:  # fmt: skip
                md[:] = [(n, {k: bad for k in v} if n == name else v) for n, v in md]

            yield f"metadata {name} every value {bad!r}", damaged


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


def first_messages(src: bytes) -> dict[str, bytes]:
    out: dict[str, bytes] = {}
    for _, channel, message in make_reader(io.BytesIO(src)).iter_messages():
        out.setdefault(channel.topic, message.data)
    return out


def hostile_logs(src: bytes) -> Iterator[tuple[str, Any]]:
    """(what, a function making the hostile log from ``src``): each topic's first message, and
    one drawn later in the log, changed every way ``mutations`` knows; records out of order,
    twice, dropped, or on a topic of someone else's; metadata records damaged or gone."""
    rng = random.Random(35)
    counts: dict[str, int] = {}
    for _, channel, _ in make_reader(io.BytesIO(src)).iter_messages():
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
    later = {t: rng.randrange(n) for t, n in counts.items()}
    for topic, message in first_messages(src).items():
        for what, payload in mutations(topic, message):
            yield f"{topic}: {what}", functools.partial(rewritten, src, topic, payload)
        nth = nth_message(src, topic, later[topic])
        for what, payload in mutations(topic, nth):
            yield (f"{topic} #{later[topic]}: {what}",
                   functools.partial(rewritten, src, topic, payload, later[topic]))  # fmt: skip
    for what, edit in order_and_count_edits(src):
        yield what, functools.partial(rebuilt, src, edit)


def nth_message(src: bytes, topic: str, n: int) -> bytes:
    got = [m.data for _, c, m in make_reader(io.BytesIO(src)).iter_messages(
        log_time_order=False) if c.topic == topic]  # fmt: skip
    return got[n]


@pytest.mark.slow  # every topic's every mutation through eight readers: several minutes
def test_no_hostile_log_makes_a_reader_raise(gate_log, tmp_path):
    wrong: dict[str, list[str]] = {}
    for what, make in hostile_logs(gate_log):
        path = tmp_path / "hostile.mcap"
        path.write_bytes(make())
        for line in read_every_way(path, tmp_path):
            wrong.setdefault(line, []).append(what)
    assert not wrong, {k: v[:3] for k, v in wrong.items()}


def test_a_sample_of_hostile_logs_makes_no_reader_raise(gate_log, tmp_path):
    """The fast suite's share of the generator: 10 hostile logs drawn with a fixed seed."""
    wrong: dict[str, list[str]] = {}
    for what, make in random.Random(35).sample(list(hostile_logs(gate_log)), 10):
        path = tmp_path / "hostile.mcap"
        path.write_bytes(make())
        for line in read_every_way(path, tmp_path):
            wrong.setdefault(line, []).append(what)
    assert not wrong, {k: v[:3] for k, v in wrong.items()}


@pytest.mark.parametrize(
    "what",
    [
        "/rx/decodes: margin not a number",
        "/rx/decodes: times not a number",
        "/tx/pulse: magnitude not a number",
        "/tx/pulse: tau huge",
    ],
)
def test_a_block_of_non_finite_numbers_is_named_not_a_traceback(gate_log, tmp_path, what):
    """Found by the generator: a block whose double column holds NaN, or a period so large
    its times overflow (a block's double holds any 64 bits; no JSON held them): every reader
    answers or names it in one line."""
    make = dict(hostile_logs(gate_log))[what]
    path = tmp_path / "hostile.mcap"
    path.write_bytes(make())
    assert read_every_way(path, tmp_path) == []


def bomb(src: bytes) -> bytes:
    """``src`` with its first chunk claiming 1 GiB once decompressed (its CRCs as they were)."""
    data = bytearray(src)
    at = 8  # after the magic: walk the records (opcode, u64 length, body) to the first chunk
    while data[at] != 0x06:
        at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
    # Chunk: opcode, length, message_start_time, message_end_time, uncompressed_size
    struct.pack_into("<Q", data, at + 9 + 16, 1 << 30)
    return bytes(data)


def test_a_chunk_claiming_gigabytes_is_refused_before_it_is_decompressed(gate_log, tmp_path):
    """A chunk's uncompressed size patched to 1 GiB (a bomb): every reader refuses it in one
    line naming the chunk, without allocating it."""
    assert MAX_CHUNK_BYTES < 1 << 30
    path = tmp_path / "bomb.mcap"
    path.write_bytes(bomb(gate_log))
    raw = scan_log(path)
    assert raw.corrupt and "claims 1073741824 bytes once decompressed" in raw.corruption
    assert read_every_way(path, tmp_path) == []


_MEASURE = """
import random, resource, sys
from pathlib import Path
sys.path[:0] = [{here!r}, {tests!r}]
import test_fault_hostile as H
src, out = Path(sys.argv[1]).read_bytes(), Path(sys.argv[2])
wrong = []
makers = [make for _, make in random.Random(7).sample(list(H.hostile_logs(src)), 40)]
for make in [*makers, lambda: H.bomb(src)]:
    (out / "hostile.mcap").write_bytes(make())
    wrong += H.read_every_way(out / "hostile.mcap", out)
# this process's own high-water mark (ru_maxrss would carry the parent's from the fork: a
# pytest that imported every test module, numba included, is past 300 MB before this starts)
hwm = [line for line in open("/proc/self/status") if line.startswith("VmHWM:")]
own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
peak = (int(hwm[0].split()[1]) if hwm else own) // 1024
print(peak, len(wrong))
"""


@pytest.mark.slow  # a fresh process through 40 hostile logs
def test_no_reader_takes_more_than_300_mb_on_hostile_logs(gate_log, tmp_path):
    """Every reader on 40 hostile logs in one fresh process, and a chunk bomb: its peak RSS
    (imports included) stays under 300 MB."""
    import subprocess
    import sys

    src = tmp_path / "gate.mcap"
    src.write_bytes(gate_log)
    here = Path(__file__).parent
    code = _MEASURE.format(here=str(here), tests=str(here.parent))
    done = subprocess.run([sys.executable, "-c", code, str(src), str(tmp_path)],
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    peak_mb, wrong = map(int, done.stdout.split())
    assert wrong == 0 and peak_mb < 300, (peak_mb, wrong)
    print(f"peak RSS {peak_mb} MB")  # for the record (pytest -s)
