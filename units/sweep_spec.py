"""What a sweep runs: a base scenario over seeds and a grid of keys (``Sweep``, its ``Task``s),
read from a sweep file (``load_sweep``: every error one line with file:line: key) or built from
arguments (``make_sweep``, the library's ``sweep()``). Running it: ``rgtbus.units.sweep``."""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import numbers
import os
import re
import tomllib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomli_w

from rgtbus.checks import ENGINES
from rgtbus.errors import BadInput, IOFailure, RgtbusError
from rgtbus.scenario import MAX_SCENARIO_BYTES, Scenario, parse_scenario
from rgtbus.scenario.limits import key_depth_error, nesting_error, read_regular
from rgtbus.scenario.shipped import find_shipped, find_sweep

SWEEP_KEYS = {"name", "description", "scenario", "seeds", "grid", "cases"}
MAX_RUNS = 1_000_000
# the version of the tables a sweep directory holds (sweep.json "tables"): 2 is native Arrow
# types and decisions.parquet; 1 (no key) held nested columns as JSON text
# 3: every row names its sweep and run (sweep, run_id); 4: the ID-codes as read (id_decodes,
# id_misread_count, id_misread_rate, id_misreads_left); 5: decode_errors as counts and a
# sample (rgtbus.misreads), decode_errors_left a derived column
TABLES_VERSION = 5
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
    """A sweep as read or built: its file's text, the base scenario's, the seeds, the grid and
    the cases; ``tasks()`` are its runs, ``digest`` names it across a resume."""

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
        """The grid's keys, ``case`` first when there are cases."""
        return [k for k, _ in self.axes]

    def case(self, name: str) -> tuple[tuple[str, Any], ...]:
        """The keys case ``name`` sets."""
        return dict(self.cases)[name]

    def cells(self) -> list[tuple[tuple[str, Any], ...]]:
        """Every grid cell (one value of each key), in order: the last key varies fastest."""
        values = [vs for _, vs in self.axes]
        return [tuple(zip(self.keys, combo, strict=True)) for combo in itertools.product(*values)]

    def tasks(self) -> list[Task]:
        """Every run: each cell with each seed, numbered in that order."""
        out: list[Task] = []
        for cell in self.cells():
            for seed in self.seeds:
                out.append(Task(len(out), cell, seed))
        return out

    @property
    def runs(self) -> int:
        """How many runs: cells times seeds."""
        return math.prod(len(vs) for _, vs in self.axes) * len(self.seeds)

    @property
    def id(self) -> str:
        """The sweep's id in its tables' rows: its name and the start of its digest (what it
        runs), so two sweeps' rows never share one."""
        return f"{self.name}-{self.digest[:8]}"

    @property
    def digest(self) -> str:
        """What a resume checks: a hash of the sweep file's and base scenario's texts."""
        return hashlib.sha256((self.text + "\0" + self.scenario_text).encode()).hexdigest()[:16]


# -- reading a sweep file ----------------------------------------------------------------------


def _line_of(text: str, key: str) -> int | None:
    pattern = re.compile(r'\s*"?' + re.escape(key) + r'"?\s*=')
    for i, line in enumerate(text.splitlines(), 1):
        if pattern.match(line):
            return i
    return None


def error_at(
    path: str, text: str, key: str | None, reason: str, what: str = "sweep"
) -> RgtbusError:
    """One line naming the file, the key's line in it (when found) and the key (else ``what``)."""
    line = _line_of(text, key) if key else None
    if line is None and key and "." in key:  # [grid.relations] p = ..., or an inline table
        line = _line_of(text, key.rpartition(".")[2])
    where = f"{path}:{line}" if line else path
    return BadInput(f"{where}: {key or what}: {reason}")


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
    sweep file, its line and key). ``path`` may name a shipped sweep (``rgtbus sweeps``:
    ``noise``) where no such file is here; its ``scenario`` may name a shipped scenario
    (``random_group``) where no such file is beside it."""
    p = Path(path)
    if not p.exists() and (shipped := find_sweep(str(path))) is not None:
        p = shipped
    where = str(p)
    text, data = read_toml(p, "sweep")

    def err(key: str | None, reason: str) -> RgtbusError:
        return error_at(where, text, key, reason)

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
    scen_path, scen_text = read_base(scen, p.parent, err)
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
    grid, cases = _axes(list(flatten_keys(grid_table)), list(cases_table.items()), err)
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
        keys = list(flatten_keys(settings))
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


def read_base(scen: str, here: Path, err: ErrorAt) -> tuple[Path, str]:
    """The base scenario a sweep or study file names: its path (relative to the file's
    directory ``here``; a shipped scenario's name where no such file is there) and its text;
    a refusal is ``err("scenario", why)``."""
    path = (here / scen).resolve() if not Path(scen).is_absolute() else Path(scen)
    if not path.exists() and (named := find_shipped(scen)) is not None:
        path = named  # a shipped scenario by name
    try:
        return path, read_capped(path, "scenario").decode("utf-8")
    except UnicodeDecodeError:
        raise err("scenario", f"{str(path)!r}: not UTF-8 text") from None
    except RgtbusError as exc:
        raise err("scenario", str(exc)) from None


def read_toml(path: Path, what: str) -> tuple[str, dict[str, Any]]:
    """A sweep or study file's text and its TOML, each refusal one line naming the file (and
    the line, for bad TOML); nesting too deep is refused before tomllib recurses, dotted keys
    too deep after."""
    where = str(path)
    raw = read_capped(path, what)
    try:
        text = raw.decode("utf-8")
        too_deep = nesting_error(text, where)  # before tomllib, which recurses
        if too_deep:
            raise BadInput(too_deep)
        data = tomllib.loads(text)
    except UnicodeDecodeError:
        raise BadInput(f"{where}: not a UTF-8 text file") from None
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"\(at line (\d+), column \d+\)", str(exc))
        raise BadInput(f"{where}:{m.group(1) if m else '?'}: not valid TOML: {exc}") from None
    too_deep = key_depth_error(data, text, where)  # a dotted key: [grid] is flattened later
    if too_deep:
        raise BadInput(too_deep)
    return text, data


def read_capped(path: Path, what: str) -> bytes:
    """A sweep or scenario file's bytes; one line if it cannot be read, is no regular file (a
    FIFO, a device: refused before a byte is read) or is far too large."""
    try:
        data = read_regular(path, what, MAX_SCENARIO_BYTES)
    except RgtbusError:  # already one line (a directory, a FIFO, a device)
        raise
    except ValueError as exc:  # a NUL in the path
        raise BadInput(f"cannot read {what} {str(path)!r}: {exc}") from None
    except OSError as exc:
        raise IOFailure(f"cannot read {what} {str(path)!r}: {exc.strerror}") from None
    if len(data) > MAX_SCENARIO_BYTES:
        raise BadInput(f"{str(path)!r}: larger than {MAX_SCENARIO_BYTES >> 20} MiB: not a {what}")
    return data


def flatten_keys(table: Mapping[str, Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    """``[grid]`` keys, dotted (``relations.p = [...]`` and ``"relations.p" = [...]`` alike)."""
    for k, v in table.items():
        if isinstance(v, Mapping):
            yield from flatten_keys(v, f"{prefix}{k}.")
        else:
            yield f"{prefix}{k}", v


# -- a sweep from arguments (the library) ------------------------------------------------------


def plain_value(value: Any) -> Any:
    """A grid value as a TOML value: numpy scalars and arrays as Python ones, tuples as lists."""
    if type(value).__module__ == "numpy" and hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, tuple | list):
        return [plain_value(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): plain_value(v) for k, v in value.items()}
    return value


def _seeds_arg(seeds: int | Sequence[int] | str) -> tuple[int, ...]:
    """``seeds=N``: seeds 0..N-1; a sequence: those seeds; ``"a..b"``: as in a sweep file."""
    if isinstance(seeds, bool):
        raise BadInput(f"sweep seeds: an integer N (seeds 0..N-1) or a list, got {seeds!r}")
    if isinstance(seeds, numbers.Integral):
        n = int(seeds)
        if not 1 <= n <= MAX_RUNS:
            raise BadInput(f"sweep seeds: N must be 1..{MAX_RUNS} (seeds 0..N-1), got {n}")
        return tuple(range(n))
    try:
        if isinstance(seeds, str):
            return parse_seeds(seeds)
        if isinstance(seeds, int):  # not reached (an Integral above); for the type checker
            raise TypeError(seeds)
        return parse_seeds(plain_value(list(seeds)))
    except (TypeError, ValueError) as exc:
        raise BadInput(f"sweep seeds: {exc}") from None


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
        raise BadInput(f"sweep grid: a mapping of key -> [values], got {type(grid).__name__}")
    if cases is not None and not isinstance(cases, Mapping):
        raise BadInput(f"sweep cases: a mapping of name -> {{key: value}}, got {cases!r}")

    def err(key: str | None, reason: str) -> RgtbusError:
        return BadInput(f"sweep: {key}: {reason}" if key else f"sweep: {reason}")

    items = []
    for key, values in flatten_keys(grid):
        try:
            if isinstance(values, str | bytes):
                raise TypeError
            listed = list(values)
        except TypeError:
            raise err(key, f"must be a non-empty list of values, got {values!r}") from None
        items.append((key, plain_value(listed)))
    case_items = [(str(k), plain_value(v)) for k, v in (cases or {}).items()]
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
        raise BadInput(f"sweep grid: a value TOML cannot hold: {exc}") from None
    sw = Sweep(f"sweep({sc.path})", text, sweep_name, sc.path, sc.text, seeds_t, grid_t, cases_t)
    check_sweep(sw, err)
    return sw


# -- a task's scenario -------------------------------------------------------------------------


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
                raise BadInput(f"n: a group size must be an integer 1..200, got {value!r}")
            set_key(data, "units", [f"u{i}" for i in range(1, value + 1)])
            continue
        set_key(data, key, value)
    data["seed"] = seed
    settings = [f"{k}={v!r}" for k, v in cell] + [f"seed {seed}"]
    label = f"{sweep.scenario_path} [{'; '.join(settings)}]"
    try:
        text = tomli_w.dumps(data)
    except TypeError as exc:  # a value TOML cannot hold (None, an object)
        raise BadInput(f"not a TOML value: {exc}") from None
    return parse_scenario(text, label)


def set_key(data: dict[str, Any], key: str, value: Any) -> None:
    parts = key.split(".")
    node = data
    for part in parts[:-1]:
        nxt = node.setdefault(part, {})
        if not isinstance(nxt, dict):
            raise BadInput(f"{key}: {part!r} is not a table in the scenario")
        node = nxt
    node[parts[-1]] = value


def _expand(sweep: Sweep, key: str, value: Any) -> tuple[tuple[str, Any], ...]:
    """A cell's key as the settings it stands for (a case: its keys)."""
    return sweep.case(value) if key == "case" else ((key, value),)


def engine_of(sweep: Sweep, cell: tuple[tuple[str, Any], ...]) -> str:
    """The engine a cell runs on (a grid or case key ``engine``; event by default)."""
    settings = dict(kv for key, value in cell for kv in _expand(sweep, key, value))
    return str(settings.get("engine", "event"))
