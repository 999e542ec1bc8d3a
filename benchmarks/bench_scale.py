"""Scale: the serial schedule against the concurrent one, and the concurrent one up to 100 units.

    python -m benchmarks.bench_scale [--sizes 4,6,8,10,12,16,20] [--large 30,50,100]
                                     [--log-upto 20] [--ser-sizes 10,50] [--quick]

Every run is a fresh process (no cache of one run helps another) over the memory bus with the
event engine. Groups of n units: a seeded decomposable group (relations policy cograph), random
influences, the automatic plan of each schedule (``rgtbus plan N --schedule ...``). Reported per
case: simulated seconds, wall seconds (no log), decode errors, peak RSS and, up to --log-upto
units, the wall and size of a run with the full MCAP log. Then the symbol error rate of the
concurrent schedule against channel noise.

Goals (issue 11): at n = 10 the concurrent schedule's simulated time at least 5x shorter than
the serial one's; n = 50 concurrent socialises in under 60 s wall without a log and at most 1.5x
that with the full log; n = 100 under 10 min.
"""

from __future__ import annotations

import argparse
import io
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def scale_toml(n: int, schedule: str, seed: int = 11, noise: float = 0.0) -> str:
    names = [f"u{i:03d}" for i in range(n)]
    return "\n".join(
        [
            f'name = "scale{n}"',
            f"seed = {seed}",
            "units = " + json.dumps(names),
            'actions = ["alpha", "beta"]',
            'frequencies = "auto"',
            "[protocol]",
            f'schedule = "{schedule}"',
            "[timing]",
            "max_seconds = 100000.0",
            "[channel]",
            f"noise = {noise}",
            "[relations]",
            'policy = "cograph"',
            "[influences]",
            'policy = "random"',
        ]
    )


def one(n: int, schedule: str, log: bool, noise: float) -> dict:
    """In a child process: one run's figures."""
    from rgtbus.units.group import run_group

    from rgtbus.scenario import parse_scenario
    from rgtbus.telemetry import McapRecorder, NullRecorder

    sc = parse_scenario(scale_toml(n, schedule, noise=noise), f"<scale{n}>")
    buf = io.BytesIO()
    rec = McapRecorder(buf) if log else NullRecorder()
    t0 = time.perf_counter()
    out = run_group(sc, "memory", rec)
    rec.close()
    wall = time.perf_counter() - t0
    s = out.summary
    decodes = sum(len(m.decoded) for m in out.units)
    return {
        "wall": wall,
        "sim": s["sim_seconds"],
        "errors": len(s["decode_errors"]),
        "decodes": decodes,
        "failure": s["error"],
        "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "log_mb": len(buf.getvalue()) / 1e6,
        "pulses": sc.codebook.pulses,
        "mode": sc.mode,
    }


def measure(n: int, schedule: str, log: bool = False, noise: float = 0.0) -> dict:
    argv = [sys.executable, "-m", "benchmarks.bench_scale", "--one", str(n), schedule]
    argv += ["--log" if log else "--no-log", "--noise", repr(noise)]
    proc = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=7200)
    if proc.returncode != 0:
        raise SystemExit(f"n={n} {schedule} failed: {proc.stderr.strip()[-800:]}")
    return json.loads(proc.stdout)


def goals(rows: list) -> None:
    """The issue's goals against this run's figures (a goal whose case was not run is left out)."""
    got = {(n, s): (r, lg) for n, s, r, lg in rows if not r["failure"]}
    lines = []
    if (10, "serial") in got and (10, "concurrent") in got:
        ratio = got[(10, "serial")][0]["sim"] / got[(10, "concurrent")][0]["sim"]
        lines.append(f"n = 10: serial / concurrent simulated time {ratio:.1f}x (goal >= 5x)")
    if (50, "concurrent") in got:
        r, lg = got[(50, "concurrent")]
        lines.append(f"n = 50 concurrent, no log: {r['wall']:.1f} s wall (goal < 60 s)")
        if lg:
            ratio = lg["wall"] / r["wall"]
            lines.append(
                f"n = 50 concurrent, full log: {lg['wall']:.1f} s wall, {ratio:.2f}x the run "
                "without a log (goal <= 1.5 x 60 s = 90 s)"
            )
    if (100, "concurrent") in got:
        lines.append(
            f"n = 100 concurrent: {got[(100, 'concurrent')][0]['wall']:.1f} s wall (goal < 600 s)"
        )
    for line in lines:
        print(f"- {line}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="4,6,8,10,12,16,20", help="serial and concurrent")
    ap.add_argument("--large", default="30,50,100", help="concurrent only")
    ap.add_argument("--log-upto", type=int, default=50, help="logged runs up to this size")
    ap.add_argument("--ser-sizes", default="10,50", help="noise sweep sizes (concurrent)")
    ap.add_argument("--quick", action="store_true", help="4,6,10; large 30; noise at 10")
    ap.add_argument("--one", nargs=2, metavar=("N", "SCHEDULE"), help=argparse.SUPPRESS)
    ap.add_argument("--log", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--no-log", dest="log", action="store_false", help=argparse.SUPPRESS)
    ap.add_argument("--noise", type=float, default=0.0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(one(int(args.one[0]), args.one[1], args.log, args.noise)))
        return
    sizes = [4, 6, 10] if args.quick else [int(x) for x in args.sizes.split(",")]
    large = [30] if args.quick else [int(x) for x in args.large.split(",") if x]
    ser_sizes = [10] if args.quick else [int(x) for x in args.ser_sizes.split(",") if x]

    print("## Serial vs concurrent schedule (memory bus, event engine, fresh processes)")
    print()
    print(
        "| n | schedule | pulses, mode | simulated s | serial / concurrent (sim) | wall s | "
        "decode errors | peak MB | wall s, full log | log / no log | log MB |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for n in sizes + large:
        for schedule in ("serial", "concurrent") if n in sizes else ("concurrent",):
            r = measure(n, schedule)
            ok = not r["failure"]
            lg = measure(n, schedule, log=True) if ok and n <= args.log_upto else None
            rows.append((n, schedule, r, lg))
    sims = {(n, s): r["sim"] for n, s, r, _ in rows if not r["failure"]}
    for n, schedule, r, lg in rows:
        if r["failure"]:  # a run that cannot finish is a result too: say where it stopped
            print(
                f"| {n} | {schedule} | {r['pulses']}, {r['mode']} | failed at "
                f"{r['sim']:.1f} s: {r['failure']} | - | {r['wall']:.2f} | "
                f"{r['errors']} of {r['decodes']} | {r['rss_mb']:.0f} | - | - | - |"
            )
            continue
        ratio = (
            f"{sims[(n, 'serial')] / r['sim']:.1f}x"
            if schedule == "concurrent" and (n, "serial") in sims
            else "-"
        )
        logged = (
            f"{lg['wall']:.2f} | {lg['wall'] / r['wall']:.2f}x | {lg['log_mb']:.1f}"
            if lg
            else "- | - | -"
        )
        print(
            f"| {n} | {schedule} | {r['pulses']}, {r['mode']} | {r['sim']:.1f} | {ratio} | "
            f"{r['wall']:.2f} | {r['errors']} of {r['decodes']} | {r['rss_mb']:.0f} | {logged} |"
        )
    print()
    goals(rows)
    print()
    print("## Symbol error rate of the concurrent schedule against channel noise (σ per sample)")
    print()
    noises = [0.0, 0.02, 0.05, 0.1]
    print("| n | " + " | ".join(f"σ = {x:g}" for x in noises) + " |")
    print("|---|" + "---|" * len(noises))
    for n in ser_sizes:
        cells = []
        for noise in noises:
            r = measure(n, "concurrent", noise=noise)
            rate = r["errors"] / max(r["decodes"], 1)
            note = "" if not r["failure"] else " (run failed)"
            cells.append(f"{rate:.4f} ({r['errors']}/{r['decodes']}){note}")
        print(f"| {n} | " + " | ".join(cells) + " |")
    print()
    print(
        "Wall: the simulation only (scenario loaded first), one fresh process a cell; decode "
        "errors: decodes (IDs and payloads, every unit) that differ from what was sent."
    )


if __name__ == "__main__":
    main()
