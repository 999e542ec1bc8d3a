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
import copy
import hashlib
import itertools
import json
import math
import numbers
import os
import platform
import re
import sys
import tempfile
import tomllib
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import BrokenExecutor, Executor, Future, wait
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import tomli_w
from rgtbus.units.workers import Pool, one_line, open_executor, open_pool, pool_of

from rgtbus import __version__
from rgtbus.errors import RgtbusError
from rgtbus.scenario import MAX_SCENARIO_BYTES, Scenario, parse_scenario
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

SWEEP_KEYS = {"name", "description", "scenario", "seeds", "grid", "cases"}
ENGINES = ("event", "dense")
MAX_RUNS = 1_000_000
# the version of the tables a sweep directory holds (sweep.json "tables"): 2 is native Arrow
# types and decisions.parquet; 1 (no key) held nested columns as JSON text
TABLES_VERSION = 2
# summary fields that are no column of the results: the run's own (its grid cell says them),
# and the decisions (decisions.parquet)

ErrorAt = Callable[[str | None, str], RgtbusError]  # (key or None, reason) -> the error to raise


@dataclass(frozen=True)
class Task:
    """One run: its place in the sweep, grid cell and seed."""

    index: int
    cell: tuple[tuple[str, Any], ...]
    seed: int

    @property
    def key(self) -> str:
        """Identifies the run across a resume (cell and seed, not its position)."""
        return json.dumps([list(self.cell), self.seed], sort_keys=False)


@dataclass(frozen=True)
class Sweep:
    path: str
    text: str
    name: str
    scenario_path: str
    scenario_text: str
    seeds: tuple[int, ...]
    grid: tuple[tuple[str, tuple[Any, ...]], ...]  # key -> values, in file order
    # case name -> its keys; crossed with the grid as one more key, "case", before the others
    cases: tuple[tuple[str, tuple[tuple[str, Any], ...]], ...] = ()

    @property
    def axes(self) -> list[tuple[str, tuple[Any, ...]]]:
        """The grid's keys and values, ``case`` first when there are cases."""
        head = [("case", tuple(name for name, _ in self.cases))] if self.cases else []
        return head + list(self.grid)

    @property
    def keys(self) -> list[str]:
        return [k for k, _ in self.axes]

    def case(self, name: str) -> tuple[tuple[str, Any], ...]:
        return dict(self.cases)[name]

    def cells(self) -> list[tuple[tuple[str, Any], ...]]:
        values = [vs for _, vs in self.axes]
        return [tuple(zip(self.keys, combo, strict=True)) for combo in itertools.product(*values)]

    def tasks(self) -> list[Task]:
        out: list[Task] = []
        for cell in self.cells():
            for seed in self.seeds:
                out.append(Task(len(out), cell, seed))
        return out

    @property
    def runs(self) -> int:
        return math.prod(len(vs) for _, vs in self.axes) * len(self.seeds)

    @property
    def digest(self) -> str:
        return hashlib.sha256((self.text + "\0" + self.scenario_text).encode()).hexdigest()[:16]


# -- reading a sweep file ----------------------------------------------------------------------


def _line_of(text: str, key: str) -> int | None:
    pattern = re.compile(r'\s*"?' + re.escape(key) + r'"?\s*=')
    for i, line in enumerate(text.splitlines(), 1):
        if pattern.match(line):
            return i
    return None


def _error(path: str, text: str, key: str | None, reason: str) -> RgtbusError:
    line = _line_of(text, key) if key else None
    if line is None and key and "." in key:  # [grid.relations] p = ..., or an inline table
        line = _line_of(text, key.rpartition(".")[2])
    where = f"{path}:{line}" if line else path
    return RgtbusError(f"{where}: {key or 'sweep'}: {reason}")


def parse_seeds(value: Any) -> tuple[int, ...]:
    """``"a..b"`` (inclusive), one integer, or a list of distinct integers >= 0."""
    if isinstance(value, str):
        m = re.fullmatch(r"\s*(\d+)\s*\.\.\s*(\d+)\s*", value)
        if not m:
            raise ValueError(f'must be "FIRST..LAST" (e.g. "0..999"), got {value!r}')
        a, b = int(m.group(1)), int(m.group(2))
        if b < a:
            raise ValueError(f"empty range {value!r} (LAST < FIRST)")
        if b - a + 1 > MAX_RUNS:
            raise ValueError(f"{value!r} is more than {MAX_RUNS} seeds")
        return tuple(range(a, b + 1))
    if isinstance(value, int) and not isinstance(value, bool):
        value = [value]
    if not isinstance(value, list) or not value:
        raise ValueError(f'must be "FIRST..LAST" or a non-empty list of integers, got {value!r}')
    for s in value:
        if not isinstance(s, int) or isinstance(s, bool) or s < 0:
            raise ValueError(f"a seed must be an integer >= 0, got {s!r}")
    if len(set(value)) != len(value):
        raise ValueError("seeds repeat")
    return tuple(value)


def load_sweep(path: str | os.PathLike[str]) -> Sweep:
    """Read and check a sweep file: every grid cell must make a valid scenario (errors name the
    sweep file, its line and key)."""
    p = Path(path)
    where = str(p)
    data_bytes = _read_capped(p, "sweep")
    try:
        text = data_bytes.decode("utf-8")
        data = tomllib.loads(text)
    except UnicodeDecodeError:
        raise RgtbusError(f"{where}: not a UTF-8 text file") from None
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"\(at line (\d+), column \d+\)", str(exc))
        raise RgtbusError(f"{where}:{m.group(1) if m else '?'}: not valid TOML: {exc}") from None

    def err(key: str | None, reason: str) -> RgtbusError:
        return _error(where, text, key, reason)

    for key in data:
        if key not in SWEEP_KEYS:
            allowed = ", ".join(sorted(SWEEP_KEYS))
            raise err(key, f"unknown key (allowed: {allowed})")
    name = data.get("name", p.stem)
    if not isinstance(name, str) or not name:
        raise err("name", f"must be a non-empty string, got {name!r}")
    scen = data.get("scenario")
    if not isinstance(scen, str) or not scen:
        raise err("scenario", "must name the base scenario file")
    scen_path = (p.parent / scen).resolve() if not Path(scen).is_absolute() else Path(scen)
    try:
        scen_text = _read_capped(scen_path, "scenario").decode("utf-8")
    except UnicodeDecodeError:
        raise err("scenario", f"{str(scen_path)!r}: not UTF-8 text") from None
    except RgtbusError as exc:
        raise err("scenario", str(exc)) from None
    try:
        seeds = parse_seeds(data.get("seeds", "0..0"))
    except ValueError as exc:
        raise err("seeds", str(exc)) from None
    grid_table = data.get("grid", {})
    if not isinstance(grid_table, dict):
        raise err("grid", "must be a table of key = [values]")
    cases_table = data.get("cases", {})
    if not isinstance(cases_table, dict):
        raise err("cases", "must be a table of name = { key = value, ... }")
    grid, cases = _axes(list(_flatten(grid_table)), list(cases_table.items()), err)
    sweep = Sweep(where, text, name, str(scen_path), scen_text, seeds, grid, cases)
    check_sweep(sweep, err)
    return sweep


def _axes(
    grid_items: list[tuple[str, Any]], case_items: list[tuple[str, Any]], err: ErrorAt
) -> tuple[
    tuple[tuple[str, tuple[Any, ...]], ...], tuple[tuple[str, tuple[tuple[str, Any], ...]], ...]
]:
    """The grid and the cases of a sweep, checked key by key (not yet against the scenario)."""
    grid = []
    for key, values in grid_items:
        if not isinstance(values, list) or not values:
            raise err(key, f"must be a non-empty list of values, got {values!r}")
        if key == "seed":
            raise err(key, "the seeds of a sweep are its seeds key, not a grid key")
        if key == "case":
            raise err(key, "'case' names the [cases] of a sweep, not a grid key")
        if key == "engine":
            for v in values:
                if v not in ENGINES:
                    raise err(key, f"unknown engine {v!r} (event or dense)")
        grid.append((key, tuple(values)))
    cases = []
    for case, settings in case_items:
        if not isinstance(settings, dict) or not settings:
            raise err(case, f"a case must be a non-empty table of keys, got {settings!r}")
        keys = list(_flatten(settings))
        for key, value in keys:
            if key in ("seed", "case", "n") or key in dict(grid):
                reason = "set by the grid" if key in dict(grid) else "not a case key"
                raise err(case, f"{key!r}: {reason}")
            if key == "engine" and value not in ENGINES:
                raise err(case, f"unknown engine {value!r} (event or dense)")
        cases.append((case, tuple(keys)))
    return tuple(grid), tuple(cases)


def check_sweep(sweep: Sweep, err: ErrorAt) -> None:
    """Every case, grid value and cell of ``sweep`` makes a valid scenario, checked before any
    run: each case and value alone first (the error names its key), then every cell."""
    runs = sweep.runs
    if runs > MAX_RUNS:
        raise err("grid", f"{runs} runs: more than {MAX_RUNS}")
    try:  # the base scenario as written: its own errors name its own lines
        parse_scenario(sweep.scenario_text, sweep.scenario_path)
    except RgtbusError as exc:
        raise err("scenario", str(exc)) from None
    base = tomllib.loads(sweep.scenario_text)
    seed = sweep.seeds[0]
    for case, _ in sweep.cases:
        try:
            scenario_for(sweep, (("case", case),), seed, base)
        except RgtbusError as exc:
            raise err(case, str(exc)) from None
    for key, values in sweep.grid:
        for value in values:
            try:
                scenario_for(sweep, ((key, value),), seed, base)
            except RgtbusError as exc:
                raise err(key, f"value {value!r}: {exc}") from None
    for cell in sweep.cells():
        try:
            scenario_for(sweep, cell, seed, base)
        except RgtbusError as exc:
            raise err("grid", f"cell {dict(cell)}: {exc}") from None


def _read_capped(path: Path, what: str) -> bytes:
    """A sweep or scenario file's bytes; one line if it cannot be read or is far too large."""
    try:
        if path.is_dir():
            raise RgtbusError(f"cannot read {what} {str(path)!r}: is a directory")
        with open(path, "rb") as f:
            data = f.read(MAX_SCENARIO_BYTES + 1)
    except OSError as exc:
        raise RgtbusError(f"cannot read {what} {str(path)!r}: {exc.strerror}") from None
    if len(data) > MAX_SCENARIO_BYTES:
        raise RgtbusError(
            f"{str(path)!r}: larger than {MAX_SCENARIO_BYTES >> 20} MiB: not a {what}"
        )
    return data


def _flatten(table: Mapping[str, Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    """``[grid]`` keys, dotted (``relations.p = [...]`` and ``"relations.p" = [...]`` alike)."""
    for k, v in table.items():
        if isinstance(v, Mapping):
            yield from _flatten(v, f"{prefix}{k}.")
        else:
            yield f"{prefix}{k}", v


# -- a sweep from arguments (the library) ------------------------------------------------------


def _plain(value: Any) -> Any:
    """A grid value as a TOML value: numpy scalars and arrays as Python ones, tuples as lists."""
    if type(value).__module__ == "numpy" and hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    return value


def _seeds_arg(seeds: int | Sequence[int] | str) -> tuple[int, ...]:
    """``seeds=N``: seeds 0..N-1; a sequence: those seeds; ``"a..b"``: as in a sweep file."""
    if isinstance(seeds, bool):
        raise RgtbusError(f"sweep seeds: an integer N (seeds 0..N-1) or a list, got {seeds!r}")
    if isinstance(seeds, numbers.Integral):
        n = int(seeds)
        if not 1 <= n <= MAX_RUNS:
            raise RgtbusError(f"sweep seeds: N must be 1..{MAX_RUNS} (seeds 0..N-1), got {n}")
        return tuple(range(n))
    try:
        if isinstance(seeds, str):
            return parse_seeds(seeds)
        if isinstance(seeds, int):  # not reached (an Integral above); for the type checker
            raise TypeError(seeds)
        return parse_seeds(_plain(list(seeds)))
    except (TypeError, ValueError) as exc:
        raise RgtbusError(f"sweep seeds: {exc}") from None


def _seeds_text(seeds: tuple[int, ...]) -> str | list[int]:
    first, last = seeds[0], seeds[-1]
    return f"{first}..{last}" if seeds == tuple(range(first, last + 1)) else list(seeds)


def make_sweep(
    scenario: Scenario | str | os.PathLike[str],
    *,
    grid: Mapping[str, Any],
    seeds: int | Sequence[int] | str,
    cases: Mapping[str, Mapping[str, Any]] | None = None,
    name: str | None = None,
) -> Sweep:
    """A checked ``Sweep`` from arguments: what ``load_sweep`` gives for the equivalent sweep
    file (its text is that file, stored as ``sweep.toml`` beside the results, with
    ``scenario = "scenario.toml"``: the copy beside it, so the directory re-runs as is)."""
    from rgtbus.scenario import load_scenario

    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    if not isinstance(grid, Mapping):
        raise RgtbusError(f"sweep grid: a mapping of key -> [values], got {type(grid).__name__}")
    if cases is not None and not isinstance(cases, Mapping):
        raise RgtbusError(f"sweep cases: a mapping of name -> {{key: value}}, got {cases!r}")

    def err(key: str | None, reason: str) -> RgtbusError:
        return RgtbusError(f"sweep: {key}: {reason}" if key else f"sweep: {reason}")

    items = []
    for key, values in _flatten(grid):
        try:
            if isinstance(values, str | bytes):
                raise TypeError
            listed = list(values)
        except TypeError:
            raise err(key, f"must be a non-empty list of values, got {values!r}") from None
        items.append((key, _plain(listed)))
    case_items = [(str(k), _plain(v)) for k, v in (cases or {}).items()]
    grid_t, cases_t = _axes(items, case_items, err)
    seeds_t = _seeds_arg(seeds)
    sweep_name = name or sc.name
    doc: dict[str, Any] = {"name": sweep_name, "scenario": "scenario.toml"}
    doc["seeds"] = _seeds_text(seeds_t)
    if cases_t:
        doc["cases"] = {c: dict(kv) for c, kv in cases_t}
    doc["grid"] = {k: list(vs) for k, vs in grid_t}
    try:
        text = tomli_w.dumps(doc)
    except TypeError as exc:
        raise RgtbusError(f"sweep grid: a value TOML cannot hold: {exc}") from None
    sw = Sweep(f"sweep({sc.path})", text, sweep_name, sc.path, sc.text, seeds_t, grid_t, cases_t)
    check_sweep(sw, err)
    return sw


# -- one run -----------------------------------------------------------------------------------


def scenario_for(
    sweep: Sweep,
    cell: tuple[tuple[str, Any], ...],
    seed: int,
    base: dict[str, Any] | None = None,
) -> Scenario:
    """The base scenario with a cell's keys set and the seed: parsed from its TOML text, so the
    run's log stores a scenario that re-runs as is."""
    data = tomllib.loads(sweep.scenario_text) if base is None else copy.deepcopy(base)
    settings_of = [(k, v) for key, value in cell for k, v in _expand(sweep, key, value)]
    for key, value in settings_of:
        if key == "engine":
            continue
        if key == "n":  # a group of n units u1..un (the scenario's own names replaced)
            if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= 200:
                raise RgtbusError(f"n: a group size must be an integer 1..200, got {value!r}")
            _set(data, "units", [f"u{i}" for i in range(1, value + 1)])
            continue
        _set(data, key, value)
    data["seed"] = seed
    settings = [f"{k}={v!r}" for k, v in cell] + [f"seed {seed}"]
    label = f"{sweep.scenario_path} [{'; '.join(settings)}]"
    try:
        text = tomli_w.dumps(data)
    except TypeError as exc:  # a value TOML cannot hold (None, an object)
        raise RgtbusError(f"not a TOML value: {exc}") from None
    return parse_scenario(text, label)


def _set(data: dict[str, Any], key: str, value: Any) -> None:
    parts = key.split(".")
    node = data
    for part in parts[:-1]:
        nxt = node.setdefault(part, {})
        if not isinstance(nxt, dict):
            raise RgtbusError(f"{key}: {part!r} is not a table in the scenario")
        node = nxt
    node[parts[-1]] = value


def _expand(sweep: Sweep, key: str, value: Any) -> tuple[tuple[str, Any], ...]:
    """A cell's key as the settings it stands for (a case: its keys)."""
    return sweep.case(value) if key == "case" else ((key, value),)


def engine_of(sweep: Sweep, cell: tuple[tuple[str, Any], ...]) -> str:
    settings = dict(kv for key, value in cell for kv in _expand(sweep, key, value))
    return str(settings.get("engine", "event"))


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
