"""A noisy medium against a clean one and against its compiled reference (issue 53).

    python -m benchmarks.bench_noisy [--sizes 50,100,200] [--noise 0.01] [--repeat R]

Every run is a fresh process, one core's worth of work (no workers), over the memory bus with
the event engine, no log: the concurrent group of ``bench_scale`` (n units, seeded relations,
random influences) once on a clean medium and once with white noise σ = ``--noise`` on every
receiver. For the noisy run, the same process then runs ``benchmarks.noisy_reference``: the
same samples, lanes and decodes as one compiled loop (numba) a receiver, and checks its
decodes against the run's, decode for decode (``mismatch``: decodes that differ, 0 wanted).
Reported per n, medians of ``--repeat`` processes: wall of each run, noisy / clean, the
reference (noise drawn, bank walked, decodes), run / reference, decodes, misreads, peak RSS of
the noisy run (before the reference runs) and the machine's load.

Goals (issue 53, 2 cores): noisy n = 100 within 3x of clean n = 100; noisy n = 100 <= 10 s and
n = 200 <= 90 s; run / reference <= 3 at n = 50, 100, 200; peak RSS at n = 200 noisy <= 600 MB;
0 mismatches.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


def one(n: int, noise: float, reference: bool) -> dict[str, Any]:
    """In a child process: one run's figures, then (``reference``) the reference's."""
    from rgtbus.units.group import run_group

    from benchmarks.bench_scale import scale_toml
    from rgtbus.scenario import parse_scenario
    from rgtbus.telemetry import NullRecorder

    sc = parse_scenario(scale_toml(n, "concurrent", noise=noise), f"<noisy{n}>")
    t0 = time.perf_counter()
    out = run_group(sc, "memory", NullRecorder())
    wall = time.perf_counter() - t0
    got: dict[str, Any] = {
        "wall": wall,
        "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "decodes": sum(len(m.decoded) for m in out.units),
        "misreads": out.summary["decode_errors"]["misread"],
        "failure": out.summary["error"],
    }
    if reference and not out.summary["error"]:
        from benchmarks.noisy_reference import compare
        from benchmarks.noisy_reference import reference as run_reference

        ref = run_reference(sc, out.units, out.summary["sim_seconds"])
        got.update({k: v for k, v in ref.items() if k.startswith("ref_")})
        got.update(compare(ref, out.units, out.misreads))
    return got


def measure(n: int, noise: float, reference: bool = False) -> dict[str, Any]:
    argv = [sys.executable, "-m", "benchmarks.bench_noisy", "--one", str(n), repr(noise)]
    argv += ["--reference"] * reference
    env = {**os.environ, "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
    proc = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=7200, env=env)
    if proc.returncode != 0:
        raise SystemExit(f"n={n} noise={noise} failed: {proc.stderr.strip()[-800:]}")
    return json.loads(proc.stdout)


def table(sizes: list[int], noise: float, repeat: int) -> list[dict[str, Any]]:
    print(f"## A noisy medium (σ = {noise:g}) against a clean one and the compiled reference")
    print()
    print(f"load before: {os.getloadavg()[0]:.2f}; medians of {repeat} fresh processes each")
    print()
    head = ("| n | clean s | noisy s | noisy / clean | reference s (noise + bank + decode) "
            "| run / reference | decodes | misreads | mismatches | peak RSS MB |")  # fmt: skip
    print(head)
    print("|---" * (head.count("|") - 1) + "|")
    rows = []
    for n in sizes:
        clean = [measure(n, 0.0) for _ in range(repeat)]
        noisy = [measure(n, noise, reference=True) for _ in range(repeat)]

        def med(rs: list[dict[str, Any]], key: str) -> float:
            return statistics.median(float(r[key]) for r in rs)

        c, w = med(clean, "wall"), med(noisy, "wall")
        ref = med(noisy, "ref_s")
        row = {
            "n": n, "clean_s": c, "noisy_s": w, "ref_s": ref,
            "ref_noise_s": med(noisy, "ref_noise_s"), "ref_bank_s": med(noisy, "ref_bank_s"),
            "ref_decode_s": med(noisy, "ref_decode_s"), "decodes": noisy[0]["decodes"],
            "misreads": noisy[0]["misreads"],
            "mismatches": max(int(r["mismatches"]) for r in noisy),
            "rss_mb": med(noisy, "rss_mb"),
        }  # fmt: skip
        rows.append(row)
        print(
            f"| {n} | {c:.2f} | {w:.2f} | {w / c:.2f}x | {ref:.2f} ({row['ref_noise_s']:.2f} + "
            f"{row['ref_bank_s']:.2f} + {row['ref_decode_s']:.2f}) | {w / ref:.2f}x | "
            f"{row['decodes']:,} | {row['misreads']:,} | {row['mismatches']} | "
            f"{row['rss_mb']:.0f} |",
            flush=True,
        )
    print()
    print(f"load after: {os.getloadavg()[0]:.2f}")
    return rows


def goals(rows: list[dict[str, Any]]) -> None:
    by = {r["n"]: r for r in rows}

    def line(ok: bool, text: str) -> None:
        print(f"- {'met' if ok else 'NOT met'}: {text}")

    print()
    print("Goals (issue 53):")
    if 100 in by:
        r = by[100]
        line(r["noisy_s"] <= 3 * r["clean_s"], f"noisy n = 100 within 3x of clean "
             f"({r['noisy_s'] / r['clean_s']:.2f}x)")  # fmt: skip
        line(r["noisy_s"] <= 10, f"noisy n = 100 <= 10 s ({r['noisy_s']:.1f} s)")
    if 200 in by:
        r = by[200]
        line(r["noisy_s"] <= 90, f"noisy n = 200 <= 90 s ({r['noisy_s']:.1f} s)")
        line(r["rss_mb"] <= 600, f"peak RSS at n = 200 noisy <= 600 MB ({r['rss_mb']:.0f} MB)")
    for n in (50, 100, 200):
        if n in by:
            ratio = by[n]["noisy_s"] / by[n]["ref_s"]
            line(ratio <= 3, f"run / reference <= 3 at n = {n} ({ratio:.2f}x)")
    line(all(r["mismatches"] == 0 for r in rows), "every decode the reference's (0 mismatches)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="50,100,200")
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--one", nargs=2, help=argparse.SUPPRESS)
    ap.add_argument("--reference", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(one(int(args.one[0]), float(args.one[1]), args.reference)))
        return
    rows = table([int(x) for x in args.sizes.split(",")], args.noise, args.repeat)
    goals(rows)


if __name__ == "__main__":
    main()
