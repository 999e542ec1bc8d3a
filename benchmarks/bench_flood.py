"""A keyed gate run across processes through a router, clean and flooded by a keyless process.

    python -m benchmarks.bench_flood [--mode mixed] [--repeat 3] [--realtime 25] [--json]

Each repeat runs, in turn, a clean and a flooded run of scenario ``gate``: a fresh
``rgtbus router`` on a free loopback port, four ``rgtbus unit`` processes (a, b, c, d) as its
clients, sharing one ``--key-file`` (32 random bytes), paced with ``--realtime`` (so a flood
lasts the whole run), each writing its own log and printing its summary (``--json``); in the
flooded run also ``benchmarks.flooder --mode MODE`` (issue 50: a process without the key that
puts junk, or a replay of the run's own frames, on the run's ``tx`` keys), started right after
the units (it waits for their subscribers) and stopped (SIGTERM) once they have all ended. Every
run is bounded (``--run-timeout``) and every process is killed when it is over.

Each unit's peak RSS is sampled from /proc (VmRSS every 20 ms, and VmHWM). The tables give,
median over the repeats: wall seconds (spawn of the units to the last one's exit) clean and
flooded and their per-repeat ratio; whether every unit ended ok and decided as in the clean run
of the same repeat (its whole report: decisions, sends, decodes; not its steps), with its error
line if not; what the flooder sent by kind; what each unit dropped, by counter; peak RSS clean /
flooded.

Goal (issue 50): the flooded run ends ok on every unit, decides as the clean run, counts the
junk (never accepts it), within 1.5x of the clean run's wall time and with bounded memory.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import select
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from rgtbus.units.launch import free_ports

from benchmarks.flooder import MODES
from rgtbus.bus.base import DROP_KEYS

ROOT = Path(__file__).resolve().parent.parent
GATE = ROOT / "scenarios" / "gate.toml"
MEMBERS = ("a", "b", "c", "d")
EXE = [sys.executable, "-m", "rgtbus"]
FLOODER = [sys.executable, "-m", "benchmarks.flooder"]
RUN_TIMEOUT = 180.0  # one run, spawn to the last unit's exit
GOAL_RATIO = 1.5
POLL = 0.02  # RSS sampling period, seconds
# What a unit's summary (``bus``) counts as not taken from the wire: every drop reason the bus
# has (rgtbus.bus.base.DROP_KEYS), and the hellos it left unanswered.
DROPPED = (*DROP_KEYS, "hellos_unanswered")


def write_key(folder: Path) -> Path:
    """A fresh shared secret: 32 random bytes in ``folder/key``."""
    path = folder / "key"
    path.write_bytes(os.urandom(32))
    return path


def _env() -> dict[str, str]:
    """The children's environment: this checkout importable (benchmarks.flooder), no zenoh
    config from the user's environment."""
    env = dict(os.environ)
    env.pop("ZENOH_CONFIG", None)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    return env


def _spawn(
    argv: list[str], out: Path, err: Path, pipe_stdout: bool = False
) -> subprocess.Popen[bytes]:
    with open(err, "wb") as e:
        if pipe_stdout:
            return subprocess.Popen(
                argv,
                stdout=subprocess.PIPE,
                stderr=e,
                stdin=subprocess.DEVNULL,
                cwd=ROOT,
                env=_env(),
            )
        with open(out, "wb") as o:
            return subprocess.Popen(
                argv, stdout=o, stderr=e, stdin=subprocess.DEVNULL, cwd=ROOT, env=_env()
            )


def _readline(p: subprocess.Popen[bytes], timeout: float) -> str:
    """One line of ``p``'s piped stdout, or "" when none came within ``timeout`` seconds."""
    assert p.stdout is not None
    ready, _, _ = select.select([p.stdout], [], [], timeout)
    return p.stdout.readline().decode(errors="replace") if ready else ""


def start_router(ep: str, folder: Path, timeout: float = 60.0) -> subprocess.Popen[bytes]:
    """``rgtbus router -l ep``, once it says it is listening (bounded)."""
    p = _spawn(
        [*EXE, "router", "-l", ep], folder / "router.out", folder / "router.err", pipe_stdout=True
    )
    line = _readline(p, timeout)
    if not line.startswith("router listening"):
        stop(p)
        err = (folder / "router.err").read_text(errors="replace").strip()
        raise RuntimeError(f"router on {ep} did not start within {timeout:g} s: {line!r} {err}")
    return p


def unit_argv(
    name: str,
    ep: str,
    key: Path,
    run_id: str,
    realtime: float | None,
    folder: Path,
    extra: tuple[str, ...] = (),
) -> list[str]:
    """``rgtbus unit NAME gate`` as a client of the router at ``ep``, keyed, its own log."""
    argv = [
        *EXE,
        "unit",
        name,
        str(GATE),
        "--mode",
        "client",
        "--connect",
        ep,
        "--key-file",
        str(key),
        "--run-id",
        run_id,
        "--log",
        str(folder / f"{name}.mcap"),
        "--json",
    ]
    if realtime:
        argv += ["--realtime", f"{realtime:g}"]
    return argv + list(extra)


def start_flooder(
    ep: str,
    run_id: str,
    mode: str,
    folder: Path,
    seconds: float = RUN_TIMEOUT,
    session: str = "client",
) -> subprocess.Popen[bytes]:
    """``benchmarks.flooder`` on the router at ``ep`` (a zenoh ``session`` of that mode); its
    report in ``folder/flooder.json``."""
    argv = [
        *FLOODER,
        "--connect",
        ep,
        "--run",
        run_id,
        "--members",
        ",".join(MEMBERS),
        "--mode",
        mode,
        "--session-mode",
        session,
        "--seconds",
        f"{seconds:g}",
        "--report",
        str(folder / "flooder.json"),
    ]
    return _spawn(argv, folder / "flooder.out", folder / "flooder.err")


def stop(p: subprocess.Popen[bytes] | None, grace: float = 15.0) -> int | None:
    """SIGTERM, then SIGKILL after ``grace`` seconds: its exit status (None: never reaped)."""
    if p is None:
        return None
    if p.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            p.send_signal(signal.SIGTERM)
        try:
            p.wait(timeout=grace)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                p.kill()
    with contextlib.suppress(subprocess.TimeoutExpired, ValueError):
        p.communicate(timeout=30)
    return p.returncode


def _status_kb(pid: int) -> dict[str, int]:
    out: dict[str, int] = {}
    with contextlib.suppress(OSError), open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(("VmRSS:", "VmHWM:")):
                out[line.split(":")[0]] = int(line.split()[1])
    return out


class RssPeaks:
    """Peak resident memory (MB) of each process named, from a thread polling /proc every
    ``POLL`` seconds (VmRSS, and VmHWM: the kernel's own peak, while the process lives)."""

    def __init__(self, pids: dict[str, int]) -> None:
        self.pids = dict(pids)
        self.kb: dict[str, int] = dict.fromkeys(pids, 0)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, daemon=True)
        self._thread.start()

    def add(self, name: str, pid: int) -> None:
        self.kb.setdefault(name, 0)
        self.pids[name] = pid

    def _watch(self) -> None:
        while not self._stop.is_set():
            for name, pid in list(self.pids.items()):
                got = _status_kb(pid)
                if got:
                    self.kb[name] = max(self.kb.get(name, 0), *got.values())
            self._stop.wait(POLL)

    def close(self) -> dict[str, float]:
        self._stop.set()
        self._thread.join(timeout=10)
        return {name: round(kb / 1024, 1) for name, kb in self.kb.items()}


def _tail(path: Path) -> str:
    """The last non-empty line of a file ("" if none)."""
    with contextlib.suppress(OSError):
        lines = [x for x in path.read_text(errors="replace").splitlines() if x.strip()]
        return lines[-1] if lines else ""
    return ""


def _summary(path: Path) -> dict[str, Any] | None:
    with contextlib.suppress(OSError, ValueError):
        text = path.read_text().strip()
        if text:
            summary: dict[str, Any] = json.loads(text.splitlines()[-1])
            return summary
    return None


def decisions(summary: dict[str, Any] | None) -> Any:
    """What a unit decided and did (to compare runs): its whole report (decisions, sends,
    decodes, result), the simulated time and the world's failure; not what depends on the
    machine's timing (wall time, steps and rounds of the wait, bus counters) or the log."""
    if summary is None:
        return None
    return {k: summary.get(k) for k in ("report", "sim_seconds", "world_failure")}


def run_case(
    folder: Path,
    flood: str | None = None,
    realtime: float | None = 25.0,
    run_timeout: float = RUN_TIMEOUT,
    run_id: str | None = None,
    unit_extra: tuple[str, ...] = (),
    flooder_session: str = "client",
) -> dict[str, Any]:
    """One routed keyed gate run in ``folder`` (clean, or flooded with mode ``flood``):

    ``{"case", "wall_s", "timed_out", "units": {u: {"ok", "rc", "error", "summary",
    "rss_mb"}}, "router_rss_mb", "flooder": its report or None, "flooder_rc", "flooder_err"}``.
    Every process is stopped before it returns, whatever happened."""
    folder.mkdir(parents=True, exist_ok=True)
    key = write_key(folder)
    ep = f"tcp/127.0.0.1:{free_ports(1)[0]}"
    run_id = run_id or f"flood{os.getpid()}-{time.monotonic_ns() % 10**9}"
    router = flooder = None
    units: dict[str, subprocess.Popen[bytes]] = {}
    peaks: RssPeaks | None = None
    rc: dict[str, int | None] = {}
    timed_out = False
    t0 = time.monotonic()
    wall = 0.0
    try:
        router = start_router(ep, folder)
        peaks = RssPeaks({"router": router.pid})
        t0 = time.monotonic()
        for u in MEMBERS:
            argv = unit_argv(u, ep, key, run_id, realtime, folder, unit_extra)
            units[u] = _spawn(argv, folder / f"{u}.json", folder / f"{u}.err")
            peaks.add(u, units[u].pid)
        if flood:
            flooder = start_flooder(
                ep, run_id, flood, folder, seconds=run_timeout, session=flooder_session
            )
        deadline = t0 + run_timeout
        for u, p in units.items():
            try:
                rc[u] = p.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                timed_out = True
                break
        wall = time.monotonic() - t0
    finally:
        flooder_rc = stop(flooder)
        for u, p in units.items():
            code = stop(p, grace=10)
            rc.setdefault(u, code)
        stop(router)
        rss = peaks.close() if peaks is not None else {}
    out_units: dict[str, Any] = {}
    for u in MEMBERS:
        summary = _summary(folder / f"{u}.json")
        error = summary.get("error") if summary else None
        if error is None and rc.get(u) != 0:
            error = _tail(folder / f"{u}.err") or f"exit status {rc.get(u)}"
        out_units[u] = {
            "ok": rc.get(u) == 0 and summary is not None and not summary.get("error"),
            "rc": rc.get(u),
            "error": error,
            "summary": summary,
            "rss_mb": rss.get(u),
        }
    report = None
    if flood:
        with contextlib.suppress(OSError, ValueError):
            report = json.loads((folder / "flooder.json").read_text())
    return {
        "case": f"flooded ({flood})" if flood else "clean",
        "mode": flood,
        "run_id": run_id,
        "wall_s": round(wall, 3),
        "timed_out": timed_out,
        "units": out_units,
        "router_rss_mb": rss.get("router"),
        "flooder": report,
        "flooder_rc": flooder_rc,
        "flooder_err": _tail(folder / "flooder.err") if flood else None,
    }


def bus(case: dict[str, Any], unit: str) -> dict[str, int]:
    """A unit's bus counters in a case ({} when it printed no summary)."""
    s = case["units"][unit]["summary"]
    return dict(s.get("bus") or {}) if s else {}


def dropped(case: dict[str, Any], unit: str) -> dict[str, int]:
    """A unit's nonzero drop counters."""
    b = bus(case, unit)
    return {k: b[k] for k in DROPPED if b.get(k)}


def compare(clean: dict[str, Any], flooded: dict[str, Any]) -> dict[str, Any]:
    """The flooded run against the clean one of the same repeat."""
    same = {
        u: decisions(flooded["units"][u]["summary"]) == decisions(clean["units"][u]["summary"])
        and clean["units"][u]["summary"] is not None
        for u in MEMBERS
    }
    return {
        "ratio": flooded["wall_s"] / clean["wall_s"] if clean["wall_s"] else None,
        "same": same,
        "all_same": all(same.values()),
        "all_ok": all(flooded["units"][u]["ok"] for u in MEMBERS),
        "clean_ok": all(clean["units"][u]["ok"] for u in MEMBERS),
    }


def _med(xs: list[float | None]) -> float | None:
    ys = [x for x in xs if x is not None]
    return statistics.median(ys) if ys else None


def _f(x: float | None, fmt: str = ".2f") -> str:
    """``x`` as ``fmt`` ("-" for None); ``fmt`` "n": a count (whole, or one decimal)."""
    if x is None:
        return "-"
    if fmt == "n":
        return f"{x:.0f}" if float(x).is_integer() else f"{x:.1f}"
    return format(x, fmt)


def print_tables(
    pairs: list[tuple[dict[str, Any], dict[str, Any]]],
    args: argparse.Namespace,
    load: tuple[float, float],
) -> None:
    n = len(pairs)
    cmps = [compare(c, f) for c, f in pairs]
    print(
        f"## gate, keyed, 4 `rgtbus unit` clients of one router (--realtime {args.realtime:g}): "
        f"clean vs flooded by a keyless {args.flooder_session} (--mode {args.mode}), median of {n} "
        f"(load {load[0]:.2f} -> {load[1]:.2f}, {os.cpu_count()} CPUs)"
    )
    print()
    print(
        "| case | wall s (min / median / max) | vs clean (median of per-repeat ratios) | runs "
        "with every unit ok | runs deciding as clean (every unit) | router peak RSS MB |"
    )
    print("|---|---|---|---|---|---|")
    for i, name in enumerate(("clean", f"flooded ({args.mode})")):
        cases = [p[i] for p in pairs]
        walls = [c["wall_s"] for c in cases]
        ok = sum(all(c["units"][u]["ok"] for u in MEMBERS) for c in cases)
        ratio = "1.00x" if i == 0 else f"{_f(_med([x['ratio'] for x in cmps]))}x"
        same = "-" if i == 0 else f"{sum(x['all_same'] for x in cmps)}/{n}"
        timed = sum(c["timed_out"] for c in cases)
        note = f" ({timed} timed out)" if timed else ""
        print(
            f"| {name} | {min(walls):.2f} / {statistics.median(walls):.2f} / {max(walls):.2f}"
            f"{note} | {ratio} | {ok}/{n} | {same} | "
            f"{_f(_med([c['router_rss_mb'] for c in cases]), '.1f')} |"
        )
    print()
    print(f"### Each unit, flooded ({args.mode}) against clean")
    print()
    print(
        "| unit | ok (flooded) | decides as clean | error line (flooded, last failing repeat) "
        "| dropped, flooded (median by counter) | accepted clean / flooded (median) | peak RSS "
        "MB clean / flooded (median) |"
    )
    print("|---|---|---|---|---|---|---|")
    for u in MEMBERS:
        ok = sum(f["units"][u]["ok"] for _, f in pairs)
        same = sum(x["same"][u] for x in cmps)
        errors = [f["units"][u]["error"] for _, f in pairs if f["units"][u]["error"]]
        error = (errors[-1] or "").replace("|", "\\|") if errors else "-"
        counters = sorted({k for _, f in pairs for k in dropped(f, u)})
        meds = {k: _med([bus(f, u).get(k, 0) for _, f in pairs]) for k in counters}
        drops = (
            ", ".join(f"{k.removeprefix('dropped_')} {_f(v, 'n')}" for k, v in meds.items())
            or "none"
        )
        acc_c = _med([bus(c, u).get("accepted") for c, _ in pairs])
        acc_f = _med([bus(f, u).get("accepted") for _, f in pairs])
        rss_c = _med([c["units"][u]["rss_mb"] for c, _ in pairs])
        rss_f = _med([f["units"][u]["rss_mb"] for _, f in pairs])
        print(
            f"| {u} | {ok}/{n} | {same}/{n} | {error} | {drops} | {_f(acc_c, 'n')} / "
            f"{_f(acc_f, 'n')} | {_f(rss_c, '.1f')} / {_f(rss_f, '.1f')} |"
        )
    print()
    print(f"### The flooder (--mode {args.mode}), median of {n}")
    print()
    print(
        "| big (256 KB) | small (4 KB) | replayed | MB sent | s flooding | frames / s | "
        "matched | stopped by | its error |"
    )
    print("|---:|---:|---:|---:|---:|---:|---|---|---|")
    reps = [f["flooder"] or {} for _, f in pairs]

    def med(key: str, sub: str | None = None) -> float | None:
        return _med([(r.get(key) or {}).get(sub) if sub else r.get(key) for r in reps])

    mb = _med([r["bytes"] / 2**20 if "bytes" in r else None for r in reps])
    matched = sum(bool(r.get("matched")) for r in reps)
    stopped = ", ".join(sorted({str(r.get("stopped_by")) for r in reps}))
    errs = [f["flooder_err"] for _, f in pairs if f["flooder_err"]]
    print(
        f"| {_f(med('sent', 'big'), 'n')} | {_f(med('sent', 'small'), 'n')} | "
        f"{_f(med('sent', 'replay'), 'n')} | {_f(mb, '.1f')} | {_f(med('seconds'))} | "
        f"{_f(med('frames_per_second'), '.0f')} | {matched}/{n} | {stopped} | "
        f"{errs[-1] if errs else '-'} |"
    )
    print()
    met = [x["all_ok"] and x["all_same"] and (x["ratio"] or 99) <= GOAL_RATIO for x in cmps]
    print(
        f"- goal (every unit ok, deciding as clean, within {GOAL_RATIO}x of clean): "
        f"{sum(met)}/{n} repeats {'met' if all(met) else 'NOT met'}"
    )
    if not all(x["clean_ok"] for x in cmps):
        print("- NOTE: a clean run failed too (see --json): the machine may be overloaded")


def rows(pairs: list[tuple[dict[str, Any], dict[str, Any]]]) -> list[dict[str, Any]]:
    """One JSON row a run (repeat, case), the units' summaries cut to what the tables use."""
    out = []
    for i, (clean, flooded) in enumerate(pairs):
        cmp = compare(clean, flooded)
        for case in (clean, flooded):
            row = {k: v for k, v in case.items() if k != "units"}
            row["repeat"] = i
            row["units"] = {
                u: {
                    "ok": d["ok"],
                    "rc": d["rc"],
                    "error": d["error"],
                    "rss_mb": d["rss_mb"],
                    "bus": bus(case, u),
                    "same_as_clean": cmp["same"][u],
                    "wall_seconds": (d["summary"] or {}).get("wall_seconds"),
                }
                for u, d in case["units"].items()
            }
            if case is flooded:
                row["ratio"] = cmp["ratio"]
            out.append(row)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode", default="mixed", choices=MODES)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--realtime", type=float, default=25.0, help="the units' --realtime")
    ap.add_argument(
        "--run-timeout", type=float, default=RUN_TIMEOUT, help="bound on one run, seconds"
    )
    ap.add_argument(
        "--flooder-session",
        choices=("client", "peer"),
        default="client",
        help="the flooder's zenoh mode (default client of the router)",
    )
    ap.add_argument("--keep", metavar="DIR", help="keep every run's logs and outputs in DIR")
    ap.add_argument("--json", action="store_true", help="print the rows as JSON")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    pairs = []
    with tempfile.TemporaryDirectory(prefix="rgtbus-flood-") as tmp:
        base = Path(args.keep) if args.keep else Path(tmp)
        for i in range(args.repeat):
            clean = run_case(base / f"r{i}-clean", None, args.realtime, args.run_timeout)
            flooded = run_case(
                base / f"r{i}-{args.mode}",
                args.mode,
                args.realtime,
                args.run_timeout,
                flooder_session=args.flooder_session,
            )
            pairs.append((clean, flooded))
    load1 = os.getloadavg()[0]
    if args.json:
        print(json.dumps(rows(pairs), indent=1))
    else:
        print_tables(pairs, args, (load0, load1))


if __name__ == "__main__":
    main()
