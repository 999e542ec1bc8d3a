"""Why a sweep's runs go to ``SweepPool`` (units/workers.py) and not to the standard library's
``ProcessPoolExecutor`` or Dask's ``LocalCluster`` (its ``Client.get_executor()``, worker
processes, one thread each): the three guarantees a sweep needs, measured on all three, the
same work in the same call.

1. **A killed worker costs one run.** Four workers, eight tasks of 2 s; one worker is killed
   (SIGKILL) half a second in. Counted: the tasks that failed, and whether the others finished.
2. **Ctrl-C stops at once.** Two workers, four tasks of 15 s; one second in, the sweep stops
   the executor the fastest way its public API offers (``SweepPool.terminate()``;
   ``ProcessPoolExecutor.shutdown(wait=True, cancel_futures=True)``; ``Client.close()`` then
   ``LocalCluster.close()``). Timed: until it returns.
3. **No orphans.** A process runs two workers on tasks of 15 s and is killed (SIGKILL) one second
   in. Counted, three seconds later: its workers still alive.
4. **A run that kills its worker** (a crash in native code, the kernel's OOM killer): four
   tasks of 1 s and one that kills its own worker. Counted: how often the bad one was tried,
   and what became of it and of the others.
5. **Start-up**: from creating the executor to every worker having run a task (informative).

    python -m benchmarks.bench_pool

prints one table, a row a guarantee, a column an executor.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import subprocess
import sys
import textwrap
import time
from concurrent.futures import Executor, ProcessPoolExecutor, wait
from typing import Any

from rgtbus.units.workers import SweepPool

LONG = 15.0


class _DaskLocal(Executor):
    """A Dask ``LocalCluster`` of worker processes (one thread each) as an ``Executor``."""

    def __init__(self, workers: int) -> None:
        import logging

        from distributed import Client, LocalCluster

        self.cluster = LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
            silence_logs=logging.CRITICAL,
        )  # fmt: skip
        self.client = Client(self.cluster)
        self.executor = self.client.get_executor()

    def submit(self, fn: Any, /, *args: Any, **kwargs: Any) -> Any:
        return self.executor.submit(fn, *args, **kwargs)

    def pids(self) -> list[int]:
        return [w.process.pid for w in self.cluster.workers.values()]  # type: ignore[attr-defined]

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self.client.close()
        self.cluster.close()


def _spawn_pool(kind: str, workers: int) -> Executor:
    if kind == "SweepPool":
        return SweepPool(workers)
    if kind == "LocalCluster":
        return _DaskLocal(workers)
    return ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"))


def _pids(pool: Executor) -> list[int]:
    if isinstance(pool, SweepPool | _DaskLocal):
        return pool.pids()
    procs: dict[int, Any] = getattr(pool, "_processes", None) or {}  # what it started
    return list(procs)


def _warm(pool: Executor, workers: int) -> None:
    """Every worker started (ProcessPoolExecutor starts them as work comes)."""
    wait([pool.submit(time.sleep, 0.2) for _ in range(workers)])


def killed_worker(kind: str) -> str:
    pool = _spawn_pool(kind, 4)
    try:
        _warm(pool, 4)
        futures = [pool.submit(time.sleep, 2.0) for _ in range(8)]
        time.sleep(0.5)
        os.kill(_pids(pool)[0], signal.SIGKILL)
        done, _ = wait(futures, timeout=30)
        failed = sum(1 for f in done if f.exception() is not None)
        return f"{failed} of 8 failed, {len(done) - failed} finished"
    finally:
        pool.shutdown(wait=False, cancel_futures=True)


def stopped(kind: str) -> str:
    pool = _spawn_pool(kind, 2)
    _warm(pool, 2)
    for _ in range(4):
        pool.submit(time.sleep, LONG)
    time.sleep(1.0)
    t0 = time.monotonic()
    if isinstance(pool, SweepPool):
        pool.terminate()
    else:
        pool.shutdown(wait=True, cancel_futures=True)
    return f"{time.monotonic() - t0:.1f} s to stop"


def _crash(path: str) -> None:
    """A run that kills its own worker, noting each try in ``path``."""
    with open(path, "a") as f:
        f.write("x")
    os.kill(os.getpid(), signal.SIGKILL)


def crashing_run(kind: str) -> str:
    import tempfile

    pool = _spawn_pool(kind, 2)
    with tempfile.TemporaryDirectory() as tmp:
        tries = os.path.join(tmp, "tries")
        try:
            _warm(pool, 2)
            good = [pool.submit(time.sleep, 1.0) for _ in range(4)]
            # by its importable name: SweepPool's workers never import the caller's __main__
            from benchmarks.bench_pool import _crash as crash

            bad = pool.submit(crash, tries)
            done, _ = wait([*good, bad], timeout=60)
            ok = sum(1 for f in good if f in done and f.exception() is None)
            error = bad.exception() if bad in done else None
            what = type(error).__name__ if error is not None else "no answer"
            n = os.path.getsize(tries) if os.path.exists(tries) else 0  # a byte a try
            return f"tried {n}×, {what}; {ok} of 4 others finished"
        finally:
            pool.shutdown(wait=False, cancel_futures=True)


def start_up(kind: str) -> str:
    t0 = time.monotonic()
    pool = _spawn_pool(kind, 2)
    try:
        _warm(pool, 2)
        return f"{time.monotonic() - t0:.1f} s"
    finally:
        pool.shutdown(wait=True)


_ORPHAN = """
import sys, time
from concurrent.futures import wait
sys.path.insert(0, {root!r})
from benchmarks.bench_pool import _spawn_pool, _pids, _warm
pool = _spawn_pool({kind!r}, 2)
_warm(pool, 2)
for _ in range(2):
    pool.submit(time.sleep, {long})
print(*_pids(pool), flush=True)
time.sleep(60)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:  # a zombie waiting for init is gone too
        return f.read().split(")")[-1].split()[0] != "Z"


def orphans(kind: str) -> str:
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    code = textwrap.dedent(_ORPHAN.format(root=root, kind=kind, long=LONG))
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert parent.stdout is not None
    pids = [int(p) for p in parent.stdout.readline().split()]
    time.sleep(1.0)
    parent.kill()
    parent.wait()
    time.sleep(3.0)
    left = [p for p in pids if _alive(p)]
    for p in left:  # the measurement leaves nothing behind either way
        os.kill(p, signal.SIGKILL)
    return f"{len(left)} of {len(pids)} workers left running"


def main() -> None:
    kinds = ["SweepPool", "ProcessPoolExecutor", "LocalCluster"]
    rows = [
        ("a worker killed (8 tasks of 2 s)", killed_worker),
        (f"Ctrl-C (tasks of {LONG:g} s running)", stopped),
        ("its process killed -9 (3 s later)", orphans),
        ("a run that kills its worker", crashing_run),
        ("start-up (2 workers, a task each)", start_up),
    ]
    table = [[name, *(fn(kind) for kind in kinds)] for name, fn in rows]
    width = [max(len(r[i]) for r in [["guarantee", *kinds], *table]) for i in range(4)]
    for r in [["guarantee", *kinds], *table]:
        print("  ".join(c.ljust(w) for c, w in zip(r, width, strict=True)))


if __name__ == "__main__":
    main()
