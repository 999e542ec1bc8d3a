"""The protocol simulation: wall time for `gate` and a 10-unit group, both buses, with and
without logging, in one run.

    python -m benchmarks.bench_run [--repeat N]

Baselines measured in the same run: the memory bus (for zenoh's cost) and no logging (for the
cost of the full MCAP log, written zstd-compressed to memory). Goals (issue 4): gate under 1 s
wall on the memory bus; zenoh at most 1.5x memory; full logging at most 1.3x no logging.
"""

from __future__ import annotations

import argparse
import io
import random
import time
from pathlib import Path

from rgtbus.rgt import polynomial_to_graph, random_polynomial
from rgtbus.rgt.algebra import Universe
from rgtbus.scenario import Scenario, load_scenario, parse_scenario
from rgtbus.telemetry import McapRecorder, NullRecorder
from units.group import run_group

ROOT = Path(__file__).resolve().parent.parent


def group_scenario(n: int, seed: int = 10) -> Scenario:
    """n units on an automatic plan with 4-pulse generated codes (3 pulses fit 8 units in an
    octave), fixed relationships forming a random decomposable group, random influences."""
    rng = random.Random(seed)
    units = [f"u{i}" for i in range(n)]
    graph = polynomial_to_graph(random_polynomial(units, rng), units)
    u = Universe(("alpha", "beta"))
    lines = [
        f'name = "group{n}"',
        f"seed = {seed}",
        f"units = {units!r}".replace("'", '"'),
        'actions = ["alpha", "beta"]',
        'frequencies = "auto"',
        "[codebook]",
        'kind = "generated"',
        "pulses = 4",
        "[relations]",
        'policy = "fixed"',
        "[relations.fixed]",
    ]
    for s in units:
        for r in units:
            if s != r:
                rel = "alliance" if graph.allied(s, r) else "conflict"
                lines.append(f'"{s}>{r}" = "{rel}"')
    lines.append("[influences]")
    for s in units:
        for r in units:
            if s != r:
                lines.append(f'"{s}>{r}" = "{u.format(rng.randrange(4))}"')
    return parse_scenario("\n".join(lines) + "\n", f"<group{n}>")


def one_run(sc: Scenario, bus: str, logging: bool) -> tuple[float, float, int]:
    buf = io.BytesIO()
    rec = McapRecorder(buf) if logging else NullRecorder()
    t0 = time.perf_counter()
    out = run_group(sc, bus, rec)
    rec.close()
    wall = time.perf_counter() - t0
    if out.summary["error"]:
        raise SystemExit(f"{sc.name} on {bus} failed: {out.summary['error']}")
    return wall, out.summary["sim_seconds"], len(buf.getvalue())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="best of N runs (default 3)")
    args = ap.parse_args()
    cases = [
        (load_scenario(ROOT / "scenarios" / "gate.toml"), args.repeat),
        (group_scenario(10), 1),
    ]
    header = (
        f"{'scenario':<9} {'bus':<7} {'log':<5} {'wall s':>8} {'sim s':>8} "
        f"{'sim s / wall s':>15} {'log MB':>7} {'vs memory':>10} {'vs no log':>10}"
    )
    print(header)
    print("-" * len(header))
    for sc, repeat in cases:
        walls: dict[tuple[str, bool], float] = {}
        for bus in ("memory", "zenoh"):
            for logging in (False, True):
                best = None
                for _ in range(repeat):
                    r = one_run(sc, bus, logging)
                    best = r if best is None or r[0] < best[0] else best
                wall, sim, size = best
                walls[(bus, logging)] = wall
                vs_mem = wall / walls[("memory", logging)] if bus == "zenoh" else 1.0
                vs_log = wall / walls[(bus, False)] if logging else 1.0
                print(
                    f"{sc.name:<9} {bus:<7} {'full' if logging else 'none':<5} {wall:>8.3f} "
                    f"{sim:>8.1f} {sim / wall:>15.0f} {size / 1e6 if logging else 0:>7.2f} "
                    f"{vs_mem:>9.2f}x {vs_log:>9.2f}x"
                )


if __name__ == "__main__":
    main()
