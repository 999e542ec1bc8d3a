"""A study's tables (docs/studies.md, "The tables"): where a point stops, what its runs say
(shares with their Wilson 95 % intervals, symbol errors beside the union bound, throughput),
the runs each point used, where a curve falls below a level, and a curve against a reference."""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rgtbus.units.study_spec import Point, Study, point_scenario
from rgtbus.units.workers import one_line

from rgtbus.errors import BadInput, IOFailure
from rgtbus.signal.evaluate import ml_ser_bounds
from rgtbus.stats import mean_interval, wilson

Z_CHECK = 3.2905267314919255  # two-sided 99.9 %: the reference check, point by point

if TYPE_CHECKING:
    import pandas as pd

# a run's row: what runs.jsonl holds and runs.csv shows (after the point's grid columns)
RUN_COLUMNS = (
    "point", "run", "seed", "steered", "clean_steered", "decision_wrong", "choice", "error",
    "id_decodes", "id_misreads", "relation_decodes", "relation_misreads",
    "relation_symbol_errors", "influence_decodes", "influence_misreads",
    "influence_symbol_errors", "repair_requests", "repair_seconds", "sim_seconds", "wall_s",
)  # fmt: skip
# a point's row (after its grid columns and sigma); the shares with their Wilson 95 % intervals
SHARES = ("p_target", "p_clean", "decision_error", "id_ser", "relation_ser", "ser", "misread")
POINT_COLUMNS = (
    "runs", "failures", "stopped", "errors", "id_decodes", "relation_decodes", "influence_decodes",
    *(c for s in SHARES for c in (s, f"{s}_lo", f"{s}_hi")),
    "relation_ser_bound", "ser_bound", "repair_requests", "repair_requests_lo",
    "repair_requests_hi", "repair_seconds", "runs_per_s",
    "decodes_per_s",
)  # fmt: skip
TIMED = ("runs_per_s", "decodes_per_s", "wall_s")  # measured time: differ from call to call


def empty_row(point: int, run: int, seed: int, error: str | None = None) -> dict[str, Any]:
    """A run's row before it ran (or one that never ran: ``error`` says why): the target not
    steered, its decision wrong, nothing decoded."""
    return {
        "point": point, "run": run, "seed": seed, "steered": False, "clean_steered": None,
        "decision_wrong": True, "choice": None, "error": error,
        **{f"{k}_{c}": 0 for k in ("id", "relation", "influence") for c in ("decodes", "misreads")},
        "relation_symbol_errors": 0, "influence_symbol_errors": 0,
        "repair_requests": 0, "repair_seconds": 0.0, "sim_seconds": 0.0, "wall_s": 0.0,
    }  # fmt: skip


# -- what a point's runs say -------------------------------------------------------------------


@dataclass(frozen=True)
class PointEnd:
    """Where a point stopped: ``runs`` used (its runs 0..runs−1), ``failures`` among them, and
    why (``failures``: the target count reached; ``budget``; ``early``: not run, an easier
    point of a chain whose harder one had no failure in its budget)."""

    runs: int
    failures: int
    stopped: str


@dataclass
class PointScan:
    """The stop rule, read as a point's runs come: runs in order, the first run that brings the
    failures to ``study.failures`` ends the point, else run ``budget − 1`` does. ``feed`` reads
    on from where it stopped (the runs read so far, ``scanned``, and their ``failures``)."""

    failures_wanted: int
    budget: int
    scanned: int = 0
    failures: int = 0

    def feed(self, rows: Mapping[int, Mapping[str, Any]]) -> PointEnd | None:
        """Where the point stops, or None while the next run it needs is missing."""
        while self.scanned < self.budget:
            row = rows.get(self.scanned)
            if row is None:
                return None
            self.scanned += 1
            self.failures += not row["steered"]
            if self.failures >= self.failures_wanted:
                return PointEnd(self.scanned, self.failures, "failures")
        return PointEnd(self.budget, self.failures, "budget")


def point_end(study: Study, rows: Mapping[int, Mapping[str, Any]]) -> PointEnd | None:
    """Where a point stops, from its rows by run index; None while a run it needs is missing
    (``PointScan``: the rule)."""
    return PointScan(study.failures, study.budget).feed(rows)


def _share(k: int, n: int, name: str) -> dict[str, float | None]:
    p, lo, hi = wilson(k, n) if n else (None, None, None)
    return {name: p, f"{name}_lo": lo, f"{name}_hi": hi}


def grid_cells(point: Point) -> dict[str, Any]:
    """A point's grid values as the tables hold them: a list or a table (``"channel.gain" =
    [{...}]``) as JSON text with its keys sorted, as a sweep's tables hold them; the rest as
    they are."""
    return {
        k: json.dumps(v, sort_keys=True) if isinstance(v, list | dict) else v
        for k, v in point.settings
    }


def point_rows(
    study: Study, ends: Mapping[int, PointEnd], rows: Mapping[tuple[int, int], Mapping[str, Any]]
) -> list[dict[str, Any]]:
    """The points table: a row a grid point in grid order, from the runs each used."""
    # the union bound of the best receiver of each family's words at the point's σ (a link of
    # gain 1): ser (the influences' words: what steers) and relation_ser (alliance/conflict)
    bounds: dict[int, tuple[float, float]] = {}
    table = []
    for p in study.points:
        end = ends.get(p.index, PointEnd(0, 0, "early"))
        used = [rows[(p.index, r)] for r in range(end.runs)]
        out: dict[str, Any] = {"point": p.index, **grid_cells(p), "sigma": p.sigma}
        out.update(runs=end.runs, failures=end.failures, stopped=end.stopped)
        out["errors"] = sum(1 for r in used if r["error"] is not None)
        for kind in ("id", "relation", "influence"):
            out[f"{kind}_decodes"] = sum(r[f"{kind}_decodes"] for r in used)
        judged = [r for r in used if r["clean_steered"] is not None]
        n = len(used)
        out.update(_share(n - end.failures, n, "p_target"))
        out.update(_share(sum(bool(r["clean_steered"]) for r in judged), len(judged), "p_clean"))
        out.update(_share(sum(bool(r["decision_wrong"]) for r in used), n, "decision_error"))
        ids = sum(r["id_decodes"] for r in used)
        out.update(_share(min(ids, sum(r["id_misreads"] for r in used)), ids, "id_ser"))
        # symbol errors: payloads read as another word (what the bound speaks of); misread:
        # every payload read otherwise than sent (another word, or for another turn or unit)
        for kind, name in (("relation", "relation_ser"), ("influence", "ser")):
            made = sum(r[f"{kind}_decodes"] for r in used)
            wrong = sum(r[f"{kind}_symbol_errors"] for r in used)
            out.update(_share(min(wrong, made), made, name))
        made = sum(r["relation_decodes"] + r["influence_decodes"] for r in used)
        wrong = sum(r["relation_misreads"] + r["influence_misreads"] for r in used)
        out.update(_share(min(wrong, made), made, "misread"))
        if p.index not in bounds:
            cb = point_scenario(study, p.index).codebook
            bounds[p.index] = (
                ml_ser_bounds(cb.relations, p.sigma).union,
                ml_ser_bounds(cb.alternatives, p.sigma).union,
            )
        out["relation_ser_bound"], out["ser_bound"] = bounds[p.index]
        # the repair's requests a run: their mean with its 95 % interval (mean ± 1.96 s/√n)
        requests = [float(r["repair_requests"]) for r in used]
        m, lo, hi = mean_interval(requests) if n else (None, None, None)
        out.update(repair_requests=m, repair_requests_lo=lo, repair_requests_hi=hi)
        out["repair_seconds"] = sum(r["repair_seconds"] for r in used) / n if n else None
        wall = math.fsum(r["wall_s"] for r in used)
        decodes = sum(r[f"{k}_decodes"] for r in used for k in ("id", "relation", "influence"))
        out["runs_per_s"] = n / wall if wall > 0 else None
        out["decodes_per_s"] = decodes / wall if wall > 0 else None
        table.append(out)
    return table


def run_rows(
    study: Study, ends: Mapping[int, PointEnd], rows: Mapping[tuple[int, int], Mapping[str, Any]]
) -> list[dict[str, Any]]:
    """The runs table: the runs each point used, in point then run order, with its grid
    columns."""
    out = []
    for p in study.points:
        end = ends.get(p.index)
        for r in range(end.runs if end else 0):
            row = dict(rows[(p.index, r)])
            out.append(
                {"point": p.index, **grid_cells(p), "sigma": p.sigma,
                 **{k: row[k] for k in RUN_COLUMNS if k != "point"}}
            )  # fmt: skip
    return out


def columns_of(study: Study, rest: Sequence[str]) -> list[str]:
    """``point``, the grid's columns, then ``rest`` (less ``point``)."""
    return ["point", *study.keys, *(c for c in rest if c != "point")]


def write_csv(frame: pd.DataFrame, path: Path) -> None:
    """A table, written whole or not at all (a temporary file renamed over it)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
            frame.to_csv(f, index=False)
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise IOFailure(f"cannot write {str(path)!r}: {exc.strerror}") from None


def read_study(out_dir: str | os.PathLike[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """A study directory's tables: (points, runs) as pandas DataFrames."""
    import pandas as pd

    out = Path(out_dir)
    tables = []
    for name in ("points.csv", "runs.csv"):
        path = out / name
        try:
            tables.append(pd.read_csv(path))
        except FileNotFoundError:
            why = f"no such table (is {str(out)!r} a finished study?)"
            raise BadInput(f"{str(path)!r}: {why}") from None
        except (OSError, ValueError) as exc:
            raise BadInput(f"{str(path)!r}: not a study table ({one_line(exc)})") from None
    return tables[0], tables[1]


def crossings(
    points: pd.DataFrame, keys: Sequence[str], level: float = 0.9, column: str = "p_target"
) -> pd.DataFrame:
    """Where each curve of ``points`` first falls below ``level`` along its channel axis (the
    last of ``keys``; from the easiest channel on: σ rising, SNR falling), linearly
    interpolated between the last point at or above it and the first below: ``crossing`` for
    the estimate, ``earliest`` and ``latest`` where the lower and upper ends of its 95 %
    interval cross (None where that curve stays above ``level`` on the points run, or starts
    below it). A row a curve, with the other axes' values."""
    import pandas as pd

    keys = list(keys)
    axis, others = keys[-1], keys[:-1]
    rising = axis != "snr_db"
    rows = []
    groups = points.groupby(others, sort=False) if others else [((), points)]
    for values, group in groups:
        values = values if isinstance(values, tuple) else (values,)
        run = group[group["runs"] > 0].sort_values(axis, ascending=rising)
        x = run[axis].astype(float).tolist()
        row: dict[str, Any] = dict(zip(others, values, strict=True))
        row["level"] = level
        for name, col in (("crossing", column), ("earliest", f"{column}_lo"),
                          ("latest", f"{column}_hi")):  # fmt: skip
            row[name] = _falls_below(x, run[col].astype(float).tolist(), level)
        rows.append(row)
    return pd.DataFrame(rows, columns=[*others, "level", "crossing", "earliest", "latest"])


def _falls_below(x: list[float], y: list[float], level: float) -> float | None:
    if not y or y[0] < level:
        return None
    for i in range(1, len(y)):
        if y[i] < level:
            x0, x1, y0, y1 = x[i - 1], x[i], y[i - 1], y[i]
            return x0 + (x1 - x0) * (y0 - level) / (y0 - y1)
    return None


# -- against a reference -----------------------------------------------------------------------


def check_reference(
    points: pd.DataFrame, reference: pd.DataFrame, keys: Iterable[str], z: float = Z_CHECK
) -> list[str]:
    """Each point of ``points`` against the reference curve's point of the same grid values
    (``keys``): P(target steered) agrees when the two Wilson intervals at ``z`` (99.9 % by
    default) overlap, both from their runs and failures: the estimate lies inside the
    reference's interval widened by what its own runs can tell, so a reduced study (fewer runs
    a point, the same seeds) is held to its own precision. At 99.9 % a point of a curve that
    did not move fails about once in a thousand, a grid of tens of points in a few hundred.
    Returns a line per point that disagrees (or has no reference point); [] when all agree."""
    keys = list(keys)
    ref = {tuple(_key(r[k]) for k in keys): r for r in reference.to_dict("records")}
    bad = []
    for row in points.to_dict("records"):
        if not row["runs"]:
            continue
        k = tuple(_key(row[c]) for c in keys)
        label = ", ".join(f"{c}={v}" for c, v in zip(keys, k, strict=True))
        r = ref.get(k)
        if r is None or not r["runs"]:
            bad.append(f"{label}: no reference point")
            continue
        p, lo, hi = wilson(int(row["runs"] - row["failures"]), int(row["runs"]), z)
        rp, rlo, rhi = wilson(int(r["runs"] - r["failures"]), int(r["runs"]), z)
        if hi < rlo or lo > rhi:
            bad.append(
                f"{label}: p_target {p:.3f} [{lo:.3f}, {hi:.3f}] of {row['runs']} runs outside "
                f"the reference's {rp:.3f} [{rlo:.3f}, {rhi:.3f}] of {r['runs']} runs"
            )
    return bad


def _key(v: Any) -> Any:
    """A grid value as both tables hold it (a CSV reads true as True, 0.10 as 0.1)."""
    if isinstance(v, str) and v in ("True", "False"):
        return v == "True"
    if isinstance(v, float) and v.is_integer():
        return int(v)
    if hasattr(v, "item"):
        return _key(v.item())
    return v
