"""Golden log digests: what a restructuring must not change (docs/engine.md, "Golden logs").

Each case runs one scenario in this process on the memory bus with its full log and digests
every message: its topic, log time and content (canonical JSON, or a block's own bytes: the
format writes them canonically, docs/format.md), and every metadata record,
less what depends on the machine rather than the run (the scenario's path, the Python version).
Messages are digested in a canonical order (log time, topic, content): the writer may place
records of one log time in another order between runs, and the order is not what a reader
uses. Per-topic digests say where a change is.

``python tests/golden.py --write`` records the digests anew (only after a change that is meant
to change the logs, and said so in its commit); ``tests/test_golden.py`` holds every case to
them.
"""

from __future__ import annotations

import hashlib
import io
import json
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

DIGESTS = Path(__file__).with_name("golden_digests.json")
# metadata values that depend on the machine, not the run
MACHINE_FIELDS = {("scenario", "path"), ("run", "python")}


@dataclass(frozen=True)
class Case:
    """A golden run: ``scenario`` (a shipped name), ``engine``, and what it varies."""

    name: str
    scenario: str
    engine: str = "event"
    edit: Callable[[str], str] | None = None  # the scenario's TOML text, changed
    traces: bool = False
    realtime: float | None = None
    slow: bool = False  # run with the slow checks (CI), not in the fast suite


def _timing(line: str) -> Callable[[str], str]:
    return lambda text: text.replace("[timing]\n", f"[timing]\n{line}\n", 1)


SHIPPED = (
    "coalition10", "cograph_group", "crowd10", "example1", "example2", "gate", "gate_fading",
    "gate_goal", "gate_noisy", "gate_repair", "group20", "group6", "overview", "random_group",
    "robots_in_a_field", "robots_on_a_plane", "steering", "tug_of_war",
)  # fmt: skip
SLOW_DENSE = {
    "coalition10", "crowd10", "group20", "robots_on_a_plane", "group6", "gate_noisy", "gate_repair",
    "tug_of_war",
}  # fmt: skip

CASES: tuple[Case, ...] = (
    *(Case(f"{s}-event", s) for s in SHIPPED),
    *(Case(f"{s}-dense", s, "dense", slow=s in SLOW_DENSE) for s in SHIPPED),
    # the paths a shipped scenario does not take on its own
    Case("gate-threshold", "gate", edit=_timing('attention = "threshold"')),
    Case("example2-traces", "example2", traces=True),
    Case("gate-paced", "gate", realtime=1e4),  # pulses logged as the clock reaches them
    Case("gate_noisy-paced", "gate_noisy", realtime=1e4),
)


def run_case(case: Case) -> bytes:
    """The case's log, as bytes."""
    from rgtbus.units.group import run_group

    from rgtbus.scenario import load_scenario
    from rgtbus.scenario.shipped import find_shipped
    from rgtbus.telemetry import McapRecorder

    path = find_shipped(case.scenario)
    assert path is not None, case.scenario
    sc = load_scenario(path)
    if case.edit is not None:
        sc = load_scenario(case.edit(path.read_text()))
    buf = io.BytesIO()
    recorder = McapRecorder(buf)
    run_group(
        sc, "memory", recorder, engine=case.engine, traces=case.traces, realtime=case.realtime
    )
    recorder.close()
    return buf.getvalue()


def log_digests(data: bytes) -> dict[str, str]:
    """``{topic: sha256}`` of a log's messages (and ``"metadata"``), and ``"all"`` over
    every one of them."""
    from mcap.reader import make_reader

    reader = make_reader(io.BytesIO(data))
    rows: list[tuple[int, str, str]] = []
    for _, channel, message in reader.iter_messages(log_time_order=False):
        if channel.message_encoding == "protobuf":  # a block: its bytes are canonical
            content = bytes(message.data).hex()
        else:
            content = json.dumps(json.loads(message.data), sort_keys=True)
        rows.append((message.log_time, channel.topic, content))
    rows.sort()
    meta: list[str] = []
    for record in reader.iter_metadata():
        meta_items = record.metadata.items()
        values = {k: v for k, v in meta_items if (record.name, k) not in MACHINE_FIELDS}
        meta.append(json.dumps([record.name, values], sort_keys=True))
    meta.sort()
    by_topic: dict[str, Any] = {}
    whole = hashlib.sha256()
    for row in rows:
        text = json.dumps(row).encode()
        by_topic.setdefault(row[1], hashlib.sha256()).update(text)
        whole.update(text)
    digests = {topic: h.hexdigest()[:16] for topic, h in sorted(by_topic.items())}
    meta_digest = hashlib.sha256("\n".join(meta).encode())
    whole.update(meta_digest.digest())
    return {"all": whole.hexdigest()[:16], "messages": str(len(rows)),
            "metadata": meta_digest.hexdigest()[:16], **digests}  # fmt: skip


def recorded() -> dict[str, dict[str, str]]:
    return dict(json.loads(DIGESTS.read_text()))


def main(argv: list[str]) -> int:
    if argv != ["--write"]:
        print("usage: python tests/golden.py --write", file=sys.stderr)
        return 2
    out = {}
    for case in CASES:
        out[case.name] = log_digests(run_case(case))
        print(case.name, out[case.name]["all"], flush=True)
    DIGESTS.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
