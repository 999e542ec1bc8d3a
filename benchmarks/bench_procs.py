"""Units in several processes: ``rgtbus launch --procs P`` against the single-process zenoh run.

    python -m benchmarks.bench_procs [--scenario group50] [--procs 1,2,4,8,16] [--repeat 3]
                                     [--noise 0.01] [--noisy-size 100]

Each case is a whole process (start-up, join, run and merged log included), timed from the
spawn to its exit; within each repeat the cases run in turn (a noisy machine slows them alike)
and each is divided by ``rgtbus run --bus zenoh`` of the same scenario in the same repeat (its
log written too): the table gives the median of those ratios. A second table gives what
keeping the clock cost each launch (``details["sync"]``, docs/engine.md "The cost of the
clock"), from one launch a P through the library.

Goal (issue 34): group50 over 4 processes within 1.3x of one process, no P above 1.5x. On a
machine with fewer cores than processes the processes share the cores, and each does work of
its own that one process does once for all its units (every unit decodes every code; one
process decodes each code once for its units): the ratio then grows with P.

The noisy case (``--noise``, 0 for none): ``bench_scale``'s concurrent group of
``--noisy-size`` units (100: a run long enough for the processes' start and join to count
little) with white noise σ on every receiver (``[channel] noise``), where no receiver hears as
another does and one process shares nothing: its P processes split the units' work. Its
table gives the speed-up over one process (one process / P, the median of per-repeat ratios).
Goal (issue 53): speed-up >= 0.7 P up to the machine's cores.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

from benchmarks.bench_lockstep import timed  # a whole process's wall seconds

ROOT = Path(__file__).resolve().parent.parent
EXE = [sys.executable, "-m", "rgtbus"]
GOAL_AT, GOAL, CEILING = 4, 1.3, 1.5


def cases(scenario: str, procs: list[int], tmp: str, path: str | None = None,
          tag: str = "") -> dict[str, list[str]]:  # fmt: skip
    """label -> argv: the single-process zenoh run first (``path``: a scenario file instead
    of the shipped one; ``tag``: a label's prefix and its logs' folder)."""
    path = path or str(ROOT / "scenarios" / f"{scenario}.toml")
    out = {f"{tag}1 process (`run --bus zenoh`)": [
        *EXE, "run", path, "--bus", "zenoh", "--log", f"{tmp}/{tag}single.mcap", "--quiet",
    ]}  # fmt: skip
    for p in procs:
        out[f"{tag}launch --procs {p}"] = [
            *EXE, "launch", path, "--procs", str(p), "--log-dir", f"{tmp}/{tag}p{p}", "--quiet",
        ]  # fmt: skip
    return out


def noisy_file(size: int, noise: float, tmp: str) -> str:
    """``bench_scale``'s concurrent group of ``size`` units with white noise σ = ``noise`` on
    every receiver, as a file."""
    from benchmarks.bench_scale import scale_toml

    path = Path(tmp) / f"noisy{size}.toml"
    path.write_text(scale_toml(size, "concurrent", noise=noise))
    return str(path)


def sync_costs(scenario: str, procs: list[int], tmp: str) -> list[dict[str, Any]]:
    """One library launch a P: what its processes say the clock cost them."""
    import rgtbus

    rows = []
    for p in procs:
        result = rgtbus.launch(ROOT / "scenarios" / f"{scenario}.toml", procs=p,
                               log_dir=f"{tmp}/sync{p}")  # fmt: skip
        if not result.ok:
            raise SystemExit(f"launch --procs {p}: {result.summary['error']}")
        windows = result.details["sim_seconds"] / result.scenario.timing.window
        # one entry a unit, its process's: a process of k units counts 1/k from each
        ss = list(result.details["sync"].values())
        members = len(ss)

        def total(key: str, ss: list[dict[str, Any]] = ss) -> float:
            return sum(s[key] / s["members"] for s in ss)

        rounds = statistics.median(s["rounds"] for s in ss)
        rows.append(
            {
                "procs": p,
                "rounds": rounds,
                "rounds_per_window": rounds / windows,
                "frames_per_member": total("frames") / members,
                "null_per_member": total("null_frames") / members,
                "wait_s": statistics.median(s["wait_seconds"] for s in ss),
                "ahead_rounds": round(total("ahead_rounds")),
            }
        )
    return rows


def noisy_table(
    scenario: str, noise: float, walls: dict[str, list[float]], noisy: dict[str, list[str]]
) -> None:
    """The noisy case: each P's speed-up over one process, and the goal (>= 0.7 P up to the
    machine's cores)."""
    base = walls[next(iter(noisy))]
    cores = os.cpu_count() or 1
    print()
    print(f"## {scenario} with white noise σ = {noise:g} on every receiver: speed-up of P "
          f"processes ({cores} CPUs)")  # fmt: skip
    print()
    print("| case | wall s (min / median / max) | speed-up over 1 process | goal (>= 0.7 P) |")
    print("|---|---|---|---|")
    for name, xs in walls.items():
        if name not in noisy:
            continue
        up = statistics.median(b / a for a, b in zip(xs, base, strict=True))
        goal = "—"
        if " --procs " in name:
            p = int(name.rsplit(" ", 1)[1])
            goal = ("met" if up >= 0.7 * p else "NOT met") if p <= cores else "(P > cores)"
        print(f"| {name} | {min(xs):.2f} / {statistics.median(xs):.2f} / {max(xs):.2f} | "
              f"{up:.2f}x | {goal} |")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="group50", help="a shipped scenario (group50)")
    ap.add_argument("--procs", default="1,2,4,8,16", help="the P to launch with")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--noise", type=float, default=0.01, help="the noisy case's σ (0: none)")
    ap.add_argument("--noisy-size", type=int, default=100, help="the noisy case's units")
    args = ap.parse_args()
    procs = [int(p) for p in args.procs.split(",")]
    load0 = os.getloadavg()[0]
    walls: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory(prefix="rgtbus-bench-") as tmp:
        todo = cases(args.scenario, procs, tmp)
        noisy = {}
        if args.noise > 0:
            path = noisy_file(args.noisy_size, args.noise, tmp)
            tag = f"{args.noisy_size} units, σ = {args.noise:g}: "
            noisy = cases(args.scenario, procs, tmp, path, tag=tag)
        for _ in range(args.repeat):
            for name, argv in noisy.items():
                walls.setdefault(name, []).append(timed(argv))
            for name, argv in todo.items():
                walls.setdefault(name, []).append(timed(argv))
        sync = sync_costs(args.scenario, procs, tmp)
    load1 = os.getloadavg()[0]
    base = walls[next(iter(todo))]
    print(f"## {args.scenario}: launch --procs P against one process (median of {args.repeat}; "
          f"load {load0:.2f} -> {load1:.2f}, {os.cpu_count()} CPUs)")  # fmt: skip
    print()
    print("| case | wall s (min / median / max) | vs 1 process (median of per-repeat ratios) |")
    print("|---|---|---|")
    ratio: dict[int, float] = {}
    for name, xs in walls.items():
        if name in noisy:
            continue
        r = statistics.median(a / b for a, b in zip(xs, base, strict=True))
        if name.startswith("launch --procs "):
            ratio[int(name.rsplit(" ", 1)[1])] = r
        print(
            f"| {name} | {min(xs):.2f} / {statistics.median(xs):.2f} / {max(xs):.2f} | {r:.2f}x |"
        )
    print()
    if GOAL_AT in ratio:
        r = ratio[GOAL_AT]
        print(f"- --procs {GOAL_AT}: {r:.2f}x one process (goal <= {GOAL}x): "
              f"{'met' if r <= GOAL else 'NOT met'}")  # fmt: skip
    worst = max(ratio, key=ratio.__getitem__)
    print(f"- slowest: --procs {worst} at {ratio[worst]:.2f}x (goal: none above {CEILING}x): "
          f"{'met' if ratio[worst] <= CEILING else 'NOT met'}")  # fmt: skip
    if noisy:
        noisy_table(f"{args.noisy_size} units", args.noise, walls, noisy)
    print()
    print(f"## The cost of the clock ({args.scenario}, one launch a P)")
    print()
    print(
        "| P | rounds (median process) | rounds a window | frames a member | null frames a "
        "member | s blocked in wait (median process) | rounds ahead |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for row in sync:
        print(f"| {row['procs']} | {row['rounds']:g} | {row['rounds_per_window']:.5f} | "
              f"{row['frames_per_member']:.2f} | {row['null_per_member']:.2f} | "
              f"{row['wait_s']:.3f} | {row['ahead_rounds']} |")  # fmt: skip


if __name__ == "__main__":
    main()
