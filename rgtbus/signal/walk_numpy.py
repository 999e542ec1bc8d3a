"""The receiver's compiled loops (``_walk.pyx``) in NumPy: the resonator walk, the decoder's
nearest-word score, its timing candidates and the readout at chosen samples.

The twin of the compiled module, used where it is missing (an sdist installed without a C
compiler; ``RGTBUS_WALK=numpy`` asks for it anyway): the same rules, and every product and sum
rounded as the compiled code rounds it, in the same order, so the same bits (a test runs every
shipped scenario both ways and compares every logged message). The rules are stated in
``rgtbus.signal.resonator`` and ``_walk.pyx``; in brief, in an epoch's rotating frame
(m = k mod R, P[m] = A^m, Q[m] = A^-m)::

    enter k:  at an epoch's start  w ← P[R]·w                     (re-anchor)
              after a spike at k−1 w ← Q[m]·(Re(A·z[k−1]) + i·rv) (reset)
    input:    w ← w + i·u[k]·Q[m]
    state:    z[k] = P[m]·w;  spike at k  ⇔  Im z[k] ≥ thr

Between two changes of w (an input, a reset, an epoch's start) z is P[m]·w for a constant w, so
the twin computes such a stretch as arrays, one element a sample, and a resonator whose |z|²
is below ``thr2`` there (it decays: |A| < 1) skips to its next input as the compiled walk does.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np


class WalkModel:
    """What every walk of a bank uses and nothing changes (see ``_walk.WalkModel``)."""

    __slots__ = ("Ai", "Ar", "Pi", "Pr", "Qr", "R", "lane_ch", "lane_rec", "nQi", "rv",
                 "stable", "thr", "thr2")  # fmt: skip

    def __init__(
        self,
        Pr: np.ndarray,
        Pi: np.ndarray,
        Qr: np.ndarray,
        nQi: np.ndarray,
        Ar: np.ndarray,
        Ai: np.ndarray,
        R: int,
        lane_ch: np.ndarray,
        lane_rec: np.ndarray,
        thr: float,
        thr2: float,
        rv: float,
        stable: bool,
    ) -> None:
        self.Pr, self.Pi, self.Qr, self.nQi = Pr, Pi, Qr, nQi
        self.Ar, self.Ai, self.R = Ar, Ai, int(R)
        self.lane_ch, self.lane_rec = lane_ch, lane_rec
        self.thr, self.thr2, self.rv, self.stable = float(thr), float(thr2), float(rv), bool(stable)


def _times_p(M: WalkModel, m: int, ch: int, wr: float, wi: float) -> tuple[float, float]:
    """P[m]·w on channel ``ch``."""
    pr, pi = float(M.Pr[m, ch]), float(M.Pi[m, ch])
    return pr * wr - pi * wi, pr * wi + pi * wr


def _walk(
    M: WalkModel, ch: int, rec: int, wr: float, wi: float, pend: bool, start: int, end: int,
    rows: np.ndarray, vals: np.ndarray, stop_first: bool, rec_xy: Any, lane: int,
    sp_k: np.ndarray, sp_l: np.ndarray, n_sp: int,
) -> tuple[float, float, bool, int, int, bool]:  # fmt: skip
    """One resonator from ``start`` to ``end`` (``_walk.walk``): returns (w_r, w_i, pend,
    next sample, spike count, overflowed)."""
    R, thr, thr2 = M.R, M.thr, M.thr2
    ar, ai = float(M.Ar[ch]), float(M.Ai[ch])
    Pr, Pi = M.Pr[:, ch], M.Pi[:, ch]
    cap = sp_k.shape[0]
    E = rows.shape[0]
    j = int(np.searchsorted(rows, start, side="left"))
    k = start
    skip = M.stable and rec_xy is None
    while k < end:
        m = k % R
        if pend:  # reset from the pre-spike state of k−1, in its own frame
            zr, zi = _times_p(M, (k - 1) % R, ch, wr, wi)
            xr = ar * zr - ai * zi
            qr, nqi = float(M.Qr[m, ch]), float(M.nQi[m, ch])
            wr, wi = qr * xr + nqi * M.rv, qr * M.rv - nqi * xr
            pend = False
        elif m == 0 and k > 0:
            wr, wi = _times_p(M, R, ch, wr, wi)
        if j < E and rows[j] == k:
            u = float(vals[j, rec])
            wr = wr + u * float(M.nQi[m, ch])
            wi = wi + u * float(M.Qr[m, ch])
            j += 1
        # the stretch over which w stays as it is: to the next input, the epoch's end or end
        nxt = int(rows[j]) if j < E else end
        stop = min(nxt if nxt > k else k + 1, end, k - m + R)
        ms = np.arange(m, m + stop - k)
        zr_s = Pr[ms] * wr - Pi[ms] * wi
        zi_s = Pr[ms] * wi + Pi[ms] * wr
        hit = np.flatnonzero(zi_s >= thr)
        last = int(hit[0]) if hit.size else stop - k - 1  # the stretch's last sample walked
        if rec_xy is not None:
            xs, ys, _, col = rec_xy
            xs[k - start : k - start + last + 1, col] = zr_s[: last + 1]
            ys[k - start : k - start + last + 1, col] = zi_s[: last + 1]
        if hit.size:
            k += last
            if n_sp >= cap:
                return wr, wi, pend, k, n_sp, True
            sp_k[n_sp] = k
            sp_l[n_sp] = lane
            n_sp += 1
            pend = True
            if rec_xy is not None:
                rec_xy[2][k - start, rec_xy[3]] = 1
            if stop_first:
                return wr, wi, pend, k + 1, n_sp, False
            k += 1
            continue
        # no spike in the stretch; a resonator below the hot bound stays below it until its
        # next input (|z| decays), so it is carried there, re-anchored at each epoch start
        cold = zr_s * zr_s + zi_s * zi_s < thr2
        k = stop
        if skip and cold.size and bool(cold[-1]) and k < nxt:
            target = min(nxt, end)
            b = ((k + R - 1) // R) * R
            while b < target:
                if b > 0:
                    wr, wi = _times_p(M, R, ch, wr, wi)
                b += R
            k = target
    return wr, wi, pend, end, n_sp, False


def walk_lanes(
    model: WalkModel,
    lanes: np.ndarray,
    wr: np.ndarray,
    wi: np.ndarray,
    pend: np.ndarray,
    start: int,
    end: int,
    rows: np.ndarray,
    vals: np.ndarray,
    stop_first: bool,
    spikes: np.ndarray,
    trajectory: np.ndarray | None = None,
    spiked: np.ndarray | None = None,
) -> tuple[int, int, bool]:
    """``_walk.walk_lanes``: each of ``lanes`` from ``start`` to ``end``; returns (stop,
    spikes, overflow)."""
    n_sp, first, found = 0, end, 0
    n_new, over = 0, False
    sp_k, sp_l = spikes[0], spikes[1]
    for lane in (int(x) for x in lanes):
        c = int(model.lane_ch[lane])
        rec_xy = None if trajectory is None else (trajectory[0], trajectory[1], spiked, lane)
        w_r, w_i, p, at, n_new, over = _walk(
            model, c, int(model.lane_rec[lane]), float(wr[lane]), float(wi[lane]),
            bool(pend[lane]), start, first, rows, vals, stop_first, rec_xy, lane, sp_k, sp_l,
            n_sp,
        )  # fmt: skip
        if over:
            break
        if stop_first:
            if n_new > n_sp:
                first = at
                found = 1
                n_sp = 0
        else:
            n_sp = n_new
            wr[lane] = w_r
            wi[lane] = w_i
            pend[lane] = p
    if over:
        return first, n_new, True
    if stop_first:
        return first, found, False
    return first, n_sp, False


def _sum_squares(diff: np.ndarray) -> np.ndarray:
    """Σ_k diff[..., k]², summed in k's order, as the compiled loop sums it."""
    acc = np.zeros(diff.shape[:-1])
    for k in range(diff.shape[-1]):
        acc = acc + diff[..., k] * diff[..., k]
    return acc


def _best(d: np.ndarray, rank: np.ndarray) -> tuple[int, int, float]:
    """The row and word of the least of the distances ``d`` (M, W), as the compiled scans
    find it (ties: the first row, then the lowest ``rank``), and that distance; every distance
    inf or nan: row 0, word 0, inf, as the compiled scan keeps them."""
    best_d = float(d.min())
    if not best_d < math.inf:
        return 0, 0, math.inf
    best_m = int(np.flatnonzero((d == best_d).any(axis=1))[0])
    ties = np.flatnonzero(d[best_m] == best_d)
    return best_m, int(ties[np.argmin(rank[ties])]), best_d


def score(
    vals: np.ndarray, mat: np.ndarray, rank: np.ndarray
) -> tuple[int, int, float, float, float]:
    """``_walk.score``: the row and word at the smallest distance (ties: the first row, the
    lowest rank), that distance, the margin to the nearest other word, and its separation."""
    d = np.sqrt(_sum_squares(vals[:, None, :] - mat[None, :, :]))  # (M, W)
    best_m, best_w, best_d = _best(d, rank)
    acc = _sum_squares(vals[best_m][None, :] - mat)
    dist2 = _sum_squares(mat - mat[best_w][None, :])
    other = dist2 != 0.0  # the same word under another name is no runner-up
    if not other.any():
        return best_m, best_w, best_d, math.inf, 0.0
    runner = float(np.sqrt(acc[other]).min())
    sep = float(np.sqrt(dist2[other]).min())
    return best_m, best_w, best_d, runner - best_d, sep


def score_many(
    vals: np.ndarray, mat: np.ndarray, rank: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``_walk.score_many``: ``score`` of each of D decodes (``vals`` (D, M, N)), as five
    arrays (D,) (a decode at a time: ``rgtbus.signal.rules`` decodes many at once by the
    rule's NumPy form where this twin stands in)."""
    got = [score(np.ascontiguousarray(v), mat, rank) for v in vals]
    cols = list(zip(*got, strict=True)) if got else [(), (), (), (), ()]
    ints = [np.array(c, dtype=np.int64) for c in cols[:2]]
    return ints[0], ints[1], *(np.array(c, dtype=np.float64) for c in cols[2:])  # type: ignore[return-value]


def _matched(a: np.ndarray, mat: np.ndarray) -> np.ndarray:
    """The matched-filter distance of every row of ``a`` (R, N) to every word of ``mat``
    (W, N), as the compiled ``_matched`` works it out: its sums in k's order."""
    vw = np.zeros((a.shape[0], mat.shape[0]))
    ww = np.zeros(mat.shape[0])
    for k in range(mat.shape[1]):
        vw = vw + a[:, k, None] * mat[None, :, k]
        ww = ww + mat[:, k] * mat[:, k]
    out: np.ndarray = np.where(ww > 0.0, -(vw / np.sqrt(np.where(ww > 0.0, ww, 1.0))), -0.0)
    return out


def score_matched(
    vals: np.ndarray, mat: np.ndarray, rank: np.ndarray
) -> tuple[int, int, float, float, float]:
    """``_walk.score_matched``: ``score`` by the matched-filter distance
    (``rgtbus.signal.rules``)."""
    best_m, best_w, best_d = _best(_matched(vals, mat), rank)  # of the (M, W) distances
    other = _sum_squares(mat - mat[best_w][None, :]) != 0.0
    if not other.any():
        return best_m, best_w, best_d, math.inf, 0.0
    runner = float(_matched(vals[best_m][None, :], mat)[0][other].min())
    exactly = _matched(mat[best_w][None, :], mat)[0]
    sep = float((exactly - exactly[best_w])[other].min())
    return best_m, best_w, best_d, runner - best_d, sep


def timings(
    chans: np.ndarray, omegas: np.ndarray, start: float, pulses: int, tau: float, search: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``_walk.timings``: every distinct pulse-instant tuple, per channel, of a code that starts
    within ± ``search`` samples of ``start``: (channel, shift, instants) rows."""
    t_lo, t_hi = start - search * tau, start + search * tau
    s0 = round(start / tau)
    owner: list[int] = []
    shift: list[int] = []
    inst: list[list[int]] = []
    for c in range(omegas.shape[0]):
        period = 2 * 3.141592653589793 / float(omegas[c])
        jts = [j * period for j in range(pulses)]
        cuts = [t_lo, t_hi]
        for jt in jts:
            h = math.floor((t_lo + jt) / tau - 0.5)
            h1 = math.ceil((t_hi + jt) / tau - 0.5)
            while h <= h1:
                t = (h + 0.5) * tau - jt
                if t_lo < t < t_hi:
                    cuts.append(t)
                h += 1
        cuts.sort()
        probes = sorted([start, *((a + b) / 2 for a, b in itertools.pairwise(cuts))])
        kept: list[list[int]] = []
        for t in probes:
            if t < 0:
                continue
            cand = [round((t + jt) / tau) for jt in jts]
            if kept and cand == kept[-1]:
                continue
            kept.append(cand)
        # nearest shift first, then the earlier (a stable sort on (|shift|, shift > 0))
        kept.sort(key=lambda q: abs(q[0] - s0) * 2 + (1 if q[0] - s0 > 0 else 0))
        for q in kept:
            owner.append(int(chans[c]))
            shift.append(q[0] - s0)
            inst.append(q)
    return (
        np.array(owner, dtype=np.int64),
        np.array(shift, dtype=np.int64),
        np.array(inst, dtype=np.int64).reshape(len(inst), pulses),
    )


def read_rows(rows: np.ndarray, vals: np.ndarray, idx: np.ndarray, chans: np.ndarray) -> np.ndarray:
    """``_walk.read_rows``: the readout at samples ``idx`` (M, N) on channel ``chans[m]`` for
    row m, for every receiver: (receivers, M, N); a sample not in ``rows`` reads 0."""
    K, R = rows.shape[0], vals.shape[1]
    out = np.zeros((R, *idx.shape))
    if K == 0 or idx.size == 0:
        return out
    at = np.searchsorted(rows, idx, side="left")
    found = (at < K) & (rows[np.minimum(at, K - 1)] == idx)
    m, n = np.nonzero(found)
    out[:, m, n] = vals[at[m, n], :, chans[m]].T
    return out
