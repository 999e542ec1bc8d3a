"""Why a sweep's runs go to ``SweepPool`` (units/workers.py) and not to the standard library's
``ProcessPoolExecutor``: the three guarantees a sweep needs, measured on both, the same work
in the same call.

1. **A killed worker costs one run.** Four workers, eight tasks of 2 s; one worker is killed
   (SIGKILL) half a second in. Counted: the tasks that failed, and whether the others finished.
2. **Ctrl-C stops at once.** Two workers, four tasks of 15 s; one second in, the sweep stops
   the executor the fastest way its public API offers (``SweepPool.terminate()``;
   ``ProcessPoolExecutor.shutdown(wait=True, cancel_futures=True)``). Timed: until it returns.
3. **No orphans.** A process runs two workers on tasks of 15 s and is killed (SIGKILL) one second
   in. Counted, three seconds later: its workers still alive.

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


def _spawn_pool(kind: str, workers: int) -> Executor:
    if kind == "SweepPool":
        return SweepPool(workers)
    return ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"))


def _pids(pool: Executor) -> list[int]:
    if isinstance(pool, SweepPool):
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
    kinds = ["SweepPool", "ProcessPoolExecutor"]
    rows = [
        ("a worker killed (8 tasks of 2 s)", killed_worker),
        (f"Ctrl-C (tasks of {LONG:g} s running)", stopped),
        ("its process killed -9 (3 s later)", orphans),
    ]
    table = [[name, *(fn(kind) for kind in kinds)] for name, fn in rows]
    width = [max(len(r[i]) for r in [["guarantee", *kinds], *table]) for i in range(3)]
    for r in [["guarantee", *kinds], *table]:
        print("  ".join(c.ljust(w) for c, w in zip(r, width, strict=True)))


if __name__ == "__main__":
    main()
