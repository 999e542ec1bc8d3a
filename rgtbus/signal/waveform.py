"""Code synthesis and the channel model (docs/model.md): what transmitters put on the medium.

A code is N pulses on channel ω, one period 2π/ω apart, starting at time t0; pulse j is one
sample of magnitude word[j] at sample ``round((t0 + j·2π/ω)/τ)`` (round half to even, as
Python's ``round``).  Transmitters superpose (the medium is the sum).  The channel model gives
each receiver r its own copy: ``heard_r = Σ_s gain[s, r]·x_s + noise_r`` with Gaussian noise of
standard deviation σ on every sample, drawn from ``numpy.random.default_rng(seed)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rgtbus.errors import BadInput
from rgtbus.signal.resonator import PAPER_TAU
from rgtbus.timebase import sample_of, time_of


def pulse_samples(omega: float, start: float, pulses: int, tau: float) -> tuple[int, ...]:
    """The rule: pulse j of a code starting at ``start`` on ω is at sample
    ``round((start + j·2π/ω)/τ)`` (round half to even). Unchecked; see ``pulse_instants``."""
    period = 2 * math.pi / omega
    return tuple(sample_of(start + j * period, tau) for j in range(pulses))


def pulse_instants(omega: float, start: float, pulses: int, tau: float = PAPER_TAU) -> np.ndarray:
    """Sample indices of a code's pulses: ``round((start + j·2π/ω)/τ)``, j = 0..pulses−1."""
    if not (math.isfinite(omega) and omega > 0):
        raise BadInput(f"omega = {omega!r} must be a positive frequency (rad/s)")
    if not math.isfinite(start) or start < 0:
        raise BadInput(f"start = {start!r} must be a time ≥ 0 s")
    if not isinstance(pulses, (int, np.integer)) or pulses < 1:
        raise BadInput(f"pulses = {pulses!r} must be a positive integer")
    return np.array(pulse_samples(omega, start, int(pulses), tau), dtype=np.int64)


@dataclass(frozen=True)
class Transmission:
    """One code on the medium: ``word`` (pulse magnitudes) on ``omega`` from ``start`` seconds,
    sent by transmitter index ``sender`` (for per-link gains)."""

    omega: float
    start: float
    word: tuple[float, ...]
    sender: int = 0

    def instants(self, tau: float = PAPER_TAU) -> np.ndarray:
        """The sample indices of this code's pulses (``pulse_instants``)."""
        return pulse_instants(self.omega, self.start, len(self.word), tau)


def _word(word: Sequence[float], where: str) -> tuple[float, ...]:
    try:
        w = tuple(float(v) for v in word)
    except (TypeError, ValueError):
        raise BadInput(f"{where}: word {word!r} is not a list of numbers") from None
    if not w or not all(math.isfinite(v) for v in w):
        raise BadInput(f"{where}: word {word!r} must be a non-empty list of finite numbers")
    return w


def code_waveform(
    word: Sequence[float], omega: float, start: float, n_samples: int, tau: float = PAPER_TAU
) -> np.ndarray:
    """The medium samples (length ``n_samples``) of one code; refuses pulses past the end."""
    return superpose([Transmission(omega, start, _word(word, "code"))], n_samples, tau)


def superpose(
    transmissions: Sequence[Transmission], n_samples: int, tau: float = PAPER_TAU
) -> np.ndarray:
    """Sum of all transmissions' pulses, length ``n_samples``."""
    if not isinstance(n_samples, (int, np.integer)) or n_samples < 0:
        raise BadInput(f"n_samples = {n_samples!r} must be a non-negative integer")
    out = np.zeros(int(n_samples))
    for j, t in enumerate(transmissions):
        word = _word(t.word, f"transmission {j}")
        idx = pulse_instants(t.omega, t.start, len(word), tau)
        if idx[-1] >= n_samples:
            raise BadInput(
                f"transmission {j}: its last pulse at sample {int(idx[-1])} "
                f"(t = {time_of(int(idx[-1]), tau):g} s) is past the end ({n_samples} samples)"
            )
        np.add.at(out, idx, word)
    return out


def code_length(omega: float, pulses: int, start: float = 0.0, tau: float = PAPER_TAU) -> int:
    """Samples needed to hold a code: last pulse index + 1."""
    return int(pulse_instants(omega, start, pulses, tau)[-1]) + 1


def hear(
    transmissions: Sequence[Transmission],
    n_samples: int,
    *,
    n_receivers: int = 1,
    gains: np.ndarray | Sequence[Sequence[float]] | None = None,
    sigma: float = 0.0,
    seed: int | None = 0,
    tau: float = PAPER_TAU,
) -> np.ndarray:
    """Medium as each receiver hears it: shape (n_samples, n_receivers).

    ``gains[s, r]`` scales sender s's signal at receiver r (default 1); ``sigma`` adds white
    Gaussian noise, independent per receiver and sample, from ``default_rng(seed)``.
    """
    if not isinstance(n_receivers, (int, np.integer)) or n_receivers < 1:
        raise BadInput(f"n_receivers = {n_receivers!r} must be a positive integer")
    if not (math.isfinite(sigma) and sigma >= 0):
        raise BadInput(f"noise sigma = {sigma!r} must be ≥ 0")
    senders = sorted({t.sender for t in transmissions})
    if senders and (senders[0] < 0 or not all(isinstance(s, (int, np.integer)) for s in senders)):
        raise BadInput(f"transmission sender {senders[0]!r} must be an index ≥ 0")
    n_send = (max(senders) + 1) if senders else 0
    if gains is None:
        g = np.ones((n_send, n_receivers))
    else:
        g = np.asarray(gains, dtype=float)
        if g.ndim != 2 or g.shape[1] != n_receivers or g.shape[0] < n_send:
            raise BadInput(
                f"gains of shape {g.shape} must be (senders ≥ {n_send}, receivers = {n_receivers})"
            )
        if not np.isfinite(g).all():
            raise BadInput("gains must be finite")
    out = np.zeros((int(n_samples), n_receivers))
    for s in senders:
        x = superpose([t for t in transmissions if t.sender == s], n_samples, tau)
        out += x[:, None] * g[s][None, :]
    if sigma > 0:
        out += np.random.default_rng(seed).normal(0.0, sigma, out.shape)
    return out
