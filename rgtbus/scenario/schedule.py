"""``[protocol]``: the schedule (serial or concurrent), the number of influence rounds and the
repair (``repair = "none" | "arq"``, ``repair_rounds``, ``repair_margin``; docs/protocol.md)."""

from __future__ import annotations

import math
from typing import Any, NamedTuple

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


class Protocol(NamedTuple):
    """``[protocol]`` as read: the schedule, the influence rounds and the repair."""

    schedule: str
    influence_rounds: int
    repair: str = "none"
    repair_rounds: int = DEFAULT_REPAIR_ROUNDS
    repair_margin: float = DEFAULT_REPAIR_MARGIN


def protocol_of(ctx: Ctx, data: dict[str, Any]) -> Protocol:
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
    return Protocol(schedule, influence_rounds, repair, rounds, float(margin))
