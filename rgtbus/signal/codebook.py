"""Codebooks as data (docs/model.md, docs/errata.md): which pulse magnitudes mean what.

A codebook has N pulses a word and three families, each decoded on its own:

- ``id``: the ID-code, sent on the sender's own frequency (paper: {.4, .4, .4});
- ``relation``: ``alliance`` {.4, .4, .4} and ``conflict`` {−.4, −.4, −.4}, sent on another
  unit's frequency (alliance and the ID-code are the same pulses: the channel tells them apart);
- ``alternative``: one word per alternative of the Boolean algebra, named by its text form
  (``1``, ``0``, ``{alpha}``, ``{alpha,beta}``; paper k = 2: ``1`` {.2,.3,.7}, ``0`` {.7,.3,.2},
  ``{alpha}`` {.5,.2,.5}, ``{beta}`` {.3,.6,.3}).

Validation refuses wrong word lengths, non-finite values, duplicate words within a family and
words closer than ``min_distance`` (Euclidean) within a family.  The ID-code must also stand
apart from every alternative, so that an ID is accepted only when it decodes as the ID-code.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rgtbus.errors import BadInput

Word = tuple[float, ...]


@dataclass(frozen=True)
class Codebook:
    """N-pulse words by family; see the module docstring.  Build with :func:`paper_codebook`,
    :func:`generate_codebook` or :meth:`from_dict`; construction validates."""

    pulses: int
    id_word: Word
    relations: Mapping[str, Word]
    alternatives: Mapping[str, Word]
    min_distance: float = 0.2
    name: str = "custom"
    actions: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        validate(self)

    @property
    def families(self) -> dict[str, dict[str, Word]]:
        """The three families by name (``id``, ``relation``, ``alternative``), each its words by
        name."""
        return {
            "id": {"id": self.id_word},
            "relation": dict(self.relations),
            "alternative": dict(self.alternatives),
        }

    def family(self, name: str) -> dict[str, Word]:
        """One family's words by name; refused for a name that is no family."""
        fams = self.families
        if name not in fams:
            raise BadInput(f"codebook family {name!r} is not one of {', '.join(fams)}")
        return fams[name]

    def all_words(self) -> dict[str, Word]:
        """Every named word (``id`` plus relations plus alternatives)."""
        return {"id": self.id_word, **self.relations, **self.alternatives}

    def distinct_words(self) -> dict[str, Word]:
        """One name per distinct word (alliance folds into ``id``): the set an ID is judged
        against."""
        out: dict[str, Word] = {}
        for name, w in self.all_words().items():
            if w not in out.values():
                out[name] = w
        return out

    def family_min_distance(self, name: str) -> float:
        """The smallest Euclidean distance between two words of a family (inf with one word)."""
        words = list(self.family(name).values())
        return min((_dist(a, b) for a, b in itertools.combinations(words, 2)), default=math.inf)

    def to_dict(self) -> dict[str, Any]:
        """The codebook as a TOML-like dict, as :meth:`from_dict` reads it."""
        return {
            "name": self.name,
            "pulses": self.pulses,
            "min_distance": self.min_distance,
            "actions": list(self.actions),
            "id": list(self.id_word),
            "relation": {k: list(v) for k, v in self.relations.items()},
            "alternative": {k: list(v) for k, v in self.alternatives.items()},
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "codebook") -> Codebook:
        """From a TOML-like dict: ``pulses``, ``id``, ``relation`` {name: [..]}, ``alternative``
        {name: [..]}, optional ``min_distance``, ``name``, ``actions``."""
        if not isinstance(data, Mapping):
            raise BadInput(f"{where}: must be a table, got {type(data).__name__}")
        known = {"name", "pulses", "min_distance", "actions", "id", "relation", "alternative"}
        for key in data:
            if key not in known:
                raise BadInput(
                    f"{where}: unknown key {key!r} (known: {', '.join(sorted(known))})"
                )
        for key in ("pulses", "id", "relation", "alternative"):
            if key not in data:
                raise BadInput(f"{where}: missing key {key!r}")
        pulses = data["pulses"]
        if not isinstance(pulses, int) or isinstance(pulses, bool) or pulses < 1:
            raise BadInput(f"{where}.pulses: {pulses!r} must be a positive integer")

        def table(key: str) -> dict[str, Word]:
            t = data[key]
            if not isinstance(t, Mapping) or not t:
                raise BadInput(f"{where}.{key}: must be a non-empty table of name = [pulses]")
            return {str(k): _as_word(v, f"{where}.{key}.{k}") for k, v in t.items()}

        md = data.get("min_distance", 0.2)
        if isinstance(md, bool) or not isinstance(md, (int, float)) or not md >= 0:
            raise BadInput(f"{where}.min_distance: {md!r} must be a number ≥ 0")
        actions = data.get("actions", ())
        if isinstance(actions, str) or not isinstance(actions, Sequence):
            raise BadInput(f"{where}.actions: {actions!r} must be a list of action names")
        return cls(
            pulses=pulses,
            id_word=_as_word(data["id"], f"{where}.id"),
            relations=table("relation"),
            alternatives=table("alternative"),
            min_distance=float(md),
            name=str(data.get("name", "custom")),
            actions=tuple(str(a) for a in actions),
        )


def _as_word(value: Any, where: str) -> Word:
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence | np.ndarray):
        raise BadInput(f"{where}: {value!r} is not a list of pulse magnitudes")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
            raise BadInput(f"{where}: {v!r} is not a number")
        if not math.isfinite(float(v)):
            raise BadInput(f"{where}: {v!r} is not finite")
        out.append(float(v))
    return tuple(out)


def _dist(a: Word, b: Word) -> float:
    return math.dist(a, b)


def validate(cb: Codebook) -> None:
    """Refuse a codebook with wrong lengths, duplicates or too-close words (message names them)."""
    if not isinstance(cb.pulses, int) or cb.pulses < 1:
        raise BadInput(f"codebook {cb.name}: pulses = {cb.pulses!r} must be a positive integer")
    if not (isinstance(cb.min_distance, (int, float)) and cb.min_distance >= 0):
        raise BadInput(f"codebook {cb.name}: min_distance = {cb.min_distance!r} must be ≥ 0")
    fams = {
        "id": {"id": cb.id_word},
        "relation": dict(cb.relations),
        "alternative": dict(cb.alternatives),
    }
    for fam, words in fams.items():
        for name, w in words.items():
            if not isinstance(w, tuple) or not all(
                isinstance(v, float) and math.isfinite(v) for v in w
            ):
                raise BadInput(
                    f"codebook {cb.name}: {fam} word {name!r} = {w!r} must be a "
                    "tuple of finite floats"
                )
            if len(w) != cb.pulses:
                raise BadInput(
                    f"codebook {cb.name}: {fam} word {name!r} has {len(w)} pulses, "
                    f"expected {cb.pulses}"
                )
        for (n1, w1), (n2, w2) in itertools.combinations(words.items(), 2):
            if w1 == w2:
                raise BadInput(
                    f"codebook {cb.name}: {fam} words {n1!r} and {n2!r} are the "
                    f"same pulses {list(w1)}"
                )
            d = _dist(w1, w2)
            if d < cb.min_distance - 1e-9:
                raise BadInput(
                    f"codebook {cb.name}: {fam} words {n1!r} and {n2!r} are "
                    f"{d:.3g} apart, closer than min_distance {cb.min_distance:g}"
                )
    for name, w in cb.alternatives.items():
        d = _dist(w, cb.id_word)
        if d < cb.min_distance - 1e-9:
            raise BadInput(
                f"codebook {cb.name}: alternative {name!r} is {d:.3g} from the "
                f"ID-code, closer than min_distance {cb.min_distance:g}"
            )


def alternative_names(actions: Sequence[str]) -> list[str]:
    """Text forms of all 2^k alternatives in mask order: ``0``, ``{a}``, ``{b}``, …, ``1``."""
    k = len(actions)
    names = []
    for mask in range(1 << k):
        if mask == 0:
            names.append("0")
        elif mask == (1 << k) - 1:
            names.append("1")
        else:
            names.append("{" + ",".join(a for j, a in enumerate(actions) if mask >> j & 1) + "}")
    return names


PAPER_ALTERNATIVES = {
    "1": (0.2, 0.3, 0.7),
    "0": (0.7, 0.3, 0.2),
    "{alpha}": (0.5, 0.2, 0.5),
    "{beta}": (0.3, 0.6, 0.3),
}


def paper_codebook(
    actions: Sequence[str] = ("alpha", "beta"), names: Mapping[str, str] | None = None
) -> Codebook:
    """The paper's codebook (docs/model.md): 3 pulses, ID/alliance {.4,.4,.4}, conflict
    {−.4,−.4,−.4} and the four k = 2 alternatives; ``actions`` renames α, β; ``names`` remaps
    alternative names (e.g. Example 2's other reading ``{"1": "0", "0": "1"}``)."""
    if len(actions) not in (1, 2) or len(set(actions)) != len(actions):
        raise BadInput(
            f"the paper codebook has words for k = 1 or 2 distinct actions, got {list(actions)}"
        )
    alts = {"1": PAPER_ALTERNATIVES["1"], "0": PAPER_ALTERNATIVES["0"]}
    if len(actions) == 2:  # k = 1 (Example 3's "open") uses only the unit- and zero-codes
        a, b = (str(x) for x in actions)
        alts["{" + a + "}"] = PAPER_ALTERNATIVES["{alpha}"]
        alts["{" + b + "}"] = PAPER_ALTERNATIVES["{beta}"]
    if names:
        unknown = [k for k in names if k not in alts]
        if unknown:
            raise BadInput(f"paper codebook: no alternative named {unknown[0]!r} to rename")
        alts = {names.get(k, k): v for k, v in alts.items()}
        if len(alts) != 1 << len(actions):
            raise BadInput("paper codebook: renaming made two alternatives share a name")
    return Codebook(
        pulses=3,
        id_word=(0.4, 0.4, 0.4),
        relations={"alliance": (0.4, 0.4, 0.4), "conflict": (-0.4, -0.4, -0.4)},
        alternatives=alts,
        min_distance=0.2,
        name="paper",
        actions=tuple(str(x) for x in actions),
    )


def generate_codebook(
    actions: Sequence[str],
    *,
    pulses: int = 3,
    min_distance: float = 0.3,
    total: float | None = None,
    low: float = 0.1,
    high: float = 0.7,
    step: float | None = None,
    seed: int = 0,
) -> Codebook:
    """Alternative words for k actions with a stated minimum distance, deterministic per seed.

    Like the paper's words, every alternative has the same total magnitude ``total`` (default
    0.4·N, the ID-code's) so all carry the same energy; magnitudes lie in [low, high] on a grid of
    ``step`` (default: the finest multiple of 0.05 that keeps enumeration small; high 0.7 as
    the paper's: a single pulse near 1 would fire every resonator at once).  Candidates are
    shuffled by ``seed`` and picked greedily farthest-first (the next word is the candidate
    farthest from those chosen and from the ID-code), then the stated
    minimum distance is checked.  ID/alliance are N × 0.4, conflict N × −0.4.  Refused when 2^k
    words cannot be placed that far apart (the message says so).
    """
    acts = [str(a) for a in actions]
    if not acts or len(set(acts)) != len(acts):
        raise BadInput(f"actions {acts!r} must be distinct non-empty names")
    if not isinstance(pulses, int) or pulses < 1:
        raise BadInput(f"pulses = {pulses!r} must be a positive integer")
    k = len(acts)
    need = 1 << k
    total = 0.4 * pulses if total is None else float(total)
    grid = _Grid(low, float(high), pulses)
    step = grid.step_for(step)
    id_word = tuple([0.4] * pulses)
    pts = grid.words(round(total / step), step).astype(float) * step
    pts = pts[np.linalg.norm(pts - np.array(id_word), axis=1) >= min_distance - 1e-9]
    if len(pts) < need:
        raise BadInput(
            f"codebook generator: only {len(pts)} candidate words for {need} "
            f"alternatives at N = {pulses} pulses; use more pulses"
        )
    words = _farthest_first(pts, id_word, need, seed)
    got = min(_dist(a, b) for a, b in itertools.combinations(words, 2)) if need > 1 else math.inf
    if got < min_distance - 1e-9:
        raise BadInput(
            f"codebook generator: {need} words of {pulses} pulses reach only "
            f"{got:.3g} apart, below min_distance {min_distance:g}; use more pulses"
        )
    # Sort words for a stable, readable assignment: names in mask order get words in order.
    words.sort()
    alts = dict(zip(alternative_names(acts), words, strict=True))
    return Codebook(
        pulses=pulses,
        id_word=id_word,
        relations={"alliance": id_word, "conflict": tuple([-0.4] * pulses)},
        alternatives=alts,
        min_distance=min_distance,
        name=f"generated-k{k}-N{pulses}-seed{seed}",
        actions=tuple(acts),
    )


MAX_CANDIDATES = 1_000_000  # candidate words the generator enumerates at most


@dataclass(frozen=True)
class _Grid:
    """The generator's grid: words of ``pulses`` magnitudes in [low, high], multiples of a
    step."""

    low: float
    high: float
    pulses: int

    def bounds(self, step: float) -> tuple[int, int]:
        """The least and the greatest magnitude on the grid, in steps."""
        return math.ceil(self.low / step - 1e-9), math.floor(self.high / step + 1e-9)

    def enumeration(self, step: float) -> int:
        """How many words the grid enumerates: every magnitude but the last (the total's)."""
        lo_u, hi_u = self.bounds(step)
        count: int = max(0, hi_u - lo_u + 1) ** max(0, self.pulses - 1)
        return count

    def step_for(self, step: float | None) -> float:
        """``step``, checked, or (None) the finest multiple of 0.05 whose enumeration stays
        within ``MAX_CANDIDATES``."""
        if step is None:
            step = next(
                (s * 0.05 for s in range(1, 100) if self.enumeration(s * 0.05) <= MAX_CANDIDATES),
                None,
            )
            if step is None:
                raise BadInput(
                    f"codebook generator: no grid step keeps N = {self.pulses} pulses small"
                )
        if not step > 0:
            raise BadInput(f"codebook generator: step = {step!r} must be positive")
        # Counted before enumerating: the product itself could outlast any caller.
        if self.enumeration(step) > MAX_CANDIDATES:
            raise BadInput(
                f"codebook generator: about {self.enumeration(step):.3g} candidates at step "
                f"{step:g} for N = {self.pulses} pulses; use a coarser step"
            )
        return step

    def words(self, units: int, step: float) -> np.ndarray:
        """Every word on the grid whose magnitudes add up to ``units`` steps, in steps: the
        first N − 1 magnitudes in lexicographic order (as itertools.product), the last one
        what the total leaves."""
        lo_u, hi_u = self.bounds(step)
        width = max(0, hi_u - lo_u + 1)
        count = width ** (self.pulses - 1)  # at most MAX_CANDIDATES (step_for)
        head = np.empty((count, self.pulses - 1), dtype=np.int32)
        rest = np.arange(count)
        for j in range(self.pulses - 2, -1, -1):  # mixed radix: the last magnitude runs fastest
            head[:, j] = rest % width + lo_u
            rest //= width
        last = units - head.sum(axis=1)
        ok = (last >= lo_u) & (last <= hi_u)
        words: np.ndarray = np.concatenate([head[ok], last[ok, None]], axis=1)
        return words


def _farthest_first(pts: np.ndarray, id_word: Word, need: int, seed: int) -> list[Word]:
    """``need`` of the candidate words ``pts``, shuffled by ``seed``, picked greedily: the
    first, then each time the candidate farthest from those chosen and from the ID-code."""
    rng = np.random.default_rng(seed)
    pts = pts[rng.permutation(len(pts))]
    chosen = [0]
    d = np.minimum(
        np.linalg.norm(pts - pts[0], axis=1), np.linalg.norm(pts - np.array(id_word), axis=1)
    )
    while len(chosen) < need:
        j = int(np.argmax(d))
        chosen.append(j)
        d = np.minimum(d, np.linalg.norm(pts - pts[j], axis=1))
    return [tuple(round(float(v), 10) for v in pts[j]) for j in chosen]
