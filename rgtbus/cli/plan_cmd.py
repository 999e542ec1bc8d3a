"""``rgtbus plan N``: the frequency plan for N units on a schedule, with its margins."""

from __future__ import annotations

import argparse
import json
import math
from typing import TYPE_CHECKING

from rgtbus.cli import add_quiet_argument
from rgtbus.cli.tables import table_lines
from rgtbus.errors import BadInput

if TYPE_CHECKING:
    from rgtbus.cli import SubParsers

# What a margin the plan does not keep means, and why the schedule can do without it.
NOT_KEPT = {
    "spacing": "channels closer than the serial schedule allows; the concurrent schedule reads "
    "each code at its own pulse instants, where no other code has a pulse",
    "octave": "the band spans an octave or more (a pulse train on ω excites 2ω too); the "
    "concurrent schedule reads each code at its own pulse instants",
    "decay": "a code's first pulse fades before its last; the concurrent schedule reads the "
    "pulses one by one, not by a spike",
    "attention": "an ID may not make its own resonator spike; the concurrent schedule is timed "
    "by the schedule, not by ID spikes",
    "crosstalk": "other channels' IDs make resonators spike too (crosstalk spikes); they are "
    "logged and never acted on",
}


def register(subparsers: SubParsers) -> None:
    """Add ``plan``."""
    p = subparsers.add_parser(
        "plan",
        help="the frequency plan for N units: mode, band, pulses, codebook, margins",
        description="Choose the resonator mode, the band, the pulses a code and the codebook for "
        "N units on a schedule (docs/model.md, 'Frequency plans'), and state how close the plan "
        "is to each rule. Rules the schedule needs are enforced; the others are margins. For "
        "the concurrent schedule it also places every round and reports the round length.",
    )
    p.add_argument("n", type=int, metavar="N", help="number of units")
    p.add_argument("--schedule", choices=("serial", "concurrent"), default="serial")
    p.add_argument("--pulses", type=int, help="pulses a code (default: chosen)")
    p.add_argument("--mode", choices=("paper", "exact"), help="resonator mode (default: chosen)")
    p.add_argument("--sample-rate", type=float, default=200.0, help="samples a second (200)")
    p.add_argument(
        "--no-crosstalk", action="store_true", help="skip the crosstalk simulation (large N)"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_quiet_argument(p)
    p.set_defaults(func=run_plan)


def _check_size(args: argparse.Namespace) -> None:
    """The plan's run is bounded as a scenario's is (docs/scenarios.md, "Budgets"): N units
    by the memory and wall time of a run with one influence round, the sample rate by the
    samples of a run at the default max_seconds (3600 s) and of a default window (0.1 s)."""
    from rgtbus.scenario import limits

    try:
        why = limits.over_run_budget(args.n, 1)
        if why:
            raise BadInput(f"N = {args.n}: a run of this plan: {why}")
        checks = [
            (f"--sample-rate {args.sample_rate:g}", limits.SAMPLES, 3600 * args.sample_rate),
            (f"--sample-rate {args.sample_rate:g}", limits.WINDOW_SAMPLES, 0.1 * args.sample_rate),
        ]
        for what, budget, estimate in checks:
            why = limits.over_budget(budget, estimate)
            if why:
                raise BadInput(f"{what}: a run of this plan: {why}")
    except OverflowError:  # N beyond floats: beyond every budget
        raise BadInput(f"N = {args.n}: far beyond every budget") from None


def run_plan(args: argparse.Namespace) -> int:
    """``rgtbus plan N``: the plan, its rules and margins (and, concurrent, its rounds)."""
    from rgtbus.protocol import plan_of
    from rgtbus.scenario import limits
    from rgtbus.signal.plan import MAX_PLAN_PULSES, crosstalk_size, make_plan
    from rgtbus.timebase import sample_of

    if not args.n >= 1:
        raise BadInput(f"N = {args.n}: must be a positive number of units")
    if not (math.isfinite(args.sample_rate) and args.sample_rate > 0):
        raise BadInput(f"--sample-rate {args.sample_rate}: must be a positive finite number")
    if args.pulses is not None and not 1 <= args.pulses <= MAX_PLAN_PULSES:
        raise BadInput(f"--pulses {args.pulses}: must be an integer 1..{MAX_PLAN_PULSES}")
    _check_size(args)
    tau = 1.0 / args.sample_rate
    options = {"schedule": args.schedule, "pulses": args.pulses, "mode": args.mode, "tau": tau}
    plan = make_plan(args.n, crosstalk=False, **options)
    if not args.no_crosstalk:  # its simulation counted before it runs
        why = limits.over_budget(limits.CROSSTALK, crosstalk_size(plan.omegas, plan.pulses, tau))
        if why:
            raise BadInput(f"the crosstalk simulation: {why}; or plan with --no-crosstalk")
        plan = make_plan(args.n, crosstalk=True, **options)
    out = plan.to_json()
    if args.schedule == "concurrent":
        units = tuple(f"u{i}" for i in range(args.n))
        timing = plan_of(
            units, tuple(zip(units, plan.omegas, strict=True)), tau, plan.pulses, 0.5, 0.5, 2,
            "concurrent", 0.001,
        ).timing()  # fmt: skip
        lengths = [r.end + 0.5 - r.start for r in timing]
        stagger = max(
            max(sample_of(p.id_start - r.start, tau), 0) for r in timing for p in r.placed
        )
        out["rounds"] = len(timing)
        out["round_seconds"] = [round(min(lengths), 3), round(max(lengths), 3)]
        out["simulated_seconds"] = round(timing[-1].end, 3)
        out["largest_id_stagger_samples"] = stagger
    if args.json:
        print(json.dumps(out))
        return 0
    print(
        f"{plan.n} units, {plan.schedule} schedule: mode {plan.mode}, {plan.pulses} pulses a "
        f"code ({_codebook_text(plan.codebook, plan.pulses)}), band "
        f"{min(plan.omegas):.4g}–{max(plan.omegas):.4g} rad/s, tau {tau:g} s"
    )
    print("frequencies (rad/s): " + ", ".join(f"{w:.5g}" for w in plan.omegas))
    print("rules (the schedule needs them: a plan that breaks one is refused) and margins:")
    rows = []
    for m in plan.margins:
        state = "ok" if m.ok else ("FAIL" if m.binding else "not met")
        rows.append([state, m.rule, "(rule)" if m.binding else "(margin)", m.text])
    for m, line in zip(plan.margins, table_lines(rows), strict=True):
        print(line)
        if not m.ok and not m.binding:
            print(f"    -> margin not met, allowed: {NOT_KEPT.get(m.rule, 'not needed here')}")
    if "rounds" in out:
        print(
            f"rounds: {out['rounds']}, {out['round_seconds'][0]:g}–{out['round_seconds'][1]:g} s "
            f"each (ID stagger up to {out['largest_id_stagger_samples']} samples): "
            f"{out['simulated_seconds']:g} s of simulated time (relations and influences)"
        )
    return 0


def _codebook_text(kind: str, pulses: int) -> str:
    """The codebook a run of this plan uses, as the run names it (its summary, ``info``)."""
    if kind == "paper":
        return "the paper's codebook, 'paper', for 1 or 2 actions"
    return f"a generated codebook: a run names it generated-kK-N{pulses}-seed0 for K actions"
