"""A log on disk is a valid MCAP file at every moment (docs/foxglove.md, "A log cut
short"): only finished chunks reach the file, each followed by a trailer (``rgtbus.unfinished``,
a DataEnd, a footer) that the next flush overwrites and the close replaces with the real
summary. The standard ``mcap`` readers read a cut log whole up to its last flush; rgtbus reads
it as truncated there.
"""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import NonSeekingReader, make_reader

from rgtbus.telemetry.recorder import UNFINISHED, McapRecorder
from rgtbus.telemetry.scan import scan_log, verified_by_crcs

ROOT = Path(__file__).parent.parent
EXE = [sys.executable, "-m", "rgtbus"]


def standard_read(data: bytes) -> list[int]:
    """The log times every standard reader finds (seeking and not, in log-time order: the
    default), which must agree; any error fails the test."""
    seeking = [m.log_time for _, _, m in make_reader(io.BytesIO(data)).iter_messages()]
    streaming = [m.log_time for _, _, m in NonSeekingReader(io.BytesIO(data)).iter_messages()]
    assert seeking == streaming
    return seeking


def test_a_log_between_flushes_is_a_whole_file_to_every_reader(tmp_path):
    path = tmp_path / "log.mcap"
    with open(path, "wb") as f:
        rec = McapRecorder(f, flush_wall=3600.0)  # flushed here only when asked
        assert standard_read(path.read_bytes()) == []  # valid from its first byte
        for k in range(50):
            rec.log("info", f"message {k}", k * 1_000_000)
        rec.flush()
        flushed = path.read_bytes()
        for k in range(50, 80):
            rec.log("info", f"message {k}", k * 1_000_000)
        # written since the flush: held back, the file is still the flushed one
        assert path.read_bytes() == flushed
        assert standard_read(flushed) == [k * 1_000_000 for k in range(50)]
        cut = scan_log(io.BytesIO(flushed))
        assert cut.truncated and "its writer had not finished" in cut.note
        assert UNFINISHED not in [name for name, _ in cut.metadata]
        rec.close()
    whole = path.read_bytes()
    assert standard_read(whole) == [k * 1_000_000 for k in range(80)]
    assert not scan_log(io.BytesIO(whole)).truncated
    assert UNFINISHED.encode() not in whole  # the close replaced the trailer
    with open(path, "rb") as f:
        assert verified_by_crcs(f)


class _Pipe(io.RawIOBase):
    """A stream that cannot seek (a pipe): it gets whole records, and no trailer."""

    def __init__(self) -> None:
        self.data = bytearray()

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return False

    def write(self, b) -> int:  # type: ignore[override]
        self.data.extend(b)
        return len(b)


def test_a_log_written_to_a_stream_that_cannot_seek_is_whole():
    pipe = _Pipe()
    rec = McapRecorder(pipe)  # type: ignore[arg-type]
    for k in range(30):
        rec.log("info", f"message {k}", k)
    rec.flush()
    assert UNFINISHED.encode() not in pipe.data  # nothing to overwrite it with later
    rec.close()
    assert standard_read(bytes(pipe.data)) == list(range(30))


def test_a_run_killed_outright_leaves_a_log_every_reader_reads(tmp_path):
    """kill -9 of a paced ``rgtbus run`` once its log has grown: Python's mcap readers read it
    without an error up to its last flush (at most about a second before the kill), and
    ``replay --verify`` says it is truncated (exit 3) with what it holds agreeing."""
    log = tmp_path / "killed.mcap"
    argv = [*EXE, "run", str(ROOT / "scenarios" / "crowd10.toml"), "--realtime", "25",
            "--log", str(log), "--quiet"]  # fmt: skip
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 60
        while not (log.exists() and len(standard_read(log.read_bytes())) > 100):
            assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
            assert time.monotonic() < deadline, "the log never grew past 100 messages"
            time.sleep(0.2)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
    if proc.returncode != -signal.SIGKILL:
        pytest.skip("the run ended before the kill: nothing cut")
    times = standard_read(log.read_bytes())
    assert len(times) > 100
    assert scan_log(log).truncated
    verify = subprocess.run([*EXE, "replay", str(log), "--verify"], capture_output=True,
                            text=True, timeout=120)  # fmt: skip
    assert verify.returncode == 3, verify.stdout + verify.stderr
    assert "INCOMPLETE" in verify.stdout and "MISMATCH" not in verify.stdout


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_run_stopped_by_a_signal_says_so_in_one_line_and_its_log_verifies_as_cut(tmp_path, sig):
    """``rgtbus run`` on SIGINT or SIGTERM: stops, one line (no traceback), exit 128 + the
    signal; its log ends cut where the run was, and ``replay --verify`` exits 3 with what it
    holds agreeing (never a mismatch for a log that is only cut)."""
    log = tmp_path / "stopped.mcap"
    argv = [*EXE, "run", str(ROOT / "scenarios" / "crowd10.toml"), "--realtime", "25",
            "--log", str(log), "--quiet"]  # fmt: skip
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not (log.exists() and len(standard_read(log.read_bytes())) > 100):
            assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
            assert time.monotonic() < deadline, "the log never grew past 100 messages"
            time.sleep(0.2)
        os.kill(proc.pid, sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
    if proc.returncode == 0:
        pytest.skip("the run ended before the signal")
    assert proc.returncode == 128 + sig, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f"interrupted by {signal.Signals(sig).name}" in lines[0], err
    assert "Traceback" not in err
    assert len(standard_read(log.read_bytes())) > 100  # a whole file to every reader
    verify = subprocess.run([*EXE, "replay", str(log), "--verify"], capture_output=True,
                            text=True, timeout=120)  # fmt: skip
    assert verify.returncode == 3, verify.stdout + verify.stderr
    assert "INCOMPLETE" in verify.stdout and "MISMATCH" not in verify.stdout
