"""A study's curves (docs/studies.md): how often the target chose what it was steered to, with
its Wilson 95 % band and the clean channel's share beside it; and the payloads' symbol error
rate measured, with its interval, beside the union bound of the best receiver. One curve per
combination of the grid's other axes; the channel axis (σ, or SNR in dB) across."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from rgtbus.errors import BadInput
from rgtbus.extras import require

if TYPE_CHECKING:
    import pandas as pd

FLOOR = 1e-5  # a symbol error rate of 0 drawn here on the log axis (said in the caption)
FEWEST = 100  # a point's symbol error rate is drawn from this many influence decodes on


def grid_columns(points: pd.DataFrame) -> list[str]:
    """The grid's columns of a points table: those between ``point`` and ``sigma``, the channel
    axis last."""
    cols = list(points.columns)
    if "point" not in cols or "sigma" not in cols or cols.index("sigma") < cols.index("point"):
        raise BadInput("not a study's points table (no point ... sigma columns)")
    return cols[cols.index("point") + 1 : cols.index("sigma")]


def plot_study(points: pd.DataFrame, output: Path, *, title: str | None = None) -> list[Path]:
    """Draw ``points`` (a study's points table) to ``output`` as PNG and SVG (its suffix
    replaced); return both paths."""
    require("matplotlib", "study-plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = grid_columns(points)
    axis, others = keys[-1], keys[:-1]
    # no constrained layout: long legends (a table-valued axis) would collapse the axes; the
    # tight bounding box at saving takes them in
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    fig.subplots_adjust(wspace=0.25)
    groups = points.groupby(others, sort=False) if others else [((), points)]
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    early = 0
    bounds: dict[tuple[float, ...], tuple[Any, Any, str, list[str]]] = {}
    for i, (values, group) in enumerate(groups):
        values = values if isinstance(values, tuple) else (values,)
        label = ", ".join(f"{k}={v}" for k, v in zip(others, values, strict=True)) or "all"
        run = group[group["runs"] > 0].sort_values(axis)
        early += int((group["runs"] == 0).sum())
        c = colours[i % len(colours)]
        x = run[axis].astype(float)
        left.fill_between(x, run["p_target_lo"], run["p_target_hi"], color=c, alpha=0.2, lw=0)
        left.plot(x, run["p_target"], "o-", color=c, label=f"{label}: noisy")
        left.plot(x, run["p_clean"], ":", color=c, label=f"{label}: clean channel")
        read = run[run["influence_decodes"] >= FEWEST]
        ser = read["ser"].clip(lower=FLOOR)
        err = [
            (ser - read["ser_lo"].clip(lower=FLOOR)).clip(lower=0),
            (read["ser_hi"].clip(lower=FLOOR) - ser).clip(lower=0),
        ]
        right.errorbar(read[axis].astype(float), ser, yerr=err, fmt="o-", color=c, capsize=3,
                       label=f"{label}: measured")  # fmt: skip
        bound = group.sort_values(axis)
        key = tuple(bound["ser_bound"].round(12)) + tuple(bound[axis].astype(float))
        bounds.setdefault(key, (bound[axis].astype(float), bound["ser_bound"], c, []))[3].append(
            label
        )
    styles = iter(["--", "-.", ":", (0, (5, 1)), (0, (3, 1, 1, 1, 1, 1))] * 100)
    for x, y, c, labels in bounds.values():  # one line for the series that share their words
        shared = len(labels) > 1 or not others
        parts = [lab.split(", ") for lab in labels]
        common = [kv for kv in parts[0] if all(kv in p for p in parts)]
        name = "union bound" + (f" ({', '.join(common)})" if common and len(bounds) > 1 else "")
        right.plot(x, y.clip(lower=FLOOR), next(styles) if shared else "--",
                   color="black" if shared else c,
                   label=name if shared else f"{labels[0]}: union bound")  # fmt: skip
    xlabel = "channel noise σ" if axis == "noise" else "SNR (dB) on a link of gain 1"
    left.axhline(0.9, color="grey", lw=0.8, ls="--")
    left.set(xlabel=xlabel, ylabel="P(target chooses what it was steered to)", ylim=(-0.02, 1.02))
    right.set(xlabel=xlabel, ylabel="payload symbol error rate", yscale="log")
    # beside few curves the legend fits inside; many (or long labels) go below each panel
    many = len(bounds) > 2 or len(left.get_lines()) > 8
    long = max((len(str(h.get_label())) for h in left.get_lines()), default=0) > 45
    for ax in (left, right):
        if many or long:
            ax.legend(fontsize="x-small", ncol=1 if long else 2, loc="upper center",
                      bbox_to_anchor=(0.5, -0.16))  # fmt: skip
        else:
            ax.legend(fontsize="small")
    notes = [
        "shaded and bars: Wilson 95 % intervals",
        f"symbol errors of points with {FEWEST}+ influence decodes, 0 drawn at {FLOOR:g}",
    ]
    if early:
        notes.append(f"{early} point(s) not run: an easier channel than one with no failure")
    fig.suptitle(title or "reflexive control over a noisy medium", y=1.0)
    fig.text(0.5, 0.93, "; ".join(notes), ha="center", fontsize="x-small")
    out = []
    for suffix in (".png", ".svg"):
        path = output.with_suffix(suffix)
        try:
            fig.savefig(path, dpi=120, bbox_inches="tight")
        except OSError as exc:
            plt.close(fig)
            raise BadInput(f"cannot write {str(path)!r}: {exc.strerror}") from None
        out.append(path)
    plt.close(fig)
    return out
