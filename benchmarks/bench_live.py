"""Live view: its cost on a run, its latency to a client, and ``rgtbus info`` on a large log.

    python -m benchmarks.bench_live [--repeat 5] [--latency-repeat 1] [--latency-until 25]
                                    [--big-units 14] [--big-log PATH]

Every live measurement has a real Foxglove WebSocket client (tests/live_client.py, in a process
of its own, as Foxglove would be) subscribed to every advertised topic before the run starts.
Runs are in-process over the memory bus with the event engine, each logging to an MCAP file
(zstd, the default recorder).

1. Cost, unpaced (no ``--realtime``): the gate (scenarios/gate.toml, 4 units) and crowd10
   (scenarios/crowd10.toml, 10 units) with the live view against the same run without it (the
   baseline). Timed: ``run_group`` plus the recorder's close; not the server's start-up, the
   client's connection or ``LiveView.close``. Each pass runs every case both ways in turn (one
   untimed warm-up of each first); the table shows medians over ``--repeat`` passes and the
   ratio of the medians. "client done": from the run's start until the client had the last
   message (``/run``); "client got all": the client's message count against the log's.
2. Latency at realtime 1: a message of log time t is due at ``LiveView.due_wall(t)``; its
   latency is the client's receipt (``time.monotonic()``, one clock for both processes on
   Linux) minus that. The gate lasts 162 simulated s, so it is cut: its ``timing.max_seconds``
   is set to ``--latency-until`` (25 s) and the run ends there as failed (the units notice at
   their next step, a few simulated seconds later); every message the client gets, the last
   ones included, is counted. cograph_group (3 units, 27.6 simulated s) is a whole run that
   succeeds. Figures pool every message of ``--latency-repeat`` runs. Some messages are written
   after they are due (the event engine logs a spike when a unit next advances, not at its
   sample; the run's start-up comes after ``begin()``): those written more than 50 ms late are
   counted apart ("written late"), and the live view's own part, receipt minus max(due,
   written), is shown too.
3. ``rgtbus info`` on a log of >= 100 MB: a concurrent group of ``--big-units`` units
   (bench_scale's seeded group, 14 units: ~120 MB) run once with ``--traces``. Timed:
   ``log_info(path)`` in-process, ``python -m rgtbus info LOG`` as a subprocess (wall, with the
   interpreter's start-up, shown apart), and the baseline: a full sequential read of the same
   log (``make_reader(f).iter_messages()``, counting messages). Medians of ``--repeat``.

Goals (issue 13): live / no-live wall <= 1.3x (gate and a 10-unit group, a client subscribed
to everything); event-to-client latency at realtime 1 under 50 ms (median); ``rgtbus info`` on
a ~100 MB log under 1 s.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict, deque
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
LATE = 0.05  # s: a message written this long after it was due counts as written late


# -- the client, in a process of its own -------------------------------------------------------


def client_main(url: str, out: str, timeout: float) -> None:
    """Collect everything until ``/run``; write [[topic, log time ns, receipt], ...] to ``out``."""
    sys.path.insert(0, str(ROOT / "tests"))
    from live_client import collect_sync

    got = collect_sync(url, until_topic="/run", timeout=timeout)
    rows = [[topic, t, received] for topic, t, _, received in got.messages]
    Path(out).write_text(json.dumps(rows))


class Client:
    """``python -m benchmarks.bench_live --client URL``: started, then waited for."""

    def __init__(self, url: str, out: Path, timeout: float) -> None:
        self.out = out
        argv = [sys.executable, "-m", "benchmarks.bench_live", "--client", url, str(out)]
        argv += ["--client-timeout", repr(timeout)]
        self.proc = subprocess.Popen(argv, cwd=ROOT, stderr=subprocess.PIPE, text=True)

    def result(self) -> list[tuple[str, int, float]]:
        _, err = self.proc.communicate(timeout=600)
        if self.proc.returncode != 0:
            raise SystemExit(f"live client failed: {err.strip()[-800:]}")
        return [(topic, int(t), float(r)) for topic, t, r in json.loads(self.out.read_text())]


class StampedSink:
    """A live sink that notes when each message was written, then hands it to the live view."""

    def __init__(self, live: Any) -> None:
        self.live = live
        self.written: dict[tuple[str, int], deque[float]] = defaultdict(deque)

    def put(self, topic: str, schema: str, data: bytes, t_ns: int) -> None:
        self.written[(topic, t_ns)].append(time.monotonic())
        self.live.put(topic, schema, data, t_ns)


# -- one run ----------------------------------------------------------------------------------


def log_count(path: Path) -> int:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages())


def run_once(
    sc: Any, d: Path, *, live: bool, realtime: float | None = None, stamp: bool = False
) -> dict[str, Any]:
    """One run of ``sc`` logged to a file in ``d``, with a live view and its client or not."""
    from rgtbus.units.group import run_group

    from rgtbus.cli.run_cmd import live_topics
    from rgtbus.telemetry import McapRecorder
    from rgtbus.telemetry.live import LiveView

    log = d / "run.mcap"
    view = client = sink = None
    if live:
        view = LiveView("127.0.0.1", 0, realtime=realtime)
        view.advertise(live_topics(sc.units, traces=False))
        client = Client(view.url, d / "client.json", 600.0)
        if not view.wait_for_client(30):
            view.close()
            raise SystemExit("live client did not subscribe within 30 s")
        sink = StampedSink(view) if stamp else view
    try:
        with open(log, "wb") as stream:
            if view is not None:
                view.begin()
            recorder = McapRecorder(stream, live=sink)
            t0, t0_mono = time.perf_counter(), time.monotonic()
            out = run_group(sc, "memory", recorder, realtime=realtime)
            recorder.close()
            wall = time.perf_counter() - t0
    finally:
        if view is not None:
            view.close()
    r: dict[str, Any] = {"wall": wall, "logged": log_count(log), "summary": out.summary}
    if client is not None and view is not None:
        got = client.result()
        r["got"] = got
        r["client_done"] = max(rec for _, _, rec in got) - t0_mono if got else float("nan")
        r["due"] = view.due_wall
        if isinstance(sink, StampedSink):
            r["written"] = sink.written
    return r


# -- the three parts ---------------------------------------------------------------------------


def part_cost(d: Path, repeat: int) -> None:
    from rgtbus.scenario import load_scenario

    cases = [(n, load_scenario(ROOT / "scenarios" / f"{n}.toml")) for n in ("gate", "crowd10")]
    for _, sc in cases:  # warm-up, untimed: imports, caches, the server's first start
        run_once(sc, d, live=False)
        run_once(sc, d, live=True)
    walls: dict[tuple[str, bool], list[float]] = defaultdict(list)
    done: dict[str, list[float]] = defaultdict(list)
    counts: dict[str, list[tuple[int, int]]] = defaultdict(list)
    for _ in range(repeat):
        for name, sc in cases:
            for live in (False, True):
                r = run_once(sc, d, live=live)
                walls[(name, live)].append(r["wall"])
                if live:
                    done[name].append(r["client_done"])
                    counts[name].append((len(r["got"]), r["logged"]))
    print(
        f"## Live view cost, unpaced (median of {repeat} passes, both ways in each pass, "
        "memory bus, event engine, MCAP log, a WebSocket client on every topic)"
    )
    print()
    print(
        "| scenario | units | messages | no live s | live s | live / no live | "
        "client done s | client got all |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name, sc in cases:
        base = statistics.median(walls[(name, False)])
        lv = statistics.median(walls[(name, True)])
        allgot = all(g == n for g, n in counts[name])
        g, n = counts[name][-1]
        print(
            f"| {name} | {len(sc.units)} | {n} | {base:.3f} | {lv:.3f} | {lv / base:.2f}x | "
            f"{statistics.median(done[name]):.3f} | {'yes' if allgot else 'NO'} ({g}/{n}) |"
        )
    print()
    print(
        "Per pass (s, no live / live): "
        + "; ".join(
            f"{name} "
            + " ".join(
                f"{a:.3f}/{b:.3f}"
                for a, b in zip(walls[(name, False)], walls[(name, True)], strict=True)
            )
            for name, _ in cases
        )
    )
    print()


def _pct(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, max(0, round(q * (len(s) - 1))))]


def part_latency(d: Path, repeat: int, until: float) -> None:
    from rgtbus.scenario import load_scenario, parse_scenario

    gate = (ROOT / "scenarios" / "gate.toml").read_text()
    assert "[timing]\n" in gate and "max_seconds" not in gate
    cut = gate.replace("[timing]\n", f"[timing]\nmax_seconds = {until!r}\n", 1)
    cases = [
        (f"gate, cut at {until:g} s", parse_scenario(cut, "gate-cut")),
        ("cograph_group, whole run", load_scenario(ROOT / "scenarios" / "cograph_group.toml")),
    ]
    print(
        f"## Event-to-client latency at realtime 1 (every message of {repeat} run(s) a case, "
        "pooled; ms)"
    )
    print()
    print(
        "| case | simulated s | messages (client/log) | median | p95 | max | written late | "
        "live view part: median | p95 | max |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for label, sc in cases:
        lat: list[float] = []
        own: list[float] = []
        late = got_n = logged = 0
        sim = 0.0
        for _ in range(repeat):
            r = run_once(sc, d, live=True, realtime=1.0, stamp=True)
            sim = r["summary"]["sim_seconds"]
            got_n += len(r["got"])
            logged += r["logged"]
            for topic, t, received in r["got"]:
                due = r["due"](t)
                written = r["written"][(topic, t)].popleft()
                lat.append(1000 * (received - due))
                own.append(1000 * (received - max(due, written)))
                late += written - due > LATE
        print(
            f"| {label} | {sim:.1f} | {got_n}/{logged} | {statistics.median(lat):.1f} | "
            f"{_pct(lat, 0.95):.1f} | {max(lat):.1f} | {late} ({100 * late / len(lat):.0f} %) | "
            f"{statistics.median(own):.1f} | {_pct(own, 0.95):.1f} | {max(own):.1f} |"
        )
    print()
    print(
        "Latency: receipt minus due (origin + t / realtime). Written late: messages the run "
        f"wrote more than {1000 * LATE:.0f} ms after they were due (their latency is the "
        "engine's, not the live view's); live view part: receipt minus max(due, written)."
    )
    print()


def make_big_log(path: Path, units: int) -> float:
    from rgtbus.units.group import run_group

    from benchmarks.bench_scale import scale_toml
    from rgtbus.scenario import parse_scenario
    from rgtbus.telemetry import McapRecorder

    sc = parse_scenario(scale_toml(units, "concurrent"), f"<scale{units}>")
    t0 = time.perf_counter()
    with open(path, "wb") as stream:
        recorder = McapRecorder(stream)
        run_group(sc, "memory", recorder, traces=True)
        recorder.close()
    return time.perf_counter() - t0


def _timed(argv: list[str]) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed: {proc.stderr.strip()[-800:]}")
    return wall


def part_info(d: Path, repeat: int, units: int, big_log: str | None) -> None:
    from mcap.reader import make_reader

    from rgtbus.telemetry.logtools import log_info

    if big_log:
        path, made = Path(big_log), "given"
    else:
        path = d / f"scale{units}-traces.mcap"
        made = f"{units} units with --traces, made in {make_big_log(path, units):.1f} s"
    size = path.stat().st_size
    walls: dict[str, list[float]] = defaultdict(list)
    info: dict[str, Any] = {}
    count = 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        info = log_info(path)
        walls["info"].append(time.perf_counter() - t0)
        walls["cli"].append(_timed([sys.executable, "-m", "rgtbus", "info", str(path)]))
        walls["python"].append(_timed([sys.executable, "-c", "pass"]))
        t0 = time.perf_counter()
        with open(path, "rb") as f:
            count = sum(1 for _ in make_reader(f).iter_messages())
        walls["read"].append(time.perf_counter() - t0)
    assert info["messages"] == count, (info["messages"], count)
    med = {k: statistics.median(v) for k, v in walls.items()}
    print(
        f"## rgtbus info on a large log ({size / 1e6:.1f} MB, {count} messages, "
        f"{info['chunks']} chunks; {made}; median of {repeat})"
    )
    print()
    print("| what | s | / full read |")
    print("|---|---|---|")
    rows = [
        ("full sequential read (`iter_messages`, baseline)", med["read"]),
        ("`log_info(path)` in-process", med["info"]),
        ("`python -m rgtbus info LOG` (subprocess wall)", med["cli"]),
        ("interpreter start-up alone (`python -c pass`)", med["python"]),
    ]
    for what, s in rows:
        print(f"| {what} | {s:.3f} | {s / med['read']:.4f}x |")
    print()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="passes; tables show medians")
    ap.add_argument("--latency-repeat", type=int, default=1, help="realtime runs per case")
    ap.add_argument("--latency-until", type=float, default=25.0, help="gate cut (simulated s)")
    ap.add_argument("--big-units", type=int, default=14, help="units of the large log's group")
    ap.add_argument("--big-log", metavar="PATH", help="time info on this log instead")
    ap.add_argument("--parts", default="1,2,3", help="which parts to run, e.g. 1,3")
    ap.add_argument("--client", nargs=2, metavar=("URL", "OUT"), help=argparse.SUPPRESS)
    ap.add_argument("--client-timeout", type=float, default=600.0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.client:
        client_main(args.client[0], args.client[1], args.client_timeout)
        return
    parts = {p.strip() for p in args.parts.split(",")}
    print(f"{os.cpu_count()} cores; load average {os.getloadavg()[0]:.2f} at the start")
    print()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        if "1" in parts:
            part_cost(d, args.repeat)
        if "2" in parts:
            part_latency(d, args.latency_repeat, args.latency_until)
        if "3" in parts:
            part_info(d, args.repeat, args.big_units, args.big_log)


if __name__ == "__main__":
    main()
