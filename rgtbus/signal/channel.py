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
With ``[channel.burst]`` the noise comes in bursts too (a Gilbert–Elliott channel): each
receiver is calm (σ) or in a burst (σ_b) at every sample, a two-state Markov chain of its own
(``BurstStates``, its own generator ``burst_rng``) that enters a burst with probability
τ / ``every`` a sample and leaves it with τ / ``length``, so bursts last ``length`` seconds
and come ``every`` seconds apart on average.

Propagation and clocks (``[channel] speed``, ``[channel.clock] offset`` and ``drift``): every
unit samples on its own clock, its sample k taken at true time ``o_u + k·τ·(1 + ε_u)`` (offset
o_u seconds, drift ε_u = ppm·10⁻⁶), and a pulse takes ``d(s, r) / speed`` seconds from s to r.
So a pulse s sends at its sample j reaches r at r's fractional sample

    x = a + b·j,  a = (o_s + d(s, r)/speed − o_r) / (τ·(1 + ε_r)),  b = (1 + ε_s)/(1 + ε_r)

(``arrivals``), and is rendered there as a first-order fractional delay (``render``): (1 − f)
of it on sample ⌊x⌋ and f on the next, f = x − ⌊x⌋; the two add up to the pulse and their
centre is x. A receiver then reads a code's value at an instant k as the sum of samples k and
k + 1 (``ReadoutHistory`` with a window of 2): exact wherever the pulse lands in [k, k + 2),
at √2 the noise. Without speed and clocks, a = 0 and b = 1: every pulse lands on its sample,
reads take one sample, and nothing changes.

Fading (``[channel] fading = "rayleigh"``): every link is faded, once a run (slow fading: the
run is shorter than the links' coherence time), by an amplitude drawn for it

    g[s→r] ← g[s→r] · |h_sr|,   |h_sr| = √((x² + y²) / 2),   x, y ~ N(0, 1)

a Rayleigh amplitude with E|h|² = 1 (no power lost on average; deep fades where the paths
cancel), the senders' amplitudes drawn in member order from receiver r's own generator
(``fading_rng``): independent per directed link, the same however the run is split. A unit
hears itself unfaded (``fading_amplitudes``).

A new channel effect (path loss, delay, drift, bursts, fading) goes here, with its scenario keys in
``rgtbus/scenario/channel.py``; the ears (``rgtbus.engine.hearing``) apply what this module says.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from rgtbus.signal.pulses import across_senders, sender_columns

Pair = tuple[str, str]


FREE_SPACE = 2.0  # the path-loss exponent of free space


@dataclass(frozen=True)
class Burst:
    """Impulsive noise: bursts of white noise ``noise`` σ_b lasting ``length`` seconds on
    average, ``every`` seconds apart on average (from one's end to the next one's start)."""

    noise: float
    every: float
    length: float

    def probabilities(self, tau: float) -> tuple[float, float]:
        """(enter, leave): the chance a sample of ``tau`` seconds starts or ends a burst."""
        return min(1.0, tau / self.every), min(1.0, tau / self.length)


class BurstStates:
    """One receiver's Gilbert–Elliott chain: calm from sample 0, then alternately in a burst
    and calm for geometric numbers of samples (P(enter) and P(leave) a sample:
    ``Burst.probabilities``), drawn from its own generator one stay at a time as far as asked,
    so the same samples are in bursts however a run asks for them."""

    def __init__(self, burst: Burst, tau: float, rng: np.random.Generator) -> None:
        self.burst = burst
        self.rng = rng
        self._p = burst.probabilities(tau)
        self._changes: list[int] = []  # samples where the state flips, ascending
        self._drawn_to = 0  # the last change drawn (or 0)
        self._flips_before = 0  # changes dropped as passed: their parity is the state's

    def in_burst(self, lo: int, hi: int) -> np.ndarray:
        """Whether each sample of [lo, hi) is in a burst (lo never before an earlier call's)."""
        while self._drawn_to < hi:  # draw stays until one ends at or beyond hi
            bursting = (self._flips_before + len(self._changes)) % 2 == 1
            stay = int(self.rng.geometric(self._p[1] if bursting else self._p[0]))
            self._drawn_to += stay
            self._changes.append(self._drawn_to)
        passed = 0
        while passed < len(self._changes) and self._changes[passed] <= lo:
            passed += 1
        if passed:  # changes at or before lo no longer matter but for the parity
            self._flips_before += passed
            del self._changes[:passed]
        k = np.arange(lo, hi, dtype=np.int64)
        flips = self._flips_before + np.searchsorted(
            np.asarray(self._changes, dtype=np.int64), k, side="right"
        )
        return np.asarray(flips % 2 == 1)

    def sigma(self, lo: int, hi: int, calm: float) -> np.ndarray:
        """Each sample's noise σ in [lo, hi): ``calm``, or the burst's within a burst."""
        return np.where(self.in_burst(lo, hi), self.burst.noise, calm)


@dataclass(frozen=True)
class Clock:
    """A unit's sampling clock: its sample k is taken at true time ``offset + k·τ·(1 +
    drift·10⁻⁶)`` (offset in seconds, drift in parts per million)."""

    offset: float = 0.0
    drift: float = 0.0

    @property
    def rate(self) -> float:
        """The clock's rate against true time, 1 + drift·10⁻⁶."""
        return 1.0 + self.drift * 1e-6


PERFECT = Clock()


@dataclass(frozen=True)
class Channel:
    """A run's channel: ``noise`` σ and the link ``gains`` ``{(sender, receiver): g}`` each
    receiver applies (path loss included: ``link_gains``); the ``positions`` (metres, x y z)
    and path-loss ``path_loss`` exponent and ``reference_distance`` they came from, if any;
    the ``speed`` of propagation (m/s; None: instant) and each unit's ``clocks``."""

    noise: float = 0.0
    gains: Mapping[Pair, float] = field(default_factory=dict)
    positions: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)
    path_loss: float = 0.0
    reference_distance: float = 1.0
    burst: Burst | None = None  # bursts of noise on top of ``noise`` (None: none)
    speed: float | None = None
    clocks: Mapping[str, Clock] = field(default_factory=dict)
    fading: str = "none"  # "rayleigh": each link faded once a run (``fading_amplitudes``)

    @property
    def timed(self) -> bool:
        """Whether pulses land off their samples (a propagation speed, or a clock that is not
        the run's): reads then take two samples (module docstring)."""
        return self.speed is not None or any(c != PERFECT for c in self.clocks.values())

    def delay(self, s: str, r: str) -> float:
        """Seconds a pulse takes from s to r (0 without a speed)."""
        return 0.0 if self.speed is None else self.distance(s, r) / self.speed

    def arrivals(self, units: Sequence[str], receiver: str, tau: float) -> np.ndarray:
        """``(a, b)`` for every sender s, in member order: s's sample j reaches ``receiver``
        at its fractional sample ``a + b·j`` (module docstring). Shape (2, senders)."""
        r = self.clocks.get(receiver, PERFECT)
        out = np.zeros((2, len(units)))
        for n, u in enumerate(units):
            s = self.clocks.get(u, PERFECT)
            out[0, n] = (s.offset + self.delay(u, receiver) - r.offset) / (tau * r.rate)
            out[1, n] = s.rate / r.rate
        return out

    @property
    def noisy(self) -> bool:
        """Whether a receiver hears any noise (white, or in bursts)."""
        return self.noise > 0 or self.burst is not None

    @cached_property
    def alike(self) -> bool:
        """Whether every receiver hears the medium alike: no noise, every link gain 1, no delay
        and no clock of its own (what a run's cost depends on: ``limits.run_estimate``). Worked
        out once: every unit of a run asks, and the gains are n² entries."""
        return not self.noisy and not self.timed and self.unit_gains

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
        """Every link has gain 1 (and none fades): every receiver hears the same medium
        (before its noise)."""
        return self.fading == "none" and all(g == 1.0 for g in self.gains.values())


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


def burst_rng(seed: int, unit_index: int) -> np.random.Generator:
    """Unit ``unit_index``'s own generator of burst states (``BurstStates``): apart from its
    noise's, so bursts change no draw of the calm noise."""
    return np.random.default_rng([seed, unit_index, 2])


def fading_rng(seed: int, unit_index: int) -> np.random.Generator:
    """Receiver ``unit_index``'s own generator of its links' fading (``fading_amplitudes``):
    apart from its noise's and its bursts', so fading changes no draw of either."""
    return np.random.default_rng([seed, unit_index, 3])


FADINGS = ("none", "rayleigh")


def fading_amplitudes(fading: str, seed: int, receiver: int, senders: int) -> np.ndarray:
    """The amplitude |h_sr| each of ``senders`` links into receiver ``receiver`` (its index in
    member order) is faded by in a run of ``seed`` (module docstring): Rayleigh,
    √((x² + y²) / 2) with x, y standard normal from ``fading_rng``, 1 on its own link; all
    ones without fading."""
    out = np.ones(senders)
    if fading == "rayleigh":
        xy = fading_rng(seed, receiver).standard_normal((2, senders))
        out = np.sqrt((xy[0] ** 2 + xy[1] ** 2) / 2.0)
        out[receiver] = 1.0
    elif fading != "none":
        raise ValueError(f"unknown fading {fading!r} ({', '.join(FADINGS)})")
    return out


def render(
    samples: np.ndarray, values: np.ndarray, a: float, b: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pulses a sender put at its ``samples`` as one receiver gets them, at fractional samples
    ``x = a + b·j``: (1 − f)·value on ⌊x⌋ and f·value on ⌊x⌋ + 1 (f = x − ⌊x⌋; a share of 0 is
    left out). Returns (rows, values), rows ascending (stable: a sample's pulses in order)."""
    if a == 0.0 and b == 1.0:  # on its samples: nothing to spread
        return samples, values
    x = a + b * samples.astype(np.float64)
    k = np.floor(x)
    f = x - k
    rows = np.concatenate([k, k + 1]).astype(np.int64)
    vals = np.concatenate([values * (1.0 - f), values * f])
    keep = np.concatenate([f < 1.0, f > 0.0])
    rows, vals = rows[keep], vals[keep]
    order = np.argsort(rows, kind="stable")
    return rows[order], vals[order]


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
