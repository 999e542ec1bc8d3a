"""Every kind of file rgtbus writes passes a reader no one here wrote: ``pymcap-cli doctor``
(the MCAP container specification, checked record by record). A run's log, each unit's log and
the merged ``run.mcap`` of a launch, a log cut by ``kill -9`` and ``recover``'s and ``merge``'s
outputs. An error fails; so does a warning (none is expected: docs/foxglove.md, "Checked by
other readers"). Infos (messages out of log-time order inside a chunk, no attachments, a cut
log without a summary) are the file as the specification allows it."""

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
]


@pytest.mark.slow  # a run, a launch, a paced run killed, merges: ~9 s (CI's slow pass runs it)
@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_of_written_file_passes_doctor(written, kind):
    found = doctor(written[kind])
    bad = {key: n for key, n in found.items() if key[0] in ("error", "warning")}
    assert not bad, f"{kind}: {bad}"


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
