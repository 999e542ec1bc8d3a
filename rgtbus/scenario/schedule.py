"""``[protocol]``: the schedule (serial or concurrent), the number of influence rounds and the
repair (``repair = "none" | "arq"``, ``repair_rounds``, ``repair_margin``; docs/protocol.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from rgtbus.protocol import MAX_INFLUENCE_ROUNDS, SCHEDULES
from rgtbus.scenario.context import Ctx, check_keys, sub_table
from rgtbus.scenario.values import is_int

PROTOCOL_KEYS = {"schedule", "influence_rounds", "repair", "repair_rounds", "repair_margin"}
REPAIRS = ("none", "arq")
MAX_REPAIR_ROUNDS = 20
DEFAULT_REPAIR_ROUNDS = 3
# A decode is unsure below this fraction of its family's smallest word distance (the margin
# of a read exactly on a word is that distance; half-way between two words it is 0).
DEFAULT_REPAIR_MARGIN = 0.65


@dataclass(frozen=True)
class ProtocolSection:
    """``[protocol]`` as read (``Scenario.protocol``): the schedule (serial: one code at a
    time; concurrent: rounds, docs/protocol.md), the influence phases (the paper: 1) and the
    repair: "none" (the paper) or "arq" (docs/protocol.md, "Repair"), its blocks after each
    phase and the margin (a fraction of a family's smallest word distance) below which a
    decode is unsure. Named for its section: not ``typing.Protocol``, not ``rgtbus.protocol``
    (the protocol itself)."""

    schedule: str = "serial"
    influence_rounds: int = 1
    repair: str = "none"
    repair_rounds: int = DEFAULT_REPAIR_ROUNDS
    repair_margin: float = DEFAULT_REPAIR_MARGIN

    @property
    def repairs_per_phase(self) -> int:
        """Repair blocks after each phase (0: no repair)."""
        return self.repair_rounds if self.repair == "arq" else 0


def protocol_of(ctx: Ctx, data: dict[str, Any]) -> ProtocolSection:
    """``[protocol]``: schedule, influence rounds and repair, each checked."""
    proto = sub_table(ctx, data, "protocol")
    check_keys(ctx, proto, PROTOCOL_KEYS, "protocol")
    schedule = proto.get("schedule", "serial")
    if schedule not in SCHEDULES:
        raise ctx.error(
            "protocol", "schedule", f"unknown schedule {schedule!r} ({', '.join(SCHEDULES)})"
        )
    influence_rounds = proto.get("influence_rounds", 1)
    if not is_int(influence_rounds) or not 1 <= influence_rounds <= MAX_INFLUENCE_ROUNDS:
        raise ctx.error(
            "protocol",
            "influence_rounds",
            f"must be an integer 1..{MAX_INFLUENCE_ROUNDS}, got {influence_rounds!r}",
        )
    repair = proto.get("repair", "none")
    if not isinstance(repair, str) or repair not in REPAIRS:
        raise ctx.error("protocol", "repair", f"unknown repair {repair!r} ({', '.join(REPAIRS)})")
    rounds = proto.get("repair_rounds", DEFAULT_REPAIR_ROUNDS)
    if not is_int(rounds) or not 1 <= rounds <= MAX_REPAIR_ROUNDS:
        raise ctx.error(
            "protocol",
            "repair_rounds",
            f"must be an integer 1..{MAX_REPAIR_ROUNDS}, got {rounds!r}",
        )
    margin = proto.get("repair_margin", DEFAULT_REPAIR_MARGIN)
    if (
        isinstance(margin, bool)
        or not isinstance(margin, int | float)
        or not math.isfinite(margin)
        or not 0 <= margin <= 2
    ):
        raise ctx.error(
            "protocol",
            "repair_margin",
            f"must be a number 0..2 (a fraction of the smallest word distance), got {margin!r}",
        )
    return ProtocolSection(schedule, influence_rounds, repair, rounds, float(margin))
