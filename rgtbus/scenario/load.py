"""Loading a scenario: from a file, from TOML text or by a shipped scenario's name; then every
section in turn (the first refusal is the one reported, so the order is part of the format)."""

from __future__ import annotations

import errno
import os
import re
import tomllib
from pathlib import Path
from typing import Any

from rgtbus.errors import BadInput, IOFailure, RgtbusError
from rgtbus.protocol.timetable import plan_of
from rgtbus.scenario.channel import channel_of, check_timed_channel
from rgtbus.scenario.codebook_section import (
    check_decoding,
    codebook_of,
    decoding_of,
    default_codebook,
    mode_of,
)
from rgtbus.scenario.context import Ctx, check_keys, sub_table
from rgtbus.scenario.decisions import decisions_of
from rgtbus.scenario.expect import check_expected_dynamics, check_expected_goals, expect_of
from rgtbus.scenario.frequencies import frequencies_of
from rgtbus.scenario.goals import goals_of
from rgtbus.scenario.group import description_of, group_of
from rgtbus.scenario.influences import influences_of
from rgtbus.scenario.limits import check_size, key_depth_error, nesting_error, read_regular
from rgtbus.scenario.model import Scenario
from rgtbus.scenario.outcome import outcome_of
from rgtbus.scenario.relations import relations_of
from rgtbus.scenario.schedule import protocol_of
from rgtbus.scenario.shipped import find_shipped, is_name
from rgtbus.scenario.timing import fit_to_schedule, timing_of

TOP_KEYS = {
    "name",
    "description",
    "seed",
    "units",
    "actions",
    "frequencies",
    "codebook",
    "mode",
    "decoding",
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
# Far beyond any real scenario; stops a device or a huge file early.
MAX_SCENARIO_BYTES = 8 * 1024 * 1024
TEXT = "<text>"  # the file name errors give for a scenario loaded from text


def load_scenario(source: str | os.PathLike[str]) -> Scenario:
    """A scenario from ``source``: the path of a file; TOML text (a string with a newline;
    errors name ``<text>``); or, when no such file exists, the name of a shipped scenario
    (``gate``, ``gate.toml``; ``rgtbus scenarios`` lists them)."""
    if isinstance(source, str) and "\n" in source:
        return parse_scenario(source, TEXT)
    p = Path(source)
    if not os.path.exists(p):  # False for a path with a NUL: refused below, as it reads
        found = find_shipped(str(p))
        if found is not None and found.parent.name == "sweeps":
            raise BadInput(
                f"cannot read scenario {str(p)!r}: {found} is a sweep file, not a scenario "
                "(rgtbus sweep runs it)"
            )
        p = p if found is None else found
    where = str(p)
    return parse_scenario(_decode_text(_read_file(p, where), where), where)


def _read_file(p: Path, where: str) -> bytes:
    """The file's bytes, at most one past the limit; one line if it is not a readable regular
    file (a directory, FIFO, device or socket is refused before a byte is read)."""
    try:
        data = read_regular(p, "scenario", MAX_SCENARIO_BYTES)
    except OSError as exc:
        hint = ""
        if exc.errno == errno.ENOENT and is_name(where):
            hint = ", nor the name of a shipped scenario (rgtbus scenarios lists them)"
        raise IOFailure(f"cannot read scenario {where!r}: {exc.strerror}{hint}") from None
    except RgtbusError:  # already one line (a directory, a FIFO, a device)
        raise
    except ValueError as exc:  # a NUL in the path
        raise BadInput(f"cannot read scenario {where!r}: {exc}") from None
    if len(data) > MAX_SCENARIO_BYTES:
        raise BadInput(
            f"{where}: larger than {MAX_SCENARIO_BYTES // 2**20} MiB: not a scenario file"
        )
    return data


def _decode_text(data: bytes, where: str) -> str:
    """UTF-8 text, or one line saying where the first bad byte is (a binary file, Latin-1)."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        col = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise BadInput(
            f"{where}:{line}: not a UTF-8 text file "
            f"(byte 0x{data[exc.start]:02x} at line {line}, column {col})"
        ) from None
    nul = text.find("\0")
    if nul >= 0:
        line = text.count("\n", 0, nul) + 1
        raise BadInput(
            f"{where}:{line}: a binary file, not a scenario (NUL byte on line {line})"
        )
    return text


def _toml_of(text: str, path: str) -> dict[str, Any]:
    too_deep = nesting_error(text, path)  # before tomllib, which recurses
    if too_deep:
        raise BadInput(too_deep)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"\(at line (\d+), column \d+\)", str(exc))
        where = f"{path}:{m.group(1)}" if m else path
        raise BadInput(f"{where}: not valid TOML: {exc}") from None
    too_deep = key_depth_error(data, text, path)
    if too_deep:
        raise BadInput(too_deep)
    return data


def parse_scenario(text: str, path: str = "<scenario>") -> Scenario:
    """A scenario from its TOML ``text``; errors name ``path``, the line and the key."""
    ctx = Ctx(path, text)
    data = _toml_of(text, path)
    check_keys(ctx, data, TOP_KEYS, "")
    group = group_of(ctx, data)
    units, universe = group.units, group.universe
    # The schedule first: the concurrent one is timed by the schedule (its default anchor).
    protocol = protocol_of(ctx, data)
    timing = timing_of(ctx, data, protocol.schedule, protocol.repair)
    # How big the run would be, before anything is built (the codebook's search: codebook_of):
    # at least what a medium every receiver hears alike costs, then (the channel's link gains
    # are n² entries: only once that fits) what its own medium costs, far more where its
    # receivers hear it differently.
    check_size(ctx, data, len(units), protocol.influence_rounds, timing)
    channel = channel_of(ctx, data, units)
    if not channel.alike:
        check_size(ctx, data, len(units), protocol.influence_rounds, timing, alike=False)
    mode = mode_of(ctx, data)
    decoding = decoding_of(ctx, data)
    # No codebook given: the paper's (one or two actions), else the shortest generated one.
    codebook = codebook_of(ctx, data.get("codebook", default_codebook(universe)), universe)
    freq = frequencies_of(ctx, data, units, universe, mode, codebook, timing.tau, protocol.schedule)
    plan = plan_of(
        tuple(units), tuple((u, float(freq.frequencies[u])) for u in units), timing.tau,
        freq.codebook.pulses, timing.reaction_delay, timing.guard, timing.search,
        protocol.schedule, timing.start, protocol.influence_rounds,
        protocol.repair_rounds if protocol.repair == "arq" else 0, 1 if channel.timed else 0,
    )  # fmt: skip
    # the run's plan (``ProtocolState`` asks for the same one, cached): what the schedule needs
    timing = fit_to_schedule(ctx, data, timing, plan.nominal_end())
    check_timed_channel(ctx, channel, protocol, timing)
    check_decoding(ctx, decoding, protocol)
    relations = relations_of(ctx, data, units)
    influences = influences_of(ctx, data, units, universe)
    decisions = decisions_of(ctx, data, units, universe)
    outcome = outcome_of(ctx, data, units, universe)
    goals = goals_of(ctx, sub_table(ctx, data, "goals"), units, universe, decisions, outcome)
    expect = expect_of(ctx, sub_table(ctx, data, "expect"), units, universe, outcome, group.seed)
    check_expected_goals(ctx, expect, goals)
    check_expected_dynamics(ctx, expect, protocol.influence_rounds)
    return Scenario(
        name=group.name,
        path=path,
        text=text,
        seed=group.seed,
        units=units,
        universe=universe,
        frequencies=freq.frequencies,
        frequency_text=freq.text,
        codebook=freq.codebook,
        mode=freq.mode,
        decoding=decoding,
        timing=timing,
        channel=channel,
        relations=relations,
        influences=influences,
        decisions=decisions,
        outcome=outcome,
        protocol=protocol,
        expect=expect,
        description=description_of(ctx, data),
        goals=goals,
    )
