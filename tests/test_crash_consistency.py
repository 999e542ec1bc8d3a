"""A log on disk is a valid MCAP file at every moment (docs/foxglove.md, "A log cut
short"): only finished chunks reach the file, each followed by a trailer (``rgtbus.unfinished``,
a DataEnd, a footer) that the next flush overwrites and the close replaces with the real
summary. The standard ``mcap`` readers read a cut log whole up to its last flush; rgtbus reads
it as truncated there.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cut_logs import assert_prefix_is_whole, paced_run, standard_read
from mcap.reader import make_reader

from rgtbus.errors import RgtbusError
from rgtbus.telemetry.log_check import verified_by_crcs
from rgtbus.telemetry.mcap_recorder import McapRecorder
from rgtbus.telemetry.recorder import UNFINISHED
from rgtbus.telemetry.scan import scan_log

ROOT = Path(__file__).parent.parent
CROWD10 = ROOT / "scenarios" / "crowd10.toml"
EXE = [sys.executable, "-m", "rgtbus"]


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


def assert_verifies_as_cut(log: Path) -> None:
    """``replay --verify``: exit 3, what the log holds agreeing (never a mismatch)."""
    verify = subprocess.run([*EXE, "replay", str(log), "--verify"], capture_output=True,
                            text=True, timeout=120)  # fmt: skip
    assert verify.returncode == 3, verify.stdout + verify.stderr
    assert "INCOMPLETE" in verify.stdout and "MISMATCH" not in verify.stdout


@pytest.mark.slow  # a paced run 90 s in (6 s), verified against the whole run: the slow pass
def test_a_run_killed_outright_leaves_a_log_every_reader_reads(tmp_path):
    """kill -9 of a paced ``rgtbus run`` once its log has grown: Python's mcap readers read it
    without an error up to its last flush (at most about a second before the kill), and
    ``replay --verify`` says it is truncated (exit 3) with what it holds agreeing, up to a
    time that is right (``assert_prefix_is_whole``)."""
    log = tmp_path / "killed.mcap"
    with paced_run(log, 600) as proc:  # about 90 s into the run: its units hold decodes
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    if proc.returncode != -signal.SIGKILL:
        pytest.skip("the run ended before the kill: nothing cut")
    assert len(standard_read(log.read_bytes())) > 100
    assert scan_log(log).truncated
    assert_verifies_as_cut(log)
    assert_prefix_is_whole(log, CROWD10)


@pytest.mark.slow  # two paced runs, each verified against the whole run: the slow pass
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_run_stopped_by_a_signal_says_so_in_one_line_and_its_log_verifies_as_cut(tmp_path, sig):
    """``rgtbus run`` on SIGINT or SIGTERM: stops, one line (no traceback), exit 128 + the
    signal; its log ends cut where the run was, and ``replay --verify`` exits 3 with what it
    holds agreeing (never a mismatch for a log that is only cut)."""
    log = tmp_path / "stopped.mcap"
    with paced_run(log, 100) as proc:
        os.kill(proc.pid, sig)
        _, err = proc.communicate(timeout=60)
    if proc.returncode == 0:
        pytest.skip("the run ended before the signal")
    assert proc.returncode == 128 + sig, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f"interrupted by {signal.Signals(sig).name}" in lines[0], err
    assert "Traceback" not in err
    assert len(standard_read(log.read_bytes())) > 100  # a whole file to every reader
    assert_verifies_as_cut(log)
    assert_prefix_is_whole(log, CROWD10)


@pytest.mark.slow  # a paced run to its end (10 s): CI's slow pass
def test_merge_never_writes_over_nor_reads_from_a_log_a_run_is_writing(tmp_path):
    """One writer, always: ``merge -o`` onto the log of a run still going is refused in one
    line (exit 2), and so is a merge with it as an input; the run goes on and its log is its
    own. A finished log merges."""
    done = tmp_path / "done.mcap"
    first = subprocess.run([*EXE, "run", str(ROOT / "scenarios" / "gate.toml"), "--log",
                            str(done), "--quiet"], capture_output=True, timeout=120)  # fmt: skip
    assert first.returncode == 0, first.stderr
    live = tmp_path / "live.mcap"
    with paced_run(live, 10) as proc:
        if proc.poll() is not None:
            pytest.skip("the run ended before the merges")
        for inputs, out, what in (([done], live, "-o"), ([done, live], tmp_path / "m.mcap",
                                                          "input")):  # fmt: skip
            merge = subprocess.run([*EXE, "merge", *map(str, inputs), "-o", str(out)],
                                   capture_output=True, text=True, timeout=120)  # fmt: skip
            if proc.poll() is not None:
                pytest.skip("the run ended during the merges")
            assert merge.returncode == 2, merge.stdout + merge.stderr
            lines = merge.stderr.strip().splitlines()
            assert len(lines) == 1 and f"{what} '{live}': a run is writing it" in lines[0], lines
        assert not (tmp_path / "m.mcap").exists()
        _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert not scan_log(live).truncated  # its own log, whole
    merged = subprocess.run([*EXE, "merge", str(live), "-o", str(tmp_path / "m.mcap"), "-q"],
                            capture_output=True, text=True, timeout=120)  # fmt: skip
    assert merged.returncode == 0, merged.stderr


def _gate_log(tmp_path: Path) -> bytes:
    path = tmp_path / "gate.mcap"
    done = subprocess.run([*EXE, "run", str(ROOT / "scenarios" / "gate.toml"), "--log",
                           str(path), "--quiet"], capture_output=True, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    return path.read_bytes()


def _recover(src: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*EXE, "recover", str(src), "-o", str(out)], capture_output=True,
                          text=True, timeout=120)  # fmt: skip


def test_recover_makes_a_complete_file_of_a_cut_or_damaged_log(tmp_path):
    """``rgtbus recover``: a log cut anywhere, or damaged, becomes a complete MCAP file (summary,
    statistics, chunk indexes, CRCs) holding every message read before the cut or damage;
    it says how many and where the input ended; rgtbus still reads the run as cut there."""
    whole = _gate_log(tmp_path)
    n_whole = len(standard_read(whole))
    cases = {
        "whole": whole,
        "cut-early": whole[: len(whole) // 8],
        "cut-late": whole[: len(whole) * 7 // 8],
        "damaged": whole[: len(whole) // 3]
        + bytes([whole[len(whole) // 3] ^ 0xFF])
        + whole[len(whole) // 3 + 1 :],
    }
    for name, data in cases.items():
        src, out = tmp_path / f"{name}.mcap", tmp_path / f"{name}-recovered.mcap"
        src.write_bytes(data)
        done = _recover(src, out)
        if name == "cut-early" and done.returncode == 2:  # cut inside the header: no log
            assert "not an MCAP file" in done.stderr, done.stderr
            continue
        assert done.returncode == 0, done.stderr
        kept = int(done.stdout.split()[1])
        assert ("it was whole" in done.stdout) == (name == "whole"), done.stdout
        with open(out, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            assert summary is not None and summary.statistics is not None
            assert summary.statistics.message_count == kept
            assert verified_by_crcs(f)
        assert len(standard_read(out.read_bytes())) == kept <= n_whole
        if name == "whole":
            assert kept == n_whole
        else:
            assert_verifies_as_cut(out)


def test_recover_refuses_what_is_no_log_in_one_line(tmp_path):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    done = _recover(junk, tmp_path / "out.mcap")
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "not an MCAP file" in done.stderr and not (tmp_path / "out.mcap").exists()


@pytest.mark.parametrize("argv", [["ser", "--trials", "1000000000"],
                                  ["figures", "OUT", "--trials", "1000000"]])  # fmt: skip
def test_monte_carlo_commands_take_the_budget_before_any_work(tmp_path, argv):
    """Bounded work everywhere: a trial count beyond the budget is one line, exit 2, at once
    (``rgtbus ser --trials 1000000000`` ran for minutes before)."""
    argv = [str(tmp_path / "figs") if a == "OUT" else a for a in argv]
    t0 = time.monotonic()
    done = subprocess.run([*EXE, *argv], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "beyond the budget" in done.stderr, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and time.monotonic() - t0 < 60
    assert not (tmp_path / "figs").exists()


class _SmallDisk(io.RawIOBase):
    """A file on a disk that holds ``limit`` bytes: a write past it takes what fits, the next
    one fails with ENOSPC, as a file on a full disk does."""

    def __init__(self, limit: int) -> None:
        self.data, self.pos, self.limit = bytearray(), 0, limit

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = 0) -> int:
        self.pos = offset if whence == 0 else len(self.data) + offset if whence == 2 else self.pos
        return self.pos

    def tell(self) -> int:
        return self.pos

    def truncate(self, size: int | None = None) -> int:
        del self.data[self.pos if size is None else size :]
        return len(self.data)

    def write(self, b) -> int:  # type: ignore[override]
        room = self.limit - self.pos
        if room <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        chunk = bytes(b[:room])
        self.data[self.pos : self.pos + len(chunk)] = chunk
        self.pos += len(chunk)
        return len(chunk)


def test_a_full_disk_leaves_a_whole_file_as_far_as_the_last_flush_that_went_through():
    disk = _SmallDisk(60_000)
    rec = McapRecorder(disk, flush_wall=3600.0, compression="none")  # type: ignore[arg-type]
    flushed = 0
    with pytest.raises(RgtbusError, match="No space left on device"):
        for k in range(100_000):
            rec.log("info", f"message {k} " + "x" * 200, k)
            if k % 20 == 19:
                rec.flush()
                flushed = k + 1
    rec.close()  # nothing more is written once the stream has failed
    data = bytes(disk.data)
    assert len(standard_read(data)) == flushed > 0  # whole to every reader, no error
    cut = scan_log(io.BytesIO(data))
    assert cut.truncated and not cut.corrupt and len(cut.messages) == flushed


@pytest.mark.slow  # four runs, each verified: CI's slow pass
def test_a_run_whose_disk_fills_verifies_up_to_a_right_time(tmp_path):
    """crowd10 logging to disks of four sizes that fill at different moments of the run: each
    log is whole to every reader up to its last flush that went through, and the time it is
    verified to is right (``assert_prefix_is_whole``); at least one fills mid-run (verified
    past the start, not to the end)."""
    from rgtbus.units.group import run_group

    from rgtbus.scenario import load_scenario

    sc = load_scenario(CROWD10)
    reached = []
    for limit in (50_000, 65_000, 80_000, 95_000):  # crowd10 logs ~118 kB
        disk = _SmallDisk(limit)
        rec = McapRecorder(disk, flush_messages=500)  # type: ignore[arg-type]
        with contextlib.suppress(RgtbusError):  # the disk filled: the run, or its close, says so
            run_group(sc, "memory", rec)
        with contextlib.suppress(RgtbusError):
            rec.close()
        log = tmp_path / f"full-{limit}.mcap"
        log.write_bytes(bytes(disk.data))
        assert standard_read(log.read_bytes())  # whole to every reader
        reached.append(assert_prefix_is_whole(log, CROWD10))
    assert any(0 < until < 200 for until in reached), reached
