"""Where a sweep's runs run: a local process pool whose workers never import the caller's
``__main__`` (so ``sweep()`` works from a plain script or a notebook cell), the calling process
for one worker, or a Dask cluster's executor; runs go out in batches and come back as rows."""

from __future__ import annotations

import collections
import contextlib
import multiprocessing
import multiprocessing.connection
import multiprocessing.context
import os
import pickle
import signal
import socket
import sys
import threading
import time
import types
from collections.abc import Callable, Iterator
from concurrent.futures import BrokenExecutor, Executor, Future, ProcessPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

from rgtbus.errors import BadInput, IOFailure
from rgtbus.extras import require

if TYPE_CHECKING:
    from multiprocessing.connection import Connection
    from multiprocessing.process import BaseProcess


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

    Process = _NoMainSpawnProcess


# -- the local pool: one run at a time per worker, a dead worker costs only its run -----------


class WorkerDied(RuntimeError):
    """The worker process running a submission died (killed, crashed): the submission's
    future fails with this; the pool and the other submissions go on."""


def _die_with_parent(parent: int) -> None:
    """In a worker: end when the sweep's process is gone, even if it was killed outright
    (SIGKILL leaves it no time to stop its workers). Linux: the kernel sends SIGKILL
    (``prctl(PR_SET_PDEATHSIG)``); everywhere: a thread polls the parent pid."""
    with contextlib.suppress(Exception):
        if sys.platform.startswith("linux"):
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG

    def watch() -> None:
        while True:
            if os.getppid() != parent:
                os._exit(1)
            time.sleep(0.5)

    if os.getppid() != parent:  # gone before the prctl above took hold
        os._exit(1)
    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _worker_main(conn: Connection, parent: int) -> None:
    """A ``SweepPool`` worker: runs what it is sent, one at a time, answers each. Ctrl-C is
    the sweep's to handle (a terminal sends it to the whole process group): ignored here."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):  # blocked while this process started
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    _die_with_parent(parent)
    conn.send(("ready", os.getpid()))
    while True:
        try:
            data = conn.recv_bytes()
        except (EOFError, OSError):
            return
        answer: tuple[bool, Any]
        try:  # a submission that does not unpickle here is its error, not the worker's end
            msg = pickle.loads(data)
        except Exception as exc:
            conn.send((False, RuntimeError(f"the worker cannot read what it was sent: {exc}")))
            continue
        if msg is None:
            return
        fn, args, kwargs = msg
        try:
            answer = (True, fn(*args, **kwargs))
        except BaseException as exc:  # the caller's to judge
            answer = (False, exc)
        try:
            conn.send(answer)
        except Exception as exc:  # an answer that does not pickle
            conn.send((False, RuntimeError(" ".join(f"{type(exc).__name__}: {exc}".split()))))


@contextlib.contextmanager
def _sigint_held() -> Iterator[None]:
    """While a worker process is started from the main thread: SIGINT is ignored (the worker
    inherits that, so a Ctrl-C during its start-up prints no traceback there) and blocked (so
    one that comes meanwhile is not lost here: it is delivered as soon as the handler is back).
    The resource tracker is started first: starting it unblocks SIGINT."""
    if (
        threading.current_thread() is not threading.main_thread()
        or not hasattr(signal, "pthread_sigmask")
        or signal.getsignal(signal.SIGINT) is None  # a handler not set from Python: kept
    ):
        yield
        return
    with contextlib.suppress(Exception):
        from multiprocessing import resource_tracker

        resource_tracker.ensure_running()
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            yield
        finally:
            signal.signal(signal.SIGINT, old)
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


@dataclass
class _Item:
    future: Future[Any]
    fn: Callable[..., Any]
    args: tuple[Any, ...]
    kwargs: dict[str, Any]
    started: bool = False


@dataclass
class _Worker:
    process: BaseProcess
    conn: Connection
    ready: bool = False
    item: _Item | None = None
    answered: int = 0


def _how_it_ended(code: int | None) -> str:
    if code is not None and code < 0:
        with contextlib.suppress(ValueError):
            return f"was killed by {signal.Signals(-code).name}"
        return f"was killed by signal {-code}"
    return f"ended with exit code {code}"


class SweepPool(Executor):
    """A pool of spawned worker processes (they never import the caller's ``__main__``) that
    runs one submission at a time in each worker.

    Unlike ``ProcessPoolExecutor``, a worker that dies (``kill -9``, a crash) fails only the
    submission it was running, with ``WorkerDied`` naming the process and how it ended, and is
    replaced; the pool breaks (``BrokenExecutor``) only when no worker process can start.
    ``terminate()`` stops every worker at once (Ctrl-C), and the workers end by themselves
    when this process is gone (``_die_with_parent``). Measured against ``ProcessPoolExecutor``
    (``python -m benchmarks.bench_pool``): a killed worker fails 1 of 8 tasks here, all 8
    there; Ctrl-C with tasks of 15 s running stops here at once, there after 29 s; when this
    process is killed -9 no worker is left running here, both are there."""

    def __init__(
        self, max_workers: int, mp_context: multiprocessing.context.BaseContext | None = None
    ) -> None:
        if max_workers < 1:
            raise ValueError("max_workers must be at least 1")
        self.max_workers = max_workers
        self._context = mp_context or _NoMainSpawnContext()
        self._workers: list[_Worker] = []
        self._queue: collections.deque[_Item] = collections.deque()
        self._lock = threading.Lock()
        self._shutdown = False
        self._terminate = False
        self._broken: str | None = None
        self._start_failure: str | None = None
        self._wake_r, self._wake_w = multiprocessing.Pipe(duplex=False)
        try:
            with _sigint_held():
                for _ in range(max_workers):
                    self._workers.append(self._spawn())
        except BaseException:
            for w in self._workers:
                w.process.kill()
                w.process.join(5)
            raise
        self._thread = threading.Thread(target=self._manage, name="sweep-pool", daemon=True)
        self._thread.start()

    def _spawn(self) -> _Worker:
        ours, theirs = multiprocessing.Pipe()
        # every concrete context has Process; the stub of BaseContext (the type of a context
        # handed in) does not
        proc = self._context.Process(  # type: ignore[attr-defined]
            target=_worker_main, args=(theirs, os.getpid()), daemon=True
        )
        try:
            proc.start()
        finally:
            theirs.close()
        return _Worker(proc, ours)

    # -- Executor --------------------------------------------------------------------------

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        """Queue ``fn(*args, **kwargs)`` for the next free worker; ``BrokenExecutor`` once no
        worker can start."""
        with self._lock:
            if self._broken:
                raise BrokenExecutor(self._broken)
            if self._shutdown or self._terminate:
                raise RuntimeError("cannot submit to a pool that is shut down")
            fut: Future[Any] = Future()
            self._queue.append(_Item(fut, fn, args, kwargs))
        self._wake()
        return fut

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Take no more submissions; the workers end once what is queued has run (what has
        not started is cancelled with ``cancel_futures``). ``wait``: return when they have."""
        with self._lock:
            self._shutdown = True
            if cancel_futures:
                self._cancel_queued()
        self._wake()
        if wait:
            self._thread.join()

    def terminate(self, timeout: float = 10.0) -> None:
        """Stop now: what is queued is cancelled, every worker is killed (SIGTERM, then SIGKILL
        after a second), and reaped; what was running fails with ``BrokenExecutor``."""
        with self._lock:
            self._terminate = True
            self._cancel_queued()
        self._wake()
        self._thread.join(timeout)

    def pids(self) -> list[int]:
        """The worker processes' ids (tests; diagnostics)."""
        with self._lock:
            return [w.process.pid for w in self._workers if w.process.pid is not None]

    # -- the manager thread ----------------------------------------------------------------

    def _wake(self) -> None:
        with contextlib.suppress(OSError, ValueError):
            self._wake_w.send_bytes(b"")

    def _cancel_queued(self) -> None:
        while self._queue:
            item = self._queue.popleft()
            if item.started:
                item.future.set_exception(BrokenExecutor("the pool was stopped"))
            else:
                item.future.cancel()

    def _dispatch(self) -> None:
        for w in self._workers:
            if not self._queue:
                return
            if not w.ready or w.item is not None:
                continue
            item = self._queue.popleft()
            if not item.started and not item.future.set_running_or_notify_cancel():
                continue
            item.started = True
            try:
                w.conn.send((item.fn, item.args, item.kwargs))
            except (BrokenPipeError, ConnectionError, EOFError):  # it is dying: run it elsewhere
                self._queue.appendleft(item)
                w.ready = False
            except Exception as exc:  # the submission does not pickle
                item.future.set_exception(exc)
            else:
                w.item = item

    def _manage(self) -> None:
        try:
            while True:
                with self._lock:
                    if self._terminate:
                        return
                    self._dispatch()
                    busy = any(w.item is not None for w in self._workers)
                    if self._shutdown and not self._queue and not busy:
                        return
                    if not self._workers:
                        self._broken = "no worker process could start" + (
                            f" ({self._start_failure})" if self._start_failure else ""
                        )
                        while self._queue:
                            self._queue.popleft().future.set_exception(BrokenExecutor(self._broken))
                        if self._shutdown:
                            return
                    conns: list[Any] = [self._wake_r]
                    for w in self._workers:
                        conns += [w.process.sentinel] + ([] if w.conn.closed else [w.conn])
                ready = set(multiprocessing.connection.wait(conns))
                if self._wake_r in ready:
                    with contextlib.suppress(OSError, EOFError):
                        while self._wake_r.poll():
                            self._wake_r.recv_bytes()
                for w in list(self._workers):
                    if w.conn in ready:
                        self._read(w)
                    if w.process.sentinel in ready or (w.conn in ready and w.conn.closed):
                        self._ended(w)
        except Exception as exc:  # a bug here: fail what is out rather than leave it hanging
            with self._lock:
                self._broken = f"the pool failed: {one_line(exc)}"
                for item in [*self._queue, *(w.item for w in self._workers if w.item)]:
                    if not item.future.done():
                        item.future.set_exception(BrokenExecutor(self._broken))
                self._queue.clear()
        finally:
            self._stop_workers(graceful=not self._terminate and self._broken is None)

    def _read(self, w: _Worker) -> None:
        try:
            while w.conn.poll():
                msg = w.conn.recv()
                if msg[0] == "ready":
                    w.ready = True
                    continue
                ok, value = msg
                item, w.item = w.item, None
                w.answered += 1
                if item is None or item.future.done():
                    continue
                if ok:
                    item.future.set_result(value)
                else:
                    item.future.set_exception(value)
        except (EOFError, OSError):
            w.conn.close()  # the worker is gone: _ended reaps it

    def _ended(self, w: _Worker) -> None:
        """A worker process ended: fail what it ran, reap it, start another in its place."""
        if not w.conn.closed:
            self._read(w)  # what it answered before it died
        w.process.join(5)
        if w.process.is_alive():
            return  # only its pipe closed; its sentinel says when it is gone
        how = _how_it_ended(w.process.exitcode)
        with self._lock:
            self._workers.remove(w)
            with contextlib.suppress(OSError):
                w.conn.close()
            if w.item is not None and not w.item.future.done():
                w.item.future.set_exception(
                    WorkerDied(f"process {w.process.pid} {how} while running it")
                )
            if self._terminate:
                return
            if not w.ready and w.answered == 0:
                self._start_failure = f"a worker process {how} as it started"
                return
            try:  # a worker that dies costs only the run it ran: another takes its place
                self._workers.append(self._spawn())
            except Exception as exc:
                self._start_failure = one_line(exc)

    def _stop_workers(self, graceful: bool) -> None:
        with self._lock:
            workers = list(self._workers)
            self._workers.clear()
            self._cancel_queued()
        if graceful:
            for w in workers:
                with contextlib.suppress(Exception):
                    w.conn.send(None)
            deadline = time.monotonic() + 5
            for w in workers:
                w.process.join(max(0.0, deadline - time.monotonic()))
        for w in workers:
            if w.process.is_alive():
                w.process.terminate()
        deadline = time.monotonic() + 1
        for w in workers:
            w.process.join(max(0.0, deadline - time.monotonic()))
            if w.process.is_alive():
                w.process.kill()
                w.process.join(5)
            if w.item is not None and not w.item.future.done():
                w.item.future.set_exception(BrokenExecutor("the pool was stopped"))
            with contextlib.suppress(OSError):
                w.conn.close()
        with contextlib.suppress(OSError):
            self._wake_r.close()
            self._wake_w.close()


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
        """What sweep.json says of the pool: kind, scheduler, workers, start method, fallback."""
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
    text = " ".join(f"{type(exc).__name__}: {exc}".split()).removesuffix(":")
    return text if len(text) <= limit else text[: limit - 1] + "…"


def pool_of(executor: Executor | None, workers: int) -> Pool:
    """How sweep.json names an executor handed to ``run_sweep``."""
    if executor is None:
        return Pool(None, 1, "in-process")
    if isinstance(executor, SweepPool):
        return Pool(executor, workers, "process-pool", start_method="spawn")
    if isinstance(executor, ProcessPoolExecutor):
        ctx = getattr(executor, "_mp_context", None)
        method = ctx.get_start_method() if ctx is not None else None
        return Pool(executor, workers, "process-pool", start_method=method)
    if type(executor).__module__.startswith("distributed"):
        return Pool(executor, workers, "dask")
    return Pool(executor, workers, type(executor).__name__)


# Dask's address schemes; tcp is the default (``HOST:PORT``)
SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx", "inproc")
CONNECT_SECONDS = 10.0  # at most; less if Dask's distributed.comm.timeouts.connect says so


def _connect_seconds() -> float:
    with contextlib.suppress(Exception):
        import dask.config
        from dask.utils import parse_timedelta

        got = parse_timedelta(dask.config.get("distributed.comm.timeouts.connect"), "s")
        if got and got > 0:
            return min(CONNECT_SECONDS, float(got))
    return CONNECT_SECONDS


def check_scheduler(address: str) -> None:
    """A Dask scheduler address, checked before a client is made: a known scheme, a host and a
    port, something listening there (within the connect timeout). One line if not."""
    if not isinstance(address, str) or not address.strip():
        raise BadInput(f"scheduler {address!r}: not an address (tcp://HOST:PORT)")
    scheme, sep, rest = address.partition("://")
    if not sep:
        scheme, rest = "tcp", address
    if scheme not in SCHEDULER_SCHEMES:
        raise BadInput(
            f"scheduler {address!r}: unknown scheme {scheme!r} (tcp://HOST:PORT; Dask knows "
            f"{', '.join(SCHEDULER_SCHEMES)})"
        )
    if scheme in ("ucx", "inproc"):
        return
    try:
        parts = urlsplit("//" + rest)
        host, port = parts.hostname, parts.port
    except ValueError as exc:
        raise BadInput(f"scheduler {address!r}: {exc} (tcp://HOST:PORT)") from None
    if not host or port is None or parts.path not in ("", "/"):
        raise BadInput(f"scheduler {address!r}: not HOST:PORT (e.g. tcp://127.0.0.1:8786)")
    try:
        socket.create_connection((host, port), timeout=_connect_seconds()).close()
    except TimeoutError:
        raise BadInput(
            f"cannot reach Dask scheduler {address!r}: no answer within {_connect_seconds():g} s"
        ) from None
    except OSError as exc:
        reason = exc.strerror or one_line(exc)
        raise IOFailure(f"cannot reach Dask scheduler {address!r}: {reason}") from None


@contextlib.contextmanager
def _dask(scheduler: str) -> Iterator[tuple[Executor, int]]:
    require("distributed", f"--scheduler {scheduler!r}")
    check_scheduler(scheduler)
    from distributed import Client

    timeout = _connect_seconds()
    with contextlib.ExitStack() as quiet:
        # a client that loses its scheduler logs tracebacks from its event loop's thread, and
        # more as it closes: the sweep says what happened in one line
        quiet.enter_context(_quiet_loggers("distributed", "tornado", tracebacks_only=True))
        client = _client(Client, scheduler, timeout)
        try:
            try:
                info = client.scheduler_info()["workers"]
            except Exception as exc:
                raise BadInput(f"Dask scheduler {scheduler!r}: {one_line(exc)}") from None
            n = max(1, sum(w.get("nthreads", 1) for w in info.values()))
            yield client.get_executor(pure=False), n
        finally:
            with _quiet_loggers("distributed", "tornado"), contextlib.suppress(Exception):
                client.close(timeout=timeout)


def _client(make: Callable[..., Any], scheduler: str, timeout: float) -> Any:
    """A Dask client of ``scheduler``, made within ``timeout`` (and a little): its own timeout
    bounds the TCP connect, but not a peer that accepts and then says nothing. Past the bound
    the attempt is left to a daemon thread."""
    box: dict[str, Any] = {}

    def connect() -> None:
        try:
            box["client"] = make(scheduler, timeout=f"{timeout}s", set_as_default=False)
        except BaseException as exc:  # told below, in one line
            box["error"] = exc

    thread = threading.Thread(target=connect, name="dask-connect", daemon=True)
    thread.start()
    thread.join(timeout + 2)
    if thread.is_alive():
        raise BadInput(
            f"cannot reach Dask scheduler {scheduler!r}: no Dask scheduler answered within "
            f"{timeout:g} s"
        )
    if "error" in box:  # a peer that is no Dask scheduler says so in many ways
        raise BadInput(
            f"cannot reach Dask scheduler {scheduler!r}: no Dask scheduler answered there "
            f"({one_line(box['error'])})"
        )
    return box["client"]


class _NoTracebacks:
    """A logging filter: drops records that carry a traceback."""

    def filter(self, record: Any) -> bool:
        return not record.exc_info


@contextlib.contextmanager
def _quiet_loggers(*prefixes: str, tracebacks_only: bool = False) -> Iterator[None]:
    """The loggers under ``prefixes`` say nothing (``tracebacks_only``: nothing with a
    traceback) meanwhile. A Dask client that loses its scheduler logs tracebacks from its
    event loop thread; the sweep says what happened in one line."""
    import logging

    names = [n for n in list(logging.root.manager.loggerDict) if n.split(".")[0] in prefixes]
    loggers = [logging.getLogger(n) for n in [*prefixes, *names]]
    levels = [lg.level for lg in loggers]
    quiet = _NoTracebacks()
    for lg in loggers:
        if tracebacks_only:
            lg.addFilter(quiet)
        else:
            lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.removeFilter(quiet)
            lg.setLevel(level)


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
        pool = SweepPool(n)
    except (OSError, NotImplementedError, ImportError) as exc:
        p = Pool(None, n, "process-pool")
        p.fall_back(one_line(exc), runs or 0)
        yield p
        return
    try:
        yield Pool(pool, n, "process-pool", start_method="spawn")
    except BaseException:  # Ctrl-C, an error: the workers are stopped now, not waited for
        pool.terminate()
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
    pool = SweepPool(n)
    try:
        yield pool, n
    except BaseException:
        pool.terminate()
        raise
    pool.shutdown()
