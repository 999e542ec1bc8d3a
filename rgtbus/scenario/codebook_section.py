"""The resonator ``mode`` and the ``codebook``: ``"paper"``, ``"generated"`` or a table with
``kind`` and that kind's options (no codebook given: the paper's for one or two actions, else
the shortest generated one)."""

from __future__ import annotations

from typing import Any

from rgtbus.errors import BadInput, RgtbusError
from rgtbus.rgt import Universe
from rgtbus.scenario.context import Ctx
from rgtbus.scenario.limits import CODEBOOK_SEARCH, codebook_search, over_budget
from rgtbus.scenario.schedule import ProtocolSection
from rgtbus.scenario.values import MAX_LEVEL, is_finite, is_int
from rgtbus.signal.codebook import (
    Codebook,
    alternative_names,
    generate_codebook,
    paper_codebook,
)
from rgtbus.signal.rules import RULES

MODES = ("paper", "exact")
CODEBOOK_KINDS = ("paper", "generated", "custom")
MAX_PULSES = 64  # a code's length grows with N; far beyond any plan's need (the paper's N = 3)


def decoding_of(ctx: Ctx, data: dict[str, Any]) -> str:
    """``decoding``: the rule a code's word is read by (``rgtbus.signal.rules``): nearest
    (default: the paper's) or matched-filter."""
    rule = data.get("decoding", "nearest")
    if not isinstance(rule, str) or rule not in RULES:
        raise ctx.error("", "decoding", f"unknown decoding rule {rule!r} ({', '.join(RULES)})")
    return rule


def check_decoding(ctx: Ctx, decoding: str, protocol: ProtocolSection) -> None:
    """The matched filter reads the serial schedule's codes only: under the concurrent one
    every channel carries a code at once, and a rule that weighs words by direction alone
    takes crosstalk for codes (35 to 49 misreads on a clean 7-unit group; docs/model.md)."""
    if decoding != "nearest" and protocol.schedule == "concurrent":
        raise ctx.error(
            "",
            "decoding",
            f"{decoding!r} reads the serial schedule only (under the concurrent one every "
            "channel carries a code at once and it takes crosstalk for codes): use "
            'decoding = "nearest" or protocol.schedule = "serial"',
        )


def mode_of(ctx: Ctx, data: dict[str, Any]) -> str:
    """``mode``: the resonator mode, paper (default) or exact."""
    mode = data.get("mode", "paper")
    if not isinstance(mode, str) or mode not in MODES:
        raise ctx.error("", "mode", f"unknown resonator mode {mode!r} (modes: {', '.join(MODES)})")
    return mode


def default_codebook(universe: Universe) -> str | dict[str, Any]:
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
    return "generated"  # refused by codebook_of, with the generator's reason


def codebook_of(ctx: Ctx, spec: Any, universe: Universe) -> Codebook:
    """``"paper"``, ``"generated"``, or a table with ``kind`` and that kind's options."""
    opts: dict[str, Any]
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
    options = _options_of(ctx, kind, opts)
    if kind == "generated":  # its search is counted before it starts (docs: "Budgets")
        k = len(universe.actions)
        why = over_budget(CODEBOOK_SEARCH, codebook_search(k, options["pulses"]))
        if why:
            raise ctx.error(
                section, key, f"generated for {k} actions at N = {options['pulses']}: {why}"
            )
    try:
        cb = _build(kind, opts, options, universe)
    except RgtbusError as exc:
        raise ctx.error(section, key, str(exc)) from None
    _check_words(ctx, cb, universe, section, key)
    return cb


def _options_of(ctx: Ctx, kind: Any, opts: dict[str, Any]) -> dict[str, Any]:
    """The builder's keyword arguments for ``kind``, each checked; no key the kind lacks."""
    options: dict[str, Any] = {}
    extra: set[str] = set()
    if kind == "paper":
        extra = set(opts) - {"names"}
        names = opts.get("names")
        if names is not None and (
            not isinstance(names, dict) or not all(isinstance(v, str) for v in names.values())
        ):
            raise ctx.error(
                "codebook", "names", f'must be a table {{"1" = "0", ...}}, got {names!r}'
            )
        options = {"names": names}
    elif kind == "generated":
        extra = set(opts) - {"pulses", "min_distance", "seed"}
        pulses = opts.get("pulses", 3)
        if not is_int(pulses) or not 1 <= pulses <= MAX_PULSES:
            raise ctx.error(
                "codebook", "pulses", f"must be an integer 1..{MAX_PULSES}, got {pulses!r}"
            )
        min_distance = opts.get("min_distance", 0.3)
        if not is_finite(min_distance) or min_distance < 0:
            raise ctx.error(
                "codebook", "min_distance", f"must be a number >= 0, got {min_distance!r}"
            )
        seed = opts.get("seed", 0)
        if not is_int(seed) or seed < 0:
            raise ctx.error("codebook", "seed", f"must be an integer >= 0, got {seed!r}")
        options = {"pulses": pulses, "min_distance": min_distance, "seed": seed}
    if extra:
        raise ctx.error("codebook", sorted(extra)[0], f"unknown key for the {kind} codebook")
    return options


def _build(
    kind: Any, opts: dict[str, Any], options: dict[str, Any], universe: Universe
) -> Codebook:
    if kind == "paper":
        return paper_codebook(universe.actions, **options)
    if kind == "generated":
        return generate_codebook(universe.actions, **options)
    if kind == "custom":
        return Codebook.from_dict(opts, where="codebook")
    raise BadInput(f"unknown codebook kind {kind!r} ({', '.join(CODEBOOK_KINDS)})")


def _check_words(ctx: Ctx, cb: Codebook, universe: Universe, section: str, key: str | None) -> None:
    """Pulses the resonators can take, a word for every alternative and relationship."""
    words = [cb.id_word, *cb.relations.values(), *cb.alternatives.values()]
    if any(abs(v) > MAX_LEVEL for w in words for v in w):
        raise ctx.error(section, key, f"a pulse magnitude beyond {MAX_LEVEL:g}")
    missing = [n for n in alternative_names(universe.actions) if n not in cb.alternatives]
    if missing:
        raise ctx.error(section, key, f"no word for alternative {missing[0]}")
    missing = [n for n in ("alliance", "conflict") if n not in cb.relations]
    if missing:
        raise ctx.error(section, key, f"no word for relationship {missing[0]}")
