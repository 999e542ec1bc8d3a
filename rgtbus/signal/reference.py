"""The resonator model stated literally, one sample at a time, and the decoder's timing
candidates stated literally: the oracles for tests and the baselines for benchmarks (no run
uses them; runs use ``resonator.resonate`` and the compiled ``timings``).

For each resonator (A the one-sample transition of its ω and mode, see ``transition``)::

    z ← A·z                       (or, after a spike: Re(A·z) + i·reset_value)
    z ← z + i·u[k]
    spike at k  ⇔  Im z ≥ threshold
    d[k] = Im z − Im(the state before the input)
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

from rgtbus.signal.resonator import (
    PAPER_B,
    PAPER_RESET_VALUE,
    PAPER_TAU,
    PAPER_THRESHOLD,
    transition,
)
from rgtbus.timebase import sample_of


def reference_trajectory(
    omegas: Sequence[float],
    samples: np.ndarray,
    *,
    mode: str = "paper",
    tau: float = PAPER_TAU,
    b: float = PAPER_B,
    threshold: float = PAPER_THRESHOLD,
    reset_value: float = PAPER_RESET_VALUE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-sample numpy loop over every receiver × channel at once.

    ``samples``: (n,) or (n, receivers).  Returns (z, spiked, d), each (n, receivers, channels):
    pre-spike states, the spike mask and the increment readout."""
    u = np.asarray(samples, dtype=float)
    if u.ndim == 1:
        u = u[:, None]
    n, n_rec = u.shape
    A = np.array([transition(w, mode=mode, tau=tau, b=b) for w in omegas])[None, :]
    z = np.zeros((n_rec, len(omegas)), dtype=complex)
    pend = np.zeros(z.shape, dtype=bool)
    zs = np.empty((n, *z.shape), dtype=complex)
    spk = np.empty((n, *z.shape), dtype=bool)
    ds = np.empty((n, *z.shape))
    for k in range(n):
        z = A * z
        z = np.where(pend, z.real + 1j * reset_value, z)
        before = z.imag
        z = z + 1j * u[k][:, None]
        pend = z.imag >= threshold
        zs[k], spk[k], ds[k] = z, pend, z.imag - before
    return zs, spk, ds


def simulate_python(
    omegas: Sequence[float],
    samples: Sequence[float],
    *,
    mode: str = "paper",
    tau: float = PAPER_TAU,
    b: float = PAPER_B,
    threshold: float = PAPER_THRESHOLD,
    reset_value: float = PAPER_RESET_VALUE,
) -> list[list[int]]:
    """Pure-Python per-sample loop (one receiver): spike sample indices per channel."""
    out: list[list[int]] = []
    us = [float(v) for v in samples]
    for w in omegas:
        a = transition(w, mode=mode, tau=tau, b=b)
        z = 0j
        pend = False
        hits: list[int] = []
        for k, v in enumerate(us):
            z = a * z
            if pend:
                z = complex(z.real, reset_value)
            z = complex(z.real, z.imag + v)
            pend = z.imag >= threshold
            if pend:
                hits.append(k)
        out.append(hits)
    return out


def reference_timings(
    omega: float, start: float, pulses: int, tau: float, search: int
) -> list[tuple[int, tuple[int, ...]]]:
    """Every distinct pulse-instant tuple of a code on ω starting within ± ``search`` samples
    of ``start``, as (shift, instants), nearest shift first (then the earlier): instant j of a
    start t is ``round((t + j·T)/τ)``, which changes only where (t + j·T)/τ crosses h + ½, so
    the tuples are those of ``start`` and of the midpoints between consecutive crossings."""
    period = 2 * math.pi / omega
    jts = [j * period for j in range(pulses)]
    t_lo, t_hi = start - search * tau, start + search * tau
    cuts = [t_lo, t_hi]
    for jt in jts:
        for h in range(math.floor((t_lo + jt) / tau - 0.5), math.ceil((t_hi + jt) / tau - 0.5) + 1):
            t = (h + 0.5) * tau - jt
            if t_lo < t < t_hi:
                cuts.append(t)
    cuts.sort()
    probes = sorted([start, *((a + b) / 2 for a, b in itertools.pairwise(cuts))])
    s0 = sample_of(start, tau)
    out: list[tuple[int, tuple[int, ...]]] = []
    prev: tuple[int, ...] | None = None
    for t in probes:
        if t < 0:
            continue
        inst = tuple(sample_of(t + jt, tau) for jt in jts)
        if inst != prev:
            out.append((inst[0] - s0, inst))
            prev = inst
    out.sort(key=lambda p: (abs(p[0]), p[0]))
    return out
