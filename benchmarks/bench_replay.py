"""Replay and verification speed, and log size, against the original simulation in one run.

    python -m benchmarks.bench_replay [--repeat N] [--quick]

For each case the baseline is the original simulation measured in the same run (memory bus,
full MCAP log written zstd-compressed to memory: the fastest way the run itself goes). Then,
on that log: ``replay`` (read and organise the log, rebuild the summary) and ``--verify``
(read, re-run every unit's receiver and reasoning on the logged medium, re-derive decisions
from the tables, diff). Speeds are simulated seconds per wall second; ratios are against the
simulation. Goal (issue 5): verify at least as fast as the simulation (ratio >= 1). Log size per
simulated second with and without ``--traces`` (traces also verified, where measured).
"""

from __future__ import annotations

import argparse
import io
import time
from pathlib import Path

from rgtbus.units.group import run_group
from rgtbus.units.rerun import verify_log

from benchmarks.bench_run import group_scenario
from rgtbus.scenario import Scenario, load_scenario
from rgtbus.telemetry import McapRecorder
from rgtbus.telemetry.read import load_replay

ROOT = Path(__file__).resolve().parent.parent


def simulate(sc: Scenario, traces: bool = False) -> tuple[float, float, bytes]:
    buf = io.BytesIO()
    rec = McapRecorder(buf)
    t0 = time.perf_counter()
    out = run_group(sc, "memory", rec, traces=traces)
    rec.close()
    wall = time.perf_counter() - t0
    if out.summary["error"]:
        raise SystemExit(f"{sc.name} failed: {out.summary['error']}")
    return wall, out.summary["sim_seconds"], buf.getvalue()


def replay_wall(data: bytes) -> float:
    t0 = time.perf_counter()
    load_replay(io.BytesIO(data)).summary()
    return time.perf_counter() - t0


def verify_wall(data: bytes) -> float:
    t0 = time.perf_counter()
    report = verify_log(io.BytesIO(data))
    wall = time.perf_counter() - t0
    if not report.ok:
        raise SystemExit(f"verification failed: {report.verdict()}")
    return wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="best of N for the short cases")
    ap.add_argument("--quick", action="store_true", help="skip the 10-unit group")
    args = ap.parse_args()
    cases: list[tuple[str, Scenario, int, bool]] = [
        ("gate (4 units)", load_scenario(ROOT / "scenarios" / "gate.toml"), args.repeat, True),
        ("group6 (6 units)", load_scenario(ROOT / "scenarios" / "group6.toml"), 1, True),
    ]
    if not args.quick:
        # traces of 10 units x 10 channels: ~0.5 MB per simulated second, not measured here
        cases.append(("group10 (10 units)", group_scenario(10), 1, False))

    speed_rows = []
    size_rows = []
    for label, sc, n, with_traces in cases:
        sim_wall, sim_s, data = min((simulate(sc) for _ in range(n)), key=lambda r: r[0])
        rep = min(replay_wall(data) for _ in range(n))
        ver = min(verify_wall(data) for _ in range(n))
        speed_rows.append((label, sim_s, sim_wall, rep, ver))
        if with_traces:
            tsim, _, traced = min((simulate(sc, traces=True) for _ in range(n)), key=lambda r: r[0])
            tver = min(verify_wall(traced) for _ in range(n))
            size_rows.append((label, sim_s, len(data), len(traced), tver, tsim))
        else:
            size_rows.append((label, sim_s, len(data), None, None, sim_wall))

    print("Replay and verify speed (simulated s per wall s; ratio = x simulation speed)")
    head = (
        f"{'case':<20}{'sim s':>8}{'simulate':>11}{'replay':>11}{'ratio':>8}"
        f"{'verify':>11}{'ratio':>8}"
    )
    print(head)
    print("-" * len(head))
    for label, sim_s, sw, rep, ver in speed_rows:
        print(
            f"{label:<20}{sim_s:>8.1f}{sim_s / sw:>11.1f}{sim_s / rep:>11.0f}{sw / rep:>8.1f}"
            f"{sim_s / ver:>11.1f}{sw / ver:>8.2f}"
        )
    print()
    print("Log size per simulated second (zstd MCAP); with traces: simulate and verify speed")
    head = (
        f"{'case':<20}{'no traces':>12}{'traces':>12}{'ratio':>8}"
        f"{'simulate':>11}{'verify':>11}{'ratio':>8}"
    )
    print(head)
    print("-" * len(head))
    for label, sim_s, plain, traced, tver, tsim in size_rows:
        p = f"{plain / sim_s / 1024:.2f} KB/s"
        if traced is None:
            print(f"{label:<20}{p:>12}{'-':>12}{'-':>8}{'-':>11}{'-':>11}{'-':>8}")
            continue
        t = f"{traced / sim_s / 1024:.1f} KB/s"
        print(
            f"{label:<20}{p:>12}{t:>12}{traced / plain:>8.1f}{sim_s / tsim:>11.1f}"
            f"{sim_s / tver:>11.1f}{tsim / tver:>8.2f}"
        )
    print()
    print(
        "simulate: memory bus, MCAP log; verify ratio >= 1 meets the goal. With traces, "
        "verify also compares every logged resonator trace, byte for byte (ratio vs the "
        "traced simulation)."
    )


if __name__ == "__main__":
    main()
