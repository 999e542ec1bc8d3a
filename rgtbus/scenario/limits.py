"""How big a run may be before it starts: estimates and budgets (docs/scenarios.md, "Budgets").

A run's size is estimated from its scenario before anything is built: samples (``max_seconds ×
sample_rate``), samples a bus window (``window × sample_rate``), the group's peak memory and
wall time (from its decodes: every unit decodes every code, ``2·n²·(n−1)·(1 + influence_rounds)``,
calibrated against ``benchmarks.bench_scale``: ``run_estimate``) and the generated codebook's
search (its ``2^k`` words against every candidate word). A group is refused only when it would
need more memory than the machine has free or more than an hour (``RUN_HOURS``); any other
estimate beyond its budget is refused too, each in one line naming the key and the estimate.
``RGTBUS_BUDGET=large`` (environment) raises every budget a hundredfold; the hard limits below
it never move.

Also here: how deep a TOML text may nest (tomllib recurses, and gives up at about 400 levels)
and the files a scenario or sweep may be read from (regular files only: a FIFO blocks forever).
"""

from __future__ import annotations

import errno
import math
import os
import re
import stat
from collections.abc import Mapping
from typing import Any, NamedTuple

from rgtbus.errors import BadInput, IOFailure, RgtbusError

BUDGET_ENV = "RGTBUS_BUDGET"
LARGE_FACTOR = 100  # RGTBUS_BUDGET=large: every budget this many times larger


class Budget(NamedTuple):
    """A limit on what a run may ask for: its ``name``, ``limit`` and ``what`` it counts."""

    name: str
    limit: float
    what: str  # what the estimate counts, for the message


# Each budget lies above what every shipped scenario, sweep and benchmark asks for and below
# what exhausts a small machine's memory or the log writer first (docs/engine.md).
SAMPLES = Budget("samples", 1e9, "samples (max_seconds × sample_rate)")
WINDOW_SAMPLES = Budget("window", 1e5, "samples a bus window (window × sample_rate)")
# A group's run in the user's terms (``run_estimate``): its wall time against an hour, its peak
# memory against what the machine has free.
RUN_HOURS = 1.0
# Calibrated against benchmarks.bench_scale --scale-sizes 50,100,200,300 (docs/engine.md, "What
# it costs"): one process running the whole group with its log, on a 2-core machine. Peak
# memory: RUN_BASE_MB, plus RUN_MEMORY_MB at 10⁸ decodes, growing as decodes^RUN_MEMORY_EXPONENT
# (measured 87, 147, 405 and 820 MB at n = 50, 100, 200, 300; 2,031 MB at n = 500 without the
# log); wall time RUN_SECONDS_PER_DECODE a decode (1.3, 6.0, 37.6 and 126.7 s: the log's; 1.2,
# 5.2, 29.1 and 113.4 s, 87, 148, 405 and 794 MB, once the log's tables and columns were
# written from JSON made once: 1.2 µs still bounds a decode from n = 100 on; 1.0, 4.3, 24.0
# and 100 s, 87, 149, 394-420 and 774 MB with a logged batch of a minute up to 200 units).
RUN_BASE_MB = 50.0
RUN_MEMORY_MB = 760.0
RUN_MEMORY_EXPONENT = 0.64
RUN_SECONDS_PER_DECODE = 1.2e-6
# A medium its receivers hear differently (noise, bursts, link gains other than 1, delays or
# clocks: ``Channel.alike`` false) costs far more: no receiver shares another's walk, and with
# noise no silence is skipped, so every receiver's resonators walk every sample and every unit
# writes its own spikes and decodes. Calibrated with the log, concurrent, noise 0.01, each
# unit batching 5 s of its log (``units.unit.DIFFER_LOGGED_BATCH_SECONDS``): 7.2 s and 148 MB
# at n = 50, 65.1 s and 303 MB at n = 100, 612 s and 1,471 MB at n = 200 (2 million misread
# decodes in its summary); path loss at n = 50 (no noise): 5.6 s and 144 MB. Against 0.7, 2.8
# and 15.7 s on a clean medium. (Batching a minute, as on a clean medium: 180, 547 and 2,233
# MB.)
DIFFER_MEMORY_MB = 3670.0
DIFFER_MEMORY_EXPONENT = 0.83
DIFFER_SECONDS_PER_DECODE = 2.2e-5  # 14.6, 16.4 and 19.2 µs at n = 50, 100, 200
CODEBOOK_SEARCH = Budget("codebook", 1e8, "word comparisons (2^actions words × candidates)")
# rgtbus plan's crosstalk simulation: every channel's ID through a bank of every channel,
# n²·L resonator-samples (L: the longest ID plus a period, in samples).
CROSSTALK = Budget("crosstalk", 5e7, "resonator-samples (n² × samples an ID)")
# rgtbus ser and figures: Monte-Carlo decodes (about 25,000 a second on a small machine; the
# defaults ask for 8,000 and 20,000)
TRIALS = Budget("trials", 2e6, "Monte-Carlo decodes (trials × noise levels × curves)")
# rgtbus resonate: every resonator's y and x recorded at every sample (16 bytes each; the
# defaults ask for about 3,000)
RECORDED = Budget("recorded", 2e7, "resonator-samples recorded (samples × resonators)")

# Hard limits (no budget lifts them): log times are unsigned 64-bit nanoseconds.
MAX_SECONDS = 1e9  # any timing value, s (31 years)
MAX_NESTING = 32  # brackets and braces, and a key's depth (a scenario needs 3)


def budget_scale() -> float:
    """1, or ``LARGE_FACTOR`` with ``RGTBUS_BUDGET=large``. RgtbusError for another value."""
    value = os.environ.get(BUDGET_ENV, "").strip().lower()
    if value in ("", "default"):
        return 1.0
    if value == "large":
        return float(LARGE_FACTOR)
    raise BadInput(
        f"{BUDGET_ENV}={os.environ.get(BUDGET_ENV)!r}: unknown budget (default or large)"
    )


def over_budget(budget: Budget, estimate: float) -> str | None:
    """None when ``estimate`` fits ``budget`` (scaled); else the reason, in one line."""
    limit = budget.limit * budget_scale()
    if estimate <= limit:
        return None
    raise_it = (
        f"set {BUDGET_ENV}=large for {LARGE_FACTOR}× the budget"
        if limit == budget.limit
        else f"beyond {BUDGET_ENV}=large too"
    )
    return (
        f"about {estimate:.3g} {budget.what}, beyond the budget of {limit:.3g} "
        f'({raise_it}; docs/scenarios.md, "Budgets")'
    )


# -- estimates ---------------------------------------------------------------------------------


class RunEstimate(NamedTuple):
    """What a group's run will take (``run_estimate``): its decodes, its peak memory in MB and
    its wall time in seconds, one process running the whole group with its log."""

    decodes: float
    memory_mb: float
    seconds: float


def run_estimate(n: int, influence_rounds: int, alike: bool = True) -> RunEstimate:
    """The peak memory and wall time of a run of ``n`` units, from its decodes (calibrated:
    ``RUN_BASE_MB``, ``RUN_MEMORY_MB``, ``RUN_MEMORY_EXPONENT``, ``RUN_SECONDS_PER_DECODE``;
    ``alike`` False, a medium its receivers hear differently: the ``DIFFER_`` figures). A
    launch's unit processes each take a share of it."""
    d = decodes(n, influence_rounds)
    if alike:
        memory = RUN_BASE_MB + RUN_MEMORY_MB * (d / 1e8) ** RUN_MEMORY_EXPONENT
        return RunEstimate(d, memory, d * RUN_SECONDS_PER_DECODE)
    memory = RUN_BASE_MB + DIFFER_MEMORY_MB * (d / 1e8) ** DIFFER_MEMORY_EXPONENT
    return RunEstimate(d, memory, d * DIFFER_SECONDS_PER_DECODE)


def free_memory_mb() -> float | None:
    """The memory this machine has free for a new run, in MB (Linux: ``MemAvailable``); None
    where it cannot be read (then only the hour limits a run)."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) / 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _size(mb: float) -> str:
    return f"{mb:,.0f} MB" if mb < 100_000 else f"{mb / 1024:.3g} GB"


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 2 * 3600:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.3g} h"


def over_run_budget(n: int, influence_rounds: int, alike: bool = True) -> str | None:
    """None when a run of ``n`` units fits this machine (``run_estimate``: its peak memory
    within the free memory, its wall time within ``RUN_HOURS``, each times ``budget_scale``);
    else the reason, in one line, naming both figures and how to override."""
    est = run_estimate(n, influence_rounds, alike)
    scale = budget_scale()
    free = free_memory_mb()
    hours = RUN_HOURS * scale
    over = []
    if free is not None and est.memory_mb > free * scale:
        times = "" if scale == 1 else f"{scale:g} × "
        over.append(f"more than {times}the memory this machine has free ({_size(free)})")
    if est.seconds > hours * 3600:
        over.append(f"more than {'an hour' if scale == 1 else f'{hours:g} hours'}")
    if not over:
        return None
    override = (
        f"set {BUDGET_ENV}=large to run it anyway"
        if scale == 1
        else f"beyond {BUDGET_ENV}=large too"
    )
    medium = "" if alike else ", on a medium its receivers hear differently"
    return (
        f"about {_size(est.memory_mb)} at its peak and {_duration(est.seconds)} of wall time "
        f"({est.decodes:.3g} decodes{medium}), {' and '.join(over)} ({override}; "
        'docs/scenarios.md, "Budgets")'
    )


def decodes(n: int, influence_rounds: int) -> float:
    """Decodes of a run of ``n`` units: each of the n units decodes every one of the n·(n−1)
    codes of the relationship phase and of each influence round, twice (the ID and the
    payload), ``2·n²·(n−1)·(1 + rounds)``. Exact for a run that finishes (the decodes in /rx/decodes
    records: 192 for the 4-unit gate, 3,600 for crowd10); the memory and time of a run grow
    with it."""
    return 2.0 * n * n * (n - 1) * (1 + influence_rounds)


def codebook_candidates(pulses: int, low: float = 0.1, high: float = 0.7) -> int:
    """Words the generated codebook enumerates at N pulses (rgtbus.signal.codebook's grid: the
    finest 0.05 step that keeps it under a million)."""
    for s in range(1, 100):
        step = s * 0.05
        width = max(0, math.floor(high / step + 1e-9) - math.ceil(low / step - 1e-9) + 1)
        count: int = width ** max(0, pulses - 1)
        if count <= 1_000_000:
            return count
    return 1_000_000


def codebook_search(actions: int, pulses: int) -> float:
    """The generated codebook's farthest-first search: 2^actions words, each against every
    candidate word."""
    return float(2**actions) * codebook_candidates(pulses)


# -- TOML text ---------------------------------------------------------------------------------

# What can hold a bracket that is no nesting: comments and strings (multi-line ones first).
_TOKENS = re.compile(
    r'#[^\n]*|"""(?:\\.|[^\\])*?"""|\'\'\'.*?\'\'\'|"(?:\\.|[^"\\\n])*"|\'[^\'\n]*\'|[\[\]{}]',
    re.DOTALL,
)


def nesting_error(text: str, where: str, limit: int = MAX_NESTING) -> str | None:
    """``file:line: nesting deeper than N`` when brackets and braces (outside strings and
    comments) nest deeper than ``limit`` in ``text``, else None. Checked before tomllib reads
    it: tomllib recurses, and 5,000 ``[`` are a RecursionError."""
    if text.count("[") + text.count("{") <= limit:
        return None
    depth = 0
    for m in _TOKENS.finditer(text):
        tok = m.group()
        if tok in "[{":
            depth += 1
            if depth > limit:
                line = text.count("\n", 0, m.start()) + 1
                return f"{where}:{line}: nesting deeper than {limit} (brackets and braces)"
        elif tok in "]}":
            depth = max(0, depth - 1)
    return None


def key_depth_error(data: Mapping[str, Any], text: str, where: str) -> str | None:
    """``file[:line]: nesting deeper than N`` when the tables of parsed TOML ``data`` nest
    deeper than ``MAX_NESTING`` (dotted keys: ``a.a.a…`` = 1 takes no bracket), else None.
    Iterative: the check must not recurse itself."""
    stack: list[tuple[Any, int]] = [(data, 1)]
    while stack:
        node, depth = stack.pop()
        if depth > MAX_NESTING:
            line = next(
                (
                    i
                    for i, ln in enumerate(text.splitlines(), 1)
                    if ln.split("=", 1)[0].count(".") >= MAX_NESTING - 1
                ),
                None,
            )
            at = f"{where}:{line}" if line else where
            return f"{at}: nesting deeper than {MAX_NESTING} (a dotted key or table name)"
        if isinstance(node, Mapping):
            stack.extend((v, depth + 1) for v in node.values())
        elif isinstance(node, list):
            stack.extend((v, depth + 1) for v in node)
    return None


# -- files -------------------------------------------------------------------------------------


def read_regular(path: str | os.PathLike[str], what: str, cap: int) -> bytes:
    """The bytes of a regular file, at most ``cap + 1`` of them; one line (RgtbusError, naming
    ``what`` and the path) for a directory, a FIFO, a device or a socket (refused before a
    byte is read: a FIFO would block forever) or a file that cannot be read. Opened without
    blocking and checked on the open file, so nothing can be swapped in between."""
    where = os.fspath(path)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        if exc.errno == errno.EISDIR:
            raise IOFailure(f"cannot read {what} {where!r}: is a directory") from None
        raise
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise IOFailure(f"cannot read {what} {where!r}: is a directory")
        if not stat.S_ISREG(mode):
            kind = "a FIFO, " if stat.S_ISFIFO(mode) else ""  # a device: as it always said
            kind = "a socket, " if stat.S_ISSOCK(mode) else kind
            raise IOFailure(f"cannot read {what} {where!r}: {kind}not a regular file")
        f = open(fd, "rb", closefd=False)  # noqa: SIM115 - fd is closed below
        return f.read(cap + 1)
    finally:
        os.close(fd)


# -- a scenario's size -------------------------------------------------------------------------

_TIMING_DEFAULTS = {"sample_rate": 200.0, "window": 0.1, "max_seconds": 3600.0}


def _blamed(t: Mapping[str, Any], keys: tuple[str, ...]) -> str:
    """Of the timing ``keys`` whose product is too large, the one the file sets furthest
    above its default (a default is nobody's typo)."""
    set_keys = [k for k in keys if k in t] or list(keys)

    def ratio(k: str) -> float:
        v = t.get(k, _TIMING_DEFAULTS[k])
        return float(v) / _TIMING_DEFAULTS[k] if isinstance(v, int | float) else 0.0

    return max(set_keys, key=ratio)


def check_size(
    ctx: Any, data: Mapping[str, Any], n: int, rounds: int, timing: Any, alike: bool = True
) -> None:
    """Refuse (``ctx.error``: file:line: key) a run whose estimated size is beyond its budget:
    samples, samples a window, decodes (``alike``: whether its receivers hear the medium
    alike, ``run_estimate``). Called as soon as the units, the protocol and the timing are
    read, before anything costly is built (channel, codebook, frequency plan, groups); again
    once the channel is read, if its receivers hear it differently."""
    try:
        budget_scale()
    except RgtbusError as exc:
        raise ctx.error("", None, str(exc)) from None
    t = data.get("timing", {})
    t = t if isinstance(t, Mapping) else {}
    why = over_budget(SAMPLES, timing.max_seconds * timing.sample_rate)
    if why:
        raise ctx.error("timing", _blamed(t, ("max_seconds", "sample_rate")), why)
    why = over_budget(WINDOW_SAMPLES, timing.window * timing.sample_rate)
    if why:
        raise ctx.error("timing", _blamed(t, ("window", "sample_rate")), why)
    why = over_run_budget(n, rounds, alike)
    if why:
        if rounds > 1 and over_run_budget(n, 1, alike) is None:
            raise ctx.error("protocol", "influence_rounds", f"{rounds} rounds of {n} units: {why}")
        raise ctx.error("", "units", f"{n} units, {rounds} influence round(s): {why}")


def check_trials(trials: int, points: int, flag: str = "--trials") -> None:
    """``trials`` Monte-Carlo decodes at each of ``points`` (noise levels × curves) within the
    ``TRIALS`` budget; else one line naming ``flag`` (RgtbusError)."""
    if trials < 1:
        raise BadInput(f"{flag} {trials}: must be at least 1")
    why = over_budget(TRIALS, float(trials) * max(1, points))
    if why is not None:
        raise BadInput(f"{flag} {trials}: {why}")
