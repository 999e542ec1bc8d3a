"""The nearest-codeword rule (docs/model.md): which word of a word set is nearest the values
read at a code's instants. Every decoder form decides by it; pure numpy, no state.

With white Gaussian noise on the medium the values read at a code's N instants are
``word + noise``, so the maximum-likelihood word is the nearest. Over candidate reads v_m
(rows, e.g. timings and channels) and words w_j, with ``rank`` the order that breaks ties::

    distance  d(m, j) = sqrt(Σ_k (v_m,k − w_j,k)²)          (summed over k in order)
    best      (m*, j*) = the least (d(m, j), m, rank[j])      (ties: the first row, then the
                                                              lowest rank)
    margin    = min_{j ∈ O} d(m*, j) − d(m*, j*)             (O: the words that differ from
                                                              w_j*; inf when there are none)
    separation = min_{j ∈ O} |w_j − w_j*|                    (0 when O is empty)
    confidence = margin / separation  (1 at the word, 0 half-way; 1 without other words)

Words equal to the best under another name (``id`` and ``alliance``) are not runners-up.
``nearest_words`` states the rule in numpy over many decodes at once (``nearest_choice``: its
choice alone); ``nearest_word`` is one decode, computed by the rule's compiled twin
(``_walk.score``: the same sums in the same order, so the same bits, ties included). Both hold
for finite reads (what a readout holds).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from rgtbus.signal.kernels import score

# (row, word, distance, margin, separation) of one decode: the compiled twin's tuple as it is
# (built at every decode: a named tuple would add its own construction to the hot path)
Score = tuple[int, int, float, float, float]

_IN_ORDER = np.arange(4096, dtype=np.int64)
_IN_ORDER.flags.writeable = False


def nearest_word(reads: np.ndarray, mat: np.ndarray, rank: np.ndarray) -> Score:
    """The rule for one decode: the row of ``reads`` (M, N, C-contiguous float64) and the word
    of ``mat`` (W, N) at the least distance (ties: the first row, the lowest ``rank``), that
    distance, the margin and the separation (module docstring). Computed by the compiled twin
    of ``nearest_words``."""
    return score(reads, mat, rank)


class Choice(NamedTuple):
    """The rule's choice for D decodes at once (``nearest_choice``), one entry a decode."""

    row: np.ndarray  # (D,) int64: the candidate row read
    word: np.ndarray  # (D,) int64: the word (an index into the words)
    distance: np.ndarray  # (D,)


class Scores(NamedTuple):
    """The rule's whole answer for D decodes at once (``nearest_words``)."""

    row: np.ndarray  # (D,) int64
    word: np.ndarray  # (D,) int64
    distance: np.ndarray  # (D,)
    margin: np.ndarray  # (D,)
    separation: np.ndarray  # (D,)


def distances(reads: np.ndarray, mat: np.ndarray) -> np.ndarray:
    """The rule's distance of every read (..., N) to every word of ``mat`` (W, N): (..., W),
    ``sqrt(Σ_k (v_k − w_k)²)`` summed over k in order, as the compiled twin sums: a running
    sum, one (..., W) array a pulse (numpy's ``sum`` adds in pairs from 8 terms on, and a
    cumulative sum over k would hold all N partial sums to read the last)."""
    reads = np.asarray(reads)
    acc: np.ndarray | None = None
    for k in range(mat.shape[1]):
        diff = reads[..., k, None] - mat[:, k]
        acc = diff * diff if acc is None else acc + diff * diff
    if acc is None:  # words of no pulses: every distance 0
        return np.zeros((*reads.shape[:-1], mat.shape[0]))
    root: np.ndarray = np.sqrt(acc)
    return root


Distance = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (..., N), (W, N) -> (..., W)


def _choose(
    reads: np.ndarray, mat: np.ndarray, rank: np.ndarray, by: Distance
) -> tuple[Choice, np.ndarray, np.ndarray]:
    """``nearest_choice``, every distance it weighed ((D, M, W), words in rank order) and
    that order (the words' indexes)."""
    reads = np.asarray(reads, dtype=np.float64)
    by_rank = np.argsort(rank, kind="stable")
    # words in rank order: the first least distance in (row, word) order is the rule's
    weighed = by(reads, mat[by_rank])
    dist = weighed.reshape(reads.shape[0], -1)
    first = dist.argmin(axis=1)
    row, at = np.divmod(first, mat.shape[0])
    return Choice(row, by_rank[at], dist[np.arange(dist.shape[0]), first]), weighed, by_rank


def nearest_choice(
    reads: np.ndarray, mat: np.ndarray, rank: np.ndarray, by: Distance = distances
) -> Choice:
    """The rule's choice (module docstring) for D decodes at once: ``reads`` (D, M, N), each
    decode's M candidate rows against the words of ``mat`` (W, N), ties broken by ``rank``
    (W,): the least (distance, row, rank). ``by``: the distance (Euclidean; another rule's,
    ``rgtbus.signal.rules``)."""
    return _choose(reads, mat, rank, by)[0]


def nearest_words(
    reads: np.ndarray, mat: np.ndarray, rank: np.ndarray, by: Distance = distances
) -> Scores:
    """The rule (module docstring) for D decodes at once: ``nearest_choice``'s row, word and
    distance, and each one's margin and separation; ``by`` as there (a word is another word
    when it differs from the best, whatever the distance). The words' distances to each
    other are a (W, W) table worked out once a call, and the best row's distance to every
    word is read from what the choice weighed: the same numbers, not worked out again."""
    (row, word, best), weighed, by_rank = _choose(reads, mat, rank, by)
    decodes = np.arange(word.size)
    table = distances(mat, mat)  # (W, W): word to word
    apart = table[word]  # (D, W): each best word's distance to every word
    others = apart != 0.0  # a word equal to the best under another name is no runner-up
    if by is not distances:  # the best word read exactly, less its distance to itself
        exactly = by(mat, mat)
        apart = exactly[word] - exactly[word, word][:, None]
    gaps = apart
    in_rank = np.empty(rank.size, dtype=np.int64)  # where each word stands in rank order
    in_rank[by_rank] = np.arange(rank.size)
    read = weighed[decodes, row][:, in_rank]  # (D, W): the best row to every word
    runner = np.where(others, read, np.inf).min(axis=1)
    has_others = others.any(axis=1)
    margin = np.where(has_others, runner - best, np.inf)
    separation = np.where(has_others, np.where(others, gaps, np.inf).min(axis=1), 0.0)
    return Scores(row, word, best, margin, separation)


def confidence(margin: float, separation: float) -> float:
    """The rule's confidence: margin over separation (1 at the word, 0 half-way); 1 when no
    other word could be mistaken for it (margin inf, separation 0)."""
    if separation > 0:
        return margin / separation
    return 1.0 if math.isinf(margin) else 0.0


def in_order(count: int) -> np.ndarray:
    """Ranks that break ties by position: the first word wins (read-only)."""
    if count <= _IN_ORDER.size:
        return _IN_ORDER[:count]
    return np.arange(count, dtype=np.int64)


@lru_cache(maxsize=256)
def alphabetical(names: tuple[str, ...]) -> np.ndarray:
    """Ranks that break ties by name: the first name in alphabetical order wins."""
    rank = np.empty(len(names), dtype=np.int64)
    rank[np.argsort(np.array(names, dtype=object), kind="stable")] = np.arange(len(names))
    return rank
