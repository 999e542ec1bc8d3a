"""Running a study (docs/studies.md): Monte Carlo per grid point that stops when it knows.

Each point runs its runs in order (run r's seed: ``Study.seed_of``) until ``failures`` runs
whose target did not choose ``steer_to``, or ``budget`` runs, whichever comes first. The points
of a chain (every axis but the channel fixed) run from the hardest channel to the easiest; a
point that ends its budget with no failure ends the easier points of its chain unrun (Sionna's
early stop: they would show none either). What a point reports depends only on its runs 0..m−1
(m where it stopped), so the tables do not depend on the workers, their order, or a stop and a
resume: runs handed out past m while a point was still open are kept in ``runs.jsonl`` but left
out of the tables.

A study's directory::

    manifest.json    the study's fingerprint (its file and base scenario) and the versions of
                     rgtbus, Python, numpy, eclipse-zenoh and simpy: --resume refuses another
    runs.jsonl       every run finished, a JSON line each with its checksum (a line cut by a kill
                     is no run: it is dropped and the run runs again)
    points/point-NNN.toml   each point's scenario: rgtbus run FILE --seed SEED re-runs a row
    points.csv       a row a grid point (``POINT_COLUMNS``)
    runs.csv         a row a run of the tables (``RUN_COLUMNS``)
    study.json       what the last call did: runs computed, seconds, workers
"""

from __future__ import annotations

import collections
import contextlib
import hashlib
import json
import math
import os
import platform
import shlex
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from rgtbus.units.study_spec import (
    Point,
    Study,
    load_study,
    point_scenario,
    target_wants,
)
from rgtbus.units.sweep import run_error
from rgtbus.units.sweep_store import lock_dir, write_text
from rgtbus.units.workers import Pool, WorkerDied, one_line, open_pool

from rgtbus._version import __version__
from rgtbus.errors import BadInput, IOFailure
from rgtbus.signal.evaluate import ml_ser_bounds
from rgtbus.stats import wilson

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    "POINT_COLUMNS",
    "RUN_COLUMNS",
    "Study",
    "StudyResult",
    "check_reference",
    "crossings",
    "load_study",
    "point_rows",
    "read_study",
    "run_study",
    "study",
    "study_run",
]

MANIFEST = "manifest.json"
ROWS = "runs.jsonl"
LOCK = "study.lock"
VERSIONED = ("numpy", "eclipse-zenoh", "simpy")  # with rgtbus and Python: what --resume checks
RETRIES = 3  # a run whose worker died is handed out again, at most this often

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
    "relation_ser_bound", "ser_bound", "repair_requests", "repair_seconds", "runs_per_s",
    "decodes_per_s",
)  # fmt: skip
TIMED = ("runs_per_s", "decodes_per_s", "wall_s")  # measured time: differ from call to call


# -- one run -----------------------------------------------------------------------------------


def study_run(study: Study, point: int, run: int) -> dict[str, Any]:
    """Run ``run`` of point ``point`` (in a worker): its row. ``steered``: the target chose
    ``steer_to``; ``clean_steered``: it would have on a perfect medium (the noise-free run of
    the same scenario and seed, ``rgtbus.truth``); ``decision_wrong``: its decision differs from
    that one's (or it did not decide); decodes, misreads and symbol errors (misreads read as
    another word: ``DecodeErrors.word_errors``) by kind; the repair's requests
    and seconds. A run that raises is a row with its error (a failure of the target)."""
    from rgtbus.units.group import run_group

    from rgtbus.summary import wrong_decisions
    from rgtbus.telemetry import NullRecorder
    from rgtbus.truth import noise_free

    sc = study.scenario_of(point, run)
    row = empty_row(point, run, sc.seed)
    want = target_wants(sc, study.steer_to)
    t0 = time.perf_counter()
    try:
        clean = noise_free(sc)
        mine = clean.get(study.target, {})
        row["clean_steered"] = bool(mine.get("decided")) and mine.get("choice") == want
        out = run_group(sc, "memory", NullRecorder())
        s = out.summary
        unit = s["units"].get(study.target) or {}
        choice = unit.get("choice") if unit.get("decided") else None
        row["steered"] = s["error"] is None and choice == want
        u = sc.universe
        row["choice"] = None if choice is None else u.format(u.from_list(choice))
        wrong = wrong_decisions({study.target: unit}, clean) if unit else [study.target]
        row["decision_wrong"] = not unit.get("decided") or bool(wrong)
        row["error"] = s["error"]
        kinds = s["decode_errors"]["by_kind"]
        words = out.misreads.word_errors()
        for kind in ("id", "relation", "influence"):
            row[f"{kind}_decodes"] = sum(m.decoded.count(kind) for m in out.units)
            row[f"{kind}_misreads"] = int(kinds.get(kind, {}).get("misread", 0))
            if kind != "id":
                row[f"{kind}_symbol_errors"] = words[kind]
        repair = s.get("repair") or {}
        row["repair_requests"] = int(repair.get("requests", 0))
        row["repair_seconds"] = float(repair.get("seconds", 0.0))
        row["sim_seconds"] = float(s["sim_seconds"])
    except Exception as exc:  # a run that raises is a result of the study, never its end
        row["error"] = run_error(exc)
        row["steered"] = False
    row["wall_s"] = round(time.perf_counter() - t0, 6)
    return row


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


def point_end(study: Study, rows: Mapping[int, Mapping[str, Any]]) -> PointEnd | None:
    """Where a point stops, from its rows by run index; None while a run it needs is missing.
    The rule reads runs in order: the first run that brings the failures to ``study.failures``
    ends it, else run ``budget − 1`` does."""
    failures = 0
    for r in range(study.budget):
        row = rows.get(r)
        if row is None:
            return None
        failures += not row["steered"]
        if failures >= study.failures:
            return PointEnd(r + 1, failures, "failures")
    return PointEnd(study.budget, failures, "budget")


def _share(k: int, n: int, name: str) -> dict[str, float | None]:
    p, lo, hi = wilson(k, n) if n else (None, None, None)
    return {name: p, f"{name}_lo": lo, f"{name}_hi": hi}


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
        out: dict[str, Any] = {"point": p.index, **dict(p.settings), "sigma": p.sigma}
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
        out["repair_requests"] = sum(r["repair_requests"] for r in used) / n if n else None
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
                {"point": p.index, **dict(p.settings), "sigma": p.sigma,
                 **{k: row[k] for k in RUN_COLUMNS if k != "point"}}
            )  # fmt: skip
    return out


# -- the directory -----------------------------------------------------------------------------


def manifest_of(study: Study) -> dict[str, Any]:
    """What a study's directory is made of: its fingerprint and the versions that make a run's
    row (``--resume`` refuses any other)."""
    from importlib.metadata import PackageNotFoundError, version

    libs: dict[str, str | None] = {}
    for lib in VERSIONED:
        try:
            libs[lib] = version(lib)
        except PackageNotFoundError:
            libs[lib] = None
    return {
        "study": study.name,
        "file": study.where,
        "fingerprint": study.fingerprint,
        "seed": study.seed,
        "versions": {"rgtbus": __version__, "python": platform.python_version(), **libs},
    }


def _checksum(row: Mapping[str, Any], fingerprint: str) -> str:
    text = json.dumps(row, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(f"{fingerprint}\n{text}".encode()).hexdigest()


def _line(row: Mapping[str, Any], fingerprint: str) -> str:
    body = {k: row[k] for k in RUN_COLUMNS}
    return json.dumps({**body, "_sha256": _checksum(body, fingerprint)}, sort_keys=True) + "\n"


class StudyStore:
    """A study's directory, held (a lock) while the study runs: its manifest checked or
    written, the runs finished read back (whole lines whose checksum holds), new ones
    appended and flushed one by one."""

    def __init__(self, study: Study, out_dir: Path, resume: bool) -> None:
        self.study, self.out_dir = study, out_dir
        self.notes: list[str] = []
        self.rows: dict[tuple[int, int], dict[str, Any]] = {}
        self._lock = lock_dir(out_dir, LOCK, "study")
        try:
            self._open(resume)
            self._sink: IO[str] = open(out_dir / ROWS, "a", encoding="utf-8")  # noqa: SIM115
        except BaseException:
            self._lock.close()
            raise

    def _open(self, resume: bool) -> None:
        study, out = self.study, self.out_dir
        manifest = out / MANIFEST
        want = manifest_of(study)
        if not manifest.exists():
            if (out / ROWS).exists() or (out / "points.csv").exists():
                raise BadInput(f"{str(out)!r} holds study files but no {MANIFEST}: not a study "
                               "directory rgtbus can resume; choose another --out")  # fmt: skip
            write_text(manifest, json.dumps(want, indent=2) + "\n")
            self._write_points()
            return
        if not resume:
            raise BadInput(
                f"{str(out)!r} holds a study already: --resume (resume=True) to finish it, "
                "or choose another --out"
            )
        try:
            have = json.loads(manifest.read_text("utf-8"))
        except (OSError, ValueError) as exc:
            raise BadInput(f"{str(manifest)!r}: not a study manifest ({one_line(exc)})") from None
        if not isinstance(have, dict):
            raise BadInput(f"{str(manifest)!r}: not a study manifest (not a JSON object)")
        if have.get("fingerprint") != want["fingerprint"]:
            raise BadInput(
                f"--resume refused: {str(out)!r} was made by another study file or base "
                f"scenario (fingerprint {str(have.get('fingerprint'))[:12]}…, this study's "
                f"{want['fingerprint'][:12]}…)"
            )
        for lib, v in want["versions"].items():
            got = (have.get("versions") or {}).get(lib)
            if got != v:
                raise BadInput(
                    f"--resume refused: {str(out)!r} was made with {lib} {got}, this is {lib} "
                    f"{v}: its runs would not be this one's"
                )
        self._read_rows()

    def _write_points(self) -> None:
        where = self.out_dir / "points"
        try:
            where.mkdir(exist_ok=True)
        except OSError as exc:
            raise IOFailure(f"cannot write {str(where)!r}: {exc.strerror}") from None
        for p, text in zip(self.study.points, self.study.point_texts, strict=True):
            head = f"# {self.study.name}, point {p.index}: {p.label()} (sigma {p.sigma:g})\n"
            write_text(where / f"point-{p.index:03d}.toml", head + text)

    def _read_rows(self) -> None:
        path = self.out_dir / ROWS
        if not path.exists():
            return
        try:
            raw = path.read_bytes()
        except OSError as exc:
            raise IOFailure(f"cannot read {str(path)!r}: {exc.strerror}") from None
        good: list[str] = []
        dropped = 0
        fp = self.study.fingerprint
        for line in raw.decode("utf-8", errors="replace").splitlines(keepends=True):
            row = _whole(line, fp)
            if row is None:
                dropped += 1
                continue
            if not 0 <= row["point"] < len(self.study.points):
                dropped += 1
                continue
            self.rows[(row["point"], row["run"])] = row
            good.append(line)
        if dropped:
            self.notes.append(
                f"{str(path)!r}: {dropped} line(s) not whole (cut by a stop) left out: their "
                "runs run again"
            )
            tmp = path.with_suffix(".jsonl.tmp")
            write_text(tmp, "".join(good))
            os.replace(tmp, path)

    def add(self, row: Mapping[str, Any]) -> None:
        """Keep a finished run: appended to runs.jsonl and flushed."""
        self.rows[(row["point"], row["run"])] = dict(row)
        try:
            self._sink.write(_line(row, self.study.fingerprint))
            self._sink.flush()
        except OSError as exc:
            raise IOFailure(
                f"cannot write {str(self.out_dir / ROWS)!r} ({exc.strerror}): the runs before "
                "are kept: --resume (resume=True) to finish"
            ) from None

    def close(self) -> None:
        try:
            self._sink.close()
        finally:
            self._lock.close()

    def __enter__(self) -> StudyStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _whole(line: str, fingerprint: str) -> dict[str, Any] | None:
    """A line of runs.jsonl as its row, or None where it is not whole: cut short, not JSON, a
    field missing or its checksum off (another study's, or changed)."""
    if not line.endswith("\n"):
        return None
    try:
        got = json.loads(line)
    except ValueError:
        return None
    if not isinstance(got, dict) or any(k not in got for k in RUN_COLUMNS):
        return None
    body = {k: got[k] for k in RUN_COLUMNS}
    if got.get("_sha256") != _checksum(body, fingerprint):
        return None
    if not isinstance(body["point"], int) or not isinstance(body["run"], int):
        return None
    return body


# -- running -----------------------------------------------------------------------------------


@dataclass
class _Chain:
    points: list[Point]
    pos: int = 0
    next_run: int = 0


class _Runner:
    """Hands the runs of each chain's open point out in order and closes points as their runs
    come back; ``ends`` holds every closed point."""

    def __init__(self, study: Study, store: StudyStore, pool: Pool,
                 progress: Callable[[Point, PointEnd], None] | None) -> None:  # fmt: skip
        self.study, self.store, self.pool, self.progress = study, store, pool, progress
        self.chains = collections.deque(_Chain(c) for c in study.chains())
        self.ends: dict[int, PointEnd] = {}
        self.computed = 0
        self.tries: collections.Counter[tuple[int, int]] = collections.Counter()

    def _close_points(self) -> None:
        study = self.study
        for ch in self.chains:
            while ch.pos < len(ch.points):
                p = ch.points[ch.pos]
                runs = {r: row for (q, r), row in self.store.rows.items() if q == p.index}
                end = point_end(study, runs)
                if end is None:
                    break
                self.ends[p.index] = end
                if self.progress:
                    self.progress(p, end)
                ch.pos += 1
                ch.next_run = 0
                if end.failures == 0:  # none in its whole budget: the easier points show none
                    for q in ch.points[ch.pos :]:
                        self.ends[q.index] = PointEnd(0, 0, "early")
                        if self.progress:
                            self.progress(q, self.ends[q.index])
                    ch.pos = len(ch.points)

    def _next(self, busy: set[tuple[int, int]]) -> tuple[int, int] | None:
        """The next run to hand out, round robin over the chains; None when none is wanted."""
        for _ in range(len(self.chains)):
            ch = self.chains[0]
            self.chains.rotate(-1)
            if ch.pos >= len(ch.points):
                continue
            p = ch.points[ch.pos]
            while ch.next_run < self.study.budget:
                key = (p.index, ch.next_run)
                ch.next_run += 1
                if key not in self.store.rows and key not in busy:
                    return key
        return None

    def run(self) -> None:
        self._close_points()
        ex = self.pool.executor
        limit = max(2, 2 * self.pool.workers)
        pending: dict[Future[dict[str, Any]], tuple[int, int]] = {}
        retry: collections.deque[tuple[int, int]] = collections.deque()
        try:
            while True:
                while len(pending) < (limit if ex is not None else 1):
                    key = retry.popleft() if retry else self._next(set(pending.values()))
                    if key is None:
                        break
                    if ex is None:
                        self._keep(study_run(self.study, *key))
                        self._close_points()
                        continue
                    pending[ex.submit(study_run, self.study, *key)] = key
                if not pending:
                    if all(ch.pos >= len(ch.points) for ch in self.chains):
                        return
                    continue
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in sorted(done, key=lambda f: pending[f]):
                    key = pending.pop(fut)
                    try:
                        row = fut.result()
                    except WorkerDied as exc:
                        self.tries[key] += 1
                        if self.tries[key] < RETRIES:
                            retry.append(key)
                            continue
                        row = self._lost(key, str(exc))
                    except Exception as exc:
                        if type(exc).__name__ != "KilledWorker":
                            raise BadInput(
                                f"the {self.pool.kind} failed ({one_line(exc)}); the finished "
                                f"runs are in {str(self.store.out_dir / ROWS)!r}: --resume to "
                                "finish"
                            ) from None
                        row = self._lost(key, one_line(exc))
                    self._keep(row)
                self._close_points()
        except BaseException:
            for fut in pending:
                fut.cancel()
            raise

    def _lost(self, key: tuple[int, int], why: str) -> dict[str, Any]:
        why = f"worker died {RETRIES} times running it: {why}"
        return empty_row(*key, self.study.seed_of(*key), why)

    def _keep(self, row: dict[str, Any]) -> None:
        self.store.add(row)
        self.computed += 1


@dataclass
class StudyResult:
    """What ``study()`` returns: the points and runs tables as pandas DataFrames, the study,
    where its directory is (None: a temporary one, gone), the runs computed by this call and
    its wall seconds, and what it had to say (``notes``)."""

    study: Study
    points: pd.DataFrame
    runs: pd.DataFrame
    out: Path | None
    computed: int = 0
    seconds: float = 0.0
    notes: list[str] = field(default_factory=list)


def run_study(
    study: Study,
    out_dir: Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    progress: Callable[[Point, PointEnd], None] | None = None,
) -> StudyResult:
    """Run ``study`` into ``out_dir`` (resuming what it holds with ``resume``) on a local
    process pool (``workers``, all cores by default; 1: this process) or the Dask cluster at
    ``scheduler``; write its tables; return them. ``progress(point, end)`` as each point
    closes."""
    import pandas as pd

    t0 = time.perf_counter()
    with StudyStore(study, Path(out_dir), resume) as store:
        runs_left = len(study.points) * study.budget - len(store.rows)
        with open_pool(workers, scheduler, max(1, runs_left)) as pool:
            runner = _Runner(study, store, pool, progress)
            runner.run()
            record = pool.record()
        points = point_rows(study, runner.ends, store.rows)
        runs = run_rows(study, runner.ends, store.rows)
        seconds = time.perf_counter() - t0
        points_df = pd.DataFrame(points, columns=_columns(study, ("sigma", *POINT_COLUMNS)))
        runs_df = pd.DataFrame(runs, columns=_columns(study, ("sigma", *RUN_COLUMNS[1:])))
        _write_csv(points_df, Path(out_dir) / "points.csv")
        _write_csv(runs_df, Path(out_dir) / "runs.csv")
        info = {
            "study": study.name, "computed": runner.computed, "kept": len(store.rows),
            "runs": len(runs), "seconds": round(seconds, 3),
            "runs_per_s": round(runner.computed / seconds, 3) if seconds > 0 else None,
            "failures": study.failures, "budget": study.budget, **record,
        }  # fmt: skip
        write_text(Path(out_dir) / "study.json", json.dumps(info, indent=2) + "\n")
        return StudyResult(study, points_df, runs_df, Path(out_dir), runner.computed, seconds,
                           list(store.notes))  # fmt: skip


def _columns(study: Study, rest: Sequence[str]) -> list[str]:
    """``point``, the grid's columns, then ``rest`` (less ``point``)."""
    return ["point", *study.keys, *(c for c in rest if c != "point")]


def _write_csv(frame: pd.DataFrame, path: Path) -> None:
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


def study(
    source: str | os.PathLike[str] | Mapping[str, Any] | Study,
    *,
    out: str | os.PathLike[str] | None = None,
    failures: int | None = None,
    budget: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    progress: Callable[[Point, PointEnd], None] | None = None,
) -> StudyResult:
    """Run a study (a file, a shipped study's name, a mapping shaped like the file, or a
    ``Study``) and return its tables (``StudyResult.points``, ``.runs``). ``out``: the
    directory to keep it in (``None``: a temporary one); ``failures``, ``budget``: override
    the file's stop; ``resume``: finish a study stopped halfway. Works from a script or a
    notebook cell without a main guard (the pool's workers never import ``__main__``)."""
    st = source if isinstance(source, Study) else load_study(source)
    st = st.with_limits(failures, budget)
    if out is not None:
        return run_study(st, Path(out), workers=workers, scheduler=scheduler, resume=resume,
                         progress=progress)  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="rgtbus-study-") as tmp:
        got = run_study(st, Path(tmp), workers=workers, scheduler=scheduler, progress=progress)
        got.out = None
        return got


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
    points: pd.DataFrame, reference: pd.DataFrame, keys: Iterable[str], column: str = "p_target"
) -> list[str]:
    """Each point of ``points`` against the reference curve's point of the same grid values
    (``keys``): it agrees when its 95 % interval and the reference's overlap, i.e. its
    estimate lies inside the reference's interval widened by its own interval's reach. A
    reduced run (fewer runs a point, the same seeds) is held to what its own runs can tell.
    Returns a line per point that disagrees (or is missing from the reference); [] when all
    agree."""
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
        lo, hi, p = row[f"{column}_lo"], row[f"{column}_hi"], row[column]
        rlo, rhi = r[f"{column}_lo"], r[f"{column}_hi"]
        if hi < rlo or lo > rhi:
            bad.append(
                f"{label}: {column} {p:.3f} [{lo:.3f}, {hi:.3f}] outside the reference's "
                f"{r[column]:.3f} [{rlo:.3f}, {rhi:.3f}]"
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


def resume_command(source: str, out: Path) -> str:
    """The command that finishes a study stopped halfway."""
    return f"rgtbus study {shlex.quote(source)} --out {shlex.quote(str(out))} --resume"
