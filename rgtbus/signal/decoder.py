"""Detection and decoding (docs/model.md): from spikes and resonator states to code values.

- **Detection**: a spike on ω_s says "something arrived on ω_s" (an ID-code spike: "s transmits").
- **Increment readout**: the resonator's update is ``z[k] = A·z[k-1] + i·u[k]``, so
  ``d[k] = Im(z[k] − ẑ[k])`` recovers the medium sample u[k], where ẑ[k] is the state at k
  before its input (``A·z[k-1]``, or after a spike the reset state).  The bank computes it
  (``resonate``, readout=True) at the samples that carry input, rounded to 12 decimals; every
  other sample reads 0.  Any channel of a receiver gives the same d (they all hear the same
  sample); ``ReadoutHistory`` keeps the last seconds of it for decoding.
- **Nearest codeword** (``rgtbus.signal.nearest``, the one rule every decode here uses): with
  white Gaussian noise on the medium the values at a code's pulse instants are
  ``word + noise``, so the maximum-likelihood word is the nearest (Euclidean); the margin is
  how much farther the runner-up is.
- **Joint decoding** (``rgtbus.signal.joint``): transmitters whose pulses share samples are
  decoded together.
- **Timing search**: when the start is known only from a spike, try every distinct set of pulse
  instants within ± ``search`` samples and keep the best fit (smallest residual, then the
  smallest shift).
- **ID acceptance**: an ID is accepted only if the code on the sender's own frequency decodes as
  the ID-code among all distinct words, within ``accept_radius`` r (default d_min / 2)::

      accept  ⇔  nearest(v, distinct words) = id  and  |v − w_id| ≤ r

  — the paper mode a↔c crosstalk fires ω_a for some codes sent on ω_c; their values at ω_a's
  instants are far from the ID-code.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from rgtbus.errors import BadInput, RgtbusError
from rgtbus.signal.codebook import Codebook
from rgtbus.signal.kernels import read_rows, timings
from rgtbus.signal.nearest import alphabetical, in_order
from rgtbus.signal.resonator import PAPER_TAU, FeedResult, ResonatorBank
from rgtbus.signal.rules import NEAREST, Rule
from rgtbus.timebase import time_of


class ReadoutHistory:
    """The increment readout of a bank's receivers over the last ``capacity`` samples.

    ``extend(result)`` after every advance of the bank with ``readout=True`` (in order): the
    samples that carried input read their increment, every other sample reads 0 (silence).
    ``values(indices, channels, receiver)`` gives d at absolute sample indices (any shape) of
    the matching channels; ``of(receiver)`` is one receiver's view (what a unit decodes from).
    A quench needs nothing here: the bank's readout already restarts from rest.

    Only the samples that carried input are kept (sorted, with their readout): a run's medium
    is nearly all silence, so the history costs what was heard, not what was waited through.
    """

    def __init__(
        self, channels: int, capacity: int = 6000, receivers: int = 1, window: int = 1
    ) -> None:
        if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 1:
            raise BadInput(f"readout capacity {capacity!r} must be a positive integer")
        if not isinstance(channels, int) or channels < 1:
            raise BadInput(f"readout channels {channels!r} must be a positive integer")
        if not isinstance(receivers, int) or receivers < 1:
            raise BadInput(f"readout receivers {receivers!r} must be a positive integer")
        if window not in (1, 2):
            raise BadInput(f"readout window {window!r} must be 1 or 2 samples")
        self.channels = channels
        self.capacity = capacity
        self.receivers = receivers
        # samples a read adds up from its instant on: 2 where pulses land off their samples
        # (delays, clocks: ``rgtbus.signal.channel``), so a pulse split over two is read whole
        self.window = window
        # Samples that carried input (ascending) and their readout, kept in buffers that grow
        # by doubling: [lo, hi) is the history. Appending costs what is appended (amortised),
        # not a copy of the whole history (many codes at once make a long history).
        # One value per receiver and sample: every channel of a receiver reads the same d (the
        # sample it heard; docs/model.md), so keeping each channel's copy would only multiply
        # the memory by the number of channels. The first channel's value is kept; the
        # channels' values agree to the readout's rounding (1e-12).
        self._buf_rows = np.zeros(16, dtype=np.int64)
        self._buf_vals = np.zeros((16, receivers, 1))
        # per row: whether its receivers' values differ (bit for bit); where none of the rows
        # a read touches does, every receiver reads what the first does (``gather_distinct``)
        self._buf_mixed = np.zeros(16, dtype=bool)
        self._lo = self._hi = 0
        self._end = 0  # absolute index one past the newest sample

    @property
    def _rows(self) -> np.ndarray:
        return self._buf_rows[self._lo : self._hi]

    @property
    def _vals(self) -> np.ndarray:
        return self._buf_vals[self._lo : self._hi]

    def _append(self, rows: np.ndarray, values: np.ndarray) -> None:
        k = rows.size
        if self._hi + k > self._buf_rows.size:
            live = self._hi - self._lo
            size = self._buf_rows.size
            if live + k <= size // 2:  # room enough once the history moves to the front
                # in place: a new buffer beside the old one would hold the history twice
                # (n receivers' values a row: the largest array of a large run)
                self._buf_rows[:live] = self._buf_rows[self._lo : self._hi].copy()
                self._buf_mixed[:live] = self._buf_mixed[self._lo : self._hi].copy()
                for a in range(0, live, _MOVE_ROWS):  # in pieces: no copy of it all at once
                    b = min(live, a + _MOVE_ROWS)
                    self._buf_vals[a:b] = self._buf_vals[self._lo + a : self._lo + b]
                self._lo, self._hi = 0, live
            else:
                while live + k > size // 2:  # keep room: a half-full buffer after compaction
                    size *= 2
                new_rows = np.zeros(size, dtype=np.int64)
                new_vals = np.zeros((size, *self._buf_vals.shape[1:]))
                new_mixed = np.zeros(size, dtype=bool)
                new_rows[:live] = self._buf_rows[self._lo : self._hi]
                new_vals[:live] = self._buf_vals[self._lo : self._hi]
                new_mixed[:live] = self._buf_mixed[self._lo : self._hi]
                self._buf_rows, self._buf_vals = new_rows, new_vals
                self._buf_mixed = new_mixed
                self._lo, self._hi = 0, live
        self._buf_rows[self._hi : self._hi + k] = rows
        vals = self._buf_vals[self._hi : self._hi + k]
        vals[...] = values
        bits = vals.reshape(k, -1).view(np.int64)
        self._buf_mixed[self._hi : self._hi + k] = (bits != bits[:, :1]).any(axis=1)
        self._hi += k

    @classmethod
    def for_bank(cls, bank: ResonatorBank, capacity: int = 6000) -> ReadoutHistory:
        """A history of every receiver and channel of ``bank``."""
        return cls(bank.n_channels, capacity, bank.n_receivers)

    @property
    def end(self) -> int:
        """The absolute sample one past the newest in the history."""
        return self._end

    def extend(self, result: FeedResult) -> None:
        """Append one advance's readout (``bank.advance(..., readout=True)`` or ``feed``)."""
        if result.readout is None or result.readout_rows is None:
            raise BadInput("readout history needs results of an advance with readout=True")
        self.store(result.start, result.n, result.readout_rows, result.readout)

    def store(self, start: int, n: int, rows: np.ndarray, values: np.ndarray) -> None:
        """Samples [start, start + n) were processed; ``values`` (len(rows), receivers,
        channels) is the readout at the absolute samples ``rows`` among them; others read 0."""
        if start != self._end:
            raise BadInput(
                f"readout: samples from {start} appended, expected {self._end} (in order)"
            )
        end = start + n
        if not len(rows) and (not self._rows.size or self._rows[0] >= end - self.capacity):
            self._end = end  # silence, and nothing fell out of the history
            return
        old = int(self._rows.searchsorted(end - self.capacity))  # out of the history now
        rows = np.asarray(rows, dtype=np.int64)
        if rows.size:
            if rows[0] < start or rows[-1] >= end or (rows[1:] <= rows[:-1]).any():
                raise BadInput(f"readout: rows must be ascending samples in {start}..{end - 1}")
            keep = rows >= end - self.capacity
            self._lo += old
            # the first channel before the rows: an advance's readout is a view broadcast
            # over every channel (receivers × channels a row)
            self._append(rows[keep], np.asarray(values)[:, :, :1][keep])
        elif old:
            self._lo += old
        self._end = start + n

    def values(
        self,
        indices: np.ndarray | Sequence[int],
        channels: np.ndarray | int | slice,
        receiver: int = 0,
        span: tuple[int, int] | None = None,
    ) -> np.ndarray:
        """d at ``indices`` (``span``: their smallest and largest, when the caller knows)."""
        idx = np.asarray(indices, dtype=np.int64)
        if self.window > 1:
            span = None if span is None else (span[0], span[1] + self.window - 1)
        self._check(idx, span)
        pos, hit = self._find(idx)
        got = np.where(hit, self._vals[pos, receiver, 0], 0.0)
        for w in range(1, self.window):
            pos, hit = self._find(idx + w)
            got = got + np.where(hit, self._vals[pos, receiver, 0], 0.0)
        if isinstance(channels, slice):  # the channels make a trailing axis
            width = len(range(self.channels)[channels])
            return np.repeat(got[..., None], width, axis=-1)
        # an int, or an array that broadcasts against the indices (as numpy indexing would)
        return np.broadcast_to(got, np.broadcast_shapes(got.shape, np.shape(channels))).copy()

    def gather(
        self,
        indices: np.ndarray,
        channels: np.ndarray,
        span: tuple[int, int] | None = None,
    ) -> np.ndarray:
        """d at ``indices`` (M, N), row m on channel ``channels[m]``, for every receiver at
        once: (receivers, M, N)."""
        idx = np.ascontiguousarray(indices, dtype=np.int64)
        if self.window > 1:
            span = None if span is None else (span[0], span[1] + self.window - 1)
        self._check(idx, span)
        chans = np.zeros(np.asarray(channels).shape, dtype=np.int64)  # every channel reads d
        got: np.ndarray = read_rows(self._rows, self._vals, idx, chans)
        for w in range(1, self.window):
            got = got + read_rows(self._rows, self._vals, idx + w, chans)
        return got

    def gather_distinct(
        self, indices: np.ndarray, channels: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``gather``'s values, each distinct receiver's once (bit for bit): (S, M, N), and
        each receiver's set, an index into them (R,). Where no row the read touches holds
        values that differ between receivers (a medium without noise heard through equal
        gains), only the first receiver's are read."""
        idx = np.ascontiguousarray(indices, dtype=np.int64)
        if idx.size and self.receivers > 1:
            lo, hi = int(idx.min()), int(idx.max()) + self.window - 1
            self._check(idx, (lo, hi))
            rows = self._rows
            a, b = int(rows.searchsorted(lo)), int(rows.searchsorted(hi, side="right"))
            if not self._buf_mixed[self._lo + a : self._lo + b].any():
                first = np.ascontiguousarray(self._vals[:, :1])
                chans = np.zeros(np.asarray(channels).shape, dtype=np.int64)
                got: np.ndarray = read_rows(rows, first, idx, chans)
                for w in range(1, self.window):
                    got = got + read_rows(rows, first, idx + w, chans)
                return got, np.zeros(self.receivers, dtype=np.int64)
        every = self.gather(idx, channels)
        firsts, which = _distinct(every)
        return every[firsts], which

    def _find(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where each sample's readout is kept (clipped), and whether it is (else it reads 0)."""
        if not self._rows.size:
            return np.zeros(idx.shape, dtype=np.int64), np.zeros(idx.shape, dtype=bool)
        pos = np.minimum(self._rows.searchsorted(idx), self._rows.size - 1)
        return pos, self._rows[pos] == idx

    def _check(self, idx: np.ndarray, span: tuple[int, int] | None) -> None:
        if idx.size:
            lo, hi = (
                span if span is not None else (int(idx.min()), int(idx.max()) + self.window - 1)
            )
            if lo < max(0, self._end - self.capacity) or hi >= self._end:
                raise BadInput(
                    f"readout: samples {lo}..{hi} are outside "
                    f"the history {max(0, self._end - self.capacity)}..{self._end - 1}"
                )

    def of(self, receiver: int) -> ReceiverReadout:
        """One receiver's view of the history (what a unit decodes from)."""
        if not 0 <= receiver < self.receivers:
            raise BadInput(f"readout: receiver {receiver} not in the history ({self.receivers})")
        return ReceiverReadout(self, receiver)


@dataclass(frozen=True)
class ReceiverReadout:
    """One receiver's readout in a shared history."""

    history: ReadoutHistory
    receiver: int

    @property
    def end(self) -> int:
        """The absolute sample one past the newest in the history."""
        return self.history.end

    def values(
        self,
        indices: np.ndarray | Sequence[int],
        channels: np.ndarray | int,
        span: tuple[int, int] | None = None,
    ) -> np.ndarray:
        """This receiver's d at ``indices`` (see ``ReadoutHistory.values``)."""
        return self.history.values(indices, channels, self.receiver, span)


Readout = ReadoutHistory | ReceiverReadout


def decode_among(
    readout: Readout,
    channels: Sequence[tuple[int, float]],
    start: float,
    words: Words,
    *,
    tau: float = PAPER_TAU,
    search: int = 0,
) -> tuple[Decision, int]:
    """Which of ``channels`` ((channel index, ω) pairs) carries a code that started at ``start``
    (± ``search`` samples), and which word: the (channel, timing, word) with the smallest
    distance, all candidates scored in one vectorised step. Returns (decision, channel index)."""
    history = readout.history if isinstance(readout, ReceiverReadout) else readout
    receiver = readout.receiver if isinstance(readout, ReceiverReadout) else 0
    chans = tuple((int(c), float(w)) for c, w in channels)
    return decode_among_each(history, chans, float(start), words, tau=tau, search=search)[receiver]


def _heard_candidates(
    history: ReadoutHistory,
    channels: tuple[tuple[int, float], ...],
    start: float,
    mat: np.ndarray,
    tau: float,
    search: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The candidates of a code at ``start`` that have been heard (channel, shift, instants)
    and every receiver's values at them, (R, M, N): what ``decode_among_each`` and
    ``decode_among_columns`` score."""
    chans, shifts, inst, lo, hi = _candidates(channels, start, mat.shape[1], tau, search)
    if hi >= history.end:  # rarely: candidates past what has been heard
        ok = inst[:, -1] < history.end
        if not ok.any():
            raise BadInput(
                f"decode: no pulse instants of a code at {start:g} s are in the readout"
            )
        chans, shifts, inst = chans[ok], shifts[ok], inst[ok]
        hi = int(inst[:, -1].max())
    return chans, shifts, inst, history.gather(inst, chans, span=(lo, hi))


def decode_among_each(
    history: ReadoutHistory,
    channels: tuple[tuple[int, float], ...],
    start: float,
    words: Words,
    *,
    tau: float = PAPER_TAU,
    search: int = 0,
) -> list[tuple[Decision, int]]:
    """``decode_among`` for every receiver of ``history`` at once, in receiver order: the
    values of all receivers are read in one step and every distinct set of values is scored
    once (receivers that heard the same decode the same; each result depends only on that
    receiver's own readout)."""
    names, mat = word_matrix(words, None, "decode")
    rule = rule_of(words)
    chans, shifts, inst, every = _heard_candidates(history, channels, start, mat, tau, search)
    order = in_order(mat.shape[0])
    out: list[tuple[Decision, int]] = []
    seen: dict[bytes, tuple[Decision, int]] = {}
    for vals in every:
        key = vals.tobytes()
        got = seen.get(key)
        if got is None:
            m, w, best, margin, sep = rule.one(vals, mat, order)
            decision = Decision(
                names[w],
                best,
                margin,
                rule.confidence(margin, sep),
                tuple(vals[m].tolist()),
                tuple(inst[m].tolist()),
                int(shifts[m]),
            )
            got = seen[key] = (decision, int(chans[m]))
        out.append(got)
    return out


def nearest_each(
    history: ReadoutHistory, samples: Sequence[int], channel: int, words: Words
) -> list[Decision]:
    """``nearest`` of the values at ``samples`` on ``channel``, for every receiver of
    ``history`` at once (each distinct set of values scored once), in receiver order."""
    idx = np.asarray(samples, dtype=np.int64).reshape(1, -1)
    every = history.gather(idx, np.array([channel]))[:, 0]  # (R, N)
    out: list[Decision] = []
    seen: dict[bytes, Decision] = {}
    for vals in every:
        key = vals.tobytes()
        got = seen.get(key)
        if got is None:
            got = seen[key] = nearest(vals, words)
        out.append(got)
    return out


def _distinct(every: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The receivers whose values (``every``: receivers first) differ, bit for bit: the first
    receiver of each distinct set, and each receiver's set (an index into the first)."""
    flat = every.reshape(every.shape[0], -1)
    if (flat == flat[0]).all():  # a noise-free medium through equal gains: one set
        return np.zeros(1, dtype=np.int64), np.zeros(flat.shape[0], dtype=np.int64)
    firsts: list[int] = []
    seen: dict[bytes, int] = {}
    which = np.empty(flat.shape[0], dtype=np.int64)
    for r, vals in enumerate(flat):
        k = seen.setdefault(vals.tobytes(), len(firsts))
        if k == len(firsts):
            firsts.append(r)
        which[r] = k
    return np.array(firsts, dtype=np.int64), which


def decode_among_columns(
    history: ReadoutHistory,
    channels: tuple[tuple[int, float], ...],
    start: float,
    words: Words,
    *,
    tau: float = PAPER_TAU,
    search: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``decode_among_each`` as columns over the receivers: each one's word (an index into
    the words' names), channel index and margin, without a ``Decision`` each (a unit's batch
    of decodes reads them as arrays; every distinct set of values is scored once, as there)."""
    _, mat = word_matrix(words, None, "decode")
    one = rule_of(words).one
    chans, _, _, every = _heard_candidates(history, channels, start, mat, tau, search)
    order = in_order(mat.shape[0])
    firsts, which = _distinct(every)
    word = np.empty(firsts.size, dtype=np.int64)
    chan = np.empty(firsts.size, dtype=np.int64)
    margin = np.empty(firsts.size)
    for k, r in enumerate(firsts.tolist()):
        m, word[k], _, margin[k], _ = one(every[r], mat, order)
        chan[k] = chans[m]
    return word[which], chan[which], margin[which]


def nearest_columns(
    history: ReadoutHistory, samples: Sequence[int], channel: int, words: Words
) -> tuple[np.ndarray, np.ndarray]:
    """``nearest_each`` as columns over the receivers: each one's word (an index into the
    words' names) and margin."""
    idx = np.asarray(samples, dtype=np.int64).reshape(1, -1)
    every = history.gather(idx, np.array([channel]))[:, 0]  # (R, N)
    names, mat = word_matrix(words, every.shape[1], "nearest")
    rank = alphabetical(names)
    one = rule_of(words).one
    firsts, which = _distinct(every)
    word = np.empty(firsts.size, dtype=np.int64)
    margin = np.empty(firsts.size)
    for k, r in enumerate(firsts.tolist()):
        reads = np.ascontiguousarray(every[r : r + 1])
        _, word[k], _, margin[k], _ = one(reads, mat, rank)
    return word[which], margin[which]


def nearest_many_columns(
    history: ReadoutHistory, instants: np.ndarray, channels: np.ndarray, words: Words, rank: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P decodes at once, each with M candidate reads: ``instants`` (P, M, N) on ``channels``
    (P, M), scored by the words' rule (``WordSet.rule``) for every receiver of ``history``. Returns
    each decode's (P, R) candidate row, word (an index into the words' names) and margin.
    ``rank`` breaks ties: ``"order"`` (the first word, as ``decode_among_columns``) or
    ``"name"`` (alphabetical, as ``nearest_columns``). Each distinct receiver's values are
    scored once, all P decodes in one vectorised step (``Rule.many``: the bits of the
    compiled form), so the answers are those of P calls of the one-decode forms."""
    P, M, N = instants.shape
    names, mat = word_matrix(words, N, "decode")
    order = in_order(mat.shape[0]) if rank == "order" else alphabetical(names)
    # each distinct receiver's values (S, P·M, N), and each receiver's set
    values, which = history.gather_distinct(instants.reshape(P * M, N), channels.reshape(P * M))
    S = values.shape[0]
    got = rule_of(words).many(values.reshape(S * P, M, N), mat, order)
    back = (S, P)
    return (
        got.row.reshape(back)[which].T,
        got.word.reshape(back)[which].T,
        got.margin.reshape(back)[which].T,
    )


def code_candidates(
    channel: int, omega: float, start: float, pulses: int, tau: float, search: int
) -> tuple[np.ndarray, np.ndarray]:
    """A code's candidates on one channel as ``decode_among_columns`` reads them: (M,)
    channel indexes and (M, pulses) instants, nearest shift first (``_candidates``, uncached:
    a shared queue reads each code once for every unit)."""
    chans, _, inst = timings(*_one_channel(channel, omega), start, pulses, tau, search)
    if start < (search + 1) * tau and inst[:, 0].min() < 0:  # before the first sample: left out
        keep = inst[:, 0] >= 0
        if not keep.any():
            raise BadInput(
                f"decode: no pulse instants of a code at {start:g} s are in the readout"
            )
        chans, inst = chans[keep], inst[keep]
    return chans, inst


@lru_cache(maxsize=4096)
def _one_channel(channel: int, omega: float) -> tuple[np.ndarray, np.ndarray]:
    """A channel index and its ω as ``timings`` takes them (one array each, made once)."""
    return np.array([channel], dtype=np.int64), np.array([omega])


@lru_cache(maxsize=64)  # every unit of a run decodes the same codes, at about the same time
def _candidates(
    channels: tuple[tuple[int, float], ...], start: float, pulses: int, tau: float, search: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """Every (channel, timing shift, instants) candidate, channels in order, nearest shift
    first: three read-only arrays (M,), (M,), (M, pulses); and the instants' span. Candidates
    before the first sample are left out."""
    chans, shifts, insts = _timings(
        tuple(c for c, _ in channels), tuple(w for _, w in channels), start, pulses, tau, search
    )
    keep = insts[:, 0] >= 0
    if not keep.any():
        raise BadInput(f"decode: no pulse instants of a code at {start:g} s are in the readout")
    a, b, c = chans[keep], shifts[keep], insts[keep]
    for arr in (a, b, c):
        arr.flags.writeable = False
    return a, b, c, int(c[:, 0].min()), int(c[:, -1].max())


def _timings(
    chans: tuple[int, ...],
    omegas: tuple[float, ...],
    start: float,
    pulses: int,
    tau: float,
    search: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every distinct pulse-instant tuple, per channel, of a code on ω that starts within
    ± ``search`` samples of ``start``: (channel, shift, instants) rows, channels in the order
    given, within a channel the nearest shift first (then the earlier).

    Instant j of a start t is round((t + j·T)/τ) (the rule of ``pulse_samples``); it changes
    only where (t + j·T)/τ crosses h + ½. So the distinct tuples are those of ``start`` and of
    the midpoints between consecutive crossings (and the window's ends); tuples of starts
    before 0 are left out. Compiled (``_walk.timings``); ``reference.reference_timings``
    states it literally."""
    return timings(
        np.asarray(chans, dtype=np.int64),
        np.asarray(omegas, dtype=np.float64),
        float(start),
        int(pulses),
        float(tau),
        int(search),
    )


_MOVE_ROWS = 256  # rows of a history moved to the front of its buffer at a time


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


@dataclass(frozen=True, eq=False)
class WordSet:
    """Candidate words as names and a read-only (W, N) matrix, and the ``rule`` they are
    decoded by (``rgtbus.signal.rules``: every decode form asks the set): built once, decoded
    often. Equal (and hashed) by value, so equal sets from different units share cached
    work."""

    names: tuple[str, ...]
    matrix: np.ndarray
    rule: Rule = NEAREST

    def __post_init__(self) -> None:
        key = (self.names, self.matrix.shape, self.matrix.tobytes(), self.rule.name)
        object.__setattr__(self, "_key", key)
        object.__setattr__(self, "_hash", hash(key))  # asked at every decode: once

    def __eq__(self, other: object) -> bool:
        return isinstance(other, WordSet) and self._key == other._key  # type: ignore[attr-defined]

    def __hash__(self) -> int:
        return self._hash  # type: ignore[attr-defined,no-any-return]

    @classmethod
    def of(
        cls, words: Mapping[str, Sequence[float]], where: str = "words", rule: Rule = NEAREST
    ) -> WordSet:
        """The set of these words, decoded by ``rule``; equal sets asked for while one is
        alive are one object, so a cache keyed by it finds it by identity (``==`` on a set
        compares its bytes, and every decode asks)."""
        made = cls(*word_matrix(words, None, where), rule)
        return _WORD_SETS.setdefault(made._key, made)  # type: ignore[attr-defined]


_WORD_SETS: weakref.WeakValueDictionary[tuple[object, ...], WordSet] = weakref.WeakValueDictionary()


Words = Mapping[str, Sequence[float]] | Mapping[str, np.ndarray] | WordSet


def rule_of(words: Words) -> Rule:
    """The rule ``words`` are decoded by: a word set's own, else nearest-word."""
    return words.rule if isinstance(words, WordSet) else NEAREST


def word_matrix(words: Words, n: int | None, where: str) -> tuple[tuple[str, ...], np.ndarray]:
    """Names and the (W, N) matrix of candidate words (checked; cached per word set)."""
    if isinstance(words, WordSet):
        if n is not None and words.matrix.shape[1] != n:
            raise BadInput(
                f"{where}: word {words.names[0]!r} has {words.matrix.shape[1]} pulses, expected {n}"
            )
        return words.names, words.matrix
    if not words:
        raise BadInput(f"{where}: no candidate words")
    try:
        key = tuple((str(k), tuple(float(x) for x in v)) for k, v in words.items())
    except (TypeError, ValueError):
        raise BadInput(f"{where}: words must be sequences of numbers") from None
    if len({len(v) for _, v in key}) != 1:
        raise BadInput(f"{where}: candidate words have different lengths")
    names, mat = _word_matrix(key)
    if n is not None and mat.shape[1] != n:
        raise BadInput(f"{where}: word {names[0]!r} has {mat.shape[1]} pulses, expected {n}")
    return names, mat


@lru_cache(maxsize=256)
def _word_matrix(
    key: tuple[tuple[str, tuple[float, ...]], ...],
) -> tuple[tuple[str, ...], np.ndarray]:
    mat = np.array([v for _, v in key], dtype=float)
    mat.flags.writeable = False
    return tuple(k for k, _ in key), mat


def _words(
    words: Mapping[str, Sequence[float]], n: int | None, where: str
) -> dict[str, np.ndarray]:
    names, mat = word_matrix(words, n, where)
    return dict(zip(names, mat, strict=True))


def nearest(values: Sequence[float] | np.ndarray, words: Words) -> Decision:
    """The word the values read at a code's instants are taken for, by the words' rule
    (``WordSet.rule``; plain words: the nearest in Euclidean distance, the maximum-likelihood
    word of ``rgtbus.signal.nearest``).

    Words equal to the best (e.g. ``id`` and ``alliance``) are not counted as runners-up; ties
    go to the first name in alphabetical order.
    """
    v = np.ascontiguousarray(values, dtype=float).reshape(1, -1)
    names, mat = word_matrix(words, v.shape[1], "nearest")
    rule = rule_of(words)
    _, w, best, margin, sep = rule.one(v, mat, alphabetical(names))
    read = tuple(float(x) for x in v[0])
    return Decision(names[w], best, margin, rule.confidence(margin, sep), read)


def nearer_than_silence(values: Sequence[float], word: Sequence[float]) -> bool:
    """Whether ``values`` lie strictly nearer ``word`` than the all-zero word (silence):

        sqrt(Σ_k (v_k − w_k)²) < sqrt(Σ_k v_k²)

    summed in the order ``nearest`` sums them, so the answer is ``nearest``'s between the two
    words, a tie going to silence (its name "(silence)" sorts before any code's). A few
    floats, no arrays: confirmed attention asks it of every ID (``AutonomousUnit._attend``),
    where ``nearest``'s set-up cost more than the sums."""
    to_word = to_zero = 0.0
    for v, w in zip(values, word, strict=True):
        d = float(v) - float(w)
        to_word = to_word + d * d
        to_zero = to_zero + float(v) * float(v)
    return math.sqrt(to_word) < math.sqrt(to_zero)


def candidate_instants(
    omega: float, start: float, pulses: int, tau: float = PAPER_TAU, search: int = 0
) -> list[tuple[int, tuple[int, ...]]]:
    """Every distinct pulse-instant tuple for starts within ± ``search`` samples of ``start``,
    as (shift in samples, instants), nearest shift first (see ``_timings``)."""
    _, shifts, insts = _timings((0,), (float(omega),), float(start), int(pulses), tau, search)
    return [(int(s), tuple(i)) for s, i in zip(shifts.tolist(), insts.tolist(), strict=True)]


def decode_code(
    readout: Readout | np.ndarray,
    omega: float,
    start: float,
    words: Mapping[str, Sequence[float]],
    *,
    tau: float = PAPER_TAU,
    search: int = 0,
    offset: int = 0,
    channel: int = 0,
) -> Decision:
    """Decode one code on ``omega`` that started at ``start`` s (± ``search`` samples).

    ``readout`` is a :class:`ReadoutHistory` (read on ``channel``) or a 1-D array of d whose
    element 0 is absolute sample ``offset``.  Returns the best fit over timing candidates
    (smallest distance, then shift).
    """
    ws = _words(words, None, "decode")
    n = {w.size for w in ws.values()}
    if len(n) != 1:
        raise BadInput("decode: candidate words have different lengths")
    pulses = n.pop()
    best: Decision | None = None
    for shift, inst in candidate_instants(omega, start, pulses, tau, search):
        try:
            vals = read_at(readout, inst, offset, channel)
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
        raise BadInput(
            f"decode: no pulse instants of the code at {start:g} s are in the readout"
        )
    return best


def read_at(
    readout: Readout | np.ndarray, inst: Sequence[int] | np.ndarray, offset: int, channel: int = 0
) -> np.ndarray:
    """The readout at the samples ``inst``: of a :class:`ReadoutHistory` on ``channel``, or of
    a 1-D array of d whose element 0 is absolute sample ``offset`` (refused outside it)."""
    if isinstance(readout, ReadoutHistory):
        return readout.values(inst, channel)
    arr = np.asarray(readout)
    idx = np.asarray(inst, dtype=np.int64) - offset
    if idx.min() < 0 or idx.max() >= arr.shape[0]:
        raise BadInput(
            f"decode: pulse instants {list(inst)} fall outside the readout "
            f"(samples {offset}..{offset + arr.shape[0] - 1})"
        )
    return arr[idx]


def start_from_spike(spike_sample: int, omega: float, pulses: int, tau: float = PAPER_TAU) -> float:
    """Start time implied by a spike at a code's last pulse (the ID-code fires there)."""
    return time_of(spike_sample, tau) - (pulses - 1) * 2 * math.pi / omega


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
    channel: int = 0,
) -> tuple[bool, Decision]:
    """Judge a spike on the sender's own ω: accepted iff the code there decodes as the ID-code
    among all distinct words, within ``accept_radius`` (default half the codebook's
    ``min_distance``)."""
    start = max(0.0, start_from_spike(spike_sample, omega, codebook.pulses, tau))
    dec = decode_code(
        readout,
        omega,
        start,
        codebook.distinct_words(),
        tau=tau,
        search=search,
        offset=offset,
        channel=channel,
    )
    radius = codebook.min_distance / 2 if accept_radius is None else accept_radius
    return dec.name == "id" and dec.distance <= radius, dec
