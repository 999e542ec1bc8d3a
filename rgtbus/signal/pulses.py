"""Pulses on the medium, and the medium sum: the one place where transmissions add up.

A unit's transmissions are ``Pulses``: sample indexes (int64, ascending per code) and their
magnitudes (float64). What the shared medium carries at sample k is

    m[k] = Σ_u ( Σ_{pulses p of u at k, in the order u sent them} a_p )

with the inner sums per sender taken in the order sent and the outer sum over senders taken
left to right in member order. Floating-point addition is not associative, so this order is
part of the model: the event engine, the dense engine, every bus, cross-process runs and the
log verifier all add pulses through ``sender_columns`` and ``across_senders`` and agree bit for
bit. Pure: NumPy only.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

Pulses = tuple[np.ndarray, np.ndarray]  # (sample indexes int64, magnitudes float64)


def merge_pulses(parts: Sequence[Pulses]) -> Pulses:
    """Concatenate pulse lists, keeping each sample's magnitudes in arrival order."""
    if not parts:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    if len(parts) == 1:
        return parts[0]
    s = np.concatenate([p[0] for p in parts])
    v = np.concatenate([p[1] for p in parts])
    order = np.argsort(s, kind="stable")
    return s[order], v[order]


def sample_rows(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct samples in ascending order, and where each of ``samples`` is among them
    (``np.unique(..., return_inverse=True)``, without its cost: pulses come nearly sorted)."""
    s = np.asarray(samples, dtype=np.int64)
    order = None if s.size < 2 or bool((s[1:] >= s[:-1]).all()) else np.argsort(s, kind="stable")
    ordered = s if order is None else s[order]
    first = np.ones(ordered.size, dtype=bool)
    first[1:] = ordered[1:] != ordered[:-1]
    at = np.cumsum(first) - 1
    if order is not None:
        inverse = np.empty_like(at)
        inverse[order] = at
        at = inverse
    return ordered[first], at


def split_pulses(pulses: Pulses, until: int) -> tuple[Pulses, Pulses]:
    """(pulses before ``until``, the rest)."""
    s, v = pulses
    k = int(s.searchsorted(until))
    return (s[:k], v[:k]), (s[k:], v[k:])


def sender_columns(
    samples: np.ndarray, senders: np.ndarray, values: np.ndarray, n_senders: int
) -> tuple[np.ndarray, np.ndarray]:
    """The samples that carry pulses (ascending) and each sender's magnitudes there
    (rows × senders), every sender's pulses at one sample added in the order given."""
    rows, at = sample_rows(samples)
    x = np.zeros(rows.size * n_senders)
    np.add.at(x, at * n_senders + senders, values)  # unbuffered: in order, per (row, sender)
    return rows, x.reshape(rows.size, n_senders)


def across_senders(x: np.ndarray) -> np.ndarray:
    """The senders' contributions (last axis) added left to right, in member order."""
    if x.shape[-1] == 0:
        return np.zeros(x.shape[:-1])
    return np.cumsum(x, axis=-1)[..., -1]


MEDIUM_CELLS = 1 << 20  # (sample, sender) cells summed at a time: 8 MB, whatever the run


def medium_sum(parts: Sequence[Pulses]) -> Pulses:
    """What the medium carries: the non-silent samples (ascending) and their values, from
    each member's pulses in member order (see the module's equation). The samples are summed
    ``MEDIUM_CELLS`` (sample, sender) cells at a time, each exactly as a whole: the memory is
    bounded whatever the run, where a long run's medium as one samples × senders matrix is
    not."""
    if not parts:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    samples = np.concatenate([np.asarray(p[0], dtype=np.int64) for p in parts])
    values = np.concatenate([np.asarray(p[1], dtype=np.float64) for p in parts])
    senders = np.repeat(np.arange(len(parts)), [len(p[0]) for p in parts])
    n = len(parts)
    step = max(1, MEDIUM_CELLS // n)  # samples a slice
    if samples.size <= step:
        rows, x = sender_columns(samples, senders, values, n)
        return rows, across_senders(x)
    rows, at = sample_rows(samples)
    order = np.argsort(at, kind="stable")  # by sample; each sample's pulses as given
    at, senders, values = at[order], senders[order], values[order]
    out = np.empty(rows.size)
    for lo in range(0, rows.size, step):
        hi = min(lo + step, rows.size)
        a, b = at.searchsorted(lo), at.searchsorted(hi)
        x = np.zeros((hi - lo) * n)
        np.add.at(x, (at[a:b] - lo) * n + senders[a:b], values[a:b])  # as sender_columns
        out[lo:hi] = across_senders(x.reshape(hi - lo, n))
    return rows, out
