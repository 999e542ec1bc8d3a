"""Start-up: how long ``rgtbus run`` of the gate, as a process, takes before its first sample.

    python -m benchmarks.bench_start [--repeat 9]

Each case is a fresh interpreter, timed from just before it is spawned (the system's monotonic
clock, shared by every process) to the moment the world starts its first sample
(``World.run``; the child patches it to say when), and to its exit. The baseline, measured in
the same run: a bare interpreter (``python -c pass``) and one that imports numpy and simpy,
the floor of any run. Medians of ``--repeat`` runs, cases interleaved (a noisy machine slows
them alike). Goal (issue 23): < 0.3 s before the first sample.

Run ``make bytecode`` first (``make test`` and ``make demo`` do): a shell that sets
PYTHONDONTWRITEBYTECODE otherwise compiles every module at every start.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# The child: say when the world starts its first sample, then run the command as rgtbus does.
PROBE = """
import os, sys, time
import rgtbus.engine.sim as sim
_run = sim.World.run
def run(self, *a, **k):
    os.write(int(os.environ["PROBE_FD"]), repr(time.monotonic()).encode())
    return _run(self, *a, **k)
sim.World.run = run
from rgtbus.cli import main
sys.exit(main(sys.argv[1:]))
"""

CASES: dict[str, list[str]] = {
    "rgtbus run gate (zenoh, with its log)": ["run", "gate", "--log", "{log}", "--quiet"],
    "rgtbus run gate --bus memory --no-log": ["run", "gate", "--bus", "memory", "--no-log"],
}
FLOORS: dict[str, str] = {
    "python -c pass": "pass",
    "python -c 'import numpy, simpy'": "import numpy, simpy",
}


def time_child(code: str, argv: list[str]) -> tuple[float | None, float]:
    """(seconds to the first sample or None, seconds to exit) of one fresh interpreter."""
    read, write = os.pipe()
    t0 = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-c", code, *argv],
        cwd=ROOT,
        pass_fds=(write,),
        env={**os.environ, "PROBE_FD": str(write)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    os.close(write)
    _, err = proc.communicate(timeout=120)
    t_exit = time.monotonic() - t0
    said = os.read(read, 64)
    os.close(read)
    if proc.returncode != 0:
        raise SystemExit(f"{argv}: exit {proc.returncode}: {err.decode()[-400:]}")
    return (float(said) - t0 if said else None), t_exit


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=9)
    args = ap.parse_args()
    first: dict[str, list[float]] = {k: [] for k in [*FLOORS, *CASES]}
    whole: dict[str, list[float]] = {k: [] for k in first}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeat):
            for name, code in FLOORS.items():
                _, t = time_child(code, [])
                first[name].append(t)
                whole[name].append(t)
            for name, argv in CASES.items():
                log = str(Path(tmp) / f"gate{i}.mcap")
                t_first, t = time_child(PROBE, [a.replace("{log}", log) for a in argv])
                assert t_first is not None, f"{name}: the world never started"
                first[name].append(t_first)
                whole[name].append(t)
    load = os.getloadavg()
    base = statistics.median(first["python -c pass"])
    print(f"## Start-up (median of {args.repeat}; load {load[0]:.2f}, {os.cpu_count()} CPUs)")
    print()
    print("| case | before the first sample s | / bare interpreter | whole process s |")
    print("|---|---|---|---|")
    for name in first:
        m = statistics.median(first[name])
        what = "(exit)" if name in FLOORS else f"{m:.3f}"
        print(f"| {name} | {what} | {m / base:.1f}x | {statistics.median(whole[name]):.3f} |")
    print()
    gate = statistics.median(first["rgtbus run gate (zenoh, with its log)"])
    verdict = "met" if gate < 0.3 else "NOT met"
    print(f"- gate, as a process, before its first sample: {gate:.3f} s (goal < 0.3 s): {verdict}")


if __name__ == "__main__":
    main()
