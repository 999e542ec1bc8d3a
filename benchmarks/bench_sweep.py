"""Sweeps: the same runs in a plain loop, on 1 worker, on all workers, on a Dask LocalCluster.

    python -m benchmarks.bench_sweep [--runs 1000] [--gate 200]

1,000 runs of example1 with random draws (its paper draws removed: ``relations.draws = {}``)
and 200 of the gate with channel noise 0.02 (turns timed by the schedule, so every run goes to
the end; with the paper's spike-timed turns every run fails early at that noise). Each pass
measures every way in turn; the table shows medians over ``--repeat`` passes. Workers are
started and have done one run before the clock starts (start-up is reported apart).

Goals (issue 12): speed-up of all workers over one >= 1.7x on 2 cores; the pool's overhead
over a plain loop of the same runs <= 10 % (1-worker pool vs loop); 1,000 example1 runs
under 60 s.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from concurrent.futures import Executor
from pathlib import Path

from rgtbus.units.sweep import Sweep, load_sweep, open_executor, run_batch, run_row, run_sweep

ROOT = Path(__file__).resolve().parent.parent


def sweep_file(d: Path, name: str, scenario: str, seeds: int, grid: str) -> Path:
    p = d / f"{name}.toml"
    p.write_text(
        f'name = "{name}"\nscenario = "{ROOT / "scenarios" / scenario}"\n'
        f'seeds = "0..{seeds - 1}"\n[grid]\n{grid}\n'
    )
    return p


def _timed_sweep(sw: Sweep, out: Path, ex: Executor, workers: int) -> float:
    # workers up and their imports done before the clock starts: one real run each (the
    # start-up is measured on its own)
    for f in [ex.submit(run_batch, sw, sw.tasks()[:1], None) for _ in range(workers)]:
        f.result()
    t0 = time.perf_counter()
    run_sweep(sw, out, executor=ex, workers=workers)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--gate", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3, help="passes; the table shows medians")
    args = ap.parse_args()
    cores = os.cpu_count() or 1
    from distributed import LocalCluster

    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        cases = [
            (
                "example1",
                load_sweep(
                    sweep_file(d, "ex1", "example1.toml", args.runs, '"relations.draws" = [{}]')
                ),
            ),
            (
                "gate σ=0.02",
                load_sweep(
                    sweep_file(
                        d,
                        "gate",
                        "gate.toml",
                        args.gate,
                        '"channel.noise" = [0.02]\n"timing.anchor" = ["schedule"]',
                    )
                ),
            ),
        ]
        walls: dict[tuple[str, str], list[float]] = {}
        failed: dict[str, int] = {}
        starts: list[float] = []
        for rep in range(args.repeat):
            for label, sw in cases:  # each pass measures every way in turn: noise hits all
                t0 = time.perf_counter()
                rows = [run_row(sw, t) for t in sw.tasks()]
                walls.setdefault((label, "loop"), []).append(time.perf_counter() - t0)
                failed[label] = sum(1 for r in rows if r.get("failed"))
                for key, workers in (("one", 1), ("all", cores)):
                    t0 = time.perf_counter()
                    with open_executor(workers, None) as (ex, n):
                        ex.submit(int).result()
                        if key == "all" and label == cases[0][0]:
                            starts.append(time.perf_counter() - t0)
                        wall = _timed_sweep(sw, d / f"{label}-{key}-{rep}", ex, n)
                    walls.setdefault((label, key), []).append(wall)
                with (
                    LocalCluster(
                        n_workers=cores,
                        threads_per_worker=1,
                        processes=True,
                        dashboard_address=None,
                    ) as cluster,
                    open_executor(None, cluster.scheduler_address) as (ex, n),
                ):
                    wall = _timed_sweep(sw, d / f"{label}-dask-{rep}", ex, n)
                walls.setdefault((label, "dask"), []).append(wall)
        med = {k: statistics.median(v) for k, v in walls.items()}
        print(
            f"## Sweeps ({cores} cores; median of {args.repeat} passes, every way measured in "
            "each pass, same machine, same run)"
        )
        print()
        print(
            "| case | runs | plain loop s | 1 worker s | pool / loop | all workers s | "
            "speed-up | Dask LocalCluster s | Dask speed-up | failed runs |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|")
        for label, sw in cases:
            loop, one, all_, dask = (med[(label, k)] for k in ("loop", "one", "all", "dask"))
            print(
                f"| {label} | {len(sw.tasks())} | {loop:.2f} | {one:.2f} | "
                f"{one / loop:.2f}x | {all_:.2f} | {one / all_:.2f}x | {dask:.2f} | "
                f"{one / dask:.2f}x | {failed[label]} |"
            )
        print()
        print(
            f"Pool start-up ({cores} spawn workers, not in the walls above): median "
            f"{statistics.median(starts):.2f} s. Per pass (s): "
            + "; ".join(
                f"{label} {k} " + "/".join(f"{w:.2f}" for w in walls[(label, k)])
                for label, _ in cases
                for k in ("loop", "one", "all", "dask")
            )
        )


if __name__ == "__main__":
    main()
