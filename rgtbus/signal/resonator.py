"""Resonate-and-fire receiver bank (docs/model.md): pure numpy, any receivers × channels.

Model (one resonator, eigen-frequency ω, complex state z = x + i·y, sample period τ)::

    update:   z[k] = A·z[k-1] + i·u[k]          (the medium sample u[k] is added to y = Im z)
              A = 1 + τ(b + iω)    mode "paper" (forward Euler, the paper's equation)
              A = exp(τ(b + iω))   mode "exact" (exact discretisation of dz/dt = (b + iω)z)
    spike:    Im z[k] ≥ threshold  →  spike at sample k; the recorded y[k] is ``spike_value``
    reset:    after a spike at k, sample k+1 starts from  Re(A·z[k]) + i·reset_value
              (x is the Euler step of the pre-spike state, y = 0.1), then adds i·u[k+1]
    readout:  d[k] = Im(z[k] − ẑ[k]), ẑ[k] = the state at k before its input (A·z[k-1], or the
              reset state): exactly u[k], the medium sample as this resonator heard it, so it
              is taken from the input (rounded to READOUT_DIGITS; ``input_readout``)

``z[k]`` is the pre-spike state.  Defaults are the paper's: b = −0.1, τ = 0.005 s, threshold 1,
spike 1.5, reset 0.1.

All of it is computed in one place, :func:`resonate`, in a rotating frame.  Within an epoch of
R samples starting at absolute sample E (a multiple of R), ``z[k] = A^(k−E)·w[k]`` with the
running sum ``w[k] = w[k−1] + i·u[k]·A^−(k−E)``: silence leaves w unchanged, so crossing it is
closed form, ``z[k+j] = A^j·z[k]``.  At an epoch's start the frame is re-anchored (w ← A^R·w);
after a spike w restarts from the reset state.  Powers of A come from tables indexed by k − E, and
the sums are sequential, so every value is a function of the absolute sample index alone: any
chunking of the input (one call, windows of 20 samples, event to event), sparse or dense, gives
*identical* (==) states, spikes and readouts.  Because |A| < 1 (paper mode inside Euler's stable
band, exact mode with b < 0), |z| cannot grow without input: a resonator with |z| < threshold after
an input cannot spike before the next one, so only "hot" resonators are scanned, and only on the
arc where sin(phase) can still reach the threshold before the decay takes |z| below it.

``rgtbus.signal.reference`` states the same model literally, sample by sample, as the oracle the
tests and benchmarks compare this with (states agree to ~1e-12 relative; spikes are identical).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rgtbus.errors import BadInput
from rgtbus.signal.kernels import WalkModel
from rgtbus.signal.lanes import Trajectory, spike_table, walk, walk_every_lane, walking_lanes
from rgtbus.timebase import times_of

PAPER_TAU = 0.005
PAPER_B = -0.1
PAPER_THRESHOLD = 1.0
PAPER_SPIKE_VALUE = 1.5
PAPER_RESET_VALUE = 0.1
MODES = ("paper", "exact")
READOUT_DIGITS = 12  # readout precision: far below any noise, far above the frame's rounding

# Skipping silence needs strict decay, with room for table rounding.
_SKIP_MAX_ABS_A = 1.0 - 1e-9
# A resonator counts as "hot" when |z| ≥ threshold·(1 − _HOT_MARGIN): covers table rounding.
_HOT_MARGIN = 1e-9


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
    raise BadInput(f"mode {mode!r} is not one of {', '.join(MODES)}")


@dataclass
class FeedResult:
    """What one advance of a bank produced.

    ``spikes``: int64 (S, 3) of absolute sample, receiver, channel, sorted by sample, receiver,
    channel. ``walker_of`` (an advance that shared walks and was asked not to ``expand``): per
    receiver, the receiver whose walk it took (itself for a walker; -1: it stood still), and
    ``spikes`` holds the walkers' alone: every other receiver's are its walker's.  With
    ``record``: ``z`` (n, receivers, channels) pre-spike states, ``y`` the
    recorded y (``spike_value`` at spike samples) and ``spiked`` the spike mask.  With
    ``readout``: ``readout_rows`` (absolute samples that carried input) and ``readout``
    (rows, receivers, channels) the increment readout there, rounded to ``READOUT_DIGITS`` (every
    other sample reads 0).  ``start`` is the first sample fed, ``n`` how many were processed
    (fewer than asked when the advance stopped at a spike: ``stopped``).
    """

    start: int
    n: int
    spikes: np.ndarray
    z: np.ndarray | None = None
    y: np.ndarray | None = None
    spiked: np.ndarray | None = None
    readout_rows: np.ndarray | None = None
    readout: np.ndarray | None = None
    stopped: bool = False
    walker_of: np.ndarray | None = None

    @property
    def x(self) -> np.ndarray | None:
        """The recorded x = Re z (None without ``record``)."""
        return None if self.z is None else self.z.real

    def spike_times(
        self, tau: float = PAPER_TAU, receiver: int = 0, channel: int | None = None
    ) -> np.ndarray | list[np.ndarray]:
        """Spike times in seconds (sample index × τ) of one receiver, one channel or all."""
        sel = self.spikes[self.spikes[:, 1] == receiver]
        if channel is not None:
            times: np.ndarray = times_of(sel[sel[:, 2] == channel, 0], tau)
            return times
        n_ch = 0 if self.z is None else self.z.shape[2]
        n_ch = max(n_ch, int(self.spikes[:, 2].max()) + 1 if len(self.spikes) else 0)
        return [times_of(sel[sel[:, 2] == c, 0], tau) for c in range(n_ch)]


@dataclass(frozen=True, eq=False)
class Tables:
    """Powers of A over one epoch, read-only: shared by every bank on the same channels, mode,
    τ and b (one copy per process, however many units listen)."""

    A: np.ndarray  # (C,) complex
    Ar: np.ndarray
    Ai: np.ndarray
    R: int  # epoch length (samples)
    Pr: np.ndarray  # (R+1, C): Re A^m
    Pi: np.ndarray  # Im A^m
    Qr: np.ndarray  # (R, C): Re A^-m
    nQi: np.ndarray  # −Im A^-m (the input term i·u·A^-m has real part −u·Im A^-m)
    stable: bool  # every |A| < 1: silence can be skipped


@functools.lru_cache(maxsize=32)
def shared_tables(
    omegas: tuple[float, ...], mode: str, tau: float, b: float, epoch: int | None
) -> Tables:
    """The tables of one bank configuration, built once per process (an LRU cache)."""
    A = np.array([transition(w, mode=mode, tau=tau, b=b) for w in omegas])
    log_abs = float(np.abs(np.log(np.abs(A))).max())
    if epoch is None:
        # Keep |A|^±R within ~e^18 so the rotating frame loses no precision; 4096 samples is
        # already more than any code, so longer epochs would only cost memory.
        r = 4096
        if log_abs > 0:
            r = max(1, min(r, 2 ** math.floor(math.log2(max(1.0, 18.0 / log_abs)))))
    else:
        r = int(epoch)
    m = np.arange(r + 1, dtype=float)[:, None]
    log_a = np.log(A)[None, :]
    p = np.exp(m * log_a)  # P[m] = A^m
    q = np.exp(-m[:-1] * log_a)  # Q[m] = A^-m
    pr, pi = np.ascontiguousarray(p.real), np.ascontiguousarray(p.imag)
    tables = Tables(
        A=A,
        Ar=A.real.copy(),
        Ai=A.imag.copy(),
        R=r,
        Pr=pr,
        Pi=pi,
        Qr=np.ascontiguousarray(q.real),
        nQi=np.ascontiguousarray(-q.imag),
        stable=float(np.abs(A).max()) < _SKIP_MAX_ABS_A,
    )
    for arr in (tables.Pr, tables.Pi, tables.Qr, tables.nQi):
        arr.flags.writeable = False
    return tables


@dataclass(frozen=True, eq=False)
class BankModel:
    """Everything of a bank that does not change as it runs: tables, thresholds, lane layout.

    Lanes are receiver-major, lane = receiver·C + channel, unless ``layout`` gives each lane's
    (channel, receiver) explicitly: a few resonators picked out of a bank, same tables, same
    values (lanes are independent). Only the full layout records trajectories and readouts."""

    tables: Tables
    threshold: float
    spike_value: float
    reset_value: float
    receivers: int
    channels: int
    layout: tuple[np.ndarray, np.ndarray] | None = None

    @functools.cached_property
    def lane_ch(self) -> np.ndarray:
        """Each lane's channel."""
        if self.layout is not None:
            return self.layout[0]
        return np.tile(np.arange(self.channels), self.receivers)

    @functools.cached_property
    def lane_rec(self) -> np.ndarray:
        """Each lane's receiver."""
        if self.layout is not None:
            return self.layout[1]
        return np.repeat(np.arange(self.receivers), self.channels)

    @functools.cached_property
    def lanes(self) -> int:
        """How many lanes the model walks."""
        return int(self.lane_ch.size)

    @functools.cached_property
    def all_lanes(self) -> np.ndarray:
        """Every lane index, ascending."""
        return np.arange(self.lanes, dtype=np.int64)

    @functools.cached_property
    def plain(self) -> bool:
        """One receiver, every channel in order: table rows can be gathered whole."""
        return self.layout is None and self.receivers == 1

    def pick(
        self, channels: np.ndarray, receivers: np.ndarray, n_inputs: int | None = None
    ) -> BankModel:
        """The model of the lanes (channel, receiver) picked out of this bank's; their input
        has ``n_inputs`` columns (default: one per receiver of this bank)."""
        return BankModel(
            self.tables,
            self.threshold,
            self.spike_value,
            self.reset_value,
            self.receivers if n_inputs is None else n_inputs,
            self.channels,
            (np.asarray(channels, dtype=np.int64), np.asarray(receivers, dtype=np.int64)),
        )

    @property
    def skip(self) -> bool:
        """Whether a walk may jump over silence (strict decay, a threshold to stay below)."""
        return self.tables.stable and self.threshold > 0

    @functools.cached_property
    def walker(self) -> WalkModel:
        """The compiled walk's view of this model (tables, lane layout, spike rule)."""
        T = self.tables
        return WalkModel(
            Pr=T.Pr,
            Pi=T.Pi,
            Qr=T.Qr,
            nQi=T.nQi,
            Ar=T.Ar,
            Ai=T.Ai,
            R=T.R,
            lane_ch=self.lane_ch,
            lane_rec=self.lane_rec,
            thr=self.threshold,
            thr2=(self.threshold * (1.0 - _HOT_MARGIN)) ** 2,  # |z|² of a hot resonator
            rv=self.reset_value,
            stable=self.skip,
        )


@dataclass(frozen=True, eq=False)
class BankState:
    """Where a bank is: the running sum w of every lane (in the frame of sample n−1's epoch),
    which lanes spiked at sample n−1 (their reset is due), and n, the next sample to process."""

    wr: np.ndarray
    wi: np.ndarray
    pend: np.ndarray
    n: int

    @staticmethod
    def rest(lanes: int, n: int = 0) -> BankState:
        """Every resonator at rest (z = 0) before sample n."""
        return BankState(np.zeros(lanes), np.zeros(lanes), np.zeros(lanes, dtype=bool), n)


# -- the frame arithmetic (same expressions everywhere → same bits) ------------------------------


def _z_of(
    T: Tables, ch: np.ndarray, m: int, wr: np.ndarray, wi: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """z = A^m·w (real and imaginary parts)."""
    C = T.Pr.shape[1]
    flat = m * C + ch
    pr = T.Pr.ravel().take(flat)
    pi = T.Pi.ravel().take(flat)
    return pr * wr - pi * wi, pr * wi + pi * wr


# -- the readout ---------------------------------------------------------------------------


def input_readout(rows: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The increment readout of an input: ``d[k] = Im z[k] − Im ẑ[k] = u[k]`` (ẑ: the state
    before the input), the sample each receiver heard, rounded to ``READOUT_DIGITS``, at the
    samples that carry input (``rows``; ``values``: (len(rows), receivers)), with every other
    sample reading 0. Returns (the rows with input, their readout (rows, receivers)).

    Taken from the input, not from the walk's state (where it is the same value to the
    frame's rounding): the same bits however the bank is stepped, and no walk at all is
    needed when no spike is awaited or logged (docs/model.md)."""
    vals = np.asarray(values, dtype=np.float64)
    vals = vals.reshape(len(rows), vals.shape[-1] if vals.ndim > 1 else 1)
    has = (vals != 0.0).any(axis=1)
    scale = 10.0**READOUT_DIGITS
    return np.asarray(rows)[has], np.rint(vals[has] * scale) / scale


# -- the one dynamics function ---------------------------------------------------------------


def resonate(
    M: BankModel,
    state: BankState,
    end: int,
    rows: np.ndarray,
    values: np.ndarray,
    *,
    stop: bool = False,
    stop_lanes: np.ndarray | None = None,
    record: bool = False,
    readout: bool = False,
    receivers: np.ndarray | None = None,
    share: bool = True,
    expand: bool = True,
) -> tuple[BankState, FeedResult]:
    """Advance a bank from ``state.n`` to ``end`` (exclusive) over the given input: every
    resonator walks (``walk``) on its own.

    ``rows``: sorted unique absolute samples in [state.n, end) that carry input; ``values``:
    (len(rows), receivers) the input there (every other sample is silence).  ``stop``: return
    right after the first sample at which a resonator spikes — any, or one of ``stop_lanes``
    (a lane mask) — with its reset pending in the returned state; every other spike before it
    is returned too.  ``record``: every sample's state (the trajectory).  ``readout``: the
    increment readout at the input rows.  Pure: ``state`` is not modified.

    ``receivers``: a mask of the receivers whose resonators walk (default: all); the others'
    lanes keep the state they had and never spike (their unit listens no more). ``share``:
    receivers whose lanes start from the same state and hear the same input, bit for bit (a
    noise-free medium through equal link gains), walk once and the others take the walk's
    state and spikes (the same values: the walk of a lane depends on nothing else); False
    walks every lane, the reference it is tested against; an advance of fewer than
    ``lanes.SHARE_MIN_WORK`` lane-samples walks every lane too. A bank that records walks every
    lane. ``expand`` False: an advance that shared walks returns the walkers' spikes alone and who
    took whose walk (``FeedResult.walker_of``), not a copy of them for every receiver.
    """
    start = state.n
    if end < start:
        raise BadInput(f"advance to sample {end}: the bank is already at {start}")
    if (record or readout) and M.layout is not None:
        raise BadInput("only a whole bank records its trajectories and readout")
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    vals = np.ascontiguousarray(values, dtype=np.float64).reshape(rows.size, M.receivers)
    stopped = False
    if stop:  # the first spike among the stop lanes decides where every lane stops
        first = first_spike(M, state, end, rows, vals, stop_lanes)
        if first is not None:
            end, stopped = first + 1, True
            cut = int(rows.searchsorted(end))
            rows, vals = rows[:cut], vals[:cut]
    n = end - start
    lanes, views = walking_lanes(M, state, vals, n, receivers, share, record)
    wr, wi, pend, spikes, n_sp, trajectory = walk_every_lane(
        M, state, end, rows, vals, lanes, record
    )
    if views is not None:  # every receiver of a view takes its walker's lanes
        for w in (wr, wi, pend):
            grid = w.reshape(M.receivers, M.channels)
            grid[views.live] = grid[views.walker_of]
    walker_of = None
    if views is not None and not expand:
        walker_of = np.full(M.receivers, -1, dtype=np.int64)
        walker_of[views.live] = views.walker_of
    table = spike_table(M, spikes, n_sp, start, n, views if expand else None)
    result = FeedResult(start=start, n=n, spikes=table, stopped=stopped, walker_of=walker_of)
    if trajectory is not None:
        _record(M, result, trajectory, n)
    if readout:  # every channel of a receiver reads the sample it heard
        at, d = input_readout(rows, vals)
        result.readout_rows = at
        result.readout = np.broadcast_to(d[:, :, None], (at.size, M.receivers, M.channels))
    return BankState(wr, wi, pend, end), result


def _record(M: BankModel, result: FeedResult, trajectory: Trajectory, n: int) -> None:
    """A recording advance's trajectory into its result: z, the recorded y (``spike_value``
    at spike samples) and the spike mask, each (n, receivers, channels)."""
    shape = (n, M.receivers, M.channels)
    x, y = trajectory.xy[0].reshape(shape), trajectory.xy[1].reshape(shape)
    result.z = x + 1j * y
    spiked = trajectory.spiked.view(np.bool_).reshape(shape)
    result.y = np.where(spiked, M.spike_value, y)
    result.spiked = spiked


def first_spike(
    M: BankModel,
    state: BankState,
    end: int,
    rows: np.ndarray,
    values: np.ndarray,
    lanes: np.ndarray | None = None,
) -> int | None:
    """The first sample in [state.n, end) at which one of ``lanes`` (a mask; default every
    lane) spikes over this input (as ``resonate``), or None. Pure, and only those lanes walk."""
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    vals = np.ascontiguousarray(values, dtype=np.float64).reshape(rows.size, M.receivers)
    watch = M.all_lanes if lanes is None else np.flatnonzero(lanes)
    first, found, _ = walk(
        M,
        lanes=watch,
        wr=state.wr,  # read, never written: only the first spike is looked for
        wi=state.wi,
        pend=state.pend,
        start=state.n,
        end=end,
        rows=rows,
        vals=vals,
        spikes=np.empty((2, max(1, watch.size)), dtype=np.int64),
        stop_first=True,
    )
    return int(first) - 1 if found else None


def _validate_float(value: float, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise BadInput(f"{name} = {value!r} is not a number") from None
    if not math.isfinite(v):
        raise BadInput(f"{name} = {value!r} is not finite")
    return v


class ResonatorBank:
    """``n_receivers`` × ``len(omegas)`` resonate-and-fire neurons (streaming; see the module
    docstring for the model).

    Every receiver has one resonator per channel ω; all of a receiver's resonators hear the same
    sample (its own copy of the medium: per-link gain and noise are applied by the caller, see
    ``waveform.hear``).  ``feed(samples)`` takes a dense array of shape (n,) (the same medium for
    every receiver) or (n, n_receivers); ``advance(end, rows, values)`` takes sparse input (the
    samples that carry anything) and can stop at the first spike.  Both go through
    :func:`resonate` and keep the state between calls; the tables are shared between banks.
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
        epoch: int | None = None,
    ):
        om = np.atleast_1d(np.asarray(omegas, dtype=float))
        if om.ndim != 1 or om.size == 0:
            raise BadInput(f"omegas must be a non-empty list of numbers, got shape {om.shape}")
        for j, w in enumerate(om):
            if not math.isfinite(w) or w <= 0:
                raise BadInput(f"omega[{j}] = {w!r} must be a positive finite number (rad/s)")
        if mode not in MODES:
            raise BadInput(f"mode {mode!r} is not one of {', '.join(MODES)}")
        self.tau = _validate_float(tau, "tau")
        if self.tau <= 0:
            raise BadInput(f"tau = {tau!r} must be positive (seconds per sample)")
        self.b = _validate_float(b, "b")
        threshold = _validate_float(threshold, "threshold")
        spike_value = _validate_float(spike_value, "spike_value")
        reset_value = _validate_float(reset_value, "reset_value")
        if isinstance(n_receivers, bool) or not isinstance(n_receivers, int | np.integer):
            raise BadInput(f"n_receivers = {n_receivers!r} must be a positive integer")
        if n_receivers < 1:
            raise BadInput(f"n_receivers = {n_receivers!r} must be a positive integer")
        if epoch is not None and (not isinstance(epoch, int | np.integer) or epoch < 1):
            raise BadInput(f"epoch = {epoch!r} must be a positive integer")
        self.omegas = om
        self.mode = mode
        self.n_receivers = int(n_receivers)
        self.n_channels = om.size
        tables = shared_tables(tuple(float(w) for w in om), mode, self.tau, self.b, epoch)
        self.model = BankModel(
            tables, threshold, spike_value, reset_value, self.n_receivers, self.n_channels
        )
        self.state = BankState.rest(self.model.lanes)

    # -- parameters ---------------------------------------------------------------------------
    @property
    def A(self) -> np.ndarray:
        """The one-sample transition A of every channel."""
        return self.model.tables.A

    @property
    def threshold(self) -> float:
        """The spike threshold on Im z."""
        return self.model.threshold

    @property
    def spike_value(self) -> float:
        """The y recorded at a spike sample."""
        return self.model.spike_value

    @property
    def reset_value(self) -> float:
        """The y a resonator restarts from after a spike."""
        return self.model.reset_value

    # -- state ----------------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to rest: z = 0 everywhere, sample counter 0."""
        self.state = BankState.rest(self.model.lanes)

    def quench(self, receiver: int | Sequence[int] | None = None) -> None:
        """Back to rest (z = 0) without moving the sample counter, so spike indexes stay
        absolute and feeding in chunks stays exact across the quench: every resonator, or only
        those of one ``receiver`` (or of each of several, at one copy of the state)."""
        if receiver is None:
            self.state = BankState.rest(self.model.lanes, self.state.n)
            return
        receivers = [receiver] if isinstance(receiver, int) else list(receiver)
        for r in receivers:
            if not 0 <= r < self.n_receivers:
                raise BadInput(f"quench: receiver {r} not in the bank ({self.n_receivers})")
        s = self.state
        wr, wi, pend = s.wr.copy(), s.wi.copy(), s.pend.copy()
        C = self.n_channels
        for r in receivers:
            lanes = slice(r * C, (r + 1) * C)
            wr[lanes], wi[lanes], pend[lanes] = 0.0, 0.0, False
        self.state = BankState(wr, wi, pend, s.n)

    @property
    def n_fed(self) -> int:
        """Number of samples processed since construction or ``reset()``."""
        return self.state.n

    @property
    def z(self) -> np.ndarray:
        """Current (pre-spike) state of the last processed sample, (n_receivers, n_channels)."""
        s = self.state
        if s.n == 0:
            z = np.zeros(self.model.lanes, dtype=complex)
        else:
            zr, zi = _z_of(
                self.model.tables, self.model.lane_ch, (s.n - 1) % self.model.tables.R, s.wr, s.wi
            )
            z = zr + 1j * zi
        return z.reshape(self.n_receivers, self.n_channels)

    @property
    def spiked_last(self) -> np.ndarray:
        """Whether the last processed sample spiked, shape (n_receivers, n_channels)."""
        return self.state.pend.reshape(self.n_receivers, self.n_channels).copy()

    # -- feeding --------------------------------------------------------------------------------
    def feed(
        self,
        samples: np.ndarray | Sequence[float],
        record: bool = False,
        readout: bool = False,
    ) -> FeedResult:
        """Advance by ``len(samples)`` samples of dense input; every spike is returned."""
        u = self._as_input(samples)
        rows = np.flatnonzero(np.any(u != 0.0, axis=1)) + self.state.n
        return self._run(
            self.state.n + u.shape[0], rows, u[rows - self.state.n], False, record, readout
        )

    def advance(
        self,
        end: int,
        rows: np.ndarray | Sequence[int] = (),
        values: np.ndarray | Sequence[float] = (),
        *,
        stop: bool = False,
        stop_lanes: np.ndarray | None = None,
        record: bool = False,
        readout: bool = False,
        receivers: np.ndarray | None = None,
        expand: bool = True,
    ) -> FeedResult:
        """Advance to sample ``end`` (exclusive) with input only at the absolute samples ``rows``
        (sorted, unique, from the bank's position on) of ``values`` ((len(rows),) for every
        receiver alike, or (len(rows), n_receivers)).  ``stop``: return right after the first
        sample with a spike (of a lane in ``stop_lanes``, a mask, if given; ``result.stopped``:
        the bank is then just past it). ``receivers``: a mask of the receivers that walk (the
        others' resonators stand still: their units listen no more; see ``resonate``, as for
        ``expand``)."""
        r = np.asarray(rows, dtype=np.int64).reshape(-1)
        v = np.asarray(values, dtype=float)
        if v.ndim <= 1:
            v = np.broadcast_to(v.reshape(-1, 1), (v.size, self.n_receivers))
        if v.shape != (r.size, self.n_receivers):
            raise BadInput(
                f"values of shape {np.shape(values)} do not fit {r.size} rows and "
                f"{self.n_receivers} receiver(s)"
            )
        n0 = self.state.n
        if r.size:
            if r[0] < n0 or r[-1] >= end or (r.size > 1 and bool((r[1:] <= r[:-1]).any())):
                raise BadInput(
                    f"input rows must be sorted, unique and within [{n0}, {end}): got "
                    f"{int(r[0])}..{int(r[-1])}"
                )
            if not np.isfinite(v).all():
                bad = int(r[np.flatnonzero(~np.isfinite(v).all(axis=1))[0]])
                raise BadInput(f"sample {bad} is not finite")
        return self._run(int(end), r, v, stop, record, readout, stop_lanes, receivers, expand)

    def _run(
        self,
        end: int,
        rows: np.ndarray,
        values: np.ndarray,
        stop: bool,
        record: bool,
        readout: bool,
        stop_lanes: np.ndarray | None = None,
        receivers: np.ndarray | None = None,
        expand: bool = True,
    ) -> FeedResult:
        self.state, result = resonate(
            self.model,
            self.state,
            end,
            rows,
            values,
            stop=stop,
            stop_lanes=stop_lanes,
            record=record,
            readout=readout,
            receivers=receivers,
            expand=expand,
        )
        return result

    def _as_input(self, samples: np.ndarray | Sequence[float]) -> np.ndarray:
        u = np.asarray(samples, dtype=float)
        if u.ndim == 1:
            u = u[:, None]
            if self.n_receivers > 1:
                u = np.broadcast_to(u, (u.shape[0], self.n_receivers))
        elif u.ndim != 2 or u.shape[1] != self.n_receivers:
            raise BadInput(
                f"samples of shape {np.shape(samples)} do not fit the bank: expected (n,) or "
                f"(n, {self.n_receivers}) for {self.n_receivers} receiver(s)"
            )
        if not np.isfinite(u).all():
            bad = int(np.flatnonzero(~np.isfinite(u).all(axis=1))[0])
            raise BadInput(f"sample {self.state.n + bad} is not finite")
        return u


@functools.lru_cache(maxsize=4096)  # every turn of a sender asks the same (its ID, its gain)
def clean_first_spike(
    omega: float,
    mode: str,
    tau: float,
    word: tuple[float, ...],
    offsets: tuple[int, ...],
    gain: float,
    within: int,
) -> int | None:
    """The sample, counted from the first pulse, at which a resonator on ω at rest first spikes
    when it hears ``gain·word[m]`` at sample ``offsets[m]`` (the first at 0) and nothing else,
    looking ``within`` samples; None if it does not. On a clean channel this is when a unit's
    attention spike to an ID comes (its resonators quenched at the turn's start, the ID alone
    on the medium): the instant the robust attention times a reaction from
    (docs/protocol.md, "Attention"). Pure: the update is time-invariant."""
    u = np.zeros(max(within, offsets[-1] + 1))
    for k, m in zip(offsets, word, strict=True):
        u[k] += gain * m
    spikes = ResonatorBank([omega], mode=mode, tau=tau).feed(u).spikes
    return int(spikes[0, 0]) if len(spikes) else None
