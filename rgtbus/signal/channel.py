"""The channel: what receiver r hears from sender s. Pure (NumPy only).

    h_r[k] = Σ_s g[s→r] · m_s[k]  +  σ · n_r[k]
    g[s→r] = G[s→r] · (d0 / max(d(s, r), d0)) ** (n / 2)

``m_s[k]`` is sender s's pulses at sample k (its own pulses added in the order sent), the
senders added left to right in member order (``rgtbus.signal.pulses``: the bit-exact medium
sum); ``g[s→r]`` the link gain: ``G[s→r]`` of ``[channel] gain`` (1 unless it says otherwise)
times the path loss of the distance between the units' ``[channel] positions`` (power falls as
distance to the ``n``-th power, ``[channel] path_loss``, beyond the ``reference_distance`` d0:
an amplitude gain of (d0/d)^(n/2); free space is n = 2; no positions, or n = 0: no loss); ``σ``
the white noise of ``[channel] noise``; ``n_r`` unit r's own standard normal draws, from its
own seeded generator (``noise_rng``), taken in sample order however a run is cut into steps.

A new channel effect (path loss, delay, drift, bursts) goes here, with its scenario keys in
``rgtbus/scenario/channel.py``; the ears (``rgtbus.hearing``) apply what this module says.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from rgtbus.signal.pulses import across_senders, sender_columns

Pair = tuple[str, str]


FREE_SPACE = 2.0  # the path-loss exponent of free space


@dataclass(frozen=True)
class Channel:
    """A run's channel: ``noise`` σ and the link ``gains`` ``{(sender, receiver): g}`` each
    receiver applies (path loss included: ``link_gains``); the ``positions`` (metres, x y z)
    and path-loss ``path_loss`` exponent and ``reference_distance`` they came from, if any."""

    noise: float = 0.0
    gains: Mapping[Pair, float] = field(default_factory=dict)
    positions: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)
    path_loss: float = 0.0
    reference_distance: float = 1.0

    def distance(self, a: str, b: str) -> float:
        """The distance between units ``a`` and ``b`` in metres (0 without positions)."""
        if not self.positions:
            return 0.0
        return float(np.linalg.norm(np.subtract(self.positions[a], self.positions[b])))

    def gain_row(self, units: Sequence[str], receiver: str) -> np.ndarray:
        """``g[s→receiver]`` for every sender s, in member order."""
        return np.array([self.gains.get((s, receiver), 1.0) for s in units])

    @property
    def unit_gains(self) -> bool:
        """Every link has gain 1: every receiver hears the same medium (before its noise)."""
        return all(g == 1.0 for g in self.gains.values())


def path_loss_gain(distance: np.ndarray, exponent: float, reference: float) -> np.ndarray:
    """The amplitude gain of a link of ``distance`` metres: (d0 / max(d, d0)) ** (n / 2), the
    square root of the received power's fall by (d / d0) ** n beyond the reference distance d0
    (1 within it; n = 0: no loss)."""
    d = np.maximum(np.asarray(distance, dtype=float), reference)
    return np.asarray((reference / d) ** (exponent / 2.0))


def link_gains(
    units: Sequence[str],
    gains: Mapping[Pair, float],
    positions: Mapping[str, Sequence[float]],
    exponent: float,
    reference: float,
) -> dict[Pair, float]:
    """Every link's gain ``g[s→r]``: the given gain (1 if not given) times the path loss of
    the distance between s and r (``path_loss_gain``); only the given links without positions
    or loss. A unit hears itself at gain 1, at distance 0."""
    if not positions or exponent == 0.0:
        return dict(gains)
    xyz = np.array([positions[u] for u in units], dtype=float)
    d = np.linalg.norm(xyz[:, None, :] - xyz[None, :, :], axis=-1)
    loss = path_loss_gain(d, exponent, reference)
    return {
        (s, r): float(gains.get((s, r), 1.0) * loss[i, j])
        for i, s in enumerate(units)
        for j, r in enumerate(units)
        if i != j
    }


def noise_rng(seed: int, unit_index: int) -> np.random.Generator:
    """Unit ``unit_index``'s own noise generator in a run of ``seed``."""
    return np.random.default_rng([seed, unit_index, 1])


def heard_by(
    pulses: np.ndarray, who: np.ndarray, val: np.ndarray, gains: np.ndarray, unit_gains: bool
) -> tuple[np.ndarray, np.ndarray]:
    """The samples that carry pulses, and what each listener hears there before its noise
    (rows × listeners): each sender's magnitudes added in the order sent, times the listener's
    link gain for that sender (``gains``: listeners × senders), added in member order."""
    if not pulses.size:
        return pulses, np.zeros((0, gains.shape[0]))
    if unit_gains and (pulses.size == 1 or bool((pulses[1:] > pulses[:-1]).all())):
        # one pulse a sample: what everyone hears is that magnitude (0 + v + 0 … is v)
        return pulses, np.repeat(val[:, None], gains.shape[0], axis=1)
    rows, x = sender_columns(pulses, who, val, gains.shape[1])
    if unit_gains:
        total = across_senders(x)  # sequential: the same sum everywhere
        return rows, np.repeat(total[:, None], gains.shape[0], axis=1)
    return rows, across_senders(x[:, None, :] * gains[None, :, :])
