"""``rgtbus sweep`` and ``rgtbus sweep-plot``: experiments across seeds and parameters."""

from __future__ import annotations

import argparse
import json
import shlex
import signal
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from rgtbus.interrupts import interrupted_by

if TYPE_CHECKING:
    from rgtbus.cli import SubParsers


def register(subparsers: SubParsers) -> None:
    """Add ``sweep`` and ``sweep-plot``."""
    p = subparsers.add_parser(
        "sweep",
        help="run a scenario over seeds and a grid of keys; a table of results",
        description="Run a sweep file (a base scenario, seeds and a [grid] of scenario keys) on "
        "local worker processes or a Dask distributed cluster; one row per run in "
        "DIR/results.jsonl and DIR/results.csv, one per run, unit and round in "
        "DIR/decisions.jsonl, and both as Parquet where pyarrow is installed "
        "(rgtbus[parquet]; docs/sweeps.md).",
    )
    p.add_argument(
        "sweep", metavar="SWEEP", help="a sweep file, e.g. scenarios/sweeps/gate_noise.toml"
    )
    p.add_argument("--out", metavar="DIR", help="results directory (default logs/sweeps/<name>)")
    p.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="local worker processes (default: all cores; 1: in this process)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="a Dask scheduler, e.g. tcp://127.0.0.1:8786 (dask scheduler / dask worker)",
    )
    p.add_argument("--resume", action="store_true", help="finish a sweep stopped halfway")
    p.add_argument("--logs", action="store_true", help="an MCAP log per run (DIR/logs)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the rows as JSON lines")
    p.set_defaults(func=run_sweep_cmd)

    q = subparsers.add_parser(
        "sweep-plot",
        help="a metric against a parameter across a sweep's runs, with 95 %% intervals",
        description="Draw a metric of a sweep's results against one of its grid keys, mean "
        "over seeds with a 95 %% interval (Wilson for yes/no metrics), as a PNG.",
    )
    q.add_argument("dir", metavar="DIR", help="a sweep's results directory")
    q.add_argument("--x", required=True, metavar="KEY", help="grid key on the x axis")
    q.add_argument(
        "--y",
        required=True,
        action="append",
        metavar="METRIC",
        help="a column (number or yes/no, e.g. decomposable, decode_error_count), or "
        "COLUMN=VALUE for the share of runs where it equals VALUE (e.g. 'outcome=gate: open'); "
        "repeat for panels side by side",
    )
    q.add_argument("--by", metavar="KEY", help="one curve per value of this grid key")
    q.add_argument(
        "--where",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="only the runs whose KEY is VALUE (e.g. protocol.influence_rounds=1); repeatable",
    )
    q.add_argument(
        "--exact",
        choices=("cograph", "alliance"),
        help="draw the exact curve too: cograph (P that G(n, p²) is decomposable; needs n and "
        "relations.p as --x/--by) or alliance (p², --x relations.p)",
    )
    q.add_argument("-o", "--output", metavar="PNG", help="default DIR/<y>[+<y>...]-vs-<x>.png")
    q.add_argument("--title", help="figure title")
    q.add_argument("--json", action="store_true", help="print one JSON object")
    q.set_defaults(func=run_sweep_plot_cmd)


def run_sweep_cmd(args: argparse.Namespace) -> int:
    """``rgtbus sweep SWEEP``: ``execute_sweep`` on the file's ``Sweep``; a stop (Ctrl-C,
    SIGTERM) says how many runs are kept and how to finish, exit 130."""
    from rgtbus.errors import BadInput
    from rgtbus.units.sweep import execute_sweep, load_sweep

    if args.workers is not None and args.workers < 1:
        raise BadInput(f"--workers must be at least 1, got {args.workers}")
    # the same call as rgtbus.sweep(): a Sweep (here from the file) run by execute_sweep
    sweep = load_sweep(args.sweep)
    out = Path(args.out) if args.out else Path("logs") / "sweeps" / sweep.name
    # SIGTERM (a scheduler or a supervisor stopping the sweep) stops it like Ctrl-C
    main_thread = threading.current_thread() is threading.main_thread()
    with interrupted_by(signal.SIGTERM, signal.SIGINT):
        try:
            rows = execute_sweep(
                sweep,
                out,
                workers=args.workers,
                scheduler=args.scheduler,
                resume=args.resume,
                logs=args.logs,
                progress=not args.quiet and sys.stderr.isatty(),
            )
        except KeyboardInterrupt:
            if main_thread:  # a second Ctrl-C does not cut the note short
                signal.signal(signal.SIGINT, signal.SIG_IGN)
            print(_interrupted(args, sweep.runs, out), file=sys.stderr, flush=True)
            return 130
    for note in rows.notes:  # said even with --quiet: a run is run again
        print(note, file=sys.stderr, flush=True)
    failed = sum(1 for r in rows if r.get("failed"))
    if args.json:
        for r in rows:
            print(json.dumps(r))
    else:
        from rgtbus.telemetry.sweep_tables import PARQUET_FILES, TABLE_FILES

        written = [str(out / f) for f in (*PARQUET_FILES, *TABLE_FILES) if (out / f).is_file()]
        print(
            f"sweep {sweep.name}: {len(rows)} runs ({failed} ended with an error) -> "
            + ", ".join(written)
        )
        if not (out / PARQUET_FILES[0]).is_file():
            print(
                "no Parquet tables: they need pyarrow, which rgtbus leaves to its 'parquet' "
                "extra: pip install 'rgtbus[parquet]'",
                file=sys.stderr,
            )
    return 0


def _interrupted(args: argparse.Namespace, runs: int, out: Path) -> str:
    """The one line of a stopped sweep: how many runs are kept, and how to finish."""
    rows = out / "rows.jsonl"
    try:
        with open(rows, "rb") as f:
            kept = sum(chunk.count(b"\n") for chunk in iter(lambda: f.read(1 << 20), b""))
    except OSError:
        kept = 0
    again = ["rgtbus", "sweep", args.sweep, "--out", str(out), "--resume"]
    if args.workers:
        again[-1:-1] = ["--workers", str(args.workers)]
    if args.scheduler:
        again[-1:-1] = ["--scheduler", args.scheduler]
    return (
        f"rgtbus sweep: interrupted: {kept} of {runs} runs are in {rows}; to finish: "
        + " ".join(shlex.quote(a) for a in again)
    )


def run_sweep_plot_cmd(args: argparse.Namespace) -> int:
    """``rgtbus sweep-plot DIR``: a metric against a grid key, as a PNG."""
    from rgtbus.telemetry.sweep_plot import plot_sweep

    path = plot_sweep(
        Path(args.dir),
        args.x,
        args.y,
        by=args.by,
        output=args.output,
        title=args.title,
        exact=args.exact,
        where=args.where,
    )
    if args.json:
        print(json.dumps({"output": str(path), "x": args.x, "y": list(args.y), "by": args.by}))
        return 0
    print(f"wrote {path}")
    return 0
