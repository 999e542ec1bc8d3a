# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled loops of the receiver: the resonator walk, the decoder's nearest-word score and its
timing candidates.

The model and its rules are stated in ``rgtbus.signal.resonator`` (docs/model.md); this file
holds the one place they are computed. Compiled without FMA contraction
(``-ffp-contract=off``), so every product and sum is rounded as written.
"""

import numpy as np

from libc.math cimport INFINITY, ceil, floor, rint, sqrt


cdef inline (double, double, bint, long, long, bint) walk(
    const double[:, ::1] Pr, const double[:, ::1] Pi, const double[:, ::1] Qr,
    const double[:, ::1] nQi, double ar, double ai, long R, long ch, long rec,
    double thr, double thr2, double rv, bint stable,
    double w_r, double w_i, bint pend, long start, long end,
    const long[::1] rows, const double[:, ::1] vals, bint stop_first,
    bint record, long col, double[:, ::1] xs, double[:, ::1] ys, unsigned char[:, ::1] mask,
    long[::1] sp_k, long[::1] sp_l, long lane, long n_sp,
) noexcept nogil:
    """One resonator (channel ``ch``, receiver ``rec``) from sample ``start`` to ``end``.

    In its epoch's rotating frame (m = k mod R, P[m] = A^m, Q[m] = A^-m)::

        enter k:  at an epoch's start  w ← P[R]·w                     (re-anchor)
                  after a spike at k−1 w ← Q[m]·(Re(A·z[k−1]) + i·rv) (reset)
        input:    w ← w + i·u[k]·Q[m]                                 (u = vals[j, rec])
        state:    z[k] = P[m]·w;  spike at k  ⇔  Im z[k] ≥ thr

(The increment readout, Im z[k] − Im ẑ[k] = u[k], needs no walk: ``resonate`` takes it from
the input.)

    Between inputs w is constant: a resonator with |z|² < thr2 (below threshold, with room for
    table rounding) cannot spike before its next input (|A| < 1), so the walk jumps there,
    re-anchoring at every epoch start on the way; otherwise it steps sample by sample.
    ``stop_first``: return right after the first spike. Spikes go to (sp_k, sp_l) from index
    n_sp on. Returns (w_r, w_i, pend, next sample, spike count, overflowed).
    """
    cdef Py_ssize_t E = rows.shape[0]
    cdef Py_ssize_t cap = sp_k.shape[0]
    cdef Py_ssize_t j = 0
    cdef Py_ssize_t lo = 0, hi = E, mid
    cdef long k = start, m, nxt
    cdef double zr, zi, u
    cdef bint has_input
    while lo < hi:  # the first input row at or after start
        mid = (lo + hi) // 2
        if rows[mid] < start:
            lo = mid + 1
        else:
            hi = mid
    j = lo
    while k < end:
        m = k % R
        if pend:  # reset from the pre-spike state of k−1, in its own frame
            w_r, w_i = _reset(Pr, Pi, Qr, nQi, ar, ai, rv, R, ch, k, w_r, w_i)
            pend = False
        elif m == 0 and k > 0:
            w_r, w_i = _times_p(Pr, Pi, R, ch, w_r, w_i)
        has_input = j < E and rows[j] == k
        if has_input:
            u = vals[j, rec]
            w_r = w_r + u * nQi[m, ch]
            w_i = w_i + u * Qr[m, ch]
            j += 1
        zr, zi = _times_p(Pr, Pi, m, ch, w_r, w_i)
        if record:
            xs[k - start, col] = zr
            ys[k - start, col] = zi
        if zi >= thr:
            if n_sp >= cap:
                return w_r, w_i, pend, k, n_sp, True
            sp_k[n_sp] = k
            sp_l[n_sp] = lane
            n_sp += 1
            pend = True
            if record:
                mask[k - start, col] = 1
            if stop_first:
                return w_r, w_i, pend, k + 1, n_sp, False
            k += 1
            continue
        k += 1
        if record or not stable or zr * zr + zi * zi >= thr2:
            continue  # every sample is wanted, or this resonator may still cross the threshold
        nxt = rows[j] if j < E else end
        if nxt > end:
            nxt = end
        w_r, w_i = _across_silence(Pr, Pi, R, ch, k, nxt, w_r, w_i)
        k = nxt
    return w_r, w_i, pend, end, n_sp, False


cdef inline (double, double) _times_p(
    const double[:, ::1] Pr, const double[:, ::1] Pi, long m, long ch, double w_r, double w_i,
) noexcept nogil:
    """P[m]·w on channel ``ch``: the state at m samples into the epoch, or (m = R) the frame
    moved on to the next epoch."""
    return Pr[m, ch] * w_r - Pi[m, ch] * w_i, Pr[m, ch] * w_i + Pi[m, ch] * w_r


cdef inline (double, double) _reset(
    const double[:, ::1] Pr, const double[:, ::1] Pi, const double[:, ::1] Qr,
    const double[:, ::1] nQi, double ar, double ai, double rv, long R, long ch, long k,
    double w_r, double w_i,
) noexcept nogil:
    """w at sample k after a spike at k−1: Q[m]·(Re(A·z[k−1]) + i·rv), z[k−1] the pre-spike
    state in its own frame (m = k mod R)."""
    cdef long m = k % R
    cdef double zr, zi, xr
    zr, zi = _times_p(Pr, Pi, (k - 1) % R, ch, w_r, w_i)
    xr = ar * zr - ai * zi
    return Qr[m, ch] * xr + nQi[m, ch] * rv, Qr[m, ch] * rv - nQi[m, ch] * xr


cdef inline (double, double) _across_silence(
    const double[:, ::1] Pr, const double[:, ::1] Pi, long R, long ch, long k, long nxt,
    double w_r, double w_i,
) noexcept nogil:
    """w carried through silence from sample k to ``nxt``: unchanged but for a re-anchoring
    (w ← P[R]·w) at every epoch start crossed on the way (none at sample 0)."""
    cdef long b = ((k + R - 1) // R) * R
    while b < nxt:
        if b > 0:
            w_r, w_i = _times_p(Pr, Pi, R, ch, w_r, w_i)
        b += R
    return w_r, w_i


cdef class WalkModel:
    """What every walk of a bank uses and nothing changes: the epoch tables (P = A^m as
    ``Pr``, ``Pi``; Q = A^-m as ``Qr``, ``nQi`` = −Im; A as ``Ar``, ``Ai``; epoch ``R``), the
    lane layout (``lane_ch``, ``lane_rec``) and the spike rule (threshold ``thr``, the hot
    bound ``thr2`` on |z|², reset value ``rv``, ``stable``: silence may be skipped). Built once
    per bank model, so a walk does not take its arrays apart again."""

    cdef const double[:, ::1] Pr
    cdef const double[:, ::1] Pi
    cdef const double[:, ::1] Qr
    cdef const double[:, ::1] nQi
    cdef const double[::1] Ar
    cdef const double[::1] Ai
    cdef long R
    cdef const long[::1] lane_ch
    cdef const long[::1] lane_rec
    cdef double thr
    cdef double thr2
    cdef double rv
    cdef bint stable

    def __init__(
        self, const double[:, ::1] Pr, const double[:, ::1] Pi, const double[:, ::1] Qr,
        const double[:, ::1] nQi, const double[::1] Ar, const double[::1] Ai, long R,
        const long[::1] lane_ch, const long[::1] lane_rec, double thr, double thr2, double rv,
        bint stable,
    ):
        self.Pr = Pr
        self.Pi = Pi
        self.Qr = Qr
        self.nQi = nQi
        self.Ar = Ar
        self.Ai = Ai
        self.R = R
        self.lane_ch = lane_ch
        self.lane_rec = lane_rec
        self.thr = thr
        self.thr2 = thr2
        self.rv = rv
        self.stable = stable


_NO_XY = np.zeros((2, 0, 0))
_NO_MASK = np.zeros((0, 0), dtype=np.uint8)


def walk_lanes(
    WalkModel model not None, const long[::1] lanes,
    double[::1] wr, double[::1] wi, unsigned char[::1] pend, long start, long end,
    const long[::1] rows, const double[:, ::1] vals, bint stop_first, long[:, ::1] spikes,
    double[:, :, ::1] trajectory=None, unsigned char[:, ::1] spiked=None,
):
    """``walk`` each of ``lanes`` of ``model`` from ``start`` to ``end`` over the input
    (``rows``, ``vals``), from the lanes' state (``wr``, ``wi``, ``pend``). With
    ``stop_first``: only find the first spike (returns one past it and 1, or ``end`` and 0;
    later lanes look no further; the state is left alone). Otherwise every lane walks to
    ``end`` and its state is updated in place. Spikes go to ``spikes`` (2, room): their
    samples, then their lanes. With a ``trajectory`` (2, samples, lanes): every sample's x and
    y there, and the spike mask to ``spiked``. Returns (stop, spikes, overflow).
    """
    cdef long n_sp = 0, first = end, n_new = 0, at, lane, c, found = 0
    cdef Py_ssize_t idx
    cdef double w_r, w_i
    cdef bint p, over = False
    cdef bint record = trajectory is not None
    cdef double[:, :, ::1] xy = trajectory if record else _NO_XY
    cdef double[:, ::1] xs = xy[0], ys = xy[1]
    cdef unsigned char[:, ::1] mask = spiked if record else _NO_MASK
    cdef long[::1] sp_k = spikes[0], sp_l = spikes[1]
    with nogil:
        for idx in range(lanes.shape[0]):
            lane = lanes[idx]
            c = model.lane_ch[lane]
            w_r, w_i, p, at, n_new, over = walk(
                model.Pr, model.Pi, model.Qr, model.nQi, model.Ar[c], model.Ai[c], model.R, c,
                model.lane_rec[lane], model.thr, model.thr2, model.rv, model.stable,
                wr[lane], wi[lane], pend[lane], start, first, rows, vals, stop_first,
                record, lane, xs, ys, mask, sp_k, sp_l, lane, n_sp,
            )
            if over:
                break
            if stop_first:
                if n_new > n_sp:
                    first = at
                    found = 1
                    n_sp = 0  # only where it stops matters here
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


def score(const double[:, ::1] vals, const double[:, ::1] mat, const long[::1] rank):
    """Maximum likelihood under white Gaussian noise: the candidate row ``m`` of ``vals``
    (M, N) and word ``w`` of ``mat`` (W, N) at the smallest Euclidean distance (ties: the first
    row, the lowest ``rank``), that distance, the margin (the nearest word that differs from
    ``w`` is this much farther; inf if none) and the separation of ``w`` from that set."""
    cdef Py_ssize_t M = vals.shape[0], W = mat.shape[0], N = mat.shape[1]
    cdef Py_ssize_t i, j, k, best_m = 0, best_w = 0
    cdef double best_d = INFINITY, acc, diff, d, runner = INFINITY, sep = INFINITY, dist2, gap
    with nogil:
        for i in range(M):
            for j in range(W):
                acc = 0.0
                for k in range(N):
                    diff = vals[i, k] - mat[j, k]
                    acc = acc + diff * diff
                d = sqrt(acc)
                if d < best_d or (d == best_d and i == best_m and rank[j] < rank[best_w]):
                    best_m = i
                    best_w = j
                    best_d = d
        for j in range(W):
            acc = 0.0
            dist2 = 0.0
            for k in range(N):
                diff = vals[best_m, k] - mat[j, k]
                acc = acc + diff * diff
                gap = mat[j, k] - mat[best_w, k]
                dist2 = dist2 + gap * gap
            if dist2 == 0.0:
                continue  # the same word under another name (e.g. id and alliance)
            if sqrt(acc) < runner:
                runner = sqrt(acc)
            if sqrt(dist2) < sep:
                sep = sqrt(dist2)
    if runner == INFINITY:
        return best_m, best_w, best_d, INFINITY, 0.0
    return best_m, best_w, best_d, runner - best_d, sep


def score_many(const double[:, :, ::1] vals, const double[:, ::1] mat, const long[::1] rank):
    """``score`` for D decodes at once: ``vals`` (D, M, N); returns five arrays (D,): row,
    word, distance, margin, separation. The words' gaps to each other (W x W) are summed once
    a call, each decode's distances once (a noisy group decodes millions of codes, each its
    own: no Python object a decode)."""
    cdef Py_ssize_t D = vals.shape[0], M = vals.shape[1], W = mat.shape[0], N = mat.shape[1]
    cdef Py_ssize_t t, i, j, k, best_m, best_w
    cdef double best_d, acc, diff, d, runner, sep
    row_a = np.empty(D, dtype=np.int64)
    word_a = np.empty(D, dtype=np.int64)
    dist_a = np.empty(D)
    margin_a = np.empty(D)
    sep_a = np.empty(D)
    gaps_a = np.empty((W, W))
    here_a = np.empty((max(M, 1), W))
    cdef long[::1] row_o = row_a, word_o = word_a
    cdef double[::1] dist_o = dist_a, margin_o = margin_a, sep_o = sep_a
    cdef double[:, ::1] gaps = gaps_a, here = here_a
    with nogil:
        for j in range(W):  # word j to word i: summed as score sums it, (w_j − w_i)² in k's order
            for i in range(W):
                acc = 0.0
                for k in range(N):
                    diff = mat[j, k] - mat[i, k]
                    acc = acc + diff * diff
                gaps[i, j] = acc
        for t in range(D):
            best_m = 0
            best_w = 0
            best_d = INFINITY
            for i in range(M):
                for j in range(W):
                    acc = 0.0
                    for k in range(N):
                        diff = vals[t, i, k] - mat[j, k]
                        acc = acc + diff * diff
                    d = sqrt(acc)
                    here[i, j] = d
                    if d < best_d or (d == best_d and i == best_m and rank[j] < rank[best_w]):
                        best_m = i
                        best_w = j
                        best_d = d
            runner = INFINITY
            sep = INFINITY
            for j in range(W):
                if gaps[best_w, j] == 0.0:
                    continue  # the same word under another name (e.g. id and alliance)
                if here[best_m, j] < runner:
                    runner = here[best_m, j]
                if sqrt(gaps[best_w, j]) < sep:
                    sep = sqrt(gaps[best_w, j])
            row_o[t] = best_m
            word_o[t] = best_w
            dist_o[t] = best_d
            if runner == INFINITY:
                margin_o[t] = INFINITY
                sep_o[t] = 0.0
            else:
                margin_o[t] = runner - best_d
                sep_o[t] = sep
    return row_a, word_a, dist_a, margin_a, sep_a


cdef inline double _matched(
    const double[:, ::1] a, Py_ssize_t i, const double[:, ::1] mat, Py_ssize_t j, Py_ssize_t N
) noexcept nogil:
    """The matched-filter rule's distance of row i of ``a`` to word j
    (``rgtbus.signal.rules.matched``): −Σ v·w / sqrt(Σ w²), −0 for the zero word, sums in k's
    order."""
    cdef double vw = 0.0, ww = 0.0
    cdef Py_ssize_t k
    for k in range(N):
        vw = vw + a[i, k] * mat[j, k]
        ww = ww + mat[j, k] * mat[j, k]
    return -(vw / sqrt(ww)) if ww > 0.0 else -0.0


def score_matched(const double[:, ::1] vals, const double[:, ::1] mat, const long[::1] rank):
    """The matched-filter rule (``rgtbus.signal.rules``): as ``score``, each distance the
    negative matched-filter output; a word is another word when it differs from the best (the
    Euclidean gap), its separation the best word's own distance to it less its distance to
    itself."""
    cdef Py_ssize_t M = vals.shape[0], W = mat.shape[0], N = mat.shape[1]
    cdef Py_ssize_t i, j, k, best_m = 0, best_w = 0
    cdef double best_d = INFINITY, d, own, runner = INFINITY, sep = INFINITY, dist2, gap
    with nogil:
        for i in range(M):
            for j in range(W):
                d = _matched(vals, i, mat, j, N)
                if d < best_d or (d == best_d and i == best_m and rank[j] < rank[best_w]):
                    best_m = i
                    best_w = j
                    best_d = d
        own = _matched(mat, best_w, mat, best_w, N)
        for j in range(W):
            dist2 = 0.0
            for k in range(N):
                gap = mat[j, k] - mat[best_w, k]
                dist2 = dist2 + gap * gap
            if dist2 == 0.0:
                continue  # the same word under another name
            d = _matched(vals, best_m, mat, j, N)
            if d < runner:
                runner = d
            d = _matched(mat, best_w, mat, j, N) - own
            if d < sep:
                sep = d
    if runner == INFINITY:
        return best_m, best_w, best_d, INFINITY, 0.0
    return best_m, best_w, best_d, runner - best_d, sep


def timings(
    const long[::1] chans, const double[::1] omegas, double start, long pulses, double tau,
    long search,
):
    """Every distinct pulse-instant tuple, per channel, of a code on ω that starts within
    ± ``search`` samples of ``start`` (see ``rgtbus.signal.decoder._timings``, which states the
    rule): (channel, shift, instants) rows, channels in the order given, within a channel the
    nearest shift first (then the earlier); tuples of starts before 0 are left out.

    Instant j of a start t is rint((t + j·T)/τ) (half to even, as Python's round); it changes
    only where (t + j·T)/τ crosses h + ½, so the tuples are those of ``start`` and of the
    midpoints between consecutive crossings (and the window's ends)."""
    cdef Py_ssize_t C = omegas.shape[0], c, j, q, a, n_probe, n_keep, m = 0
    cdef double t_lo = start - search * tau, t_hi = start + search * tau
    cdef long s0 = <long> rint(start / tau)
    # at most 2 + P·(2·search + 3) crossings a channel, one probe more
    cdef Py_ssize_t cap = 3 + pulses * (2 * search + 4)
    cuts_np = np.empty(cap, dtype=np.float64)
    probes_np = np.empty(cap, dtype=np.float64)
    jts_np = np.empty(pulses, dtype=np.float64)
    cand_np = np.empty((cap, pulses), dtype=np.int64)
    key_np = np.empty(cap, dtype=np.int64)
    owner_np = np.empty(C * cap, dtype=np.int64)
    shift_np = np.empty(C * cap, dtype=np.int64)
    inst_np = np.empty((C * cap, pulses), dtype=np.int64)
    cdef double[::1] cuts = cuts_np, probes = probes_np, jts = jts_np
    cdef long[:, ::1] cand = cand_np
    cdef long[::1] key = key_np, owner = owner_np, shift = shift_np
    cdef long[:, ::1] inst = inst_np
    cdef long[::1] order = np.empty(cap, dtype=np.int64)
    for c in range(C):
        n_probe = _probes(
            2 * 3.141592653589793 / omegas[c], start, pulses, tau, t_lo, t_hi, cuts, probes, jts
        )
        n_keep = _distinct_instants(n_probe, pulses, tau, probes, jts, cand)
        _by_shift(n_keep, s0, cand, key, order)
        for a in range(n_keep):
            q = order[a]
            owner[m] = chans[c]
            shift[m] = cand[q, 0] - s0
            for j in range(pulses):
                inst[m, j] = cand[q, j]
            m += 1
    return owner_np[:m].copy(), shift_np[:m].copy(), inst_np[:m].copy()


cdef Py_ssize_t _probes(
    double period, double start, long pulses, double tau, double t_lo, double t_hi,
    double[::1] cuts, double[::1] probes, double[::1] jts,
) noexcept nogil:
    """The starts to try on a channel of ``period``: ``start`` and the midpoints between the
    consecutive crossings of h + ½ by (t + j·T)/τ within (t_lo, t_hi) and the window's ends,
    ascending, into ``probes`` (``cuts``: room for the crossings; ``jts``: each pulse's j·T).
    Returns how many."""
    cdef Py_ssize_t j, a, n_cut = 2, n_probe = 1
    cdef double jt, t, h, h1
    cuts[0] = t_lo
    cuts[1] = t_hi
    for j in range(pulses):
        jt = j * period
        jts[j] = jt
        h = floor((t_lo + jt) / tau - 0.5)
        h1 = ceil((t_hi + jt) / tau - 0.5)
        while h <= h1:
            t = (h + 0.5) * tau - jt
            if t_lo < t and t < t_hi:
                cuts[n_cut] = t
                n_cut += 1
            h += 1.0
    _sort(cuts, n_cut)
    probes[0] = start
    for a in range(n_cut - 1):
        probes[n_probe] = (cuts[a] + cuts[a + 1]) / 2
        n_probe += 1
    _sort(probes, n_probe)
    return n_probe


cdef Py_ssize_t _distinct_instants(
    Py_ssize_t n_probe, long pulses, double tau, double[::1] probes, double[::1] jts,
    long[:, ::1] cand,
) noexcept nogil:
    """The distinct instant tuples of the ``probes`` at or after 0 (instant j of a start t is
    rint((t + j·T)/τ)), in probe order, into ``cand``. Returns how many."""
    cdef Py_ssize_t q, j, n_keep = 0
    cdef double t
    cdef bint same
    for q in range(n_probe):
        t = probes[q]
        if t < 0:
            continue
        for j in range(pulses):
            cand[n_keep, j] = <long> rint((t + jts[j]) / tau)
        if n_keep:  # instants grow with t: equal tuples are adjacent
            same = True
            for j in range(pulses):
                if cand[n_keep, j] != cand[n_keep - 1, j]:
                    same = False
                    break
            if same:
                continue
        n_keep += 1
    return n_keep


cdef void _by_shift(
    Py_ssize_t n_keep, long s0, long[:, ::1] cand, long[::1] key, long[::1] order,
) noexcept nogil:
    """``order`` of the first ``n_keep`` tuples of ``cand``: the nearest shift from ``s0``
    first, then the earlier (a stable insertion sort on (|shift|, shift))."""
    cdef Py_ssize_t q, a, b
    cdef long sh
    for q in range(n_keep):
        sh = cand[q, 0] - s0
        key[q] = (sh if sh >= 0 else -sh) * 2 + (1 if sh > 0 else 0)
        order[q] = q
    for a in range(1, n_keep):
        b = a
        while b > 0 and key[order[b - 1]] > key[order[b]]:
            order[b - 1], order[b] = order[b], order[b - 1]
            b -= 1


cdef void _sort(double[::1] a, Py_ssize_t n) noexcept nogil:
    """Ascending insertion sort of a[:n] (a few dozen values)."""
    cdef Py_ssize_t i, j
    cdef double v
    for i in range(1, n):
        v = a[i]
        j = i - 1
        while j >= 0 and a[j] > v:
            a[j + 1] = a[j]
            j -= 1
        a[j + 1] = v


def read_rows(
    const long[::1] rows, const double[:, :, ::1] vals, const long[:, ::1] idx,
    const long[::1] chans,
):
    """The readout at samples ``idx`` (M, N) on channel ``chans[m]`` for row m, for every
    receiver: (receivers, M, N). ``rows`` (ascending) are the samples kept, ``vals`` (rows,
    receivers, channels) their readout; any other sample reads 0."""
    cdef Py_ssize_t K = rows.shape[0], R = vals.shape[1], M = idx.shape[0], N = idx.shape[1]
    cdef Py_ssize_t m, n, r, lo, hi, mid
    cdef long s
    out_np = np.zeros((R, M, N), dtype=np.float64)
    cdef double[:, :, ::1] out = out_np
    with nogil:
        for m in range(M):
            for n in range(N):
                s = idx[m, n]
                lo = 0
                hi = K
                while lo < hi:  # the first kept row at or after s
                    mid = (lo + hi) // 2
                    if rows[mid] < s:
                        lo = mid + 1
                    else:
                        hi = mid
                if lo < K and rows[lo] == s:
                    for r in range(R):
                        out[r, m, n] = vals[lo, r, chans[m]]
    return out_np
