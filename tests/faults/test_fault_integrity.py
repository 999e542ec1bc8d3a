"""Every reader checks a log's integrity, and a log has one writer.

``rgtbus cat``, ``info``, ``scenario`` and ``rgtbus.open_log`` on a log with a flipped byte (or
a file holding only MCAP's magic): each outcome is exit 0 with unchanged output, 2 (corrupt:
one line) or 3 (truncated: one line saying how far it read), never a traceback nor altered
content. Of two runs given the same log path, the second is refused before it writes."""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
from functools import cache
from pathlib import Path

import pytest

import rgtbus
from rgtbus.cli import main
from rgtbus.errors import RgtbusError
from rgtbus.telemetry import log_check
from rgtbus.telemetry.log_check import check_log
from rgtbus.telemetry.recorder import MCAP_MAGIC
from rgtbus.telemetry.scan import scan_log

ROOT = Path(__file__).resolve().parent.parent.parent
GATE = str(ROOT / "scenarios" / "gate.toml")
COMMANDS = ("cat", "info", "scenario")
FLIPS = 40


@cache
def gate_log_bytes() -> bytes:
    """A small logged run: the gate on the memory bus, in chunks of 1 KB (~110 of them, as a
    long run's log has: many chunks to cut and flip; the default size would make one)."""
    import tempfile

    from conftest import small_chunk_logs

    with tempfile.TemporaryDirectory() as d, small_chunk_logs():
        log = Path(d) / "gate.mcap"
        assert main(["run", GATE, "--bus", "memory", "--log", str(log), "--quiet"]) == 0
        return log.read_bytes()


def cli(capsys, *args: object) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main([str(a) for a in args])  # a traceback would escape main and fail the test
    out, err = capsys.readouterr()
    return code, out, err


def flipped(data: bytes, at: int) -> bytes:
    return data[:at] + bytes([data[at] ^ 0x01]) + data[at + 1 :]


def spread(size: int, count: int = FLIPS) -> list[int]:
    """``count`` offsets spread evenly over the file, first and last byte included."""
    return sorted({(size - 1) * i // (count - 1) for i in range(count)})


def one_line(err: str) -> bool:
    return err.count("\n") == 1 and "Traceback" not in err


def test_every_flipped_byte_is_refused_or_harmless(tmp_path, capsys):
    data = gate_log_bytes()
    path = tmp_path / "flip.mcap"
    path.write_bytes(data)
    reference = {}
    for command in COMMANDS:
        code, out, err = cli(capsys, command, path)
        assert (code, err) == (0, ""), (command, err)
        reference[command] = out
    outcomes: dict[str, list[int]] = {}
    for at in spread(len(data)):
        path.write_bytes(flipped(data, at))
        for command in COMMANDS:
            code, out, err = cli(capsys, command, path)
            if code == 0:
                assert out == reference[command] and err == "", (command, at, "altered output")
            elif code == 2:
                assert out == "" and one_line(err) and str(path) in err, (command, at, err)
            elif code == 3:
                assert one_line(err) and "truncated" in err, (command, at, err)
                if command == "cat":  # what it printed was in the log as written
                    assert set(out.splitlines()) <= set(reference["cat"].splitlines())
            else:
                pytest.fail(f"{command} with byte {at} flipped: exit {code}: {err}")
            outcomes.setdefault(f"{command} {code}", []).append(at)
        # the library reads through the same checks
        try:
            log = rgtbus.open_log(path)
        except RgtbusError as exc:
            assert "\n" not in str(exc) and str(path) in str(exc)
        else:
            assert log.truncated, at
    # every byte of a finished log is under a CRC (or is the magic): a flip is always found
    assert set(outcomes) == {"cat 2", "info 2", "scenario 2"}, outcomes


@pytest.mark.parametrize("content", [b"", MCAP_MAGIC], ids=["empty", "magic-only"])
def test_an_empty_or_magic_only_file_is_one_line_exit_2(tmp_path, capsys, content):
    path = tmp_path / "x.mcap"
    path.write_bytes(content)
    for command in COMMANDS:
        code, out, err = cli(capsys, command, path)
        assert code == 2 and out == "" and one_line(err), (command, err)
        assert "not an MCAP file" in err, err
    with pytest.raises(RgtbusError, match="not an MCAP file"):
        rgtbus.open_log(path)


def test_a_cut_log_exits_3_saying_how_far_it_read(tmp_path, capsys):
    data = gate_log_bytes()
    whole = tmp_path / "whole.mcap"
    whole.write_bytes(data)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    full_cat = cli(capsys, "cat", whole)[1].splitlines()
    for command in COMMANDS:
        code, out, err = cli(capsys, command, cut)
        assert code == 3 and one_line(err), (command, err)
        assert "log truncated" in err and "last log time read" in err, err
    code, out, err = cli(capsys, "replay", cut)  # as replay says it (its timeline's note)
    assert code == 3 and "log truncated" in out and "last log time read" in out
    code, out, err = cli(capsys, "cat", cut)
    lines = out.splitlines()
    assert 0 < len(lines) < len(full_cat) and set(lines) <= set(full_cat)
    last = json.loads(lines[-1])["t"]
    assert f"last log time read {last:.6f} s" in err, (last, err)
    code, out, _ = cli(capsys, "info", cut, "--json")
    assert code == 3 and json.loads(out)["truncated"] is True
    assert rgtbus.open_log(cut).truncated


def test_info_checks_a_clean_log_by_its_crcs_without_scanning(tmp_path, capsys, monkeypatch):
    """The fast path: a finished log's data-section and summary CRCs cover every byte, so
    ``info`` reads its summary without decompressing a chunk; damage sends it to the scan,
    which names the damage."""
    data = gate_log_bytes()
    path = tmp_path / "gate.mcap"
    path.write_bytes(data)
    with check_log(path) as log:
        assert log.raw is None and log.summary is not None and not log.truncated
    scans = []
    real_scan = log_check._scan
    monkeypatch.setattr(log_check, "_scan", lambda *a: scans.append(a) or real_scan(*a))
    code, out, err = cli(capsys, "info", path)
    assert code == 0 and "outcome:     gate: open" in out and scans == []
    path.write_bytes(flipped(data, len(data) // 3))  # inside a chunk
    code, out, err = cli(capsys, "info", path)
    assert code == 2 and one_line(err) and "corrupt log" in err and len(scans) == 1


# -- one writer a log --------------------------------------------------------------------------

HOLDER = """
import sys
from pathlib import Path
from rgtbus.telemetry.logfile import close_log, open_log

stream, rec = open_log(Path(sys.argv[1]))
rec.metadata("scenario", {"name": "holder", "text": "held"})
rec.metadata("run", {"seed": "1"})
rec.log("info", "the first run's record", 0)
rec.flush()
print("ready", flush=True)
sys.stdin.readline()  # hold the log until the test says
close_log(stream, rec)
print("closed", flush=True)
"""


def _line(proc: subprocess.Popen, timeout: float = 60.0) -> str:
    """The holder's next line, waiting at most ``timeout`` s (never for ever)."""
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    assert ready, "the holder process did not answer"
    return proc.stdout.readline().strip()


def test_a_second_writer_to_the_same_log_is_refused_before_it_writes(tmp_path, capsys):
    log = tmp_path / "shared.mcap"
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(log)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        assert _line(holder) == "ready"
        before = log.read_bytes()
        code, out, err = cli(capsys, "run", GATE, "--bus", "memory", "--log", log, "--quiet")
        assert code == 2 and out == "" and one_line(err), err
        assert f"log '{log}' is being written by another run" in err, err
        assert f"(pid {holder.pid})" in err, err
        with pytest.raises(RgtbusError, match="is being written by another run"):
            rgtbus.run("gate", bus="memory", log=log)
        assert log.read_bytes() == before  # not a byte written, not truncated
        assert holder.stdin is not None
        holder.stdin.write("\n")
        holder.stdin.flush()
        assert _line(holder) == "closed"
    finally:
        holder.kill() if holder.poll() is None else None
        holder.wait(timeout=60)
    raw = scan_log(log)  # the first run's log, whole
    assert not raw.corrupt and not raw.truncated
    assert dict(raw.metadata)["scenario"]["name"] == "holder"
    # the lock ends with the first run's log: the path can be written again
    code, _, err = cli(capsys, "run", GATE, "--bus", "memory", "--log", log, "--quiet")
    assert code == 0, err
    assert rgtbus.open_log(log).summary()["outcome"] == "gate: open"
