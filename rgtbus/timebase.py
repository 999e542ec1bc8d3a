"""The one time base: simulated seconds in the core, integer nanoseconds at the MCAP boundary
(``log_time``), converted here and nowhere else. Pure."""

from __future__ import annotations

NS_PER_SECOND = 1_000_000_000


def ns(seconds: float) -> int:
    """Simulated seconds -> integer nanoseconds (the MCAP ``log_time``)."""
    return round(seconds * 1e9)


def seconds(t_ns: int) -> float:
    """Integer nanoseconds (an MCAP ``log_time``) -> seconds."""
    return t_ns / NS_PER_SECOND
