"""Reading a log in bounded memory: ``rgtbus.open_log`` against reading every message.

    python -m benchmarks.bench_open_log [--big] [--scale N] [--repeat N]

Each case's log is written once (memory bus, zstd MCAP). Every measurement runs in a fresh
Python process (its peak RSS is ``ru_maxrss``, imports included), the baselines in the same
run: the Python ``mcap`` reader going over every message undecoded (its read rate, MB of file
a second, against ``open_log``'s: issue 51 asks 100 MB/s of a reader); ``read_log`` decodes
every message into Python objects, as ``open_log`` first did before issue 35 (it then also
expanded every spike and decode into a row object: 6.3 GB for the 3.5 MB group50 log). Then
``open_log`` alone, ``open_log`` + ``summary()``, + one unit's traces as a DataFrame
(``messages("/trace/<unit>")``), + ``spikes()``, + ``decodes()`` (built as columns since
issue 51: 890 MB for group50, as row objects, before). Goal (issue 35): a log opens in under
2x its size; a topic's frame costs about its own size; issue 51: 100 MB/s or more, in at most
its own size of memory (``rgtbus`` imported is the ``imports`` step: what every step pays
before it reads a byte). ``--big``: the traced group20 log (~104 MB in format 2; about 20 s to
write). ``--scale N``: an N-unit concurrent run's log (``bench_scale``'s group): its n²
tables and n³ decodes are what ``summary()`` reads.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

STEPS = {
    "imports": "pass",
    "mcap reader": (
        "from mcap.reader import make_reader\n"
        "with open(path, 'rb') as f:\n"
        "    for _ in make_reader(f).iter_messages(log_time_order=False): pass"
    ),
    "read_log": "from rgtbus.telemetry import read_log; read_log(path)",
    "open_log": "log = rgtbus.open_log(path)",
    "+summary": "log = rgtbus.open_log(path); log.summary()",
    "+traces": "log = rgtbus.open_log(path); log.messages(trace)",
    "+spikes": "log = rgtbus.open_log(path); log.spikes()",
    "+decodes": "log = rgtbus.open_log(path); log.decodes()",
}

_CHILD = """
import json, resource, sys, time
import rgtbus
path, trace = sys.argv[1], sys.argv[2]
t0 = time.perf_counter()
{step}
wall = time.perf_counter() - t0
print(json.dumps({{"wall": wall, "rss": peak_kib()}}))
"""

# The child's own peak (KiB): Linux's VmHWM, which exec resets; ru_maxrss keeps the peak of the
# process before its exec, which is the parent's size when it forked (the parent writes the
# logs, so every step read as at least its size).
_PEAK = """
def peak_kib():
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
"""


def write_log(scenario: str, traces: bool, path: Path) -> None:
    import rgtbus

    if scenario.startswith("scale"):  # an N-unit group of bench_scale's
        from benchmarks.bench_scale import scale_toml
        from rgtbus.scenario import parse_scenario

        n = int(scenario.removeprefix("scale"))
        sc = parse_scenario(scale_toml(n, "concurrent"), f"<scale{n}>")
        result = rgtbus.run(sc, bus="memory", log=path)
    else:
        result = rgtbus.run(ROOT / "scenarios" / scenario, bus="memory", log=path, traces=traces)
    if result.summary["error"]:
        raise SystemExit(f"{scenario} failed: {result.summary['error']}")


def rgtbus_units(path: Path) -> tuple[str, ...]:
    import rgtbus

    return rgtbus.open_log(path).units


def measure(step: str, path: Path, trace: str) -> tuple[float, float]:
    """(wall seconds, peak RSS in MiB) of ``step`` in a fresh process."""
    code = _PEAK + _CHILD.format(step=STEPS[step])
    out = subprocess.run(
        [sys.executable, "-c", code, str(path), trace],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
    )
    got = json.loads(out.stdout.strip().splitlines()[-1])
    return got["wall"], got["rss"] / 1024


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--big", action="store_true", help="also the traced group20 log (~330 MB)")
    ap.add_argument("--scale", type=int, default=0, help="also an N-unit concurrent run's log")
    ap.add_argument("--repeat", type=int, default=3, help="median of N runs of each step")
    ap.add_argument(
        "--skip", default="", help="steps left out, comma-separated (e.g. read_log,+spikes)"
    )
    args = ap.parse_args()
    skip = set(filter(None, args.skip.split(",")))
    if skip - set(STEPS):
        bad = sorted(skip - set(STEPS))[0]
        raise SystemExit(f"--skip: no step {bad!r} (steps: {', '.join(STEPS)})")
    steps = [s for s in STEPS if s not in skip]
    if "imports" not in steps:
        steps.insert(0, "imports")
    cases = [("group6 traced", "group6.toml", True), ("group50", "group50.toml", False)]
    if args.big:
        cases.append(("group20 traced", "group20.toml", True))
    if args.scale:
        cases.append((f"{args.scale} units", f"scale{args.scale}", False))
    with tempfile.TemporaryDirectory() as tmp:
        rows = []
        for label, scenario, traces in cases:
            path = Path(tmp) / f"{label.replace(' ', '-')}.mcap"
            write_log(scenario, traces, path)
            size = path.stat().st_size / 2**20
            trace = "/trace/" + rgtbus_units(path)[0] if traces else "/log"
            got = {}
            for step in steps:
                runs = [measure(step, path, trace) for _ in range(args.repeat)]
                got[step] = (
                    statistics.median(w for w, _ in runs),
                    statistics.median(r for _, r in runs),
                )
            rows.append((label, size, got))
            print(f"{label}: done", file=sys.stderr)
    print("Peak RSS (MiB, imports included) and wall (s), median of", args.repeat, "runs")
    head = (
        f"{'case':<16}{'file MiB':>9}" + "".join(f"{s:>18}" for s in steps) + f"{'open/read':>10}"
    )
    print(head)
    print("-" * len(head))
    for label, size, got in rows:
        cells = "".join(f"{got[s][1]:>9.0f} /{got[s][0]:>6.2f}s" for s in steps)
        ratio = got["open_log"][1] / got["read_log"][1] if "read_log" in got else math.nan
        print(f"{label:<16}{size:>9.1f}{cells}{ratio:>10.2f}")
    print()
    print("Read rate (MB of file a second, median wall) and memory over the imports' (MiB)")
    for label, size, got in rows:
        mb = size * 2**20 / 1e6
        base = got["imports"][1]
        cells = ", ".join(
            f"{s} {mb / got[s][0]:.1f} MB/s +{got[s][1] - base:.0f} MiB"
            for s in ("mcap reader", "open_log", "+summary")
            if s in got
        )
        print(f"{label:<16}{cells}")
    print()
    print(
        "read_log: every message decoded (the baseline); "
        "+traces: one unit's traces as a DataFrame (/log where untraced). Goal: open_log "
        "under 2x the file size."
    )


if __name__ == "__main__":
    main()
