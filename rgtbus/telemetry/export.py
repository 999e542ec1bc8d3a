"""Exporting a run's log: the CSV tables of ``rgtbus replay --csv`` and the one rule for
time ranges (``in_span``) every timeline and table shares."""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from typing import IO, Any

from rgtbus.telemetry.read import Replay, in_span
from rgtbus.timebase import sample_of, time_of


def sample_time(t: float, tau: float | None) -> float:
    """A time on the sample grid, without float noise: 162.04500000000002 -> 162.045."""
    if not tau:
        return round(t, 9)
    digits = min(9, max(0, math.ceil(-math.log10(tau)) + 1))
    return round(time_of(sample_of(t, tau), tau), digits)


Table = tuple[list[str], list[list[Any]]]  # (header, rows)
Span = tuple[float | None, float | None] | None  # (from, to); None: the whole run

RUN_COLUMNS = ["run_id", "scenario", "seed"]  # every table's first columns


def csv_tables(replay: Replay, span: Span = None) -> dict[str, Table]:
    """``{file name: (header, rows)}``: transmissions, decodes, decisions, spikes. Every row
    starts with the run's id, scenario and seed (tables of many runs concatenate); times are
    on the sample grid; ``span`` (from, to) keeps what happens in it (a transmission: any of
    its pulses)."""
    tau = replay.scenario.timing.tau if replay.scenario is not None else None
    info = replay.info()
    run = [info["run_id"], info["scenario"], info["seed"]]

    def ts(t: float) -> float:
        return sample_time(t, tau)

    return {
        "transmissions.csv": _transmissions(replay, span, run, ts),
        "decodes.csv": _decodes(replay, span, run, ts),
        "decisions.csv": _decisions(replay, span, run, ts),
        "spikes.csv": _spikes(replay, span, run, ts),
    }


def _transmissions(
    replay: Replay, span: Span, run: list[Any], ts: Callable[[float], float]
) -> Table:
    head = [*RUN_COLUMNS, "turn", "phase", "kind", "sender", "addressee", "channel", "code",
            "meaning", "start", "end", "pulses"]  # fmt: skip
    rows = [
        [
            *run,
            x.turn,
            x.phase,
            x.kind,
            x.sender,
            x.addressee,
            x.channel,
            x.code,
            x.meaning,
            ts(x.start),
            ts(x.end),
            len(x.pulses),
        ]
        for x in replay.transmissions
        if in_span(x.start, span, until=x.end)
    ]
    return head, rows


def _decodes(replay: Replay, span: Span, run: list[Any], ts: Callable[[float], float]) -> Table:
    head = [*RUN_COLUMNS, "t", "unit", "sender", "addressee", "channel", "kind", "code", "margin",
            "accepted", "turn", "sent", "matches"]  # fmt: skip
    rows = [
        [
            *run,
            ts(d.t),
            d.unit,
            d.sender,
            d.addressee,
            d.channel,
            d.kind,
            d.code,
            d.margin,
            d.accepted,
            d.turn,
            d.sent,
            d.matches,
        ]
        for d in replay.decodes
        if in_span(d.t, span)
    ]
    return head, rows


def _decisions(replay: Replay, span: Span, run: list[Any], ts: Callable[[float], float]) -> Table:
    u = replay.scenario.universe if replay.scenario is not None else None

    def alt(v: Any) -> str:  # the text form (1, 0, {alpha}); empty when there is none
        if v is None:
            return ""
        return u.format(u.from_list(v)) if u is not None else "{" + ",".join(v) + "}"

    head = [*RUN_COLUMNS, "t", "unit", "subject", "A", "B", "low", "high", "frustrated",
            "choice", "canonical"]  # fmt: skip
    rows = [
        [
            *run,
            ts(d["t"]),
            d["unit"],
            d["subject"],
            alt(d["A"]),
            alt(d["B"]),
            alt(d["interval"][0]) if d["interval"] else "",
            alt(d["interval"][1]) if d["interval"] else "",
            d["frustrated"],
            alt(d["choice"]),
            d["canonical"],
        ]
        for d in replay.decisions
        if in_span(d["t"], span)
    ]
    return head, rows


def _spikes(replay: Replay, span: Span, run: list[Any], ts: Callable[[float], float]) -> Table:
    head = [*RUN_COLUMNS, "t", "unit", "channel", "omega", "sample"]
    rows = [
        [*run, ts(s["t"]), s["unit"], s["channel"], s["omega"], s["sample"]]
        for s in replay.spikes.rows(replay.spikes.within(span))
    ]
    return head, rows


def write_csv(header: list[str], rows: list[list[Any]], stream: IO[str]) -> None:
    """One table as CSV (booleans as true/false, None as empty)."""
    w = csv.writer(stream, lineterminator="\n")
    w.writerow(header)
    for row in rows:
        w.writerow(
            [
                "" if v is None else ("true" if v is True else "false" if v is False else v)
                for v in row
            ]
        )
