"""Sweeps: the same runs in a plain loop, on 1 worker, on all workers, on a Dask LocalCluster.

    python -m benchmarks.bench_sweep [--runs 1000] [--gate 200]

1,000 runs of example1 with random draws (its paper draws removed: ``relations.draws = {}``)
and 200 of the gate with channel noise 0.02. Goals (issue 12): speed-up of all workers over
one >= 1.7x on 2 cores; the pool's overhead over a plain loop of the same runs <= 10 %
(1-worker pool vs loop); 1,000 example1 runs under 60 s.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from units.sweep import load_sweep, open_executor, run_row, run_sweep

ROOT = Path(__file__).resolve().parent.parent


def sweep_file(d: Path, name: str, scenario: str, seeds: int, grid: str) -> Path:
    p = d / f"{name}.toml"
    p.write_text(
        f'name = "{name}"\nscenario = "{ROOT / "scenarios" / scenario}"\n'
        f'seeds = "0..{seeds - 1}"\n[grid]\n{grid}\n'
    )
    return p


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--gate", type=int, default=200)
    args = ap.parse_args()
    cores = os.cpu_count() or 1
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
                    sweep_file(d, "gate", "gate.toml", args.gate, '"channel.noise" = [0.02]')
                ),
            ),
        ]
        print(f"## Sweeps ({cores} cores; one pass each, same machine, same run)")
        print()
        print(
            "| case | runs | plain loop s | 1 worker s | pool / loop | all workers s | "
            "speed-up | Dask LocalCluster s | Dask speed-up | failed runs |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|")
        from distributed import LocalCluster

        for label, sw in cases:
            tasks = sw.tasks()
            t0 = time.perf_counter()
            rows = [run_row(sw, t) for t in tasks]
            loop = time.perf_counter() - t0
            failed = sum(1 for r in rows if r.get("failed"))
            walls = {}
            for key, workers in (("one", 1), ("all", cores)):
                with open_executor(workers, None) as (ex, n):
                    ex.submit(int).result()  # workers up before the clock starts
                    t0 = time.perf_counter()
                    run_sweep(sw, d / f"{label}-{key}", executor=ex, workers=n)
                    walls[key] = time.perf_counter() - t0
            with (
                LocalCluster(
                    n_workers=cores, threads_per_worker=1, processes=True, dashboard_address=None
                ) as cluster,
                open_executor(None, cluster.scheduler_address) as (ex, n),
            ):
                ex.submit(int).result()
                t0 = time.perf_counter()
                run_sweep(sw, d / f"{label}-dask", executor=ex, workers=n)
                walls["dask"] = time.perf_counter() - t0
            print(
                f"| {label} | {len(tasks)} | {loop:.1f} | {walls['one']:.1f} | "
                f"{walls['one'] / loop:.2f}x | {walls['all']:.1f} | "
                f"{walls['one'] / walls['all']:.2f}x | {walls['dask']:.1f} | "
                f"{walls['one'] / walls['dask']:.2f}x | {failed} |"
            )


if __name__ == "__main__":
    main()
