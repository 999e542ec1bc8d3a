"""``[channel]``: Gaussian ``noise`` on every sample heard, per-pair ``gain``, the units'
``positions`` with the ``path_loss`` of the distances between them and the ``speed`` pulses
travel at, the links' ``fading``, noise in bursts (``[channel.burst]``) and each unit's clock
(``[channel.clock]`` ``offset`` and ``drift``) (the model: ``rgtbus.signal.channel``)."""

from __future__ import annotations

from typing import Any

from rgtbus.scenario.context import Ctx, check_keys, sub_table
from rgtbus.scenario.model import Timing
from rgtbus.scenario.schedule import ProtocolSection
from rgtbus.scenario.values import MAX_LEVEL, is_finite, pair_of, unit_of
from rgtbus.signal.channel import FADINGS, FREE_SPACE, Burst, Channel, Clock, link_gains

CHANNEL_KEYS = {
    "noise", "gain", "positions", "path_loss", "reference_distance", "burst", "speed", "clock",
    "fading",
}  # fmt: skip
BURST_KEYS = {"noise", "every", "length"}
CLOCK_KEYS = {"offset", "drift"}
MAX_OFFSET = 1.0  # seconds a unit's clock may be off the run's
MAX_PPM = 1000.0  # a unit's clock drift (quartz: tens of ppm)
MAX_SPEED = 1e9  # m/s (light: 3e8)
MAX_SECONDS = 1e6  # a burst's mean length or spacing
MAX_METRES = 1e6  # a coordinate or reference distance (1,000 km: no robot group is wider)
MAX_EXPONENT = 10.0  # path-loss exponents met in practice are 1.6 to 6


def channel_of(ctx: Ctx, data: dict[str, Any], units: tuple[str, ...]) -> Channel:
    """``[channel]``: noise, bursts, link gains, positions and path loss, speed and clocks, each
    checked."""
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
    positions = _positions(ctx, ch, units)
    exponent = _path_loss(ctx, ch, positions)
    reference = ch.get("reference_distance", 1.0)
    if "reference_distance" in ch and not positions:
        raise ctx.error("channel", "reference_distance", "needs [channel.positions]")
    if not is_finite(reference) or not 0 < reference <= MAX_METRES:
        raise ctx.error(
            "channel",
            "reference_distance",
            f"must be a distance in metres > 0 (at most {MAX_METRES:g}), got {reference!r}",
        )
    reference = float(reference)
    return Channel(
        float(noise),
        link_gains(units, gains, positions, exponent, reference),
        positions,
        exponent,
        reference,
        _burst(ctx, ch),
        _speed(ctx, ch, positions),
        _clocks(ctx, ch, units),
        _fading(ctx, ch),
    )


def _fading(ctx: Ctx, ch: dict[str, Any]) -> str:
    """``fading``: "none" (the default) or "rayleigh" (each link faded once a run)."""
    fading = ch.get("fading", "none")
    if not isinstance(fading, str) or fading not in FADINGS:
        raise ctx.error("channel", "fading", f"unknown fading {fading!r} ({', '.join(FADINGS)})")
    return fading


def _speed(ctx: Ctx, ch: dict[str, Any], positions: dict[str, Any]) -> float | None:
    """``speed``: how fast pulses travel, m/s (343 for sound in air); none: instantly."""
    if "speed" not in ch:
        return None
    value = ch["speed"]
    if not positions:
        raise ctx.error(
            "channel", "speed", "needs [channel.positions] (delays come from distances)"
        )
    if not is_finite(value) or not 0 < value <= MAX_SPEED:
        raise ctx.error(
            "channel", "speed", f"must be m/s > 0 (at most {MAX_SPEED:g}), got {value!r}"
        )
    return float(value)


def _clocks(ctx: Ctx, ch: dict[str, Any], units: tuple[str, ...]) -> dict[str, Clock]:
    """``[channel.clock]``: ``offset`` (seconds) and ``drift`` (ppm) tables by unit; a unit
    not named runs on the run's clock."""
    if "clock" not in ch:
        return {}
    table = ch["clock"]
    if not isinstance(table, dict):
        raise ctx.error(
            "channel", "clock", "must be a table {offset = {a = 0.001}, drift = {a = 20}}"
        )
    check_keys(ctx, table, CLOCK_KEYS, "channel.clock")
    values: dict[str, dict[str, float]] = {"offset": {}, "drift": {}}
    for key, bound, what in (("offset", MAX_OFFSET, "seconds"), ("drift", MAX_PPM, "ppm")):
        sub = table.get(key, {})
        if not isinstance(sub, dict):
            raise ctx.error("channel.clock", key, f"must be a table {{a = ...}} of {what}")
        for name, v in sub.items():
            unit = unit_of(ctx, units, name, f"channel.clock.{key}", name)
            if not is_finite(v) or abs(v) > bound:
                raise ctx.error(
                    f"channel.clock.{key}",
                    name,
                    f"must be {what}, finite and at most {bound:g} from 0, got {v!r}",
                )
            values[key][unit] = float(v)
    return {
        u: Clock(values["offset"].get(u, 0.0), values["drift"].get(u, 0.0))
        for u in units
        if u in values["offset"] or u in values["drift"]
    }


def _burst(ctx: Ctx, ch: dict[str, Any]) -> Burst | None:
    """``[channel.burst]``: ``noise`` σ_b > 0 within a burst, and the mean ``every`` (calm
    seconds between bursts) and ``length`` (seconds of a burst), all three; or none."""
    if "burst" not in ch:
        return None
    table = ch["burst"]
    if not isinstance(table, dict):
        raise ctx.error(
            "channel", "burst", "must be a table {noise = 0.2, every = 10, length = 0.1}"
        )
    check_keys(ctx, table, BURST_KEYS, "channel.burst")
    missing = sorted(BURST_KEYS - set(table))
    if missing:
        raise ctx.error("channel.burst", None, f"needs {missing[0]!r} (noise, every and length)")
    noise, every, length = table["noise"], table["every"], table["length"]
    if not is_finite(noise) or not 0 < noise <= MAX_LEVEL:
        raise ctx.error(
            "channel.burst",
            "noise",
            f"must be a standard deviation > 0 and finite (at most {MAX_LEVEL:g}), got {noise!r}",
        )
    for key, value in (("every", every), ("length", length)):
        if not is_finite(value) or not 0 < value <= MAX_SECONDS:
            raise ctx.error(
                "channel.burst",
                key,
                f"must be mean seconds > 0 (at most {MAX_SECONDS:g}), got {value!r}",
            )
    return Burst(float(noise), float(every), float(length))


def _positions(
    ctx: Ctx, ch: dict[str, Any], units: tuple[str, ...]
) -> dict[str, tuple[float, float, float]]:
    """``[channel.positions]``: every unit's ``[x, y]`` or ``[x, y, z]`` in metres (z = 0 if
    not given), or none at all."""
    table = ch.get("positions", {})
    if not isinstance(table, dict):
        raise ctx.error("channel", "positions", "must be a table {a = [x, y], ...} in metres")
    out: dict[str, tuple[float, float, float]] = {}
    for key, xyz in table.items():
        unit = unit_of(ctx, units, key, "channel.positions", key)
        if (
            not isinstance(xyz, list)
            or len(xyz) not in (2, 3)
            or not all(is_finite(v) and abs(v) <= MAX_METRES for v in xyz)
        ):
            raise ctx.error(
                "channel.positions",
                key,
                f"must be [x, y] or [x, y, z] in metres, each finite and at most {MAX_METRES:g} "
                f"from 0, got {xyz!r}",
            )
        x, y, *z = (float(v) for v in xyz)
        out[unit] = (x, y, z[0] if z else 0.0)
    if out:
        missing = [u for u in units if u not in out]
        if missing:
            raise ctx.error(
                "channel",
                "positions",
                f"every unit needs a position, or none: {', '.join(missing)} "
                f"{'has' if len(missing) == 1 else 'have'} none",
            )
    return out


def _path_loss(ctx: Ctx, ch: dict[str, Any], positions: dict[str, Any]) -> float:
    """``path_loss``: ``"free-space"`` (2) or an exponent in [0, 10]; 0 without it."""
    if "path_loss" not in ch:
        return 0.0
    value = ch["path_loss"]
    if not positions:
        raise ctx.error("channel", "path_loss", "needs [channel.positions]")
    if value == "free-space":
        return FREE_SPACE
    if not is_finite(value) or not 0 <= value <= MAX_EXPONENT:
        raise ctx.error(
            "channel",
            "path_loss",
            f'must be "free-space" or an exponent in [0, {MAX_EXPONENT:g}], got {value!r}',
        )
    return float(value)


def check_timed_channel(ctx: Ctx, channel: Channel, protocol: ProtocolSection, timing: Timing
) -> None:
    """A channel whose pulses land off their samples (a speed, clocks) needs turns that follow
    what each unit hears: the serial schedule timed by confirmed attention (each unit times
    every ID it hears by its timing search; docs/protocol.md, "Attention"), without a repair
    (its blocks sit at samples fixed before the run). And clocks may drift apart by at most
    half the reaction delay over the run (the lookahead that keeps every promise ahead of
    what the units hear)."""
    if not channel.timed:
        return
    follows = protocol.schedule == "serial" and protocol.repair == "none"
    if not follows or timing.anchor != "spike" or timing.attention != "confirmed":
        raise ctx.error(
            "channel",
            "speed" if channel.speed is not None else "clock",
            "delays and clocks need turns that follow what each unit hears: the serial "
            'schedule without a repair, timed by confirmed attention (timing.anchor = "spike", '
            'timing.attention = "confirmed"; docs/protocol.md, "Attention")',
        )
    clocks = list(channel.clocks.values()) or [Clock()]
    offsets = [c.offset for c in clocks] + [0.0]
    drifts = [c.drift for c in clocks] + [0.0]
    apart = max(offsets) - min(offsets) + (max(drifts) - min(drifts)) * 1e-6 * timing.max_seconds
    if apart > timing.reaction_delay / 2:
        raise ctx.error(
            "channel.clock",
            "drift" if max(drifts) != min(drifts) else "offset",
            f"the clocks come {apart:.3g} s apart within timing.max_seconds "
            f"({timing.max_seconds:g} s): more than half the reaction delay "
            f"({timing.reaction_delay:g} s), the lookahead",
        )
