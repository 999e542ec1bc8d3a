"""``[protocol]``: the schedule (serial or concurrent) and the number of influence rounds."""

from __future__ import annotations

from typing import Any, NamedTuple

from rgtbus.protocol import MAX_INFLUENCE_ROUNDS, SCHEDULES
from rgtbus.scenario.context import Ctx, check_keys, sub_table
from rgtbus.scenario.values import is_int

PROTOCOL_KEYS = {"schedule", "influence_rounds"}


class Protocol(NamedTuple):
    schedule: str
    influence_rounds: int


def protocol_of(ctx: Ctx, data: dict[str, Any]) -> Protocol:
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
    return Protocol(schedule, influence_rounds)
