"""Scale: the serial schedule against the concurrent one, and the concurrent one up to 100 units.

    python -m benchmarks.bench_scale [--sizes 4,6,8,10,12,16,20] [--large 30,50,100]
                                     [--log-upto 50] [--ser-sizes 10,50] [--quick]
    python -m benchmarks.bench_scale --scale-sizes 50,100,200,300 [--repeat R] [--calls-upto 30]
    python -m benchmarks.bench_scale --instructions 50,100   (needs valgrind)

Every run is a fresh process (no cache of one run helps another) over the memory bus with the
event engine. Groups of n units: a seeded decomposable group (relations policy cograph), random
influences, the automatic plan of each schedule (``rgtbus plan N --schedule ...``). Reported per
case: simulated seconds, wall seconds (no log), decode errors, peak RSS and, up to --log-upto
units, the wall and size of a run with the full MCAP log. Then the symbol error rate of the
concurrent schedule against channel noise.

Goals (issue 11): at n = 10 the concurrent schedule's simulated time at least 5x shorter than
the serial one's; n = 50 concurrent socialises in under 60 s wall without a log and at most 1.5x
that with the full log; n = 100 under 10 min.

``--scale-sizes`` prints only the engine table of the concurrent schedule (issue 23): per n the
wall without and with the full log, and with the log's records built and none written
(``DiscardingRecorder``: what the log costs before encoding and writing), each the median of
``--repeat`` fresh processes (default 3 up to n = 30, 1 above), peak RSS of both, a NumPy reference
doing the run's necessary work (a dense per-sample resonator bank over the medium for every
distinct receiver view, then a vectorised nearest-codeword decode of every code for every receiver)
and the run's ratio to it, Python calls per pulse (cProfile, up to ``--calls-upto`` units), the
fitted exponent of wall in n and the machine's load. ``--instructions`` prints the instructions
(callgrind's Ir) of the run without a log and of the reference, each section counted alone in a
process run under ``valgrind --tool=callgrind --instr-atstart=no``: issue 38 asks for the run /
reference ratio in instructions as well as in wall time. Goals (issue 23, 2 cores): n = 100
concurrent with its full log under 20 s and 250 MB, n = 200 under 2 min and 1 GB; the run within 3x
the NumPy reference at n = 50; log / no log <= 1.3x at n = 50; exponent of wall over n = 10...100
<= 3.0 (the decodes are n^3).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import itertools
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rgtbus.telemetry import NullRecorder

if TYPE_CHECKING:
    from rgtbus.units.unit import AutonomousUnit

    from rgtbus.scenario import Scenario

ROOT = Path(__file__).resolve().parent.parent


def scale_toml(n: int, schedule: str, seed: int = 11, noise: float = 0.0) -> str:
    names = [f"u{i:03d}" for i in range(n)]
    return "\n".join(
        [
            f'name = "scale{n}"',
            f"seed = {seed}",
            "units = " + json.dumps(names),
            'actions = ["alpha", "beta"]',
            'frequencies = "auto"',
            "[protocol]",
            f'schedule = "{schedule}"',
            "[timing]",
            "max_seconds = 100000.0",
            "[channel]",
            f"noise = {noise}",
            "[relations]",
            'policy = "cograph"',
            "[influences]",
            'policy = "random"',
        ]
    )


class Callgrind:
    """Instruction counts of marked sections of this process, when it runs under callgrind
    started with ``--instr-atstart=no`` (``instructions``): each section is instrumented alone
    and dumped under its label (``callgrind_control``); otherwise sections cost nothing."""

    def __init__(self, active: bool) -> None:
        self.active = active

    def _control(self, *args: str) -> None:
        subprocess.run(["callgrind_control", *args, str(os.getpid())], check=True,
                       capture_output=True, timeout=600)  # fmt: skip

    def start(self) -> None:
        if self.active:
            self._control("-i", "on")

    def stop(self, label: str) -> None:
        if self.active:
            self._control("-d", label)  # a dump zeroes the counts: sections do not add up
            self._control("-i", "off")

    @contextlib.contextmanager
    def section(self, label: str) -> Iterator[None]:
        self.start()
        try:
            yield
        finally:
            self.stop(label)


NO_COUNT = Callgrind(False)


def medium_pulses(members: list[AutonomousUnit]) -> int:
    """Every pulse the run put on the medium (each send's samples, every unit)."""
    return sum(len(send.samples) for m in members for send in m.sent)


class DiscardingRecorder(NullRecorder):
    """A recorder that is on (``enabled``: the units build every record of a full log, work
    out every spike, batch as a logged run does) and keeps nothing, as ``NullRecorder``: what
    a log costs before a byte of it is encoded or written (``--scale-sizes``'s "records built"
    cell)."""

    enabled = True


def one(
    n: int,
    schedule: str,
    log: bool,
    noise: float,
    *,
    log_file: bool = False,
    discard: bool = False,
    reference: bool = False,
    count: Callgrind = NO_COUNT,
) -> dict[str, Any]:
    """In a child process: one run's figures (``discard``: its log's records built and none
    written, ``DiscardingRecorder``; ``reference``: then the NumPy reference's; ``count``: the
    run's instructions and the reference's, under callgrind)."""
    from rgtbus.units.group import run_group

    from rgtbus.scenario import parse_scenario
    from rgtbus.telemetry import McapRecorder

    sc = parse_scenario(scale_toml(n, schedule, noise=noise), f"<scale{n}>")
    # a log file on disk, as `rgtbus run` writes it: in memory its bytes would count as RSS
    with tempfile.TemporaryFile() if log and log_file else io.BytesIO() as buf:
        rec = DiscardingRecorder() if discard else McapRecorder(buf) if log else NullRecorder()
        t0 = time.perf_counter()
        with count.section("run"):
            out = run_group(sc, "memory", rec)
            rec.close()
        wall = time.perf_counter() - t0
        log_mb = buf.seek(0, io.SEEK_END) / 1e6
    s = out.summary
    decodes = sum(len(m.decoded) for m in out.units)
    got = {
        "wall": wall,
        "sim": s["sim_seconds"],
        "errors": len(s["decode_errors"]),
        "decodes": decodes,
        "failure": s["error"],
        # before the reference runs: its arrays must not count as the run's peak
        "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "log_mb": log_mb,
        "pulses": sc.codebook.pulses,
        "medium_pulses": medium_pulses(out.units),
        "mode": sc.mode,
    }
    if reference and not s["error"]:
        got.update(numpy_reference(sc, out.units, s["sim_seconds"], count))
    return got


def count_calls(n: int, schedule: str) -> dict[str, Any]:
    """In a child process: the run under cProfile; every call it makes, per pulse on the medium
    (cProfile counts calls of Python functions and of C builtins alike)."""
    import cProfile
    import pstats

    from rgtbus.units.group import run_group

    from rgtbus.scenario import parse_scenario

    sc = parse_scenario(scale_toml(n, schedule), f"<scale{n}>")
    pr = cProfile.Profile()
    pr.enable()
    out = run_group(sc, "memory", NullRecorder())
    pr.disable()
    calls = pstats.Stats(pr).total_calls  # type: ignore[attr-defined]
    pulses = medium_pulses(out.units)
    return {"calls": calls, "medium_pulses": pulses, "calls_per_pulse": calls / max(pulses, 1)}


IDLE_MB = 50.0  # peak RSS of a child before its run: the interpreter, numpy, rgtbus (measured)
REF_CHUNK = 1 << 22  # scores per decode block: bounds the reference's memory (32 MB a block)


def numpy_reference(
    sc: Scenario, members: list[AutonomousUnit], sim_seconds: float, count: Callgrind = NO_COUNT
) -> dict[str, Any]:
    """The run's necessary work in plain NumPy, timed apart from the run (noise 0 assumed).

    (a) The medium rebuilt from the units' sends, then a dense per-sample resonator bank over
    every sample of the run for (distinct receiver views x n channels) lanes, literally as in
    ``rgtbus.signal.reference.reference_trajectory``; the readout is kept only at the (sample,
    channel) pairs some code is decoded from. (b) Every code decoded by every receiver at once:
    the readout at the code's pulse samples on its channel, nearest word of its family."""
    import numpy as np

    from rgtbus.protocol import PHASES
    from rgtbus.signal.resonator import PAPER_B, PAPER_RESET_VALUE, PAPER_THRESHOLD, transition

    units = list(sc.units)
    n = len(units)
    index = {u: i for i, u in enumerate(units)}
    tau = sc.timing.tau
    cb = sc.codebook
    families = {
        "id": cb.distinct_words(),  # an ID is judged against every distinct word
        "relation": cb.family("relation"),
        "alternative": cb.family("alternative"),
    }
    fam_index = {f: i for i, f in enumerate(families)}
    # what the sends say, as plain arrays (Python bookkeeping: not timed)
    rows_s, rows_m, chans, senders, fams, want = [], [], [], [], [], []
    for m in members:
        for send in m.sent:
            if send.kind == "id":
                fam, name = "id", "id"
            else:  # a receiver knows a payload's family from the schedule's phase
                phase = m.protocol.schedule[send.turn].phase
                fam, name = ("relation" if phase == PHASES[0] else "alternative"), send.code
            rows_s.append(send.samples)
            rows_m.append(m.transmitter.word(send))
            chans.append(index[send.channel])
            senders.append(index[m.name])
            fams.append(fam_index[fam])
            want.append(list(families[fam]).index(name))
    S = np.array(rows_s, dtype=np.int64)  # (codes, pulses)
    M = np.array(rows_m, dtype=float)
    ch = np.array(chans, dtype=np.int64)
    fam_of = np.array(fams)
    want_of = np.array(want)
    reaction = round(sc.timing.reaction_delay / tau)
    end = max(round(sim_seconds / tau), int(S.max()) + reaction) + 1

    # (a) the dense bank
    count.start()
    t0 = time.perf_counter()
    gains = np.array([sc.channel.gain_row(units, u) for u in units])  # [receiver, sender]
    views, view_of = np.unique(gains, axis=0, return_inverse=True)
    view_of = view_of.reshape(-1)
    n_views = len(views)
    medium = np.zeros((end, n_views))
    # each view hears every pulse times its sender's link gain
    heard = M[:, :, None] * views[:, senders].T[:, None, :]  # (codes, pulses, views)
    np.add.at(medium, S.ravel(), heard.reshape(-1, n_views))
    keys = np.unique((S * n + ch[:, None]).ravel())  # (sample, channel) pairs decoded from
    need_k = keys // n
    starts = np.flatnonzero(np.r_[True, need_k[1:] != need_k[:-1]])
    bounds = np.r_[starts, keys.size]
    plan = {int(need_k[a]): (int(a), int(b), keys[a:b] % n) for a, b in itertools.pairwise(bounds)}
    readout = np.empty((keys.size, n_views))
    A = np.array([transition(sc.frequencies[u], mode=sc.mode, tau=tau, b=PAPER_B) for u in units])
    z = np.zeros((n_views, n), dtype=complex)
    zi = z.imag  # a view: writes go to z
    pend = np.zeros(z.shape, dtype=bool)
    for k in range(end):
        np.multiply(z, A, out=z)
        if pend.any():  # after a spike: y restarts from the reset value
            np.copyto(zi, PAPER_RESET_VALUE, where=pend)
        hit = plan.get(k)
        if hit is not None:
            a, b, c = hit
            before = zi[:, c]  # fancy indexing: a copy, the state before the input
        zi += medium[k][:, None]
        np.greater_equal(zi, PAPER_THRESHOLD, out=pend)
        if hit is not None:  # d = Im z - Im(before the input), only where a decode reads it
            readout[a:b] = (zi[:, c] - before).T
    bank_s = time.perf_counter() - t0
    count.stop("ref_bank")

    # (b) every code, every receiver, at once (in blocks of receivers to bound the memory)
    count.start()
    t0 = time.perf_counter()
    X = readout[np.searchsorted(keys, S * n + ch[:, None])].transpose(2, 0, 1)  # (views, C, P)
    decodes = mismatches = 0
    for fam, words in families.items():
        sel = np.flatnonzero(fam_of == fam_index[fam])
        if not sel.size:
            continue
        W = np.array(list(words.values()))  # (words, pulses)
        weights, bias = -2.0 * W.T, (W * W).sum(1)  # |x - w|^2 - |x|^2 = |w|^2 - 2 x.w
        Xf, wf = X[:, sel], want_of[sel]
        block = max(1, REF_CHUNK // (sel.size * len(W)))
        for r0 in range(0, n, block):
            Xr = Xf[view_of[r0 : r0 + block]]  # each receiver's copy of its view
            got = (Xr @ weights + bias).argmin(-1)  # the nearest word's index: its name
            mismatches += int(np.count_nonzero(got != wf))
            decodes += got.size
    decode_s = time.perf_counter() - t0
    count.stop("ref_decode")
    return {
        "ref_s": bank_s + decode_s,
        "ref_bank_s": bank_s,
        "ref_decode_s": decode_s,
        "ref_decodes": decodes,
        "ref_mismatches": mismatches,
        "ref_views": n_views,
        "ref_samples": end,
        "ref_lanes": n_views * n,
    }


def measure(
    n: int,
    schedule: str,
    log: bool = False,
    noise: float = 0.0,
    *,
    log_file: bool = False,
    discard: bool = False,
    reference: bool = False,
    calls: bool = False,
) -> dict[str, Any]:
    argv = [sys.executable, "-m", "benchmarks.bench_scale", "--one", str(n), schedule]
    argv += ["--log" if log else "--no-log", "--noise", repr(noise)]
    argv += ["--log-file"] * log_file + ["--discard"] * discard + ["--reference"] * reference
    argv += ["--count-calls"] * calls
    proc = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=7200)
    if proc.returncode != 0:
        raise SystemExit(f"n={n} {schedule} failed: {proc.stderr.strip()[-800:]}")
    return json.loads(proc.stdout)


def goals(rows: list) -> None:
    """The issue's goals against this run's figures (a goal whose case was not run is left out)."""
    got = {(n, s): (r, lg) for n, s, r, lg in rows if not r["failure"]}
    lines = []
    if (10, "serial") in got and (10, "concurrent") in got:
        ratio = got[(10, "serial")][0]["sim"] / got[(10, "concurrent")][0]["sim"]
        lines.append(f"n = 10: serial / concurrent simulated time {ratio:.1f}x (goal >= 5x)")
    if (50, "concurrent") in got:
        r, lg = got[(50, "concurrent")]
        lines.append(f"n = 50 concurrent, no log: {r['wall']:.1f} s wall (goal < 60 s)")
        if lg:
            ratio = lg["wall"] / r["wall"]
            lines.append(
                f"n = 50 concurrent, full log: {lg['wall']:.1f} s wall, {ratio:.2f}x the run "
                "without a log (goal <= 1.5 x 60 s = 90 s)"
            )
    if (100, "concurrent") in got:
        lines.append(
            f"n = 100 concurrent: {got[(100, 'concurrent')][0]['wall']:.1f} s wall (goal < 600 s)"
        )
    for line in lines:
        print(f"- {line}")


def fit_exponent(points: list[tuple[int, float]]) -> float | None:
    """Least-squares slope of log(wall) against log(n): wall ~ n^slope."""
    if len({n for n, _ in points}) < 2:
        return None
    xs = [math.log(n) for n, _ in points]
    ys = [math.log(w) for _, w in points]
    mx, my = statistics.fmean(xs), statistics.fmean(ys)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sum(
        (x - mx) ** 2 for x in xs
    )


def engine_table(sizes: list[int], repeat: int | None, calls_upto: int) -> None:
    """Issue 23's table of the concurrent schedule, every figure from fresh child processes."""
    load0 = os.getloadavg()
    cases: dict[int, dict[str, Any]] = {}
    for n in sizes:
        runs: list[dict[str, Any]] = []
        logs: list[dict[str, Any]] = []
        built: list[dict[str, Any]] = []
        for _ in range(repeat or (3 if n <= 30 else 1)):
            # alternated, so a change of the machine's load hits them alike
            runs.append(measure(n, "concurrent", reference=True))
            logs.append(measure(n, "concurrent", log=True, log_file=True))
            built.append(measure(n, "concurrent", discard=True))
        calls = measure(n, "concurrent", calls=True) if n <= calls_upto else None
        cases[n] = {"runs": runs, "logs": logs, "built": built, "calls": calls}
    load1 = os.getloadavg()

    def med(rs: list[dict[str, Any]], key: str) -> float:
        return statistics.median(r[key] for r in rs)

    print("## Engine at scale: concurrent schedule (memory bus, event engine, fresh processes)")
    print()
    print(
        "| n | R | pulses | decodes: run / reference (ref. mismatches) | wall s no log | "
        "wall s full log | log / no log | wall s records built, none written | built / no log "
        "| peak MB no log / log | NumPy reference s (bank + decode) | run / reference | "
        "Python calls per pulse |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    fig: dict[int, dict[str, float]] = {}
    for n, case in cases.items():
        runs, logs, built, calls = case["runs"], case["logs"], case["built"], case["calls"]
        bad = [r["failure"] for r in runs + logs + built if r["failure"]]
        r0 = runs[0]
        if bad:  # a run that cannot finish is a result too: say where it stopped
            print(f"| {n} | {len(runs)} | - | failed: {bad[0]} |" + " - |" * 9)
            continue
        f = {k: med(runs, k) for k in ("wall", "rss_mb", "ref_s", "ref_bank_s", "ref_decode_s")}
        f |= {"log_wall": med(logs, "wall"), "log_rss_mb": med(logs, "rss_mb")}
        f["log_ratio"] = f["log_wall"] / f["wall"]
        f["built_wall"] = med(built, "wall")
        f["built_ratio"] = f["built_wall"] / f["wall"]
        f["ref_ratio"] = f["wall"] / f["ref_s"]
        fig[n] = f
        per_pulse = f"{calls['calls_per_pulse']:.0f}" if calls else "-"
        print(
            f"| {n} | {len(runs)} | {r0['medium_pulses']} | {r0['decodes']} / "
            f"{r0['ref_decodes']} ({max(r['ref_mismatches'] for r in runs)}) | "
            f"{f['wall']:.2f} | {f['log_wall']:.2f} | {f['log_ratio']:.2f}x | "
            f"{f['built_wall']:.2f} | {f['built_ratio']:.2f}x | "
            f"{f['rss_mb']:.0f} / {f['log_rss_mb']:.0f} | {f['ref_s']:.2f} "
            f"({f['ref_bank_s']:.2f} + {f['ref_decode_s']:.2f}) | {f['ref_ratio']:.2f}x | "
            f"{per_pulse} |"
        )
    print()
    slope = fit_exponent([(n, f["wall"]) for n, f in fig.items()])
    span = f"n = {min(fig)}...{max(fig)}" if fig else "no size"
    print(
        f"Exponent of wall (no log) in n over {span}: "
        + (f"{slope:.2f}" if slope is not None else "- (needs two sizes)")
    )
    # memory above what the interpreter holds before the run (its imports: the smallest run's
    # peak less its decodes' share is close to it)
    base = IDLE_MB
    mem = fit_exponent([(n, f["rss_mb"] - base) for n, f in fig.items() if f["rss_mb"] > base])
    print(
        f"Exponent of peak memory (no log, less {base:.0f} MB of interpreter and imports) in n "
        f"over {span}: " + (f"{mem:.2f}" if mem is not None else "- (needs two sizes)")
    )
    print("The loader's estimate (rgtbus.scenario.limits.run_estimate, with the log) per n:")
    from rgtbus.scenario.limits import run_estimate

    for n, f in fig.items():
        est = run_estimate(n, 1)
        print(
            f"- n = {n}: estimated {est.memory_mb:.0f} MB and {est.seconds:.0f} s; measured "
            f"{f['log_rss_mb']:.0f} MB and {f['log_wall']:.1f} s with the log"
        )
    print(
        f"Machine: {os.cpu_count()} CPUs; load average (1, 5, 15 min) at start "
        f"{', '.join(f'{x:.2f}' for x in load0)}, at end {', '.join(f'{x:.2f}' for x in load1)}"
    )
    print(
        "Medians of R fresh processes per cell; the log run writes its MCAP to a temporary "
        "file; the records-built run builds every record of the log and writes none (the "
        "log's cost before encoding and writing); the reference assumes noise 0 and is timed "
        "after the run, in its process."
    )
    print()
    engine_goals(fig)


def callgrind_counts(n: int) -> dict[str, int]:
    """Instructions (callgrind's Ir) of a fresh process's run without a log and of its NumPy
    reference's bank and decode, each section counted alone (``Callgrind``)."""
    import shutil

    if shutil.which("valgrind") is None or shutil.which("callgrind_control") is None:
        raise SystemExit("--instructions needs valgrind (callgrind) on PATH")
    python = sys.executable  # the venv's interpreter (a link to a binary, not a shim script)
    with tempfile.TemporaryDirectory() as tmp:
        argv = [
            "valgrind", "--tool=callgrind", "--instr-atstart=no",
            f"--callgrind-out-file={tmp}/cg.%p", python, "-m", "benchmarks.bench_scale",
            "--one", str(n), "concurrent", "--no-log", "--reference", "--callgrind",
        ]  # fmt: skip
        proc = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=7200)
        if proc.returncode != 0:
            raise SystemExit(f"n={n} under callgrind failed: {proc.stderr.strip()[-800:]}")
        counts: dict[str, int] = {}
        for dump in Path(tmp).glob("cg.*"):
            label, total = None, None
            for line in dump.read_text(errors="replace").splitlines():
                if line.startswith("desc: Trigger: dump "):
                    label = line.removeprefix("desc: Trigger: dump ").strip()
                elif line.startswith("totals:"):
                    total = int(line.split()[1])
            if label is not None and total is not None:
                counts[label] = total
    missing = {"run", "ref_bank", "ref_decode"} - set(counts)
    if missing:
        raise SystemExit(f"n={n}: no callgrind dump of {sorted(missing)}")
    return counts


def instructions_table(sizes: list[int]) -> None:
    """Instruction counts of the run (no log) and of the NumPy reference, per n, beside the
    walls of a plain fresh process: a figure the machine's load does not move."""
    print("## Instructions (callgrind Ir): run without a log against the NumPy reference")
    print()
    print(
        "| n | run Ir (G) | reference Ir (G): bank + decode | run / reference (Ir) | "
        "run / reference (wall, plain process) |"
    )
    print("|---|---|---|---|---|")
    for n in sizes:
        c = callgrind_counts(n)
        wall = measure(n, "concurrent", reference=True)
        ref = c["ref_bank"] + c["ref_decode"]
        print(
            f"| {n} | {c['run'] / 1e9:.2f} | {ref / 1e9:.2f}: {c['ref_bank'] / 1e9:.2f} + "
            f"{c['ref_decode'] / 1e9:.2f} | {c['run'] / ref:.2f}x | "
            f"{wall['wall'] / wall['ref_s']:.2f}x |"
        )
    print()
    print(
        "Each count is of its section alone (callgrind_control toggles the instrumentation "
        "around it); imports, the scenario's parse and the reference's Python bookkeeping are "
        "not counted."
    )


def engine_goals(fig: dict[int, dict[str, float]]) -> None:
    """Issues 23's and 38's goals against the engine table (a goal whose case was not run is
    left out)."""

    def verdict(ok: bool) -> str:
        return "met" if ok else "NOT met"

    lines = []
    for n, mb_goal in ((300, 800.0), (500, 2048.0)):
        if n in fig:
            f = fig[n]
            ok = max(f["rss_mb"], f["log_rss_mb"]) < mb_goal
            lines.append(
                f"n = {n} peak memory: {f['rss_mb']:.0f} MB no log, {f['log_rss_mb']:.0f} MB with "
                f"it (goal < {mb_goal:g} MB): {verdict(ok)}"
            )
    for n in (100, 200, 300):
        if n in fig:
            f = fig[n]
            lines.append(
                f"n = {n} run / NumPy reference: {f['ref_ratio']:.2f}x (goal <= 1.0x): "
                f"{verdict(f['ref_ratio'] <= 1.0)}"
            )
            if n <= 200:
                lines.append(
                    f"n = {n} log / no log: {f['log_ratio']:.2f}x (goal <= 1.5x): "
                    f"{verdict(f['log_ratio'] <= 1.5)} (records built, none written: "
                    f"{f['built_ratio']:.2f}x)"
                )
    for n, wall_goal, mb_goal in ((100, 20.0, 250.0), (200, 120.0, 1024.0)):
        if n in fig:
            f = fig[n]
            ok = f["log_wall"] < wall_goal and f["log_rss_mb"] < mb_goal
            lines.append(
                f"n = {n} concurrent, full log: {f['log_wall']:.1f} s, {f['log_rss_mb']:.0f} MB "
                f"(goal < {wall_goal:g} s and < {mb_goal:g} MB): {verdict(ok)}"
            )
    if 50 in fig:
        f = fig[50]
        lines.append(
            f"n = 50 run / NumPy reference: {f['ref_ratio']:.2f}x (goal <= 3x): "
            f"{verdict(f['ref_ratio'] <= 3.0)}"
        )
        lines.append(
            f"n = 50 log / no log: {f['log_ratio']:.2f}x (goal <= 1.3x): "
            f"{verdict(f['log_ratio'] <= 1.3)}"
        )
    if 10 in fig and 100 in fig:
        slope = fit_exponent([(n, f["wall"]) for n, f in fig.items() if 10 <= n <= 100])
        assert slope is not None
        lines.append(
            f"exponent of wall over n = 10...100: {slope:.2f} (goal <= 3.0): "
            f"{verdict(slope <= 3.0)}"
        )
    for line in lines:
        print(f"- {line}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="4,6,8,10,12,16,20", help="serial and concurrent")
    ap.add_argument("--large", default="30,50,100", help="concurrent only")
    ap.add_argument("--log-upto", type=int, default=50, help="logged runs up to this size")
    ap.add_argument("--ser-sizes", default="10,50", help="noise sweep sizes (concurrent)")
    ap.add_argument("--quick", action="store_true", help="4,6,10; large 30; noise at 10")
    ap.add_argument("--one", nargs=2, metavar=("N", "SCHEDULE"), help=argparse.SUPPRESS)
    ap.add_argument("--log", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--no-log", dest="log", action="store_false", help=argparse.SUPPRESS)
    ap.add_argument("--noise", type=float, default=0.0, help=argparse.SUPPRESS)
    ap.add_argument("--log-file", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--discard", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--reference", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--count-calls", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--callgrind", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument(
        "--instructions",
        help="only the instruction counts (callgrind) of run and reference at these sizes",
    )
    ap.add_argument(
        "--scale-sizes", help="only the engine table (issue 23) at these sizes, e.g. 10,30,50,100"
    )
    ap.add_argument(
        "--repeat", type=int, help="engine table: runs per cell (default 3 up to n = 30, else 1)"
    )
    ap.add_argument(
        "--calls-upto", type=int, default=30, help="engine table: count calls up to this size"
    )
    args = ap.parse_args()
    if args.one:
        n, schedule = int(args.one[0]), args.one[1]
        if args.count_calls:
            print(json.dumps(count_calls(n, schedule)))
            return
        got = one(
            n, schedule, args.log, args.noise, log_file=args.log_file, discard=args.discard,
            reference=args.reference, count=Callgrind(args.callgrind),
        )  # fmt: skip
        print(json.dumps(got))
        return
    if args.instructions:
        instructions_table([int(x) for x in args.instructions.split(",") if x])
        return
    if args.scale_sizes:
        sizes = [int(x) for x in args.scale_sizes.split(",") if x]
        engine_table(sizes, args.repeat, args.calls_upto)
        return
    sizes = [4, 6, 10] if args.quick else [int(x) for x in args.sizes.split(",")]
    large = [30] if args.quick else [int(x) for x in args.large.split(",") if x]
    ser_sizes = [10] if args.quick else [int(x) for x in args.ser_sizes.split(",") if x]

    print("## Serial vs concurrent schedule (memory bus, event engine, fresh processes)")
    print()
    print(
        "| n | schedule | pulses, mode | simulated s | serial / concurrent (sim) | wall s | "
        "decode errors | peak MB | wall s, full log | log / no log | log MB |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for n in sizes + large:
        for schedule in ("serial", "concurrent") if n in sizes else ("concurrent",):
            r = measure(n, schedule)
            ok = not r["failure"]
            lg = measure(n, schedule, log=True) if ok and n <= args.log_upto else None
            rows.append((n, schedule, r, lg))
    sims = {(n, s): r["sim"] for n, s, r, _ in rows if not r["failure"]}
    for n, schedule, r, lg in rows:
        if r["failure"]:  # a run that cannot finish is a result too: say where it stopped
            print(
                f"| {n} | {schedule} | {r['pulses']}, {r['mode']} | failed at "
                f"{r['sim']:.1f} s: {r['failure']} | - | {r['wall']:.2f} | "
                f"{r['errors']} of {r['decodes']} | {r['rss_mb']:.0f} | - | - | - |"
            )
            continue
        ratio = (
            f"{sims[(n, 'serial')] / r['sim']:.1f}x"
            if schedule == "concurrent" and (n, "serial") in sims
            else "-"
        )
        logged = (
            f"{lg['wall']:.2f} | {lg['wall'] / r['wall']:.2f}x | {lg['log_mb']:.1f}"
            if lg
            else "- | - | -"
        )
        print(
            f"| {n} | {schedule} | {r['pulses']}, {r['mode']} | {r['sim']:.1f} | {ratio} | "
            f"{r['wall']:.2f} | {r['errors']} of {r['decodes']} | {r['rss_mb']:.0f} | {logged} |"
        )
    print()
    goals(rows)
    print()
    print("## Symbol error rate of the concurrent schedule against channel noise (σ per sample)")
    print()
    noises = [0.0, 0.02, 0.05, 0.1]
    print("| n | " + " | ".join(f"σ = {x:g}" for x in noises) + " |")
    print("|---|" + "---|" * len(noises))
    for n in ser_sizes:
        cells = []
        for noise in noises:
            r = measure(n, "concurrent", noise=noise)
            rate = r["errors"] / max(r["decodes"], 1)
            note = "" if not r["failure"] else " (run failed)"
            cells.append(f"{rate:.4f} ({r['errors']}/{r['decodes']}){note}")
        print(f"| {n} | " + " | ".join(cells) + " |")
    print()
    print(
        "Wall: the simulation only (scenario loaded first), one fresh process a cell; decode "
        "errors: decodes (IDs and payloads, every unit) that differ from what was sent."
    )


if __name__ == "__main__":
    main()
