"""Steering a running group (docs/foxglove.md, "Steer a live run"): what a client may change,
checked against the scenario; where a change takes effect; what the summary's truth must know
of the changes that were made. Pure: no SimPy, bus, log or Foxglove.

**Parameters** (named by their scenario keys; a value set applies at the next window boundary
of simulated time, ``boundary``):

    channel.noise        σ of every receiver's white noise, 0..MAX_LEVEL
    channel.gains.a>b    the gain of link a→b at b, > 0 (also spelt channel.gain.a>b)
    channel.clock.drift.U
                         unit U's clock drift, ppm (a run whose units keep clocks of their
                         own: [channel.clock] or a speed), its clock running on continuous
    repair.budget        the repair blocks after each phase in which units still ask, 0..K
                         (a run with repair = "arq" only)
    pace                 simulated seconds a wall second (a paced run's; never a result)

**Services**: ``pause``, ``resume``, ``step`` (``by``: window, turn or round: the run goes on to
the next such boundary and pauses there), ``relation`` (unit U holds pair a>b as ``alliance``
or ``conflict`` from now on: its later decisions use that group), ``influence`` (SRC's
influence on DST is VALUE in the next round SRC has not sent yet), ``mark`` (the log records
every unit's state there).

A change is applied, or refused with one line of why, at sample ``S`` =
``boundary(computed, window)``: the first window boundary at or after everything the run has
computed; both are logged there. A re-run applies the logged changes at the same samples.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from rgtbus.errors import RgtbusError
from rgtbus.pairs import Pair, pair_key, parse_pair_key
from rgtbus.scenario import Scenario
from rgtbus.scenario.channel import MAX_PPM
from rgtbus.scenario.values import MAX_LEVEL

NOISE = "channel.noise"
GAIN_PREFIX = "channel.gains."
GAIN_ALIAS = "channel.gain."  # the scenario file's own table, [channel] gain
DRIFT_PREFIX = "channel.clock.drift."  # a unit's clock drift, ppm
BUDGET = "repair.budget"
PACE = "pace"
MAX_PACE = 1000.0  # simulated seconds a wall second

SERVICES = ("pause", "resume", "step", "relation", "influence", "mark")
STEPS = ("window", "turn", "round")
RELATIONS = ("alliance", "conflict")
MAX_LABEL = 200  # characters of a mark's label


MAX_WHY = 500  # characters of a refusal's line (it may quote what a client sent)


class Refused(RgtbusError):
    """A change that cannot be made: its one line says why, at most ``MAX_WHY`` characters
    (a client's huge value is quoted only in part)."""

    def __init__(self, why: str) -> None:
        super().__init__(why if len(why) <= MAX_WHY else why[: MAX_WHY - 1] + "…")


@dataclass(frozen=True)
class Setting:
    """A parameter value, checked: ``name`` as advertised, ``kind`` (noise, gain, budget,
    pace), the link for a gain, the value."""

    name: str
    kind: str
    value: float | int
    link: Pair | None = None  # a gain's link; a drift's unit, as (unit, unit)


@dataclass(frozen=True)
class Call:
    """A service call, checked: its service and what it names."""

    service: str
    unit: str | None = None  # relation: the unit that holds it; influence: its source
    peer: str | None = None  # influence: its destination
    pair: Pair | None = None  # relation: the pair
    alliance: bool | None = None
    value: int | None = None  # influence: the alternative, as a mask
    by: str | None = None  # step: window, turn or round
    label: str = ""  # mark


@dataclass(frozen=True)
class Request:
    """What a client asked of a run: a ``parameter`` set to ``value``, or a ``service`` called
    with ``value`` (its JSON object), by ``who``; ``refused``: why it may not be made, known
    before it reached the run (a client not allowed to steer); ``logged``: the record of it
    in a log being re-run."""

    kind: str  # "parameter" | "service"
    name: str
    value: Any
    who: str
    refused: str | None = None
    logged: Mapping[str, Any] | None = None
    # placed by the process that steers a run across processes: its sample and order
    at: int | None = None
    seq: int | None = None

    def refuse(self, why: str) -> Request:
        """The same request, refused for ``why``."""
        return replace(self, refused=why)

    def placed(self, at: int, seq: int) -> Request:
        """The same request, due at sample ``at`` as change ``seq`` of the run."""
        return replace(self, at=at, seq=seq)


def boundary(sample: int, window: int) -> int:
    """The first window boundary at or after ``sample`` (a multiple of ``window`` samples)."""
    return -(-sample // window) * window


def parameter_names(sc: Scenario) -> list[str]:
    """Every parameter a run of ``sc`` advertises: noise, a gain for every ordered pair, the
    repair budget (with repair), the pace."""
    names = [NOISE, *(GAIN_PREFIX + pair_key(a, b) for a, b in sc.pairs())]
    if sc.channel.timed:
        names += [DRIFT_PREFIX + u for u in sc.units]
    if sc.protocol.repairs_per_phase:
        names.append(BUDGET)
    return [*names, PACE]


def _number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise Refused(f"{name}: {value!r} is not a finite number")
    return float(value)


def _unit(sc: Scenario, name: Any, what: str) -> str:
    if not isinstance(name, str) or name not in sc.units:
        raise Refused(f"{what}: unknown unit {name!r} (the units: {', '.join(sc.units)})")
    return name


def _pair(sc: Scenario, text: Any, what: str) -> Pair:
    if not isinstance(text, str) or ">" not in text:
        raise Refused(f"{what}: {text!r} is not a pair SRC>DST")
    a, b = parse_pair_key(text)
    _unit(sc, a, what)
    _unit(sc, b, what)
    if a == b:
        raise Refused(f"{what}: {text!r} is not a pair of two units")
    return a, b


def check_setting(sc: Scenario, name: str, value: Any) -> Setting:
    """A parameter set to ``value``, checked against ``sc`` (``Refused``: why not)."""
    if name == NOISE:
        v = _number(name, value)
        if not 0 <= v <= MAX_LEVEL:
            raise Refused(f"{name}: {value!r} is not a standard deviation in 0..{MAX_LEVEL:g}")
        return Setting(name, "noise", v)
    if name.startswith((GAIN_PREFIX, GAIN_ALIAS)):
        key = (
            name.removeprefix(GAIN_PREFIX)
            if name.startswith(GAIN_PREFIX)
            else name[len(GAIN_ALIAS) :]
        )
        link = _pair(sc, key, name)
        v = _number(name, value)
        if not 0 < v <= MAX_LEVEL:
            raise Refused(f"{name}: {value!r} is not a gain in (0, {MAX_LEVEL:g}]")
        return Setting(GAIN_PREFIX + pair_key(*link), "gain", v, link)
    if name.startswith(DRIFT_PREFIX):
        unit = _unit(sc, name[len(DRIFT_PREFIX) :], name)
        if not sc.channel.timed:
            raise Refused(
                f"{name}: this run's units share one clock (no [channel.clock] or speed): "
                "there is no clock to drift"
            )
        v = _number(name, value)
        if not abs(v) <= MAX_PPM:
            raise Refused(f"{name}: {value!r} is not a drift in ppm within ±{MAX_PPM:g}")
        return Setting(DRIFT_PREFIX + unit, "drift", v, (unit, unit))
    if name == BUDGET:
        k = sc.protocol.repairs_per_phase
        if not k:
            raise Refused(f'{name}: this run has no repair ([protocol] repair = "none")')
        if isinstance(value, bool) or not isinstance(value, int | float) or value != int(value):
            raise Refused(f"{name}: {value!r} is not a whole number of repair blocks")
        if not 0 <= value <= k:
            raise Refused(f"{name}: {value!r} is not in 0..{k} (the run's repair_rounds)")
        return Setting(name, "budget", int(value))
    if name == PACE:
        v = _number(name, value)
        if not 0 < v <= MAX_PACE:
            raise Refused(
                f"{name}: {value!r} is not a pace in (0, {MAX_PACE:g}] simulated s a wall s"
            )
        return Setting(name, "pace", v)
    raise Refused(
        f"unknown parameter {name!r} (channel.noise, channel.gains.a>b, "
        "channel.clock.drift.U, repair.budget, pace)"
    )


def _args(service: str, args: Any, allowed: Iterable[str]) -> Mapping[str, Any]:
    if args is None:
        args = {}
    if not isinstance(args, Mapping):
        raise Refused(f"{service}: the request is not a JSON object")
    extra = sorted(set(args) - set(allowed))
    if extra:
        raise Refused(
            f"{service}: unknown key {extra[0]!r} (allowed: {', '.join(allowed) or 'none'})"
        )
    return args


def check_call(sc: Scenario, service: str, args: Any) -> Call:
    """A service call with its arguments (a JSON object), checked against ``sc``."""
    if service in ("pause", "resume"):
        _args(service, args, ())
        return Call(service)
    if service == "step":
        a = _args(service, args, ("by",))
        by = a.get("by", "window")
        if by not in STEPS:
            raise Refused(f"step: by {by!r} is not one of {', '.join(STEPS)}")
        return Call(service, by=by)
    if service == "relation":
        a = _args(service, args, ("unit", "pair", "relation"))
        unit = _unit(sc, a.get("unit"), "relation: unit")
        pair = _pair(sc, a.get("pair"), "relation: pair")
        relation = a.get("relation")
        if relation not in RELATIONS:
            raise Refused(f"relation: {relation!r} is not alliance or conflict")
        return Call(service, unit=unit, pair=pair, alliance=relation == "alliance")
    if service == "influence":
        a = _args(service, args, ("influence",))
        text = a.get("influence")
        if not isinstance(text, str) or "=" not in text:
            raise Refused(f"influence: {text!r} is not SRC>DST=VALUE")
        key, _, value_text = text.partition("=")
        src, dst = _pair(sc, key.strip(), "influence")
        try:
            value = sc.universe.parse_alternative(value_text)
        except RgtbusError as exc:
            raise Refused(
                f"influence: {value_text.strip()!r} is not an alternative ({exc})"
            ) from None
        return Call(service, unit=src, peer=dst, value=value)
    if service == "auth":  # a client proved it may steer (``rgtbus.telemetry.control``)
        _args(service, args, ())
        return Call(service)
    if service == "mark":
        a = _args(service, args, ("label",))
        label = a.get("label", "")
        if not isinstance(label, str) or len(label) > MAX_LABEL:
            raise Refused(f"mark: the label must be text of at most {MAX_LABEL} characters")
        return Call(service, label=label)
    raise Refused(f"unknown service {service!r} (one of {', '.join(SERVICES)})")


def step_target(by: str, at: int, window: int, starts: Mapping[str, Iterable[int]]) -> int | None:
    """Where a step taken at sample ``at`` pauses: the next window boundary, or the boundary
    at or after the next turn's or round's first sample after ``at`` (``starts``: the clean
    schedule's, by ``turn`` and ``round``); None: no such turn or round is left (the run
    goes on to its end)."""
    if by == "window":
        return boundary(at + 1, window)
    later = [s for s in starts[by] if s > at]
    return boundary(min(later), window) if later else None


@dataclass
class Steered:
    """What the changes made to a run mean for its truth (``rgtbus.truth``): the influences
    injected, by schedule turn, and each relation a unit was made to hold, from the round it
    decided next."""

    injected: dict[int, int] = field(default_factory=dict)  # turn -> the alternative sent
    # (unit, pair, alliance?, first round decided with it)
    relations: list[tuple[str, Pair, bool, int]] = field(default_factory=list)

    def __bool__(self) -> bool:
        return bool(self.injected or self.relations)

    def held_by(self, unit: str, rnd: int) -> dict[Pair, bool]:
        """The relations ``unit`` was made to hold by the time it decided round ``rnd``."""
        return {p: a for u, p, a, r in self.relations if u == unit and r <= rnd}


def steered_in(reports: Iterable[Mapping[str, Any]]) -> Steered | None:
    """The ``Steered`` of a run from its units' reports (each steered unit's ``steered``:
    the influences injected into its sends, the relations it was made to hold); None: the
    run was not steered (no report says it was)."""
    out: Steered | None = None
    for r in reports:
        mine = r.get("steered")
        if mine is None:
            continue
        out = out or Steered()
        for turn, value in mine["injected"]:
            out.injected[int(turn)] = int(value)
        for s, rcv, alliance, rnd in mine["held"]:
            out.relations.append((r["unit"], (s, rcv), bool(alliance), int(rnd)))
    return out
