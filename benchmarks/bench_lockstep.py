"""Cross-process lockstep: windows per second for 3, 6 and 10 processes, and the gate scenario
cross-process against the single-process zenoh run, in one run.

    python -m benchmarks.bench_lockstep [--windows N]

Each lockstep process is a bare member of a zenoh run on loopback (full mesh, multicast off):
it joins, then publishes a 20-sample window and gathers every member's, N times. Goals
(issue 6): at least 2,000 windows/s at 3 processes on this 2-core machine, and the gate scenario
cross-process in under 3 s wall including start-up.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def worker(name: str, run_id: str, members: list[str], ports: list[int], windows: int) -> None:
    from rgtbus.bus import open_bus

    i = members.index(name)
    with open_bus(
        "zenoh",
        run_id,
        members,
        200.0,
        20,
        local=[name],
        mode="peer",
        listen=[f"tcp/127.0.0.1:{ports[i]}"],
        connect=[f"tcp/127.0.0.1:{p}" for p in ports[:i]],
    ) as bus:
        bus.join(name, "bench", timeout=30)
        samples = np.zeros(20)
        t0 = time.perf_counter()
        for w in range(windows):
            bus.publish(name, w, samples)
            bus.gather(w, timeout=10)
        dt = time.perf_counter() - t0
    print(json.dumps({"unit": name, "seconds": dt, "windows": windows}))


def lockstep(n: int, windows: int) -> float:
    from rgtbus.cli.proc_cmds import free_ports

    members = [f"p{i}" for i in range(n)]
    ports = free_ports(n)
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                "-m",
                "benchmarks.bench_lockstep",
                "--worker",
                m,
                "--run-id",
                f"bench{n}",
                "--members",
                ",".join(members),
                "--ports",
                ",".join(map(str, ports)),
                "--windows",
                str(windows),
            ],
            stdout=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
        for m in members
    ]
    try:
        outs = [json.loads(p.communicate(timeout=300)[0]) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    return windows / max(o["seconds"] for o in outs)


def timed(argv: list[str]) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=300, cwd=ROOT)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed: {proc.stderr.strip()}")
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--windows", type=int, default=5000)
    ap.add_argument("--worker")
    ap.add_argument("--run-id")
    ap.add_argument("--members")
    ap.add_argument("--ports")
    args = ap.parse_args()
    if args.worker:
        worker(
            args.worker,
            args.run_id,
            args.members.split(","),
            [int(p) for p in args.ports.split(",")],
            args.windows,
        )
        return

    print(f"{'processes':>9} {'windows':>8} {'windows/s':>10} {'vs 3 processes':>15}")
    base = None
    for n in (3, 6, 10):
        rate = lockstep(n, args.windows)
        base = base or rate
        print(f"{n:>9} {args.windows:>8} {rate:>10.0f} {rate / base:>14.2f}x")

    gate = str(ROOT / "scenarios" / "gate.toml")
    exe = [sys.executable, "-m", "rgtbus"]
    log = "/tmp/rgtbus-bench-gate.mcap"
    single = min(
        timed([*exe, "run", gate, "--bus", "zenoh", "--log", log, "--quiet"]) for _ in range(2)
    )
    cross = min(
        timed([*exe, "launch", gate, "--log-dir", "/tmp/rgtbus-bench-launch", "--json"])
        for _ in range(2)
    )
    print()
    print(f"{'gate (wall, incl. start-up)':<30} {'seconds':>8} {'vs single':>10}")
    print(f"{'single process, zenoh':<30} {single:>8.2f} {1.0:>9.2f}x")
    print(f"{'cross-process (launch)':<30} {cross:>8.2f} {cross / single:>9.2f}x")


if __name__ == "__main__":
    main()
