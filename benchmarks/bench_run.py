"""The protocol simulation: the event engine against the time-stepped reference, in one run.

    python -m benchmarks.bench_run [--sizes 4,6,8,10,12,14] [--repeat 5] [--pairs 3] [--quick]

Every run is a fresh process, so no cache of one run helps another: the gate and group6
(scenario files) and generated groups of n units (serial schedule, codes of the fewest pulses,
at least 4, that fit n channels in an octave, automatic plan), on both engines over the memory
bus without a log. The machine's speed drifts, so figures are taken as drift cannot bias them:
the event engine in --repeat rounds, each running every case once (median per case); the
ratio to the reference pair by pair, an event and a reference run in turn (median of --pairs).
Reported per case: simulated seconds, wall seconds of the simulation, their ratio, peak RSS
and the world's steps; then the slope of log wall over log n (the event engine, n = 4…14),
and the costs of zenoh and of the full MCAP log.

Goals (issue 9): group10 at least 30x faster than ``--engine dense``; the gate's simulation
under 0.1 s; the exponent of wall time over n = 4…14 at most 2.5; n = 10 under 60 MB peak RSS.
"""

from __future__ import annotations

import argparse
import io
import json
import random
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def group_scenario(n: int, seed: int = 10):
    """The scenario of ``group_toml``."""
    from rgtbus.scenario import parse_scenario

    return parse_scenario(group_toml(n, seed), f"<group{n}>")


def group_toml(n: int, seed: int = 10) -> str:
    """The scenario file of n units on an automatic plan with generated codes of the fewest
    pulses (at least 4) that fit n channels in an octave, fixed relationships forming a random
    decomposable group, random influences."""
    from rgtbus.rgt import polynomial_to_graph, random_polynomial
    from rgtbus.rgt.algebra import Universe
    from rgtbus.signal.plan import max_units

    pulses = next(p for p in range(4, 64) if max_units(p) >= n)

    rng = random.Random(seed)
    units = [f"u{i}" for i in range(n)]
    graph = polynomial_to_graph(random_polynomial(units, rng), units)
    u = Universe(("alpha", "beta"))
    lines = [
        f'name = "group{n}"',
        f"seed = {seed}",
        f"units = {units!r}".replace("'", '"'),
        'actions = ["alpha", "beta"]',
        'frequencies = "auto"',
        "[timing]",
        "max_seconds = 100000.0",  # 14 units take about an hour of simulated time
        "[codebook]",
        'kind = "generated"',
        f"pulses = {pulses}",
        "[relations]",
        'policy = "fixed"',
        "[relations.fixed]",
    ]
    for s in units:
        for r in units:
            if s != r:
                rel = "alliance" if graph.allied(s, r) else "conflict"
                lines.append(f'"{s}>{r}" = "{rel}"')
    lines.append("[influences]")
    for s in units:
        for r in units:
            if s != r:
                lines.append(f'"{s}>{r}" = "{u.format(rng.randrange(4))}"')
    return "\n".join(lines) + "\n"


def load_case(case: str):
    from rgtbus.scenario import load_scenario

    if case.startswith("n="):
        return group_scenario(int(case[2:]))
    return load_scenario(ROOT / "scenarios" / f"{case}.toml")


def _median(runs: list[dict]) -> dict:
    out = dict(runs[0])
    for key in ("wall", "rss_mb"):
        out[key] = statistics.median(r[key] for r in runs)
    return out


def label(case: str) -> str:
    return f"generated, {case[2:]} units" if case.startswith("n=") else f"{case}.toml"


def one(case: str, engine: str, bus: str, log: bool, repeat: int) -> dict:
    """In a child process: the simulation's wall (median of ``repeat``) and the peak RSS."""
    from rgtbus.units.group import run_group

    from rgtbus.telemetry import McapRecorder, NullRecorder

    sc = load_case(case)
    walls = []
    out = None
    size = 0
    for _ in range(repeat):
        buf = io.BytesIO()
        rec = McapRecorder(buf) if log else NullRecorder()
        t0 = time.perf_counter()
        out = run_group(sc, bus, rec, engine=engine)
        rec.close()
        walls.append(time.perf_counter() - t0)
        size = len(buf.getvalue())
    assert out is not None
    s = out.summary
    return {
        "wall": statistics.median(walls),
        "sim": s["sim_seconds"],
        "steps": s["steps"],
        "error": s["error"],
        "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "log_mb": size / 1e6,
    }


def measure(case: str, engine: str, bus: str = "memory", log: bool = False, repeat: int = 1):
    """The median over ``repeat`` fresh processes (a process's caches never help a repeat)."""
    argv = [sys.executable, "-m", "benchmarks.bench_run", "--one", case, engine, bus]
    argv += ["--log" if log else "--no-log", "--repeat", "1"]
    runs = []
    for _ in range(repeat):
        proc = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=3600)
        if proc.returncode != 0:
            raise SystemExit(f"{case} {engine} failed: {proc.stderr.strip()[-500:]}")
        r = json.loads(proc.stdout)
        if r["error"]:
            raise SystemExit(f"{case} {engine}: the run failed: {r['error']}")
        runs.append(r)
    return _median(runs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="4,6,8,10,12,14", help="generated group sizes")
    ap.add_argument(
        "--repeat", type=int, default=5, help="event-engine runs a case, each a fresh process"
    )
    ap.add_argument("--pairs", type=int, default=3, help="event/reference pairs a case, n <= 10")
    ap.add_argument("--quick", action="store_true", help="sizes 4,6,8; the reference to n = 6")
    ap.add_argument("--one", nargs=3, metavar=("CASE", "ENGINE", "BUS"), help=argparse.SUPPRESS)
    ap.add_argument("--log", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--no-log", dest="log", action="store_false", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        case, engine, bus = args.one
        print(json.dumps(one(case, engine, bus, args.log, args.repeat)))
        return
    sizes = [4, 6, 8] if args.quick else [int(x) for x in args.sizes.split(",")]
    dense_upto = 6 if args.quick else max(sizes)

    cases = ["gate", "group6", *(f"n={n}" for n in sizes)]
    # The machine's speed drifts: every round runs every case once, so drift hits all sizes
    # alike, and each case's figure is the median over the rounds.
    runs: dict[str, list[dict]] = {c: [] for c in cases}
    for _ in range(args.repeat):
        for case in cases:
            runs[case].append(measure(case, "event"))
    event = {c: _median(rs) for c, rs in runs.items()}
    print("## Event engine vs the time-stepped reference (memory bus, no log, fresh processes)")
    print()
    print(
        "| case | units | simulated s | dense wall s | event wall s | dense / event | "
        "event steps | event peak MB | dense peak MB |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    points = []
    for case in cases:
        n = len(load_case(case).units)
        ev = event[case]
        ratio, de = "-", None
        if n <= dense_upto:
            # the reference and the event engine in turn; the ratio taken pair by pair
            pairs = args.pairs if n <= 10 else 1
            ratios, dense_runs = [], []
            for _ in range(pairs):
                e1 = measure(case, "event")
                d1 = measure(case, "dense")
                if d1["sim"] != e1["sim"]:
                    raise SystemExit(f"{case}: the engines disagree ({e1['sim']} vs {d1['sim']} s)")
                ratios.append(d1["wall"] / e1["wall"])
                dense_runs.append(d1)
            de = _median(dense_runs)
            ratio = f"{statistics.median(ratios):.1f}x"
        if case.startswith("n="):
            points.append((n, ev["wall"], ev["sim"]))
        print(
            f"| {label(case)} | {n} | {ev['sim']:.1f} | "
            f"{de['wall'] if de else float('nan'):.2f} | {ev['wall']:.3f} | {ratio} | "
            f"{ev['steps']} | {ev['rss_mb']:.1f} | "
            f"{de['rss_mb'] if de else float('nan'):.1f} |"
        )
    if len(points) >= 2:
        x = np.log([p[0] for p in points])
        y = np.log([p[1] for p in points])
        slope = float(np.polyfit(x, y, 1)[0])
        span = f"{points[0][0]}…{points[-1][0]}"
        sims = np.log([s for _, _, s in points])
        print()
        print(
            f"Exponent of the event engine's wall time over n = {span}: {slope:.2f} "
            f"(least squares, log wall on log n; simulated time grows as n^"
            f"{float(np.polyfit(x, sims, 1)[0]):.2f})"
        )
    print()
    print(
        f"Event wall: median of {args.repeat} rounds, each running every case once. "
        f"dense / event: the median of {args.pairs} pairs (one beyond 10 units), each an event "
        "and a reference run in turn; dense wall: their median."
    )

    print()
    print("## The costs of zenoh and of the full MCAP log (event engine, fresh processes)")
    print()
    print("| case | bus | log | wall s | log MB | vs memory | vs no log |")
    print("|---|---|---|---|---|---|---|")
    for case in ("gate", "n=10" if not args.quick else "n=6"):
        walls = {}
        for bus in ("memory", "zenoh"):
            for log in (False, True):
                r = measure(case, "event", bus, log, args.repeat)
                walls[(bus, log)] = r["wall"]
                vs_mem = r["wall"] / walls[("memory", log)]
                vs_log = r["wall"] / walls[(bus, False)]
                print(
                    f"| {label(case)} | {bus} | {'full' if log else 'none'} | "
                    f"{r['wall']:.3f} | {r['log_mb']:.2f} | {vs_mem:.2f}x | {vs_log:.2f}x |"
                )
    print()
    print(f"Medians of {args.repeat} runs a configuration, each a fresh process.")


if __name__ == "__main__":
    main()
