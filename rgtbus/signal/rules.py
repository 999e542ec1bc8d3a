"""The decoding rules: which word of a word set the values read at a code's instants are taken
for, and how sure that is. A rule is one object (``Rule``) with its forms, handed to every
decode form through the word set it decodes (``rgtbus.signal.decoder.WordSet.rule``), so a new
rule sits beside these without touching the decode forms. A scenario names its rule
(``decoding = "nearest" | "matched-filter"``, docs/model.md, "Decoding rules").

* ``nearest`` (``rgtbus.signal.nearest``): the word at the least Euclidean distance,
  ``d(v, w) = |v − w|``: maximum likelihood under white Gaussian noise when each link's gain is
  known (the receiver reads its words through its link: the paper's rule).
* ``matched-filter``: the word (and the timing) of the largest normalised matched-filter
  output, ``z(v, w) = Σ_k v_k·w_k / sqrt(Σ_k w_k²)``, its distance ``d(v, w) = −z(v, w)``
  (−0 for the all-zero word; sums in k's order). It needs no link gain: a read ``a·w`` with
  any gain a > 0 is nearest its own word ``w`` (Cauchy–Schwarz), so faded or unknown links
  cost it nothing without noise; with noise it weighs words by their direction only, so
  words of one direction and different lengths are one word to it. It reads payloads of the
  serial schedule: under the concurrent one every channel carries a code at once and it takes
  crosstalk for codes (the loader refuses the pair); IDs keep the nearest word.

Both rules break ties alike (the first row, then the lowest rank), and report a ``margin``
(the least distance to a word that differs from the best, minus the best's) and a
``separation`` (that least distance with the best word itself as the read): confidence =
margin / separation is 1 at the word and 0 where another word is as near (the separation is
the best word's distance to that word less its distance to itself: 0 for the nearest rule).

Each rule has three forms held equal bit for bit by the tests: ``many`` (NumPy, many decodes
at once), ``one`` (one decode by the compiled receiver, ``rgtbus.signal._walk``) and its NumPy
twin (``rgtbus.signal.walk_numpy``), which stands in where the compiled module is missing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rgtbus.errors import BadInput
from rgtbus.signal import kernels
from rgtbus.signal.nearest import Score, Scores, confidence, nearest_words


@dataclass(frozen=True)
class Rule:
    """A decoding rule (module docstring): its ``name`` (the scenario's ``decoding``), one
    decode (``one(reads (M, N), mat (W, N), rank (W,))``: row, word, distance, margin,
    separation) and many at once (``many(reads (D, M, N), mat, rank)``)."""

    name: str
    one: Callable[[np.ndarray, np.ndarray, np.ndarray], Score]
    many: Callable[[np.ndarray, np.ndarray, np.ndarray], Scores]

    @staticmethod
    def confidence(margin: float, separation: float) -> float:
        """Margin over separation: 1 at the word, 0 half-way (``nearest.confidence``)."""
        return confidence(margin, separation)


def matched(reads: np.ndarray, mat: np.ndarray) -> np.ndarray:
    """The matched-filter rule's distance of every read (..., N) to every word of ``mat``
    (W, N): (..., W), the negative matched-filter output ``−Σ v·w / sqrt(Σ w²)`` (−0 for the
    zero word), every sum in k's order as the compiled form sums (a running sum)."""
    reads = np.asarray(reads, dtype=np.float64)
    vw = np.zeros((*reads.shape[:-1], mat.shape[0]))  # (..., W)
    ww = np.zeros(mat.shape[0])  # (W,)
    for k in range(mat.shape[1]):  # running sums in k's order (0 + x is x, bit for bit)
        vw = vw + reads[..., k, None] * mat[:, k]
        ww = ww + mat[:, k] * mat[:, k]
    out: np.ndarray = np.where(ww > 0.0, -(vw / np.sqrt(np.where(ww > 0.0, ww, 1.0))), -0.0)
    return out


def matched_words(reads: np.ndarray, mat: np.ndarray, rank: np.ndarray) -> Scores:
    """The matched-filter rule for D decodes at once (``nearest_words`` by ``matched``)."""
    return nearest_words(reads, mat, rank, by=matched)


def _nearest_compiled(reads: np.ndarray, mat: np.ndarray, rank: np.ndarray) -> Scores:
    """``nearest_words`` computed by the compiled receiver (``_walk.score_many``): the same
    sums in the same order, so the same bits (tested), a loop in C over the decodes."""
    return Scores(
        *kernels.score_many(
            np.ascontiguousarray(reads, dtype=np.float64),
            np.ascontiguousarray(mat, dtype=np.float64),
            np.ascontiguousarray(rank, dtype=np.int64),
        )
    )


# many decodes at once: compiled where the receiver is (its NumPy twin decodes one at a time)
NEAREST = Rule("nearest", kernels.score, _nearest_compiled if kernels.COMPILED else nearest_words)
MATCHED = Rule("matched-filter", kernels.score_matched, matched_words)
RULES: dict[str, Rule] = {rule.name: rule for rule in (NEAREST, MATCHED)}


def rule_named(name: str) -> Rule:
    """The rule called ``name``; a one-line error naming the rules there are."""
    rule = RULES.get(name) if isinstance(name, str) else None
    if rule is None:
        raise BadInput(f"unknown decoding rule {name!r} ({', '.join(RULES)})")
    return rule
