"""What the logged pulses say: each code on the medium (``Transmission``: a sender's pulses of one
message, with its meaning) and each decode matched with the code it read (``DecodeRow``),
for the replay, the DataFrames and the plots (``Replay.transmissions``, ``Replay.decodes``).
"""

from __future__ import annotations

import bisect
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from rgtbus.telemetry.records import PulseRecord
from rgtbus.timebase import seconds

# Two logged times of one instant agree to within this (a log time is whole nanoseconds).
_NANOSECOND = seconds(1)


@dataclass
class Transmission:
    """One code on the medium: the logged pulses of one message, with what it means."""

    turn: int
    kind: str  # "id" | "payload"
    phase: str  # "relations" | "influences"
    sender: str
    addressee: str
    channel: str
    code: str
    meaning: str  # "ID", "alliance", "conflict", "influence {alpha}", ...
    start: float
    end: float
    pulses: list[tuple[float, float]]  # (t, magnitude)

    @property
    def label(self) -> str:
        """``sender → addressee: meaning``, as a plot labels the code."""
        return f"{self.sender} → {self.addressee}: {self.meaning}"


@dataclass
class DecodeRow:
    """One decode as the log holds it, matched with the transmission it read (``turn``, ``sent``)
    and whether it read what was sent (``matches``)."""

    unit: str
    t: float
    sender: str
    addressee: str
    kind: str
    code: str
    margin: float
    accepted: bool
    turn: int | None  # of the transmission it read (None: no such transmission logged)
    sent: str | None  # the code that transmission carried
    matches: bool | None  # decoded what was sent (None: nothing to compare with)
    channel: str | None = None  # the unit whose channel carried it (None: an older log)


def _phase_of(turn: int, n_units: int) -> str:
    return "relations" if turn < n_units * (n_units - 1) else "influences"


def transmissions_of(pulses: Iterable[PulseRecord], units: Sequence[str]) -> list[Transmission]:
    """The logged pulses (``records.pulse`` rows) grouped into codes, each with what it
    means, in start order: a sender's pulses of one message (and repair block) are one
    code; pulses of one time go on air in the run's unit order."""
    groups: dict[tuple[str, int, int], list[PulseRecord]] = {}
    # in time order, units of one time in the scenario's order: as they go on air
    rank = {u: i for i, u in enumerate(units)}
    ordered = sorted(pulses, key=lambda p: (p["t"], rank.get(p["unit"], len(rank))))
    for p in ordered:
        m = p["message"]
        groups.setdefault((p["unit"], m["id"], m.get("block", 0)), []).append(p)
    out = []
    n = len(units)
    for (_, mid, _), code in groups.items():
        msg = code[0]["message"]
        turn = mid // 2
        phase = _phase_of(turn, n)
        if msg["kind"] == "id":
            meaning = "ID"
        elif msg["kind"] == "request":
            meaning = f"request (repair block {msg['block']})"
        elif phase == "relations":
            meaning = msg["code"]
        else:
            meaning = f"influence {msg['code']}"
        if msg["kind"] == "repeat":
            meaning += f" again (repair block {msg['block']})"
        out.append(
            Transmission(
                turn=turn,
                kind=msg["kind"],
                phase=phase,
                sender=msg["sender"],
                addressee=msg["addressee"],
                channel=code[0]["channel"],
                code=msg["code"],
                meaning=meaning,
                start=code[0]["t"],
                end=code[-1]["t"],
                pulses=[(p["t"], p["magnitude"]) for p in code],
            )
        )
    out.sort(key=lambda x: (x.start, x.turn, x.kind))
    return out


def matched_decodes(
    transmissions: Sequence[Transmission], decodes: Iterable[tuple[int, dict[str, Any]]]
) -> list[DecodeRow]:
    """Each decode (``/rx/decode`` records, in log-time order) matched with the
    transmission it read: the one of its turn, or (a log from before turns) the latest of
    its class its sender started before it."""
    starts: dict[tuple[str, str], list[Transmission]] = defaultdict(list)
    of_turn: dict[tuple[str, str, int], Transmission] = {}
    for sent in transmissions:  # in start order: the latest of a turn wins
        starts[(sent.sender, sent.kind)].append(sent)
        of_turn[(sent.sender, sent.kind, sent.turn)] = sent
    begun = {key: [tx.start for tx in txs] for key, txs in starts.items()}
    rows = []
    for _, d in decodes:
        cls = "id" if d["kind"] == "id" else "payload"
        tx: Transmission | None = None
        if "turn" in d:
            tx = of_turn.get((d["sender"], cls, d["turn"]))
        else:  # logs from before turns: the latest started by the decode
            key = (d["sender"], cls)
            i = bisect.bisect_right(begun.get(key, []), d["t"] + _NANOSECOND)
            tx = starts[key][i - 1] if i else None
        if tx is None:
            matches = None
        elif cls == "id":
            matches = d["code"] == "id"
        else:
            matches = d["code"] == tx.code and d["addressee"] == tx.addressee
        rows.append(
            DecodeRow(
                unit=d["unit"],
                t=d["t"],
                sender=d["sender"],
                addressee=d["addressee"],
                kind=d["kind"],
                code=d["code"],
                margin=d["margin"],
                accepted=d["accepted"],
                turn=None if tx is None else tx.turn,
                sent=None if tx is None else tx.code,
                matches=matches,
                channel=d.get("channel"),
            )
        )
    return rows
