"""Resonate-and-fire receiver bank (SPEC §2): pure numpy, streaming, any receivers × channels.

Model (one resonator, eigen-frequency ω, complex state z = x + i·y, sample period τ)::

    update:  z[k] = A·z[k-1] + i·u[k]            (the medium sample u[k] is added to y = Im z)
             A = 1 + τ(b + iω)     mode "paper"  (forward Euler, the paper's equation)
             A = exp(τ(b + iω))    mode "exact"  (exact discretisation of dz/dt = (b + iω)z)
    spike:   y[k] ≥ threshold  →  spike at sample k; the recorded y[k] is ``spike_value`` (1.5)
    reset:   after a spike at k, the next sample starts from
             z' = Re(A·z[k]) + i·reset_value      (x is the Euler step of the *pre-spike* state,
             z[k+1] = z' + i·u[k+1]                y = 0.1; the medium sample is still added and the
                                                   spike rule applies to sample k+1 as to any other)

``z[k]`` always means the *pre-spike* state (y[k] may be ≥ 1); only the recorded trajectory
shows ``spike_value``.  Defaults are the paper's: b = −0.1, τ = 0.005 s, threshold 1, spike 1.5,
reset 0.1.

Two engines compute this same model:

- ``"reference"``: the obvious per-sample loop ``z = A*z; z += 1j*u; ...`` (for cross-checks).
- ``"fast"`` (default) integrates in a rotating frame.  Within an *epoch* of R samples starting at
  absolute sample E (E a multiple of R), ``z[k] = A^(k-E)·w[k]`` with
  ``w[k] = w[k-1] + i·u[k]·A^-(k-E)``: a running sum, so a block of samples is one ``cumsum`` and a
  run of zero input leaves w unchanged.  Because |A| < 1 (paper mode inside Euler's stable band,
  exact mode with b < 0), |z| cannot grow between inputs: if |z| < threshold after an input, no
  spike can occur before the next nonzero input, and those samples are skipped outright.  Lanes
  that might spike are scanned sample by sample in blocks; after each spike the lane's running sum
  is restarted from the reset state.  Powers of A come from tables indexed by k − E, the sums are
  sequential, and epochs sit on absolute sample indices, so every value is a function of the
  absolute sample index only: feeding in chunks of any size gives states and spikes *identical*
  (==) to feeding the whole waveform, and skipping gives the same values as scanning.  Against the
  reference engine the states agree to ~1e-12 relative (different rounding, not different maths);
  spikes are identical unless some y lands within ~1e-12 of the threshold.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rgtbus.errors import RgtbusError

PAPER_TAU = 0.005
PAPER_B = -0.1
PAPER_THRESHOLD = 1.0
PAPER_SPIKE_VALUE = 1.5
PAPER_RESET_VALUE = 0.1
MODES = ("paper", "exact")
ENGINES = ("fast", "reference")

# Skipping is allowed only below this |A| (needs strict decay, with room for table rounding).
_SKIP_MAX_ABS_A = 1.0 - 1e-9
# A lane counts as "might spike" when |z| ≥ threshold·(1 − _HOT_MARGIN): covers rounding of tables.
_HOT_MARGIN = 1e-9
_SPARSE_MIN_LANES = 8


def euler_limit(tau: float = PAPER_TAU, b: float = PAPER_B) -> float:
    """Largest ω (rad/s) with |1 + τ(b + iω)| < 1, i.e. where paper mode still decays.

    |1 + τb + iτω|² < 1  ⇔  ω² < −2b/τ − b²   (≈ 6.32 rad/s for the paper's b, τ).
    """
    v = -2.0 * b / tau - b * b
    return math.sqrt(v) if v > 0 else 0.0


def transition(
    omega: float, *, mode: str = "paper", tau: float = PAPER_TAU, b: float = PAPER_B
) -> complex:
    """The one-sample transition A: ``1 + τ(b + iω)`` (paper) or ``exp(τ(b + iω))`` (exact)."""
    if mode == "paper":
        return complex(1.0 + tau * b, tau * omega)
    if mode == "exact":
        return complex(np.exp(tau * complex(b, omega)))
    raise RgtbusError(f"mode {mode!r} is not one of {', '.join(MODES)}")


@dataclass
class FeedResult:
    """What one ``ResonatorBank.feed`` call produced.

    ``spikes`` is an int64 array of shape (S, 3): absolute sample index, receiver, channel; sorted
    by sample, receiver, channel.  With ``record=True``: ``z`` (n, receivers, channels) complex
    pre-spike states, ``y`` the recorded y (``spike_value`` at spike samples) and ``spiked`` the
    spike mask.  ``start`` is the absolute index of the first sample fed.
    """

    start: int
    n: int
    spikes: np.ndarray
    z: np.ndarray | None = None
    y: np.ndarray | None = None
    spiked: np.ndarray | None = None

    @property
    def x(self) -> np.ndarray | None:
        return None if self.z is None else self.z.real

    def spike_times(
        self, tau: float = PAPER_TAU, receiver: int = 0, channel: int | None = None
    ) -> np.ndarray | list[np.ndarray]:
        """Spike times in seconds (sample index × τ) of one receiver, one channel or all."""
        sel = self.spikes[self.spikes[:, 1] == receiver]
        if channel is not None:
            return sel[sel[:, 2] == channel, 0] * tau
        n_ch = 0 if self.z is None else self.z.shape[2]
        n_ch = max(n_ch, int(self.spikes[:, 2].max()) + 1 if len(self.spikes) else 0)
        return [sel[sel[:, 2] == c, 0] * tau for c in range(n_ch)]


def _validate_float(value: float, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise RgtbusError(f"{name} = {value!r} is not a number") from None
    if not math.isfinite(v):
        raise RgtbusError(f"{name} = {value!r} is not finite")
    return v


class ResonatorBank:
    """``n_receivers`` × ``len(omegas)`` resonate-and-fire neurons fed by one medium (streaming).

    Every receiver has one resonator per channel ω; all of a receiver's resonators hear the same
    sample (its own copy of the medium: per-link gain and noise are applied by the caller, see
    ``waveform.hear``).  Model, spike and reset rules: see the module docstring — update
    ``z[k] = A·z[k-1] + i·u[k]``, spike when ``Im z[k] ≥ threshold`` (recorded as ``spike_value``),
    then ``z = Re(A·z[k]) + i·reset_value`` before the next sample's input.

    ``feed(samples)`` takes an array of shape (n,) (same medium for every receiver) or
    (n, n_receivers) and returns a :class:`FeedResult`; the bank keeps its state between calls.
    """

    def __init__(
        self,
        omegas: Sequence[float] | np.ndarray,
        *,
        mode: str = "paper",
        tau: float = PAPER_TAU,
        b: float = PAPER_B,
        threshold: float = PAPER_THRESHOLD,
        spike_value: float = PAPER_SPIKE_VALUE,
        reset_value: float = PAPER_RESET_VALUE,
        n_receivers: int = 1,
        engine: str = "fast",
        epoch: int | None = None,
        block: int | None = None,
    ):
        om = np.atleast_1d(np.asarray(omegas, dtype=float))
        if om.ndim != 1 or om.size == 0:
            raise RgtbusError(f"omegas must be a non-empty list of numbers, got shape {om.shape}")
        for j, w in enumerate(om):
            if not math.isfinite(w) or w <= 0:
                raise RgtbusError(f"omega[{j}] = {w!r} must be a positive finite number (rad/s)")
        if mode not in MODES:
            raise RgtbusError(f"mode {mode!r} is not one of {', '.join(MODES)}")
        if engine not in ENGINES:
            raise RgtbusError(f"engine {engine!r} is not one of {', '.join(ENGINES)}")
        self.tau = _validate_float(tau, "tau")
        if self.tau <= 0:
            raise RgtbusError(f"tau = {tau!r} must be positive (seconds per sample)")
        self.b = _validate_float(b, "b")
        self.threshold = _validate_float(threshold, "threshold")
        self.spike_value = _validate_float(spike_value, "spike_value")
        self.reset_value = _validate_float(reset_value, "reset_value")
        if not isinstance(n_receivers, (int, np.integer)) or n_receivers < 1:
            raise RgtbusError(f"n_receivers = {n_receivers!r} must be a positive integer")
        self.omegas = om
        self.mode = mode
        self.engine = engine
        self.n_receivers = int(n_receivers)
        self.n_channels = om.size
        self.A = np.array([transition(w, mode=mode, tau=self.tau, b=self.b) for w in om])
        self._Ar = self.A.real.copy()
        self._Ai = self.A.imag.copy()
        L = self.n_receivers * self.n_channels
        self._L = L
        self._rec = np.repeat(np.arange(self.n_receivers), self.n_channels)
        self._ch = np.tile(np.arange(self.n_channels), self.n_receivers)
        self._all = np.arange(L)
        abs_a = float(np.abs(self.A).max())
        self._can_skip = abs_a < _SKIP_MAX_ABS_A and self.threshold > 0
        # Epoch length: keep |A|^±m within 1e8 so the rotating frame loses no precision.
        log_abs = float(np.abs(np.log(np.abs(self.A))).max())
        # Tables cost 32 bytes × epoch × channels: cap them near 32 MB.
        r = (
            1 << min(14, max(10, int(math.log2(max(1, (1 << 20) // om.size)))))
            if epoch is None
            else int(epoch)
        )
        if epoch is None and log_abs > 0:
            r = max(1, min(r, 2 ** math.floor(math.log2(max(1.0, 18.0 / log_abs)))))
        if r < 1:
            raise RgtbusError(f"epoch = {epoch!r} must be a positive integer")
        self._R = r
        self._block = int(block) if block else 256
        # Rows examined at once for a free-running hot lane: a spike comes a few rows into the
        # arc where sin ≥ thr/ρ, and a lane not done by then resumes in the next round (16:
        # measured best on protocol traffic).
        self._hot_block = 16
        self._span = 4096  # rows per sparse pass: bounds the work redone after each spike
        if self._block < 1:
            raise RgtbusError(f"block = {block!r} must be a positive integer")
        self._theta = np.angle(self.A)  # rotation per sample
        with np.errstate(divide="ignore"):
            self._lam = -np.log(np.abs(self.A))  # decay rate per sample (> 0 when skipping)
        self._tables()
        self.reset()

    # -- state ------------------------------------------------------------------------------
    def _tables(self) -> None:
        m = np.arange(self._R + 1, dtype=float)[:, None]
        log_a = np.log(self.A)[None, :]
        p = np.exp(m * log_a)  # P[m] = A^m
        q = np.exp(-m[:-1] * log_a)  # Q[m] = A^-m
        self._Pr = np.ascontiguousarray(p.real)
        self._Pi = np.ascontiguousarray(p.imag)
        # Channel-major copies padded by K rows: a lane's next K samples are one contiguous run.
        K = self._hot_block
        pad = np.zeros((self.n_channels, K))
        self._PrT = np.concatenate([self._Pr.T, pad], axis=1)
        self._PiT = np.concatenate([self._Pi.T, pad], axis=1)
        win = np.lib.stride_tricks.sliding_window_view
        self._PrT_win = win(self._PrT, K, axis=1)
        self._PiT_win = win(self._PiT, K, axis=1)
        self._Qr = np.ascontiguousarray(q.real)
        self._nQi = np.ascontiguousarray(-q.imag)  # input term i·u·Q has real part −u·Im Q

    def reset(self) -> None:
        """Back to rest: z = 0 everywhere, sample counter 0."""
        self._n = 0
        self.quench()

    def quench(self) -> None:
        """Back to rest (z = 0 everywhere) without moving the sample counter, so spike indexes
        stay absolute and feeding in chunks stays exact across the quench."""
        self._wr = np.zeros(self._L)
        self._wi = np.zeros(self._L)
        self._pend = np.zeros(self._L, dtype=bool)
        self._z_ref = np.zeros(self._L, dtype=complex)  # reference engine's state

    @property
    def n_fed(self) -> int:
        """Number of samples fed since construction or ``reset()``."""
        return self._n

    @property
    def z(self) -> np.ndarray:
        """Current (pre-spike) state of the last fed sample, shape (n_receivers, n_channels)."""
        if self.engine == "reference":
            z = self._z_ref.copy()
        elif self._n == 0:
            z = np.zeros(self._L, dtype=complex)
        else:
            zr, zi = self._z_of(self._all, (self._n - 1) % self._R, self._wr, self._wi)
            z = zr + 1j * zi
        return z.reshape(self.n_receivers, self.n_channels)

    @property
    def spiked_last(self) -> np.ndarray:
        """Whether the last fed sample spiked, shape (n_receivers, n_channels)."""
        return self._pend.reshape(self.n_receivers, self.n_channels).copy()

    # -- arithmetic shared by every path (same expressions → same bits) ---------------------
    # Table lookups go through flat take(): the same values as [m, ch], a fraction of the cost
    # on the small arrays of the event-driven path.
    def _z_of(self, lanes: np.ndarray, m, wr: np.ndarray, wi: np.ndarray):
        ch = self._ch.take(lanes)
        flat = m * self.n_channels + ch
        pr = self._Pr.ravel().take(flat)
        pi = self._Pi.ravel().take(flat)
        return pr * wr - pi * wi, pr * wi + pi * wr

    def _post_carry(self, lanes: np.ndarray, zr: np.ndarray, zi: np.ndarray, m_next):
        """Running-sum value that starts sample m_next after a spike with pre-spike state z."""
        ch = self._ch.take(lanes)
        xr = self._Ar.take(ch) * zr - self._Ai.take(ch) * zi  # x: Euler step of pre-spike state
        rv = self.reset_value
        flat = m_next * self.n_channels + ch
        qr = self._Qr.ravel().take(flat)
        nqi = self._nQi.ravel().take(flat)
        return qr * xr + nqi * rv, qr * rv - nqi * xr  # Q[m_next]·(x + i·reset_value)

    def _carry(self, n_abs: int, wr: np.ndarray, wi: np.ndarray, pend: np.ndarray):
        """Carry into absolute sample n_abs from the state of sample n_abs − 1."""
        m = n_abs % self._R
        if n_abs == 0:
            return wr.copy(), wi.copy()
        cr, ci = wr.copy(), wi.copy()
        if m == 0:  # new epoch: re-anchor the frame, A^R·w
            pr = self._Pr[self._R, self._ch]
            pi = self._Pi[self._R, self._ch]
            cr, ci = pr * wr - pi * wi, pr * wi + pi * wr
        if pend.any():
            lanes = np.flatnonzero(pend)
            zr, zi = self._z_of(lanes, (n_abs - 1) % self._R, wr[lanes], wi[lanes])
            cr[lanes], ci[lanes] = self._post_carry(lanes, zr, zi, m)
        return cr, ci

    # -- feeding ------------------------------------------------------------------------------
    def _as_input(self, samples) -> np.ndarray:
        u = np.asarray(samples, dtype=float)
        if u.ndim == 1:
            u = u[:, None]
            if self.n_receivers > 1:
                u = np.broadcast_to(u, (u.shape[0], self.n_receivers))
        elif u.ndim != 2 or u.shape[1] != self.n_receivers:
            raise RgtbusError(
                f"samples of shape {np.shape(samples)} do not fit the bank: expected (n,) or "
                f"(n, {self.n_receivers}) for {self.n_receivers} receiver(s)"
            )
        if not np.isfinite(u).all():
            bad = int(np.flatnonzero(~np.isfinite(u).all(axis=1))[0])
            raise RgtbusError(f"sample {self._n + bad} is not finite")
        return u

    def feed(self, samples: np.ndarray | Sequence[float], record: bool = False) -> FeedResult:
        """Advance by ``len(samples)`` samples; return spikes (and trajectories if ``record``)."""
        u = self._as_input(samples)
        n = u.shape[0]
        start = self._n
        rec = None
        if record:
            shape = (n, self.n_receivers, self.n_channels)
            rec = (np.empty(shape), np.empty(shape), np.zeros(shape, dtype=bool))
        spikes: list[tuple[np.ndarray, np.ndarray]] = []
        if self.engine == "reference":
            self._feed_reference(u, rec, spikes)
        elif n:
            self._feed_fast(u, rec, spikes)
        self._n += n
        if spikes:
            rows = np.concatenate([s[0] for s in spikes])
            lanes = np.concatenate([s[1] for s in spikes])
            order = np.lexsort((lanes, rows))
            rows, lanes = rows[order], lanes[order]
            arr = np.stack([rows + start, self._rec[lanes], self._ch[lanes]], axis=1)
        else:
            arr = np.zeros((0, 3), dtype=np.int64)
        result = FeedResult(start=start, n=n, spikes=arr.astype(np.int64))
        if rec is not None:
            zr, zi, mask = rec
            result.z = zr + 1j * zi
            result.y = np.where(mask, self.spike_value, zi)
            result.spiked = mask
        return result

    def _feed_reference(self, u: np.ndarray, rec, spikes) -> None:
        """The obvious per-sample loop (vectorised over receivers × channels only)."""
        A = self.A[self._ch]
        z = self._z_ref.copy()
        pend = self._pend.copy()
        thr, rv = self.threshold, self.reset_value
        uu = u[:, self._rec]
        for k in range(u.shape[0]):
            z = A * z
            if pend.any():
                z = np.where(pend, z.real + 1j * rv, z)
            z = z + 1j * uu[k]
            pend = z.imag >= thr
            if pend.any():
                spikes.append((np.full(int(pend.sum()), k), np.flatnonzero(pend)))
            if rec is not None:
                rec[0][k].flat[:] = z.real
                rec[1][k].flat[:] = z.imag
                rec[2][k].flat[:] = pend
        self._z_ref = z
        self._pend = pend

    def _feed_fast(self, u: np.ndarray, rec, spikes) -> None:
        R = self._R
        n = u.shape[0]
        nz_rows = np.flatnonzero(np.any(u != 0.0, axis=1))
        cr, ci = self._carry(self._n, self._wr, self._wi, self._pend)
        row = 0
        wr = wi = pend = None
        while row < n:
            n_abs = self._n + row
            m0 = n_abs % R
            seg = min(n - row, R - m0, self._span)
            lo, hi = np.searchsorted(nz_rows, [row, row + seg])
            nz = nz_rows[lo:hi] - row
            # Skipping pays when inputs are sparse and there are enough lanes to amortise its
            # per-spike rounds; with a handful of lanes the block scan is cheaper (measured).
            sparse = (
                rec is None
                and self._can_skip
                and 16 * len(nz) <= seg
                and (self._L >= _SPARSE_MIN_LANES or not len(nz))
            )
            if sparse:
                wr, wi, pend = self._sparse(u, row, seg, m0, nz, cr, ci, spikes)
            else:
                wr, wi, pend = self._dense_segment(u, row, seg, m0, cr, ci, rec, spikes)
            row += seg
            if row < n:
                cr, ci = self._carry(self._n + row, wr, wi, pend)
        self._wr, self._wi, self._pend = wr, wi, pend

    def _dense_segment(self, u, row, seg, m0, cr, ci, rec, spikes):
        B = self._block
        off = 0
        while True:
            nb = min(B, seg - off)
            wr, wi, pend = self._dense(u, row + off, nb, m0 + off, None, cr, ci, rec, spikes)
            off += nb
            if off >= seg:
                return wr, wi, pend
            cr, ci = wr, wi
            if pend.any():
                cr, ci = wr.copy(), wi.copy()
                lanes = np.flatnonzero(pend)
                zr, zi = self._z_of(lanes, m0 + off - 1, wr[lanes], wi[lanes])
                cr[lanes], ci[lanes] = self._post_carry(lanes, zr, zi, m0 + off)

    def _dense(self, u, row, nb, m0, lanes, cr, ci, rec, spikes):
        """Scan rows [row, row+nb) of u (one epoch, frame index m0 at row) sample by sample.

        ``lanes`` None means all lanes.  Returns w at the last row and the last row's spike mask.
        """
        ub = u[row : row + nb]
        if lanes is None and self.n_receivers == 1:
            sl = slice(m0, m0 + nb)
            ul = ub  # (nb, 1) broadcasts against (nb, C)
            q_r, nq_i = self._Qr[sl], self._nQi[sl]
            pr, pi = self._Pr[sl], self._Pi[sl]
            lane_ids = self._all
        else:
            lane_ids = self._all if lanes is None else lanes
            ch = self._ch[lane_ids]
            ul = ub[:, self._rec[lane_ids]]
            ms = np.arange(m0, m0 + nb)[:, None]
            q_r, nq_i = self._Qr[ms, ch], self._nQi[ms, ch]
            pr, pi = self._Pr[ms, ch], self._Pi[ms, ch]
        tr = ul * nq_i
        ti = ul * q_r
        tr[0] += cr
        ti[0] += ci
        wr = np.cumsum(tr, axis=0)
        wi = np.cumsum(ti, axis=0)
        y = pr * wi + pi * wr
        spk = y >= self.threshold
        last = np.zeros(len(lane_ids), dtype=bool)
        hit_rows: list[np.ndarray] = []
        hit_cols: list[np.ndarray] = []
        if spk.any():
            rows = np.arange(nb)[:, None]
            start = np.zeros(len(lane_ids), dtype=np.int64)
            cols = np.flatnonzero(spk.any(axis=0))
            while cols.size:
                cand = spk[:, cols] & (rows >= start[cols])
                has = cand.any(axis=0)
                cols = cols[has]
                if not cols.size:
                    break
                k = cand[:, has].argmax(axis=0)
                hit_rows.append(k)
                hit_cols.append(cols)
                at_end = k == nb - 1
                last[cols[at_end]] = True
                cols, k = cols[~at_end], k[~at_end]
                if not cols.size:
                    break
                # Restart these lanes' running sums from the reset state at row k+1.
                zr = pr[k, cols] * wr[k, cols] - pi[k, cols] * wi[k, cols]
                zi = y[k, cols]
                k1 = k + 1
                c2r, c2i = self._post_carry(lane_ids[cols], zr, zi, m0 + k1)
                keep = rows >= k1
                sr = np.where(keep, tr[:, cols], 0.0)
                si = np.where(keep, ti[:, cols], 0.0)
                j = np.arange(cols.size)
                sr[k1, j] += c2r
                si[k1, j] += c2i
                sr = np.cumsum(sr, axis=0)
                si = np.cumsum(si, axis=0)
                wr[:, cols] = np.where(keep, sr, wr[:, cols])
                wi[:, cols] = np.where(keep, si, wi[:, cols])
                ynew = pr[:, cols] * wi[:, cols] + pi[:, cols] * wr[:, cols]
                y[:, cols] = np.where(keep, ynew, y[:, cols])
                spk[:, cols] = y[:, cols] >= self.threshold
                start[cols] = k1
            for k, c in zip(hit_rows, hit_cols, strict=True):
                spikes.append((k + row, lane_ids[c]))
        if rec is not None:
            x = pr * wr - pi * wi
            U, C = self.n_receivers, self.n_channels
            if lanes is not None:
                raise AssertionError("recording scans all lanes")
            rec[0][row : row + nb] = x.reshape(nb, U, C)
            rec[1][row : row + nb] = y.reshape(nb, U, C)
            for k, c in zip(hit_rows, hit_cols, strict=True):
                rec[2][row + k, self._rec[c], self._ch[c]] = True
        return wr[-1].copy(), wi[-1].copy(), last

    def _sparse(self, u, row, seg, m0, nz, cr, ci, spikes):
        """Event-driven pass over a sparse segment (rows [row, row+seg) of one epoch).

        Rounds, each vectorised over the lanes still in play: the running sum w is evaluated at
        input rows only (it is constant in between); a lane whose |z| there is below threshold
        cannot spike before its next input, so only "hot" (row, lane) pairs are examined, sample
        by sample, up to the next input.  A lane's first spike restarts it from the reset state
        in the next round; lanes without a spike are final.
        """
        thr = self.threshold
        thr2 = (thr * (1.0 - _HOT_MARGIN)) ** 2
        L = self._L
        K = self._hot_block
        if not nz.size:  # quiet stretch: nothing changes unless some lane is already hot
            zr0, zi0 = self._z_of(self._all, m0, cr, ci)
            if not (zr0 * zr0 + zi0 * zi0 >= thr2).any():
                return cr.copy(), ci.copy(), np.zeros(L, dtype=bool)
        out_wr = np.empty(L)
        out_wi = np.empty(L)
        out_pend = np.zeros(L, dtype=bool)
        lanes = self._all
        p = np.zeros(L, dtype=np.int64)  # row each lane (re)starts at, within the segment
        c_r, c_i = cr.copy(), ci.copy()  # its running sum entering that row
        while lanes.size:
            H = lanes.size
            ev = _union(nz[nz >= p.min()], p)  # input rows plus restart rows
            ch = self._ch.take(lanes)
            ms = m0 + ev
            full = H == L and self.n_receivers == 1
            ue = u.take(row + ev, axis=0)  # (E, U)
            if full:  # all lanes: plain row gathers
                tq, tn = self._Qr.take(ms, axis=0), self._nQi.take(ms, axis=0)
                pr, pi = self._Pr.take(ms, axis=0), self._Pi.take(ms, axis=0)
            else:
                ue = ue.take(self._rec.take(lanes), axis=1)
                tq = self._Qr.take(ms, axis=0).take(ch, axis=1)
                tn = self._nQi.take(ms, axis=0).take(ch, axis=1)
                pr = self._Pr.take(ms, axis=0).take(ch, axis=1)
                pi = self._Pi.take(ms, axis=0).take(ch, axis=1)
            tr = ue * tn
            ti = ue * tq
            fresh = not p.any()
            if fresh:
                valid = True
                tr[0] += c_r
                ti[0] += c_i
            else:
                valid = ev[:, None] >= p[None, :]
                tr = np.where(valid, tr, 0.0)
                ti = np.where(valid, ti, 0.0)
                first = np.searchsorted(ev, p)
                cols = np.arange(H)
                tr[first, cols] += c_r
                ti[first, cols] += c_i
            wr = np.cumsum(tr, axis=0)
            wi = np.cumsum(ti, axis=0)
            zr = pr * wr - pi * wi
            zi = pr * wi + pi * wr
            hot = zr * zr + zi * zi >= thr2
            if not fresh:
                hot &= valid
            # Earliest event per lane: (row, kind) with kind 0 = spike, 1 = still hot at window end.
            ev_row = np.full(H, seg, dtype=np.int64)
            ev_kind = np.zeros(H, dtype=np.int8)
            ev_j = np.zeros(H, dtype=np.int64)
            if hot.any():
                hj, hh = np.nonzero(hot)
                flat = hj * H + hh  # (row, lane) pairs as flat indexes: take() beats [rows, cols]
                at_ev = zi.ravel().take(flat) >= thr
                # spikes right at an input (or restart) row
                sj, sh = hj[at_ev], hh[at_ev]
                np.minimum.at(ev_row, sh, ev.take(sj))
                # Free-running rows after the other hot rows, up to the next input row.  There
                # y[k] = ρ|A|^k·sin(φ + kθ) (up to ~1e-13 rounding), so only rows whose phase lies
                # on the arc sin ≥ thr/ρ, and before |z| decays below thr, can spike: scan those.
                free = ~at_ev
                fj, fh = hj[free], hh[free]
                if fj.size:
                    ff = flat[free]
                    nxt = np.append(ev[1:], seg).take(fj)
                    base = ev.take(fj)
                    chf = ch.take(fh)
                    zr_f, zi_f = zr.ravel().take(ff), zi.ravel().take(ff)
                    rho = np.sqrt(zr_f * zr_f + zi_f * zi_f)
                    phi = np.mod(np.arctan2(zi_f, zr_f), 2 * np.pi)
                    th = self._theta.take(chf)
                    alpha = np.arcsin(np.clip(thr / rho - 1e-9, -1.0, 1.0))
                    in_arc = (phi >= alpha - 1e-12) & (phi <= np.pi - alpha + 1e-12)
                    d_start = np.mod(alpha - phi, 2 * np.pi)
                    d_end = np.mod(np.pi - alpha - phi, 2 * np.pi)
                    k0 = np.where(in_arc, 1, np.maximum(1, np.floor(d_start / th) - 1))
                    k1 = np.where(
                        in_arc,
                        np.floor(np.where(in_arc, d_end, 0) / th) + 2,
                        np.floor(d_end / th) + 2,
                    )
                    k_cool = (
                        np.floor(np.log(np.maximum(rho, thr2) / thr2**0.5) / self._lam.take(chf))
                        + 2
                    )
                    k0 = k0.astype(np.int64)
                    top = np.minimum(nxt, base + np.minimum(k_cool, 1e15).astype(np.int64) + 1)
                    start = base + k0
                    stop = np.minimum(
                        np.minimum(top, base + np.minimum(k1, 1e15).astype(np.int64) + 1), start + K
                    )
                    width = int(max(0, (stop - start).max()))
                    krow = np.full(fj.size, seg, dtype=np.int64)
                    if width:
                        rows = start[:, None] + np.arange(width)[None, :]
                        inside = rows < stop[:, None]
                        # channel-major tables: each window is one contiguous slice
                        m_first = m0 + np.minimum(start, seg - 1)  # empty windows: any row
                        prw = self._PrT_win[chf, m_first, :width]
                        piw = self._PiT_win[chf, m_first, :width]
                        y = prw * wi.ravel().take(ff)[:, None] + piw * wr.ravel().take(ff)[:, None]
                        hit = inside & (y >= thr)
                        got = hit.any(axis=1)
                        krow = np.where(got, start + hit.argmax(axis=1), seg)
                    else:
                        got = np.zeros(fj.size, dtype=bool)
                    np.minimum.at(ev_row, fh, krow)
                    # no spike in the scanned rows but later rows before the next input might:
                    # the lane resumes from there in the next round
                    capped = ~got & (np.maximum(stop, start) < top)
                    if capped.any():
                        cap_row = np.full(H, seg, dtype=np.int64)
                        np.minimum.at(cap_row, fh[capped], np.maximum(stop, start)[capped])
                        use_cap = cap_row < ev_row
                        ev_kind[use_cap] = 1
                        ev_row = np.where(use_cap, cap_row, ev_row)
                # the running sum in force at ev_row: last evaluated row ≤ ev_row
                ev_j = np.searchsorted(ev, ev_row, side="right") - 1
            done = ev_row >= seg
            # lanes without further events: final state is w at their last row
            if done.any():
                d = np.flatnonzero(done)
                out_wr[lanes[d]] = wr[-1, d]
                out_wi[lanes[d]] = wi[-1, d]
            go = np.flatnonzero(~done)
            if not go.size:
                break
            k = ev_row[go]
            j = ev_j[go]
            gl = lanes[go]
            w_r, w_i = wr.ravel().take(j * H + go), wi.ravel().take(j * H + go)
            spk = ev_kind[go] == 0
            nr, ni = w_r.copy(), w_i.copy()  # capped lanes resume with the same sum
            if spk.any():
                sl, sk = gl[spk], k[spk]
                spikes.append((sk + row, sl))
                zr_k, zi_k = self._z_of(sl, m0 + sk, w_r[spk], w_i[spk])
                last = sk + 1 >= seg
                if last.any():  # spike on the segment's last row: reset pending
                    out_wr[sl[last]] = w_r[spk][last]
                    out_wi[sl[last]] = w_i[spk][last]
                    out_pend[sl[last]] = True
                mid = ~last
                a_r, a_i = self._post_carry(sl[mid], zr_k[mid], zi_k[mid], m0 + sk[mid] + 1)
                idx = np.flatnonzero(spk)[mid]
                nr[idx], ni[idx] = a_r, a_i
                k = k.copy()
                k[spk] += 1
                keep = ~(spk & (k >= seg))
            else:
                keep = np.ones(go.size, dtype=bool)
            lanes = gl[keep]
            p = k[keep]
            c_r, c_i = nr[keep], ni[keep]
        return out_wr, out_wi, out_pend


def _union(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Sorted unique values of both (np.union1d without its generality: half the time)."""
    c = np.concatenate((a, b))
    c.sort()
    keep = np.empty(c.size, dtype=bool)
    keep[:1] = True
    np.not_equal(c[1:], c[:-1], out=keep[1:])
    return c[keep]


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
    """Pure-Python per-sample loop (one receiver): spike sample indices per channel.

    Same model as the bank: ``z = A·z`` (or the reset state after a spike), ``y += u``, spike when
    ``y ≥ threshold``.  Baseline for benchmarks and a second cross-check.
    """
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
