"""Every resonator spike of a log as columns (``SpikeTable``), read from its ``/rx/spike``
records of any form a block at a time into columns allocated once (``spike_table``): a large
run's receivers fire tens of millions of times, and no spike is a Python object."""

from __future__ import annotations

import math
from collections.abc import Container, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rgtbus.errors import BadLog
from rgtbus.telemetry.record_rows import spike_samples, spike_units
from rgtbus.telemetry.records import RX_SPIKE
from rgtbus.timebase import seconds, time_of

_NANOSECOND = seconds(1)


@dataclass(frozen=True)
class SpikeTable:
    """Every resonator spike of a log as columns, one entry a spike (a large run's receivers
    fire tens of millions of times: no object a spike). ``unit`` and ``channel`` index
    ``units`` and ``channels``; ``omega`` is NaN where the log names no frequency. In sample
    order (stable: as logged within a sample)."""

    units: list[str]
    channels: list[str]
    unit: np.ndarray  # int32
    channel: np.ndarray  # int32
    sample: np.ndarray  # int64
    t: np.ndarray  # float64, seconds
    omega: np.ndarray  # float64

    def __len__(self) -> int:
        return len(self.sample)

    def __iter__(self) -> Iterator[dict[str, Any]]:
        """The spikes one dict each (``rows``)."""
        return self.rows()

    def within(self, span: tuple[float | None, float | None] | None) -> np.ndarray:
        """A mask of the spikes within ``span`` (from, to in seconds; None: unbounded), to a
        nanosecond (as ``in_span``)."""
        keep = np.ones(len(self), dtype=bool)
        if span is not None:
            lo, hi = span
            if lo is not None:
                keep &= self.t >= lo - _NANOSECOND
            if hi is not None:
                keep &= self.t <= hi + _NANOSECOND
        return keep

    def of_unit(self, unit: str) -> dict[str, np.ndarray]:
        """``unit``'s spike times (seconds, in order) on each channel that fired."""
        if unit not in self.units:
            return {}
        mine = self.unit == self.units.index(unit)
        ch, t = self.channel[mine], self.t[mine]
        return {self.channels[c]: t[ch == c] for c in np.unique(ch).tolist()}

    def rows(self, keep: np.ndarray | None = None) -> Iterator[dict[str, Any]]:
        """The spikes (those ``keep`` marks) one dict each: ``{unit, channel, omega, t,
        sample}`` (``omega`` None where unknown)."""
        idx = np.arange(len(self)) if keep is None else np.flatnonzero(keep)
        units, channels = self.units, self.channels
        for i in idx.tolist():
            om = float(self.omega[i])
            yield {
                "unit": units[int(self.unit[i])],
                "channel": channels[int(self.channel[i])],
                "omega": None if math.isnan(om) else om,
                "t": float(self.t[i]),
                "sample": int(self.sample[i]),
            }


_SpikeRow = tuple[str, str, float | None, float, int]  # unit, channel, omega, t, sample


class _SpikeColumns:
    """``spike_table``'s columns, allocated once at their full length and filled a record at a
    time (no part a record kept and joined after: a large run fires tens of millions of
    times, and the parts' memory would stay with the process)."""

    def __init__(self, units: Sequence[str], frequencies: dict[str, float], n: int) -> None:
        self.units: dict[str, int] = {u: i for i, u in enumerate(units)}
        self.channels: dict[str, int] = {}
        self.frequencies = frequencies
        self.unit = np.empty(n, dtype=np.int32)
        self.channel = np.empty(n, dtype=np.int32)
        self.sample = np.empty(n, dtype=np.int64)
        self.t = np.empty(n)
        self.omega = np.empty(n)
        self.at = 0

    def unit_index(self, name: str) -> int:
        return self.units.setdefault(name, len(self.units))

    def channel_index(self, name: str) -> int:
        return self.channels.setdefault(name, len(self.channels))

    def omega_of(self, names: Iterable[str]) -> np.ndarray:
        return np.array([self.frequencies.get(n, math.nan) for n in names], dtype=float)

    def add(self, unit: np.ndarray, channel: np.ndarray, sample: np.ndarray, t: np.ndarray,
            omega: np.ndarray) -> None:  # fmt: skip
        at, k = self.at, len(sample)
        self.unit[at : at + k] = unit
        self.channel[at : at + k] = channel
        self.sample[at : at + k] = sample
        self.t[at : at + k] = t
        self.omega[at : at + k] = omega
        self.at += k

    def block(
        self, m: Mapping[str, Any], tau: float | None, only: Container[str] | None = None
    ) -> None:
        """A block of spikes as columns (``records.spikes``): each of its units heard them
        all (those of ``only``, when given); rows of a sample go unit by unit, channels in
        the order logged."""
        units = [self.unit_index(u) for u in spike_units(m) if only is None or u in only]
        names = [str(n) for n in m["names"]]
        samples = np.asarray(m["samples"], dtype=np.int64)
        channel = np.asarray(m["channel"], dtype=np.int64)
        if samples.ndim != 1 or channel.shape != samples.shape:
            raise BadLog(
                f"{RX_SPIKE} at sample {m.get('sample')}: {samples.size} samples but "
                f"{channel.size} channels"
            )
        outside = (channel < 0) | (channel >= len(names))
        if outside.any():
            i = int(np.argmax(outside))
            raise BadLog(
                f"{RX_SPIKE} at sample {int(samples[i])}: channel {int(channel[i])} is not one "
                f"of its {len(names)} names"
            )
        k0, t0 = int(m["sample"]), float(m["t"])
        step = tau if tau is not None else (t0 / k0 if k0 else 0.0)
        times = samples * step
        times[samples == k0] = t0
        glob = np.array([self.channel_index(n) for n in names], dtype=np.int32)
        omega = self.omega_of(names)
        p, n_units = samples.size, len(units)
        # order: sample group, then unit, then the spike's place in the block
        group = np.concatenate(([0], np.cumsum(samples[1:] != samples[:-1]))) if p else samples
        spike = np.tile(np.arange(p), n_units)
        who = np.repeat(np.arange(n_units), p)
        order = np.lexsort((spike, who, group[spike]))
        spike, who = spike[order], who[order]
        self.add(np.asarray(units, dtype=np.int32)[who], glob[channel[spike]], samples[spike],
                 times[spike], omega[channel[spike]])  # fmt: skip

    def rows(self, rows: list[_SpikeRow]) -> None:
        """Spikes one row each (logs before the columnar block)."""
        if not rows:
            return
        unit, channel, omega, t, sample = zip(*rows, strict=True)
        self.add(
            np.array([self.unit_index(u) for u in unit], dtype=np.int32),
            np.array([self.channel_index(c) for c in channel], dtype=np.int32),
            np.array(sample, dtype=np.int64),
            np.array(t, dtype=float),
            np.array([math.nan if o is None else o for o in omega], dtype=float),
        )

    def table(self) -> SpikeTable:
        cols: list[np.ndarray] = [self.unit, self.channel, self.sample, self.t, self.omega]
        for name in ("unit", "channel", "sample", "t", "omega"):  # let go of them here
            setattr(self, name, np.empty(0))
        sample = cols[2]
        if sample.size > 1 and not (sample[1:] >= sample[:-1]).all():
            order = np.argsort(sample, kind="stable")  # in time order, however they were written
            for i, c in enumerate(cols):  # a column at a time: one copy held, not five
                cols[i] = c[order]
                del c
        unit, channel, sample, t, omega = cols
        return SpikeTable(list(self.units), list(self.channels), unit, channel, sample, t, omega)


def _old_spike_rows(
    m: Mapping[str, Any], frequencies: dict[str, float], tau: float | None
) -> list[_SpikeRow]:
    """A ``/rx/spike`` record of a log from before the columnar block, one row a spike: a
    block of per-sample lists of names, one record a sample, or one spike with its ω."""
    rows: list[_SpikeRow] = []
    if "samples" in m:
        names, k0, t0 = spike_units(m), m["sample"], m["t"]
        step = tau if tau is not None else (t0 / k0 if k0 else 0.0)
        for k, chans in spike_samples(m):
            t = time_of(k, step) if k != k0 else t0
            for unit in names:  # a shared record: each unit heard the same spikes
                rows += [(unit, ch, frequencies.get(ch), t, k) for ch in chans]
    elif "channels" not in m:
        rows.append((m["unit"], m["channel"], m.get("omega"), m["t"], m["sample"]))
    else:
        unit, t, k = m["unit"], m["t"], m["sample"]
        rows += [(unit, ch, frequencies.get(ch), t, k) for ch in m["channels"]]
    return rows


def spike_table(
    records: Iterable[dict[str, Any]],
    frequencies: dict[str, float],
    tau: float | None = None,
    units: Sequence[str] = (),
    only: Container[str] | None = None,
) -> SpikeTable:
    """Every resonator spike of ``/rx/spike`` records as columns (``SpikeTable``): a unit's
    spikes of one block as columns (``records.spikes``); ω comes from the log's frequencies.
    Older logs hold a block as per-sample lists of names, or one record a sample (``channels``
    a list of names), or one spike a record (with its ω); all still read. ``tau``: the sample
    period (else each spike's time is worked out from the record's first). ``units``: the
    run's units, in order (units the records name beyond them follow). ``only``: those
    units' spikes alone (a record many units share is one row a unit and spike: a 100-unit
    run's are 14.8 GB as one table, a unit's 1 %)."""
    # first how many rows there are (the columns are allocated once), then the rows
    parts: list[Mapping[str, Any] | list[_SpikeRow]] = []
    n = 0
    for m in records:
        if "samples" in m and "names" in m:
            whose = [u for u in spike_units(m) if only is None or u in only]
            if whose:
                parts.append(m)
                n += len(m["samples"]) * len(whose)
        else:
            rows = [r for r in _old_spike_rows(m, frequencies, tau) if only is None or r[0] in only]
            parts.append(rows)
            n += len(rows)
    cols = _SpikeColumns(units, frequencies, n)
    for part in parts:
        if isinstance(part, list):
            cols.rows(part)
        else:
            cols.block(part, tau, only)
    return cols.table()
