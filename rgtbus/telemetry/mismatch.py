"""One disagreement between a log and what reading it again, or re-running its units, gives
(``Mismatch``): what the replay, the verifier and the CSV export report."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any


@dataclass
class Mismatch:
    """One disagreement between the log and what verification recomputed."""

    topic: str
    t: float | None
    unit: str | None
    field: str
    logged: Any
    recomputed: Any

    def text(self) -> str:
        """The disagreement in one line: topic, time, unit, field, both values (long values cut
        short)."""
        when = "" if self.t is None else f" t={self.t:.3f}s"
        who = "" if self.unit is None else f" unit={self.unit}"
        return (
            f"{self.topic}{when}{who} {self.field}: logged {_short(self.logged)}, "
            f"recomputed {_short(self.recomputed)}"
        )


def _short(value: Any, limit: int = 120) -> str:
    text = json.dumps(value, ensure_ascii=False, default=str)
    return text if len(text) <= limit else text[: limit - 1] + "…"
