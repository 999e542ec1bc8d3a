"""Sweeps survive faults (issue 22, item 5): Ctrl-C and SIGTERM, a worker or the sweep killed
outright, a second writer, a rows.jsonl tampered with, a bad --out or --scheduler, a Dask
scheduler lost mid-sweep. Each ends in one line (exit 2, or 130 when stopped), keeps every
finished row, and leaves no process behind.

The process tests run real ``rgtbus sweep`` processes (their own session, killed as a group at
the end whatever happens) on tiny runs (scenarios/random_group.toml, 3 units); every wait is
bounded and generous, and no test depends on when a signal lands: a worker is killed while it
is stopped (SIGSTOP) inside a run, which its open run log shows.
"""

from __future__ import annotations

import contextlib
import json
import operator
import os
import signal
import socket
import subprocess
import sys
import time
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from rgtbus.units import sweep as sweep_mod
from rgtbus.units.sweep import execute_sweep, load_sweep, run_sweep
from rgtbus.units.sweep_store import read_rows
from rgtbus.units.workers import SweepPool, WorkerDied

from rgtbus.cli import main

ROOT = Path(__file__).resolve().parent.parent.parent
RANDOM = str(ROOT / "scenarios" / "random_group.toml")
EXE = [sys.executable, "-m", "rgtbus"]
pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="processes are found through /proc"
)
STOP_BOUND = 15.0  # seconds from the signal to the exit (measured: well under one)


def write_sweep(tmp_path: Path, seeds: int, name: str = "tiny") -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(
        f'name = "{name}"\nscenario = "{RANDOM}"\nseeds = "0..{seeds - 1}"\n'
        '[grid]\n"relations.p" = [0.61]\n'
    )
    return path


def lines(out: Path) -> list[str]:
    path = out / "rows.jsonl"
    return path.read_text().splitlines() if path.exists() else []


def wait_until(pred, what: str, timeout: float = 120.0, proc: subprocess.Popen | None = None):
    deadline = time.monotonic() + timeout
    while not pred():
        if proc is not None and proc.poll() is not None:
            pytest.fail(f"the sweep ended before {what}: {proc.communicate(timeout=30)}")
        if time.monotonic() > deadline:
            pytest.fail(f"not {what} within {timeout:g} s")
        time.sleep(0.05)


def _stat(pid: int) -> list[str] | None:
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return text[text.rindex(")") + 2 :].split()  # state, ppid, ...; the name may hold spaces


def children(pid: int) -> dict[int, str]:
    """A process's children (of any of its threads: the pool starts replacements from its
    own) -> their start time, which tells a pid reused later apart."""
    found: dict[int, str] = {}
    with contextlib.suppress(OSError):
        for task in Path(f"/proc/{pid}/task").iterdir():
            with contextlib.suppress(OSError):
                for kid in (task / "children").read_text().split():
                    st = _stat(int(kid))
                    if st is not None:
                        found[int(kid)] = st[19]
    return found


def alive(procs: dict[int, str]) -> list[int]:
    """Those of ``procs`` still running (a zombie is no longer running)."""
    out = []
    for pid, started in procs.items():
        st = _stat(pid)
        if st is not None and st[19] == started and st[0] not in ("Z", "X"):
            out.append(pid)
    return out


def workers_of(pid: int) -> list[int]:
    """The pool's worker processes (not multiprocessing's resource tracker)."""
    out = []
    for kid in children(pid):
        with contextlib.suppress(OSError):
            if b"resource_tracker" not in Path(f"/proc/{kid}/cmdline").read_bytes():
                out.append(kid)
    return out


@pytest.fixture
def sweeps():
    """``start(path, out, *extra)``: ``rgtbus sweep`` in its own session, with 2 workers; every
    process of it is killed and reaped at the end, even when the test fails."""
    started: list[subprocess.Popen] = []

    def start(path: Path, out: Path, *extra: str, env=None) -> subprocess.Popen:
        p = subprocess.Popen(
            [*EXE, "sweep", str(path), "--out", str(out), "--quiet", *extra],
            cwd=ROOT,
            start_new_session=True,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            stdin=subprocess.DEVNULL,
            text=True,
            env=env,
        )
        started.append(p)
        return p

    try:
        yield start
    finally:
        for p in started:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGCONT)
                os.killpg(p.pid, signal.SIGKILL)
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.communicate(timeout=30)


def one_line(err: str) -> str:
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


# -- Ctrl-C, SIGTERM ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("sig", "group"),
    [(signal.SIGINT, True), (signal.SIGINT, False), (signal.SIGTERM, False)],
    ids=["ctrl-c", "sigint", "sigterm"],
)
def test_a_stopped_sweep_ends_at_once_keeps_its_rows_and_its_workers_end(
    tmp_path, sweeps, sig, group
):
    """Ctrl-C at a terminal signals the whole process group (the workers too); SIGINT or
    SIGTERM to the sweep alone is the same stop. Exit 130, one line saying how to resume,
    every finished row kept (each is written as its run ends), no worker left."""
    path, out = write_sweep(tmp_path, 2000), tmp_path / "out"
    proc = sweeps(path, out, "--workers", "2")
    wait_until(lambda: len(lines(out)) >= 2, "the first rows", proc=proc)
    wait_until(lambda: len(workers_of(proc.pid)) == 2, "both workers", proc=proc)
    kids = children(proc.pid)
    before = len(lines(out))
    t0 = time.monotonic()
    if group:
        os.killpg(proc.pid, sig)
    else:
        proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    took = time.monotonic() - t0
    assert proc.returncode == 130, err
    assert took < STOP_BOUND, took
    one_line(err)
    assert "interrupted" in err and f"--out {out} --workers 2 --resume" in err, err
    kept = lines(out)
    assert before <= len(kept) < 2000 and f"{len(kept)} of 2000 runs" in err
    rows, rewrite, notes = read_rows(out, load_sweep(path).digest)  # every line whole and sealed
    assert notes == []
    assert len(rows) == len(kept) and not rewrite
    wait_until(lambda: not alive(kids), "every worker gone", timeout=15)
    assert not (out / "results.parquet").exists()


def test_the_library_sweep_lets_keyboard_interrupt_through_after_stopping_its_workers(tmp_path):
    """sweep() / execute_sweep(): Ctrl-C propagates as KeyboardInterrupt once the workers are
    stopped; the rows so far are kept, and resume runs only the rest."""
    sw = load_sweep(write_sweep(tmp_path, 12))
    out = tmp_path / "out"
    others = set(children(os.getpid()))
    seen: dict[int, str] = {}

    def stop_after_three(done: int, total: int, failures: int) -> None:
        mine = set(workers_of(os.getpid())) - others
        seen.update((pid, t) for pid, t in children(os.getpid()).items() if pid in mine)
        if done >= 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        execute_sweep(sw, out, workers=2, progress=stop_after_three)
    assert len(seen) == 2  # the pool's workers, stopped before the interrupt came out
    assert not alive(seen)
    assert len(lines(out)) == 3
    ran = []
    real = sweep_mod.run_row
    sweep_mod.run_row = lambda s, t, d=None: ran.append(t.index) or real(s, t, d)
    try:
        with ThreadPoolExecutor(1) as ex:
            rows = run_sweep(sw, out, executor=ex, workers=1, resume=True)
    finally:
        sweep_mod.run_row = real
    assert len(rows) == 12 and len(ran) == 9 and not any(r["failed"] for r in rows)


# -- killed outright ---------------------------------------------------------------------------


def _run_log_open(pid: int, logs: Path) -> int | None:
    """The run whose log the process holds open (it is inside that run), else None."""
    logs = Path(os.path.realpath(logs))
    with contextlib.suppress(OSError):
        for fd in Path(f"/proc/{pid}/fd").iterdir():
            with contextlib.suppress(OSError):
                target = os.readlink(fd)
                if target.startswith(str(logs) + "/run-") and target.endswith(".mcap"):
                    return int(target[len(str(logs)) + 5 : -5])
    return None


@pytest.mark.slow  # one of the longest waits: CI's slow pass runs it
def test_a_killed_worker_costs_only_its_run_which_resume_runs_again(tmp_path, sweeps):
    """kill -9 of one pool worker inside a run: that run is an error row naming the death,
    the others complete (exit 0), and --resume runs that one run again."""
    path, out = write_sweep(tmp_path, 200), tmp_path / "out"
    proc = sweeps(path, out, "--workers", "2", "--logs")
    wait_until(lambda: len(lines(out)) >= 1, "the first rows", proc=proc)
    victim = run = None
    deadline = time.monotonic() + 120
    while victim is None:
        assert time.monotonic() < deadline, "no worker caught inside a run"
        assert proc.poll() is None, proc.communicate(timeout=30)
        for pid in workers_of(proc.pid):
            os.kill(pid, signal.SIGSTOP)  # still: its open log says whether it is in a run
            run = _run_log_open(pid, out / "logs")
            if run is not None:
                os.kill(pid, signal.SIGKILL)
                victim = pid
                break
            os.kill(pid, signal.SIGCONT)
        time.sleep(0.01)
    said, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert "200 runs (1 ended with an error)" in said
    table = pq.read_table(out / "results.parquet").to_pylist()
    failed = [r for r in table if r["failed"]]
    assert [r["run"] for r in failed] == [run], failed
    assert failed[0]["error"].startswith(f"worker died: process {victim} was killed by SIGKILL")
    assert len(table) == 200
    again = subprocess.run(
        [*EXE, "sweep", str(path), "--out", str(out), "--resume", "--quiet"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert again.returncode == 0, again.stderr
    assert "200 runs (0 ended with an error)" in again.stdout
    assert len(lines(out)) == 201  # the one run again, nothing else


def test_resume_runs_again_a_run_whose_worker_died_but_keeps_a_run_that_raised(
    tmp_path, monkeypatch
):
    import rgtbus.units.group

    real_group = rgtbus.units.group.run_group

    def boom(sc, *a, **k):
        if sc.seed == 1:
            raise ZeroDivisionError("division by zero")
        return real_group(sc, *a, **k)

    class DiesOnRun2(Executor):
        """Run 2's worker dies; the others run here."""

        def submit(self, fn, /, *args, **kwargs):
            f: Future = Future()
            if any(t.index == 2 for t in args[1]):
                f.set_exception(WorkerDied("process 4242 was killed by SIGKILL while running it"))
            else:
                f.set_result(fn(*args, **kwargs))
            return f

    sw, out = load_sweep(write_sweep(tmp_path, 4)), tmp_path / "out"
    monkeypatch.setattr(rgtbus.units.group, "run_group", boom)
    rows = run_sweep(sw, out, executor=DiesOnRun2(), workers=2)
    assert [r["run"] for r in rows if r["failed"]] == [1, 2]
    assert rows[2]["error"].startswith("worker died: process 4242 was killed by SIGKILL")
    ran = []
    real = sweep_mod.run_row
    monkeypatch.setattr(
        sweep_mod, "run_row", lambda s, t, d=None: ran.append(t.index) or real(s, t, d)
    )
    rows = run_sweep(sw, out, resume=True)
    assert ran == [2]  # the run that raised is a result, kept
    assert [r["run"] for r in rows if r["failed"]] == [1]
    monkeypatch.undo()
    assert len(read_rows(out, sw.digest)[0]) == 5  # a dead worker's row, then its run again


class Unreadable:
    """Pickles here; unpickling it (in a worker) raises."""

    def __reduce__(self):
        return (operator.truediv, (1, 0))


def test_a_submission_a_worker_cannot_read_fails_alone():
    """...and costs no worker (a worker that died of it would be replaced for every run)."""
    pool = SweepPool(1)
    try:
        pid = pool.pids()
        with pytest.raises(RuntimeError, match="the worker cannot read what it was sent"):
            pool.submit(len, Unreadable()).result(timeout=60)
        assert [pool.submit(os.getpid).result(timeout=60)] == pid == pool.pids()
    finally:
        pool.terminate()
    assert pool.pids() == []


def test_a_killed_sweep_leaves_no_worker_behind(tmp_path, sweeps):
    """kill -9 of the sweep itself gives it no time to stop its workers: they notice that
    their parent is gone (PR_SET_PDEATHSIG; a thread polling the parent pid elsewhere)."""
    path, out = write_sweep(tmp_path, 2000), tmp_path / "out"
    proc = sweeps(path, out, "--workers", "2")
    wait_until(lambda: len(lines(out)) >= 1, "the first rows", proc=proc)
    wait_until(lambda: len(workers_of(proc.pid)) == 2, "both workers", proc=proc)
    kids = children(proc.pid)
    proc.kill()
    proc.communicate(timeout=60)
    wait_until(lambda: not alive(kids), "every worker gone", timeout=15)
    read_rows(out, load_sweep(path).digest)  # what was written is whole (a cut line at most)


# -- one writer, intact rows -------------------------------------------------------------------


def test_a_second_writer_is_refused_naming_the_directory_and_the_holder(tmp_path, sweeps, capsys):
    path, out = write_sweep(tmp_path, 2000), tmp_path / "out"
    proc = sweeps(path, out, "--workers", "2")
    wait_until(lambda: len(lines(out)) >= 1, "the first rows", proc=proc)
    second = subprocess.run(
        [*EXE, "sweep", str(path), "--out", str(out), "--resume", "--quiet"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert second.returncode == 2, second.stderr
    err = one_line(second.stderr)
    assert f"'{out}' is in use by another sweep (pid {proc.pid})" in err, err
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=60)
    assert proc.returncode == 130
    # the lock went with its holder: a resume may go on now (here: it is held by this test)
    import fcntl

    with open(out / "sweep.lock", "r+") as f:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        f.truncate()
        f.write("4242\n")
        f.flush()
        capsys.readouterr()
        assert main(["sweep", str(path), "--out", str(out), "--resume", "--quiet"]) == 2
        assert "(pid 4242)" in one_line(capsys.readouterr().err)


def _tamper(out: Path, how: str) -> tuple[list[str], int]:
    """The rows.jsonl lines of sweep directory ``out`` made bad in one way, and the line that
    is then bad."""
    rows = lines(out)
    if how == "not an object":
        return [*rows[:3], "42", *rows[3:]], 4
    if how == "not JSON":
        return [*rows[:1], "{run: 1", *rows[1:]], 2
    if how == "altered":
        row = json.loads(rows[3])
        row["decomposable"] = not row["decomposable"]  # its digest kept
        return [*rows[:3], json.dumps(row), *rows[4:]], 4
    if how == "tampered duplicate":
        row = json.loads(rows[2])
        row["polynomial"] = "u1+u2+u3"
        return [*rows, json.dumps(row)], len(rows) + 1
    if how == "duplicate":
        return [*rows, rows[1]], len(rows) + 1
    if how == "no digest":
        row = json.loads(rows[0])
        del row["_hmac"]
        return [json.dumps(row), *rows[1:]], 1
    if how in ("forged, unkeyed", "forged, another key"):  # resealed by one without the key
        from rgtbus.units.sweep_store import row_digest, row_seal

        row = json.loads(rows[3])
        del row["_hmac"]
        row["decomposable"] = not row["decomposable"]
        digest = json.loads((out / "sweep.json").read_text())["digest"]
        if how == "forged, unkeyed":  # the rule the docs give, with the sweep's own digest
            row["_sha256"] = row_digest(row, digest)
        else:
            row["_hmac"] = row_seal(row, digest, b"not the sweep's key, 32 bytes...")
        return [*rows[:3], json.dumps(row), *rows[4:]], 4
    raise AssertionError(how)


@pytest.mark.parametrize(
    ("how", "says"),
    [
        ("not an object", "not a row (a JSON object expected, got '42')"),
        ("not JSON", "not a row (not JSON"),
        ("altered", "its seal does not match"),
        ("tampered duplicate", "its seal does not match"),
        ("duplicate", "a second row of the run of line 2"),
        ("no digest", "a row without its seal"),
        ("forged, unkeyed", "a row with an unkeyed digest"),
        ("forged, another key", "its seal does not match the sweep's key"),
    ],
)
def test_a_bad_line_in_rows_jsonl_is_refused_naming_the_file_and_line(tmp_path, capsys, how, says):
    path, out = write_sweep(tmp_path, 6), tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out), "--workers", "1", "--quiet"]) == 0
    bad, line = _tamper(out, how)
    (out / "rows.jsonl").write_text("\n".join(bad) + "\n")
    capsys.readouterr()
    assert main(["sweep", str(path), "--out", str(out), "--resume", "--quiet"]) == 2
    err = one_line(capsys.readouterr().err)
    assert f"{out / 'rows.jsonl'}:{line}: " in err and says in err, err
    assert lines(out) == bad  # nothing ran, nothing was appended


def test_a_line_cut_by_a_kill_is_run_again_with_a_note(tmp_path, capsys):
    path, out = write_sweep(tmp_path, 6), tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out), "--workers", "1", "--quiet"]) == 0
    whole = pq.read_table(out / "results.parquet").drop(["wall_seconds"])
    text = (out / "rows.jsonl").read_text()
    (out / "rows.jsonl").write_text(text[: text.rindex("\n", 0, -1) + 40])  # the last row cut
    capsys.readouterr()
    assert main(["sweep", str(path), "--out", str(out), "--resume", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "rows.jsonl:6: a line cut short" in err, err
    assert pq.read_table(out / "results.parquet").drop(["wall_seconds"]).equals(whole)
    assert len(lines(out)) == 6
    assert main(["sweep", str(path), "--out", str(out), "--resume", "--quiet"]) == 0


def test_the_library_returns_its_note_on_a_cut_line_and_prints_nothing(tmp_path, capsys):
    """``run_sweep`` and ``sweep()`` say what they have to say as data (``SweepRows.notes``,
    the frame's ``attrs["notes"]``), never on stderr: only ``rgtbus sweep`` prints it."""
    from rgtbus.units.sweep import sweep

    path, out = write_sweep(tmp_path, 6), tmp_path / "out"
    sw = load_sweep(path)
    run_sweep(sw, out)
    text = (out / "rows.jsonl").read_text()
    (out / "rows.jsonl").write_text(text[: text.rindex("\n", 0, -1) + 40])  # the last row cut
    capsys.readouterr()
    rows = run_sweep(sw, out, resume=True)
    assert len(rows) == 6 and len(rows.notes) == 1
    assert "rows.jsonl:6: a line cut short" in rows.notes[0]
    assert run_sweep(sw, out, resume=True).notes == []
    again = tmp_path / "again"
    kw = {"grid": {"n": [3]}, "seeds": 3, "out": again, "workers": 1}
    assert sweep("random_group", **kw).attrs["notes"] == []
    text = (again / "rows.jsonl").read_text()
    (again / "rows.jsonl").write_text(text[: text.rindex("\n", 0, -1) + 40])
    frame = sweep("random_group", resume=True, **kw)
    assert len(frame) == 3 and "a line cut short" in frame.attrs["notes"][0]
    assert capsys.readouterr().err == ""


# -- bad --out, bad --scheduler, a lost scheduler ----------------------------------------------


def _bad_outs(tmp_path: Path) -> list[tuple[str, str]]:
    a_file = tmp_path / "a-file"
    a_file.write_text("x")
    return [
        (str(a_file), "exists and is not a directory"),
        (str(a_file / "sub"), "cannot write a sweep there (Not a directory)"),
        ("/proc/xx", "cannot write a sweep there (No such file or directory)"),
        ("/proc/xx/yy", "cannot write a sweep there (No such file or directory)"),
        ("/proc/self", "cannot write a sweep there"),  # a directory no file can be made in
        ("/sys/rgtbus-sweep", "cannot write a sweep there"),
    ]


def test_a_bad_out_is_one_line(tmp_path, capsys):
    path = write_sweep(tmp_path, 2)
    for out, says in _bad_outs(tmp_path):
        capsys.readouterr()
        assert main(["sweep", str(path), "--out", out, "--quiet"]) == 2, out
        err = one_line(capsys.readouterr().err)
        assert f"'{out}'" in err and says in err, err


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only directory")
def test_an_unwritable_out_is_one_line(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        assert main(["sweep", str(write_sweep(tmp_path, 2)), "--out", str(ro / "o")]) == 2
        assert "Permission denied" in one_line(capsys.readouterr().err)
    finally:
        ro.chmod(0o700)


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize(
    ("address", "says"),
    [
        ("garbage", "not HOST:PORT"),
        ("foo://bar", "unknown scheme 'foo'"),
        ("tcp://127.0.0.1", "not HOST:PORT"),
        ("tcp://127.0.0.1:99999", "Port out of range"),
        ("tcp://127.0.0.1:{closed}", "Connection refused"),
    ],
)
def test_a_bad_scheduler_is_one_line(tmp_path, capsys, address, says):
    address = address.replace("{closed}", str(_closed_port()))
    out = tmp_path / "o"
    assert (
        main(["sweep", str(write_sweep(tmp_path, 2)), "--out", str(out), "--scheduler", address])
        == 2
    )
    err = one_line(capsys.readouterr().err)
    assert f"{address!r}" in err and says in err, err
    assert not (out / "rows.jsonl").exists()


@pytest.mark.slow  # one of the longest waits: CI's slow pass runs it
def test_a_scheduler_that_does_not_answer_is_one_line_within_the_connect_timeout(tmp_path):
    """A peer that accepts and says nothing (no Dask there, or a hung one): bounded by the
    connect timeout (here Dask's distributed.comm.timeouts.connect, 2 s)."""
    pytest.importorskip("distributed")
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(8)
        address = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
        env = {**os.environ, "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "2s"}
        t0 = time.monotonic()
        done = subprocess.run(
            [*EXE, "sweep", str(write_sweep(tmp_path, 2)), "--scheduler", address, "--out", "o"],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=120,
            env=env,
        )
    assert done.returncode == 2, done.stderr
    assert "no Dask scheduler answered within 2 s" in one_line(done.stderr)
    assert time.monotonic() - t0 < 60


@pytest.mark.slow  # a few seconds: CI's slow pass (the fast suite stays near 3 min)
def test_a_dask_scheduler_lost_mid_sweep_is_one_line_and_keeps_the_rows(tmp_path, sweeps):
    pytest.importorskip("distributed")
    port = _closed_port()
    address = f"tcp://127.0.0.1:{port}"
    cluster: list[subprocess.Popen] = []

    def start(*args: str) -> None:
        cluster.append(
            subprocess.Popen(
                [sys.executable, "-m", *args, "--no-dashboard"],
                start_new_session=True,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )

    def listening() -> bool:
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 1):
            return True
        return False

    try:
        start("distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", str(port))
        wait_until(listening, "the scheduler listening", timeout=60)
        start("distributed.cli.dask_worker", address, "--nworkers", "1", "--nthreads", "1")
        path, out = write_sweep(tmp_path, 2000), tmp_path / "out"
        proc = sweeps(path, out, "--scheduler", address)
        wait_until(lambda: len(lines(out)) >= 1, "the first rows", proc=proc)
        before = len(lines(out))
        os.killpg(cluster[0].pid, signal.SIGKILL)
        _, err = proc.communicate(timeout=120)
    finally:
        for p in cluster:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=30)
    assert proc.returncode == 2, err
    one_line(err)
    assert f"lost the Dask scheduler '{address}'" in err and "--resume" in err, err
    assert len(lines(out)) >= before
    read_rows(out, load_sweep(path).digest)


def test_rows_are_sealed_with_a_key_beside_the_table_and_an_older_sweep_is_sealed_anew(
    tmp_path, capsys
):
    """The seal is keyed by DIR/sweep.key (its owner's alone): without it no row is checked;
    a directory of an older rgtbus (unkeyed SHA-256 digests) is checked by that rule, then
    sealed with a key of its own on resume."""
    from rgtbus.units.sweep_store import row_digest

    path, out = write_sweep(tmp_path, 6), tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out), "--workers", "1", "--quiet"]) == 0
    key = out / "sweep.key"
    assert key.stat().st_mode & 0o777 == 0o600 and len(bytes.fromhex(key.read_text())) == 32
    assert "sweep.key" not in (out / "rows.jsonl").read_text()
    assert all("_hmac" in json.loads(r) for r in lines(out))
    key.rename(tmp_path / "elsewhere")
    capsys.readouterr()
    assert main(["sweep", str(path), "--out", str(out), "--resume", "--quiet"]) == 2
    assert "sweep.key is missing" in one_line(capsys.readouterr().err)
    # as an older rgtbus left it: unkeyed digests, no key
    info = json.loads((out / "sweep.json").read_text())
    old = []
    for r in lines(out)[:4]:
        row = json.loads(r)
        del row["_hmac"]
        old.append(json.dumps({**row, "_sha256": row_digest(row, info["digest"])}))
    (out / "rows.jsonl").write_text("\n".join(old) + "\n")
    (out / "sweep.json").write_text(json.dumps({**info, "rows": "sha256"}))
    assert main(["sweep", str(path), "--out", str(out), "--resume", "--quiet"]) == 0
    assert key.exists() and len(lines(out)) == 6
    assert all("_hmac" in json.loads(r) and "_sha256" not in r for r in lines(out))
    assert json.loads((out / "sweep.json").read_text())["rows"] == "hmac-sha256"
