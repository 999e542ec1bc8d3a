"""``[channel]``: Gaussian ``noise`` on every sample heard, and per-pair ``gain`` (the model:
``rgtbus.signal.channel``)."""

from __future__ import annotations

from typing import Any

from rgtbus.scenario.context import Ctx, check_keys, sub_table
from rgtbus.scenario.values import MAX_LEVEL, is_finite, pair_of
from rgtbus.signal.channel import Channel

CHANNEL_KEYS = {"noise", "gain"}


def channel_of(ctx: Ctx, data: dict[str, Any], units: tuple[str, ...]) -> Channel:
    ch = sub_table(ctx, data, "channel")
    check_keys(ctx, ch, CHANNEL_KEYS, "channel")
    noise = ch.get("noise", 0.0)
    if not is_finite(noise) or not 0 <= noise <= MAX_LEVEL:
        raise ctx.error(
            "channel",
            "noise",
            f"must be a standard deviation >= 0 and finite (at most {MAX_LEVEL:g}), got {noise!r}",
        )
    gains: dict[tuple[str, str], float] = {}
    gain_table = ch.get("gain", {})
    if not isinstance(gain_table, dict):
        raise ctx.error("channel", "gain", 'must be a table {"a>b" = 0.9, ...}')
    for key, g in gain_table.items():
        if not is_finite(g) or not 0 < g <= MAX_LEVEL:
            raise ctx.error(
                "channel.gain",
                key,
                f"gain must be a finite number > 0 (at most {MAX_LEVEL:g}), got {g!r}",
            )
        gains[pair_of(ctx, units, key, "channel.gain")] = float(g)
    return Channel(float(noise), gains)
