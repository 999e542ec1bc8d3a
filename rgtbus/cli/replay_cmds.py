"""``rgtbus replay LOG`` (timeline, --verify, --plot, --csv) and ``rgtbus merge``."""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO, TypeVar

from rgtbus.cli import add_quiet_argument
from rgtbus.cli.tables import (
    fitted_table_lines,
    relations_lines,
    table_lines,
    wrapped_table_lines,
)
from rgtbus.errors import BadInput, IOFailure, RgtbusError
from rgtbus.extras import require
from rgtbus.telemetry.untrusted import printable

if TYPE_CHECKING:
    from rgtbus.cli import SubParsers
    from rgtbus.telemetry.read import Replay
    from rgtbus.telemetry.transmissions import DecodeRow

# simulated seconds (from, to) the timeline, CSV tables and plot are cut to; None: open
Span = tuple[float | None, float | None]

SERVE_ADDRESS = "127.0.0.1:8765"  # --serve's default (rgtbus.telemetry.live.DEFAULT_ADDRESS)
_EXIT_LINGER = 5.0  # s: --exit-at-end gives the clients this long to leave once played out


def register(subparsers: SubParsers) -> None:
    """Add ``replay`` and ``merge``."""
    p = subparsers.add_parser(
        "replay",
        help="read a run's MCAP log: timeline, verification, plots, CSV tables; --serve it "
        "to Foxglove",
        description="Read a run back from its MCAP log. Without options: what happened, in "
        "order (transmissions with their decodes, spikes, tables, decisions, outcome). "
        "--verify re-runs every unit's receiver and reasoning on the logged medium and lists "
        "each disagreement (exit 0: verified; 1: mismatches; 3: truncated log, everything read "
        "agrees (3 without --verify too); 2: unreadable, corrupt, header-only or not an rgtbus "
        "log). --serve plays the log to Foxglove over its WebSocket protocol (Open connection, "
        "Foxglove WebSocket, ws://HOST:PORT): every channel as the log holds it, on the log's "
        "own clock, with a playback bar to play, pause, seek and set the speed (0.1 to 100x); "
        "it serves until Ctrl-C (exit 3 for a log that stops short: served as far as it reads).",
    )
    p.add_argument("log", metavar="LOG", help="an MCAP log written by rgtbus run")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--verify", action="store_true", help="re-run the units and compare")
    p.add_argument("--plot", metavar="OUT.png", help="the activity-of-unit figure as PNG")
    p.add_argument("--unit", metavar="NAME", help="unit to plot (default: the first)")
    p.add_argument(
        "--from",
        dest="t_from",
        type=float,
        metavar="T",
        help="the timeline, CSV tables and plot from T simulated s",
    )
    p.add_argument("--to", dest="t_to", type=float, metavar="T", help="... up to T simulated s")
    p.add_argument("--csv", metavar="DIR", help="write transmissions/decodes/decisions/spikes.csv")
    p.add_argument(
        "--serve",
        nargs="?",
        const=SERVE_ADDRESS,
        metavar="HOST:PORT",
        help=f"serve the log to Foxglove, with play, pause, seek and speed (default "
        f"{SERVE_ADDRESS}; port 0: a free one); until Ctrl-C",
    )
    p.add_argument(
        "--speed",
        metavar="X",
        help="with --serve: play at X times the log's own pace (0.1 to 100; default 1)",
    )
    p.add_argument(
        "--paused",
        action="store_true",
        help="with --serve: wait for a client's play (default: play once a client subscribes)",
    )
    p.add_argument(
        "--exit-at-end",
        action="store_true",
        help="with --serve: stop serving once the log has played to its end (and the "
        "clients have left, 5 s at most)",
    )
    add_quiet_argument(p)
    p.set_defaults(func=replay)

    m = subparsers.add_parser(
        "merge",
        help="merge per-process MCAP logs into one time-ordered log",
        description="Merge MCAP logs into one, ordered by log time: schemas and channels shared "
        "when identical, byte-identical messages (same topic and time) kept once, metadata "
        "kept once when identical, differing records with the same name kept as NAME.K "
        "(K = the input's position).",
    )
    m.add_argument("inputs", nargs="+", metavar="LOG", help="input MCAP logs")
    m.add_argument("-o", "--output", required=True, metavar="OUT.mcap", help="merged log")
    m.add_argument(
        "--keep-duplicates",
        action="store_true",
        help="keep byte-identical messages, and each process's record of spikes its units "
        "heard alike",
    )
    m.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")
    m.add_argument("--json", action="store_true", help="print one JSON object")
    add_quiet_argument(m)
    m.set_defaults(func=merge)

    r = subparsers.add_parser(
        "recover",
        help="a complete MCAP file from a cut or damaged log",
        description="Read LOG as far as it goes (to its cut, or to its first damaged record: "
        "every chunk CRC-checked) and write everything read as a complete MCAP file: summary, "
        "statistics, indexes and CRCs, for every MCAP reader. rgtbus still reads the result "
        "as cut where LOG ended.",
    )
    r.add_argument("log", metavar="LOG", help="the cut or damaged MCAP log")
    r.add_argument("-o", "--output", required=True, metavar="OUT.mcap", help="recovered log")
    r.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")
    r.add_argument("--json", action="store_true", help="print one JSON object")
    add_quiet_argument(r)
    r.set_defaults(func=recover)

    c = subparsers.add_parser(
        "convert",
        help="write a log of format 1 (before 2) as format 2",
        description="Write LOG, an rgtbus log of format 1 (every topic JSON), as a log of "
        "format 2 (docs/format.md): the hot topics as protobuf blocks, every other topic and "
        "the metadata as they are. A log cut short is converted up to its cut and stays cut; "
        "a damaged one is refused (recover needs format 2: convert what a cut file holds).",
    )
    c.add_argument("log", metavar="LOG", help="the format-1 MCAP log")
    c.add_argument("-o", "--output", required=True, metavar="OUT.mcap", help="the format-2 log")
    c.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")
    c.add_argument("--json", action="store_true", help="print one JSON object")
    add_quiet_argument(c)
    c.set_defaults(func=convert)


def replay(args: argparse.Namespace) -> int:
    """``rgtbus replay LOG``: the options checked, the log loaded; ``_replay`` does the rest
    (``--serve``: ``_serve``)."""
    from rgtbus.telemetry.read import load_replay
    from rgtbus.telemetry.untrusted import explained

    if args.serve is not None:
        return _serve(args)
    for flag, given in (("--speed", args.speed is not None), ("--paused", args.paused),
                        ("--exit-at-end", args.exit_at_end)):  # fmt: skip
        if given:
            raise BadInput(f"{flag} goes with --serve")
    if args.plot is None and args.unit:
        raise BadInput("--unit goes with --plot OUT.png")
    if args.plot is not None:  # before the log is read: the plot is what was asked for
        require("matplotlib", "--plot")
    if (args.t_from is not None or args.t_to is not None) and (args.verify or args.json):
        raise BadInput("--from and --to go with the timeline, --csv and --plot")
    from rgtbus.telemetry.untrusted import printable_errors, printable_lines

    with printable_errors():  # an error quoting the log is printed escaped
        rp = load_replay(args.log)
        with explained(rp.messages, rp.label):  # a message that breaks its schema: exit 2
            if args.json:  # JSON escapes every control character itself
                return _replay(rp, args)
            with printable_lines():  # what the log holds cannot forge lines on the screen
                return _replay(rp, args)


def _replay(rp: Replay, args: argparse.Namespace) -> int:
    from rgtbus.telemetry.log_cat import check_time_range
    from rgtbus.telemetry.verify import EXIT_TRUNCATED

    span = None
    if args.t_from is not None or args.t_to is not None:
        check_time_range(args.t_from, args.t_to, 0.0, rp.sim_seconds)
        span = (args.t_from, args.t_to)
    timeline = not (args.json or args.verify or args.csv or args.plot)
    if rp.truncated and not timeline and (args.json or not args.verify):
        print(f"note: {rp.note}", file=sys.stderr)  # the text reports print it themselves
    side = []
    if args.csv:
        side.append(_write_csv(rp, Path(args.csv), span))
    if args.plot:
        side.append(_plot(rp, args))
    for line in side if not args.quiet else ():
        print(line, file=sys.stderr)
    if args.verify:
        from rgtbus.units.rerun import verify_log

        report = verify_log(rp)
        if args.json:
            print(json.dumps(report.to_json()))
        else:
            for mm in report.mismatches:
                print(mm.text())
            if report.truncated:
                print(f"note: {report.note}")
            print(report.verdict())
        return report.exit_code
    if args.json:
        print(json.dumps(rp.to_json()))
    elif timeline:
        print_timeline(rp, span)
    # A log that ends early was read as far as it goes: say so in the exit code too.
    return EXIT_TRUNCATED if rp.truncated else 0


def _serve(args: argparse.Namespace) -> int:
    """``rgtbus replay LOG --serve [HOST:PORT]``: the log served (``LogServer``) until Ctrl-C
    or SIGTERM (or its end, ``--exit-at-end``); its address on stderr as it starts, what it
    sent at the end (``--json``: one object). Exit 0, or 3 for a log that stops short (a cut,
    damage: served as far as it reads)."""
    import signal
    import threading

    from rgtbus.telemetry.live import parse_address
    from rgtbus.telemetry.serve import LogServer, check_speed, index_log
    from rgtbus.telemetry.verify import EXIT_TRUNCATED
    from rgtbus.timebase import seconds

    others = [flag for flag, given in (
        ("--verify", args.verify), ("--plot", args.plot is not None), ("--unit", args.unit),
        ("--from", args.t_from is not None), ("--to", args.t_to is not None),
        ("--csv", args.csv is not None),
    ) if given]  # fmt: skip
    if others:
        raise BadInput(f"--serve goes alone (not with {', '.join(others)})")
    speed = 1.0
    if args.speed is not None:
        try:
            speed = float(args.speed)
        except ValueError:
            raise BadInput(f"--speed {args.speed!r}: not a number") from None
        check_speed(speed, "--speed")
    host, port = parse_address(args.serve, "--serve")
    index = index_log(args.log)
    stop = threading.Event()
    old: dict[signal.Signals, Any] = {}
    if threading.current_thread() is threading.main_thread():  # (where handlers can be set)
        for sig in (signal.SIGINT, signal.SIGTERM):  # Ctrl-C or SIGTERM: stop serving
            old[sig] = signal.signal(sig, lambda *_: stop.set())
    linger = 0.0
    try:
        server = LogServer(index, host, port, speed=speed, autoplay=not args.paused)
        try:
            _serve_start(server, args)  # even --quiet: the address (port 0: the one taken)
            if index.note:
                print(f"note: {printable(index.note)}; served up to there", file=sys.stderr)
            while not stop.wait(0.1):
                if args.exit_at_end and server.wait_ended(0):
                    linger = _EXIT_LINGER  # the clients take the last messages, and leave
                    break
        finally:
            server.close(linger)
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
    ended = server.state()["status"] == "ended"
    if args.json:
        print(json.dumps({
            "url": server.url, "log": index.path, "messages": index.messages,
            "sent": server.sent, "seeks": server.seeks, "ended": ended,
            "start": seconds(index.start_ns), "end": seconds(index.end_ns),
            "note": index.note, "problem": server.problem,
        }))  # fmt: skip
    elif not args.quiet:
        print(
            f"served {printable(index.path)} on {server.url}: {server.sent} messages sent "
            f"({index.messages} in the log), {server.seeks} seeks"
            + ("; played to its end" if ended else "")
        )
    return EXIT_TRUNCATED if index.note or server.problem else 0


def _serve_start(server: Any, args: argparse.Namespace) -> None:
    """The line saying where the log is served (stderr: stdout is the result's)."""
    from rgtbus.timebase import seconds

    ix = server.index
    how = "paused: play from Foxglove" if args.paused else "plays once a client subscribes"
    print(
        f"serving {printable(ix.path)} on {server.url} (Foxglove: Open connection, Foxglove "
        f"WebSocket): {ix.messages} messages, {seconds(ix.start_ns):g} to {seconds(ix.end_ns):g} s "
        f"of log time; {how}; Ctrl-C stops",
        file=sys.stderr,
        flush=True,
    )


def _write_csv(rp: Replay, out: Path, span: Span | None) -> str:
    from rgtbus.telemetry.export import csv_tables, write_csv

    tables = csv_tables(rp, span)
    try:
        out.mkdir(parents=True, exist_ok=True)
        for name, (header, rows) in tables.items():
            with open(out / name, "w", newline="", encoding="utf-8") as f:
                write_csv(header, rows, f)
    except OSError as e:
        raise IOFailure(f"--csv {str(out)!r}: {e.strerror}") from None
    return f"wrote {', '.join(tables)} to {out}"


def _plot(rp: Replay, args: argparse.Namespace) -> str:
    from rgtbus.telemetry.plots import activity_figure, save_png
    from rgtbus.units.rerun import traces_for

    unit = args.unit or (rp.units[0] if rp.units else None)
    if unit is None or unit not in rp.units:
        raise BadInput(f"--unit {unit!r}: not a unit of this log (units: {', '.join(rp.units)})")
    trace = traces_for(rp, unit)
    fig = activity_figure(rp, unit, trace, t_from=args.t_from, t_to=args.t_to)
    try:
        with open(args.plot, "wb") as f:
            save_png(fig, f)
    except OSError as e:
        raise IOFailure(f"--plot {args.plot!r}: {e.strerror}") from None
    src = "recomputed" if trace["recomputed"] else "logged"
    return f"wrote {args.plot} (unit {unit}, {src} resonator trace)"


_T = TypeVar("_T")


def _one_writer(out: Path, inputs: Sequence[str]) -> None:
    """One writer, always: no log written over, nor read from, while a run writes it."""
    from rgtbus.telemetry.logfile import refuse_if_being_written

    refuse_if_being_written(out, "-o")
    for src in inputs:
        refuse_if_being_written(src, "input")


def _written_whole(out: Path, write: Callable[[BinaryIO], _T]) -> _T:
    """``write(stream)`` to ``out`` whole or not at all (through ``OUT.part``); a run that
    began writing ``out`` meanwhile keeps its log. What ``write`` returned."""
    from rgtbus.telemetry.logfile import refuse_if_being_written

    tmp = out.with_name(out.name + ".part")
    try:
        with open(tmp, "wb") as f:
            result = write(f)
        refuse_if_being_written(out, "-o")
        os.replace(tmp, out)
    except RgtbusError:  # already one line (an IOFailure is an OSError too)
        raise
    except OSError as e:
        raise IOFailure(f"-o {str(out)!r}: {e.strerror}") from None
    finally:
        if tmp.exists():
            tmp.unlink()
    return result


def merge(args: argparse.Namespace) -> int:
    """``rgtbus merge LOG... -o OUT``: run logs merged into one, written whole or not at all
    (through ``OUT.part``)."""
    from rgtbus.telemetry.merge import merge_logs
    from rgtbus.telemetry.scan import require_run_log, scan_log

    out = Path(args.output)
    for src in args.inputs:
        if os.path.exists(src) and out.exists() and os.path.samefile(src, out):
            raise BadInput(f"-o {args.output!r}: is also an input")
    _one_writer(out, args.inputs)
    logs = [scan_log(src) for src in args.inputs]
    for log in logs:
        try:
            require_run_log(log)  # corrupt, header-only or foreign: exit 2 naming the file
        except RgtbusError as e:
            raise BadInput(f"{e}; not merged") from None
    res = _written_whole(
        out,
        lambda f: merge_logs(
            logs, f, compression=args.compression, dedupe=not args.keep_duplicates
        ),
    )
    for note in res.notes:
        print(f"warning: {note}; merged as far as it goes", file=sys.stderr)
    if args.json:
        print(json.dumps({"output": str(out), "inputs": list(args.inputs), **asdict(res)}))
        return 0
    renamed = "; ".join(f"{k} -> {v}" for k, v in res.renamed.items())
    print(
        f"merged {len(logs)} logs into {out}: {res.messages} messages "
        f"({res.duplicates} duplicates dropped, {res.joined} records of spikes heard alike "
        f"joined), {res.channels} channels, {res.schemas} schemas, "
        f"metadata {', '.join(res.metadata)}" + (f" (renamed: {renamed})" if renamed else "")
    )
    return 0


def recover(args: argparse.Namespace) -> int:
    """``rgtbus recover LOG -o OUT``: ``recover_log``, written whole or not at all (through
    ``OUT.part``); one line saying what it kept and where LOG ended."""
    from rgtbus.telemetry.merge import recover_log
    from rgtbus.telemetry.scan import scan_log

    out = Path(args.output)
    if os.path.exists(args.log) and out.exists() and os.path.samefile(args.log, out):
        raise BadInput(f"-o {args.output!r}: is the log to recover (write it elsewhere)")
    _one_writer(out, [args.log])
    log = scan_log(args.log)  # not an MCAP file at all: one line, exit 2
    res = _written_whole(out, lambda f: recover_log(log, f, compression=args.compression))
    if args.json:
        print(json.dumps({"output": str(out), "input": args.log, **asdict(res)}))
    elif not args.quiet:
        how = f"it ended early: {res.ended}" if res.ended else "it was whole"
        print(f"recovered {res.messages} messages of {args.log} into {out}; {how}")
    return 0


def convert(args: argparse.Namespace) -> int:
    """``rgtbus convert LOG -o OUT``: ``convert_log``, written whole or not at all (through
    ``OUT.part``); one line saying what it wrote."""
    from rgtbus.telemetry.convert import convert_log
    from rgtbus.telemetry.scan import scan_log

    out = Path(args.output)
    if os.path.exists(args.log) and out.exists() and os.path.samefile(args.log, out):
        raise BadInput(f"-o {args.output!r}: is the log to convert (write it elsewhere)")
    _one_writer(out, [args.log])
    log = scan_log(args.log)  # not an MCAP file at all: one line, exit 2
    res = _written_whole(
        out, lambda f: convert_log(log, f, compression=args.compression, source=args.log)
    )
    if args.json:
        print(json.dumps({"output": str(out), "input": args.log, **asdict(res)}))
    elif not args.quiet:
        how = f"; it ended early: {res.ended}" if res.ended else ""
        print(
            f"converted {res.read} messages of {printable(args.log)} (format 1) into "
            f"{res.written} of {out} (format 2){printable(how)}"
        )
    return 0


# -- the timeline ---------------------------------------------------------------------------


def _alt(rp: Replay, v: Any) -> str:
    if v is None:
        return "none"
    u = rp.scenario.universe if rp.scenario else None
    return u.format(u.from_list(v)) if u else "{" + ",".join(v) + "}"


def print_timeline(rp: Replay, span: Span | None = None) -> None:
    """What happened, in order; with ``span`` (from, to) only what happens in it."""
    rp.read_tables()
    info = {k: printable(v) if isinstance(v, str) else v for k, v in rp.info().items()}
    s = rp.summary()
    units = list(rp.units)  # a scenario's unit names are plain (printable_lines: the rest)
    _print_head(rp, info, s, units, span)
    _print_transmissions(rp, span)
    print("spikes per unit (rows) and channel (columns):")
    counts = rp.spike_counts(span)
    spike_rows = [[u, *(str(counts.get(u, {}).get(c, 0)) for c in units)] for u in units]
    align = ["left", *(["right"] * len(units))]
    for line in wrapped_table_lines(spike_rows, ["", *units], align=align):
        print(line)
    _print_relations(rp, s, units, span)
    _print_decisions(rp, span)
    if s["outcome"] is not None:
        print(f"outcome: {printable(s['outcome'])}")
    _print_ending(rp, s, units)


def _print_head(
    rp: Replay, info: dict[str, Any], s: dict[str, Any], units: list[str], span: Span | None
) -> None:
    """The log (``info``: its metadata), its run and what part of it is shown."""
    print(
        f"log {printable(rp.label)}: scenario {info['scenario']} ({info['path']}), "
        f"seed {info['seed']}, "
        f"rgtbus {info['version']}, bus {info['bus']}, run {info['run_id']}"
    )
    print(
        f"units {', '.join(units)}; {s['sim_seconds']:g} s simulated; {rp.message_count()} messages"
    )
    if rp.truncated:
        print(f"NOTE: {printable(rp.note)}")
    if span is not None:
        lo = "start" if span[0] is None else f"{span[0]:g} s"
        hi = "end" if span[1] is None else f"{span[1]:g} s"
        print(f"showing {lo} to {hi} (--from/--to)")


def _print_transmissions(rp: Replay, span: Span | None) -> None:
    """Every transmission in ``span`` with its decodes (one row each), then the decodes'
    count, mismatches and smallest margin."""
    from rgtbus.telemetry.read import in_span

    txs = [tx for tx in rp.transmissions if in_span(tx.start, span, until=tx.end)]
    decodes = [d for d in rp.decodes if in_span(d.t, span)]
    by_tx: dict[tuple[int | None, str], list[DecodeRow]] = {}
    for d in decodes:
        key = (d.turn, "id" if d.kind == "id" else "payload")
        by_tx.setdefault(key, []).append(d)
    print(
        f"transmissions ({len(txs)}), each with its decodes "
        "(unit ✓/✗ margin; ✗ = not what was sent):"
    )
    rows = []
    for tx in txs:
        decs = by_tx.get((tx.turn, tx.kind), [])
        marks = "  ".join(
            f"{d.unit}{'✓' if d.matches else '✗'}{d.margin:.3f}"
            + (
                ""
                if d.matches
                else f"={d.code}" + ("" if d.addressee == tx.addressee else f"@{d.addressee}")
            )
            for d in decs
        )
        rows.append(
            [f"{tx.start:.3f}–{tx.end:.3f} s", f"turn {tx.turn}", printable(tx.label),
             f"on {printable(tx.channel)}", printable(marks) or "(no decodes)"]
        )  # fmt: skip
    for line in table_lines(rows, align=("right", "right", "left", "left", "left")):
        print(line)
    lost = [d for d in decodes if d.turn is None]
    if lost:
        print(f"  decodes matching no logged transmission: {len(lost)}")
    bad = [d for d in decodes if d.matches is False]
    margins = [d.margin for d in decodes]
    print(
        f"decodes: {len(decodes)}, {len(bad)} not what was sent"
        + (f"; smallest margin {min(margins):.3f}" if margins else "")
    )


def _print_relations(rp: Replay, s: dict[str, Any], units: list[str], span: Span | None) -> None:
    """The relationship table each unit holds (if it was installed in ``span``), whether they
    agree, and the influences the first unit holds."""
    from rgtbus.telemetry.read import in_span

    print("relationship tables (as each unit holds them):")
    held: dict[str, dict[str, str] | None] = {}
    extra: dict[str, list[str]] = {}
    missing: dict[str, str] = {}
    for u in units:
        rel = rp.relations.get(u)
        if rel is None or not in_span(rel["t"], span):
            held[u] = None
            missing[u] = "no table" if rel is None else "no table in this span"
            continue
        held[u] = rel["installed"]
        extra[u] = [rel["polynomial"] or "(none)", f"t={rel['t']:.3f}s"]
    for line in relations_lines(
        units, held, missing=missing, extra=extra, extra_headers=["polynomial", ""]
    ):
        print(line)
    print(f"  all units agree: {'yes' if s['agree'] else 'NO'}")
    if s["influences"]:
        print("influences (row influences column), as the first unit holds them:")
        grid = [
            [src]
            + [
                "·" if src == dst else _alt(rp, s["influences"].get(f"{src}>{dst}"))
                for dst in units
            ]
            for src in units
        ]
        for line in wrapped_table_lines(grid, ["", *units]):
            print(line)


def _print_decisions(rp: Replay, span: Span | None) -> None:
    """Each unit's own decisions in ``span``: interval and choice, or frustrated."""
    from rgtbus.telemetry.read import in_span

    print("decisions (each unit's own; predictions of the others in --json):")
    own = [d for d in rp.decisions if d["unit"] == d["subject"] and in_span(d["t"], span)]
    if not own:
        print("  (none)")
    rows = []
    for dec in own:
        if dec["frustrated"] or not dec["interval"]:  # no interval: no decision to show
            verdict, choice = "frustrated: no decision", ""
        else:
            lo, hi = (_alt(rp, x) for x in dec["interval"])
            verdict = f"{dec['unit']} = {lo}" if lo == hi else f"{hi} ⊇ {dec['unit']} ⊇ {lo}"
            choice = f"choice {_alt(rp, dec['choice'])}"
        rows.append([f"t={dec['t']:.3f}s", *map(printable, (dec["canonical"], verdict, choice))])
    for line in fitted_table_lines(rows):
        print(line)


def _print_ending(rp: Replay, s: dict[str, Any], units: list[str]) -> None:
    """How the run ended, where the log does not hold it whole, or its error."""
    if rp.run is None and not rp.unit_processes:
        print("no /run record: the run did not finish writing its log")
    elif rp.run is None and rp.cut_inputs:
        pass  # a merge of unit logs with a unit that ended early: the NOTE above says which
    elif rp.run is None and set(rp.unit_processes) != set(units):
        absent = ", ".join(u for u in units if u not in rp.unit_processes)
        print(f"no /run record, and no log of {absent} in this one: not the whole run")
    elif s["error"]:
        print(f"run failed: {printable(s['error'])}")
