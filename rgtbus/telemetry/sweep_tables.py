"""A sweep's tables: ``results.parquet`` (one row per run: grid columns, seed, the run
summary with native Arrow types) and ``decisions.parquet`` (one row per run, unit and influence
round), each with a schema fixed by the grid's axes, never by the data, so two sweeps' tables
stack. ``axes``: the grid's keys and values in column order (``case`` first when there are
cases). Written and read here; run by ``rgtbus.units.sweep``."""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from rgtbus.errors import RgtbusError
from rgtbus.summary import SUMMARY_JSON_KEYS

if TYPE_CHECKING:
    import pandas as pd
    import pyarrow as pa


Axes = Sequence[tuple[str, Sequence[Any]]]
# summary fields that are no column of their own (a grid key, or a table of their own)
NOT_COLUMNS = ("seed", "engine", "schedule", "log", "decisions")

# -- the tables --------------------------------------------------------------------------------


def _summary_types() -> dict[str, pa.DataType]:
    """The Arrow type of each summary field that is a column of the results (a field not named
    here, e.g. one a later summary adds, is stored as JSON text)."""
    import pyarrow as pa

    text, alts = pa.string(), pa.list_(pa.string())
    i64, f64, yes = pa.int64(), pa.float64(), pa.bool_()
    influences = pa.map_(text, alts)  # "s>r" -> the alternative sent (sorted action names)
    unit = pa.struct(
        [
            ("unit", text),
            ("low", alts),  # the interval [low, high] of its decision (B and A); None: frustrated
            ("high", alts),
            ("choice", alts),
            ("frustrated", yes),
            ("decided", yes),
            ("A", alts),
            ("B", alts),
            ("canonical", text),
        ]
    )
    goal = pa.struct(
        [
            ("unit", text),
            ("target", text),
            ("want_low", alts),
            ("want_high", alts),
            ("mode", text),
            ("reached", yes),
            ("reachable", yes),
            ("share", f64),
        ]
    )
    rounds = pa.struct(
        [
            ("count", i64),
            ("state", text),
            ("since", i64),
            ("length", i64),
            ("influences", pa.list_(influences)),
        ]
    )
    decode_error = pa.struct(
        [("unit", text), ("turn", i64), ("kind", text), ("decoded", text), ("sent", text)]
    )
    counts = ("requests", "repeats", "copies", "missing", "resolved", "unresolved")
    repair = pa.struct(
        [("mode", text), ("blocks_per_phase", i64), ("seconds", f64)] + [(k, i64) for k in counts]
    )
    return {
        "scenario": text,
        "polynomial": text,
        "decomposable": yes,
        "p4": alts,
        "relations": pa.map_(text, text),  # "a-b" -> alliance | conflict
        "agree": yes,
        "influences": influences,
        "units": pa.list_(unit),
        "frustrated": alts,
        "wrong_decisions": alts,
        "goals": pa.list_(goal),
        "rounds": rounds,
        "outcome": text,
        "sim_seconds": f64,
        "wall_seconds": f64,
        "decode_errors": pa.list_(decode_error),
        "decode_errors_left": i64,  # those not set right (summary.decode_errors_left)
        "codebook": text,
        "repair": repair,  # null without a repair
        "error": text,
    }


def _derived_types() -> list[tuple[str, pa.DataType]]:
    import pyarrow as pa

    i64, f64, yes = pa.int64(), pa.float64(), pa.bool_()
    return [
        ("decode_error_count", i64),
        ("frustrated_count", i64),
        ("decided_count", i64),
        ("wrong_decision_count", i64),
        ("wrong_decision_rate", f64),
        ("goal_count", i64),
        ("goal_reached_rate", f64),
        ("goal_reachable_rate", f64),
        ("goal_share_mean", f64),
        ("goal_reached", yes),
        ("goal_reachable", yes),
        ("rounds_state", pa.string()),
        ("rounds_cycle_length", i64),
        ("alliance_share", f64),
        ("decodes", i64),
        ("decode_error_rate", f64),
        ("id_decodes", i64),
        ("id_misread_count", i64),
        ("id_misread_rate", f64),
        ("id_misreads_left", i64),
        ("failed", yes),
        ("log", pa.string()),
    ]


def grid_type(key: str, values: Sequence[Any]) -> pa.DataType:
    """A grid column's type, from the grid's values (never from the runs): all booleans bool,
    all integers int64, numbers float64, anything else text (a list or table as JSON text)."""
    import pyarrow as pa

    kinds = {type(v) for v in values}
    if key in ("case", "engine") or not kinds:
        return pa.string()
    if kinds == {bool}:
        return pa.bool_()
    if kinds == {int}:
        return pa.int64()
    if kinds <= {int, float}:
        return pa.float64()
    return pa.string()


def _grid_fields(axes: Axes) -> list[tuple[str, pa.DataType]]:
    return [(key, grid_type(key, values)) for key, values in axes]


def results_schema(axes: Axes) -> pa.Schema:
    """The results table's schema: fixed but for the grid columns (``grid_type``), so two
    sweeps' tables concatenate and a column whose runs are all empty keeps its type."""
    import pyarrow as pa

    keys = {k for k, _ in axes}
    # which sweep and which run, across sweeps: two sweeps' tables concatenate with every row
    # still named (``run`` is a run's place in its own sweep)
    fields: list[tuple[str, pa.DataType]] = [
        ("sweep", pa.string()), ("run_id", pa.string()), ("run", pa.int64())
    ]  # fmt: skip
    fields += _grid_fields(axes)
    fields.append(("seed", pa.int64()))
    if "engine" not in keys:
        fields.append(("engine", pa.string()))
    fields += [("digest", pa.string()), ("schedule", pa.string()), ("n_units", pa.int64())]
    types_ = _summary_types()
    for k in SUMMARY_JSON_KEYS:
        if k not in NOT_COLUMNS:
            fields.append((f"summary.{k}" if k in keys else k, types_.get(k, pa.string())))
    fields += _derived_types()
    names = [n for n, _ in fields]
    clash = sorted({n for n in names if names.count(n) > 1})
    if clash:
        raise RgtbusError(f"sweep grid: {clash[0]!r} is a column of the results, not a grid key")
    return pa.schema(fields)


def decisions_schema(axes: Axes) -> pa.Schema:
    """decisions.parquet: one row per run, unit and influence round."""
    import pyarrow as pa

    alts = pa.list_(pa.string())
    return pa.schema(
        [
            ("sweep", pa.string()),
            ("run_id", pa.string()),
            ("run", pa.int64()),
            *_grid_fields(axes),
            ("seed", pa.int64()),
            ("unit", pa.string()),
            ("round", pa.int64()),
            ("low", alts),
            ("high", alts),
            ("choice", alts),
            ("frustrated", pa.bool_()),
            ("wrong", pa.bool_()),
            ("t", pa.float64()),
        ]
    )


def _loaded(value: Any) -> Any:
    """A nested value as the summary states it (rows of an older rgtbus: JSON text)."""
    return json.loads(value) if isinstance(value, str) else value


def _influence_map(value: Any) -> list[tuple[str, Any]] | None:
    return None if value is None else list(value.items())


def _unit_rows(units: Any) -> list[dict[str, Any]]:
    out = []
    for name, r in units.items():
        interval = r.get("interval")
        out.append(
            {
                "unit": name,
                "low": interval[0] if interval else None,
                "high": interval[1] if interval else None,
                **{k: r.get(k) for k in ("choice", "frustrated", "decided", "A", "B", "canonical")},
            }
        )
    return out


def _goal_rows(goals: Any) -> list[dict[str, Any]]:
    out = []
    for g in goals:
        want = g.get("want") or [None, None]
        out.append({**g, "want_low": want[0], "want_high": want[1]})
    return out


def _rounds_struct(rounds: Any) -> dict[str, Any]:
    infl = rounds.get("influences")
    return {
        **{k: rounds.get(k) for k in ("count", "state", "since", "length")},
        "influences": None if infl is None else [_influence_map(r) for r in infl],
    }


_SHAPES: dict[str, Callable[[Any], Any]] = {
    "relations": _influence_map,
    "influences": _influence_map,
    "units": _unit_rows,
    "goals": _goal_rows,
    "rounds": _rounds_struct,
}


def _shaped(axes: Axes, schema: pa.Schema, row: Mapping[str, Any]) -> dict[str, Any]:
    """A row as ``run_row`` gives it (or an older rgtbus stored it) in the table's shapes."""
    import pyarrow as pa

    grid = {k for k, _ in axes}
    out: dict[str, Any] = {}
    for f in schema:
        v = row.get(f.name)
        if v is None:
            out[f.name] = None
            continue
        # the summary field a column holds (a grid column: none)
        if f.name.startswith("summary."):
            summary_field: str | None = f.name.removeprefix("summary.")
        else:
            summary_field = None if f.name in grid else f.name
        nested = pa.types.is_nested(f.type)
        if nested:
            v = _loaded(v)
            if summary_field in _SHAPES and v is not None:
                v = _SHAPES[summary_field](v)
        elif pa.types.is_string(f.type) and not isinstance(v, str):
            v = json.dumps(v)
        elif pa.types.is_floating(f.type) and isinstance(v, int) and not isinstance(v, bool):
            v = float(v)
        out[f.name] = v
    return out


def run_id(sweep_id: str, run: Any) -> str:
    """A run's name across sweeps: its sweep's id and its place in it (``SWEEP/RUN``)."""
    return f"{sweep_id}/{run}"


def results_table(axes: Axes, rows: Sequence[Mapping[str, Any]], sweep_id: str = "") -> pa.Table:
    """The results table of ``rows`` (one a run, in order), typed by ``results_schema``;
    ``sweep_id`` (``Sweep.id``) names the sweep in each row."""
    import pyarrow as pa

    schema = results_schema(axes)
    named = [{**r, "sweep": sweep_id, "run_id": run_id(sweep_id, r.get("run"))} for r in rows]
    return pa.Table.from_pylist([_shaped(axes, schema, r) for r in named], schema=schema)


def decisions_table(axes: Axes, rows: Sequence[Mapping[str, Any]], sweep_id: str = "") -> pa.Table:
    """Every decision of every run: one row per run, unit and influence round (each named by
    its sweep and run id, as in the results)."""
    import pyarrow as pa

    schema = decisions_schema(axes)
    keys = [k for k, _ in axes]
    head = ["sweep", "run_id", "run", *keys, "seed"]
    rows = [{**r, "sweep": sweep_id, "run_id": run_id(sweep_id, r.get("run"))} for r in rows]
    grid = {f.name: f.type for f in schema if f.name in keys}
    out = []
    for r in rows:
        decisions = r.get("_decisions")
        if decisions is None and "decisions" not in keys:  # an older row, if it had them
            decisions = r.get("decisions")
        cell = {k: r.get(k) for k in head}
        for k, t in grid.items():
            v = cell[k]
            if v is not None and pa.types.is_string(t) and not isinstance(v, str):
                cell[k] = json.dumps(v)
            elif v is not None and pa.types.is_floating(t):
                cell[k] = float(v)
        for d in _loaded(decisions) or ():
            out.append({**cell, **{k: d.get(k) for k in schema.names if k not in cell}})
    return pa.Table.from_pylist(out, schema=schema)


def jsonable(value: Any, typ: pa.DataType) -> Any:
    """An Arrow value (``to_pylist``) as plain JSON: a map as an object."""
    import pyarrow as pa

    if value is None:
        return None
    if pa.types.is_map(typ):
        return {k: jsonable(v, typ.item_type) for k, v in value}
    if pa.types.is_list(typ) or pa.types.is_large_list(typ):
        return [jsonable(v, typ.value_type) for v in value]
    if pa.types.is_struct(typ):
        return {f.name: jsonable(value.get(f.name), f.type) for f in typ}
    return value


def table_rows(table: pa.Table) -> list[dict[str, Any]]:
    """A table's rows as plain Python and JSON values (maps as dicts)."""
    import pyarrow as pa

    nested = {f.name: f.type for f in table.schema if pa.types.is_nested(f.type)}
    rows: list[dict[str, Any]] = table.to_pylist()
    for r in rows:
        for name, typ in nested.items():
            r[name] = jsonable(r[name], typ)
    return rows


def _csv_table(table: pa.Table) -> pa.Table:
    """The table with nested columns as JSON text (CSV holds no nested values)."""
    import pyarrow as pa

    for i, f in enumerate(table.schema):
        if pa.types.is_nested(f.type):
            text = [
                None if v is None else json.dumps(jsonable(v, f.type))
                for v in table.column(i).to_pylist()
            ]
            table = table.set_column(i, pa.field(f.name, pa.string()), pa.array(text, pa.string()))
    return table


def write_tables(
    axes: Axes, rows: Sequence[Mapping[str, Any]], out_dir: Path, sweep_id: str = ""
) -> pa.Table:
    """``results.parquet`` and ``results.csv`` (one row per run, the same columns in both) and
    ``decisions.parquet``; each written whole, then moved into place. Returns the results."""
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    results = results_table(axes, rows, sweep_id)
    decisions = decisions_table(axes, rows, sweep_id)
    writes: list[tuple[str, Callable[[Path], None]]] = [
        ("results.parquet", lambda p: pq.write_table(results, p)),
        ("decisions.parquet", lambda p: pq.write_table(decisions, p)),
        ("results.csv", lambda p: pacsv.write_csv(_csv_table(results), p)),
    ]
    for name, write in writes:
        tmp = out_dir / f".{name}.part"
        write(tmp)
        os.replace(tmp, out_dir / name)
    return results


class Record(dict[str, Any]):
    """A table's struct or map cell as a dict that pandas can group, sort, deduplicate and
    merge on: hashable, and ordered, by its content (JSON with sorted keys). Read it as a dict
    (``cell["unit"]``, ``dict(cell)``); it is not to be changed in place (its hash would)."""

    __slots__ = ()

    def _key(self) -> str:
        return json.dumps(self, sort_keys=True, default=repr)

    def __hash__(self) -> int:  # type: ignore[override]
        return hash(self._key())

    def __lt__(self, other: object) -> bool:
        if not isinstance(other, Record):
            return NotImplemented
        return self._key() < other._key()


def usable(value: Any) -> Any:
    """A cell as a value pandas can use: a list or array as a tuple, a dict (a struct, or a map
    read as one) as a ``Record``, each inside too; anything else as it is."""
    if isinstance(value, dict):
        return Record({k: usable(v) for k, v in value.items()})
    if isinstance(value, list | tuple) or getattr(value, "ndim", 0) == 1:  # a NumPy array
        return tuple(usable(v) for v in value)
    return value


def read_table(path: Path) -> pd.DataFrame:
    """A sweep's Parquet table as a DataFrame whose every column pandas can group, sort,
    deduplicate and merge on: lists as tuples, structs and maps as ``Record`` dicts."""
    import pyarrow.parquet as pq

    frame: pd.DataFrame = pq.read_table(path).to_pandas(maps_as_pydicts="strict")
    for column in frame.columns:
        if frame[column].dtype == object:
            frame[column] = frame[column].map(usable, na_action="ignore")
    return frame


class SweepTables(NamedTuple):
    """A sweep directory's tables as pandas DataFrames (``read_sweep``)."""

    results: pd.DataFrame
    decisions: pd.DataFrame


def read_sweep(out: str | os.PathLike[str]) -> SweepTables:
    """``(results, decisions)`` of the sweep written to ``out`` (``sweep(..., out=DIR)`` or
    ``rgtbus sweep --out DIR``), each column one pandas can group, sort, deduplicate and merge
    on (``read_table``: lists as tuples, structs and maps as ``Record`` dicts). A directory
    without ``decisions.parquet`` (an older rgtbus) gives an empty decisions table."""
    import pandas as pd

    d = Path(out)
    path = d / "results.parquet"
    if not path.is_file():
        raise RgtbusError(f"{str(d)!r}: no results.parquet (run the sweep first)")
    dec = d / "decisions.parquet"
    columns = ["sweep", "run_id", "run", "seed", "unit", "round", "low", "high", "choice",
               "frustrated", "wrong", "t"]  # fmt: skip
    decisions = read_table(dec) if dec.is_file() else pd.DataFrame(columns=columns)
    return SweepTables(read_table(path), decisions)
