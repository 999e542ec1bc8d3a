"""``rgtbus study``, ``rgtbus study-plot`` and ``rgtbus studies``: reflexive control over a noisy
medium, as curves with confidence (docs/studies.md)."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from rgtbus.interrupts import interrupted_by

if TYPE_CHECKING:
    from rgtbus.cli import SubParsers
    from rgtbus.units.study import PointEnd
    from rgtbus.units.study_spec import Point


def register(subparsers: SubParsers) -> None:
    """Add ``study``, ``study-plot`` and ``studies``."""
    p = subparsers.add_parser(
        "study",
        help="how often one unit steers another over a noisy medium: curves with intervals",
        description="Run a study file (a controller, a target and the alternative it is steered "
        "to, over a [grid] of channel points): each point runs until --failures target failures "
        "or --budget runs; DIR/points.csv (a row a point: shares with Wilson 95 %% intervals, "
        "symbol error beside the union bound, runs/s) and DIR/runs.csv (a row a run: its seed "
        "re-runs it). --resume finishes a study stopped halfway (docs/studies.md).",
    )
    p.add_argument("study", metavar="FILE", help="a study file, or a shipped study's name")
    p.add_argument("--out", metavar="DIR", help="its directory (default logs/studies/<name>)")
    p.add_argument("--budget", type=int, metavar="RUNS", help="runs a point at most (the file's)")
    p.add_argument(
        "--failures", type=int, metavar="N", help="stop a point at N target failures (the file's)"
    )
    p.add_argument(
        "--workers", type=int, metavar="N", help="local worker processes (default: all cores)"
    )
    p.add_argument(
        "--scheduler", metavar="ADDRESS", help="a Dask scheduler, e.g. tcp://127.0.0.1:8786"
    )
    p.add_argument("--resume", action="store_true", help="finish a study stopped halfway")
    p.add_argument("--quiet", action="store_true", help="no line as each point closes")
    p.add_argument("--json", action="store_true", help="print the points as JSON lines")
    p.set_defaults(func=run_study_cmd)

    q = subparsers.add_parser(
        "study-plot",
        help="a study's curves with their intervals and the bound, as PNG and SVG",
        description="Draw a study's points (DIR/points.csv): P(target steered) with its Wilson "
        "95 %% band and the clean channel's, and the payloads' symbol error rate beside the "
        "union bound, one curve per value of the grid's other axes.",
    )
    q.add_argument("dir", metavar="DIR", help="a study's directory")
    q.add_argument(
        "-o", "--output", metavar="PATH", help="PATH.png and PATH.svg (default DIR/study)"
    )
    q.add_argument("--title", help="figure title")
    q.add_argument("--json", action="store_true", help="print one JSON object")
    q.set_defaults(func=run_study_plot_cmd)

    s = subparsers.add_parser(
        "studies",
        help="the studies shipped with rgtbus (rgtbus study NAME)",
        description="List the shipped study files by name.",
    )
    s.add_argument("--json", action="store_true", help="one JSON object a study")
    s.set_defaults(func=run_studies_cmd)


def run_study_cmd(args: argparse.Namespace) -> int:
    """``rgtbus study FILE``: the library's ``study()``; a line as each point closes; the
    points table at the end. A stop (Ctrl-C, SIGTERM) says how to finish, exit 130."""
    from rgtbus.errors import BadInput
    from rgtbus.units.study import load_study, resume_command, run_study

    if args.workers is not None and args.workers < 1:
        raise BadInput(f"--workers must be at least 1, got {args.workers}")
    st = load_study(args.study)
    try:
        st = st.with_limits(args.failures, args.budget)
    except BadInput as exc:  # "budget: must be ..." -> "--budget: must be ..."
        raise BadInput(f"--{exc}") from None
    out = Path(args.out) if args.out else Path("logs") / "studies" / st.name

    def said(point: Point, end: PointEnd) -> None:
        if end.stopped == "early":
            what = "not run (an easier channel than a point with no failure)"
        else:
            what = f"{end.runs} runs, {end.failures} failures ({end.stopped})"
        line = f"{st.name}: {point.label()}: {what}"
        if bar is not None:
            bar.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr, flush=True)

    main_thread = threading.current_thread() is threading.main_thread()
    bar = None
    if not args.quiet and sys.stderr.isatty():  # runs as they come: a point may take minutes
        from tqdm import tqdm

        bar = tqdm(unit="run", desc=st.name, file=sys.stderr, leave=False)
    with interrupted_by(signal.SIGTERM, signal.SIGINT):
        try:
            got = run_study(
                st, out, workers=args.workers, scheduler=args.scheduler, resume=args.resume,
                progress=None if args.quiet else said,
                on_run=None if bar is None else bar.update,
            )  # fmt: skip
        except KeyboardInterrupt:
            if main_thread:
                signal.signal(signal.SIGINT, signal.SIG_IGN)
            print(
                f"rgtbus study: interrupted: every finished run is in {out / 'runs.jsonl'}; "
                f"to finish: {resume_command(args.study, out)}",
                file=sys.stderr,
                flush=True,
            )
            return 130
        finally:
            if bar is not None:
                bar.close()
    for note in got.notes:
        print(note, file=sys.stderr, flush=True)
    if args.json:  # an empty cell (a point not run) as null: NaN is no JSON
        plain = got.points.astype(object).where(got.points.notna(), None)
        for row in plain.to_dict("records"):
            print(json.dumps(row, default=str, allow_nan=False))
        return 0
    from tabulate import tabulate

    cols = [*st.keys, "runs", "failures", "p_target", "p_target_lo", "p_target_hi", "p_clean",
            "ser", "ser_bound", "runs_per_s"]  # fmt: skip
    table = got.points[cols]
    print(tabulate(table.values.tolist(), headers=cols, floatfmt=".4g"))
    from rgtbus.units.study import crossings

    axis = "σ" if st.axis == "noise" else "SNR (dB)"
    for row in crossings(got.points, st.keys).to_dict("records"):
        where = ", ".join(f"{k}={row[k]}" for k in st.keys[:-1])
        at = row["crossing"]
        if at is None or at != at:
            line = "does not fall below 0.9 on the points run"
        else:
            lo, hi = (row["earliest"], row["latest"])
            span = ", ".join("?" if v is None or v != v else f"{v:.4g}" for v in (lo, hi))
            line = f"falls below 0.9 at {axis} ≈ {at:.4g} (95 %: {span})"
        print(f"p_target {line}" + (f" ({where})" if where else ""))
    print(
        f"study {st.name}: {got.computed} runs in {got.seconds:.1f} s -> {out / 'points.csv'}, "
        f"{out / 'runs.csv'}"
    )
    return 0


def run_study_plot_cmd(args: argparse.Namespace) -> int:
    """``rgtbus study-plot DIR``: the curves as PNG and SVG."""
    from rgtbus.telemetry.study_plot import plot_study
    from rgtbus.units.study import read_study

    points, _ = read_study(args.dir)
    output = Path(args.output) if args.output else Path(args.dir) / "study"
    paths = plot_study(points, output, title=args.title)
    if args.json:
        print(json.dumps({"outputs": [str(p) for p in paths], "points": len(points)}))
        return 0
    for path in paths:
        print(f"wrote {path}")
    return 0


def run_studies_cmd(args: argparse.Namespace) -> int:
    """``rgtbus studies``: the shipped study files."""
    import tomllib

    from rgtbus.scenario.shipped import shipped_studies

    for path in shipped_studies():
        head = tomllib.loads(path.read_text("utf-8")).get("study", {})
        entry = {"name": path.stem, "path": str(path), "description": head.get("description", "")}
        if args.json:
            print(json.dumps(entry))
        else:
            print(f"{path.stem:<20} {entry['description']}")
    return 0
