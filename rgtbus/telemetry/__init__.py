"""MCAP telemetry: every step of a run as JSON messages with JSON Schemas (Foxglove-readable).

``McapRecorder(stream)`` for real runs, ``MemoryRecorder()`` for tests, ``NullRecorder()`` to
record nothing; ``read_log(path_or_stream)`` reads a log back (truncated files too),
``scan_log`` its undecoded records. Reading a run back: ``replay`` (timeline, summary,
verification against a re-run), ``merge`` (per-process logs into one), ``plots`` (figures).
"""

from rgtbus.telemetry.recorder import (
    LOG_LEVELS,
    LOG_TOPIC,
    LogContents,
    McapRecorder,
    MemoryRecorder,
    NullRecorder,
    RawLog,
    Recorder,
    decode_log,
    level_number,
    log_message,
    read_log,
    require_run_log,
    scan_log,
)
from rgtbus.telemetry.topics import TOPIC_PATTERNS, TOPICS, schema_for, topics_markdown

__all__ = [
    "LOG_LEVELS",
    "LOG_TOPIC",
    "TOPICS",
    "TOPIC_PATTERNS",
    "LogContents",
    "McapRecorder",
    "MemoryRecorder",
    "NullRecorder",
    "RawLog",
    "Recorder",
    "decode_log",
    "level_number",
    "log_message",
    "read_log",
    "require_run_log",
    "scan_log",
    "schema_for",
    "topics_markdown",
]
