"""A metric of a sweep's runs against one of its parameters, with 95 % intervals over seeds.

Per x value (and curve): a yes/no metric is a share p̂ = k/n with its Wilson score interval
(``rgtbus.stats.wilson``); a number is a mean with mean ± z·s/sqrt(n) (s the sample standard
deviation). Runs where the metric is empty (e.g. ``decomposable`` of a run that failed before
its table) are left out and counted in the caption.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from rgtbus.errors import BadInput
from rgtbus.extras import require
from rgtbus.stats import mean_interval, wilson
from rgtbus.telemetry.sweep_read import results_of


def _metric(
    rows: list[dict[str, Any]], y: str
) -> tuple[Callable[[dict[str, Any]], Any], bool, str]:
    """(value of a row or None, whether it is a share, label)."""
    columns = list(rows[0]) if rows else []
    col, eq, want = y.partition("=")
    if col not in columns:
        raise BadInput(f"--y {y!r}: no column {col!r} (columns: {', '.join(columns)})")
    if eq:
        return (
            # a run without the column's value (no outcome: it failed) is not one with it
            (lambda r: float(r.get(col) is not None and str(r[col]) == want)),
            True,
            (f"share of runs with {col} = {want}"),
        )
    sample = [r[col] for r in rows if r.get(col) is not None]
    if all(isinstance(v, bool) for v in sample):
        return (lambda r: None if r.get(col) is None else float(r[col])), True, f"share {col}"
    if any(isinstance(v, list | dict | tuple) for v in sample):
        raise BadInput(
            f"--y {y!r}: column {col!r} holds lists or tables, not one number a run (e.g. "
            "units: decided_count, frustrated_count; relations: alliance_share; "
            "decode_errors: decode_error_count)"
        )
    if not all(isinstance(v, int | float) for v in sample):
        raise BadInput(
            f"--y {y!r}: column {col!r} holds text; use {col}=VALUE for the share of runs "
            "where it equals VALUE"
        )
    return (lambda r: None if r.get(col) is None else float(r[col])), False, col


def select_rows(rows: list[dict[str, Any]], where: Sequence[str]) -> list[dict[str, Any]]:
    """The rows whose column KEY reads VALUE for every ``KEY=VALUE`` (compared as text, so
    ``n=5`` and ``x=0.5`` match the numbers)."""
    for cond in where:
        key, eq, want = cond.partition("=")
        if not eq:
            raise BadInput(f"--where {cond!r}: write KEY=VALUE")
        _key(rows, key, "--where")
        rows = [r for r in rows if r.get(key) is not None and _text(r[key]) == want]
        if not rows:
            raise BadInput(f"--where {cond!r}: no run has {key} = {want}")
    return rows


def _text(v: Any) -> str:
    return json.dumps(v) if isinstance(v, bool) else str(v)


def _key(rows: list[dict[str, Any]], key: str, flag: str) -> None:
    if rows and key not in rows[0]:
        raise BadInput(f"{flag} {key!r}: not a column of the results")


def _sort_key(v: Any) -> tuple[int, float, str]:
    return (0, float(v), "") if isinstance(v, int | float) else (1, 0.0, str(v))


def exact_cograph(n: int, p: float) -> float:
    """The exact probability that a group of n units socialised at p is decomposable: each
    pair allied with probability p² (both must send alliance), so G(n, p²) must be a cograph."""
    from rgtbus.rgt.cographs import cograph_probability

    return cograph_probability(n, p * p)


def plot_sweep(
    out_dir: Path,
    x: str,
    y: str | Sequence[str],
    *,
    by: str | None = None,
    output: str | None = None,
    title: str | None = None,
    exact: str | None = None,
    where: Sequence[str] = (),
) -> Path:
    """Draw each metric of ``y`` against ``x`` in its own panel, side by side (one curve per
    ``by`` value), of the runs that match every ``where`` (``KEY=VALUE``); return the PNG's
    path."""
    require("matplotlib", "sweep-plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ys = [y] if isinstance(y, str) else list(y)
    if not ys:
        raise BadInput("--y: name at least one metric")
    rows = results_of(out_dir)
    if not rows:
        raise BadInput(f"{str(out_dir)!r}: the sweep's results hold no runs")
    _key(rows, x, "--x")
    if by:
        _key(rows, by, "--by")
    rows = select_rows(rows, where)
    metrics = [_metric(rows, m) for m in ys]  # every --y checked before anything is drawn
    fig, axes = plt.subplots(
        1, len(ys), figsize=(7.5 if len(ys) == 1 else 5.6 * len(ys), 4.8), layout="constrained"
    )
    axes = [axes] if len(ys) == 1 else list(axes)
    counts: set[int] = set()
    skipped = []
    for ax, m, (value, share, label) in zip(axes, ys, metrics, strict=True):
        c, k = _panel(ax, rows, x, m, by, exact, value, share, label)
        counts |= c
        if k:
            skipped.append(f"{k} runs without {m}")
    meta = _sweep_name(out_dir)
    n_txt = f"{min(counts)}–{max(counts)}" if len(counts) > 1 else f"{next(iter(counts))}"
    labels = [label for _, _, label in metrics]
    default = f"{meta}: {labels[0]} vs {x}" if len(ys) == 1 else f"{meta}: vs {x}"
    if len(ys) == 1:
        axes[0].set_title(title or default, fontsize=12, wrap=True)
    else:
        fig.suptitle(title or default, fontsize=13, wrap=True)
    kinds = {share for _, share, _ in metrics}
    names = {True: "Wilson interval", False: "interval of the mean"}
    interval = " / ".join(names[k] for k in (True, False) if k in kinds)
    note = f"{n_txt} runs (seeds) a point; bars: 95 % {interval}" + (
        f"; left out: {', '.join(skipped)}" if skipped else ""
    )
    fig.supxlabel(note, fontsize=8, color="0.3", x=0.01, ha="left")  # laid out: never overlaps
    safe = "".join(c if c.isalnum() or c in "._-+" else "_" for c in f"{'+'.join(ys)}-vs-{x}")
    path = Path(output) if output else out_dir / f"{safe}.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _panel(
    ax: Any,
    rows: list[dict[str, Any]],
    x: str,
    y: str,
    by: str | None,
    exact: str | None,
    value: Callable[[dict[str, Any]], Any],
    share: bool,
    label: str,
) -> tuple[set[int], int]:
    """One metric's curves on ``ax``; the runs a point (set) and the runs without a value."""
    groups: dict[Any, dict[Any, list[float]]] = {}
    skipped = 0
    for r in rows:
        v = value(r)
        if v is None:
            skipped += 1
            continue
        groups.setdefault(r.get(by) if by else None, {}).setdefault(r[x], []).append(v)
    if not groups:
        raise BadInput(f"--y {y!r}: no run has a value")
    counts = set()
    for curve in sorted(groups, key=_sort_key):
        pts = groups[curve]
        xs = sorted(pts, key=_sort_key)
        stats = []
        for xv in xs:
            vals = pts[xv]
            counts.add(len(vals))
            if share:
                stats.append(wilson(round(sum(vals)), len(vals)))
            else:
                m, lo, hi = mean_interval(vals)
                if min(vals) >= 0:  # counts and rates: a mean of them is never below 0
                    lo = max(0.0, lo)
                stats.append((m, lo, hi))
        numeric = all(isinstance(v, int | float) for v in xs)
        pos = [float(v) for v in xs] if numeric else list(range(len(xs)))
        mid = [s[0] for s in stats]
        err = [[max(0.0, s[0] - s[1]) for s in stats], [max(0.0, s[2] - s[0]) for s in stats]]
        name = f"{by} = {curve}" if by else "simulated"
        line = ax.errorbar(pos, mid, yerr=err, marker="o", capsize=3, label=name)
        if not numeric:
            ax.set_xticks(pos, [str(v) for v in xs])
        if exact == "cograph":
            ns = xs if x == "n" else [curve if by == "n" else None] * len(xs)
            ps = xs if x == "relations.p" else [curve if by == "relations.p" else None] * len(xs)
            if all(isinstance(n, int) for n in ns) and all(isinstance(p, int | float) for p in ps):
                ex = [exact_cograph(int(n), float(p)) for n, p in zip(ns, ps, strict=True)]
                ax.plot(
                    pos,
                    ex,
                    ls="--",
                    color=line.lines[0].get_color(),
                    alpha=0.8,
                    label=f"exact ({name})",
                )
            else:
                raise BadInput(
                    "--exact cograph needs n and relations.p as --x and --by (in either order)"
                )
        elif exact == "alliance":  # both ends must send alliance: p² (the AND rule)
            if x != "relations.p":
                raise BadInput("--exact alliance needs relations.p as --x")
            ax.plot(pos, [float(p) ** 2 for p in xs], ls="--", color="0.3", label="p² (AND rule)")
        elif exact:
            raise BadInput(f"--exact {exact!r}: unknown (cograph or alliance)")
    ax.set_xlabel(x)
    ax.set_ylabel(label)
    flat = all(v == 0 for pts in groups.values() for vals in pts.values() for v in vals)
    if share or flat:  # a metric that is 0 everywhere: the zero line at the bottom, not mid-air
        ax.set_ylim(-0.03, 1.03)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=9)
    return counts, skipped


def _sweep_name(out_dir: Path) -> str:
    try:
        return str(json.loads((out_dir / "sweep.json").read_text(encoding="utf-8"))["name"])
    except (OSError, ValueError, KeyError):
        return out_dir.name
