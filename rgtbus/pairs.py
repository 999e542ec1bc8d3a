"""Ordered pairs of units and their text key ``"s>r"`` (sender s, receiver r): the one place
that builds and reads them. Pure."""

from __future__ import annotations

from collections.abc import Sequence

Pair = tuple[str, str]


def ordered_pairs(units: Sequence[str]) -> list[Pair]:
    """Every ordered pair ``(s, r)`` of distinct units, senders in the given order."""
    return [(s, r) for s in units for r in units if s != r]


def pair_key(sender: str, receiver: str) -> str:
    """``"s>r"``: how records, summaries and scenario files name an ordered pair."""
    return f"{sender}>{receiver}"


def parse_pair_key(key: str) -> Pair:
    """``"s>r"`` -> ``(s, r)`` (split at the first ``>``: unit names never hold one)."""
    s, _, r = key.partition(">")
    return s, r
