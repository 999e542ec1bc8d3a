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
import json
import os
import shlex
import tempfile
import time
from collections.abc import Callable, Mapping
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rgtbus.units.study_spec import (
    Point,
    RunTask,
    Study,
    load_study,
    run_task,
    target_wants,
)
from rgtbus.units.study_store import ROWS, StudyStore
from rgtbus.units.study_tables import (
    POINT_COLUMNS,
    RUN_COLUMNS,
    TIMED,
    PointEnd,
    PointScan,
    check_reference,
    columns_of,
    crossings,
    empty_row,
    point_end,
    point_rows,
    read_study,
    run_rows,
    write_csv,
)
from rgtbus.units.sweep import run_error
from rgtbus.units.sweep_store import write_text
from rgtbus.units.workers import Pool, WorkerDied, one_line, open_pool

from rgtbus.errors import BadInput

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    "POINT_COLUMNS",
    "RUN_COLUMNS",
    "TIMED",
    "Point",
    "PointEnd",
    "RunTask",
    "Study",
    "StudyResult",
    "check_reference",
    "crossings",
    "load_study",
    "point_end",
    "point_rows",
    "read_study",
    "run_study",
    "study",
    "study_run",
]

RETRIES = 3  # a run whose worker died is handed out again, at most this often


# -- one run -----------------------------------------------------------------------------------


def study_run(task: RunTask) -> dict[str, Any]:
    """Run a study's run (in a worker): its row. ``steered``: the target chose
    ``steer_to``; ``clean_steered``: it would have on a perfect medium (the noise-free run of
    the same scenario and seed, ``rgtbus.truth``); ``decision_wrong``: its decision differs from
    that one's (or it did not decide); decodes, misreads and symbol errors (misreads read as
    another word: ``DecodeErrors.word_errors``) by kind; the repair's requests
    and seconds. A run that raises is a row with its error (a failure of the target)."""
    from rgtbus.units.group import run_group

    from rgtbus.summary import wrong_decisions
    from rgtbus.telemetry import NullRecorder
    from rgtbus.truth import noise_free

    sc = task.scenario_of()
    row = empty_row(task.point, task.run, sc.seed)
    want = target_wants(sc, task.steer_to)
    target = task.target
    t0 = time.perf_counter()
    try:
        out = run_group(sc, "memory", NullRecorder())
        s = out.summary
        # the perfect medium's decisions: the summary's where it judged the run by them
        clean = s.get("noise_free") or noise_free(sc)
        mine = clean.get(target, {})
        row["clean_steered"] = bool(mine.get("decided")) and mine.get("choice") == want
        unit = s["units"].get(target) or {}
        choice = unit.get("choice") if unit.get("decided") else None
        row["steered"] = s["error"] is None and choice == want
        u = sc.universe
        row["choice"] = None if choice is None else u.format(u.from_list(choice))
        wrong = wrong_decisions({target: unit}, clean) if unit else [target]
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


# -- running -----------------------------------------------------------------------------------


@dataclass
class _Chain:
    points: list[Point]
    scan: PointScan  # the open point's stop rule, read as far as its runs have come
    pos: int = 0
    next_run: int = 0


class _Runner:
    """Hands the runs of each chain's open point out in order and closes points as their runs
    come back; ``ends`` holds every closed point."""

    def __init__(self, study: Study, store: StudyStore, pool: Pool,
                 progress: Callable[[Point, PointEnd], None] | None,
                 on_run: Callable[[], None] | None = None) -> None:  # fmt: skip
        self.study, self.store, self.pool, self.progress = study, store, pool, progress
        self.on_run = on_run
        self.chains = collections.deque(_Chain(c, self._scan()) for c in study.chains())
        self.ends: dict[int, PointEnd] = {}
        self.computed = 0
        self.tries: collections.Counter[tuple[int, int]] = collections.Counter()

    def _scan(self) -> PointScan:
        return PointScan(self.study.failures, self.study.budget)

    def _close_points(self) -> None:
        for ch in self.chains:
            while ch.pos < len(ch.points):
                p = ch.points[ch.pos]
                end = ch.scan.feed(self.store.by_point.get(p.index, {}))
                if end is None:
                    break
                self.ends[p.index] = end
                if self.progress:
                    self.progress(p, end)
                ch.pos += 1
                ch.next_run = 0
                ch.scan = self._scan()
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
                        self._keep(study_run(run_task(self.study, *key)))
                        self._close_points()
                        continue
                    pending[ex.submit(study_run, run_task(self.study, *key))] = key
                if not pending:  # nothing out and nothing to hand out: every point closed
                    self._close_points()
                    open_points = [ch.points[ch.pos].label() for ch in self.chains
                                   if ch.pos < len(ch.points)]  # fmt: skip
                    if open_points:  # a run neither kept nor out: a fault of the runner
                        raise RuntimeError(f"study runner stalled at {', '.join(open_points)}")
                    return
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
        if self.on_run:
            self.on_run()


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
    on_run: Callable[[], None] | None = None,
) -> StudyResult:
    """Run ``study`` into ``out_dir`` (resuming what it holds with ``resume``) on a local
    process pool (``workers``, all cores by default; 1: this process) or the Dask cluster at
    ``scheduler``; write its tables; return them. ``progress(point, end)`` as each point
    closes, ``on_run()`` as each run is kept."""
    import pandas as pd

    t0 = time.perf_counter()
    with StudyStore(study, Path(out_dir), resume) as store:
        runs_left = len(study.points) * study.budget - len(store.rows)
        with open_pool(workers, scheduler, max(1, runs_left)) as pool:
            runner = _Runner(study, store, pool, progress, on_run)
            runner.run()
            record = pool.record()
        points = point_rows(study, runner.ends, store.rows)
        runs = run_rows(study, runner.ends, store.rows)
        seconds = time.perf_counter() - t0
        points_df = pd.DataFrame(points, columns=columns_of(study, ("sigma", *POINT_COLUMNS)))
        runs_df = pd.DataFrame(runs, columns=columns_of(study, ("sigma", *RUN_COLUMNS[1:])))
        write_csv(points_df, Path(out_dir) / "points.csv")
        write_csv(runs_df, Path(out_dir) / "runs.csv")
        info = {
            "study": study.name, "computed": runner.computed, "kept": len(store.rows),
            "runs": len(runs), "seconds": round(seconds, 3),
            "runs_per_s": round(runner.computed / seconds, 3) if seconds > 0 else None,
            "failures": study.failures, "budget": study.budget, **record,
        }  # fmt: skip
        write_text(Path(out_dir) / "study.json", json.dumps(info, indent=2) + "\n")
        return StudyResult(study, points_df, runs_df, Path(out_dir), runner.computed, seconds,
                           list(store.notes))  # fmt: skip


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


def resume_command(source: str, out: Path) -> str:
    """The command that finishes a study stopped halfway."""
    return f"rgtbus study {shlex.quote(source)} --out {shlex.quote(str(out))} --resume"
