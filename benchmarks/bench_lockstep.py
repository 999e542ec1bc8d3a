"""Cross-process runs: synchronisation rounds per second at 3, 6 and 10 processes; the gate and
a 10-unit group with one process per unit; in one run.

    python -m benchmarks.bench_lockstep [--rounds N] [--repeat R]

1. Rounds. Each process is a bare member of a zenoh run on loopback (full mesh, multicast off).
   A round: it publishes a frame with no pulses and a promise 20 samples further (a null
   message) and waits until every member has promised as far. The event engine needs about
   one round per protocol turn; the time-stepped reference one per 0.1 s window.
2. The gate: ``rgtbus launch`` (one process per unit, a zenoh mesh on loopback) against
   ``rgtbus run --bus zenoh`` (one process), each timed as a whole process, start-up
   included, A and B in turn; the ratio is taken pair by pair (median of --repeat pairs).
3. group10: ``rgtbus launch`` of the generated 10-unit group of ``bench_run`` (10 processes).

Goals (issue 9): the gate cross-process at most 1.5x the single-process zenoh run, start-up
included; group10 with 10 processes under 10 s.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
STEP = 20  # samples a round's promise moves


def worker(name: str, run_id: str, members: list[str], ports: list[int], rounds: int) -> None:
    from rgtbus.bus import open_bus

    i = members.index(name)
    none = np.zeros(0, dtype=np.int64), np.zeros(0)
    with open_bus(
        "zenoh",
        run_id,
        members,
        200.0,
        local=[name],
        mode="peer",
        multicast=False,
        listen=[f"tcp/127.0.0.1:{ports[i]}"],
        connect=[f"tcp/127.0.0.1:{p}" for p in ports[:i]],
    ) as bus:
        bus.join(name, hashlib.sha256(b"bench").hexdigest(), timeout=30)
        t0 = time.perf_counter()
        for r in range(rounds):
            bus.publish(name, *none, promise=(r + 1) * STEP)
            bus.wait(r * STEP, timeout=30)  # returns once everyone promised (r + 1)·STEP
        dt = time.perf_counter() - t0
    print(json.dumps({"unit": name, "seconds": dt, "rounds": rounds}))


def rounds_per_second(n: int, rounds: int) -> float:
    from rgtbus.units.launch import free_ports

    members = [f"p{i}" for i in range(n)]
    ports = free_ports(n)
    argv = [sys.executable, "-m", "benchmarks.bench_lockstep", "--worker"]
    procs = [
        subprocess.Popen(
            [
                *argv,
                m,
                "--run-id",
                f"bench{n}",
                "--members",
                ",".join(members),
                "--ports",
                ",".join(map(str, ports)),
                "--rounds",
                str(rounds),
            ],
            stdout=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
        for m in members
    ]
    try:
        outs = [json.loads(p.communicate(timeout=600)[0]) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    return rounds / max(o["seconds"] for o in outs)


def timed(argv: list[str]) -> float:
    """Wall seconds of a whole process (start-up included)."""
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=600, cwd=ROOT)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed: {proc.stderr.strip()[-800:]}")
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=2000, help="rounds a process count")
    ap.add_argument("--repeat", type=int, default=5, help="pairs of gate runs (median)")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--run-id", help=argparse.SUPPRESS)
    ap.add_argument("--members", help=argparse.SUPPRESS)
    ap.add_argument("--ports", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        ports = [int(p) for p in args.ports.split(",")]
        worker(args.worker, args.run_id, args.members.split(","), ports, args.rounds)
        return

    print("## Synchronisation rounds across processes (zenoh, loopback mesh)")
    print()
    print("| processes | rounds | rounds/s | vs 3 processes |")
    print("|---|---|---|---|")
    base = None
    for n in (3, 6, 10):
        rate = rounds_per_second(n, args.rounds)
        base = base or rate
        print(f"| {n} | {args.rounds} | {rate:.0f} | {rate / base:.2f}x |")

    exe = [sys.executable, "-m", "rgtbus"]
    with tempfile.TemporaryDirectory(prefix="rgtbus-bench-") as tmp:
        gate = str(ROOT / "scenarios" / "gate.toml")
        single_argv = [*exe, "run", gate, "--bus", "zenoh", "--log", f"{tmp}/gate.mcap"]
        launch_argv = [*exe, "launch", gate, "--log-dir", f"{tmp}/gate", "--json"]
        singles, launches = [], []
        for _ in range(args.repeat):
            launches.append(timed(launch_argv))
            singles.append(timed([*single_argv, "--quiet"]))
        ratios = [a / b for a, b in zip(launches, singles, strict=True)]

        from benchmarks.bench_run import group_toml

        group = Path(tmp) / "group10.toml"
        group.write_text(group_toml(10))
        group_walls = [
            timed([*exe, "launch", str(group), "--log-dir", f"{tmp}/g{i}", "--json"])
            for i in range(max(1, args.repeat // 2))
        ]

    print()
    print("## Whole processes, start-up included (medians)")
    print()
    print("| run | processes | wall s (min / median / max) | vs single process |")
    print("|---|---|---|---|")

    def spread(xs: list[float]) -> str:
        return f"{min(xs):.2f} / {statistics.median(xs):.2f} / {max(xs):.2f}"

    print(f"| gate, `rgtbus run --bus zenoh` | 1 | {spread(singles)} | 1.00x |")
    print(
        f"| gate, `rgtbus launch` | 4 | {spread(launches)} | "
        f"{statistics.median(ratios):.2f}x (median of {len(ratios)} pairs) |"
    )
    print(f"| group10, `rgtbus launch` | 10 | {spread(group_walls)} | - |")


if __name__ == "__main__":
    main()
