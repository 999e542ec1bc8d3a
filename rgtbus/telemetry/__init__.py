"""MCAP telemetry: every step of a run as JSON messages with JSON Schemas (Foxglove-readable).

``McapRecorder(stream)`` for real runs, ``MemoryRecorder()`` for tests, ``NullRecorder()`` to
record nothing; ``read_log(path_or_stream)`` reads a log back (truncated files too),
``scan_log`` its undecoded records (``rgtbus.telemetry.scan``, loaded on first use). Reading
a run back: ``replay`` (timeline, summary, verification against a re-run), ``merge``
(per-process logs into one), ``plots`` (figures).
"""

from typing import TYPE_CHECKING, Any

from rgtbus.telemetry.mcap_recorder import McapRecorder
from rgtbus.telemetry.message_json import LOG_LEVELS, level_number, log_message
from rgtbus.telemetry.recorder import LogContents, MemoryRecorder, NullRecorder, Recorder
from rgtbus.telemetry.topics import TOPIC_PATTERNS, TOPICS, schema_for, topics_markdown

if TYPE_CHECKING:
    from rgtbus.telemetry.scan import RawLog, decode_log, read_log, require_run_log, scan_log

# The reader (mcap-py) loads on first use: a run that only writes its log never needs it.
_READING = ("RawLog", "decode_log", "read_log", "require_run_log", "scan_log")


def __getattr__(name: str) -> Any:
    if name in _READING:
        from rgtbus.telemetry import scan

        return getattr(scan, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "LOG_LEVELS",
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
