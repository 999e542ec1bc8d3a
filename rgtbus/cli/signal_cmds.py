"""``rgtbus resonate``, ``rgtbus ser`` and ``rgtbus figures``: the resonate-and-fire receiver
from the shell.

Plotting lives here (an adapter: it writes files); matplotlib is imported lazily with Agg.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rgtbus.cli import add_quiet_argument
from rgtbus.cli.arguments import add_seed_argument
from rgtbus.cli.tables import table_lines
from rgtbus.errors import BadInput, IOFailure
from rgtbus.extras import require
from rgtbus.scenario.limits import MAX_SECONDS, RECORDED, check_trials, over_budget
from rgtbus.signal.codebook import paper_codebook
from rgtbus.signal.plan import PAPER_OMEGA_TEXT, PAPER_OMEGAS, parse_omega
from rgtbus.signal.resonator import PAPER_TAU, FeedResult, ResonatorBank, euler_limit
from rgtbus.signal.waveform import Transmission, hear, pulse_instants
from rgtbus.timebase import sample_of, time_of, times_of

if TYPE_CHECKING:
    from types import ModuleType

    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from rgtbus.cli import SubParsers

PI = math.pi


def register(subparsers: SubParsers) -> None:
    """Add ``resonate``, ``ser`` and ``figures``."""
    _add_resonate(subparsers)
    _add_ser(subparsers)
    _add_figures(subparsers)


def _add_resonate(subparsers: SubParsers) -> None:
    p = subparsers.add_parser(
        "resonate",
        help="feed one code to a bank of resonators; report peak y and spikes",
        description="Send one code (pulse magnitudes --pulses on channel --on) and report, per "
        "resonator: omega, peak recorded y (1.5 when it spiked) and spike times.",
    )
    p.add_argument(
        "--omega",
        action="append",
        metavar="EXPR",
        help="resonator frequency, rad/s: 3pi/2, 1.5pi, 4.71 (repeat; default the "
        "paper's 3pi/2, 4pi/3, 5pi/3)",
    )
    p.add_argument(
        "--pulses",
        default="0.4,0.4,0.4",
        metavar="M1,M2,...",
        help="pulse magnitudes of the code (default the ID-code 0.4,0.4,0.4)",
    )
    p.add_argument(
        "--on",
        type=int,
        default=0,
        metavar="INDEX",
        help="index of the --omega the code is sent on (default 0)",
    )
    p.add_argument(
        "--start",
        type=float,
        default=0.001,
        metavar="SECONDS",
        help="time of the first pulse (default 0.001, the paper's 1 ms)",
    )
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="SECONDS",
        help="simulated time (default: start + pulses × slowest period + 0.5 s)",
    )
    p.add_argument("--mode", choices=("paper", "exact"), default="paper")
    p.add_argument(
        "--noise",
        type=float,
        default=0.0,
        metavar="SIGMA",
        help="white Gaussian noise on every sample (default 0)",
    )
    add_seed_argument(p, help="noise seed (default 0)", default=0)
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--plot", metavar="PNG", help="also write the y trajectories to this PNG")
    add_quiet_argument(p)
    p.set_defaults(func=cmd_resonate)


def _add_ser(subparsers: SubParsers) -> None:
    e = subparsers.add_parser(
        "ser",
        help="the decoder's symbol error rate against noise, beside the best possible receiver's",
        description="Monte-Carlo symbol error rate of the resonator bank's decoder for one "
        "family of a codebook (its words sent on one channel under white noise), beside the "
        "maximum-likelihood bounds at the same noise (docs/model.md, 'How far from the limit').",
    )
    e.add_argument(
        "--family",
        choices=("alternative", "relation"),
        default="alternative",
        help="the words decoded: the alternatives (default) or alliance/conflict",
    )
    e.add_argument(
        "--scenario",
        metavar="NAME_OR_FILE",
        help="take the codebook, first unit's channel, mode and sample time from this scenario "
        "(default: the paper's codebook on 3pi/2)",
    )
    e.add_argument(
        "--sigma",
        default="0.05,0.1,0.15,0.2",
        metavar="S1,S2,...",
        help="noise levels (default 0.05,0.1,0.15,0.2)",
    )
    e.add_argument("--trials", type=int, default=2000, help="trials per level (default 2000)")
    add_seed_argument(e, help=None, default=0)
    e.add_argument("--json", action="store_true", help="print one JSON object per level")
    e.add_argument(
        "--plot",
        metavar="PNG",
        help="also draw the decoder's rate beside the bounds against noise, as a PNG",
    )
    e.set_defaults(func=cmd_ser)


def _add_figures(subparsers: SubParsers) -> None:
    f = subparsers.add_parser(
        "figures",
        help="regenerate the paper's resonator figures and the decoder's error rate",
        description="Write PNGs: matched vs unmatched resonators for the paper's excitatory, "
        "inhibitory and mixed series on two frequency pairs, receiving a message, "
        "and the decoder's symbol error rate against noise.",
    )
    f.add_argument("outdir", metavar="OUTDIR")
    f.add_argument(
        "--trials",
        type=int,
        default=1000,
        help="Monte-Carlo trials per point of the error-rate figure (default 1000)",
    )
    add_seed_argument(f, help=None, default=0)
    f.add_argument(
        "--json", action="store_true", help="print a JSON list: each figure's path and caption"
    )
    add_quiet_argument(f)
    f.set_defaults(func=cmd_figures)


# -- resonate ------------------------------------------------------------------------------


def _numbers(text: str, flag: str) -> tuple[float, ...]:
    """``1,2.5,-3``: the finite numbers of option ``flag``, or one line naming the bad one."""
    out = []
    for tok in str(text).split(","):
        tok = tok.strip()
        try:
            v = float(tok)
        except ValueError:
            raise BadInput(f"{flag}: {tok!r} is not a number") from None
        if not math.isfinite(v):
            raise BadInput(f"{flag}: {tok!r} is not finite")
        out.append(v)
    return tuple(out)


def _parse_pulses(text: str) -> tuple[float, ...]:
    return _numbers(text, "--pulses")


def run_resonate(
    omegas: Sequence[float],
    word: Sequence[float],
    on: int,
    *,
    start: float = 0.001,
    duration: float | None = None,
    mode: str = "paper",
    noise: float = 0.0,
    seed: int = 0,
    tau: float = PAPER_TAU,
) -> tuple[ResonatorBank, FeedResult]:
    """Bank over ``omegas`` fed one code (``word`` on ``omegas[on]`` from ``start``)."""
    if not 0 <= on < len(omegas):
        raise BadInput(f"--on {on}: no such resonator (give 0..{len(omegas) - 1})")
    if not (math.isfinite(start) and start >= 0):
        raise BadInput(f"--start {start!r}: must be a time ≥ 0 s")
    if not (math.isfinite(noise) and noise >= 0):
        raise BadInput(f"--noise {noise!r}: must be ≥ 0")
    if mode == "paper":
        lim = euler_limit(tau)
        for w in omegas:
            if w >= lim:
                raise BadInput(
                    f"--omega {w:.6g}: beyond Euler's stable band ({lim:.4g} rad/s) "
                    "in paper mode; use --mode exact"
                )
    if duration is None:
        duration = start + len(word) * 2 * PI / min(omegas) + 0.5
    if not (math.isfinite(duration) and duration > 0):
        raise BadInput(f"--duration {duration!r}: must be positive")
    if duration > MAX_SECONDS:
        raise BadInput(f"--duration {duration:g}: beyond {MAX_SECONDS:g} s")
    n = sample_of(duration, tau) + 1
    why = over_budget(RECORDED, float(n) * len(omegas))  # bounded work, before any sample
    if why is not None:
        raise BadInput(f"--duration {duration:g}: {why}")
    last = pulse_instants(omegas[on], start, len(word), tau)[-1]
    if last >= n:
        raise BadInput(
            f"--duration {duration:g}: the code's last pulse comes at "
            f"{time_of(last, tau):g} s, after the end"
        )
    u = hear([Transmission(omegas[on], start, tuple(word))], n, sigma=noise, seed=seed, tau=tau)
    bank = ResonatorBank(omegas, mode=mode, tau=tau)
    return bank, bank.feed(u[:, 0], record=True)


def cmd_resonate(args: argparse.Namespace) -> int:
    """``rgtbus resonate``: each resonator's peak y and spike times (and ``--plot``)."""
    if args.plot:
        require("matplotlib", "--plot")
    texts = args.omega or list(PAPER_OMEGA_TEXT[:3])
    omegas = [parse_omega(t, where="--omega") for t in texts]
    word = _parse_pulses(args.pulses)
    bank, res = run_resonate(
        omegas,
        word,
        args.on,
        start=args.start,
        duration=args.duration,
        mode=args.mode,
        noise=args.noise,
        seed=args.seed,
    )
    tau = bank.tau
    assert res.y is not None  # run_resonate feeds with record=True
    rows: list[dict[str, Any]] = []
    for c, w in enumerate(omegas):
        times = times_of(res.spikes[res.spikes[:, 2] == c, 0], tau)
        rows.append(
            {
                "omega": float(w),
                "peak_y": float(res.y[:, 0, c].max()),
                "spikes": [round(float(t), 9) for t in times],
            }
        )
    if args.plot:
        _plot_resonate(
            Path(args.plot),
            omegas,
            texts,
            word,
            args.on,
            args.start,
            res.y,
            tau,
            args.mode,
            noise=args.noise,
            seed=args.seed,
        )
    if args.json:
        print(json.dumps({"resonators": rows}))
    else:
        print(
            f"code {_word_text(word)} on {texts[args.on]} from {args.start:g} s, mode {args.mode}"
            + (f", noise {args.noise:g} (seed {args.seed})" if args.noise else "")
        )
        cells = [
            [
                t,
                f"{r['omega']:.4f}",
                f"{r['peak_y']:.3f}",
                ", ".join(f"{s:.3f}" for s in r["spikes"]) or "-",
            ]
            for t, r in zip(texts, rows, strict=True)
        ]
        headers = ["omega", "rad/s", "peak y", "spikes (s)"]
        for line in table_lines(cells, headers, align=("right",) * 3 + ("left",), indent=""):
            print(line)
    return 0


# -- ser ------------------------------------------------------------------------------------


def _sigmas(text: str) -> list[float]:
    sigmas = list(_numbers(text, "--sigma"))
    for v in sigmas:
        if v < 0:
            raise BadInput(f"--sigma: {v:g} is not a noise level >= 0")
    return sigmas


def cmd_ser(args: argparse.Namespace) -> int:
    """``rgtbus ser``: the decoder's symbol error rate at each noise level beside the
    maximum-likelihood bounds (and ``--plot``)."""
    from rgtbus.signal.evaluate import ser_against_bound

    if args.plot:
        require("matplotlib", "--plot")
    sigmas = _sigmas(args.sigma)
    check_trials(args.trials, len(sigmas))  # bounded work: the budget, before any decode
    if args.scenario:
        from rgtbus.scenario import load_scenario

        sc = load_scenario(args.scenario)
        cb, omega = sc.codebook, sc.frequencies[sc.units[0]]
        mode, tau, where = sc.mode, sc.timing.tau, f"scenario {sc.name}"
    else:
        cb, omega, mode, tau, where = paper_codebook(), PAPER_OMEGAS[0], "paper", PAPER_TAU, "paper"
    words = cb.alternatives if args.family == "alternative" else cb.relations
    rows = ser_against_bound(
        words, omega, sigmas, trials=args.trials, seed=args.seed, mode=mode, tau=tau
    )
    if args.plot:
        figure_ser_bound(Path(args.plot), rows, f"{args.family} words, {where} codebook")
    if args.json:
        for r in rows:
            print(json.dumps(r))
        return 0
    print(f"{args.family} words of the {where} codebook ({len(words)}), on {omega:.4f} rad/s")
    cells = [
        [
            f"{r['sigma']:g}",
            f"{r['errors']}/{r['trials']}",
            f"{r['ser']:.4g}",
            f"{r['ml_lower']:.3g}",
            f"{r['ml_union']:.3g}",
            "-" if r["vs_bound"] is None else f"{r['vs_bound']:.2f}x",
        ]
        for r in rows
    ]
    headers = ["sigma", "errors", "decoder SER", "ML >=", "ML <=", "SER / ML <="]
    for line in table_lines(cells, headers, align=("right",) * 6, indent=""):
        print(line)
    return 0


# -- plotting (lazy matplotlib) ---------------------------------------------------------------


def _pyplot() -> ModuleType:
    """``matplotlib.pyplot``, drawing to files only (Agg)."""
    require("matplotlib", "a plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Figure, path: Path, caption: str) -> None:
    fig.text(0.5, 0.01, caption, ha="center", va="bottom", fontsize=8.5, wrap=True)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110)
    except OSError as exc:
        raise IOFailure(f"cannot write {str(path)!r}: {exc.strerror or exc}") from None
    finally:
        _pyplot().close(fig)


def pi_text(text: str) -> str:
    """A frequency as figures write it: ``3pi/2`` → ``3π/2`` (``4.71`` unchanged)."""
    return text.replace("pi", "π")


def _word_text(word: Sequence[float]) -> str:
    return "{" + ", ".join(f"{m:g}" for m in word) + "}"


def _plot_resonate(
    path: Path,
    omegas: Sequence[float],
    texts: Sequence[str],
    word: Sequence[float],
    on: int,
    start: float,
    y: np.ndarray,
    tau: float,
    mode: str,
    *,
    noise: float,
    seed: int,
) -> None:
    """The y trajectories ``y`` (samples × 1 × resonators) of ``rgtbus resonate --plot``."""
    plt = _pyplot()
    n = y.shape[0]
    t = times_of(np.arange(n), tau)
    names = [pi_text(x) for x in texts]
    fig, axes = plt.subplots(
        len(omegas), 1, figsize=(8, 1.9 * len(omegas) + 1.3), sharex=True, squeeze=False
    )
    inst = times_of(pulse_instants(omegas[on], start, len(word), tau), tau)
    for c, ax in enumerate(axes[:, 0]):
        ax.plot(t, y[:, 0, c], lw=1, color="C0" if c == on else "C7")
        ax.axhline(1.0, color="k", lw=0.6, ls=":")
        for x in inst:
            ax.axvline(x, color="g", lw=0.8, alpha=0.7)
        ax.set_ylabel(f"y, ω={names[c]}", fontsize=8)
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle(
        f"Resonators fed the code {_word_text(word)} on ω = {names[on]}, "
        + (f"noise σ = {noise:g}" if noise else "no noise"),
        fontsize=11,
    )
    fig.tight_layout(rect=(0, 0.09, 1, 1))
    noise_text = (
        f"white Gaussian noise σ = {noise:g} per sample (seed {seed})"
        if noise
        else "no noise (σ = 0)"
    )
    _save(
        fig,
        path,
        f"Code {_word_text(word)} sent on ω = {names[on]} from {start:g} s ({mode} mode), "
        f"{noise_text}; green lines: pulses; dotted: threshold 1; spikes are drawn as y = 1.5.",
    )


def _trace(
    omegas: Sequence[float], word: Sequence[float], on: int, seconds: float, start: float = 0.001
) -> tuple[np.ndarray, np.ndarray]:
    n = sample_of(seconds, PAPER_TAU) + 1
    u = hear([Transmission(omegas[on], start, tuple(word))], n)[:, 0]
    res = ResonatorBank(omegas).feed(u, record=True)
    assert res.y is not None  # fed with record=True
    return times_of(np.arange(n), PAPER_TAU), res.y[:, 0, :]


def figure_pair(path: Path, pair: tuple[int, int], word: Sequence[float], title: str) -> str:
    """The paper's matched/unmatched figure for one series on one frequency pair."""
    plt = _pyplot()
    oms = [PAPER_OMEGAS[pair[0]], PAPER_OMEGAS[pair[1]]]
    names = [pi_text(PAPER_OMEGA_TEXT[pair[0]]), pi_text(PAPER_OMEGA_TEXT[pair[1]])]
    seconds = 5.0
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    colors = ("tab:green", "tab:red")
    verdict = []
    for row, ax in enumerate(axes):
        other = 1 - row
        t, y_m = _trace(oms, word, row, seconds)
        _, y_u = _trace(oms, word, other, seconds)
        fired = (
            "fires" if (y_m[:, row] >= 1.5).any() else "does not fire",
            "fires" if (y_u[:, row] >= 1.5).any() else "does not fire",
        )
        verdict.append(
            f"ω = {names[row]} {fired[0]} for its own series and {fired[1]} for {names[other]}'s"
        )
        ax.plot(t, y_m[:, row], color="C0", lw=1.1, label=f"input on ω = {names[row]} (matched)")
        ax.plot(
            t,
            y_u[:, row],
            color="C1",
            lw=1.1,
            ls="--",
            label=f"input on ω = {names[other]} (unmatched)",
        )
        for j, c in ((row, colors[row]), (other, colors[other])):
            for x in times_of(pulse_instants(oms[j], 0.001, len(word)), PAPER_TAU):
                ax.axvline(x, color=c, lw=0.8, alpha=0.6)
        ax.axhline(1.0, color="k", lw=0.6, ls=":")
        ax.set_ylabel("y")
        ax.set_title(f"resonator ω = {names[row]}", fontsize=10)
        ax.legend(fontsize=8, loc="lower left")
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(title, fontsize=11)
    fig.tight_layout(rect=(0, 0.09, 1, 1))
    caption = (
        f"{title}: " + "; ".join(verdict) + f" (spikes drawn as y = 1.5). Green/red "
        f"lines: pulses on {names[0]}/{names[1]}; paper mode, b = −0.1, τ = 5 ms, "
        "start 1 ms."
    )
    _save(fig, path, caption)
    return caption


RECEIVING_DELAY = 0.5  # the protocol's reaction delay D, s


@dataclass(frozen=True)
class Receiving:
    """One run of the "receiving messages" experiment: y traces (samples × [a, b, c]), the
    spike times per channel (s), when the ω_c code started and whether the bank was quenched
    just before it."""

    t: np.ndarray
    y: np.ndarray
    spikes: dict[str, list[float]]
    t_send: float
    quench: bool


def receiving_run(*, quench: bool, delay: float = RECEIVING_DELAY) -> Receiving:
    """a's ID-code on ω_a from 1 ms; ``delay`` s after the ω_a spike, the ID-code on ω_c
    (a addressing c, the paper's "receiving messages"), into a paper-mode bank of ω_a, ω_b,
    ω_c. ``quench``: put every resonator back to rest just before the ω_c code, as if it
    arrived alone; without it a's ID still rings (1/|b| = 10 s), as within a protocol turn."""
    oms = list(PAPER_OMEGAS[:3])
    word = (0.4, 0.4, 0.4)
    # 4 s (800 samples) hold the ID's three pulses and its spike (2.67 s)
    first = ResonatorBank(oms).feed(hear([Transmission(oms[0], 0.001, word)], 800)[:, 0])
    k_spike = int(first.spikes[first.spikes[:, 2] == 0, 0][0])
    t_send = time_of(k_spike + sample_of(delay, PAPER_TAU), PAPER_TAU)
    n = sample_of(t_send + 4.0, PAPER_TAU)
    u = hear([Transmission(oms[0], 0.001, word), Transmission(oms[2], t_send, word)], n)[:, 0]
    bank = ResonatorBank(oms)
    k_send = int(pulse_instants(oms[2], t_send, 1)[0])
    parts = [bank.feed(u[:k_send], record=True)]
    if quench:
        bank.quench()
    parts.append(bank.feed(u[k_send:], record=True))
    assert parts[0].y is not None and parts[1].y is not None  # fed with record=True
    y = np.concatenate([parts[0].y[:, 0, :], parts[1].y[:, 0, :]])
    spikes: dict[str, list[float]] = {"a": [], "b": [], "c": []}
    for part in parts:
        for k, _, c in part.spikes:
            spikes["abc"[int(c)]].append(round(time_of(int(k), PAPER_TAU), 6))
    return Receiving(times_of(np.arange(n), PAPER_TAU), y, spikes, t_send, quench)


def _spike_text(run: Receiving) -> str:
    def one(name: str) -> str:
        ts = [x for x in run.spikes[name] if x >= run.t_send]
        return f"ω_{name} " + (
            "spikes at " + ", ".join(f"{x:.2f}" for x in ts) + " s" if ts else "no spike"
        )

    return ", ".join(one(name) for name in "cba")


def _ring_text(run: Receiving) -> str:
    """y of ω_c and ω_b just before each pulse of the ω_c code: why they spike or not."""
    ks = pulse_instants(PAPER_OMEGAS[2], run.t_send, 3)
    return "; ".join(
        f"ω_{name}'s y before the ω_c pulses "
        + ", ".join(f"{run.y[k - 1, c]:.2f}".replace("-", "−") for k in ks)
        for c, name in ((2, "c"), (1, "b"))
    )


def figure_receiving(path: Path) -> str:
    """The paper's "receiving messages" (a's ID on ω_a, then 0.5 s after its spike the ID on
    ω_c), twice: left under the conditions the paper's claim implies (the bank at rest when
    the ω_c code arrives), right as a protocol turn has it (a's ID still ringing)."""
    plt = _pyplot()
    oms = list(PAPER_OMEGAS[:3])
    runs = (receiving_run(quench=True), receiving_run(quench=False))
    fig, axes = plt.subplots(3, 2, figsize=(13, 7.4), sharex=True, sharey=True)
    order = [(0, "a"), (2, "c"), (1, "b")]
    heads = (
        "Paper's claim: bank at rest (quenched)\nwhen the ω_c code arrives",
        "rgtbus default (a protocol turn): no quench,\n"
        "a's ID still rings when the ω_c code arrives",
    )
    for col, (run, head) in enumerate(zip(runs, heads, strict=True)):
        for row, (c, name) in enumerate(order):
            ax = axes[row, col]
            ax.plot(run.t, run.y[:, c], lw=1)
            ax.axhline(1.0, color="k", lw=0.6, ls=":")
            for x in times_of(pulse_instants(oms[0], 0.001, 3), PAPER_TAU):
                ax.axvline(x, color="tab:green", lw=0.8, alpha=0.6)
            for x in times_of(pulse_instants(oms[2], run.t_send, 3), PAPER_TAU):
                ax.axvline(x, color="tab:red", lw=0.8, alpha=0.6)
            if run.quench:
                ax.axvline(run.t_send, color="0.3", lw=1.0, ls="--")
            late = [x for x in run.spikes[name] if x >= run.t_send]
            verdict = "spikes" if late else "no spike"
            ax.set_title(
                f"ω_{name} = {pi_text(PAPER_OMEGA_TEXT[c])}"
                + (f": {verdict} on the ω_c code" if name != "a" else ""),
                fontsize=10,
            )
            if col == 0:
                ax.set_ylabel("y")
        axes[0, col].text(
            0.5, 1.32, head, transform=axes[0, col].transAxes, ha="center", fontsize=11
        )
        axes[-1, col].set_xlabel("time (s)")
    fig.suptitle("Receiving messages: unit a addresses unit c", fontsize=12)
    fig.tight_layout(rect=(0, 0.1, 1, 0.97))
    left, right = runs

    def claim(run: Receiving) -> str:  # said only when this run shows it
        c, b = (any(x >= run.t_send for x in run.spikes[k]) for k in "cb")
        return ", the paper's outcome" if c and not b else ", not the paper's outcome"

    caption = (
        f"a sends its ID-code on ω_a (green), then {RECEIVING_DELAY:g} s after the ω_a spike "
        f"(at {left.spikes['a'][0]:.2f} s) the ID-code on ω_c (red, from {left.t_send:.2f} s); "
        f"paper mode, b = −0.1, τ = 5 ms. Left, every resonator put back to rest just before "
        f"the ω_c code (dashed): {_spike_text(left)}{claim(left)}. Right, as in a protocol "
        f"turn (no quench between ID and payload): {_spike_text(right)}{claim(right)}. "
        f"a's ID still rings (1/|b| = 10 s): {_ring_text(right)}."
    )
    _save(fig, path, caption)
    return caption


SIGMAS = (0.0, 0.02, 0.05, 0.1, 0.2)
SER_CURVES = 4  # figure_ser's curves


def _ser_axes(fig: Figure, ax: Axes, floor: float, title: str) -> None:
    """An error rate against noise: log scale down to ``floor`` (half an error in the trials,
    where a rate of 0 is drawn), a dotted line there, labels, legend."""
    ax.set_yscale("log")
    ax.set_ylim(floor * 0.8, 1)
    ax.axhline(floor, color="k", lw=0.5, ls=":")
    ax.set_xlabel("noise σ (per sample)")
    ax.set_ylabel("symbol error rate")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout(rect=(0, 0.07, 1, 1))


def figure_ser(path: Path, trials: int, seed: int) -> str:
    """The decoder's symbol error rate against noise for the paper's codebook (alone, with an
    interferer, alliance/conflict words), as a PNG at ``path``; its caption."""
    from rgtbus.signal.evaluate import symbol_error_rate

    plt = _pyplot()
    cb = paper_codebook()
    wa, wc = PAPER_OMEGAS[0], PAPER_OMEGAS[2]
    curves: dict[str, dict[str, Any]] = {
        "alternatives, alone": dict(words=cb.alternatives),
        "alternatives + interferer on ω_c, joint": dict(words=cb.alternatives, interferer=wc),
        "alternatives + interferer, independent": dict(
            words=cb.alternatives, interferer=wc, joint=False
        ),
        "alliance/conflict, alone": dict(words=cb.relations),
    }
    assert len(curves) == SER_CURVES  # the budget counted them (cmd_figures)
    fig, ax = plt.subplots(figsize=(7.5, 5))
    floor = 0.5 / trials
    for j, (label, kw) in enumerate(curves.items()):
        sers = [
            symbol_error_rate(omega=wa, sigma=s, trials=trials, seed=seed + j, **kw).ser
            for s in SIGMAS
        ]
        ax.plot(SIGMAS, [max(s, floor) for s in sers], marker="o", label=label)
    _ser_axes(
        fig, ax, floor, f"Decoder symbol error rate, code on ω_a = 3π/2, {trials} trials a point"
    )
    caption = (
        "Increment readout + nearest codeword through the paper-mode bank; the "
        "interferer starts with the code (first pulses collide). Points on the dotted "
        f"line had no error in {trials} trials."
    )
    _save(fig, path, caption)
    return caption


def figure_ser_bound(path: Path, rows: list[dict[str, Any]], what: str) -> str:
    """The decoder's symbol error rate (``ser_against_bound`` rows) against noise, beside the
    maximum-likelihood bounds: how far from the limit the receiver is."""
    plt = _pyplot()
    sig = [r["sigma"] for r in rows]
    trials = min(int(r["trials"]) for r in rows)
    floor = 0.5 / trials
    fig, ax = plt.subplots(figsize=(7.5, 5))
    ax.fill_between(
        sig, [max(r["ml_lower"], floor) for r in rows], [max(r["ml_union"], floor) for r in rows],
        color="tab:gray", alpha=0.3, label="maximum likelihood: between its bounds",
    )  # fmt: skip
    ax.plot(sig, [max(r["ser"], floor) for r in rows], marker="o", label="the bank's decoder")
    _ser_axes(fig, ax, floor, f"Decoder against the limit: {what}, {trials} trials a point")
    worst = max((r["vs_bound"] for r in rows if r["vs_bound"] is not None), default=None)
    caption = (
        "Shaded: the nearest-neighbour and union bounds on the best receiver's error rate. "
        + (f"The decoder is at most {worst:.2f}x the union bound. " if worst is not None else "")
        + f"Points on the dotted line had no error in {trials} trials."
    )
    _save(fig, path, caption)
    return caption


SERIES = (
    ("excitatory", (0.4, 0.4, 0.4), "Excitatory series {0.4, 0.4, 0.4}"),
    ("inhibitory", (-0.4, -0.4, -0.4), "Inhibitory series {−0.4, −0.4, −0.4}"),
    ("mixed", (0.1, 0.4, 0.6), "Excitatory series {0.1, 0.4, 0.6}"),
    ("mixed-inhibitory", (-0.1, -0.4, -0.6), "Inhibitory series {−0.1, −0.4, −0.6}"),
)
PAIRS = (((0, 1), "ab"), ((0, 2), "ac"))


def cmd_figures(args: argparse.Namespace) -> int:
    """``rgtbus figures OUTDIR``: every figure written, each with its caption on stdout."""
    require("matplotlib", "rgtbus figures")
    out = Path(args.outdir)
    if out.exists() and not out.is_dir():
        raise BadInput(f"OUTDIR {str(out)!r} exists and is not a directory")
    check_trials(args.trials, len(SIGMAS) * SER_CURVES)  # decoder-ser.png's points
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise IOFailure(f"cannot create OUTDIR {str(out)!r}: {exc.strerror or exc}") from None
    if not os.access(out, os.W_OK):
        raise BadInput(f"OUTDIR {str(out)!r} is not writable")
    made = []
    for pair, tag in PAIRS:
        a, b = (pi_text(PAPER_OMEGA_TEXT[i]) for i in pair)
        for key, word, title in SERIES:
            p = out / f"resonators-{key}-{tag}.png"
            made.append((p, figure_pair(p, pair, word, f"{title}, ω = {a} vs {b}")))
    p = out / "receiving.png"
    made.append((p, figure_receiving(p)))
    p = out / "decoder-ser.png"
    made.append((p, figure_ser(p, args.trials, args.seed)))
    if args.json:
        print(json.dumps([{"path": str(p), "caption": caption} for p, caption in made]))
        return 0
    for p, caption in made:
        print(f"{p}: {caption}")
    return 0
