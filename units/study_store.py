"""A study's directory (docs/studies.md, "Resumable by contract"): its manifest checked or
written, the runs finished read back (whole lines whose checksum holds), new ones appended and
flushed one by one, each point's scenario file; held by a lock while a study runs."""

from __future__ import annotations

import hashlib
import json
import os
import platform
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any

from rgtbus.units.study_spec import Study
from rgtbus.units.study_tables import RUN_COLUMNS
from rgtbus.units.sweep_store import lock_dir, write_text
from rgtbus.units.workers import one_line

from rgtbus._version import __version__
from rgtbus.errors import BadInput, IOFailure

MANIFEST = "manifest.json"
ROWS = "runs.jsonl"
LOCK = "study.lock"
VERSIONED = ("numpy", "eclipse-zenoh", "simpy")  # with rgtbus and Python: what --resume checks


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
        self.by_point: dict[int, dict[int, dict[str, Any]]] = {}  # the same rows, by point
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
        rows = out / ROWS
        if not resume and (not rows.exists() or rows.stat().st_size == 0):
            # a study that never finished a run (its pool could not start): begin it again
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
        dropped = 0
        fp = self.study.fingerprint
        try:
            with open(path, "rb") as f:
                for raw in f:  # a line at a time: the file may hold many runs
                    row = _whole(raw.decode("utf-8", errors="replace"), fp)
                    if row is None or not 0 <= row["point"] < len(self.study.points):
                        dropped += 1
                        continue
                    self._hold(row)
        except OSError as exc:
            raise IOFailure(f"cannot read {str(path)!r}: {exc.strerror}") from None
        if dropped:
            self.notes.append(
                f"{str(path)!r}: {dropped} line(s) not whole (cut by a stop) left out: their "
                "runs run again"
            )
            # the whole lines again, as they were written (one canonical form a row)
            tmp = path.with_suffix(".jsonl.tmp")
            write_text(tmp, "".join(_line(r, fp) for r in self.rows.values()))
            os.replace(tmp, path)

    def _hold(self, row: dict[str, Any]) -> None:
        self.rows[(row["point"], row["run"])] = row
        self.by_point.setdefault(row["point"], {})[row["run"]] = row

    def add(self, row: Mapping[str, Any]) -> None:
        """Keep a finished run: appended to runs.jsonl and flushed."""
        self._hold(dict(row))
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
