"""What "the same run" means when units run in other processes (or on other hosts) than the
single-process reference: the shared comparison of the cross-process suites
(tests/test_cross_process.py, tests/hosts/)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from rgtbus.units.group import run_group

from rgtbus.scenario import load_scenario
from rgtbus.telemetry import MemoryRecorder

ROOT = Path(__file__).parent.parent
EXE = [sys.executable, "-m", "rgtbus"]


def plain(value):
    """``json.dumps``'s ``default`` for a record as read: a block's columns (NumPy arrays)
    as lists, so records compare and print as JSON."""
    return value.tolist()


def read_message(topic: str, data: bytes):
    """A message's bytes as a reader reads them: a hot topic's block decoded (columns as
    lists, to compare as JSON), any other's JSON."""
    from rgtbus.telemetry.blocks import decode_record, schema_of

    schema = schema_of(topic)
    if schema is None:
        return json.loads(data)
    record = decode_record(schema, bytes(data), topic)
    return {k: v.tolist() if hasattr(v, "tolist") else v for k, v in record.items()}


def single(name: str):
    """The single-process run of shipped scenario ``name`` on the memory bus: (its summary,
    its log's messages)."""
    sc = load_scenario(ROOT / "scenarios" / f"{name}.toml")
    rec = MemoryRecorder()
    return run_group(sc, "memory", rec).summary, rec.read()[0]


def content(messages):
    """Log content, order-free among simultaneous messages, decodes one a row: how a unit's
    wakes group its decodes into records depends on whether a live view waits for them (a
    unit process feeds ``rgtbus watch``), what it decoded does not; spikes one record a unit
    (the units of one process share their records); a bus's note of what it dropped left
    out (the network's doing)."""
    from rgtbus.telemetry.record_rows import decodes_per_row, spikes_per_unit

    rows = spikes_per_unit(decodes_per_row(messages))
    return sorted(
        (ns, t, json.dumps(m, sort_keys=True, default=plain))
        for t, ns, m in rows
        if not _transport_note(t, m)
    )


def _transport_note(topic: str, message) -> bool:
    """A unit's note of what its bus dropped (``dropped: …``, once at its end): what the
    network did (a link down for a while has frames sent again, and copies dropped), not
    what the run did."""
    return (
        topic == "/log"
        and isinstance(message, dict)
        and str(message.get("message", "")).startswith("dropped: ")
    )


RESULT_KEYS = (
    "polynomial",
    "relations",
    "agree",
    "influences",
    "units",
    "outcome",
    "sim_seconds",
    "decode_errors",
    "goals",
    "rounds",
    "repair",
    "error",
)


def assert_verifies(log: Path) -> None:
    """``rgtbus replay LOG --verify`` (a fresh process) finds the log's run again."""
    verify = subprocess.run(
        [*EXE, "replay", str(log), "--verify", "--quiet"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert verify.returncode == 0, verify.stderr
