"""Monte-Carlo symbol error rate of the decoder, through the resonator bank (pure numpy).

Each trial is one receiver of a bank: it hears a target code (a random word of the family) on
ω_t, optionally an interferer (a random word) on ω_i starting at the same time — so their first
pulses land on the same sample — plus white Gaussian noise σ on every sample.  The bank runs the
full model (noise spikes and resets included); the decoder reads the increments at the pulse
instants and decides: alone, by nearest word; with an interferer, jointly (least squares over
the union of instants, exhaustive ML over word pairs) or, as a baseline, independently
(ignoring the interferer).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from rgtbus.errors import BadInput
from rgtbus.signal.nearest import in_order, nearest_choice
from rgtbus.signal.resonator import PAPER_TAU, ResonatorBank
from rgtbus.signal.waveform import pulse_instants
from rgtbus.timebase import sample_of


@dataclass(frozen=True)
class SerResult:
    """A Monte-Carlo symbol error rate: ``errors`` of ``trials`` at noise ``sigma``."""

    sigma: float
    trials: int
    errors: int

    @property
    def ser(self) -> float:
        """The symbol error rate, errors over trials."""
        return self.errors / self.trials


def symbol_error_rate(
    words: Mapping[str, Sequence[float]],
    omega: float,
    sigma: float,
    *,
    trials: int = 1000,
    seed: int = 0,
    interferer: float | None = None,
    interferer_words: Mapping[str, Sequence[float]] | None = None,
    joint: bool = True,
    start: float = 0.001,
    mode: str = "paper",
    tau: float = PAPER_TAU,
    batch: int = 500,
) -> SerResult:
    """Symbol error rate of decoding ``words`` sent on ``omega`` under noise ``sigma``."""
    if trials < 1:
        raise BadInput(f"trials = {trials!r} must be positive")
    if not sigma >= 0:
        raise BadInput(f"noise sigma = {sigma!r} must be ≥ 0")
    names = list(words)
    W = np.array([words[n] for n in names], dtype=float)
    N = W.shape[1]
    inst = pulse_instants(omega, start, N, tau)
    channels = [omega]
    if interferer is not None:
        iw = words if interferer_words is None else interferer_words
        IW = np.array(list(iw.values()), dtype=float)
        inst_i = pulse_instants(interferer, start, IW.shape[1], tau)
        channels.append(interferer)
        last = max(inst[-1], inst_i[-1])
    else:
        last = inst[-1]
    n = int(last) + 2
    rng = np.random.default_rng(seed)
    errors = 0
    done = 0
    while done < trials:
        m = min(batch, trials - done)
        done += m
        pick = rng.integers(len(names), size=m)
        u = np.zeros((n, m))
        u[inst] += W[pick].T
        if interferer is not None:
            pick_i = rng.integers(len(IW), size=m)
            u[inst_i] += IW[pick_i].T
        if sigma > 0:
            u += rng.normal(0.0, sigma, u.shape)
        res = ResonatorBank(channels, mode=mode, tau=tau, n_receivers=m).feed(u, readout=True)
        assert res.readout is not None and res.readout_rows is not None
        d = np.zeros((n, m))  # the increment readout on the code's channel (0 where silent)
        d[res.readout_rows] = res.readout[:, :, 0]
        if interferer is None or not joint:
            got = _nearest_each(d[inst].T, W)
        else:
            got = _joint_batch(d, inst, W, inst_i, IW)
        errors += int(np.sum(~np.all(W[got] == W[pick], axis=1)))
    return SerResult(float(sigma), trials, errors)


def _joint_batch(
    d: np.ndarray, inst: np.ndarray, W: np.ndarray, inst_i: np.ndarray, IW: np.ndarray
) -> np.ndarray:
    """Exhaustive joint ML over (target word, interferer word) pairs, vectorised over trials."""
    union = np.unique(np.concatenate([inst, inst_i]))
    pos_t = np.searchsorted(union, inst)
    pos_i = np.searchsorted(union, inst_i)
    combos = list(itertools.product(range(len(W)), range(len(IW))))
    pred = np.zeros((len(combos), union.size))
    for c, (a, b) in enumerate(combos):
        np.add.at(pred[c], pos_t, W[a])
        np.add.at(pred[c], pos_i, IW[b])
    best = _nearest_each(d[union].T, pred)
    return np.array([combos[b][0] for b in best])


def _nearest_each(reads: np.ndarray, words: np.ndarray) -> np.ndarray:
    """The word of ``words`` (W, N) each trial's ``reads`` (trials, N) decode as: the
    nearest-codeword rule (``rgtbus.signal.nearest``), ties to the first word."""
    return nearest_choice(reads[:, None, :], words, in_order(len(words))).word


def noise_spike_rate(
    omegas: Sequence[float],
    sigma: float,
    *,
    seconds: float = 600.0,
    seed: int = 0,
    mode: str = "paper",
    tau: float = PAPER_TAU,
) -> float:
    """Spikes per second per resonator on noise alone (false attention at noise σ)."""
    if not sigma >= 0:
        raise BadInput(f"noise sigma = {sigma!r} must be ≥ 0")
    n = sample_of(seconds, tau)
    u = np.random.default_rng(seed).normal(0.0, sigma, n) if sigma > 0 else np.zeros(n)
    res = ResonatorBank(omegas, mode=mode, tau=tau).feed(u)
    return len(res.spikes) / (seconds * len(omegas))


@dataclass(frozen=True)
class MlSerBounds:
    """The symbol error rate of the best possible receiver (maximum likelihood) of a family of
    words under white Gaussian noise, bracketed: ``lower`` <= ML SER <= ``union``."""

    sigma: float
    lower: float  # nearest-neighbour bound: (1/M) Σ_i Q(d_i,min / 2σ)
    union: float  # union bound: (1/M) Σ_i Σ_{j≠i} Q(d_ij / 2σ), at most 1


def _q(x: np.ndarray) -> np.ndarray:
    """The Gaussian tail Q(x) = P(N(0, 1) > x) = erfc(x / √2) / 2."""
    flat = [0.5 * math.erfc(v / math.sqrt(2.0)) for v in np.asarray(x, dtype=float).ravel()]
    return np.array(flat).reshape(np.shape(x))


def ml_ser_bounds(words: Mapping[str, Sequence[float]], sigma: float) -> MlSerBounds:
    """How well any receiver could tell ``words`` apart under noise ``sigma``.

    A code's pulses land on N known samples (its instants); every other sample carries noise
    alone, independent of them, so the best receiver decides from those N samples: the
    received vector r = w_i + n, n ~ N(0, σ² I), equally likely words, decided by the nearest
    word (maximum likelihood). Word i is mistaken for word j when r is nearer w_j: probability
    Q(d_ij / 2σ), d_ij = |w_i − w_j|. So P(error | i) lies between the largest of those (its
    nearest neighbour) and their sum: averaged over the M words,

        (1/M) Σ_i Q(d_i,min / 2σ)  <=  ML SER  <=  min(1, (1/M) Σ_i Σ_{j≠i} Q(d_ij / 2σ)).

    Both are exact for two words, and tight once errors are rare (the nearest pairs dominate).
    Words that are equal can never be told apart: Q(0) = 1/2 each way."""
    if not sigma >= 0 or not math.isfinite(sigma):
        raise BadInput(f"noise sigma = {sigma!r} must be finite and ≥ 0")
    W = np.array([list(words[n]) for n in words], dtype=float)
    if W.ndim != 2 or len(W) < 1:
        raise BadInput("words: at least one word, all of the same length")
    M = len(W)
    if M == 1:
        return MlSerBounds(float(sigma), 0.0, 0.0)
    d = np.linalg.norm(W[:, None, :] - W[None, :, :], axis=2)
    # d / 2σ; without noise only equal words are mistaken (d = 0: Q(0) = 1/2)
    z = d / (2.0 * sigma) if sigma > 0 else np.where(d > 0, np.inf, 0.0)
    q = _q(z)
    np.fill_diagonal(q, 0.0)
    union = float(min(1.0, q.sum() / M))
    lower = float(q.max(axis=1).sum() / M)
    return MlSerBounds(float(sigma), lower, union)


def ml_ser_monte_carlo(
    words: Mapping[str, Sequence[float]], sigma: float, *, trials: int = 10000, seed: int = 0
) -> SerResult:
    """The maximum-likelihood receiver of ``ml_ser_bounds`` run: a random word plus white noise
    at its N samples, decided by the nearest word (ties to the first). A check of the bounds,
    and what ``ser_against_bound`` puts the bank's decoder beside."""
    if trials < 1:
        raise BadInput(f"trials = {trials!r} must be positive")
    W = np.array([list(words[n]) for n in words], dtype=float)
    rng = np.random.default_rng(seed)
    pick = rng.integers(len(W), size=trials)
    r = W[pick] + rng.normal(0.0, sigma, (trials, W.shape[1]))
    got = _nearest_each(r, W)
    return SerResult(float(sigma), trials, int(np.sum(~np.all(W[got] == W[pick], axis=1))))


def ser_against_bound(
    words: Mapping[str, Sequence[float]],
    omega: float,
    sigmas: Sequence[float],
    *,
    trials: int = 2000,
    seed: int = 0,
    mode: str = "paper",
    tau: float = PAPER_TAU,
) -> list[dict[str, float | int | None]]:
    """The bank's decoder (``symbol_error_rate``) beside the best possible receiver, one row a
    noise level: ``sigma``, ``trials``, ``errors``, ``ser`` (the decoder's), ``ml_lower`` and
    ``ml_union`` (``ml_ser_bounds``), and ``vs_bound`` = ser / ml_union where the decoder
    erred and the bound is above 0 (else None): how far from the limit the receiver is."""
    rows: list[dict[str, float | int | None]] = []
    for i, s in enumerate(sigmas):
        sim = symbol_error_rate(words, omega, s, trials=trials, seed=seed + i, mode=mode, tau=tau)
        b = ml_ser_bounds(words, s)
        rows.append(
            {
                "sigma": float(s),
                "trials": sim.trials,
                "errors": sim.errors,
                "ser": sim.ser,
                "ml_lower": b.lower,
                "ml_union": b.union,
                "vs_bound": sim.ser / b.union if sim.errors and b.union > 0 else None,
            }
        )
    return rows
