"""Units in several processes: ``rgtbus launch --procs P`` against the single-process zenoh run.

    python -m benchmarks.bench_procs [--repeat 3] [--skip-50]

Each case is a whole process (start-up, join, run and merged log included), timed from the
launcher's spawn to its exit, cases in turn within each repeat (a noisy machine slows them
alike); the ratio is taken repeat by repeat against ``rgtbus run --bus zenoh`` of the same
scenario in the same repeat. Cases: group20 in 1 process (``run``), in 4 (``--procs 4``) and in
20 (one per unit, ``launch``'s default); group50 in 1 and in 8 processes.

Goals (issue 23, 2 cores): group20 with ``--procs 4`` at most 2x the single-process zenoh run;
group50 over 8 processes under 60 s.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

from benchmarks.bench_lockstep import timed  # a whole process's wall seconds

ROOT = Path(__file__).resolve().parent.parent
EXE = [sys.executable, "-m", "rgtbus"]


def cases(tmp: str, with_50: bool) -> dict[str, tuple[str, list[str]]]:
    """name -> (scenario, argv): the single-process run of each scenario first."""
    out: dict[str, tuple[str, list[str]]] = {}
    for sc, procs in (("group20", (4, None)), ("group50", (8,))):
        if sc == "group50" and not with_50:
            continue
        path = str(ROOT / "scenarios" / f"{sc}.toml")
        out[f"{sc}, 1 process (`run --bus zenoh`)"] = (
            sc,
            [*EXE, "run", path, "--bus", "zenoh", "--log", f"{tmp}/{sc}.mcap", "--quiet"],
        )
        for p in procs:
            label = "one per unit" if p is None else f"--procs {p}"
            extra = [] if p is None else ["--procs", str(p)]
            out[f"{sc}, launch {label}"] = (
                sc,
                [*EXE, "launch", path, "--log-dir", f"{tmp}/{sc}-{p}", "--quiet", *extra],
            )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-50", action="store_true", help="leave group50 out (~2 min a repeat)")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    walls: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory(prefix="rgtbus-bench-") as tmp:
        todo = cases(tmp, not args.skip_50)
        for _ in range(args.repeat):
            for name, (_, argv) in todo.items():
                walls.setdefault(name, []).append(timed(argv))
    load1 = os.getloadavg()[0]
    singles = {sc: name for name, (sc, argv) in todo.items() if "run" in argv[3:4]}
    print(f"## Units in several processes (median of {args.repeat}; load {load0:.2f} -> "
          f"{load1:.2f}, {os.cpu_count()} CPUs)")  # fmt: skip
    print()
    print("| case | wall s (min / median / max) | vs 1 process (median of per-repeat ratios) |")
    print("|---|---|---|")
    ratio: dict[str, float] = {}
    for name, (sc, _) in todo.items():
        xs = walls[name]
        base = walls[singles[sc]]
        ratio[name] = statistics.median(a / b for a, b in zip(xs, base, strict=True))
        spread = f"{min(xs):.2f} / {statistics.median(xs):.2f} / {max(xs):.2f}"
        print(f"| {name} | {spread} | {ratio[name]:.2f}x |")
    print()
    r = ratio["group20, launch --procs 4"]
    print(
        f"- group20, --procs 4: {r:.2f}x one process (goal <= 2x): {'met' if r <= 2 else 'NOT met'}"
    )
    if "group50, launch --procs 8" in walls:
        w = statistics.median(walls["group50, launch --procs 8"])
        print(
            f"- group50 over 8 processes: {w:.1f} s (goal < 60 s): {'met' if w < 60 else 'NOT met'}"
        )


if __name__ == "__main__":
    main()
