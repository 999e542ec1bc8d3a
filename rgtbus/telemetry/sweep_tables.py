"""A sweep's tables: the results (one row per run: grid columns, seed, the run summary with
typed nested columns) and the decisions (one row per run, unit and influence round), each with
columns fixed by the grid's axes, never by the data, so two sweeps' tables stack. ``axes``: the
grid's keys and values in column order (``case`` first when there are cases).

Files: ``results.jsonl`` and ``decisions.jsonl`` (a row a line, plain JSON: what the core reads
back), ``results.csv`` (nested columns as JSON text) and, with pyarrow (the ``parquet``
extra), ``results.parquet`` and ``decisions.parquet`` with native Arrow types. A column's type
is said here once, without Arrow (``ColumnType``), and made an Arrow type only for Parquet.
Written and read here; run by ``rgtbus.units.sweep``."""

from __future__ import annotations

import csv
import importlib.util
import json
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

import orjson

from rgtbus.errors import BadInput
from rgtbus.summary import SUMMARY_JSON_KEYS

if TYPE_CHECKING:
    import pyarrow as pa


Axes = Sequence[tuple[str, Sequence[Any]]]
# summary fields that are no column of their own (a grid key, or a table of their own)
NOT_COLUMNS = ("seed", "engine", "schedule", "log", "decisions")

# -- column types, without Arrow ---------------------------------------------------------------

# "text", "int", "float", "bool"; ("list", T); ("map", K, V); ("struct", ((name, T), ...))
ColumnType: TypeAlias = "str | tuple[Any, ...]"
Columns = list[tuple[str, ColumnType]]
TEXT, INT, FLOAT, BOOL = "text", "int", "float", "bool"


def list_of(item: ColumnType) -> ColumnType:
    return ("list", item)


def map_of(key: ColumnType, value: ColumnType) -> ColumnType:
    return ("map", key, value)


def struct_of(*fields: tuple[str, ColumnType]) -> ColumnType:
    return ("struct", tuple(fields))


def is_nested(kind: ColumnType) -> bool:
    """A list, map or struct (JSON text in the CSV; ``Record`` dicts and tuples in frames)."""
    return isinstance(kind, tuple)


def arrow_type(kind: ColumnType) -> pa.DataType:
    """The Arrow type of a column type (Parquet's, and the frames read from it)."""
    import pyarrow as pa

    scalars = {TEXT: pa.string(), INT: pa.int64(), FLOAT: pa.float64(), BOOL: pa.bool_()}
    if isinstance(kind, str):
        return scalars[kind]
    if kind[0] == "list":
        return pa.list_(arrow_type(kind[1]))
    if kind[0] == "map":
        return pa.map_(arrow_type(kind[1]), arrow_type(kind[2]))
    return pa.struct([(name, arrow_type(t)) for name, t in kind[1]])


def arrow_schema(columns: Columns) -> pa.Schema:
    import pyarrow as pa

    return pa.schema([(name, arrow_type(kind)) for name, kind in columns])


def plain(value: Any, kind: ColumnType) -> Any:
    """A cell as plain JSON, as Arrow would hold it and give it back: a map as an object, a
    struct with exactly its fields (a missing one null), numbers of the column's type."""
    if value is None:
        return None
    if isinstance(kind, str):
        if kind == FLOAT:
            return float(value)
        if kind == INT:
            return int(value)
        return value
    if kind[0] == "list":
        return [plain(v, kind[1]) for v in value]
    if kind[0] == "map":
        pairs = value.items() if isinstance(value, Mapping) else value
        return {k: plain(v, kind[2]) for k, v in pairs}
    return {name: plain(value.get(name), t) for name, t in kind[1]}


# -- the tables --------------------------------------------------------------------------------


def _summary_types() -> dict[str, ColumnType]:
    """The type of each summary field that is a column of the results (a field not named
    here, e.g. one a later summary adds, is stored as JSON text)."""
    alts = list_of(TEXT)
    influences = map_of(TEXT, alts)  # "s>r" -> the alternative sent (sorted action names)
    unit = struct_of(
        ("unit", TEXT),
        ("low", alts),  # the interval [low, high] of its decision (B and A); None: frustrated
        ("high", alts),
        ("choice", alts),
        ("frustrated", BOOL),
        ("decided", BOOL),
        ("A", alts),
        ("B", alts),
        ("canonical", TEXT),
    )
    goal = struct_of(
        ("unit", TEXT),
        ("target", TEXT),
        ("want_low", alts),
        ("want_high", alts),
        ("mode", TEXT),
        ("reached", BOOL),
        ("reachable", BOOL),
        ("share", FLOAT),
    )
    rounds = struct_of(
        ("count", INT),
        ("state", TEXT),
        ("since", INT),
        ("length", INT),
        ("influences", list_of(influences)),
    )
    misread = struct_of(
        ("unit", TEXT), ("turn", INT), ("kind", TEXT), ("decoded", TEXT), ("sent", TEXT),
        ("left_wrong", BOOL),
    )  # fmt: skip
    fates = (("misread", INT), ("set_right", INT), ("left_wrong", INT))
    decode_errors = struct_of(
        *fates, ("by_kind", map_of(TEXT, struct_of(*fates))), ("sample", list_of(misread)),
        ("rest", TEXT),
    )  # fmt: skip
    counts = ("requests", "repeats", "copies", "missing", "resolved", "unresolved")
    repair = struct_of(
        ("mode", TEXT), ("blocks_per_phase", INT), ("seconds", FLOAT), *[(k, INT) for k in counts]
    )
    return {
        "scenario": TEXT,
        "polynomial": TEXT,
        "decomposable": BOOL,
        "p4": alts,
        "relations": map_of(TEXT, TEXT),  # "a-b" -> alliance | conflict
        "agree": BOOL,
        "influences": influences,
        "units": list_of(unit),
        "frustrated": alts,
        "wrong_decisions": alts,
        "goals": list_of(goal),
        "rounds": rounds,
        "outcome": TEXT,
        "sim_seconds": FLOAT,
        "wall_seconds": FLOAT,
        "decode_errors": decode_errors,  # counts and a sample (rgtbus.misreads)
        "codebook": TEXT,
        "repair": repair,  # null without a repair
        "error": TEXT,
    }


def _derived_types() -> Columns:
    return [
        ("decode_error_count", INT),
        ("frustrated_count", INT),
        ("decided_count", INT),
        ("wrong_decision_count", INT),
        ("wrong_decision_rate", FLOAT),
        ("goal_count", INT),
        ("goal_reached_rate", FLOAT),
        ("goal_reachable_rate", FLOAT),
        ("goal_share_mean", FLOAT),
        ("goal_reached", BOOL),
        ("goal_reachable", BOOL),
        ("rounds_state", TEXT),
        ("rounds_cycle_length", INT),
        ("alliance_share", FLOAT),
        ("decodes", INT),
        ("decode_error_rate", FLOAT),
        ("decode_errors_left", INT),  # the summary's decode_errors.left_wrong
        ("id_decodes", INT),
        ("id_misread_count", INT),
        ("id_misread_rate", FLOAT),
        ("id_misreads_left", INT),
        ("failed", BOOL),
        ("log", TEXT),
    ]


def grid_type(key: str, values: Sequence[Any]) -> ColumnType:
    """A grid column's type, from the grid's values (never from the runs): all booleans bool,
    all integers int, numbers float, anything else text (a list or table as JSON text)."""
    kinds = {type(v) for v in values}
    if key in ("case", "engine") or not kinds:
        return TEXT
    if kinds == {bool}:
        return BOOL
    if kinds == {int}:
        return INT
    if kinds <= {int, float}:
        return FLOAT
    return TEXT


def _grid_fields(axes: Axes) -> Columns:
    return [(key, grid_type(key, values)) for key, values in axes]


def results_columns(axes: Axes) -> Columns:
    """The results table's columns: fixed but for the grid columns (``grid_type``), so two
    sweeps' tables concatenate and a column whose runs are all empty keeps its type."""
    keys = {k for k, _ in axes}
    # which sweep and which run, across sweeps: two sweeps' tables concatenate with every row
    # still named (``run`` is a run's place in its own sweep)
    fields: Columns = [("sweep", TEXT), ("run_id", TEXT), ("run", INT)]
    fields += _grid_fields(axes)
    fields.append(("seed", INT))
    if "engine" not in keys:
        fields.append(("engine", TEXT))
    fields += [("digest", TEXT), ("schedule", TEXT), ("n_units", INT)]
    types_ = _summary_types()
    for k in SUMMARY_JSON_KEYS:
        if k not in NOT_COLUMNS:
            fields.append((f"summary.{k}" if k in keys else k, types_.get(k, TEXT)))
    fields += _derived_types()
    names = [n for n, _ in fields]
    clash = sorted({n for n in names if names.count(n) > 1})
    if clash:
        raise BadInput(f"sweep grid: {clash[0]!r} is a column of the results, not a grid key")
    return fields


def decisions_columns(axes: Axes) -> Columns:
    """The decisions table's columns: one row per run, unit and influence round."""
    alts = list_of(TEXT)
    return [
        ("sweep", TEXT),
        ("run_id", TEXT),
        ("run", INT),
        *_grid_fields(axes),
        ("seed", INT),
        ("unit", TEXT),
        ("round", INT),
        ("low", alts),
        ("high", alts),
        ("choice", alts),
        ("frustrated", BOOL),
        ("wrong", BOOL),
        ("t", FLOAT),
    ]


def results_schema(axes: Axes) -> pa.Schema:
    """results.parquet's Arrow schema (``results_columns``)."""
    return arrow_schema(results_columns(axes))


def decisions_schema(axes: Axes) -> pa.Schema:
    """decisions.parquet's Arrow schema (``decisions_columns``)."""
    return arrow_schema(decisions_columns(axes))


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


def _shaped(axes: Axes, columns: Columns, row: Mapping[str, Any]) -> dict[str, Any]:
    """A row as ``run_row`` gives it (or an older rgtbus stored it) in the table's shapes."""
    grid = {k for k, _ in axes}
    out: dict[str, Any] = {}
    for name, kind in columns:
        v = row.get(name)
        if v is None:
            out[name] = None
            continue
        # the summary field a column holds (a grid column: none)
        if name.startswith("summary."):
            summary_field: str | None = name.removeprefix("summary.")
        else:
            summary_field = None if name in grid else name
        if is_nested(kind):
            v = _loaded(v)
            if summary_field in _SHAPES and v is not None:
                v = _SHAPES[summary_field](v)
        elif kind == TEXT and not isinstance(v, str):
            v = json.dumps(v)
        elif kind == FLOAT and isinstance(v, int) and not isinstance(v, bool):
            v = float(v)
        out[name] = v
    return out


def run_id(sweep_id: str, run: Any) -> str:
    """A run's name across sweeps: its sweep's id and its place in it (``SWEEP/RUN``)."""
    return f"{sweep_id}/{run}"


def _named(rows: Sequence[Mapping[str, Any]], sweep_id: str) -> list[dict[str, Any]]:
    return [{**r, "sweep": sweep_id, "run_id": run_id(sweep_id, r.get("run"))} for r in rows]


def _results_shaped(
    axes: Axes, rows: Sequence[Mapping[str, Any]], sweep_id: str
) -> tuple[Columns, list[dict[str, Any]]]:
    columns = results_columns(axes)
    return columns, [_shaped(axes, columns, r) for r in _named(rows, sweep_id)]


def _decisions_shaped(
    axes: Axes, rows: Sequence[Mapping[str, Any]], sweep_id: str
) -> tuple[Columns, list[dict[str, Any]]]:
    columns = decisions_columns(axes)
    names = [n for n, _ in columns]
    keys = [k for k, _ in axes]
    head = ["sweep", "run_id", "run", *keys, "seed"]
    grid = {n: kind for n, kind in columns if n in keys}
    out = []
    for r in _named(rows, sweep_id):
        decisions = r.get("_decisions")
        if decisions is None and "decisions" not in keys:  # an older row, if it had them
            decisions = r.get("decisions")
        cell = {k: r.get(k) for k in head}
        for k, kind in grid.items():
            v = cell[k]
            if v is not None and kind == TEXT and not isinstance(v, str):
                cell[k] = json.dumps(v)
            elif v is not None and kind == FLOAT:
                cell[k] = float(v)
        for d in _loaded(decisions) or ():
            out.append({**cell, **{k: d.get(k) for k in names if k not in cell}})
    return columns, out


def _plain_rows(columns: Columns, shaped: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    return [{name: plain(r.get(name), kind) for name, kind in columns} for r in shaped]


def results_rows(
    axes: Axes, rows: Sequence[Mapping[str, Any]], sweep_id: str = ""
) -> list[dict[str, Any]]:
    """The results of ``rows`` (one a run, in order) as plain JSON rows, every column of
    ``results_columns`` in each, as the Parquet table gives them back (``table_rows``);
    ``sweep_id`` (``Sweep.id``) names the sweep in each row."""
    return _plain_rows(*_results_shaped(axes, rows, sweep_id))


def decisions_rows(
    axes: Axes, rows: Sequence[Mapping[str, Any]], sweep_id: str = ""
) -> list[dict[str, Any]]:
    """Every decision of every run as plain JSON rows: one per run, unit and influence round
    (each named by its sweep and run id, as in the results)."""
    return _plain_rows(*_decisions_shaped(axes, rows, sweep_id))


def results_table(axes: Axes, rows: Sequence[Mapping[str, Any]], sweep_id: str = "") -> pa.Table:
    """The results as an Arrow table (results.parquet), typed by ``results_columns``."""
    import pyarrow as pa

    columns, shaped = _results_shaped(axes, rows, sweep_id)
    return pa.Table.from_pylist(shaped, schema=arrow_schema(columns))


def decisions_table(axes: Axes, rows: Sequence[Mapping[str, Any]], sweep_id: str = "") -> pa.Table:
    """The decisions as an Arrow table (decisions.parquet), typed by ``decisions_columns``."""
    import pyarrow as pa

    columns, shaped = _decisions_shaped(axes, rows, sweep_id)
    return pa.Table.from_pylist(shaped, schema=arrow_schema(columns))


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
    """An Arrow table's rows as plain Python and JSON values (maps as dicts)."""
    import pyarrow as pa

    nested = {f.name: f.type for f in table.schema if pa.types.is_nested(f.type)}
    rows: list[dict[str, Any]] = table.to_pylist()
    for r in rows:
        for name, typ in nested.items():
            r[name] = jsonable(r[name], typ)
    return rows


def _csv_cell(value: Any, kind: ColumnType) -> str:
    """A plain cell as CSV text: null empty, booleans ``true``/``false``, nested as JSON."""
    if value is None:
        return ""
    if is_nested(kind):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value) if not isinstance(value, float) else repr(value)


def _write_csv(path: Path, columns: Columns, rows: Sequence[Mapping[str, Any]]) -> None:
    with open(path, "w", encoding="utf-8", newline="") as f:
        out = csv.writer(f)
        out.writerow([name for name, _ in columns])
        for r in rows:
            out.writerow([_csv_cell(r.get(name), kind) for name, kind in columns])


def _write_jsonl(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    with open(path, "wb") as f:
        for r in rows:
            f.write(orjson.dumps(r) + b"\n")


def _write_columns(path: Path, results: Columns, decisions: Columns) -> None:
    text = json.dumps({"results": results, "decisions": decisions})
    path.write_text(text + "\n", encoding="utf-8")


def parquet_available() -> bool:
    """Whether this install writes and reads Parquet (pyarrow: the ``parquet`` extra)."""
    return importlib.util.find_spec("pyarrow") is not None


TABLE_FILES = ("results.jsonl", "decisions.jsonl", "results.csv", "columns.json")
PARQUET_FILES = ("results.parquet", "decisions.parquet")


def write_tables(
    axes: Axes, rows: Sequence[Mapping[str, Any]], out_dir: Path, sweep_id: str = ""
) -> list[dict[str, Any]]:
    """The sweep's tables in ``out_dir``: ``results.jsonl``, ``decisions.jsonl``,
    ``results.csv`` and their columns' types (``columns.json``) always, ``results.parquet`` and
    ``decisions.parquet`` where pyarrow is installed (else any left by an earlier write go:
    they would be stale); each written whole, then moved into place. Returns the results as
    plain rows (``results_rows``)."""
    columns, shaped = _results_shaped(axes, rows, sweep_id)
    dcolumns, dshaped = _decisions_shaped(axes, rows, sweep_id)
    results = _plain_rows(columns, shaped)
    decisions = _plain_rows(dcolumns, dshaped)
    writes: list[tuple[str, Callable[[Path], None]]] = [
        ("results.jsonl", lambda p: _write_jsonl(p, results)),
        ("decisions.jsonl", lambda p: _write_jsonl(p, decisions)),
        ("results.csv", lambda p: _write_csv(p, columns, results)),
        # each table's columns and their types: frames read from the JSON Lines get the
        # dtypes of the Parquet tables', without Arrow
        ("columns.json", lambda p: _write_columns(p, columns, dcolumns)),
    ]
    if parquet_available():
        import pyarrow as pa
        import pyarrow.parquet as pq

        def parquet(cols: Columns, table_rows: list[dict[str, Any]]) -> Callable[[Path], None]:
            table = pa.Table.from_pylist(table_rows, schema=arrow_schema(cols))
            return lambda p: pq.write_table(table, p)

        writes += [
            ("results.parquet", parquet(columns, shaped)),
            ("decisions.parquet", parquet(dcolumns, dshaped)),
        ]
    else:
        for name in PARQUET_FILES:
            (out_dir / name).unlink(missing_ok=True)
    for name, write in writes:
        tmp = out_dir / f".{name}.part"
        write(tmp)
        os.replace(tmp, out_dir / name)
    return results
