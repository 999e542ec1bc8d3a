"""A sweep's directory, the store of its results (``SweepStore``): locked while a sweep writes
it (``sweep.lock``), its rows one sealed JSON line each (``rows.jsonl``: HMAC-SHA256 under the
sweep's own key, ``sweep.key``), the sweep file, its scenario and the versions that ran it
(``sweep.json``); read back on ``resume`` (``read_rows``: every line checked, a line cut by a
kill dropped with a note). Nothing here prints: what it has to say is returned (``notes``).
The runner (``rgtbus.units.sweep``) runs what the store lacks; docs/sweeps.md says the rules.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import platform
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any, NamedTuple

from rgtbus.units.sweep_spec import TABLES_VERSION, Sweep
from rgtbus.units.workers import Pool, one_line

from rgtbus._version import __version__
from rgtbus.errors import BadInput, IOFailure, RgtbusError
from rgtbus.telemetry.sweep_tables import (
    decisions_rows,
    decisions_table,
    parquet_available,
    results_rows,
    results_table,
)

ROWS = "rows.jsonl"
LOCK = "sweep.lock"
KEY = "sweep.key"  # the sweep's secret: beside its table, never in it (mode 0600)
ROW_SEAL = "_hmac"  # each line of rows.jsonl: HMAC-SHA256 of the rest of it, keyed
ROW_DIGEST = "_sha256"  # the unkeyed digest of an older rgtbus (read, then sealed anew)
SEALS = (ROW_SEAL, ROW_DIGEST)


def _canonical(row: Mapping[str, Any]) -> str:
    """A row's canonical JSON (sorted keys, no spaces), its seal left out."""
    plain = {k: v for k, v in row.items() if k not in SEALS}
    return json.dumps(plain, sort_keys=True, separators=(",", ":"))


def row_digest(row: Mapping[str, Any], sweep_digest: str) -> str:
    """The unkeyed digest an older rgtbus sealed a line of rows.jsonl with: SHA-256 over the
    sweep's digest and the row's canonical JSON. Anyone can compute it: it finds a row edited
    by mistake or copied from another sweep, not a row forged on purpose."""
    return hashlib.sha256(f"{sweep_digest}\n{_canonical(row)}".encode()).hexdigest()


def row_seal(row: Mapping[str, Any], sweep_digest: str, key: bytes) -> str:
    """The seal a line of rows.jsonl carries: HMAC-SHA256, keyed by the sweep's secret
    (``sweep_key``), over the sweep's digest and the row's canonical JSON. Without the key no
    row can be sealed: a row forged, altered or copied from another sweep is refused."""
    import hmac

    message = f"{sweep_digest}\n{_canonical(row)}".encode()
    return hmac.new(key, message, hashlib.sha256).hexdigest()


def sweep_key(out_dir: Path, *, create: bool) -> bytes | None:
    """The sweep's secret in ``out_dir/sweep.key`` (32 random bytes, hex, readable by its
    owner alone); made when ``create`` and there is none; None when there is none."""
    path = out_dir / KEY
    try:
        text = path.read_text(encoding="ascii").strip()
    except FileNotFoundError:
        if not create:
            return None
        key = os.urandom(32)
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            with os.fdopen(fd, "w", encoding="ascii") as f:
                f.write(key.hex() + "\n")
        except OSError as exc:
            raise IOFailure(f"cannot write {str(path)!r}: {exc.strerror}") from None
        return key
    except (OSError, UnicodeDecodeError) as exc:
        raise IOFailure(f"cannot read {str(path)!r}: {one_line(exc)}") from None
    try:
        key = bytes.fromhex(text)
    except ValueError:
        key = b""
    if len(key) < 16:
        raise BadInput(f"{str(path)!r}: not a sweep's key (hex, at least 16 bytes)")
    return key


def _same(a: str, b: str) -> bool:
    """Two seals alike, compared in constant time."""
    import hmac

    return hmac.compare_digest(a.encode(), b.encode())


def sealed_line(row: Mapping[str, Any], sweep_digest: str, key: bytes) -> str:
    """A row as one line of rows.jsonl, with its seal (``row_seal``)."""
    plain = json.loads(json.dumps(row))  # what a reader gets back (keys as text, lists)
    for seal in SEALS:
        plain.pop(seal, None)
    plain[ROW_SEAL] = row_seal(plain, sweep_digest, key)
    return json.dumps(plain) + "\n"


def _short(raw: bytes, limit: int = 40) -> str:
    text = raw.decode("utf-8", "replace").strip()
    return repr(text if len(text) <= limit else text[: limit - 1] + "…")


class StoredRows(NamedTuple):
    """What ``read_rows`` found: the rows, whether rows.jsonl must be written anew, and what
    it has to say (one line each)."""

    rows: list[dict[str, Any]]
    rewrite: bool
    notes: list[str]


def read_rows(out_dir: Path, sweep_digest: str, sealed: bool | str = True) -> StoredRows:
    """The rows a sweep has written to ``out_dir`` (each with its ``_key``), in file order, and
    whether rows.jsonl must be written anew (a last line cut by a kill, dropped with a note
    in ``notes``; rows of an older rgtbus, unsealed or with unkeyed digests). Every other line must
    be a row of this sweep whose seal matches under the sweep's key (``row_seal``), and no run
    may have two rows (but a run whose worker died, run again): else one line naming
    rows.jsonl and the line. ``sealed``: True, the directory's rows carry seals (rows without
    one are refused); ``"sha256"``, they carry an older rgtbus's unkeyed digests (checked,
    then sealed anew); False, an older rgtbus's rows without either."""
    path = out_dir / ROWS
    secret = sweep_key(out_dir, create=False)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return StoredRows([], False, [])
    except OSError as exc:
        raise IOFailure(f"cannot read {str(path)!r}: {exc.strerror}") from None
    lines = data.split(b"\n")
    tail = lines.pop()  # b"" when the file ends with a newline

    def bad(n: int, why: str) -> RgtbusError:
        return BadInput(f"cannot resume: {path}:{n}: {why}")

    rewrite = False
    rows: list[dict[str, Any]] = []
    notes: list[str] = []
    seen: dict[str, tuple[int, bool]] = {}
    for n, raw in enumerate([*lines, tail], 1):
        last = n == len(lines) + 1
        if not raw.strip():
            continue
        try:
            row = json.loads(raw)
        except ValueError:
            row = None
            if not last:
                raise bad(n, f"not a row (not JSON: {_short(raw)})") from None
        if last and not isinstance(row, dict):  # cut by a kill: its run runs again
            notes.append(
                f"rgtbus sweep: {path}:{n}: a line cut short (the sweep was killed while "
                "writing it): its run runs again"
            )
            rewrite = True
            continue
        if not isinstance(row, dict):
            raise bad(n, f"not a row (a JSON object expected, got {_short(raw)})")
        seal, digest = row.pop(ROW_SEAL, None), row.pop(ROW_DIGEST, None)
        if seal is not None:
            if secret is None:
                raise bad(n, f"its seal cannot be checked: {out_dir / KEY} is missing")
            if not isinstance(seal, str) or not _same(seal, row_seal(row, sweep_digest, secret)):
                raise bad(
                    n,
                    "a row altered, forged, or of another sweep (its seal does not match "
                    "the sweep's key): remove the line to run that run again",
                )
        elif digest is not None and sealed == ROW_DIGEST.lstrip("_"):
            if digest != row_digest(row, sweep_digest):  # an older rgtbus's, unkeyed
                raise bad(
                    n,
                    "a row altered, or of another sweep (its digest does not match): "
                    "remove the line to run that run again",
                )
            rewrite = True  # sealed with the key when written anew
        elif digest is not None:
            raise bad(
                n,
                "a row with an unkeyed digest in a sweep whose rows are sealed with its key "
                "(anyone can compute that digest: forged?): remove the line to run that run "
                "again",
            )
        elif sealed:
            raise bad(
                n,
                "a row without its seal (not written by rgtbus sweep): remove the line to "
                "run that run again",
            )
        else:
            rewrite = True  # an older rgtbus's row: sealed when written anew
        key = row.get("_key")
        if isinstance(key, str):
            before = seen.get(key)
            if before is not None and not before[1]:
                raise bad(
                    n,
                    f"a second row of the run of line {before[0]} (appended twice, "
                    "or two sweeps wrote here): remove one of them",
                )
            seen[key] = (n, bool(row.get("_worker_died")))
        if last:
            rewrite = True  # whole, but its newline is missing
        rows.append(row)
    return StoredRows(rows, rewrite, notes)


def lock_dir(out_dir: Path, name: str = LOCK, what: str = "sweep") -> IO[str]:
    """Create ``out_dir`` and hold it: an exclusive ``flock`` on ``DIR/NAME`` (``sweep.lock``,
    holding this process's pid), refused at once (one line naming the holder) when another
    ``what`` (a sweep, a study) holds it. Released when the returned file is closed (or the
    process ends, however it ends)."""
    if out_dir.exists() and not out_dir.is_dir():
        raise BadInput(f"{str(out_dir)!r}: exists and is not a directory")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        f = open(out_dir / name, "a+", encoding="utf-8")  # noqa: SIM115 (held until closed)
    except OSError as exc:
        reason = exc.strerror or one_line(exc)
        raise IOFailure(f"{str(out_dir)!r}: cannot write a {what} there ({reason})") from None
    try:
        import fcntl
    except ImportError:  # no flock here: unlocked
        return f
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
            return f  # a file system without locks: unlocked
        f.seek(0)
        holder = f.read().strip() or "unknown"
        f.close()
        raise BadInput(
            f"{str(out_dir)!r} is in use by another {what} (pid {holder}): wait for it to end, "
            "or stop it"
        ) from None
    f.seek(0)
    f.truncate()
    f.write(f"{os.getpid()}\n")
    f.flush()
    return f


def write_text(path: Path, text: str) -> None:
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise IOFailure(f"cannot write {str(path)!r}: {exc.strerror or one_line(exc)}") from None


def prepare_out(
    sweep: Sweep, out_dir: Path, resume: bool
) -> tuple[list[dict[str, Any]], list[str]]:
    """Fill ``out_dir`` (created and held by ``lock_dir``) with the sweep file and versions; on
    resume, the rows already there (they must be of this sweep, intact, and fit its tables);
    and what reading them had to say."""
    rows_path = out_dir / ROWS
    stored = out_dir / "sweep.json"
    if not resume and rows_path.exists() and rows_path.stat().st_size:
        raise BadInput(
            f"{str(out_dir)!r} holds results already: --resume (resume=True) to finish that "
            "sweep, or choose another --out"
        )
    rows: list[dict[str, Any]] = []
    notes: list[str] = []
    sealed: bool | str = False
    if resume and stored.exists():
        try:
            before = json.loads(stored.read_text(encoding="utf-8"))
            if not isinstance(before, dict):
                raise ValueError("not a JSON object")
        except (OSError, ValueError) as exc:
            raise IOFailure(
                f"{str(out_dir)!r}: cannot resume: sweep.json unreadable: {exc}"
            ) from None
        if before.get("digest") != sweep.digest:
            raise BadInput(
                f"{str(out_dir)!r} holds results of another sweep (digest "
                f"{before.get('digest')}, this one {sweep.digest}): cannot resume it with "
                f"{sweep.path!r}"
            )
        if before.get("tables", 1) > TABLES_VERSION:
            raise BadInput(
                f"{str(out_dir)!r}: cannot resume: its tables are of a newer rgtbus (version "
                f"{before.get('tables')}, this one writes {TABLES_VERSION})"
            )
        seals: dict[str, bool | str] = {"hmac-sha256": True, "sha256": "sha256"}
        sealed = seals.get(str(before.get("rows")), False)
    if resume:
        rows, rewrite, notes = read_rows(out_dir, sweep.digest, sealed)
        try:  # rows of an older rgtbus (JSON text columns) are re-tabled, or refused here
            results_rows(sweep.axes, rows)
            decisions_rows(sweep.axes, rows)
            if parquet_available():
                results_table(sweep.axes, rows)
                decisions_table(sweep.axes, rows)
        except Exception as exc:
            raise BadInput(
                f"{str(out_dir)!r}: cannot resume: its rows.jsonl does not fit this rgtbus's "
                f"tables ({one_line(exc)}); "
                "run the sweep into another directory"
            ) from None
        if rewrite:  # every row sealed, a cut last line gone: written whole, then moved in
            tmp = out_dir / f".{ROWS}.part"
            key = sweep_key(out_dir, create=True)
            assert key is not None
            write_text(tmp, "".join(sealed_line(r, sweep.digest, key) for r in rows))
            os.replace(tmp, rows_path)
    write_text(out_dir / "sweep.toml", sweep.text)
    write_text(out_dir / "scenario.toml", sweep.scenario_text)
    write_versions(sweep, out_dir, None)
    return rows, notes


def write_versions(sweep: Sweep, out_dir: Path, pool: Pool | None) -> None:
    record = versions(sweep)
    if pool is not None:
        record.update(pool.record())
    write_text(out_dir / "sweep.json", json.dumps(record, indent=2) + "\n")


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
        "rows": "hmac-sha256",  # each line of rows.jsonl carries its seal (row_seal)
        "rgtbus": __version__,
        "python": platform.python_version(),
        "libraries": libs,
    }


class SweepStore:
    """A sweep's directory while a sweep writes it: locked, the rows there so far (``have``:
    run key -> row), what is left to run (``todo``), and what reading it had to say
    (``notes``: one line each, for the caller to show)."""

    def __init__(self, sweep: Sweep, out_dir: Path, resume: bool) -> None:
        self.sweep, self.out_dir = sweep, out_dir
        self._lock = lock_dir(out_dir)
        try:
            done_rows, self.notes = prepare_out(sweep, out_dir, resume)
            secret = sweep_key(out_dir, create=True)
        except BaseException:
            self._lock.close()
            raise
        assert secret is not None
        self.key = secret  # every row this sweep writes is sealed with it
        self.tasks = sweep.tasks()
        by_key = {t.key: t for t in self.tasks}
        self.have: dict[str, dict[str, Any]] = {}
        for r in done_rows:
            key = r.pop("_key", None)
            if key in by_key:
                r["run"] = by_key[key].index  # the run's place in this sweep
                self.have[key] = r  # a later row of a run (run again) replaces the earlier
        for key in [k for k, r in self.have.items() if r.get("_worker_died")]:
            del self.have[key]  # its worker died under it: run it again
        self.todo = [t for t in self.tasks if t.key not in self.have]

    def close(self) -> None:
        self._lock.close()

    def __enter__(self) -> SweepStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
