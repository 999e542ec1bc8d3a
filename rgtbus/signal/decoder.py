"""Detection and decoding (SPEC §2): from spikes and resonator states to code values.

- **Detection**: a spike on ω_s says "something arrived on ω_s" (an ID-code spike: "s transmits").
- **Increment readout**: the resonator's update is ``z[k] = A·z[k-1] + i·u[k]``, so
  ``d[k] = (z[k] − next(z[k-1])) / i`` recovers the medium sample u[k], where ``next(z) = A·z``,
  or after a spike the reset state ``Re(A·z) + i·reset_value``.  Any channel of a receiver gives
  the same d (they all hear the same sample); the imaginary rounding residue is ~1e-15.
- **Nearest codeword**: with white Gaussian noise on the medium the values at a code's pulse
  instants are ``word + noise``, so the maximum-likelihood word is the nearest (Euclidean); the
  margin is how much farther the runner-up is.
- **Joint decoding**: transmitters whose pulses share samples add up there; stack every
  transmitter's pulses into ``d_U = M·c`` over the union U of instants, estimate c by least
  squares and pick the word combination with the smallest residual (exhaustive when small,
  coordinate descent otherwise).
- **Timing search**: when the start is known only from a spike, try every distinct set of pulse
  instants within ± ``search`` samples and keep the best fit (smallest residual, then the
  smallest shift).
- **ID acceptance**: an ID is accepted only if the code on the sender's own frequency decodes as
  the ID-code among all distinct words, within ``accept_radius`` — the paper mode a↔c crosstalk
  fires ω_a for some codes sent on ω_c; their values at ω_a's instants are far from the ID-code.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from rgtbus.errors import RgtbusError
from rgtbus.signal.codebook import Codebook
from rgtbus.signal.resonator import PAPER_RESET_VALUE, PAPER_TAU, FeedResult, ResonatorBank

MAX_EXHAUSTIVE = 4096


def increments(
    z: np.ndarray,
    spiked: np.ndarray,
    A: np.ndarray | complex,
    reset_value: float = PAPER_RESET_VALUE,
    z_prev: np.ndarray | complex = 0j,
    spiked_prev: np.ndarray | bool = False,
) -> np.ndarray:
    """Increment readout ``d[k] = Im(z[k] − next(z[k-1]))`` along axis 0 (real array).

    ``z``/``spiked``: pre-spike states and spike mask (e.g. ``FeedResult.z``, ``.spiked``);
    ``A`` broadcasts over the trailing axes (one per channel); ``z_prev``/``spiked_prev`` are
    the state before the first row (0 and False at rest).
    """
    z = np.asarray(z)
    spiked = np.asarray(spiked, dtype=bool)
    if z.shape != spiked.shape:
        raise RgtbusError(f"z of shape {z.shape} and spiked of shape {spiked.shape} differ")
    zp = np.empty_like(z)
    sp = np.empty_like(spiked)
    zp[0] = z_prev
    sp[0] = spiked_prev
    zp[1:] = z[:-1]
    sp[1:] = spiked[:-1]
    step = A * zp
    pred_im = np.where(sp, reset_value, step.imag)
    return z.imag - pred_im


class Readout:
    """Streaming increment readout of one receiver's channel, kept for ``capacity`` samples.

    ``append(result)`` after each ``bank.feed(..., record=True)``; ``values(indices)`` gives the
    medium estimate d at absolute sample indices still in the history.
    """

    def __init__(
        self,
        A: complex,
        reset_value: float = PAPER_RESET_VALUE,
        capacity: int = 6000,
        receiver: int = 0,
        channel: int = 0,
    ):
        """Prefer :meth:`for_bank`, which takes A and the reset value from the bank."""
        if not isinstance(capacity, int) or capacity < 1:
            raise RgtbusError(f"readout capacity {capacity!r} must be a positive integer")
        self.A = complex(A)
        self.reset_value = float(reset_value)
        self.capacity = capacity
        self.receiver = receiver
        self.channel = channel
        self._buf = np.zeros(capacity)
        self._end = 0  # absolute index one past the newest sample
        self._z_prev = 0j
        self._sp_prev = False

    @classmethod
    def for_bank(
        cls, bank: ResonatorBank, channel: int = 0, receiver: int = 0, capacity: int = 6000
    ) -> Readout:
        if not 0 <= channel < bank.n_channels or not 0 <= receiver < bank.n_receivers:
            raise RgtbusError(
                f"readout: channel {channel} / receiver {receiver} not in the bank "
                f"({bank.n_channels} channels, {bank.n_receivers} receivers)"
            )
        return cls(complex(bank.A[channel]), bank.reset_value, capacity, receiver, channel)

    @property
    def end(self) -> int:
        return self._end

    def quench(self) -> None:
        """The bank was quenched (z = 0): the next increment starts from rest."""
        self._z_prev = 0j
        self._sp_prev = False

    def append(self, result: FeedResult) -> None:
        if result.z is None or result.spiked is None:
            raise RgtbusError("readout needs bank.feed(..., record=True) results")
        if result.start != self._end:
            raise RgtbusError(
                f"readout: result starts at sample {result.start}, expected "
                f"{self._end} (results must be appended in order)"
            )
        z = result.z[:, self.receiver, self.channel]
        s = result.spiked[:, self.receiver, self.channel]
        if not len(z):
            return
        d = increments(z, s, self.A, self.reset_value, self._z_prev, self._sp_prev)
        self._z_prev, self._sp_prev = complex(z[-1]), bool(s[-1])
        idx = (np.arange(self._end, self._end + len(d))) % self.capacity
        self._buf[idx] = d
        self._end += len(d)

    def values(self, indices: Sequence[int] | np.ndarray) -> np.ndarray:
        idx = np.asarray(indices, dtype=np.int64)
        if idx.size and (idx.min() < max(0, self._end - self.capacity) or idx.max() >= self._end):
            raise RgtbusError(
                f"readout: samples {int(idx.min())}..{int(idx.max())} are outside "
                f"the history {max(0, self._end - self.capacity)}..{self._end - 1}"
            )
        return self._buf[idx % self.capacity]


DIGITS = 12  # readout precision: far below any noise, far above rounding residue (~1e-17)


class BankReadout:
    """Streaming increment readout of every channel of one receiver at once (what a unit keeps:
    one vectorised update a window instead of one per channel).

    Values are rounded to ``DIGITS`` decimals, so a silent sample reads exactly 0 whether it was
    computed (``append``) or known (``append_quiet``): results never depend on which windows
    happened to be silent, i.e. on the window size.

    ``append(result)`` after each ``bank.feed(..., record=True)``; ``values(indices, channels)``
    gives d at absolute sample indices (any shape) of the matching channels.
    """

    def __init__(self, bank: ResonatorBank, receiver: int = 0, capacity: int = 6000) -> None:
        if not isinstance(capacity, int) or capacity < 1:
            raise RgtbusError(f"readout capacity {capacity!r} must be a positive integer")
        if not 0 <= receiver < bank.n_receivers:
            raise RgtbusError(
                f"readout: receiver {receiver} not in the bank ({bank.n_receivers} receivers)"
            )
        self.A = np.asarray(bank.A, dtype=complex)
        self.reset_value = float(bank.reset_value)
        self.receiver = receiver
        self.capacity = capacity
        self._buf = np.zeros((capacity, self.A.size))
        self._end = 0
        self._z_prev = np.zeros(self.A.size, dtype=complex)
        self._sp_prev = np.zeros(self.A.size, dtype=bool)

    @property
    def end(self) -> int:
        return self._end

    def quench(self) -> None:
        """The bank was quenched (z = 0): the next increments start from rest."""
        self._z_prev[:] = 0
        self._sp_prev[:] = False

    def append(self, result: FeedResult) -> None:
        if result.z is None or result.spiked is None:
            raise RgtbusError("readout needs bank.feed(..., record=True) results")
        if result.start != self._end:
            raise RgtbusError(
                f"readout: result starts at sample {result.start}, expected "
                f"{self._end} (results must be appended in order)"
            )
        z = result.z[:, self.receiver, :]
        sp = result.spiked[:, self.receiver, :]
        if not len(z):
            return
        d = increments(z, sp, self.A, self.reset_value, self._z_prev, self._sp_prev)
        self._z_prev = z[-1].copy()
        self._sp_prev = sp[-1].copy()
        self._store(np.round(d, DIGITS))

    def append_quiet(self, n: int, bank: ResonatorBank) -> None:
        """``n`` samples of silence were fed (``record=False``): their increments are 0, and the
        next increment starts from the bank's current state."""
        self._z_prev = bank.z[self.receiver].copy()
        self._sp_prev = bank.spiked_last[self.receiver].copy()
        self._store(np.zeros((n, self.A.size)))

    def _store(self, d: np.ndarray) -> None:
        idx = np.arange(self._end, self._end + len(d)) % self.capacity
        self._buf[idx] = d
        self._end += len(d)

    def values(self, indices: np.ndarray | Sequence[int], channels: np.ndarray | int) -> np.ndarray:
        idx = np.asarray(indices, dtype=np.int64)
        if idx.size and (idx.min() < max(0, self._end - self.capacity) or idx.max() >= self._end):
            raise RgtbusError(
                f"readout: samples {int(idx.min())}..{int(idx.max())} are outside "
                f"the history {max(0, self._end - self.capacity)}..{self._end - 1}"
            )
        return self._buf[idx % self.capacity, channels]


def decode_among(
    readout: BankReadout,
    channels: Sequence[tuple[int, float]],
    start: float,
    words: Mapping[str, Sequence[float]],
    *,
    tau: float = PAPER_TAU,
    search: int = 0,
) -> tuple[Decision, int]:
    """Which of ``channels`` ((channel index, ω) pairs) carries a code that started at ``start``
    (± ``search`` samples), and which word: the (channel, timing, word) with the smallest
    distance, all candidates scored in one vectorised step. Returns (decision, channel index)."""
    ws = _words(words, None, "decode")
    names = list(ws)
    mat = np.stack([ws[n] for n in names])  # (W, N)
    pulses = mat.shape[1]
    rows: list[tuple[int, int, tuple[int, ...]]] = []
    for ch, omega in channels:
        for shift, inst in candidate_instants(omega, start, pulses, tau, search):
            if inst[0] >= 0 and inst[-1] < readout.end:
                rows.append((ch, shift, inst))
    if not rows:
        raise RgtbusError(f"decode: no pulse instants of a code at {start:g} s are in the readout")
    inst = np.array([r[2] for r in rows])
    chans = np.array([r[0] for r in rows])
    vals = readout.values(inst, chans[:, None])  # (M, N)
    dist = np.linalg.norm(vals[:, None, :] - mat[None, :, :], axis=2)  # (M, W)
    best_w = dist.argmin(axis=1)
    best_d = dist[np.arange(len(rows)), best_w]
    m = int(np.argmin(best_d))  # the first minimum: channels in order, nearest shift first
    w = int(best_w[m])
    same = np.all(mat == mat[w], axis=1)
    others = dist[m][~same]
    margin = float(others.min() - dist[m, w]) if others.size else math.inf
    sep = float(np.linalg.norm(mat[~same] - mat[w], axis=1).min()) if others.size else 0.0
    conf = margin / sep if sep > 0 else (1.0 if not others.size else 0.0)
    ch, shift, instants = rows[m]
    return Decision(
        names[w], float(dist[m, w]), margin, conf, tuple(float(x) for x in vals[m]), instants, shift
    ), ch


@dataclass(frozen=True)
class Decision:
    """A decoded code: ``name`` of the nearest word, its Euclidean ``distance`` to the read
    ``values``, ``margin`` (runner-up distance minus best), ``confidence`` (margin over the
    best–runner-up word distance, 1 at the word, 0 half-way), and the timing ``shift`` (samples)
    and ``instants`` used."""

    name: str
    distance: float
    margin: float
    confidence: float
    values: tuple[float, ...]
    instants: tuple[int, ...] = ()
    shift: int = 0


def _words(
    words: Mapping[str, Sequence[float]], n: int | None, where: str
) -> dict[str, np.ndarray]:
    if not words:
        raise RgtbusError(f"{where}: no candidate words")
    out = {str(k): np.asarray(v, dtype=float) for k, v in words.items()}
    for k, v in out.items():
        if v.ndim != 1 or (n is not None and v.size != n):
            raise RgtbusError(f"{where}: word {k!r} has {v.size} pulses, expected {n}")
    return out


def nearest(values: Sequence[float] | np.ndarray, words: Mapping[str, Sequence[float]]) -> Decision:
    """Maximum-likelihood (nearest Euclidean) word for the values read at a code's instants.

    Words equal to the best (e.g. ``id`` and ``alliance``) are not counted as runners-up.
    """
    v = np.asarray(values, dtype=float)
    ws = _words(words, v.size, "nearest")
    scored = sorted((float(np.linalg.norm(v - w)), name) for name, w in ws.items())
    best_d, best = scored[0]
    rest = [(d, n) for d, n in scored[1:] if not np.array_equal(ws[n], ws[best])]
    if rest:
        margin = rest[0][0] - best_d
        sep = float(np.linalg.norm(ws[rest[0][1]] - ws[best]))
        conf = margin / sep if sep > 0 else 0.0
    else:
        margin, conf = math.inf, 1.0
    return Decision(best, best_d, margin, conf, tuple(float(x) for x in v))


def candidate_instants(
    omega: float, start: float, pulses: int, tau: float = PAPER_TAU, search: int = 0
) -> list[tuple[int, tuple[int, ...]]]:
    """Every distinct pulse-instant tuple for starts within ± ``search`` samples of ``start``,
    as (shift in samples, instants), nearest shift first."""
    period = 2 * math.pi / omega
    t_lo, t_hi = start - search * tau, start + search * tau
    cuts = {t_lo, t_hi}
    for j in range(pulses):
        # instant j changes where (t + j·T)/τ crosses h + 1/2
        h_lo = math.floor((t_lo + j * period) / tau - 0.5)
        h_hi = math.ceil((t_hi + j * period) / tau - 0.5)
        for h in range(h_lo, h_hi + 1):
            t = (h + 0.5) * tau - j * period
            if t_lo < t < t_hi:
                cuts.add(t)
    pts = sorted(cuts)
    probes = [start] + [(a + b) / 2 for a, b in itertools.pairwise(pts)]
    seen: dict[tuple[int, ...], int] = {}
    for t in probes:
        if t < 0:
            continue
        inst = tuple(round((t + j * period) / tau) for j in range(pulses))
        shift = inst[0] - round(start / tau)
        if inst not in seen or abs(shift) < abs(seen[inst]):
            seen[inst] = shift
    return sorted(((s, i) for i, s in seen.items()), key=lambda p: (abs(p[0]), p[0]))


def decode_code(
    readout: Readout | np.ndarray,
    omega: float,
    start: float,
    words: Mapping[str, Sequence[float]],
    *,
    tau: float = PAPER_TAU,
    search: int = 0,
    offset: int = 0,
) -> Decision:
    """Decode one code on ``omega`` that started at ``start`` s (± ``search`` samples).

    ``readout`` is a :class:`Readout` or a 1-D array of d whose element 0 is absolute sample
    ``offset``.  Returns the best fit over timing candidates (smallest distance, then shift).
    """
    ws = _words(words, None, "decode")
    n = {w.size for w in ws.values()}
    if len(n) != 1:
        raise RgtbusError("decode: candidate words have different lengths")
    pulses = n.pop()
    best: Decision | None = None
    for shift, inst in candidate_instants(omega, start, pulses, tau, search):
        try:
            vals = _read(readout, inst, offset)
        except RgtbusError:
            if search:
                continue
            raise
        dec = nearest(vals, ws)
        if best is None or dec.distance < best.distance - 1e-12:
            best = Decision(
                dec.name, dec.distance, dec.margin, dec.confidence, dec.values, inst, shift
            )
    if best is None:
        raise RgtbusError(
            f"decode: no pulse instants of the code at {start:g} s are in the readout"
        )
    return best


def _read(readout: Readout | np.ndarray, inst: Sequence[int], offset: int) -> np.ndarray:
    if isinstance(readout, Readout):
        return readout.values(inst)
    arr = np.asarray(readout)
    idx = np.asarray(inst, dtype=np.int64) - offset
    if idx.min() < 0 or idx.max() >= arr.shape[0]:
        raise RgtbusError(
            f"decode: pulse instants {list(inst)} fall outside the readout "
            f"(samples {offset}..{offset + arr.shape[0] - 1})"
        )
    return arr[idx]


def start_from_spike(spike_sample: int, omega: float, pulses: int, tau: float = PAPER_TAU) -> float:
    """Start time implied by a spike at a code's last pulse (the ID-code fires there)."""
    return spike_sample * tau - (pulses - 1) * 2 * math.pi / omega


def accept_id(
    readout: Readout | np.ndarray,
    spike_sample: int,
    omega: float,
    codebook: Codebook,
    *,
    tau: float = PAPER_TAU,
    search: int = 3,
    offset: int = 0,
    accept_radius: float | None = None,
) -> tuple[bool, Decision]:
    """Judge a spike on the sender's own ω: accepted iff the code there decodes as the ID-code
    among all distinct words, within ``accept_radius`` (default half the codebook's
    ``min_distance``)."""
    start = max(0.0, start_from_spike(spike_sample, omega, codebook.pulses, tau))
    dec = decode_code(
        readout, omega, start, codebook.distinct_words(), tau=tau, search=search, offset=offset
    )
    radius = codebook.min_distance / 2 if accept_radius is None else accept_radius
    return dec.name == "id" and dec.distance <= radius, dec


def decode_joint(
    readout: Readout | np.ndarray,
    transmissions: Sequence[tuple[Sequence[int], Mapping[str, Sequence[float]]]],
    *,
    offset: int = 0,
) -> list[Decision]:
    """Decode overlapping transmissions together.

    ``transmissions``: (pulse instants, candidate words) per transmitter.  Over the union U of
    instants the readout is ``d_U = M·c`` (M sums the pulses landing on each sample): the
    per-transmitter values reported are the least-squares estimate of c (minimum norm when
    pulses coincide), and the names the word combination with the smallest residual
    ``‖d_U − M·c‖`` — exhaustive up to ``MAX_EXHAUSTIVE`` combinations, else coordinate descent.
    ``distance`` is that residual, ``margin`` the residual increase of the best combination that
    changes this transmitter's word.
    """
    if not transmissions:
        raise RgtbusError("decode_joint: no transmissions")
    insts = [np.asarray(i, dtype=np.int64) for i, _ in transmissions]
    wsets = [
        _words(w, len(i), f"decode_joint transmission {j}")
        for j, ((_, w), i) in enumerate(zip(transmissions, insts, strict=True))
    ]
    union = np.unique(np.concatenate(insts))
    d = _read(readout, union, offset)
    cols = []
    for inst in insts:
        for k in inst:
            col = np.zeros(union.size)
            col[np.searchsorted(union, k)] += 1.0
            cols.append(col)
    M = np.stack(cols, axis=1)
    c_hat = np.linalg.lstsq(M, d, rcond=None)[0]
    bounds = np.cumsum([0] + [len(i) for i in insts])
    names = [list(w) for w in wsets]
    mats = [np.stack([wsets[j][n] for n in names[j]]) for j in range(len(insts))]
    # Contribution of each candidate word of transmitter j to d_U.
    contrib = [m @ M[:, bounds[j] : bounds[j + 1]].T for j, m in enumerate(mats)]
    sizes = [len(n) for n in names]

    def resid(choice: Sequence[int]) -> float:
        return float(np.linalg.norm(d - sum(contrib[j][c] for j, c in enumerate(choice))))

    if math.prod(sizes) <= MAX_EXHAUSTIVE:
        combos = list(itertools.product(*[range(s) for s in sizes]))
        total = np.stack([sum(contrib[j][c] for j, c in enumerate(ch)) for ch in combos])
        res = np.linalg.norm(d[None, :] - total, axis=1)
        b = int(np.argmin(res))
        best = combos[b]
        margins = []
        for j in range(len(insts)):
            other = [
                r
                for r, ch in zip(res, combos, strict=True)
                if not np.array_equal(mats[j][ch[j]], mats[j][best[j]])
            ]
            margins.append(float(min(other) - res[b]) if other else math.inf)
        best_res = float(res[b])
    else:
        choice = [
            int(np.argmin(np.linalg.norm(mats[j] - c_hat[bounds[j] : bounds[j + 1]], axis=1)))
            for j in range(len(insts))
        ]
        for _ in range(20):
            changed = False
            for j in range(len(insts)):
                rest = d - sum(contrib[i][c] for i, c in enumerate(choice) if i != j)
                cj = int(np.argmin(np.linalg.norm(rest[None, :] - contrib[j], axis=1)))
                if cj != choice[j]:
                    choice[j], changed = cj, True
            if not changed:
                break
        best = tuple(choice)
        best_res = resid(best)
        margins = []
        for j in range(len(insts)):
            alts = [
                resid([*best[:j], c, *best[j + 1 :]])
                for c in range(sizes[j])
                if not np.array_equal(mats[j][c], mats[j][best[j]])
            ]
            margins.append(min(alts) - best_res if alts else math.inf)
    out = []
    for j in range(len(insts)):
        w = mats[j][best[j]]
        others = [m for m in mats[j] if not np.array_equal(m, w)]
        sep = min((float(np.linalg.norm(m - w)) for m in others), default=0.0)
        conf = margins[j] / sep if sep > 0 and math.isfinite(margins[j]) else 1.0
        out.append(
            Decision(
                names[j][best[j]],
                best_res,
                margins[j],
                conf,
                tuple(float(x) for x in c_hat[bounds[j] : bounds[j + 1]]),
                tuple(int(k) for k in insts[j]),
            )
        )
    return out
