"""Ordered pairs of units and their text key ``"s>r"`` (sender s, receiver r): the one place
that builds and reads them. Pure."""

from __future__ import annotations

import functools
from collections.abc import Sequence

Pair = tuple[str, str]


def ordered_pairs(units: Sequence[str]) -> list[Pair]:
    """Every ordered pair ``(s, r)`` of distinct units, senders in the given order."""
    return [(s, r) for s in units for r in units if s != r]


@functools.lru_cache(maxsize=1 << 17)
def pair_key(sender: str, receiver: str) -> str:
    """``"s>r"``: how records, summaries and scenario files name an ordered pair. One string
    a pair, shared: every unit's tables name every pair (n³ strings at n units otherwise)."""
    return f"{sender}>{receiver}"


@functools.lru_cache(maxsize=1 << 17)
def relation_key(a: str, b: str) -> str:
    """``"a-b"``: how tables name the relationship of an unordered pair (a before b in the
    group's order). One string a pair, shared, as ``pair_key``."""
    return f"{a}-{b}"


def parse_pair_key(key: str) -> Pair:
    """``"s>r"`` -> ``(s, r)`` (split at the first ``>``: unit names never hold one)."""
    s, _, r = key.partition(">")
    return s, r
