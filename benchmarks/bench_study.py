"""Studies: what a study's machinery costs over the bare runs, and what its workers give.

    python -m benchmarks.bench_study [--runs 300] [--repeat 3]

One point of the shipped control_gate study (d steers a to open, σ = 0.1, no repair: runs that
go to the end and runs that a misread ID ends), ``--runs`` runs with the study's seeds:

- **loop**: ``rgtbus.run`` of the point's scenario with each run's seed, in this process (the
  independent loop the tests compare a study with);
- **study, 1 worker**: ``rgtbus.study`` of that point with its stop set so that every run is run
  (budget = runs, failures = runs + 1), in this process: the loop's work plus the noise-free
  reference of each run (p_clean), the checksummed rows, the tables;
- **study, all workers**: the same on the local process pool (workers up before the clock).

Each pass measures every way in turn; the table shows medians and same-run ratios. Goals: the
study's overhead over the loop at most 25 % (1 worker); a speed-up of all workers over one of
at least 1.6x on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from rgtbus.units.study import Study, load_study, run_study

import rgtbus

ROOT = Path(__file__).resolve().parent.parent


def study_of(runs: int) -> Study:
    """control_gate's point (no repair, σ = 0.1) as a study of its own that runs every run."""
    return load_study(
        {
            "study": {
                "name": "bench",
                "scenario": str(ROOT / "scenarios" / "gate_goal.toml"),
                "controller": "d",
                "target": "a",
                "steer_to": "open",
                "repair": False,
                "failures": min(runs + 1, 10_000_000),  # no stop before the budget
                "budget": runs,
            },
            "grid": {"noise": [0.1]},
        }
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=300)
    ap.add_argument("--repeat", type=int, default=3, help="passes; the table shows medians")
    args = ap.parse_args()
    cores = os.cpu_count() or 1
    st = study_of(args.runs)
    walls: dict[str, list[float]] = {"loop": [], "one": [], "all": []}
    steered: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(args.repeat):
            t0 = time.perf_counter()
            ok = 0
            for r in range(args.runs):
                res = rgtbus.run(st.scenario_of(0, r))
                unit = res.summary["units"].get("a") or {}
                ok += bool(res.ok and unit.get("choice") == ["open"])
            walls["loop"].append(time.perf_counter() - t0)
            steered["loop"] = ok
            for key, workers in (("one", 1), ("all", cores)):
                t0 = time.perf_counter()
                got = run_study(st, Path(tmp) / f"{key}-{rep}", workers=workers)
                walls[key].append(time.perf_counter() - t0)
                steered[key] = int(got.points["runs"].sum() - got.points["failures"].sum())
    med = {k: statistics.median(v) for k, v in walls.items()}
    assert steered["loop"] == steered["one"] == steered["all"], steered
    print(
        f"## Studies ({cores} cores; median of {args.repeat} passes, every way measured in each "
        "pass, same machine, same run)"
    )
    print()
    print("| way | runs | wall s | runs/s | vs loop | speed-up over 1 worker | steered |")
    print("|---|---|---|---|---|---|---|")
    for key, label in (("loop", "loop over rgtbus.run"), ("one", "study, 1 worker"),
                       ("all", f"study, {cores} workers")):  # fmt: skip
        w = med[key]
        speed = f"{med['one'] / w:.2f}x" if key != "loop" else ""
        print(
            f"| {label} | {args.runs} | {w:.2f} | {args.runs / w:.1f} | {w / med['loop']:.2f}x |"
            f" {speed} | {steered[key]} |"
        )
    print()
    print(
        "Per pass (s): "
        + "; ".join(f"{k} " + "/".join(f"{w:.2f}" for w in walls[k]) for k in walls)
        + ". The study's walls include its pool's start-up (spawned workers)."
    )


if __name__ == "__main__":
    main()
