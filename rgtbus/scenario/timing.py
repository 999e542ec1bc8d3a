"""``[timing]``: every key on its own first (blamed by its own name), then how they fit
together (blamed on a key the file sets)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from rgtbus.protocol import ANCHORS, ATTENTIONS
from rgtbus.scenario.context import Ctx, check_keys, sub_table
from rgtbus.scenario.limits import MAX_SECONDS
from rgtbus.scenario.model import Timing
from rgtbus.scenario.values import is_int

TIMING_KEYS = {
    "sample_rate",
    "window",
    "start",
    "reaction_delay",
    "guard",
    "max_seconds",
    "stop",
    "anchor",
    "attention",
    "search",
}
MAX_SEARCH = 64  # samples of timing search either way
# With a gap under one sample the next ID is misread, and the run would fail only after
# simulating its whole length: refused at load instead.
_GUARD_WHY = (
    ": the next ID's first pulse would fall on the previous code's last sample and be misread"
)


def timing_of(ctx: Ctx, data: dict[str, Any], schedule: str, repair: str = "none") -> Timing:
    """The timing; the concurrent schedule times its own rounds, and a repair needs turns timed
    by the schedule (each makes anchor ``schedule`` the default)."""
    t = sub_table(ctx, data, "timing")
    check_keys(ctx, t, TIMING_KEYS, "timing")
    anchor = _anchor_of(ctx, t, schedule, repair)
    attention = t.get("attention", "confirmed")
    if not isinstance(attention, str) or attention not in ATTENTIONS:
        raise ctx.error(
            "timing", "attention", f"unknown attention {attention!r} ({', '.join(ATTENTIONS)})"
        )
    search = t.get("search", 2)
    if not is_int(search) or not 0 <= search <= MAX_SEARCH:
        raise ctx.error(
            "timing", "search", f"must be an integer 0..{MAX_SEARCH} (samples), got {search!r}"
        )
    timing = Timing(**_values_of(ctx, t), anchor=anchor, attention=attention, search=search)
    _check_window(ctx, t, timing)
    _check_gaps(ctx, t, timing)
    return timing


def _anchor_of(ctx: Ctx, t: dict[str, Any], schedule: str, repair: str = "none") -> str:
    by_schedule = schedule == "concurrent" or repair != "none"
    anchor = t.get("anchor", "schedule" if by_schedule else "spike")
    if repair != "none" and anchor != "schedule":
        raise ctx.error(
            "timing",
            "anchor",
            f"{anchor!r} with [protocol] repair = {repair!r}: a repair block sits at samples "
            'every unit must know whatever it heard, use anchor = "schedule" (the default '
            "with it)",
        )
    if schedule == "concurrent" and anchor != "schedule":
        raise ctx.error(
            "timing",
            "anchor",
            f"{anchor!r} with the concurrent schedule: its rounds are timed by the schedule, "
            'use anchor = "schedule" (the default with it)',
        )
    if not isinstance(anchor, str) or anchor not in ANCHORS:
        raise ctx.error("timing", "anchor", f"unknown anchor {anchor!r} (spike or schedule)")
    return anchor


def _values_of(ctx: Ctx, t: dict[str, Any]) -> dict[str, float]:
    values: dict[str, float] = {}
    for key, v in t.items():  # in file order: the first bad line is the one reported
        if key not in ("anchor", "attention", "search"):
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ctx.error("timing", key, f"must be a finite number, got {v!r}")
            # log times are 64-bit nanoseconds (the window is bounded by reaction_delay)
            if key not in ("sample_rate", "window") and v > MAX_SECONDS:
                raise ctx.error("timing", key, f"must be at most {MAX_SECONDS:g} s, got {v!r}")
            values[key] = float(v)
            if key == "start":
                if v < 0:
                    raise ctx.error("timing", key, f"must not be negative, got {v!r}")
            elif not v > 0:
                why = _GUARD_WHY if key == "guard" else ""
                raise ctx.error("timing", key, f"must be positive, got {v!r}{why}")
    return values


def _blame(t: dict[str, Any], key: str, other: str) -> str:
    # A cross-key rule names a key the file sets: a default is nobody's typo.
    return key if key in t or other not in t else other


def _check_window(ctx: Ctx, t: dict[str, Any], timing: Timing) -> None:
    """A whole number of samples, and no longer than the reaction delay (the lookahead)."""
    samples = timing.window * timing.sample_rate
    if not math.isfinite(samples) or abs(samples - round(samples)) > 1e-9:
        if _blame(t, "window", "sample_rate") == "window":
            raise ctx.error(
                "timing",
                "window",
                f"must be a positive whole number of samples ({timing.window:g} s at "
                f"{timing.sample_rate:g} samples/s is {samples:g})",
            )
        raise ctx.error(
            "timing",
            "sample_rate",
            f"{timing.sample_rate:g} samples/s makes the window {timing.window:g} s (default) "
            f"{samples:g} samples: not a whole number",
        )
    if timing.window > timing.reaction_delay:
        if _blame(t, "window", "reaction_delay") == "window":
            raise ctx.error(
                "timing",
                "window",
                f"{timing.window:g} s exceeds the reaction delay {timing.reaction_delay:g} s "
                "(the lookahead)",
            )
        raise ctx.error(
            "timing",
            "reaction_delay",
            f"{timing.reaction_delay:g} s is shorter than the window {timing.window:g} s "
            "(default; the window is the lookahead and must fit in the reaction delay)",
        )


# The default max_seconds: the schedule's nominal end times SCHEDULE_MARGIN plus SCHEDULE_SLACK
# seconds (spikes later than a code's last pulse, propagation delays), and never under an hour.
SCHEDULE_MARGIN = 1.25
SCHEDULE_SLACK = 60.0
DEFAULT_MAX_SECONDS = 3600.0


def default_max_seconds(needed: float) -> float:
    """The default ``max_seconds`` of a schedule whose last transmission ends at ``needed``
    seconds at the earliest (``Plan.nominal_end``)."""
    return max(DEFAULT_MAX_SECONDS, float(math.ceil(needed * SCHEDULE_MARGIN + SCHEDULE_SLACK)))


def fit_to_schedule(ctx: Ctx, data: dict[str, Any], timing: Timing, needed: float) -> Timing:
    """``max_seconds`` for a schedule that needs ``needed`` seconds (``Plan.nominal_end``): the
    default follows from it; a value the file sets that is shorter is refused here, at load,
    naming what the schedule needs, never a run that fails on it after all its work. A
    deliberate cut short of it is ``stop``."""
    t = sub_table(ctx, data, "timing")
    default = default_max_seconds(needed)
    if "max_seconds" not in t:
        return dataclasses.replace(timing, max_seconds=default)
    if timing.max_seconds < needed:
        raise ctx.error(
            "timing",
            "max_seconds",
            f"{timing.max_seconds:g} s is shorter than the schedule needs: its last "
            f"transmission ends at {needed:.1f} s at the earliest (leave max_seconds out for "
            f"a default that fits, {default:g} s; timing.stop cuts a run short on purpose)",
        )
    return timing


def _check_gaps(ctx: Ctx, t: dict[str, Any], timing: Timing) -> None:
    """A guard of at least one sample; the first transmission before the run's end."""
    if timing.guard < timing.tau - 1e-12:
        raise ctx.error(
            "timing",
            _blame(t, "guard", "sample_rate"),
            f"guard {timing.guard:g} s is shorter than one sample "
            f"(1/sample_rate = {timing.tau:g} s){_GUARD_WHY}",
        )
    if timing.stop is not None and timing.start >= timing.stop:
        raise ctx.error(
            "timing",
            "stop",
            f"stop {timing.stop:g} s is not after start {timing.start:g} s: the run would end "
            "before its first transmission",
        )
    if timing.start >= timing.max_seconds:
        raise ctx.error(
            "timing",
            _blame(t, "start", "max_seconds"),
            f"start {timing.start:g} s is not before max_seconds {timing.max_seconds:g} s: "
            "the run would end before its first transmission",
        )
