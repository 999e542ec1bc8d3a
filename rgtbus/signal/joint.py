"""Joint decoding (docs/model.md): transmitters whose pulses share samples add up there.

Stack every transmitter's pulses into ``d_U = M·c`` over the union U of their instants,
estimate c by least squares and pick the word combination whose prediction is nearest the
readout (the nearest-codeword rule, ``rgtbus.signal.nearest``, over combinations):
exhaustive up to ``MAX_EXHAUSTIVE`` combinations, coordinate descent otherwise.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from rgtbus.errors import BadInput
from rgtbus.signal.decoder import Decision, Readout, read_at, word_matrix
from rgtbus.signal.nearest import distances, in_order, nearest_choice

MAX_EXHAUSTIVE = 4096  # word combinations tried one by one; beyond, coordinate descent


def decode_joint(
    readout: Readout | np.ndarray,
    transmissions: Sequence[tuple[Sequence[int], Mapping[str, Sequence[float]]]],
    *,
    offset: int = 0,
    channel: int = 0,
) -> list[Decision]:
    """Decode overlapping transmissions together.

    ``transmissions``: (pulse instants, candidate words) per transmitter.  Over the union U of
    instants the readout is ``d_U = M·c`` (M sums the pulses landing on each sample): the
    per-transmitter values reported are the least-squares estimate of c (minimum norm when
    pulses coincide), and the names the word combination with the smallest residual
    ``‖d_U − M·c‖`` — exhaustive up to ``MAX_EXHAUSTIVE`` combinations, else coordinate descent.
    ``distance`` is that residual, ``margin`` the residual increase of the best combination that
    changes this transmitter's word.
    """
    if not transmissions:
        raise BadInput("decode_joint: no transmissions")
    system = _JointSystem.of(transmissions)
    d = read_at(readout, system.union, offset, channel)
    estimate = np.linalg.lstsq(system.mixing, d, rcond=None)[0]
    if math.prod(len(names) for names in system.names) <= MAX_EXHAUSTIVE:
        best, residual, margins = _joint_exhaustive(system, d)
    else:
        best, residual, margins = _joint_descent(system, d, estimate)
    return [
        _joint_decision(system, j, best[j], residual, margins[j], estimate)
        for j in range(len(system.instants))
    ]


@dataclass(frozen=True)
class _JointSystem:
    """Overlapping transmissions over the union U of their instants (``decode_joint``):
    ``mixing`` M (|U|, Σ pulses) sums the pulses landing on each sample; per transmitter j its
    ``instants``, word ``names`` and ``words`` (W_j, N_j), each word's ``contributions`` to
    d_U (W_j, |U|), and its columns of M, ``bounds[j]:bounds[j + 1]``."""

    union: np.ndarray
    mixing: np.ndarray
    bounds: np.ndarray
    instants: list[np.ndarray]
    names: list[tuple[str, ...]]
    words: list[np.ndarray]
    contributions: list[np.ndarray]

    @classmethod
    def of(
        cls, transmissions: Sequence[tuple[Sequence[int], Mapping[str, Sequence[float]]]]
    ) -> _JointSystem:
        """The system of these transmissions (their words checked)."""
        insts = [np.asarray(i, dtype=np.int64) for i, _ in transmissions]
        named = [
            word_matrix(w, len(i), f"decode_joint transmission {j}")
            for j, ((_, w), i) in enumerate(zip(transmissions, insts, strict=True))
        ]
        union = np.unique(np.concatenate(insts))
        cols = []
        for inst in insts:
            for k in inst:
                col = np.zeros(union.size)
                col[union.searchsorted(k)] += 1.0
                cols.append(col)
        mixing = np.stack(cols, axis=1)
        bounds = np.cumsum([0] + [len(i) for i in insts])
        words = [mat for _, mat in named]
        contributions = [m @ mixing[:, bounds[j] : bounds[j + 1]].T for j, m in enumerate(words)]
        names = [names for names, _ in named]
        return cls(union, mixing, bounds, insts, names, words, contributions)

    def predictions(self, combos: np.ndarray) -> np.ndarray:
        """d_U of each word combination (C, transmitters) of word indexes: (C, |U|), the
        transmitters' contributions added in their order."""
        total: np.ndarray = sum(
            self.contributions[j][combos[:, j]] for j in range(len(self.contributions))
        )
        return total

    def residuals(self, d: np.ndarray, combos: np.ndarray) -> np.ndarray:
        """‖d_U − M·c‖ of each word combination: the nearest-codeword rule's distance."""
        return distances(d, self.predictions(combos))

    def same_word(self, j: int, w: int) -> np.ndarray:
        """Which words of transmitter j are word ``w``'s pulses (under any name)."""
        same: np.ndarray = (self.words[j] == self.words[j][w]).all(axis=1)
        return same


def _joint_exhaustive(system: _JointSystem, d: np.ndarray) -> tuple[list[int], float, list[float]]:
    """Every word combination: the nearest prediction to d (ties: the first combination),
    its residual, and per transmitter the residual increase of the best combination that
    changes its word (inf if none does)."""
    sizes = [len(names) for names in system.names]
    combos = np.array(list(itertools.product(*[range(s) for s in sizes])), dtype=np.int64)
    total = system.predictions(combos)
    b = int(nearest_choice(d[None, None, :], total, in_order(len(combos))).word[0])
    res = distances(d, total)
    best = combos[b].tolist()
    margins = []
    for j in range(len(sizes)):
        other = ~system.same_word(j, best[j])[combos[:, j]]
        margins.append(float(res[other].min() - res[b]) if other.any() else math.inf)
    return best, float(res[b]), margins


def _joint_descent(
    system: _JointSystem, d: np.ndarray, estimate: np.ndarray
) -> tuple[list[int], float, list[float]]:
    """Coordinate descent from each transmitter's word nearest its least-squares estimate:
    each transmitter in turn takes the word whose contribution is nearest what the others
    leave of d, until none changes (20 rounds at most); the residual and margins as
    ``_joint_exhaustive``'s, the others' words held."""
    count = len(system.words)
    choice = [
        _nearest_row(estimate[system.bounds[j] : system.bounds[j + 1]], system.words[j])
        for j in range(count)
    ]
    for _ in range(20):
        changed = False
        for j in range(count):
            rest = d - sum(system.contributions[i][c] for i, c in enumerate(choice) if i != j)
            cj = _nearest_row(rest, system.contributions[j])
            if cj != choice[j]:
                choice[j], changed = cj, True
        if not changed:
            break
    residual = float(system.residuals(d, np.array([choice]))[0])
    margins = []
    for j in range(count):
        alts = np.repeat(np.array([choice]), len(system.words[j]), axis=0)
        alts[:, j] = np.arange(len(system.words[j]))  # j's every word, the others' held
        differs = ~system.same_word(j, choice[j])
        other = system.residuals(d, alts[differs])
        margins.append(float(other.min()) - residual if other.size else math.inf)
    return choice, residual, margins


def _nearest_row(reads: np.ndarray, mat: np.ndarray) -> int:
    """The row of ``mat`` nearest ``reads`` by the nearest-codeword rule (ties: the first)."""
    return int(nearest_choice(reads[None, None, :], mat, in_order(len(mat))).word[0])


def _joint_decision(
    system: _JointSystem, j: int, w: int, residual: float, margin: float, estimate: np.ndarray
) -> Decision:
    """Transmitter j's decision: word ``w`` at the joint ``residual``, its ``margin``, the
    confidence against its nearest other word, and its least-squares values."""
    gaps = distances(system.words[j][w], system.words[j])
    others = gaps[~system.same_word(j, w)]
    sep = float(others.min()) if others.size else 0.0
    conf = margin / sep if sep > 0 and math.isfinite(margin) else 1.0
    values = estimate[system.bounds[j] : system.bounds[j + 1]]
    return Decision(
        system.names[j][w],
        residual,
        margin,
        conf,
        tuple(float(x) for x in values),
        tuple(int(k) for k in system.instants[j]),
    )
