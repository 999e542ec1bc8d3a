"""Sweeps: one scenario run over seeds and a grid of scenario keys, on a distributed engine.

A sweep file (TOML) names a base scenario, seeds and a grid::

    name = "decomposable"
    scenario = "../example1.toml"        # relative to the sweep file
    seeds = "0..199"                     # inclusive range, or a list of integers
    [grid]
    n = [3, 4, 5]                        # a group of n units u1..un
    "relations.p" = [0.3, 0.61, 0.9]     # any scenario key, dotted
    engine = ["event"]                   # not a scenario key: the engine of the run
    [cases]                              # optional: named sets of keys that go together
    spike = { "timing.anchor" = "spike" }
    concurrent = { "protocol.schedule" = "concurrent" }

The library function ``sweep(scenario, grid=..., seeds=...)`` builds the same ``Sweep`` from
arguments; ``rgtbus sweep FILE`` builds it from the file (``load_sweep``); both then run
``execute_sweep``: one code path.

Every (grid cell, seed) is one run on the memory bus (the same results as zenoh, docs/engine.md)
in a worker process; each run gives one row of the results table (``run_row``). Runs are
handed out to any ``concurrent.futures.Executor``: a local process pool by default (one run a
submission: ``SweepPool``, where a worker that dies costs only its run), or a Dask distributed
cluster's (``Client(address).get_executor()``, small batches), the same code path; one worker
runs them in this process. Rows are appended to ``rows.jsonl`` as they arrive, each sealed, in
a directory locked against a second writer (the store: ``rgtbus.units.sweep_store``), so a
sweep stopped halfway (Ctrl-C, a kill, a lost cluster: docs/sweeps.md, "Faults") resumes with
only what is missing; the tables
are written as
``results.jsonl`` (one row per run, plain JSON), ``decisions.jsonl`` (one row per run, unit and
influence round), ``results.csv`` (the results, nested columns as JSON text) and, where pyarrow
is installed (the ``parquet`` extra), ``results.parquet`` and ``decisions.parquet`` with native
Arrow types (``rgtbus.telemetry.sweep_tables``).

The local pool never imports the caller's ``__main__`` in its workers (``_NoMainSpawnContext``):
the task function lives here, so a script or notebook cell without an
``if __name__ == "__main__"`` guard can run a sweep on many processes.
"""

from __future__ import annotations

import collections
import hashlib
import json
import math
import os
import sys
import tempfile
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, BrokenExecutor, Executor, Future, wait
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rgtbus.units.sweep_spec import (
    Sweep,
    Task,
    engine_of,
    load_sweep,
    make_sweep,
    scenario_for,
)
from rgtbus.units.sweep_store import ROWS, SweepStore, sealed_line, write_versions
from rgtbus.units.workers import (
    Pool,
    WorkerDied,
    one_line,
    open_executor,
    open_pool,
    pool_of,
)

from rgtbus.errors import BadInput, IOFailure, RgtbusError
from rgtbus.scenario import Scenario
from rgtbus.summary import summary_json
from rgtbus.telemetry.sweep_read import SweepTables, read_results, read_sweep
from rgtbus.telemetry.sweep_tables import (
    NOT_COLUMNS,
    table_rows,
    write_tables,
)


class SweepRows(list[dict[str, Any]]):
    """The results' rows of a sweep, in task order (a list), and what the sweep had to say
    as it ran (``notes``: one line each, e.g. a line of rows.jsonl cut by a kill and run
    again): the library returns them; ``rgtbus sweep`` prints them on stderr."""

    def __init__(self, rows: Sequence[dict[str, Any]], notes: Sequence[str] = ()) -> None:
        super().__init__(rows)
        self.notes = list(notes)


__all__ = [
    "Sweep",
    "SweepRows",
    "SweepTables",
    "Task",
    "decisions",
    "execute_sweep",
    "load_sweep",
    "make_sweep",
    "open_executor",
    "read_sweep",
    "run_row",
    "run_sweep",
    "sweep",
    "table_rows",
]

if TYPE_CHECKING:
    import pandas as pd
    from rgtbus.units.unit import AutonomousUnit

# -- one run -----------------------------------------------------------------------------------


def run_row(sweep: Sweep, task: Task, log_dir: str | None = None) -> dict[str, Any]:
    """One run as one row of the results table, its fields as the run summary states them
    (``table_row`` shapes it for the table); the run's decisions under ``"_decisions"``. A run
    that raises is a row with its error."""
    from rgtbus.units.group import run_group

    from rgtbus.telemetry import McapRecorder, NullRecorder

    row = _row_head(sweep, task)
    engine = row["engine"]
    log_path = None
    try:
        sc = scenario_for(sweep, task.cell, task.seed)
        row["digest"] = hashlib.sha256(sc.text.encode()).hexdigest()[:16]
        row["schedule"] = sc.protocol.schedule
        row["n_units"] = len(sc.units)
        if log_dir is not None:
            log_path = os.path.join(log_dir, f"run-{task.index:07d}.mcap")
            with open(log_path, "wb") as f, McapRecorder(f) as rec:
                out = run_group(sc, "memory", rec, engine=engine)
        else:
            out = run_group(sc, "memory", NullRecorder(), engine=engine)
        s = summary_json({**out.summary, "log": log_path})
        grid_keys = {k for k, _ in task.cell}
        for k, v in s.items():
            if k in NOT_COLUMNS:
                continue
            # a grid key keeps its name; a summary field of the same name gets a prefix
            row[f"summary.{k}" if k in grid_keys else k] = v
        row["_decisions"] = s.get("decisions") or []
        misread = s["decode_errors"]
        row["decode_error_count"] = misread["misread"]
        row["frustrated_count"] = len(s["frustrated"])
        decided = sum(1 for u in s["units"].values() if u["decided"])
        row["decided_count"] = decided
        row["wrong_decision_count"] = len(s["wrong_decisions"])
        # per unit that decided; a run that failed before deciding has no rate
        row["wrong_decision_rate"] = len(s["wrong_decisions"]) / decided if decided else None
        row.update(goal_columns(s))
        rels = list(s["relations"].values())
        row["alliance_share"] = rels.count("alliance") / len(rels) if rels else None
        decodes = sum(len(m.decoded) for m in out.units)
        row["decodes"] = decodes
        row["decode_error_rate"] = misread["misread"] / decodes if decodes else None
        row["decode_errors_left"] = misread["left_wrong"]
        row.update(id_columns(misread, out.units))
        row["failed"] = s["error"] is not None
    except Exception as exc:  # a run that raises is a result of the sweep, never its end
        row["error"] = run_error(exc)
        row["failed"] = True
    row["log"] = log_path
    return row


def run_error(exc: Exception) -> str:
    """The one line of a run that raised: an rgtbus error as it says, anything else with its
    type and where it was raised (the file and line)."""
    if isinstance(exc, RgtbusError):
        return str(exc)
    last = traceback.extract_tb(exc.__traceback__)[-1:] or None
    at = f" (at {Path(last[0].filename).name}:{last[0].lineno})" if last else ""
    return f"{type(exc).__name__}: {exc}{at}"


def id_columns(misread: Mapping[str, Any], units: Sequence[AutonomousUnit]) -> dict[str, Any]:
    """A run's ID-codes as read: how many its units decoded (``id_decodes``), how many of
    those read otherwise than sent (``id_misread_count``, ``id_misread_rate``), and how many
    misread IDs stayed wrong in what the unit took from their turns (``id_misreads_left``:
    a repair, or the payload read right all the same, sets one right). ``misread``: the
    summary's ``decode_errors`` (``rgtbus.misreads``). What the ID-noise study plots
    (scenarios/sweeps/id_noise.toml)."""
    ids = misread["by_kind"]["id"]
    decoded = sum(m.decoded.count("id") for m in units)
    return {
        "id_decodes": decoded,
        "id_misread_count": ids["misread"],
        "id_misread_rate": ids["misread"] / decoded if decoded else None,
        "id_misreads_left": ids["left_wrong"],
    }


def _row_head(sweep: Sweep, task: Task) -> dict[str, Any]:
    row: dict[str, Any] = {"run": task.index}
    for key, value in task.cell:
        row[key] = json.dumps(value) if isinstance(value, list | dict) else value
    row["seed"] = task.seed
    row["engine"] = engine_of(sweep, task.cell)
    return row


def lost_row(sweep: Sweep, task: Task, why: str) -> dict[str, Any]:
    """The row of a run whose worker died under it (``kill -9``, the OOM killer, a crash of
    the interpreter): an error row, marked so that ``--resume`` runs it again (an error the run
    itself raised is its result, kept)."""
    row = _row_head(sweep, task)
    error = f"{WORKER_DIED}: {why}; --resume runs it again"
    row.update(error=error, failed=True, log=None, _worker_died=True)
    return row


def goal_columns(s: Mapping[str, Any]) -> dict[str, Any]:
    """A run's goals and rounds as plain columns: how many goals; of the judged ones the share
    reached by the targets' decisions (simulated) and the share reachable by the unit's own
    influence given what the others sent (the inverse task); the mean steerable share (the
    inverse task over every joint influence of the others); the rounds' state and cycle
    length. ``goal_reached`` / ``goal_reachable``: the same for a run with exactly one goal,
    as yes/no (``sweep-plot`` draws a share with Wilson intervals)."""
    goals = s.get("goals") or []
    rounds = s.get("rounds") or {}

    def share(key: str) -> float | None:
        judged = [g[key] for g in goals if g[key] is not None]
        return sum(judged) / len(judged) if judged else None

    shares = [g["share"] for g in goals if g["share"] is not None]
    one = goals[0] if len(goals) == 1 else None
    return {
        "goal_count": len(goals),
        "goal_reached_rate": share("reached"),
        "goal_reachable_rate": share("reachable"),
        "goal_share_mean": sum(shares) / len(shares) if shares else None,
        "goal_reached": None if one is None else one["reached"],
        "goal_reachable": None if one is None else one["reachable"],
        "rounds_state": rounds.get("state"),
        "rounds_cycle_length": rounds.get("length") if rounds.get("state") == "cycle" else None,
    }


def run_batch(sweep: Sweep, tasks: list[Task], log_dir: str | None) -> list[dict[str, Any]]:
    """What a worker runs: a batch of tasks (one submission each, for low overhead)."""
    return [run_row(sweep, t, log_dir) for t in tasks]


# -- runs as they finish -----------------------------------------------------------------------

# the error of a run whose worker process died under it; --resume runs such a run again
WORKER_DIED = "worker died"


def batches(tasks: list[Task], workers: int, most: int = 10) -> list[list[Task]]:
    """Batches for an executor with a cost per submission (Dask): enough to keep every worker
    busy to the end (8 a worker), at most ``most`` runs each (a batch's rows come back
    together: what a stop or a lost cluster can take with it)."""
    size = max(1, min(most, math.ceil(len(tasks) / (workers * 8))))
    return [tasks[i : i + size] for i in range(0, len(tasks), size)]


def _worker_death(exc: BaseException) -> str | None:
    """Why a submission's worker died (the local pool's ``WorkerDied``, Dask's
    ``KilledWorker``), else ``None``."""
    if isinstance(exc, WorkerDied):
        return str(exc)
    if type(exc).__name__ == "KilledWorker":
        return one_line(exc)
    return None


def _lost(pool: Pool, exc: BaseException, out_dir: Path) -> RgtbusError:
    where = (
        f"lost the Dask scheduler {pool.scheduler!r}"
        if pool.kind == "dask"
        else f"the {pool.kind} failed"
    )
    return BadInput(
        f"{where} ({one_line(exc)}); the finished runs are in "
        f"{str(out_dir / 'rows.jsonl')!r}: --resume (resume=True) to finish"
    )


def _rows_as_they_finish(
    sweep: Sweep, todo: list[Task], pool: Pool, log_dir: str | None, out_dir: Path
) -> Iterator[list[dict[str, Any]]]:
    """The rows of the runs as they finish. The local pool gets one run a submission (a stop
    loses no finished run; a dead worker costs only the run it ran), Dask small batches; at
    most two submissions a worker are out at once (a stop has little to cancel). A run whose
    worker died is its ``lost_row``. A pool that breaks before any run came back (its workers
    could not start) falls back to this process; one that breaks later, or a lost Dask
    scheduler, is an error of one line (the rows so far are kept: resume)."""
    if pool.executor is None:
        for t in todo:
            yield [run_row(sweep, t, log_dir)]
        return
    groups = collections.deque(
        batches(todo, pool.workers) if pool.kind == "dask" else [[t] for t in todo]
    )
    limit = max(4, 2 * pool.workers)
    pending: dict[Future[list[dict[str, Any]]], list[Task]] = {}
    got = 0
    reason = None
    try:
        while (groups or pending) and reason is None:
            while groups and len(pending) < limit:
                try:
                    fut = pool.executor.submit(run_batch, sweep, groups[0], log_dir)
                except (BrokenExecutor, OSError, RuntimeError) as exc:
                    if got:
                        raise _lost(pool, exc, out_dir) from None
                    reason = one_line(exc)
                    break
                pending[fut] = groups.popleft()
            if reason is not None:
                break
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in sorted(finished, key=lambda f: pending[f][0].index):
                batch = pending.pop(fut)
                try:
                    rows = fut.result()
                except BrokenExecutor as exc:
                    if got:
                        raise _lost(pool, exc, out_dir) from None
                    reason = one_line(exc)
                    groups.appendleft(batch)
                    continue
                except Exception as exc:  # run_row catches what a run raises: this is not one
                    why = _worker_death(exc)
                    if why is None:
                        raise _lost(pool, exc, out_dir) from None
                    rows = [lost_row(sweep, t, why) for t in batch]
                got += 1
                yield rows
    except BaseException:  # Ctrl-C, a lost cluster: what is still out is not waited for
        for fut in pending:
            fut.cancel()
        raise
    if reason is None:
        return
    for fut in pending:
        fut.cancel()
    redo = sorted([*groups, *pending.values()], key=lambda b: b[0].index)
    pool.fall_back(reason, sum(len(b) for b in redo))
    for b in redo:
        for t in b:
            yield [run_row(sweep, t, log_dir)]


def _run(
    held: SweepStore,
    pool: Pool,
    *,
    logs: bool = False,
    progress: Callable[[int, int, int], None] | None = None,
) -> list[dict[str, Any]]:
    """Run what ``held`` lacks on ``pool``, each row appended to rows.jsonl (and flushed) as it
    comes; write the tables; their rows in task order."""
    sweep, out_dir, tasks, have = held.sweep, held.out_dir, held.tasks, held.have
    write_versions(sweep, out_dir, pool)
    log_dir = None
    if logs:
        log_dir = str(out_dir / "logs")
        try:
            os.makedirs(log_dir, exist_ok=True)
        except OSError as exc:
            raise IOFailure(f"cannot write {log_dir!r}: {exc.strerror}") from None
    failures = sum(1 for r in have.values() if r.get("failed"))
    if progress:
        progress(len(have), len(tasks), failures)
    keys = {t.index: t.key for t in held.todo}
    rows_path = out_dir / ROWS
    try:
        sink = open(rows_path, "a", encoding="utf-8")  # noqa: SIM115 (closed below)
    except OSError as exc:
        raise IOFailure(f"cannot write {str(rows_path)!r}: {exc.strerror}") from None
    with sink:
        for batch_rows in _rows_as_they_finish(sweep, held.todo, pool, log_dir, out_dir):
            lines = []
            for row in batch_rows:
                key = keys[row["run"]]
                have[key] = row
                failures += bool(row.get("failed"))
                lines.append(sealed_line({**row, "_key": key}, sweep.digest, held.key))
            try:
                sink.write("".join(lines))
                sink.flush()
            except OSError as exc:
                raise IOFailure(
                    f"cannot write {str(rows_path)!r} ({exc.strerror}): the rows before are "
                    "kept: --resume (resume=True) to finish"
                ) from None
            if progress:
                progress(len(have), len(tasks), failures)
    if pool.fallback:
        write_versions(sweep, out_dir, pool)
    rows = [have[t.key] for t in tasks]
    try:
        return write_tables(sweep.axes, rows, out_dir, sweep.id)
    except OSError as exc:
        raise IOFailure(
            f"cannot write the tables in {str(out_dir)!r} ({exc.strerror}): every row is in "
            f"{str(rows_path)!r}: --resume (resume=True) writes them"
        ) from None


def run_sweep(
    sweep: Sweep,
    out_dir: Path,
    *,
    executor: Executor | None = None,
    workers: int = 1,
    resume: bool = False,
    logs: bool = False,
    progress: Callable[[int, int, int], None] | None = None,
    pool: Pool | None = None,
) -> SweepRows:
    """Run every task not yet in ``out_dir`` on ``executor`` (``None``: in this process) or
    ``pool``; write the tables and return the results table's rows in task order (plain
    values: ``results_rows``). ``progress(done, total, failures)`` after every batch (every run
    on the local pool)."""
    with SweepStore(sweep, Path(out_dir), resume) as held:
        rows = _run(held, pool or pool_of(executor, workers), logs=logs, progress=progress)
        return SweepRows(rows, held.notes)


def execute_sweep(
    sweep: Sweep,
    out_dir: str | os.PathLike[str],
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    logs: bool = False,
    progress: bool | Callable[[int, int, int], None] = False,
) -> SweepRows:
    """Run ``sweep`` into ``out_dir`` on the pool ``open_pool`` gives (what ``rgtbus sweep``
    and ``sweep()`` both do); ``progress``: a tqdm bar on stderr, or a callback
    ``(done, total, failures)``. Returns the results' rows and what the sweep had to say
    (``SweepRows.notes``).

    The directory is checked and locked before any worker starts. A ``KeyboardInterrupt``
    (Ctrl-C) stops the workers at once (none is left behind) and propagates; every run that
    finished is in rows.jsonl, and ``resume=True`` runs the rest."""
    if workers is not None and (isinstance(workers, bool) or workers < 1):
        raise BadInput(f"workers must be at least 1, got {workers}")
    bar = None
    callback = progress if callable(progress) else None
    if progress is True:
        from tqdm import tqdm

        bar = tqdm(total=sweep.runs, unit="run", desc=sweep.name, file=sys.stderr)

        def callback(done: int, total: int, failures: int) -> None:
            assert bar is not None
            bar.n = done
            bar.set_postfix(failures=failures, refresh=False)
            bar.refresh()

    try:
        with (
            SweepStore(sweep, Path(out_dir), resume) as held,
            open_pool(workers, scheduler, runs=max(1, len(held.todo))) as pool,
        ):
            return SweepRows(_run(held, pool, logs=logs, progress=callback), held.notes)
    finally:
        if bar is not None:
            bar.close()


def sweep(
    scenario_or_path: Scenario | str | os.PathLike[str],
    *,
    grid: Mapping[str, Sequence[Any]],
    seeds: int | Sequence[int],
    workers: int | None = None,
    out: str | os.PathLike[str] | None = None,
    scheduler: str | None = None,
    cases: Mapping[str, Mapping[str, Any]] | None = None,
    progress: bool = False,
    resume: bool = False,
    logs: bool = False,
    name: str | None = None,
) -> pd.DataFrame:
    """Run a scenario over seeds and a grid of keys; the results table ``rgtbus sweep`` writes.

    ``scenario_or_path``: a ``Scenario``, or what ``rgtbus.scenario.load_scenario`` reads.
    ``grid``: key -> values, crossed (every combination, in order): ``n`` (a group of n units
    u1..un), ``engine`` (``"event"``/``"dense"``), any dotted scenario key
    (``"relations.p"``, ``"channel.noise"``); ``cases``: name -> {key: value}, crossed with the
    grid as one more key, ``case``. ``seeds``: ``N`` for seeds 0..N-1, or a list of seeds.
    Each (cell, seed) is one run: the base scenario with the cell's keys and the seed set.

    Runs go to ``workers`` local processes (all cores by default; one: this process), or the
    Dask cluster at ``scheduler``. Workers never import the caller's ``__main__``, so this
    works from a plain script or notebook cell without an ``if __name__ == "__main__"`` guard.

    Returns one row per run (in grid-then-seed order), the results read so that pandas
    can group, sort, deduplicate and merge on every column (``frame_of``: ``relations`` a
    ``Record`` dict, ``units`` a tuple of them, lists as tuples; docs/sweeps.md).
    Equation-free: the table holds what the simulated units did (their intervals, choices,
    decode errors) and judgements against the noise-free forward task; it computes no RGT of
    its own. ``out=None`` keeps nothing on disk; a directory keeps what
    ``rgtbus sweep --out DIR`` writes there (``read_sweep(out)`` gives results and
    decisions, one row per run, unit and round); ``resume=True`` finishes one stopped
    halfway; ``logs=True`` an MCAP log per run (needs ``out``). A run that raises is a row with
    ``failed`` and its ``error``, never the end of the sweep. ``KeyboardInterrupt`` (Ctrl-C)
    stops the workers at once and propagates; the finished runs are kept in ``out`` for
    ``resume=True``. Faults (a bad ``out`` or ``scheduler``, ``out`` in use by another sweep, a
    tampered rows.jsonl, a lost scheduler) raise ``RgtbusError``, one line (docs/sweeps.md).
    What the sweep had to say (a line of rows.jsonl cut by a kill, its run run again) is in
    ``frame.attrs["notes"]``, one line each; nothing is printed.

    >>> df = sweep("scenarios/random_group.toml", grid={"n": [3, 4], "relations.p": [0.3, 0.9]},
    ...            seeds=20)                                              # doctest: +SKIP
    >>> df.groupby(["n", "relations.p"])["decomposable"].mean()           # doctest: +SKIP
    """

    sw = make_sweep(scenario_or_path, grid=grid, seeds=seeds, cases=cases, name=name)
    kw: dict[str, Any] = {
        "workers": workers,
        "scheduler": scheduler,
        "resume": resume,
        "logs": logs,
        "progress": progress,
    }
    if out is None:
        if logs:
            raise BadInput("sweep: logs=True needs out= (a directory to keep them in)")
        with tempfile.TemporaryDirectory(prefix="rgtbus-sweep-") as tmp:
            execute_sweep(sw, tmp, **kw)
            return read_results(tmp)
    notes = execute_sweep(sw, out, **kw).notes
    frame = read_results(out)
    frame.attrs["notes"] = notes  # what it had to say (a line cut by a kill, run again)
    return frame


def decisions(out: str | os.PathLike[str]) -> pd.DataFrame:
    """The decisions of the sweep written to ``out``: ``read_sweep(out).decisions``."""
    return read_sweep(out).decisions
