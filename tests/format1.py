"""Format 1 (rgtbus before format 2, docs/format.md) written from a log of today: what an
rgtbus of format 1 wrote for the same run. The tests of ``rgtbus convert`` and of the readers'
refusal make their format-1 logs so (no log of an older writer is kept in the repository);
``tests/data/format1/frames.json`` holds what format 1's own reader gave."""

from __future__ import annotations

import io
import json
from pathlib import Path

from same_run import plain

from rgtbus.cli import main
from rgtbus.telemetry import blocks, pulse_blocks
from rgtbus.telemetry.version import FORMAT_RECORD

ROOT = Path(__file__).resolve().parent.parent


# Format 1 (rgtbus before format 2): every topic JSON, the hot ones under these schemas; no
# ``format`` record. A ``/tx/pulse`` record was one pulse.
FORMAT1_SCHEMAS = {
    "/medium": "rgtbus.MediumWindow",
    "/tx/pulse": "rgtbus.Pulse",
    "/rx/spike": "rgtbus.Spikes",
    "/rx/decode": "rgtbus.Decode",
    "/rx/decodes": "rgtbus.Decodes",
}


def as_format1(data: bytes, spikes=None, decodes=None) -> bytes:
    """The log as an rgtbus of format 1 wrote the same run: no ``format`` record, every hot
    topic JSON under format 1's schemas, one ``/tx/pulse`` record a pulse. ``spikes`` and
    ``decodes``: ``(t_ns, record) -> [(topic, t_ns, record), ...]``, the format-1 messages of
    a ``/rx/spike`` or ``/rx/decodes`` record (as JSON gives it back; default: that record)."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    def pulses(t_ns, record):
        return [("/tx/pulse", round(p["t"] * 1e9), p) for p in pulse_blocks.pulse_rows(record)]

    def each_unit(t_ns, record):  # format 1 wrote a unit's decodes a record of its own
        units = record.pop("units", None) or [record.pop("unit")]
        return [("/rx/decodes", t_ns, {"unit": u, **record}) for u in units]

    forms = {"/tx/pulse": pulses, "/rx/spike": spikes, "/rx/decodes": decodes or each_unit}
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    assert summary is not None
    buf = io.BytesIO()
    writer = Writer(buf, compression=CompressionType.ZSTD)
    writer.start(profile="", library="rgtbus 0.9 (format 1)")
    for record in reader.iter_metadata():
        if record.name != FORMAT_RECORD:
            writer.add_metadata(record.name, dict(record.metadata))
    channels: dict[str, int] = {}

    def channel(topic: str, schema_id: int) -> int:
        if topic not in channels:
            if blocks.schema_of(topic) is None and topic != "/rx/decode":
                s = summary.schemas[schema_id]
                sid = writer.register_schema(s.name, s.encoding, s.data)
            else:
                name = FORMAT1_SCHEMAS.get(topic, "rgtbus.ResonatorTrace")
                text = json.dumps({"title": name, "type": "object"}).encode()
                sid = writer.register_schema(name, "jsonschema", text)
            channels[topic] = writer.register_channel(topic, "json", sid)
        return channels[topic]

    held = []
    for _, c, m in reader.iter_messages(log_time_order=False):
        block = blocks.schema_of(c.topic)
        if block is None:
            held.append((m.log_time, c.topic, c.schema_id, m.data))
            continue
        record = blocks.decode_record(block, m.data, "the log")
        if c.topic != "/tx/pulse":
            record = json.loads(json.dumps(record, default=plain))
        form = forms.get(c.topic) or (lambda t_ns, rec, topic=c.topic: [(topic, t_ns, rec)])
        for topic, t_ns, old in form(m.log_time, record):
            held.append((t_ns, topic, c.schema_id, json.dumps(old, default=plain).encode()))
    for t_ns, topic, schema_id, body in sorted(held, key=lambda h: h[0]):
        writer.add_message(channel(topic, schema_id), t_ns, body, t_ns)
    writer.finish()
    return buf.getvalue()


def format1_log(name: str, path: Path) -> Path:
    """Shipped scenario ``name`` (its own seed) run now, its log written to ``path`` as format 1
    wrote it."""
    today = path.with_name(path.stem + "-today.mcap")
    scenario = str(ROOT / "scenarios" / f"{name}.toml")
    assert main(["run", scenario, "--bus", "memory", "--log", str(today), "--quiet"]) == 0
    path.write_bytes(as_format1(today.read_bytes()))
    today.unlink()
    return path
