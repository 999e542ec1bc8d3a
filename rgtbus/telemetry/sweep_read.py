"""A sweep's tables read back (``read_sweep``, ``read_results``, ``results_of``): from
Parquet where the writer wrote it, else from JSON lines with the column types it wrote
(``columns.json``); struct and map cells as ``Record`` (hashable, ordered dicts pandas can
group and merge on). The tables are written by ``sweep_tables``."""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import orjson

from rgtbus.errors import BadInput, IOFailure
from rgtbus.extras import require
from rgtbus.telemetry.sweep_tables import (
    BOOL,
    FLOAT,
    INT,
    TEXT,
    Columns,
    ColumnType,
    table_rows,
)

if TYPE_CHECKING:
    import pandas as pd


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


def _usable_frame(frame: pd.DataFrame) -> pd.DataFrame:
    for column in frame.columns:
        if frame[column].dtype == object:
            frame[column] = frame[column].map(usable, na_action="ignore")
    return frame


def read_table(path: Path) -> pd.DataFrame:
    """A sweep's Parquet table as a DataFrame whose every column pandas can group, sort,
    deduplicate and merge on: lists as tuples, structs and maps as ``Record`` dicts. Needs
    pyarrow (the ``parquet`` extra)."""
    require("pyarrow", f"reading {str(path)!r}")
    import pyarrow.parquet as pq

    return _usable_frame(pq.read_table(path).to_pandas(maps_as_pydicts="strict"))


_PYTHON_TYPES: dict[str, tuple[type, ...]] = {
    INT: (int,),
    FLOAT: (int, float),
    BOOL: (bool,),
    TEXT: (str,),
}


def _misfit(value: Any, kind: ColumnType) -> bool:
    """Whether a plain cell cannot be of ``kind`` (a row and its columns from two sources)."""
    if value is None:
        return False
    if isinstance(kind, str):
        if kind in (INT, FLOAT) and isinstance(value, bool):
            return True
        return not isinstance(value, _PYTHON_TYPES.get(kind, (object,)))
    return not isinstance(value, dict if kind[0] in ("map", "struct") else list)


def frame_of(
    rows: Sequence[Mapping[str, Any]],
    columns: Columns | Sequence[str] = (),
    where: str = "rows",
) -> pd.DataFrame:
    """Plain rows (``results_rows``, a line of ``results.jsonl`` each) as a DataFrame whose every
    column pandas can group, sort, deduplicate and merge on: lists as tuples, structs and maps
    as ``Record`` dicts. ``columns``: (name, type) pairs give each column the dtype the Parquet
    table's frame has (``read_table``: whole numbers int64, float64 with a null; yes/no bool,
    object with a null; text pandas' string dtype); bare names (or none: the first row's) leave
    the dtypes to pandas. ``where``: what the rows are, for the one-line error (RgtbusError)
    when a cell is not of its column's type."""
    import pandas as pd

    kinds = dict(c for c in columns if isinstance(c, tuple))
    names = [c[0] if isinstance(c, tuple) else c for c in columns] or (
        list(rows[0]) if rows else []
    )
    frame = pd.DataFrame.from_records(list(rows), columns=names)
    # pandas 3 reads Arrow text as its string dtype, pandas 2 as objects
    text = "str" if int(pd.__version__.split(".")[0]) >= 3 else object
    for name, kind in kinds.items():
        if name not in frame:
            continue
        values = [r.get(name) for r in rows]
        bad = next((v for v in values if _misfit(v, kind)), None)
        if bad is not None:
            raise BadInput(
                f"{where}: column {name!r} holds {bad!r}, not of its type {kind!r} "
                "(its columns.json does not fit its rows)"
            )
        nulls = any(v is None for v in values)
        if kind == INT:
            frame[name] = pd.Series(values, dtype="float64" if nulls else "int64")
        elif kind == FLOAT:
            frame[name] = pd.Series(values, dtype="float64")
        elif kind == BOOL:
            frame[name] = pd.Series(values, dtype=object if nulls else bool)
        elif kind == TEXT:
            frame[name] = pd.Series(values, dtype=text)
        else:
            frame[name] = pd.Series(values, dtype=object)
    return _usable_frame(frame)


def _read_jsonl(path: Path) -> list[dict[str, Any]]:
    rows = []
    try:
        with open(path, "rb") as f:
            for n, line in enumerate(f, 1):
                if not line.strip():
                    continue
                try:
                    row = orjson.loads(line)
                except orjson.JSONDecodeError:
                    row = None
                if not isinstance(row, dict):
                    raise BadInput(f"{path}:{n}: not a row of a sweep's table (a JSON object)")
                rows.append(row)
    except OSError as exc:
        raise IOFailure(f"cannot read {str(path)!r}: {exc.strerror}") from None
    return rows


def results_of(out: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """The results of the sweep written to ``out`` as plain rows: ``results.jsonl``, or, in a
    directory an rgtbus before it wrote, ``results.parquet`` (pyarrow)."""
    d = Path(out)
    if (d / "results.jsonl").is_file():
        return _read_jsonl(d / "results.jsonl")
    if (d / "results.parquet").is_file():
        require("pyarrow", f"reading {str(d / 'results.parquet')!r}")
        import pyarrow.parquet as pq

        return table_rows(pq.read_table(d / "results.parquet"))
    raise BadInput(f"{str(d)!r}: no results.jsonl or results.parquet (run the sweep first)")


_DECISION_COLUMNS = ("sweep", "run_id", "run", "seed", "unit", "round", "low", "high", "choice",
                     "frustrated", "wrong", "t")  # fmt: skip


class SweepTables(NamedTuple):
    """A sweep directory's tables as pandas DataFrames (``read_sweep``)."""

    results: pd.DataFrame
    decisions: pd.DataFrame


def _as_column(item: Any) -> tuple[str, ColumnType]:
    """A (name, type) pair as ``columns.json`` holds it (JSON lists for tuples)."""

    def kind(k: Any) -> ColumnType:
        if isinstance(k, str):
            return k
        if k[0] == "struct":
            return ("struct", tuple((n, kind(t)) for n, t in k[1]))
        return (k[0], *(kind(t) for t in k[1:]))

    return str(item[0]), kind(item[1])


def table_columns(out: str | os.PathLike[str], table: str) -> Columns:
    """The columns of a sweep directory's ``table`` ("results" or "decisions") with their
    types, from its ``columns.json`` (none in a directory an older rgtbus wrote)."""
    path = Path(out) / "columns.json"
    if not path.is_file():
        return []
    try:
        return [_as_column(c) for c in json.loads(path.read_text(encoding="utf-8"))[table]]
    except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
        raise IOFailure(f"{str(path)!r}: not a sweep's columns ({type(exc).__name__})") from None


def read_results(out: str | os.PathLike[str]) -> pd.DataFrame:
    """The results of the sweep written to ``out`` as a DataFrame (``read_sweep(out).results``)."""
    return frame_of(
        results_of(out), table_columns(out, "results"), str(Path(out) / "results.jsonl")
    )


def read_sweep(out: str | os.PathLike[str]) -> SweepTables:
    """``(results, decisions)`` of the sweep written to ``out`` (``sweep(..., out=DIR)`` or
    ``rgtbus sweep --out DIR``), read from ``results.jsonl`` and ``decisions.jsonl`` (no pyarrow
    needed), each column one pandas can group, sort, deduplicate and merge on (``frame_of``:
    lists as tuples, structs and maps as ``Record`` dicts). A directory an older rgtbus wrote
    (Parquet only) is read from its Parquet files (pyarrow); one without decisions gives an
    empty decisions table."""
    d = Path(out)
    results = read_results(d)
    if (d / "decisions.jsonl").is_file():
        columns = table_columns(d, "decisions") or _DECISION_COLUMNS
        decisions = frame_of(
            _read_jsonl(d / "decisions.jsonl"), columns, str(d / "decisions.jsonl")
        )
    elif (d / "decisions.parquet").is_file() and not (d / "results.jsonl").is_file():
        decisions = read_table(d / "decisions.parquet")
    else:
        decisions = frame_of([], _DECISION_COLUMNS)
    return SweepTables(results, decisions)
