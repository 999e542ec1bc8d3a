"""Where a sweep's runs run: a local process pool whose workers never import the caller's
``__main__`` (so ``sweep()`` works from a plain script or a notebook cell), the calling process
for one worker, or a Dask cluster's executor; runs go out in batches and come back as rows."""

from __future__ import annotations

import contextlib
import multiprocessing
import multiprocessing.context
import os
import sys
import threading
import types
from collections.abc import Iterator
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from rgtbus.errors import RgtbusError

if TYPE_CHECKING:
    pass


# -- where the runs run ------------------------------------------------------------------------

_HIDING = threading.Lock()


@contextlib.contextmanager
def _main_hidden() -> Iterator[None]:
    """``__main__`` is a bare module while a worker process starts.

    The spawn start method sends a new process the caller's main script path or module name
    (``multiprocessing.spawn.get_preparation_data``: ``init_main_from_path`` /
    ``init_main_from_name``) and the worker runs that script again as ``__mp_main__``; a script
    or notebook without an ``if __name__ == "__main__"`` guard then starts the sweep again in
    every worker, and the pool breaks. The workers of a sweep need nothing from ``__main__``
    (the task, ``run_batch``, and its arguments live in this module), so while one starts
    ``sys.modules["__main__"]`` is a module without ``__file__`` or ``__spec__``: the worker
    is told of no main module and imports only what it unpickles."""
    with _HIDING:
        main = sys.modules.get("__main__")
        sys.modules["__main__"] = types.ModuleType("__main__")
        try:
            yield
        finally:
            if main is not None:
                sys.modules["__main__"] = main
            else:
                del sys.modules["__main__"]


class _NoMainSpawnProcess(multiprocessing.context.SpawnProcess):
    """A spawned process that is never told of the caller's ``__main__`` (``_main_hidden``)."""

    @staticmethod
    def _Popen(process_obj: Any) -> Any:
        with _main_hidden():
            return multiprocessing.context.SpawnProcess._Popen(process_obj)


class _NoMainSpawnContext(multiprocessing.context.SpawnContext):
    """The spawn context (no state of this process leaks into a run) with workers that never
    import the caller's ``__main__``; pools may start workers at any ``submit``: each start
    hides it."""

    Process = _NoMainSpawnProcess  # type: ignore[assignment]


@dataclass
class Pool:
    """Where a sweep's runs go: ``executor`` (``None``: in this process) with ``workers``;
    ``record()`` is what sweep.json says of it."""

    executor: Executor | None
    workers: int
    kind: str  # "process-pool", "dask" or "in-process"
    scheduler: str | None = None
    start_method: str | None = None
    fallback: str | None = None  # why the runs went to this process instead of a pool

    def record(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "executor": self.kind,
            "scheduler": self.scheduler,
            "workers": self.workers,
            "start_method": self.start_method,
        }
        if self.fallback:
            out["fallback"] = self.fallback
        return out

    def fall_back(self, reason: str, runs: int) -> None:
        """Run the rest here; say so in one line on stderr."""
        print(
            f"rgtbus sweep: worker processes unavailable ({reason}); running {runs} runs in "
            "this process",
            file=sys.stderr,
            flush=True,
        )
        self.executor, self.workers, self.kind = None, 1, "in-process"
        self.start_method, self.fallback = None, reason


def one_line(exc: BaseException, limit: int = 200) -> str:
    """An exception as one short line (some, e.g. multiprocessing's, span many)."""
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def pool_of(executor: Executor | None, workers: int) -> Pool:
    """How sweep.json names an executor handed to ``run_sweep``."""
    if executor is None:
        return Pool(None, 1, "in-process")
    if isinstance(executor, ProcessPoolExecutor):
        ctx = getattr(executor, "_mp_context", None)
        method = ctx.get_start_method() if ctx is not None else None
        return Pool(executor, workers, "process-pool", start_method=method)
    if type(executor).__module__.startswith("distributed"):
        return Pool(executor, workers, "dask")
    return Pool(executor, workers, type(executor).__name__)


@contextlib.contextmanager
def _dask(scheduler: str) -> Iterator[tuple[Executor, int]]:
    from distributed import Client

    try:
        client = Client(scheduler, timeout="20s")
    except (OSError, TimeoutError) as exc:
        raise RgtbusError(f"cannot reach Dask scheduler {scheduler!r}: {exc}") from None
    try:
        n = max(1, sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values()))
        yield client.get_executor(pure=False), n
    finally:
        client.close()


@contextlib.contextmanager
def open_pool(
    workers: int | None, scheduler: str | None, runs: int | None = None
) -> Iterator[Pool]:
    """The Dask cluster at ``scheduler`` (``tcp://host:port``); else a local spawn process pool
    of ``workers`` (all cores by default, no more than ``runs``) whose workers never import
    ``__main__``; one worker: this process. A pool that cannot be made (no process support
    here) falls back to this process, said in one line on stderr."""
    if scheduler:
        with _dask(scheduler) as (ex, n):
            yield Pool(ex, n, "dask", scheduler=scheduler)
        return
    n = workers or os.cpu_count() or 1
    if runs is not None:
        n = max(1, min(n, runs))
    if n == 1:
        yield Pool(None, 1, "in-process")
        return
    try:
        pool = ProcessPoolExecutor(max_workers=n, mp_context=_NoMainSpawnContext())
    except (OSError, NotImplementedError, ImportError) as exc:
        p = Pool(None, n, "process-pool")
        p.fall_back(one_line(exc), runs or 0)
        yield p
        return
    try:
        yield Pool(pool, n, "process-pool", start_method="spawn")
    except BaseException:  # Ctrl-C, a broken pool: the batches not started are dropped
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()


@contextlib.contextmanager
def open_executor(workers: int | None, scheduler: str | None) -> Iterator[tuple[Executor, int]]:
    """A local process pool of ``workers`` (all cores by default; its workers never import
    ``__main__``), or the executor of the Dask cluster at ``scheduler``; with the number of
    workers it has. Always an executor (``open_pool`` runs one worker in this process)."""
    if scheduler:
        with _dask(scheduler) as got:
            yield got
        return
    n = workers or os.cpu_count() or 1
    with ProcessPoolExecutor(max_workers=n, mp_context=_NoMainSpawnContext()) as pool:
        yield pool, n
