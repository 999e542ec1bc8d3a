"""Scenario files: TOML data -> a validated, typed ``Scenario``.

A scenario names its units, actions, frequencies (or ``"auto"``), codebook, resonator mode,
policies (relationships, influences, decisions), timing, channel noise and seed, and may carry an
``[expect]`` table that ``rgtbus run --check`` verifies. Every refusal names the file, the line
(where it can be found) and the key, and says why.
"""

from __future__ import annotations

import math
import re
import stat
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rgtbus.errors import RgtbusError
from rgtbus.protocol import ANCHORS, MAX_INFLUENCE_ROUNDS, SCHEDULES
from rgtbus.rgt import (
    Universe,
    graph_to_polynomial,
    install_relations,
    parse_polynomial,
    polynomial_to_graph,
)
from rgtbus.rgt.diagonal import EXACT_VARS
from rgtbus.rgt.expr import format_expr, needs_star
from rgtbus.signal.codebook import (
    Codebook,
    alternative_names,
    generate_codebook,
    paper_codebook,
)
from rgtbus.signal.plan import auto_plan, check_plan, make_plan, parse_omega

_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")

TOP_KEYS = {
    "name",
    "description",
    "seed",
    "units",
    "actions",
    "frequencies",
    "codebook",
    "mode",
    "timing",
    "channel",
    "relations",
    "influences",
    "decision",
    "outcome",
    "expect",
    "protocol",
    "goals",
}
PROTOCOL_KEYS = {"schedule", "influence_rounds"}
GOAL_KEYS = {"mode", "outcome"}  # any other key of [goals.UNIT] is a target unit
GOAL_TARGET_KEYS = {"want", "mode"}
GOAL_MODES = ("exact", "contains", "choice")
DYNAMICS = ("fixed point", "cycle", "neither")
TIMING_KEYS = {
    "sample_rate",
    "window",
    "start",
    "reaction_delay",
    "guard",
    "max_seconds",
    "anchor",
}
CHANNEL_KEYS = {"noise", "gain"}
RELATION_KEYS = {"policy", "p", "fixed", "draws"}
DECISION_KEYS = {"policy", "units"}
OUTCOME_KEYS = {"name", "all_of", "choose", "then", "else"}
EXPECT_KEYS = {
    "polynomial",
    "agree",
    "outcome",
    "choices",
    "intervals",
    "frustrated",
    "relations",
    "influences",
    "goals",
    "dynamics",
}
DECISION_POLICIES = ("max", "min", "seeded-random")
RELATION_POLICIES = ("fixed", "random", "cograph")
INFLUENCE_POLICIES = ("fixed", "uniform", "random")
INFLUENCE_KEYS = {"policy", "value", "weights"}  # any other key of [influences] is a pair
MODES = ("paper", "exact")
# Noise, gains and pulse magnitudes above this overflow the resonators' floats mid-run (1e200
# did; 1e3 runs and fails cleanly); pulses are about 0.4, decoding fails from noise ~0.08.
MAX_LEVEL = 1000.0
# Measured: with a gap under one sample every shipped scenario misreads the next ID, and the
# run fails only after simulating its whole length.
_GUARD_WHY = (
    ": the next ID's first pulse would fall on the previous code's last sample and be misread"
)


@dataclass(frozen=True)
class Timing:
    sample_rate: float = 200.0  # samples per second (tau = 5 ms)
    window: float = 0.1  # seconds per bus window; at most the reaction delay (the lookahead)
    start: float = 0.001  # first transmission, seconds after onset (the paper's 1 ms)
    reaction_delay: float = 0.5  # from the ID spike to the addressed code
    guard: float = 0.5  # silence between one transmission's end and the next ID
    max_seconds: float = 3600.0  # a run that has not finished by then fails
    anchor: str = "spike"  # reactions count from the ID spike (paper) or the ID's last pulse

    @property
    def tau(self) -> float:
        return 1.0 / self.sample_rate

    @property
    def window_samples(self) -> int:
        return round(self.window * self.sample_rate)


@dataclass(frozen=True)
class Outcome:
    """``name: then`` when every unit of ``all_of`` chooses ``choose``, else ``name: else``."""

    name: str
    all_of: tuple[str, ...]
    choose: int
    then: str
    otherwise: str


@dataclass(frozen=True)
class Goal:
    """Unit ``unit`` wants subject ``target`` to meet ``[lo, hi]`` in ``mode`` (one of
    ``rgtbus.rgt.control.MODES``; a scenario's ``choice`` is resolved to the mode that is the
    target's choice under its decision policy: ``max`` -> ``largest``, ``min`` ->
    ``smallest``, any other -> ``exact``, the one interval that leaves no choice)."""

    unit: str
    target: str
    lo: int
    hi: int
    mode: str


@dataclass(frozen=True)
class Scenario:
    name: str
    path: str
    text: str
    seed: int
    units: tuple[str, ...]
    universe: Universe
    frequencies: dict[str, float]
    frequency_text: dict[str, str]
    codebook: Codebook
    mode: str
    timing: Timing
    noise: float
    gains: dict[tuple[str, str], float]
    relation_policy: str
    alliance_p: float
    fixed_relations: dict[tuple[str, str], bool]
    draws: dict[tuple[str, str], float]
    influences: dict[tuple[str, str], int]
    decisions: dict[str, str]
    outcome: Outcome | None
    expect: dict[str, Any] = field(default_factory=dict)
    description: str = ""
    # How influences not listed per pair are chosen (rgtbus.mind.choose_influences).
    schedule: str = (
        "serial"  # [protocol] schedule: one code at a time, or rounds (docs/protocol.md)
    )
    influence_policy: str = "fixed"
    influence_value: int | None = None  # policy uniform
    influence_weights: dict[int, float] = field(default_factory=dict)  # policy random
    influence_rounds: int = 1  # [protocol] influence_rounds: influence phases (the paper: 1)
    goals: tuple[Goal, ...] = ()  # [goals.UNIT]: influences chosen by the inverse task

    def goals_of(self, unit: str) -> dict[str, Goal]:
        """Unit ``unit``'s goals by target (empty: it keeps its influence policy)."""
        return {g.target: g for g in self.goals if g.unit == unit}

    def pairs(self) -> list[tuple[str, str]]:
        """Every ordered pair of distinct units, sender-major in unit order."""
        return [(s, r) for s in self.units for r in self.units if s != r]

    def with_seed(self, seed: int) -> Scenario:
        from dataclasses import replace

        return replace(self, seed=seed)


class _Ctx:
    """Where a value came from, for one-line errors: ``file:line: key: reason``."""

    def __init__(self, path: str, text: str) -> None:
        self.path = path
        self.lines = text.splitlines()

    def line_of(self, section: str, key: str | None) -> int | None:
        header = (
            re.compile(r"\s*\[+\s*" + re.escape(section) + r"\s*\]+\s*(#.*)?\Z")
            if section
            else None
        )
        in_section = section == ""
        for i, line in enumerate(self.lines, 1):
            stripped = line.strip()
            if stripped.startswith("["):
                in_section = bool(header and header.match(line))
                if in_section and key is None:
                    return i
                continue
            if in_section and key is not None:
                m = re.match(r'\s*"?([^"=\s]+)"?\s*=', line)
                if m and m.group(1) == key:
                    return i
        if section:
            # An inline table (``codebook = {...}``): the line that opens it.
            parent, _, last = section.rpartition(".")
            found = self.line_of(parent, last)
            if found is not None:
                return found
        if section and key is not None and "." not in section:
            # Dotted keys: fall back to any line naming the key.
            for i, line in enumerate(self.lines, 1):
                if re.match(r'\s*"?' + re.escape(key) + r'"?\s*=', line):
                    return i
        return None

    def error(self, section: str, key: str | None, reason: str) -> RgtbusError:
        line = self.line_of(section, key)
        where = f"{self.path}:{line}" if line else self.path
        name = ".".join(p for p in (section, key) if p)
        return RgtbusError(f"{where}: {name or 'scenario'}: {reason}")


# Far beyond any real scenario (six units are ~2 KB); stops a device or a huge file early.
MAX_SCENARIO_BYTES = 8 * 1024 * 1024


def load_scenario(path: str | Path) -> Scenario:
    p = Path(path)
    where = str(p)
    try:
        mode = p.stat().st_mode
        if stat.S_ISDIR(mode):
            raise RgtbusError(f"cannot read scenario {where!r}: is a directory")
        if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) or stat.S_ISSOCK(mode):
            raise RgtbusError(f"cannot read scenario {where!r}: not a regular file")
        with open(p, "rb") as f:
            data = f.read(MAX_SCENARIO_BYTES + 1)
    except OSError as exc:
        raise RgtbusError(f"cannot read scenario {where!r}: {exc.strerror}") from None
    except ValueError as exc:  # a NUL in the path
        raise RgtbusError(f"cannot read scenario {where!r}: {exc}") from None
    if len(data) > MAX_SCENARIO_BYTES:
        raise RgtbusError(
            f"{where}: larger than {MAX_SCENARIO_BYTES // 2**20} MiB: not a scenario file"
        )
    return parse_scenario(_decode_text(data, where), where)


def _decode_text(data: bytes, where: str) -> str:
    """UTF-8 text, or one line saying where the first bad byte is (a binary file, Latin-1)."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        col = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise RgtbusError(
            f"{where}:{line}: not a UTF-8 text file "
            f"(byte 0x{data[exc.start]:02x} at line {line}, column {col})"
        ) from None
    nul = text.find("\0")
    if nul >= 0:
        line = text.count("\n", 0, nul) + 1
        raise RgtbusError(
            f"{where}:{line}: a binary file, not a scenario (NUL byte on line {line})"
        )
    return text


def parse_scenario(text: str, path: str = "<scenario>") -> Scenario:
    ctx = _Ctx(path, text)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"\(at line (\d+), column \d+\)", str(exc))
        where = f"{path}:{m.group(1)}" if m else path
        raise RgtbusError(f"{where}: not valid TOML: {exc}") from None

    def unknown(table: Mapping[str, Any], allowed: set[str], section: str) -> None:
        for key in table:
            if key not in allowed:
                raise ctx.error(
                    section, key, f"unknown key (allowed: {', '.join(sorted(allowed))})"
                )

    def table(name: str) -> dict[str, Any]:
        value = data.get(name, {})
        if not isinstance(value, dict):
            raise ctx.error("", name, "must be a table")
        return value

    unknown(data, TOP_KEYS, "")
    name = data.get("name")
    if not isinstance(name, str) or not _IDENT.match(name):
        raise ctx.error("", "name", f"need a scenario name (letters, digits, _), got {name!r}")
    seed = data.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise ctx.error("", "seed", f"must be a non-negative integer, got {seed!r}")

    units = data.get("units")
    if not isinstance(units, list) or len(units) < 2:
        raise ctx.error("", "units", "need a list of at least two unit names")
    for u in units:
        if not isinstance(u, str) or not _IDENT.match(u):
            raise ctx.error("", "units", f"bad unit name {u!r}")
    if len(set(units)) != len(units):
        dup = next(u for u in units if units.count(u) > 1)
        raise ctx.error("", "units", f"unit {dup!r} is listed twice")
    units_t = tuple(units)

    def unit(value: str, section: str, key: str) -> str:
        if value not in units_t:
            raise ctx.error(section, key, f"unknown unit {value!r} (units: {', '.join(units_t)})")
        return value

    def pair(key: str, section: str) -> tuple[str, str]:
        parts = key.split(">")
        if len(parts) != 2:
            raise ctx.error(section, key, 'write the pair as SENDER>ADDRESSEE, e.g. "a>b"')
        s, r = (unit(x.strip(), section, key) for x in parts)
        if s == r:
            raise ctx.error(section, key, "a unit does not address itself")
        return s, r

    actions = data.get("actions")
    if not isinstance(actions, list) or not actions or not all(isinstance(a, str) for a in actions):
        raise ctx.error("", "actions", 'need a list of action names, e.g. ["alpha", "beta"]')
    try:
        universe = Universe(tuple(actions))
    except RgtbusError as exc:
        raise ctx.error("", "actions", str(exc)) from None

    def alternative(value: Any, section: str, key: str) -> int:
        return _alternative_of(value, universe, ctx, section, key)

    # The schedule first: the concurrent one is timed by the schedule (its default anchor).
    proto = table("protocol")
    unknown(proto, PROTOCOL_KEYS, "protocol")
    schedule = proto.get("schedule", "serial")
    if schedule not in SCHEDULES:
        raise ctx.error(
            "protocol", "schedule", f"unknown schedule {schedule!r} ({', '.join(SCHEDULES)})"
        )
    influence_rounds = proto.get("influence_rounds", 1)
    if not _int(influence_rounds) or not 1 <= influence_rounds <= MAX_INFLUENCE_ROUNDS:
        raise ctx.error(
            "protocol",
            "influence_rounds",
            f"must be an integer 1..{MAX_INFLUENCE_ROUNDS}, got {influence_rounds!r}",
        )
    t = table("timing")
    unknown(t, TIMING_KEYS, "timing")
    values: dict[str, float] = {}
    anchor = t.get("anchor", "schedule" if schedule == "concurrent" else "spike")
    if schedule == "concurrent" and anchor != "schedule":
        raise ctx.error(
            "timing",
            "anchor",
            f"{anchor!r} with the concurrent schedule: its rounds are timed by the schedule, "
            'use anchor = "schedule" (the default with it)',
        )
    if not isinstance(anchor, str) or anchor not in ANCHORS:
        raise ctx.error("timing", "anchor", f"unknown anchor {anchor!r} (spike or schedule)")
    for key, v in t.items():  # in file order: the first bad line is the one reported
        if key != "anchor":
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ctx.error("timing", key, f"must be a finite number, got {v!r}")
            values[key] = float(v)
            if key == "start":
                if v < 0:
                    raise ctx.error("timing", key, f"must not be negative, got {v!r}")
            elif not v > 0:
                why = _GUARD_WHY if key == "guard" else ""
                raise ctx.error("timing", key, f"must be positive, got {v!r}{why}")
    timing = Timing(**values, anchor=anchor)

    def blame(key: str, other: str) -> str:
        # A cross-key rule names a key the file sets: a default is nobody's typo.
        return key if key in t or other not in t else other

    samples = timing.window * timing.sample_rate
    if not math.isfinite(samples) or abs(samples - round(samples)) > 1e-9:
        if blame("window", "sample_rate") == "window":
            raise ctx.error(
                "timing",
                "window",
                f"must be a positive whole number of samples ({timing.window:g} s at "
                f"{timing.sample_rate:g} samples/s is {samples:g})",
            )
        raise ctx.error(
            "timing",
            "sample_rate",
            f"{timing.sample_rate:g} samples/s makes the window {timing.window:g} s (default) "
            f"{samples:g} samples: not a whole number",
        )
    if timing.window > timing.reaction_delay:
        if blame("window", "reaction_delay") == "window":
            raise ctx.error(
                "timing",
                "window",
                f"{timing.window:g} s exceeds the reaction delay {timing.reaction_delay:g} s "
                "(the lookahead)",
            )
        raise ctx.error(
            "timing",
            "reaction_delay",
            f"{timing.reaction_delay:g} s is shorter than the window {timing.window:g} s "
            "(default; the window is the lookahead and must fit in the reaction delay)",
        )
    if timing.guard < timing.tau - 1e-12:
        raise ctx.error(
            "timing",
            blame("guard", "sample_rate"),
            f"guard {timing.guard:g} s is shorter than one sample "
            f"(1/sample_rate = {timing.tau:g} s){_GUARD_WHY}",
        )
    if timing.start >= timing.max_seconds:
        raise ctx.error(
            "timing",
            blame("start", "max_seconds"),
            f"start {timing.start:g} s is not before max_seconds {timing.max_seconds:g} s: "
            "the run would end before its first transmission",
        )

    mode = data.get("mode", "paper")
    if mode not in MODES:
        raise ctx.error("", "mode", f"unknown resonator mode {mode!r} (modes: {', '.join(MODES)})")
    # No codebook given: the paper's (one or two actions), else the shortest generated one.
    codebook = _codebook(data.get("codebook", _default_codebook(universe)), universe, ctx)

    # Frequencies: a table per unit, or "auto" (a plan by the rules of docs/model.md).
    # With "auto" and neither mode nor codebook given, the plan chooses them too: the pulses a
    # code and the mode that n units on this schedule need (rgtbus plan N prints the same).
    freq = data.get("frequencies", "auto")
    frequencies: dict[str, float] = {}
    frequency_text: dict[str, str] = {}
    if freq == "auto" and "mode" not in data and "codebook" not in data:
        try:
            chosen = make_plan(len(units_t), schedule=schedule, tau=timing.tau, crosstalk=False)
            if chosen.pulses < codebook.pulses:  # the actions need longer words than the plan
                chosen = make_plan(
                    len(units_t),
                    schedule=schedule,
                    tau=timing.tau,
                    crosstalk=False,
                    pulses=codebook.pulses,
                )
        except RgtbusError as exc:
            raise ctx.error("", "frequencies", str(exc)) from None
        mode = chosen.mode
        if chosen.pulses != codebook.pulses:
            codebook = _codebook({"kind": "generated", "pulses": chosen.pulses}, universe, ctx)
    if freq == "auto":
        try:
            plan = auto_plan(
                len(units_t),
                pulses=codebook.pulses,
                mode=mode,
                tau=timing.tau,
                schedule=schedule,
            )
        except RgtbusError as exc:
            raise ctx.error("", "frequencies", str(exc)) from None
        for u, w in zip(units_t, plan, strict=True):
            frequencies[u] = float(w)
            frequency_text[u] = f"{float(w):.6g}"
    elif isinstance(freq, dict):
        for key, value in freq.items():
            unit(key, "frequencies", key)
            try:
                frequencies[key] = parse_omega(value, "frequency")
            except RgtbusError as exc:
                raise ctx.error("frequencies", key, str(exc)) from None
            frequency_text[key] = str(value)
        missing = [u for u in units_t if u not in frequencies]
        if missing:
            raise ctx.error("frequencies", None, f"no frequency for unit {missing[0]!r}")
        seen: dict[float, str] = {}
        for u in units_t:
            w = frequencies[u]
            if w in seen:
                raise ctx.error(
                    "frequencies", u, f"frequency clash: {u} and {seen[w]} share {w:.6g} rad/s"
                )
            seen[w] = u
        try:
            check_plan(
                [frequencies[u] for u in units_t],
                pulses=codebook.pulses,
                mode=mode,
                tau=timing.tau,
                schedule=schedule,
            )
        except RgtbusError as exc:
            raise ctx.error("frequencies", None, str(exc)) from None
    else:
        raise ctx.error("", "frequencies", 'must be a table {unit = "3pi/2", ...} or "auto"')

    # Timing: every key on its own first (blamed by its own name), then how they fit together.
    # Channel
    ch = table("channel")
    unknown(ch, CHANNEL_KEYS, "channel")
    noise = ch.get("noise", 0.0)
    if not _finite(noise) or not 0 <= noise <= MAX_LEVEL:
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
        if not _finite(g) or not 0 < g <= MAX_LEVEL:
            raise ctx.error(
                "channel.gain",
                key,
                f"gain must be a finite number > 0 (at most {MAX_LEVEL:g}), got {g!r}",
            )
        gains[pair(key, "channel.gain")] = float(g)

    # Relationship policy
    rel = table("relations")
    unknown(rel, RELATION_KEYS, "relations")
    policy = rel.get("policy", "random")
    if policy not in RELATION_POLICIES:
        raise ctx.error(
            "relations", "policy", f"unknown policy {policy!r} (fixed, random or cograph)"
        )
    if policy == "cograph":
        for key in ("fixed", "draws", "p"):
            if key in rel:
                raise ctx.error(
                    "relations",
                    key,
                    "not with policy cograph (the seed draws the whole decomposable group)",
                )
    p = rel.get("p", 0.61)
    if isinstance(p, bool) or not isinstance(p, int | float) or not 0 <= p <= 1:
        raise ctx.error("relations", "p", f"alliance probability must be within [0, 1], got {p!r}")
    fixed: dict[tuple[str, str], bool] = {}
    fixed_table = rel.get("fixed", {})
    if not isinstance(fixed_table, dict):
        raise ctx.error("relations", "fixed", 'must be a table {"a>b" = "alliance", ...}')
    for key, v in fixed_table.items():
        if v not in ("alliance", "conflict"):
            raise ctx.error("relations.fixed", key, f'must be "alliance" or "conflict", got {v!r}')
        fixed[pair(key, "relations.fixed")] = v == "alliance"
    draws: dict[tuple[str, str], float] = {}
    draw_table = rel.get("draws", {})
    if not isinstance(draw_table, dict):
        raise ctx.error("relations", "draws", 'must be a table {"a>b" = 0.42, ...}')
    for key, v in draw_table.items():
        if not _finite(v) or not 0 <= v <= 1:
            raise ctx.error("relations.draws", key, f"a draw must be within [0, 1], got {v!r}")
        draws[pair(key, "relations.draws")] = float(v)
    if policy == "fixed":
        missing = [f"{s}>{r}" for s, r in _pairs(units_t) if (s, r) not in fixed]
        if missing:
            raise ctx.error("relations.fixed", None, f"policy fixed: no relation for {missing[0]}")
        # Fixed relations decide the group before any run: a P4 would only fail at phase 2.
        try:
            graph_to_polynomial(install_relations(units_t, fixed))
        except RgtbusError as exc:
            raise ctx.error("relations.fixed", None, f"policy fixed: {exc}") from None

    # Influences: per ordered pair ("a>b" keys), and by policy for the pairs not listed:
    # fixed (every pair listed), uniform (one value), random (seeded, over weights).
    inf = table("influences")
    for key in inf:  # a typo of a policy key would otherwise be blamed on another key
        if key not in INFLUENCE_KEYS and ">" not in key:
            raise ctx.error(
                "influences",
                key,
                f'unknown key (allowed: {", ".join(sorted(INFLUENCE_KEYS))}, or a pair "a>b")',
            )
    inf_policy = inf.get("policy", "fixed")
    if inf_policy not in INFLUENCE_POLICIES:
        raise ctx.error(
            "influences",
            "policy",
            f"unknown policy {inf_policy!r} ({', '.join(INFLUENCE_POLICIES)})",
        )
    inf_value = None
    if "value" in inf:
        if inf_policy != "uniform":
            raise ctx.error("influences", "value", "only with policy uniform")
        inf_value = alternative(inf["value"], "influences", "value")
    elif inf_policy == "uniform":
        raise ctx.error("influences", "policy", 'uniform needs a value, e.g. value = "1"')
    inf_weights: dict[int, float] = {}
    if "weights" in inf:
        if inf_policy != "random":
            raise ctx.error("influences", "weights", "only with policy random")
        w_table = inf["weights"]
        if not isinstance(w_table, dict) or not w_table:
            raise ctx.error("influences", "weights", 'must be a table {"1" = 2, "0" = 1, ...}')
        named: dict[int, str] = {}
        for key, w in w_table.items():
            if not _finite(w) or not 0 <= w <= 1e9:
                raise ctx.error(
                    "influences.weights", key, f"weight must be within [0, 1e9], got {w!r}"
                )
            alt = alternative(key, "influences.weights", key)
            if alt in named:
                raise ctx.error(
                    "influences.weights", key, f"names the same alternative as {named[alt]!r}"
                )
            named[alt] = key
            inf_weights[alt] = float(w)
        if not any(inf_weights.values()):
            raise ctx.error("influences", "weights", "at least one weight must be > 0")
    influences: dict[tuple[str, str], int] = {}
    for key, v in inf.items():
        if key in INFLUENCE_KEYS:
            continue
        influences[pair(key, "influences")] = alternative(v, "influences", key)
    missing = [f"{s}>{r}" for s, r in _pairs(units_t) if (s, r) not in influences]
    if missing and inf_policy == "fixed":
        raise ctx.error(
            "influences",
            None,
            f"no influence for {missing[0]} (list every pair, or use policy uniform or random)",
        )

    # Decision policies
    dec = table("decision")
    unknown(dec, DECISION_KEYS, "decision")
    default_policy = dec.get("policy", "max")
    per_unit = dec.get("units", {})
    if not isinstance(per_unit, dict):
        raise ctx.error("decision", "units", "must be a table {unit = policy}")
    decisions: dict[str, str] = {}

    def decision_policy(v: Any, section: str, key: str) -> str:
        if v in DECISION_POLICIES:
            return v
        if isinstance(v, str):
            try:
                universe.parse_alternative(v)
                return v
            except RgtbusError:
                pass
        raise ctx.error(
            section,
            key,
            f"unknown decision policy {v!r} (max, min, seeded-random, or a preferred alternative)",
        )

    default_policy = decision_policy(default_policy, "decision", "policy")
    for u in units_t:
        decisions[u] = default_policy
    for key, v in per_unit.items():
        decisions[unit(key, "decision.units", key)] = decision_policy(v, "decision.units", key)

    # Outcome
    outcome = None
    if "outcome" in data:
        o = table("outcome")
        unknown(o, OUTCOME_KEYS, "outcome")
        for key in ("name", "all_of", "choose", "then", "else"):
            if key not in o:
                raise ctx.error("outcome", key, "missing")
        all_of = o["all_of"]
        if not isinstance(all_of, list) or not all_of:
            raise ctx.error("outcome", "all_of", "need a list of units")
        for key in ("name", "then", "else"):
            if not isinstance(o[key], str):
                raise ctx.error("outcome", key, f"must be a string, got {o[key]!r}")
        outcome = Outcome(
            name=o["name"],
            all_of=tuple(unit(u, "outcome", "all_of") for u in all_of),
            choose=alternative(o["choose"], "outcome", "choose"),
            then=o["then"],
            otherwise=o["else"],
        )

    goals = _goals(table("goals"), units_t, universe, decisions, outcome, ctx)
    expect = _expect(table("expect"), units_t, universe, outcome, ctx)
    for who in expect.get("goals", {}):
        if not any(g.unit == who for g in goals):
            raise ctx.error("expect.goals", who, f"unit {who!r} has no [goals.{who}] table")

    description = data.get("description", "")
    if not isinstance(description, str):
        raise ctx.error("", "description", "must be a string")

    return Scenario(
        name=name,
        path=path,
        text=text,
        seed=seed,
        units=units_t,
        universe=universe,
        frequencies=frequencies,
        frequency_text=frequency_text,
        codebook=codebook,
        mode=mode,
        timing=timing,
        noise=float(noise),
        gains=gains,
        relation_policy=policy,
        alliance_p=float(p),
        fixed_relations=fixed,
        draws=draws,
        influences=influences,
        decisions=decisions,
        outcome=outcome,
        expect=expect,
        description=description,
        schedule=schedule,
        influence_policy=inf_policy,
        influence_value=inf_value,
        influence_weights=inf_weights,
        influence_rounds=influence_rounds,
        goals=goals,
    )


def _goals(
    goals: dict[str, Any],
    units: tuple[str, ...],
    universe: Universe,
    decisions: dict[str, str],
    outcome: Outcome | None,
    ctx: _Ctx,
) -> tuple[Goal, ...]:
    """``[goals.UNIT]``: target = alternative or "[LOW,HIGH]" (or an inline table with
    ``want`` and ``mode``), ``mode`` for the table's targets (exact, the default; contains;
    choice), ``outcome`` = the ``then`` of the scenario's [outcome]: every unit of its
    ``all_of`` is a target that must choose its alternative (mode choice unless given)."""
    out: list[Goal] = []
    if goals and len(units) > EXACT_VARS:
        first = next(iter(goals))
        raise ctx.error(
            f"goals.{first}",
            None,
            f"goals need the inverse task, solved on F's truth table: groups of at most "
            f"{EXACT_VARS} units (this one has {len(units)})",
        )
    for name, spec in goals.items():
        section = f"goals.{name}"
        if name not in units:
            raise ctx.error(section, None, f"unknown unit {name!r} (units: {', '.join(units)})")
        if not isinstance(spec, dict):
            raise ctx.error("goals", name, 'must be a table [goals.UNIT] with target = "1", ...')
        mode = spec.get("mode", "exact")
        if mode not in GOAL_MODES:
            raise ctx.error(section, "mode", f"unknown mode {mode!r} ({', '.join(GOAL_MODES)})")
        wanted: dict[str, tuple[int, int, str]] = {}
        if "outcome" in spec:
            said = spec["outcome"]
            if outcome is None:
                raise ctx.error(section, "outcome", "the scenario has no [outcome] rule")
            if said not in (outcome.then, f"{outcome.name}: {outcome.then}"):
                raise ctx.error(
                    section,
                    "outcome",
                    f"{said!r}: a goal names the outcome's then ({outcome.then!r}); "
                    "its else is not a choice each target can make",
                )
            for target in outcome.all_of:
                if target != name:
                    v = outcome.choose
                    wanted[target] = (v, v, spec.get("mode", "choice"))
        for key, value in spec.items():
            if key in GOAL_KEYS:
                continue
            if key not in units:
                allowed = ", ".join(sorted(GOAL_KEYS))
                raise ctx.error(section, key, f"unknown unit {key!r} (a target unit, or {allowed})")
            if key == name:
                raise ctx.error(section, key, "a unit does not influence itself")
            target_mode = mode
            if isinstance(value, dict):
                for k in value:
                    if k not in GOAL_TARGET_KEYS:
                        raise ctx.error(section, key, f"unknown key {k!r} (want, mode)")
                if "want" not in value:
                    raise ctx.error(section, key, 'an inline goal needs want = "..."')
                target_mode = value.get("mode", mode)
                if target_mode not in GOAL_MODES:
                    raise ctx.error(
                        section, key, f"unknown mode {target_mode!r} ({', '.join(GOAL_MODES)})"
                    )
                value = value["want"]
            if isinstance(value, str) and value.strip().startswith("["):
                lo, hi = _interval_of(value, universe, ctx, section, key)
            else:
                lo = hi = _alternative_of(value, universe, ctx, section, key)
            wanted[key] = (lo, hi, target_mode)
        if not wanted:
            raise ctx.error(section, None, "names no target")
        for target, (lo, hi, m) in wanted.items():
            if m == "choice":
                if lo != hi:
                    raise ctx.error(
                        section, target, "mode choice wants one alternative, not an interval"
                    )
                policy = decisions[target]
                m = {"max": "largest", "min": "smallest"}.get(policy, "exact")
            out.append(Goal(name, target, lo, hi, m))
    return tuple(out)


def _interval_of(
    text: str, universe: Universe, ctx: _Ctx, section: str, key: str
) -> tuple[int, int]:
    """An interval as a scenario writes it, "[LOW,HIGH]", non-empty (LOW within HIGH)."""
    try:
        lo, hi = universe.parse_interval(text)
    except RgtbusError as exc:
        raise ctx.error(section, key, str(exc)) from None
    if lo & ~hi:
        raise ctx.error(
            section, key, f"empty interval {text!r}: its low end is not within its high end"
        )
    return lo, hi


def _alternative_of(value: Any, universe: Universe, ctx: _Ctx, section: str, key: str) -> int:
    """An alternative as a scenario writes it: "1", "{alpha}", a list of actions, 0 or 1."""
    if isinstance(value, list) and not all(isinstance(x, str) for x in value):
        raise ctx.error(section, key, f"bad alternative {value!r}: a list of action names")
    try:
        if isinstance(value, list):
            return universe.from_list(value)
        if isinstance(value, int) and not isinstance(value, bool) and value in (0, 1):
            return universe.full if value else 0
        if isinstance(value, str):
            return universe.parse_alternative(value)
    except RgtbusError as exc:
        raise ctx.error(section, key, str(exc)) from None
    raise ctx.error(section, key, f"bad alternative {value!r}")


def _expect(
    expect: dict[str, Any],
    units: tuple[str, ...],
    universe: Universe,
    outcome: Outcome | None,
    ctx: _Ctx,
) -> dict[str, Any]:
    """``[expect]`` checked at load, so ``--check`` never meets a value it cannot compare.

    The polynomial and the relation pairs are stored as a run prints them (``b-a`` -> ``a-b``,
    ``cb+a`` -> ``a+bc``): the same group written another way must not fail the check."""
    for key in expect:
        if key not in EXPECT_KEYS:
            allowed = ", ".join(sorted(EXPECT_KEYS))
            raise ctx.error("expect", key, f"unknown key (allowed: {allowed})")
    out = dict(expect)

    def sub_table(key: str, what: str) -> dict[str, Any]:
        sub = expect.get(key, {})
        if not isinstance(sub, dict):
            raise ctx.error("expect", key, f"must be a table {{{what}}}")
        return sub

    def known_unit(name: str, section: str, key: str | None = None) -> None:
        if name not in units:
            key = name if key is None else key
            raise ctx.error(section, key, f"unknown unit {name!r} (units: {', '.join(units)})")

    if "agree" in expect and not isinstance(expect["agree"], bool):
        raise ctx.error("expect", "agree", f"must be true or false, got {expect['agree']!r}")
    if "polynomial" in expect:
        text = expect["polynomial"]
        if not isinstance(text, str):
            raise ctx.error("expect", "polynomial", f'must be a string like "ab+c", got {text!r}')
        try:
            poly = parse_polynomial(text)
            graph = polynomial_to_graph(poly, units)
        except RgtbusError as exc:
            raise ctx.error("expect", "polynomial", f"{exc} (units: {', '.join(units)})") from None
        out["polynomial"] = format_expr(graph_to_polynomial(graph), needs_star(units))
    if "outcome" in expect:
        text = expect["outcome"]
        if not isinstance(text, str):
            raise ctx.error("expect", "outcome", f"must be a string, got {text!r}")
        if outcome is None:
            raise ctx.error("expect", "outcome", "the scenario has no [outcome] rule to expect")
        possible = [f"{outcome.name}: {v}" for v in (outcome.then, outcome.otherwise)]
        if text not in possible:
            raise ctx.error(
                "expect",
                "outcome",
                f"{text!r} is not an outcome of the [outcome] rule "
                f"({' or '.join(repr(p) for p in possible)})",
            )
    relations = sub_table("relations", '"a-b" = "alliance"')
    pairs: dict[str, str] = {}
    for key, v in relations.items():
        section = "expect.relations"
        parts = key.split("-")
        if len(parts) != 2:
            raise ctx.error(section, key, 'write the pair as UNIT-UNIT, e.g. "a-b"')
        a, b = (x.strip() for x in parts)
        known_unit(a, section, key)
        known_unit(b, section, key)
        if a == b:
            raise ctx.error(section, key, "a unit has no relation with itself")
        if v not in ("alliance", "conflict"):
            raise ctx.error(section, key, f'must be "alliance" or "conflict", got {v!r}')
        if units.index(a) > units.index(b):
            a, b = b, a
        name = f"{a}-{b}"
        if name in pairs:
            raise ctx.error(section, key, f"the pair {name} is given twice")
        pairs[name] = v
    if "relations" in expect:
        out["relations"] = pairs
    for key, what in (("intervals", '"[LOW,HIGH]"'), ("choices", "an alternative")):
        for name, v in sub_table(key, "unit = value").items():
            known_unit(name, f"expect.{key}")
            if not isinstance(v, str):
                raise ctx.error(f"expect.{key}", name, f"must be a string ({what}), got {v!r}")
            if key == "intervals":
                _interval_of(v, universe, ctx, "expect.intervals", name)
            else:
                _alternative_of(v, universe, ctx, "expect.choices", name)
    for key in ("frustrated", "goals"):
        for name, v in sub_table(key, "unit = true").items():
            known_unit(name, f"expect.{key}")
            if not isinstance(v, bool):
                raise ctx.error(f"expect.{key}", name, f"must be true or false, got {v!r}")
    sent: dict[str, list[str]] = {}
    for key, v in sub_table("influences", '"a>b" = "1"').items():
        parts = [x.strip() for x in key.split(">")]
        if len(parts) != 2:
            raise ctx.error("expect.influences", key, 'write the pair as SENDER>ADDRESSEE, "a>b"')
        for x in parts:
            known_unit(x, "expect.influences", key)
        if parts[0] == parts[1]:
            raise ctx.error("expect.influences", key, "a unit does not address itself")
        value = _alternative_of(v, universe, ctx, "expect.influences", key)
        sent[f"{parts[0]}>{parts[1]}"] = universe.to_list(value)
    if "influences" in expect:
        out["influences"] = sent
    if "dynamics" in expect and expect["dynamics"] not in DYNAMICS:
        raise ctx.error(
            "expect",
            "dynamics",
            f"{expect['dynamics']!r} is not one of {', '.join(repr(d) for d in DYNAMICS)}",
        )
    return out


def _int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _finite(v: Any) -> bool:
    """A real, finite number (TOML allows inf and nan; bool is an int in Python)."""
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _pairs(units: tuple[str, ...]) -> list[tuple[str, str]]:
    return [(s, r) for s in units for r in units if s != r]


CODEBOOK_KINDS = ("paper", "generated", "custom")
MAX_PULSES = 64  # a code's length grows with N; far beyond any plan's need (the paper's N = 3)


def _default_codebook(universe: Universe) -> Any:
    """The paper's codebook covers one or two actions; for more, the generated codebook of the
    fewest pulses whose words keep their distance (3 actions: 4 pulses). Searched up to six
    actions (64 alternatives, under a second); beyond, the paper's refusal asks for one."""
    if len(universe.actions) <= 2 or len(universe.actions) > 6:
        return "paper"
    for pulses in range(3, MAX_PULSES + 1):
        try:
            generate_codebook(universe.actions, pulses=pulses)
        except RgtbusError:
            continue
        return {"kind": "generated", "pulses": pulses}
    return "generated"  # refused by _codebook, with the generator's reason


def _codebook(spec: Any, universe: Universe, ctx: _Ctx) -> Codebook:
    """``"paper"``, ``"generated"``, or a table with ``kind`` and that kind's options."""
    if isinstance(spec, str):
        kind, opts = spec, {}
    elif isinstance(spec, dict):
        opts = dict(spec)
        kind = opts.pop("kind", "custom")
    else:
        raise ctx.error("", "codebook", 'must be "paper", "generated" or a table')
    section = "codebook" if isinstance(spec, dict) else ""
    key = None if isinstance(spec, dict) else "codebook"
    # Options are checked first and blamed by name; the builders' own refusals name the table.
    if kind == "paper":
        extra = set(opts) - {"names"}
        names = opts.get("names")
        if names is not None and (
            not isinstance(names, dict) or not all(isinstance(v, str) for v in names.values())
        ):
            raise ctx.error(
                "codebook", "names", f'must be a table {{"1" = "0", ...}}, got {names!r}'
            )
    elif kind == "generated":
        extra = set(opts) - {"pulses", "min_distance", "seed"}
        pulses = opts.get("pulses", 3)
        if not _int(pulses) or not 1 <= pulses <= MAX_PULSES:
            raise ctx.error(
                "codebook", "pulses", f"must be an integer 1..{MAX_PULSES}, got {pulses!r}"
            )
        min_distance = opts.get("min_distance", 0.3)
        if not _finite(min_distance) or min_distance < 0:
            raise ctx.error(
                "codebook", "min_distance", f"must be a number >= 0, got {min_distance!r}"
            )
        seed = opts.get("seed", 0)
        if not _int(seed) or seed < 0:
            raise ctx.error("codebook", "seed", f"must be an integer >= 0, got {seed!r}")
    else:
        extra = set()
    if extra:
        raise ctx.error("codebook", sorted(extra)[0], f"unknown key for the {kind} codebook")
    try:
        if kind == "paper":
            cb = paper_codebook(universe.actions, names=names)
        elif kind == "generated":
            cb = generate_codebook(
                universe.actions, pulses=pulses, min_distance=min_distance, seed=seed
            )
        elif kind == "custom":
            cb = Codebook.from_dict(opts, where="codebook")
        else:
            raise RgtbusError(f"unknown codebook kind {kind!r} ({', '.join(CODEBOOK_KINDS)})")
    except RgtbusError as exc:
        raise ctx.error(section, key, str(exc)) from None
    words = [cb.id_word, *cb.relations.values(), *cb.alternatives.values()]
    if any(abs(v) > MAX_LEVEL for w in words for v in w):
        raise ctx.error(section, key, f"a pulse magnitude beyond {MAX_LEVEL:g}")
    missing = [n for n in alternative_names(universe.actions) if n not in cb.alternatives]
    if missing:
        raise ctx.error(section, key, f"no word for alternative {missing[0]}")
    missing = [n for n in ("alliance", "conflict") if n not in cb.relations]
    if missing:
        raise ctx.error(section, key, f"no word for relationship {missing[0]}")
    return cb
