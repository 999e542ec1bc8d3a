"""The channel: what receiver r hears from sender s. Pure (NumPy only).

    h_r[k] = Σ_s g[s→r] · m_s[k]  +  σ · n_r[k]

``m_s[k]`` is sender s's pulses at sample k (its own pulses added in the order sent), the
senders added left to right in member order (``rgtbus.signal.pulses``: the bit-exact medium
sum); ``g[s→r]`` the link gain (1 unless ``[channel] gain`` says otherwise); ``σ`` the white
noise of ``[channel] noise``; ``n_r`` unit r's own standard normal draws, from its own seeded
generator (``noise_rng``), taken in sample order however a run is cut into steps.

A new channel effect (path loss, delay, drift, bursts) goes here, with its scenario keys in
``rgtbus/scenario/channel.py``; the ears (``rgtbus.hearing``) apply what this module says.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from rgtbus.signal.pulses import across_senders, sender_columns

Pair = tuple[str, str]


@dataclass(frozen=True)
class Channel:
    """A run's channel: ``noise`` σ and the link ``gains`` ``{(sender, receiver): g}``."""

    noise: float = 0.0
    gains: Mapping[Pair, float] = field(default_factory=dict)

    def gain_row(self, units: Sequence[str], receiver: str) -> np.ndarray:
        """``g[s→receiver]`` for every sender s, in member order."""
        return np.array([self.gains.get((s, receiver), 1.0) for s in units])

    @property
    def unit_gains(self) -> bool:
        """Every link has gain 1: every receiver hears the same medium (before its noise)."""
        return all(g == 1.0 for g in self.gains.values())


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
