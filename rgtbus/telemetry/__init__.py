"""MCAP telemetry: every step of a run as JSON messages with JSON Schemas (Foxglove-readable).

``McapRecorder(stream)`` for real runs, ``MemoryRecorder()`` for tests, ``NullRecorder()`` to
record nothing; ``read_log(path_or_stream)`` reads a log back (truncated files too).
"""

from rgtbus.telemetry.recorder import (
    LOG_LEVELS,
    LOG_TOPIC,
    LogContents,
    McapRecorder,
    MemoryRecorder,
    NullRecorder,
    Recorder,
    level_number,
    log_message,
    read_log,
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
    "Recorder",
    "level_number",
    "log_message",
    "read_log",
    "schema_for",
    "topics_markdown",
]
