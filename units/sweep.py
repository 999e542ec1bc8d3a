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
handed out in batches to any ``concurrent.futures.Executor``: a local process pool by default,
or a Dask distributed cluster's (``Client(address).get_executor()``), the same code path; one
worker runs them in this process. Rows are appended to ``rows.jsonl`` as they arrive, so a
sweep stopped halfway resumes with only what is missing; the tables are written as
``results.parquet`` (one row per run, native Arrow types: ``RESULTS_SCHEMA``),
``results.csv`` (the same, nested columns as JSON text) and ``decisions.parquet`` (one row per
run, unit and influence round).

The local pool never imports the caller's ``__main__`` in its workers (``_NoMainSpawnContext``):
the task function lives here, so a script or notebook cell without an
``if __name__ == "__main__"`` guard can run a sweep on many processes.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import platform
import sys
import tempfile
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import BrokenExecutor, Executor, Future, wait
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rgtbus.units.sweep_spec import (
    TABLES_VERSION,
    Sweep,
    Task,
    engine_of,
    load_sweep,
    make_sweep,
    scenario_for,
)
from rgtbus.units.workers import Pool, one_line, open_executor, open_pool, pool_of

from rgtbus import __version__
from rgtbus.errors import RgtbusError
from rgtbus.scenario import Scenario
from rgtbus.summary import summary_json
from rgtbus.telemetry.sweep_tables import (
    NOT_COLUMNS,
    SweepTables,
    decisions_table,
    read_sweep,
    results_table,
    table_rows,
    write_tables,
)

__all__ = [
    "Sweep",
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

# -- one run -----------------------------------------------------------------------------------


def run_row(sweep: Sweep, task: Task, log_dir: str | None = None) -> dict[str, Any]:
    """One run as one row of the results table, its fields as the run summary states them
    (``table_row`` shapes it for the table); the run's decisions under ``"_decisions"``. A run
    that raises is a row with its error."""
    from rgtbus.units.group import run_group

    from rgtbus.telemetry import McapRecorder, NullRecorder

    row: dict[str, Any] = {"run": task.index}
    for key, value in task.cell:
        row[key] = json.dumps(value) if isinstance(value, list | dict) else value
    row["seed"] = task.seed
    engine = engine_of(sweep, task.cell)
    row["engine"] = engine
    log_path = None
    try:
        sc = scenario_for(sweep, task.cell, task.seed)
        row["digest"] = hashlib.sha256(sc.text.encode()).hexdigest()[:16]
        row["schedule"] = sc.schedule
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
        row["decode_error_count"] = len(s["decode_errors"])
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
        row["decode_error_rate"] = len(s["decode_errors"]) / decodes if decodes else None
        row["failed"] = s["error"] is not None
    except Exception as exc:  # a run that raises is a result of the sweep, never its end
        last = traceback.extract_tb(exc.__traceback__)[-1:] or None
        at = f" (at {Path(last[0].filename).name}:{last[0].lineno})" if last else ""
        msg = str(exc) if isinstance(exc, RgtbusError) else f"{type(exc).__name__}: {exc}{at}"
        row["error"] = msg
        row["failed"] = True
    row["log"] = log_path
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


# -- runs in batches --------------------------------------------------------------------------


def batches(tasks: list[Task], workers: int) -> list[list[Task]]:
    """Enough batches to keep every worker busy to the end (8 a worker), at most 50 runs each."""
    size = max(1, min(50, math.ceil(len(tasks) / (workers * 8))))
    return [tasks[i : i + size] for i in range(0, len(tasks), size)]


def _batch_results(
    sweep: Sweep, todo: list[Task], pool: Pool, log_dir: str | None, out_dir: Path
) -> Iterator[list[dict[str, Any]]]:
    """The rows of each batch as it finishes. A pool that breaks before any batch came back
    (its workers could not start) falls back to this process; one that breaks later is an
    error of one line (the rows so far are kept: resume)."""
    groups = batches(todo, pool.workers)
    redo: list[list[Task]] = []
    reason = None
    if pool.executor is not None:
        pending: dict[Future, list[Task]] = {}
        got = 0
        try:
            for b in groups:
                pending[pool.executor.submit(run_batch, sweep, b, log_dir)] = b
        except (BrokenExecutor, OSError, RuntimeError) as exc:
            for fut in pending:
                fut.cancel()
            reason, redo, pending = one_line(exc), groups, {}
        while pending:
            finished, _ = wait(pending, return_when="FIRST_COMPLETED")
            broken = None
            for fut in finished:
                batch = pending.pop(fut)
                try:
                    rows = fut.result()
                except BrokenExecutor as exc:
                    broken = exc
                    redo.append(batch)
                    continue
                got += 1
                yield rows
            if broken is not None:
                if got:
                    raise RgtbusError(
                        f"a worker process died ({one_line(broken)}); the runs "
                        f"so far are in {str(out_dir / 'rows.jsonl')!r}: resume to finish"
                    ) from None
                for fut in pending:
                    fut.cancel()
                reason = one_line(broken)
                redo += list(pending.values())
                pending = {}
        if reason is None:
            return
        pool.fall_back(reason, sum(len(b) for b in redo))
        groups = redo
    for b in groups:
        yield run_batch(sweep, b, log_dir)


# -- the whole sweep ---------------------------------------------------------------------------


def read_rows(out_dir: Path) -> list[dict[str, Any]]:
    """The rows a sweep has written so far (a line cut by a kill is dropped)."""
    path = out_dir / "rows.jsonl"
    if not path.exists():
        return []
    rows = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            with contextlib.suppress(json.JSONDecodeError):
                rows.append(json.loads(line))
    return rows


def prepare_out(
    sweep: Sweep, out_dir: Path, resume: bool, pool: Pool | None = None
) -> list[dict[str, Any]]:
    """Create ``out_dir`` with the sweep file and versions beside it; on resume, the rows
    already there (they must be of this sweep, and fit its tables)."""
    rows_path = out_dir / "rows.jsonl"
    stored = out_dir / "sweep.json"
    if rows_path.exists() and not resume:
        raise RgtbusError(
            f"{str(out_dir)!r} holds results already: --resume (resume=True) to finish that "
            "sweep, or choose another --out"
        )
    if out_dir.exists() and not out_dir.is_dir():
        raise RgtbusError(f"{str(out_dir)!r}: not a directory")
    rows: list[dict[str, Any]] = []
    if resume and stored.exists():
        try:
            before = json.loads(stored.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise RgtbusError(
                f"{str(out_dir)!r}: cannot resume: sweep.json unreadable: {exc}"
            ) from None
        if before.get("digest") != sweep.digest:
            raise RgtbusError(
                f"{str(out_dir)!r} holds results of another sweep (digest "
                f"{before.get('digest')}, this one {sweep.digest}): cannot resume it with "
                f"{sweep.path!r}"
            )
        if before.get("tables", 1) > TABLES_VERSION:
            raise RgtbusError(
                f"{str(out_dir)!r}: cannot resume: its tables are of a newer rgtbus (version "
                f"{before.get('tables')}, this one writes {TABLES_VERSION})"
            )
    if resume:
        rows = read_rows(out_dir)
        try:  # rows of an older rgtbus (JSON text columns) are re-tabled, or refused here
            results_table(sweep.axes, rows)
            decisions_table(sweep.axes, rows)
        except Exception as exc:
            raise RgtbusError(
                f"{str(out_dir)!r}: cannot resume: its rows.jsonl does not fit this rgtbus's "
                f"tables ({one_line(exc)}); "
                "run the sweep into another directory"
            ) from None
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "sweep.toml").write_text(sweep.text, encoding="utf-8")
    (out_dir / "scenario.toml").write_text(sweep.scenario_text, encoding="utf-8")
    _write_versions(sweep, out_dir, pool)
    return rows


def _write_versions(sweep: Sweep, out_dir: Path, pool: Pool | None) -> None:
    record = versions(sweep)
    if pool is not None:
        record.update(pool.record())
    (out_dir / "sweep.json").write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")


def versions(sweep: Sweep) -> dict[str, Any]:
    from importlib.metadata import version

    libs = {}
    for lib in ("numpy", "simpy", "mcap", "foxglove-sdk", "distributed", "pyarrow", "tqdm"):
        with contextlib.suppress(Exception):
            libs[lib] = version(lib)
    return {
        "sweep": sweep.path,
        "name": sweep.name,
        "scenario": sweep.scenario_path,
        "digest": sweep.digest,
        "runs": sweep.runs,
        "tables": TABLES_VERSION,
        "rgtbus": __version__,
        "python": platform.python_version(),
        "libraries": libs,
    }


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
) -> list[dict[str, Any]]:
    """Run every task not yet in ``out_dir`` on ``executor`` (``None``: in this process) or
    ``pool``; write the tables and return the results table's rows in task order (plain
    values: ``table_rows``). ``progress(done, total, failures)`` after every batch."""
    out_dir = Path(out_dir)
    pool = pool or pool_of(executor, workers)
    done_rows = prepare_out(sweep, out_dir, resume, pool)
    tasks = sweep.tasks()
    by_key = {t.key: t for t in tasks}
    have = {}
    for r in done_rows:
        key = r.pop("_key", None)
        if key in by_key:
            r["run"] = by_key[key].index  # the run's place in this sweep
            have[key] = r
    todo = [t for t in tasks if t.key not in have]
    log_dir = None
    if logs:
        log_dir = str(out_dir / "logs")
        os.makedirs(log_dir, exist_ok=True)
    failures = sum(1 for r in have.values() if r.get("failed"))
    if progress:
        progress(len(have), len(tasks), failures)
    keys = {t.index: t.key for t in todo}
    with open(out_dir / "rows.jsonl", "a", encoding="utf-8") as sink:
        for batch_rows in _batch_results(sweep, todo, pool, log_dir, out_dir):
            for row in batch_rows:
                key = keys[row["run"]]
                have[key] = row
                failures += bool(row.get("failed"))
                sink.write(json.dumps({**row, "_key": key}) + "\n")
            sink.flush()
            if progress:
                progress(len(have), len(tasks), failures)
    if pool.fallback:
        _write_versions(sweep, out_dir, pool)
    rows = [have[t.key] for t in tasks]
    return table_rows(write_tables(sweep.axes, rows, out_dir))


def execute_sweep(
    sweep: Sweep,
    out_dir: str | os.PathLike[str],
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    logs: bool = False,
    progress: bool | Callable[[int, int, int], None] = False,
) -> list[dict[str, Any]]:
    """Run ``sweep`` into ``out_dir`` on the pool ``open_pool`` gives (what ``rgtbus sweep``
    and ``sweep()`` both do); ``progress``: a tqdm bar on stderr, or a callback
    ``(done, total, failures)``. Returns the results' rows."""
    if workers is not None and (isinstance(workers, bool) or workers < 1):
        raise RgtbusError(f"workers must be at least 1, got {workers}")
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
        with open_pool(workers, scheduler, runs=sweep.runs) as pool:
            return run_sweep(
                sweep,
                Path(out_dir),
                executor=pool.executor,
                workers=pool.workers,
                resume=resume,
                logs=logs,
                progress=callback,
                pool=pool,
            )
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

    Returns one row per run (in grid-then-seed order), as ``pd.read_parquet`` reads
    ``results.parquet``: native types (``relations`` a map, ``units`` a list of structs, ...;
    docs/sweeps.md). Equation-free: the table holds what the simulated units did (their
    intervals, choices, decode errors) and judgements against the noise-free forward task; it
    computes no RGT of its own. ``out=None`` keeps nothing on disk; a directory keeps what
    ``rgtbus sweep --out DIR`` writes there (``read_sweep(out)`` gives results and
    decisions, one row per run, unit and round); ``resume=True`` finishes one stopped
    halfway; ``logs=True`` an MCAP log per run (needs ``out``). A run that raises is a row with
    ``failed`` and its ``error``, never the end of the sweep.

    >>> df = sweep("scenarios/random_group.toml", grid={"n": [3, 4], "relations.p": [0.3, 0.9]},
    ...            seeds=20)                                              # doctest: +SKIP
    >>> df.groupby(["n", "relations.p"])["decomposable"].mean()           # doctest: +SKIP
    """
    import pandas as pd

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
            raise RgtbusError("sweep: logs=True needs out= (a directory to keep them in)")
        with tempfile.TemporaryDirectory(prefix="rgtbus-sweep-") as tmp:
            execute_sweep(sw, tmp, **kw)
            return pd.read_parquet(Path(tmp) / "results.parquet")
    execute_sweep(sw, out, **kw)
    return pd.read_parquet(Path(out) / "results.parquet")


def decisions(out: str | os.PathLike[str]) -> pd.DataFrame:
    """decisions.parquet of the sweep written to ``out``: ``read_sweep(out).decisions``."""
    return read_sweep(out).decisions
