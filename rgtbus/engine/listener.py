"""One unit's share of the ears (``Listener``): its link gains, its noise, its readout history,
where its spikes and traces go, and what it asked the ears for; and what a wake tells it
(``Heard``).

The engine makes each receiver's view of the medium from the run's channel (``Reception``):
gains, noise and its generator, bursts, arrivals. The unit supplies only what is its own
(``OwnHearing``: how much readout it keeps, where its traces and spikes go, whether its plans
wait for a spike). A new channel effect is then ``rgtbus/signal/channel.py``, its keys in
``rgtbus/scenario/channel.py`` and its share of a receiver here.

A receiver's noise is white, ``n_k ~ N(0, σ²)`` (or ``σ_b(k)·z_k`` inside a burst), drawn in
sample order from the unit's own seeded generator: the same numbers however the run is cut.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from rgtbus.errors import BadInput
from rgtbus.signal.channel import BurstStates, Channel, burst_rng, fading_amplitudes, noise_rng

if TYPE_CHECKING:
    from rgtbus.engine.spike_log import SpikeLog

TraceSink = Callable[[int, np.ndarray, np.ndarray], None]  # (first sample, x (n, C), y (n, C))


class Heard(NamedTuple):
    """What woke a unit: ``spikes`` of its resonators since it last woke, in order, as
    (sample, channel indexes); ``reached``: its boundary (else: its watched spike, the last).
    A plain tuple: one is made at every wake of every unit."""

    spikes: tuple[tuple[int, tuple[int, ...]], ...]
    reached: bool


HEARD_NOTHING = Heard((), True)  # a unit woken at its boundary that heard no spike
Wake = Callable[[Heard], None]  # a unit's handler: what it heard, then it asks again or stops


@dataclass
class Listener:
    """One unit's share of the ears."""

    name: str
    gains: np.ndarray  # gain of each sender's signal at this unit, in member order
    noise: float  # σ of the white noise this unit's receiver adds to every sample
    rng: np.random.Generator | None  # its noise's generator (None: a receiver with no noise)
    keep: int  # samples of readout history the unit decodes from
    trace: TraceSink | None = None
    spike_log: SpikeLog | None = None  # where its every spike goes as it is heard (a log)
    # whether its plans can wait for a spike (an ID spike, under anchor "spike"): when no
    # unit's can and none logs or traces its spikes, the event engine's ears never walk the
    # resonators (the readout a decode needs is the input itself)
    awaits: bool = True
    active: bool = True
    request: tuple[int, int, Wake] | None = None  # (boundary, at, what to call)
    watch: int | None = None  # the channel whose spike could change this unit's plans
    watch_from: int = 0  # ... from this sample on (earlier spikes there change nothing)
    heard: list[tuple[int, tuple[int, ...]]] = field(default_factory=list)  # not yet told
    bursts: BurstStates | None = None  # when its noise comes in bursts (σ_b, not ``noise``)
    # where each sender's sample j lands in its own samples, a + b·j (rows a, b; None: on j):
    # delays and clocks (``Channel.arrivals``)
    arrival: np.ndarray | None = None
    _noise: np.ndarray = field(default_factory=lambda: np.zeros(0))
    _noise_at: int = 0  # sample of _noise[0]

    @property
    def noisy(self) -> bool:
        """Whether this receiver hears any noise (white, or in bursts)."""
        return self.noise > 0 or self.bursts is not None

    def noise_for(self, lo: int, hi: int) -> np.ndarray:
        """This unit's noise for samples [lo, hi), drawn in order from its own generator (the
        same numbers however the stretch is cut)."""
        have = self._noise_at + self._noise.size
        if lo < self._noise_at:
            raise BadInput(f"{self.name}: noise for sample {lo} was already used")
        if hi > have:
            assert self.rng is not None, f"{self.name}: noise {self.noise} with no generator"
            if self.bursts is None:
                more = self.rng.normal(0.0, self.noise, hi - have)
            else:  # the same draws, each times its sample's σ (normal(0, σ) is σ·z)
                more = self.rng.standard_normal(hi - have) * self.bursts.sigma(have, hi, self.noise)
            self._noise = np.concatenate([self._noise[lo - self._noise_at :], more])
            self._noise_at = lo
        out = self._noise[lo - self._noise_at : hi - self._noise_at]
        return out

    def used_noise(self, upto: int) -> None:
        """The noise before sample ``upto`` has been heard: it is let go."""
        if upto > self._noise_at:
            cut = min(upto - self._noise_at, self._noise.size)
            self._noise = self._noise[cut:]
            self._noise_at += cut


class OwnHearing(NamedTuple):
    """What a unit supplies of its receiver, all of it its own: the samples of readout history
    it decodes from (``keep``), where its traces and its every spike go (None: nowhere), and
    whether its plans can wait for a spike (``Listener.awaits``)."""

    keep: int
    trace: TraceSink | None = None
    spike_log: SpikeLog | None = None
    awaits: bool = True


@dataclass(frozen=True)
class Reception:
    """How the receivers of a run hear the medium, made from its ``channel`` (units in member
    order, the run's ``seed`` and sample period ``tau``): receiver r's link gains ``g[s→r]``
    for every sender s, faded (``fading_amplitudes``); its noise σ (``noise_rng(seed, r)``;
    no generator for a noise-free receiver, which never draws); its bursts
    (``burst_rng(seed, r)``); where each sender's samples land on its own
    (``Channel.arrivals``, for a timed channel). The equations: ``rgtbus.signal.channel``."""

    channel: Channel
    units: tuple[str, ...]
    seed: int
    tau: float

    @cached_property
    def _index(self) -> dict[str, int]:
        return {u: i for i, u in enumerate(self.units)}

    def listener(self, name: str, own: OwnHearing) -> Listener:
        """Unit ``name``'s receiver: its view of the medium, and what it supplies (``own``)."""
        ch, me = self.channel, self._index[name]
        return Listener(
            name=name,
            gains=ch.gain_row(self.units, name)
            * fading_amplitudes(ch.fading, self.seed, me, len(self.units)),
            noise=ch.noise,
            rng=noise_rng(self.seed, me) if ch.noisy else None,
            bursts=None
            if ch.burst is None
            else BurstStates(ch.burst, self.tau, burst_rng(self.seed, me)),
            keep=own.keep,
            arrival=ch.arrivals(self.units, name, self.tau) if ch.timed else None,
            trace=own.trace,
            spike_log=own.spike_log,
            awaits=own.awaits,
        )

    def set_noise(self, lst: Listener, sigma: float) -> None:
        """A steered run's noise (``rgtbus.steering``): ``lst`` hears white noise of σ =
        ``sigma`` from the next sample it draws (its own generator, made now if it had none:
        a receiver that was noise-free starts its draws here)."""
        lst.noise = sigma
        if sigma > 0 and lst.rng is None:
            lst.rng = noise_rng(self.seed, self._index[lst.name])

    def set_gain(self, lst: Listener, sender: str, gain: float) -> None:
        """A steered run's link gain: ``sender`` reaches ``lst`` with ``gain`` (faded as the
        run's links are) from the next sample it hears. A new array: whoever was told the old
        gains keeps them."""
        s = self._index[sender]
        me = self._index[lst.name]
        faded = fading_amplitudes(self.channel.fading, self.seed, me, len(self.units))
        gains = lst.gains.copy()
        gains[s] = gain * faded[s]
        lst.gains = gains
