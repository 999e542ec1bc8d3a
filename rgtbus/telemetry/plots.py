"""The paper's "activity of unit" figure for a logged run (matplotlib, Agg, imported lazily).

One panel per channel (one resonator of the unit's bank): its y trace, the pulses on the
medium on that channel (stems, coloured by sender), the unit's spikes (filled: the attention
spike of an ID the unit accepted; hollow grey: any other spike, e.g. crosstalk), and each
transmission labelled with its meaning ("a → c: ID", "a → c: conflict"). Below, the decision
timeline of the whole run: per unit, its decodes (green: read what was sent, red: not), when its
relationship table was complete (with the polynomial) and its decision; the zoomed range is
shaded.

``attention_spikes`` is pure (no matplotlib): it tells attention from other spikes without
drawing. A ``--from``/``--to`` range is checked by ``log_cat.check_time_range``, the one rule
for the timeline, CSV, ``cat`` and plots.

Labels are placed in up to ``LABEL_ROWS`` staggered rows; a label that fits in no row is left
out and the panel says how many were (zoom in with ``t_from``/``t_to``).
"""

from __future__ import annotations

import bisect
import math
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np

from rgtbus.errors import BadInput
from rgtbus.extras import require
from rgtbus.telemetry.log_cat import check_time_range

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from rgtbus.rgt.algebra import Universe
    from rgtbus.telemetry.read import Replay

WIDTH_IN = 14.0
CHANNEL_IN = 2.5
TIMELINE_MIN_IN = 2.0
DPI = 100
LABEL_ROWS = 3
# Sizes in points, read at the PNG's own size (1400 px wide) and still when a viewer shrinks a
# six-unit figure to a screen's height.
LABEL_FONT = 9.5  # transmission labels
FONT = 10.5  # ticks, axis labels, annotations
TITLE_FONT = 12  # panel titles, legend
SUPTITLE_FONT = 14
_Y_LABELS = (1.85, 2.4, 2.95)  # label rows above the threshold
_Y_SPIKE = 1.5  # where spikes are drawn (a resonator's recorded y at a spike)
_EPS = 1e-6  # s: two logged times of the same sample agree far closer than this
_COLORS = [
    "#1f77b4",
    "#d62728",
    "#2ca02c",
    "#9467bd",
    "#ff7f0e",
    "#8c564b",
    "#e377c2",
    "#17becf",
    "#7f7f7f",
    "#bcbd22",
]


def figure_size(n_channels: int, n_units: int) -> tuple[float, float]:
    """Figure size in inches for a unit with ``n_channels`` resonators in a group of
    ``n_units`` (the PNG is ``DPI`` times this)."""
    timeline = max(TIMELINE_MIN_IN, 0.9 + 0.4 * n_units)
    return WIDTH_IN, CHANNEL_IN * n_channels + timeline


def attention_spikes(replay: Replay, unit: str) -> set[tuple[str, float]]:
    """The (channel, t) of every *accepted attention spike* of ``unit``: for each ID it
    decoded and accepted, the spike of its resonator on the ID's channel that the protocol
    takes as "the sender transmits". With the spike anchor that is the first spike from the
    ID's first pulse to the decode (due at the later of the spike and the ID's last pulse);
    with the schedule anchor nothing waits for a spike, and it is the spike at the ID's last
    pulse, where a clean ID fires. Every other spike of the unit (crosstalk, noise, an ID it
    refused) is not in the set."""
    anchor = replay.scenario.timing.anchor if replay.scenario is not None else "spike"
    ids = {(tx.turn, tx.sender): tx for tx in replay.transmissions if tx.kind == "id"}
    times = {ch: sorted(ts.tolist()) for ch, ts in replay.spikes.of_unit(unit).items()}
    out: set[tuple[str, float]] = set()
    for d in replay.decodes:
        if d.unit != unit or d.kind != "id" or not d.accepted or d.turn is None:
            continue
        tx = ids.get((d.turn, d.sender))
        ts = times.get(tx.channel, []) if tx is not None else []
        if tx is None or not ts:
            continue
        if anchor == "spike":
            i = bisect.bisect_left(ts, tx.start - _EPS)
            if i < len(ts) and ts[i] <= max(d.t, tx.end) + _EPS:
                out.add((tx.channel, ts[i]))
        else:
            i = bisect.bisect_left(ts, tx.end - _EPS)
            if i < len(ts) and ts[i] <= tx.end + _EPS:
                out.add((tx.channel, ts[i]))
    return out


def activity_figure(
    replay: Replay,
    unit: str,
    trace: dict[str, Any],
    *,
    t_from: float | None = None,
    t_to: float | None = None,
) -> Figure:
    """The figure (not yet saved). ``trace``: ``{"t", "y" (n × channels), "channels",
    "recomputed"}`` as ``rgtbus.units.rerun.traces_for`` returns it."""
    require("matplotlib", "the activity figure")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    units = list(replay.units)
    if unit not in units:
        raise BadInput(f"--unit {unit!r}: not a unit of this log (units: {', '.join(units)})")
    end = max(replay.sim_seconds, trace["t"][-1] if len(trace["t"]) else 0.0)
    lo, hi = check_time_range(t_from, t_to, 0.0, end)
    channels = list(trace["channels"]) or units
    color = {u: _COLORS[i % len(_COLORS)] for i, u in enumerate(units)}

    w, h = figure_size(len(channels), len(units))
    fig = Figure(figsize=(w, h), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    heights = [CHANNEL_IN] * len(channels) + [h - CHANNEL_IN * len(channels)]
    axes = fig.subplots(len(channels) + 1, 1, gridspec_kw={"height_ratios": heights})
    chan_axes = list(axes[:-1])
    for ax in chan_axes[1:]:
        ax.sharex(chan_axes[0])
    source = "recomputed from the logged medium" if trace.get("recomputed") else "logged trace"
    fig.suptitle(
        f"Activity of unit {unit} — scenario {replay.info()['scenario']}, "
        f"seed {replay.info()['seed']} ({source}); {lo:g}–{hi:g} s",
        fontsize=SUPTITLE_FONT,
    )
    panels = _Panels(replay, unit, trace, lo, hi, color)
    hidden_total = 0
    for ci, (ax, ch) in enumerate(zip(chan_axes, channels, strict=True)):
        hidden_total += panels.draw(ax, ci, ch, last=ci == len(channels) - 1)
    chan_axes[-1].set_xlabel("t (s)", fontsize=FONT)
    if hidden_total:
        chan_axes[0].text(
            1.0,
            1.02,
            f"{hidden_total} labels left out: zoom in with --from/--to",
            transform=chan_axes[0].transAxes,
            ha="right",
            va="bottom",
            fontsize=FONT,
            color="0.4",
        )
    _timeline(axes[-1], replay, lo, hi, end, color)
    _legend(fig, units, color)
    return fig


class _Panels:
    """What every channel's panel of one unit's figure draws from: its trace in the range
    shown, the log's pulses and the unit's spikes (attention spikes told apart)."""

    def __init__(
        self,
        replay: Replay,
        unit: str,
        trace: dict[str, Any],
        lo: float,
        hi: float,
        color: dict[str, str],
    ) -> None:
        self.replay, self.unit, self.lo, self.hi, self.color = replay, unit, lo, hi, color
        self.omegas = replay.info()["frequencies"]
        self.attention = attention_spikes(replay, unit)
        self.spike_times = {ch: ts.tolist() for ch, ts in replay.spikes.of_unit(unit).items()}
        self.t = np.asarray(trace["t"])
        self.y = np.asarray(trace["y"])
        self.view = (self.t >= lo) & (self.t <= hi)
        self.px_per_s = (WIDTH_IN * DPI * 0.86) / (hi - lo)  # axes width ≈ 86 % of the figure

    def draw(self, ax: Axes, ci: int, ch: str, *, last: bool) -> int:
        """Channel ``ch`` (column ``ci`` of the trace) on ``ax``; how many labels did not fit."""
        replay, lo, hi = self.replay, self.lo, self.hi
        if self.y.size:
            ax.plot(
                self.t[self.view], self.y[self.view, ci], color="0.25", lw=0.6, label="resonator y"
            )
        ax.axhline(1.0, color="0.6", lw=0.6, ls="--")
        ax.axhline(0.0, color="0.85", lw=0.5)
        # pulses on this channel, coloured by sender
        for tx in replay.transmissions:
            if tx.channel != ch or tx.end < lo or tx.start > hi:
                continue
            ts = [p[0] for p in tx.pulses]
            ms = [p[1] for p in tx.pulses]
            ax.vlines(ts, 0, ms, color=self.color[tx.sender], lw=1.6)
        spikes = [t for t in self.spike_times.get(ch, ()) if lo <= t <= hi]
        other = [x for x in spikes if (ch, x) not in self.attention]
        accepted = [x for x in spikes if (ch, x) in self.attention]
        if other:  # drawn first: an attention spike on the same sample stays on top
            ax.plot(other, [_Y_SPIKE] * len(other), ls="", **_OTHER_SPIKE)
        if accepted:
            ax.plot(accepted, [_Y_SPIKE] * len(accepted), ls="", **_ATTENTION_SPIKE)
        hidden = _labels(ax, replay, ch, lo, hi, self.px_per_s, self.color)
        om = self.omegas.get(ch)
        ax.set_title(
            f"channel {ch}" + (f" (ω = {om:.3f} rad/s)" if om else ""),
            loc="left",
            fontsize=TITLE_FONT,
        )
        ax.set_ylim(-1.7, 3.3)
        ax.set_yticks([-1, 0, 1])
        ax.set_ylabel("y", fontsize=FONT)
        ax.tick_params(labelsize=FONT)
        ax.set_xlim(lo, hi)
        if not last:
            ax.tick_params(labelbottom=False)
        return hidden


def _legend(fig: Figure, units: list[str], color: dict[str, str]) -> None:
    """The figure's legend below its panels: the trace, the threshold, both kinds of spike and
    each unit's pulses."""
    from matplotlib.lines import Line2D

    handles = [
        Line2D([], [], color="0.25", lw=0.8, label="resonator y"),
        Line2D([], [], color="0.6", lw=0.8, ls="--", label="threshold"),
        Line2D([], [], ls="", label="attention spike (accepted ID)", **_ATTENTION_SPIKE),
        Line2D([], [], ls="", label="other spike (crosstalk, noise)", **_OTHER_SPIKE),
        *(Line2D([], [], color=color[u], lw=2, label=f"pulses from {u}") for u in units),
    ]
    # At most 6 entries a row fit the width at this font; rows filled evenly.
    rows = math.ceil(len(handles) / 6)
    fig.legend(
        handles=handles,
        loc="outside lower center",
        ncols=math.ceil(len(handles) / rows),
        fontsize=FONT,
        frameon=False,
    )


_ATTENTION_SPIKE: dict[str, Any] = {"marker": "v", "color": "#d62728", "ms": 8}
_OTHER_SPIKE: dict[str, Any] = {"marker": "v", "mfc": "none", "mec": "0.5", "mew": 0.9, "ms": 5.5}


def _labels(
    ax: Axes, replay: Replay, ch: str, lo: float, hi: float, px_per_s: float, color: dict[str, str]
) -> int:
    """Transmission labels on a channel, greedily in staggered rows; returns how many did not
    fit."""
    free = [-np.inf] * LABEL_ROWS  # time from which each row is free
    hidden = 0
    char_px = LABEL_FONT * 0.62  # average glyph width at DPI 100, points≈pixels·0.72
    for tx in replay.transmissions:
        if tx.channel != ch or tx.start < lo or tx.start > hi:
            continue
        width_s = (len(tx.label) * char_px + 8) / px_per_s
        # near the right edge the label ends at its transmission instead of starting there
        left = tx.start if tx.start + width_s <= hi else tx.start - width_s
        for row in range(LABEL_ROWS):
            if left >= free[row]:
                free[row] = left + width_s
                ax.text(
                    tx.start,
                    _Y_LABELS[row],
                    tx.label,
                    fontsize=LABEL_FONT,
                    color=color[tx.sender],
                    va="center",
                    ha="left" if left == tx.start else "right",
                    clip_on=True,
                )
                ax.plot(
                    [tx.start, tx.start],
                    [1.55, _Y_LABELS[row] - 0.15],
                    color=color[tx.sender],
                    lw=0.5,
                    alpha=0.6,
                )
                break
        else:
            hidden += 1
    return hidden


def _timeline(
    ax: Axes, replay: Replay, lo: float, hi: float, end: float, color: dict[str, str]
) -> None:
    units = list(replay.units)
    row = {u: len(units) - 1 - i for i, u in enumerate(units)}
    # phases of the protocol as bands
    for phase, shade in (("relations", "#e8f0fa"), ("influences", "#faf0e0")):
        txs = [x for x in replay.transmissions if x.phase == phase]
        if txs:
            a, b = txs[0].start, txs[-1].end
            ax.axvspan(a, b, color=shade, zorder=0)
            ax.text(
                (a + b) / 2,
                len(units) - 0.35,
                f"{phase} phase",
                ha="center",
                va="center",
                fontsize=FONT,
                color="0.35",
            )
    if lo > 0 or hi < end:  # the zoomed range of the panels above
        ax.axvspan(lo, hi, facecolor="0.5", alpha=0.12, edgecolor="0.2", lw=0.8, zorder=1)
    for d in replay.decodes:
        c = "#2ca02c" if d.matches is not False else "#d62728"
        ax.plot([d.t], [row[d.unit]], "|", color=c, ms=9, mew=1.0) if d.unit in row else None
    for u, rel in replay.relations.items():
        if u in row:
            ax.plot([rel["t"]], [row[u]], "s", color=color[u], ms=7)
            ax.annotate(
                rel["polynomial"] or "no polynomial",
                (rel["t"], row[u]),
                xytext=(5, 4),
                textcoords="offset points",
                fontsize=FONT,
            )
    universe = replay.scenario.universe if replay.scenario else None
    for dec in replay.decisions:
        if dec["unit"] != dec["subject"] or dec["unit"] not in row:
            continue
        if dec["frustrated"]:
            text = f"{dec['unit']}: frustrated"
        else:
            text = f"{dec['unit']} chooses {_alt(dec['choice'], universe)}"
            if dec["interval"]:
                lo_a, hi_a = (_alt(v, universe) for v in dec["interval"])
                text += f"  (in [{lo_a}, {hi_a}])" if lo_a != hi_a else ""
        ax.plot([dec["t"]], [row[dec["unit"]]], "D", color=color[dec["unit"]], ms=8)
        ax.annotate(
            text,
            (dec["t"], row[dec["unit"]]),
            xytext=(-7, 4),
            textcoords="offset points",
            fontsize=FONT,
            ha="right",
        )
    outcome = replay.summary()["outcome"]
    ax.set_title(
        "decision timeline: decodes (green ok, red wrong), tables complete (■), decisions (◆)"
        + (f" — outcome {outcome}" if outcome else ""),
        loc="left",
        fontsize=TITLE_FONT,
    )
    ax.set_yticks([row[u] for u in units], units, fontsize=FONT)
    ax.set_ylim(-0.6, len(units) - 0.1)
    ax.set_xlim(0, end * 1.01 if end else 1)
    ax.tick_params(labelsize=FONT)
    ax.set_xlabel("t (s), whole run", fontsize=FONT)


def _alt(value: Any, universe: Universe | None) -> str:
    if value is None:
        return "none"
    if universe is None:
        return "{" + ",".join(value) + "}"
    return universe.format(universe.from_list(value))


def save_png(fig: Figure, stream: BinaryIO) -> None:
    """Write the figure as PNG to an open binary stream."""
    fig.savefig(stream, format="png", dpi=DPI)
