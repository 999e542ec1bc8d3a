"""The MCAP topics: topic name -> schema name, the one table the recorder and the docs use.

Schemas live in ``schemas/<schema name>.json``; ``docs/topics.md`` is ``topics_markdown()``.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from functools import cache
from importlib import resources
from typing import Any

import orjson

from rgtbus.errors import BadInput, BadLog, IOFailure, RgtbusError
from rgtbus.telemetry import records as r
from rgtbus.timebase import seconds

# topic -> (schema name, what it carries)
TOPICS: dict[str, tuple[str, str]] = {
    r.MEDIUM: (
        "rgtbus.MediumBlock",
        "every window of the shared medium that carries a pulse (silent ones are not logged)",
    ),
    r.TX_PULSE: (
        "rgtbus.PulseBlock",
        "every transmitted pulse: one block a process's senders and 5 s, one row a pulse",
    ),
    r.RX_SPIKE: (
        "rgtbus.SpikeBlock",
        "every resonator spike, per receiving unit (or units that heard alike) and block: each "
        "spike's sample and channel",
    ),
    r.RX_DECODE: (
        "rgtbus.Decode",
        "every decoded code, one record each, as each is made: a live view's alone (the log "
        "holds them in /rx/decodes)",
    ),
    r.RX_DECODES: (
        "rgtbus.DecodeBlock",
        "every decoded code, per receiving unit and 5 s block: one column a field",
    ),
    r.UNIT_RELATIONS: ("rgtbus.Relations", "relationship table as a unit holds it"),
    r.UNIT_INFLUENCES: (
        "rgtbus.Influences",
        "influence table as a unit holds it, per influence round",
    ),
    r.UNIT_DECISION: (
        "rgtbus.Decision",
        "forward task and choice, per unit, subject and influence round",
    ),
    r.UNIT_GOAL: (
        "rgtbus.Goal",
        "a goal-driven unit's influence on a target, chosen by the inverse task",
    ),
    r.UNIT_REPORT: (
        "rgtbus.UnitReport",
        "what a unit knows at the end of its run: its share of the run summary",
    ),
    r.LOG: ("foxglove.Log", "text log lines (Foxglove's Log panel)"),
    r.SCENE: (
        "foxglove.SceneUpdate",
        "a spatial scenario's units on Foxglove's 3D panel: each unit's sphere and name, then "
        "its half of each link, green for an alliance and red for a conflict as it holds it",
    ),
    r.CONTROL_PARAMETER: (
        "rgtbus.ControlParameter",
        "a steered run's parameter changes (`--control`): who set what, from, to, at which "
        "window boundary, or why it was refused",
    ),
    r.CONTROL_SERVICE: (
        "rgtbus.ControlService",
        "a steered run's service calls (pause, resume, step, relation, influence, mark): "
        "applied or refused, and what they changed",
    ),
    r.RUN: ("rgtbus.RunSummary", "how the run ended, written last"),
}

# Topic families with a unit name in them: (display form, regex, schema, what it carries).
_UNIT = r"[A-Za-z0-9_][A-Za-z0-9_.\-]*"
TOPIC_PATTERNS: tuple[tuple[str, re.Pattern[str], str, str], ...] = (
    (
        r.trace_topic("<unit>"),
        re.compile(rf"^{re.escape(r.TRACE_PREFIX)}{_UNIT}$"),
        "rgtbus.TraceBlock",
        "resonator states per sample (optional, `--traces`)",
    ),
)

# Metadata records (besides scenario, run, frequencies, codebook, merge): a unit run as its own
# process says how it ended in ``end.<unit>``: {"status": "done" or "ended early", "detail",
# "sim_seconds"}. A merge whose unit processes did not all end "done" is incomplete
# (docs/protocol.md).
UNIT_END_PREFIX = "end."
UNIT_DONE = "done"
UNIT_ENDED_EARLY = "ended early"


def unit_end_record(unit: str) -> str:
    """The name of the metadata record saying how ``unit``'s process ended."""
    return f"{UNIT_END_PREFIX}{unit}"


SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"

def is_block_schema(name: str) -> bool:
    """Whether schema ``name`` is a hot topic's protobuf block (else a JSON Schema)."""
    from rgtbus.telemetry.blocks import SCHEMAS

    return name in SCHEMAS


def encodings(name: str) -> tuple[str, str]:
    """(schema encoding, message encoding) of the channels of schema ``name``."""
    from rgtbus.telemetry import blocks

    if is_block_schema(name):
        return blocks.SCHEMA_ENCODING, blocks.MESSAGE_ENCODING
    return SCHEMA_ENCODING, MESSAGE_ENCODING


def schema_for(topic: str) -> str:
    """The schema name of ``topic``; RgtbusError for a topic not in the table."""
    entry = TOPICS.get(topic)
    if entry is not None:
        return entry[0]
    for _, pattern, schema, _ in TOPIC_PATTERNS:
        if isinstance(topic, str) and pattern.match(topic):
            return schema
    known = [*TOPICS, *(p[0] for p in TOPIC_PATTERNS)]
    raise BadInput(f"unknown telemetry topic {topic!r} (known: {', '.join(known)})")


def schema_names() -> list[str]:
    """Every schema the table uses, in table order, each once."""
    names = [s for s, _ in TOPICS.values()] + [p[2] for p in TOPIC_PATTERNS]
    return list(dict.fromkeys(names))


@cache
def schema_bytes(name: str) -> bytes:
    """The schema's bytes, as registered in MCAP: a block's ``FileDescriptorSet``, else the
    JSON Schema file's bytes."""
    if is_block_schema(name):
        from rgtbus.telemetry.blocks import descriptor

        return descriptor(name)
    try:
        return (resources.files("rgtbus.telemetry") / "schemas" / f"{name}.json").read_bytes()
    except FileNotFoundError:
        raise IOFailure(f"no schema file for {name!r} in rgtbus/telemetry/schemas") from None


@cache
def load_schema(name: str) -> dict[str, Any]:
    """The schema ``name``, parsed (once)."""
    schema: dict[str, Any] = json.loads(schema_bytes(name))
    return schema


def checked_message(
    topic: str,
    t_ns: int,
    message: Any,
    label: str,
    check: bool = True,
    tables: SharedTables | None = None,
) -> Any:
    """A message as a reader may use it: decoded from its JSON (where still bytes) and, with
    ``check``, checked against its topic's schema (a topic not rgtbus's is taken as it is).
    Not JSON, or breaking the schema: RgtbusError naming the log, the topic, the log time and
    what is wrong. A hot topic's block (``blocks``) is decoded and checked as it is read,
    whatever ``check`` says: its checks are what keep a reader's memory bounded."""
    from rgtbus.telemetry import blocks, validate

    where = f"{label}: message on {topic} at t = {seconds(t_ns):.3f} s"
    block = blocks.schema_of(topic)
    if block is not None:
        if not isinstance(message, bytes | bytearray | memoryview):
            return message  # decoded already
        return blocks.decode_record(block, bytes(message), where)
    if isinstance(message, bytes | bytearray | memoryview):
        try:
            message = orjson.loads(message)
        except ValueError as e:
            raise BadLog(f"{where} is not JSON: {e}") from None
    if not check:
        return message
    try:
        schema = schema_for(topic)
    except RgtbusError:
        return message  # someone else's topic: not ours to read
    rules = load_schema(schema)
    if tables is not None and tables.known(topic, message, lambda m: not validate.errors(m, rules)):
        return message  # its large tables are ones checked before: held once
    errs = validate.errors(message, rules)
    if errs:
        raise BadLog(f"{where} breaks {schema}: {errs[0]}")
    if tables is not None:
        tables.keep(topic, message)
    return message


class SharedTables:
    """The large tables (objects of ``LARGE`` entries or more) that messages of one topic
    hold alike, checked once and held once: every unit's ``/unit/relations`` holds the n²
    pairs its group agreed on, and a 100-unit log's 300 such tables were 3 s of schema
    checks and 1.3 GB as Python objects, for a handful of distinct tables."""

    LARGE = 64

    def __init__(self) -> None:
        self._held: dict[tuple[str, str], dict[str, Any]] = {}

    def known(self, topic: str, message: Any, valid: Callable[[Any], bool]) -> bool:
        """Whether ``message`` is valid (``valid``) with each large table that equals one
        held in its place: checked as the message with those tables empty (an object the
        schemas of such tables take), then made to hold the held ones. False: check it
        whole."""
        if type(message) is not dict:
            return False
        same = [
            k for k, v in message.items()
            if type(v) is dict and len(v) >= self.LARGE and self._held.get((topic, k)) == v
        ]  # fmt: skip
        if not same or not valid({**message, **{k: {} for k in same}}):
            return False
        for k in same:
            message[k] = self._held[(topic, k)]
        return True

    def keep(self, topic: str, message: Any) -> None:
        """Hold the large tables of ``message``, checked whole."""
        if type(message) is dict:
            for k, v in message.items():
                if type(v) is dict and len(v) >= self.LARGE:
                    self._held[(topic, k)] = v


# -- docs -----------------------------------------------------------------------------------


def _type_text(s: dict[str, Any]) -> str:
    if "const" in s:
        return json.dumps(s["const"])
    if "enum" in s:
        return " or ".join(json.dumps(v) for v in s["enum"])
    if "oneOf" in s:
        return " or ".join(
            f"{_type_text(o)} ({o['title']})" if "title" in o else _type_text(o) for o in s["oneOf"]
        )
    types = s.get("type")
    if types is None:
        return "any"
    parts = []
    for t in [types] if isinstance(types, str) else types:
        if t == "array" and "items" in s:
            parts.append(f"array of {_type_text(s['items'])}")
        elif t == "object" and isinstance(s.get("additionalProperties"), dict):
            parts.append(f"map to {_type_text(s['additionalProperties'])}")
        else:
            parts.append(t)
    return " or ".join(parts)


def _field_rows(schema: dict[str, Any], prefix: str = "") -> list[str]:
    rows = []
    required = set(schema.get("required", ()))
    # a oneOf of required fields: exactly one of them is present
    either = [k for sub in schema.get("oneOf", ()) for k in sub.get("required", ())]
    for name, sub in schema.get("properties", {}).items():
        path = f"{prefix}{name}"
        desc = sub.get("description", "").replace("|", "\\|")
        req = "yes" if name in required else "no"
        if name in either:
            req = "one of " + ", ".join(f"`{k}`" for k in either)
        rows.append(
            f"| `{path}` | {_type_text(sub).replace('|', chr(92) + '|')} | {req} | {desc} |"
        )
        if sub.get("type") == "object" and "properties" in sub:
            rows.extend(_field_rows(sub, prefix=f"{path}."))
    return rows


def topics_markdown() -> str:
    """docs/topics.md: the topic table and every schema's fields."""
    lines = [
        "# MCAP topics",
        "",
        "<!-- Generated by rgtbus.telemetry.topics.topics_markdown(); do not edit by hand. -->",
        "",
        "Log format 2 (docs/format.md). The hot topics (pulses, spikes, decodes, the medium,",
        "traces) are protobuf blocks of columns (schema encoding `protobuf`: a",
        "`FileDescriptorSet`); every other topic is JSON (message encoding `json`) with a JSON",
        "Schema (schema encoding `jsonschema`). Foxglove decodes both. `log_time` =",
        "`publish_time` = simulated time in integer nanoseconds. Times `t` inside messages are",
        "simulated seconds; alternatives are sorted lists of action names (`[]` is 0).",
        "",
        "| Topic | Schema | Encoding | Carries |",
        "| --- | --- | --- | --- |",
    ]
    for topic, (schema, what) in TOPICS.items():
        lines.append(f"| `{topic}` | `{schema}` | {encodings(schema)[1]} | {what} |")
    for display, _, schema, what in TOPIC_PATTERNS:
        lines.append(f"| `{display}` | `{schema}` | {encodings(schema)[1]} | {what} |")
    for name in schema_names():
        if is_block_schema(name):
            from rgtbus.telemetry.blocks import SCHEMAS
            from rgtbus.telemetry.codec import proto_text

            lines += [
                "",
                f"## `{name}`",
                "",
                "A block of columns (message encoding `protobuf`; its `FileDescriptorSet` is the "
                "channel's schema): each `repeated` field a packed column, one entry a row; "
                "columns of one table hold one entry each per row (docs/format.md).",
                "",
                "```text",
                *proto_text(SCHEMAS[name]).rstrip("\n").split("\n"),
                "```",
            ]
            continue
        body = load_schema(name)
        lines += [
            "",
            f"## `{name}`",
            "",
            body.get("description", ""),
            "",
            "| Field | Type | Required | Description |",
            "| --- | --- | --- | --- |",
            *_field_rows(body),
        ]
    return "\n".join(lines) + "\n"
