"""Where a run's log goes, topic by topic, against the run without a log.

    python -m benchmarks.bench_log_topics [--sizes 50,100] [--repeat R]

Per n (a seeded decomposable group under the concurrent schedule, as ``bench_scale``'s), in
fresh processes over the memory bus: the run without a log (the baseline) and with its full
MCAP log (zstd, as ``rgtbus run --log`` writes it). For the logged run, per topic: messages,
bytes before compression, those bytes compressed alone by zstd at the recorder's level (what
the topic adds to the file, near enough: chunks mix topics), and the CPU seconds its records
took to encode (the recorder's ``_encode``: checks, block columns or JSON). The last line per
n is the log's total against the baseline: issue 51 asks log / no log <= 1.5x at n = 100 and
200. Medians of ``--repeat`` runs (default 1) for the walls; the split is the last run's. The
logged run here also times every encode and keeps every message's bytes (to compress each
topic alone): its wall is a little above ``bench_scale``'s, which is the one to quote.
"""

from __future__ import annotations

import argparse
import io
import json
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


def child(n: int, logged: bool) -> dict[str, Any]:
    """In a child process: one run's wall, and (logged) its per-topic split."""
    import zstandard
    from rgtbus.units.group import run_group

    from benchmarks.bench_scale import scale_toml
    from rgtbus.scenario import parse_scenario
    from rgtbus.telemetry import McapRecorder, NullRecorder

    sc = parse_scenario(scale_toml(n, "concurrent"), f"<scale{n}>")
    split: dict[str, list[Any]] = defaultdict(lambda: [0, 0, 0.0, []])

    class Timed(McapRecorder):
        """The recorder, its encoding timed and its bytes kept per topic."""

        def _encode(self, topic: str, message: Any, t_ns: int) -> tuple[str, bytes, int]:
            t0 = time.process_time()
            out = super()._encode(topic, message, t_ns)
            row = split["/trace/*" if topic.startswith("/trace/") else topic]
            row[2] += time.process_time() - t0
            row[0] += 1
            row[1] += len(out[1])
            row[3].append(out[1])
            return out

    buf = io.BytesIO()
    rec = Timed(buf) if logged else NullRecorder()
    t0 = time.perf_counter()
    run_group(sc, "memory", rec)
    rec.close()
    wall = time.perf_counter() - t0
    level = zstandard.ZstdCompressor(level=1)
    topics = {
        topic: {
            "messages": row[0],
            "raw_mb": row[1] / 1e6,
            "zstd_mb": len(level.compress(b"".join(row[3]))) / 1e6,
            "encode_s": row[2],
        }
        for topic, row in split.items()
    }
    return {"wall": wall, "file_mb": buf.tell() / 1e6, "topics": topics}


def measure(n: int, logged: bool) -> dict[str, Any]:
    argv = [sys.executable, "-m", "benchmarks.bench_log_topics", "--child", str(n)]
    out = subprocess.run(
        [*argv, "--logged"] if logged else argv,
        capture_output=True, text=True, cwd=ROOT, check=True,
    )  # fmt: skip
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def table(n: int, repeat: int) -> None:
    bare = [measure(n, False)["wall"] for _ in range(repeat)]
    runs = [measure(n, True) for _ in range(repeat)]
    base, wall = statistics.median(bare), statistics.median(r["wall"] for r in runs)
    last = runs[-1]
    print(f"### n = {n}: no log {base:.2f} s, full log {wall:.2f} s, "
          f"log / no log {wall / base:.2f}x, file {last['file_mb']:.2f} MB")  # fmt: skip
    print()
    print("| topic | messages | MB before compression | MB zstd alone | encode CPU s |")
    print("|---|---|---|---|---|")
    rows = sorted(last["topics"].items(), key=lambda kv: -kv[1]["raw_mb"])
    for topic, r in rows:
        print(f"| `{topic}` | {r['messages']:,} | {r['raw_mb']:.2f} | {r['zstd_mb']:.2f} | "
              f"{r['encode_s']:.3f} |")  # fmt: skip
    total = {k: sum(r[k] for _, r in rows) for k in ("messages", "raw_mb", "zstd_mb", "encode_s")}
    print(f"| all | {total['messages']:,} | {total['raw_mb']:.2f} | {total['zstd_mb']:.2f} | "
          f"{total['encode_s']:.3f} |")  # fmt: skip
    print()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="50,100", help="group sizes")
    ap.add_argument("--repeat", type=int, default=1, help="runs per wall (median)")
    ap.add_argument("--child", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--logged", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        print(json.dumps(child(args.child, args.logged)))
        return
    print("## The log topic by topic (memory bus, concurrent schedule, fresh processes)")
    print()
    for n in [int(x) for x in args.sizes.split(",") if x]:
        table(n, max(1, args.repeat))
    print("MB zstd alone: the topic's messages compressed together at level 1, apart from the")
    print("others (the file's chunks mix topics); encode CPU: the recorder's checks and encoding.")


if __name__ == "__main__":
    main()
