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

Every (grid cell, seed) is one run on the memory bus (the same results as zenoh, docs/engine.md)
in a worker process; each run gives one row of the results table (``run_row``). Runs are
handed out in batches to any ``concurrent.futures.Executor``: a local process pool by default,
or a Dask distributed cluster's (``Client(address).get_executor()``), the same code path.
Rows are appended to ``rows.jsonl`` as they arrive, so a sweep stopped halfway resumes with
only what is missing; the table is written as ``results.parquet`` and ``results.csv``.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import itertools
import json
import math
import os
import platform
import re
import tomllib
import traceback
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomli_w

from rgtbus import __version__
from rgtbus.errors import RgtbusError
from rgtbus.scenario import MAX_SCENARIO_BYTES, Scenario, parse_scenario
from rgtbus.summary import summary_json

SWEEP_KEYS = {"name", "description", "scenario", "seeds", "grid", "cases"}
ENGINES = ("event", "dense")
MAX_RUNS = 1_000_000
# summary fields stored as JSON text (a nested value: one cell, any shape, in parquet and CSV)
JSON_COLUMNS = (
    "relations",
    "influences",
    "units",
    "decode_errors",
    "frustrated",
    "wrong_decisions",
    "p4",
    "goals",
    "rounds",
)


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
    for key in data:
        if key not in SWEEP_KEYS:
            allowed = ", ".join(sorted(SWEEP_KEYS))
            raise _error(where, text, key, f"unknown key (allowed: {allowed})")
    name = data.get("name", p.stem)
    if not isinstance(name, str) or not name:
        raise _error(where, text, "name", f"must be a non-empty string, got {name!r}")
    scen = data.get("scenario")
    if not isinstance(scen, str) or not scen:
        raise _error(where, text, "scenario", "must name the base scenario file")
    scen_path = (p.parent / scen).resolve() if not Path(scen).is_absolute() else Path(scen)
    try:
        scen_text = _read_capped(scen_path, "scenario").decode("utf-8")
    except UnicodeDecodeError:
        raise _error(where, text, "scenario", f"{str(scen_path)!r}: not UTF-8 text") from None
    except RgtbusError as exc:
        raise _error(where, text, "scenario", str(exc)) from None
    try:
        seeds = parse_seeds(data.get("seeds", "0..0"))
    except ValueError as exc:
        raise _error(where, text, "seeds", str(exc)) from None
    grid_table = data.get("grid", {})
    if not isinstance(grid_table, dict):
        raise _error(where, text, "grid", "must be a table of key = [values]")
    grid = []
    for key, values in _flatten(grid_table):
        if not isinstance(values, list) or not values:
            raise _error(where, text, key, f"must be a non-empty list of values, got {values!r}")
        if key == "seed":
            raise _error(where, text, key, "the seeds of a sweep are its seeds key, not a grid key")
        if key == "case":
            raise _error(where, text, key, "'case' names the [cases] of a sweep, not a grid key")
        if key == "engine":
            for v in values:
                if v not in ENGINES:
                    raise _error(where, text, key, f"unknown engine {v!r} (event or dense)")
        grid.append((key, tuple(values)))
    cases_table = data.get("cases", {})
    if not isinstance(cases_table, dict):
        raise _error(where, text, "cases", "must be a table of name = { key = value, ... }")
    cases = []
    for case, settings in cases_table.items():
        if not isinstance(settings, dict) or not settings:
            raise _error(
                where, text, case, f"a case must be a non-empty table of keys, got {settings!r}"
            )
        keys = list(_flatten(settings))
        for key, value in keys:
            if key in ("seed", "case", "n") or key in dict(grid):
                reason = "set by the grid" if key in dict(grid) else "not a case key"
                raise _error(where, text, case, f"{key!r}: {reason}")
            if key == "engine" and value not in ENGINES:
                raise _error(where, text, case, f"unknown engine {value!r} (event or dense)")
        cases.append((case, tuple(keys)))
    sweep = Sweep(where, text, name, str(scen_path), scen_text, seeds, tuple(grid), tuple(cases))
    runs = len(sweep.cells()) * len(seeds)
    if runs > MAX_RUNS:
        raise _error(where, text, "grid", f"{runs} runs: more than {MAX_RUNS}")
    try:  # the base scenario as written: its own errors name its own lines
        parse_scenario(scen_text, str(scen_path))
    except RgtbusError as exc:
        raise _error(where, text, "scenario", str(exc)) from None
    base = tomllib.loads(scen_text)
    # Every case and value alone first (the error names its key), then every cell: all before
    # any run.
    for case, _ in cases:
        try:
            scenario_for(sweep, (("case", case),), seeds[0], base)
        except RgtbusError as exc:
            raise _error(where, text, case, str(exc)) from None
    for key, values in grid:
        for value in values:
            try:
                scenario_for(sweep, ((key, value),), seeds[0], base)
            except RgtbusError as exc:
                raise _error(where, text, key, f"value {value!r}: {exc}") from None
    for cell in sweep.cells():
        try:
            scenario_for(sweep, cell, seeds[0], base)
        except RgtbusError as exc:
            raise _error(where, text, "grid", f"cell {dict(cell)}: {exc}") from None
    return sweep


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


def _flatten(table: dict[str, Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    """``[grid]`` keys, dotted (``relations.p = [...]`` and ``"relations.p" = [...]`` alike)."""
    for k, v in table.items():
        if isinstance(v, dict):
            yield from _flatten(v, f"{prefix}{k}.")
        else:
            yield f"{prefix}{k}", v


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
    return parse_scenario(tomli_w.dumps(data), label)


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
    """One run as one row of the results table; a run that raises is a row with its error."""
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
            if k in ("seed", "engine", "schedule", "log"):
                continue
            # a grid key keeps its name; a summary field of the same name gets a prefix
            name = f"summary.{k}" if k in grid_keys else k
            row[name] = json.dumps(v) if k in JSON_COLUMNS or isinstance(v, list | dict) else v
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


def goal_columns(s: dict[str, Any]) -> dict[str, Any]:
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


# -- the whole sweep ---------------------------------------------------------------------------


@contextlib.contextmanager
def open_executor(workers: int | None, scheduler: str | None) -> Iterator[tuple[Executor, int]]:
    """A local process pool of ``workers`` (all cores by default), or the executor of the Dask
    cluster at ``scheduler`` (``tcp://host:port``); with the number of workers it has."""
    if scheduler:
        from distributed import Client

        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise RgtbusError(f"cannot reach Dask scheduler {scheduler!r}: {exc}") from None
        try:
            n = max(
                1, sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values())
            )
            yield client.get_executor(pure=False), n
        finally:
            client.close()
        return
    import multiprocessing

    n = workers or os.cpu_count() or 1
    ctx = multiprocessing.get_context("spawn")  # no state of this process leaks into a run
    with ProcessPoolExecutor(max_workers=n, mp_context=ctx) as pool:
        yield pool, n


def batches(tasks: list[Task], workers: int) -> list[list[Task]]:
    """Enough batches to keep every worker busy to the end (8 a worker), at most 50 runs each."""
    size = max(1, min(50, math.ceil(len(tasks) / (workers * 8))))
    return [tasks[i : i + size] for i in range(0, len(tasks), size)]


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


def prepare_out(sweep: Sweep, out_dir: Path, resume: bool) -> list[dict[str, Any]]:
    """Create ``out_dir`` with the sweep file and versions beside it; on resume, the rows
    already there (they must be of this sweep)."""
    rows_path = out_dir / "rows.jsonl"
    stored = out_dir / "sweep.json"
    if rows_path.exists() and not resume:
        raise RgtbusError(
            f"{str(out_dir)!r} holds results already: --resume to finish that sweep, or "
            "choose another --out"
        )
    if resume and stored.exists():
        before = json.loads(stored.read_text(encoding="utf-8")).get("digest")
        if before != sweep.digest:
            raise RgtbusError(
                f"{str(out_dir)!r} holds results of another sweep (digest {before}, this "
                f"one {sweep.digest}): cannot resume it with {sweep.path!r}"
            )
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "sweep.toml").write_text(sweep.text, encoding="utf-8")
    (out_dir / "scenario.toml").write_text(sweep.scenario_text, encoding="utf-8")
    stored.write_text(json.dumps(versions(sweep), indent=2) + "\n", encoding="utf-8")
    return read_rows(out_dir) if resume else []


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
        "runs": len(sweep.cells()) * len(sweep.seeds),
        "rgtbus": __version__,
        "python": platform.python_version(),
        "libraries": libs,
    }


def run_sweep(
    sweep: Sweep,
    out_dir: Path,
    *,
    executor: Executor,
    workers: int,
    resume: bool = False,
    logs: bool = False,
    progress: Callable[[int, int, int], None] | None = None,
) -> list[dict[str, Any]]:
    """Run every task not yet in ``out_dir``; return all rows in task order and write the
    tables. ``progress(done, total, failures)`` after every batch."""
    done_rows = prepare_out(sweep, out_dir, resume)
    tasks = sweep.tasks()
    by_key = {t.key: t for t in tasks}
    have = {}
    for r in done_rows:
        key = r.pop("_key", None)
        if key in by_key:
            have[key] = r
    todo = [t for t in tasks if t.key not in have]
    log_dir = None
    if logs:
        log_dir = str(out_dir / "logs")
        os.makedirs(log_dir, exist_ok=True)
    failures = sum(1 for r in have.values() if r.get("failed"))
    if progress:
        progress(len(have), len(tasks), failures)
    with open(out_dir / "rows.jsonl", "a", encoding="utf-8") as sink:
        pending: set[Future] = {
            executor.submit(run_batch, sweep, batch, log_dir) for batch in batches(todo, workers)
        }
        keys = {t.index: t.key for t in todo}
        while pending:
            finished, pending = wait(pending, return_when="FIRST_COMPLETED")
            for fut in finished:
                for row in fut.result():
                    key = keys[row["run"]]
                    have[key] = row
                    failures += bool(row.get("failed"))
                    sink.write(json.dumps({**row, "_key": key}) + "\n")
                sink.flush()
            if progress:
                progress(len(have), len(tasks), failures)
    rows = [have[t.key] for t in tasks]
    write_tables(rows, out_dir)
    return rows


def write_tables(rows: list[dict[str, Any]], out_dir: Path) -> None:
    """``results.parquet`` and ``results.csv``: one row per run, the same columns in both."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    columns: dict[str, None] = {}
    for r in rows:
        columns.update(dict.fromkeys(r))
    data = {c: _column([r.get(c) for r in rows]) for c in columns}
    table = pa.table(data)
    pq.write_table(table, out_dir / "results.parquet")
    pacsv.write_csv(table, out_dir / "results.csv")


def _column(values: list[Any]) -> list[Any]:
    """One type a column: numbers of mixed kinds become floats; anything else mixed, text."""
    kinds = {type(v) for v in values if v is not None}
    if len(kinds) <= 1:
        return values
    if kinds <= {int, float}:
        return [None if v is None else float(v) for v in values]
    return [None if v is None else (v if isinstance(v, str) else json.dumps(v)) for v in values]
