"""A noisy medium's necessary work at the arithmetic limit, compiled (numba), apart from the run.

On a noisy medium every receiver hears its own copy, ``heard_r[k] = Σ_s g[s→r]·x_s[k] + n_r[k]``
(docs/model.md), so nothing is shared between receivers and nothing is skipped: for each
receiver r, every sample of the run goes through its bank of n resonators (one a channel),

    z[k] = A_ch · z[k−1]  (then Im z := reset value after a spike at k−1),
    ẑ = z[k];  Im z[k] += heard_r[k];  spike when Im z[k] ≥ threshold,
    readout d[k] = Im z[k] − Im ẑ, rounded to READOUT_DIGITS,

and every code on the medium is decoded from the readout on its channel: an ID at its pulse
samples, the nearest of every distinct word; a payload at each of its candidate timings (the
protocol's timing search, ``code_candidates``: the schedule's instants shifted by up to
``search`` samples), the nearest (timing, word) of its family (relation words, or the
alternatives' words): ``argmin_{m,w} |d_m − w|²``.

The same samples (the receiver's own noise, drawn in order from ``noise_rng(seed, r)``, as the
run draws it), the same lanes (n receivers × n channels) and the same decodes as the run: the
bank is one compiled loop over samples and lanes a receiver, the decodes one matrix product a
family. ``reference`` returns its timings and every decode's word, and ``compare`` checks them
decode for decode against what the run's units decoded (their misreads, and their counts).

Kept apart from the package: it imports the model's constants (transition matrix, threshold,
reset value, readout digits), never the run's walk, readout or decoder.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from rgtbus.units.unit import AutonomousUnit

    from rgtbus.scenario import Scenario


def _bank_kernel() -> Any:
    """The compiled bank walk (numba, compiled on first use)."""
    from numba import njit

    @njit(cache=True, fastmath=False, nogil=True)
    def walk(
        heard: np.ndarray,  # (samples,) the receiver's medium, noise included
        ar: np.ndarray,  # (lanes,) Re A
        ai: np.ndarray,  # (lanes,) Im A
        threshold: float,
        reset: float,
        need_k: np.ndarray,  # sorted samples at which some lane's readout is needed
        need_start: np.ndarray,  # need_lane[need_start[i]:need_start[i+1]]: lanes at need_k[i]
        need_lane: np.ndarray,
        out: np.ndarray,  # (len(need_lane),) readout in need order
    ) -> int:
        lanes = ar.size
        zr = np.zeros(lanes)
        zi = np.zeros(lanes)
        pend = np.zeros(lanes, dtype=np.bool_)
        before = np.zeros(lanes)
        spikes = 0
        q = 0
        for k in range(heard.size):
            u = heard[k]
            for c in range(lanes):
                r = ar[c] * zr[c] - ai[c] * zi[c]
                i = ar[c] * zi[c] + ai[c] * zr[c]
                if pend[c]:
                    i = reset
                before[c] = i
                i += u
                zr[c] = r
                zi[c] = i
                hit = i >= threshold
                pend[c] = hit
                spikes += hit
            if q < need_k.size and need_k[q] == k:
                for j in range(need_start[q], need_start[q + 1]):
                    c = need_lane[j]
                    out[j] = zi[c] - before[c]
                q += 1
        return spikes

    return walk


def _decode_kernel() -> Any:
    """The compiled nearest (timing, word) decode of every code for one receiver."""
    from numba import njit

    @njit(cache=True, nogil=True)
    def decode(
        d: np.ndarray,  # the receiver's rounded readout, in need order
        where: np.ndarray,  # (codes, M, pulses) index into d
        fam_of: np.ndarray,  # (codes,) family index
        words: np.ndarray,  # (families, most words, pulses)
        counts: np.ndarray,  # (families,) words in each
        out: np.ndarray,  # (codes,) the word index
    ) -> None:
        codes, cands, pulses = where.shape
        for c in range(codes):
            f = fam_of[c]
            best = np.inf
            got = 0
            for m in range(cands):
                for w in range(counts[f]):
                    dist = 0.0
                    for p in range(pulses):
                        e = d[where[c, m, p]] - words[f, w, p]
                        dist += e * e
                    if dist < best:  # the first (timing, word) of the least distance
                        best = dist
                        got = w
            out[c] = got

    return decode


def reference(sc: Scenario, members: list[AutonomousUnit], sim_seconds: float) -> dict[str, Any]:
    """The noisy run's necessary work, timed: the bank of every receiver (compiled), then every
    decode (vectorised). Returns the timings, the sizes and ``words``: for every receiver and
    code (in send order, ``codes``), the index of the word it decodes in its family's list."""
    from rgtbus.protocol import PHASES
    from rgtbus.signal.channel import noise_rng
    from rgtbus.signal.resonator import (
        PAPER_B,
        PAPER_RESET_VALUE,
        PAPER_THRESHOLD,
        READOUT_DIGITS,
        transition,
    )

    ch = sc.channel
    if ch.burst is not None or ch.fading != "none" or ch.timed:
        raise SystemExit("the noisy reference knows white noise and static gains only")
    units = list(sc.units)
    n = len(units)
    index = {u: i for i, u in enumerate(units)}
    tau, cb = sc.timing.tau, sc.codebook
    families = {
        "id": cb.distinct_words(),  # an ID is judged against every distinct word
        "relation": cb.family("relation"),
        "influence": cb.family("alternative"),
    }
    fam_names = list(families)
    from rgtbus.signal.decoder import code_candidates

    rows_s, rows_m, chans, senders, fams, turns, cands = [], [], [], [], [], [], []
    search = members[0].protocol.search if members else 0
    for m in members:
        for send in m.sent:
            if send.kind == "id":
                fam = "id"
            else:  # a receiver knows a payload's family from the schedule's phase
                phase = m.protocol.schedule[send.turn].phase
                fam = "relation" if phase == PHASES[0] else "influence"
            rows_s.append(send.samples)
            rows_m.append(m.transmitter.word(send))
            chans.append(index[send.channel])
            senders.append(index[m.name])
            fams.append(fam_names.index(fam))
            turns.append(send.turn)
            if fam == "id":  # read at its instants
                cands.append(np.array([send.samples], dtype=np.int64))
            else:
                c = index[send.channel]
                omega = float(sc.frequencies[send.channel])
                got = code_candidates(c, omega, send.start, cb.pulses, tau, search)[1]
                cands.append(np.asarray(got, dtype=np.int64))
    S = np.array(rows_s, dtype=np.int64)  # (codes, pulses)
    width = max(len(x) for x in cands)  # candidates a code, padded with its first (no tie)
    C = np.stack([np.concatenate([x, np.repeat(x[:1], width - len(x), 0)]) for x in cands])
    M = np.array(rows_m, dtype=float)
    chan = np.array(chans, dtype=np.int64)
    sender = np.array(senders, dtype=np.int64)
    fam_of = np.array(fams, dtype=np.int64)
    reaction = round(sc.timing.reaction_delay / tau)
    end = max(round(sim_seconds / tau), int(C.max()) + reaction) + 1

    # where readout is needed: (sample, lane) pairs some code is decoded from, sorted
    keys = np.unique((C * n + chan[:, None, None]).ravel())
    need_k_all = keys // n
    starts = np.flatnonzero(np.r_[True, need_k_all[1:] != need_k_all[:-1]])
    need_k = need_k_all[starts]
    need_start = np.r_[starts, keys.size].astype(np.int64)
    need_lane = (keys % n).astype(np.int64)
    where = np.searchsorted(keys, C * n + chan[:, None, None])  # (codes, M, pulses) -> slot
    A = np.array([transition(sc.frequencies[u], mode=sc.mode, tau=tau, b=PAPER_B) for u in units])
    ar, ai = np.ascontiguousarray(A.real), np.ascontiguousarray(A.imag)
    walk = _bank_kernel()
    tiny = np.zeros(1)  # compile outside the timing
    walk(tiny, ar[:1], ai[:1], PAPER_THRESHOLD, PAPER_RESET_VALUE, np.zeros(0, np.int64),
         np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0))  # fmt: skip
    gains = np.array([ch.gain_row(units, u) for u in units])  # [receiver, sender]
    scale = 10.0**READOUT_DIGITS
    words = [np.array(list(w.values()), dtype=float) for w in families.values()]
    counts = np.array([len(W) for W in words], dtype=np.int64)
    padded = np.zeros((len(words), int(counts.max()), S.shape[1]))
    for f, W in enumerate(words):
        padded[f, : len(W)] = W
    decode = _decode_kernel()
    decode(np.zeros(1), np.zeros((0, 1, 1), np.int64), np.zeros(0, np.int64), padded, counts,
           np.zeros(0, np.int64))  # fmt: skip
    got = np.empty((n, S.shape[0]), dtype=np.int64)
    bank_s = decode_s = noise_s = 0.0
    spikes = 0
    readout = np.empty(keys.size)
    for r in range(n):
        t0 = time.perf_counter()
        heard = noise_rng(sc.seed, r).normal(0.0, ch.noise, end) if ch.noise > 0 else np.zeros(end)
        np.add.at(heard, S.ravel(), (M * gains[r, sender][:, None]).ravel())
        t1 = time.perf_counter()
        spikes += walk(heard, ar, ai, PAPER_THRESHOLD, PAPER_RESET_VALUE,
                       need_k, need_start, need_lane, readout)  # fmt: skip
        t2 = time.perf_counter()
        decode(np.rint(readout * scale) / scale, where, fam_of, padded, counts, got[r])
        t3 = time.perf_counter()
        noise_s += t1 - t0
        bank_s += t2 - t1
        decode_s += t3 - t2
    return {
        "ref_s": noise_s + bank_s + decode_s,
        "ref_noise_s": noise_s,
        "ref_bank_s": bank_s,
        "ref_decode_s": decode_s,
        "ref_samples": end,
        "ref_lanes": n * n,
        "ref_spikes": spikes,
        "ref_decodes": int(got.size),
        "words": got,
        "families": {f: list(w) for f, w in families.items()},
        "codes": list(zip(turns, [fam_names[i] for i in fams], senders, strict=True)),
    }


def compare(ref: dict[str, Any], members: list[AutonomousUnit], misreads: Any) -> dict[str, int]:
    """The reference's decodes against the run's, decode for decode: every decode the
    reference reads otherwise than sent must be one of the run's misreads (unit, turn, kind,
    word) and the other way round; the counts of decodes must agree. ``misreads``: the run's
    ``DecodeErrors``."""
    codes, families, got = ref["codes"], ref["families"], ref["words"]
    names = [m.name for m in members]
    sent_word = []
    for m in members:  # what each code sent, as its family names it
        for send in m.sent:
            sent_word.append("id" if send.kind == "id" else send.code)
    want = np.array(
        [families[fam].index(w) for (_, fam, _), w in zip(codes, sent_word, strict=True)]
    )
    r_idx, c_idx = np.nonzero(got != want[None, :])
    ref_wrong = {
        (names[r], codes[c][0], codes[c][1], families[codes[c][1]][got[r, c]])
        for r, c in zip(r_idx.tolist(), c_idx.tolist(), strict=True)
    }
    run_wrong = {(e["unit"], e["turn"], e["kind"], e["decoded"]) for e in misreads.rows()}
    run_decodes = sum(len(m.decoded) for m in members)
    return {
        "decodes": run_decodes,
        "ref_decodes": ref["ref_decodes"],
        "misreads": len(run_wrong),
        "ref_misreads": len(ref_wrong),
        "mismatches": len(ref_wrong ^ run_wrong) + abs(run_decodes - ref["ref_decodes"]),
    }
