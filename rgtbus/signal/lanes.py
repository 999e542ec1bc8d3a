"""How the lanes of a bank walk an advance (``rgtbus.signal.resonator.resonate``): the typed
wrapper of the compiled walk (``_walk.walk_lanes``), the receivers that share one walk, and
the spikes found as a table. Arrays only: one call a walk, whatever the lanes."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from rgtbus.signal.kernels import WalkModel, walk_lanes


class BankModel(Protocol):
    """What a walk reads of a bank (``rgtbus.signal.resonator.BankModel``): its lane layout
    and its compiled view."""

    @property
    def receivers(self) -> int: ...
    @property
    def channels(self) -> int: ...
    @property
    def layout(self) -> tuple[np.ndarray, np.ndarray] | None: ...
    @property
    def lane_ch(self) -> np.ndarray: ...
    @property
    def lane_rec(self) -> np.ndarray: ...
    @property
    def lanes(self) -> int: ...
    @property
    def all_lanes(self) -> np.ndarray: ...
    @property
    def walker(self) -> WalkModel: ...


class BankState(Protocol):
    """What a walk reads of a bank's state (``rgtbus.signal.resonator.BankState``): each lane's
    rotating-frame state, its pending resets, and the next sample."""

    @property
    def wr(self) -> np.ndarray: ...
    @property
    def wi(self) -> np.ndarray: ...
    @property
    def pend(self) -> np.ndarray: ...
    @property
    def n(self) -> int: ...


def walk(
    M: BankModel,
    *,
    lanes: np.ndarray,
    wr: np.ndarray,
    wi: np.ndarray,
    pend: np.ndarray,
    start: int,
    end: int,
    rows: np.ndarray,
    vals: np.ndarray,
    spikes: np.ndarray,
    stop_first: bool = False,
    trajectory: Trajectory | None = None,
) -> tuple[int, int, bool]:
    """The compiled walk (``_walk.walk_lanes``) of ``lanes`` (ascending lane indexes) of the
    bank ``M``, from their state ``wr``, ``wi``, ``pend`` at sample ``start`` to ``end``,
    over the input at ``rows`` (int64) of ``vals`` (float64, (rows, receivers)).

    Every lane walks to ``end`` and its state is updated in place (the caller's copies), the
    spikes found written to ``spikes`` (int64 (2, room): their samples, then their lanes);
    with ``stop_first`` only the first spike is looked for and the state is only read; with
    a ``trajectory`` every sample's state is recorded there. Returns (the sample it stopped
    at, the spikes found, whether there were more than ``spikes`` has room for)."""
    xy, spiked = (None, None) if trajectory is None else trajectory
    return walk_lanes(
        model=M.walker,
        lanes=lanes,
        wr=wr,
        wi=wi,
        pend=pend.view(np.uint8),  # the compiled walk sees booleans as bytes
        start=start,
        end=end,
        rows=rows,
        vals=vals,
        stop_first=stop_first,
        spikes=spikes,
        trajectory=xy,
        spiked=spiked,
    )


class Trajectory(NamedTuple):
    """Every sample's state of every lane a recording walk writes: ``xy`` (2, samples,
    lanes), x then y, and the ``spiked`` mask (bytes: the compiled walk's booleans)."""

    xy: np.ndarray
    spiked: np.ndarray

    @staticmethod
    def empty(samples: int, lanes: int) -> Trajectory:
        """Room for a recording walk of ``samples`` samples of ``lanes`` lanes."""
        return Trajectory(np.empty((2, samples, lanes)), np.zeros((samples, lanes), dtype=np.uint8))


def walk_every_lane(
    M: BankModel,
    state: BankState,
    end: int,
    rows: np.ndarray,
    vals: np.ndarray,
    lanes: np.ndarray,
    record: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, Trajectory | None]:
    """Walk ``lanes`` from ``state`` to ``end`` on copies of its arrays (``state`` is left as
    it is): the walked wr, wi and pend, the spikes found (``walk``'s (2, room): the first
    ``count`` of each row) and, with ``record``, the trajectory. A walk that finds more
    spikes than it has room for walks again with more."""
    room = max(64, 4 * M.lanes)
    while True:
        wr, wi, pend = state.wr.copy(), state.wi.copy(), state.pend.copy()
        spikes = np.empty((2, room), dtype=np.int64)
        trajectory = Trajectory.empty(end - state.n, M.lanes) if record else None
        _, count, overflow = walk(
            M,
            lanes=lanes,
            wr=wr,
            wi=wi,
            pend=pend,
            start=state.n,
            end=end,
            rows=rows,
            vals=vals,
            spikes=spikes,
            trajectory=trajectory,
        )
        if not overflow:
            return wr, wi, pend, spikes, count, trajectory
        room *= 4


def walking_lanes(
    M: BankModel,
    state: BankState,
    vals: np.ndarray,
    n: int,
    receivers: np.ndarray | None,
    share: bool,
    record: bool,
) -> tuple[np.ndarray, Views | None]:
    """The lanes that walk an advance of ``n`` samples (ascending), and the views that share
    walks, if any (``resonate``'s ``receivers`` and ``share``; a picked layout, or a bank that
    records, walks every lane)."""
    if M.layout is not None or record:
        return M.all_lanes, None
    C = M.channels
    live = np.arange(M.receivers) if receivers is None else np.flatnonzero(receivers)
    # sharing costs a comparison of the views and a copy of the spikes: worth it on
    # long advances of many lanes, not on the short ones a serial run stops at
    share = share and n * live.size * C >= SHARE_MIN_WORK
    views = shared_views(M, state, vals, live) if share else None
    if views is not None:
        return views.lanes, views
    if receivers is not None:
        return (live[:, None] * C + np.arange(C)).ravel(), None
    return M.all_lanes, None


SHARE_MIN_WORK = 1 << 16  # lanes × samples of an advance from which receivers share views


@dataclass(frozen=True)
class Views:
    """Receivers that walk as one (``resonate``'s ``share``): ``live`` the receivers that
    walk, ``walker_of`` the receiver whose walk each takes (itself for a walker), ``lanes``
    the walkers' lanes (ascending)."""

    live: np.ndarray
    walker_of: np.ndarray
    lanes: np.ndarray

    def spikes(
        self, sp_k: np.ndarray, sp_l: np.ndarray, start: int, n: int, M: BankModel
    ) -> np.ndarray:
        """The walkers' spikes (sample, lane; lanes in ascending order within a sample, as
        they walk) as every live receiver's: (sample, receiver, channel), sorted by sample,
        receiver, channel."""
        C = M.channels
        if n < 2**15:  # by sample, stable (radix): the walkers' lane order is kept within
            order = np.argsort((sp_k - start).astype(np.int16), kind="stable")
        else:
            order = np.lexsort((sp_l, sp_k))
        k, lane = sp_k[order], sp_l[order]
        walker = lane // C
        # segments: the spikes of one walker at one sample (contiguous in this order)
        new = np.flatnonzero((k[1:] != k[:-1]) | (walker[1:] != walker[:-1])) + 1
        seg_start = np.concatenate(([0], new))
        seg_len = np.diff(np.concatenate((seg_start, [k.size])))
        seg_k = k[seg_start]
        runs, seg_run = np.unique(seg_k, return_inverse=True)
        # each live receiver, at each sample with spikes, takes its walker's segment there
        live, walker_of = self.live, self.walker_of
        walkers, col = np.unique(walker_of, return_inverse=True)
        table = np.full((runs.size, walkers.size), -1, dtype=np.int64)
        table[seg_run, np.searchsorted(walkers, walker[seg_start])] = np.arange(seg_start.size)
        take = table[:, col]  # (run, live receiver) -> segment, or -1
        counts = np.where(take >= 0, seg_len[take], 0).ravel()
        total = int(counts.sum())
        first = np.repeat(np.where(take >= 0, seg_start[take], 0).ravel(), counts)
        offset = np.repeat(np.cumsum(counts) - counts, counts)
        src = first + (np.arange(total) - offset)
        out = np.empty((total, 3), dtype=np.int64)
        out[:, 0] = k[src]
        out[:, 1] = np.repeat(np.tile(live, runs.size), counts)
        out[:, 2] = lane[src] % C
        return out


def shared_views(
    M: BankModel, state: BankState, vals: np.ndarray, live: np.ndarray
) -> Views | None:
    """Which of the ``live`` receivers start from the same lane states and hear the same input
    (bit for bit), so that one walk serves them all; None when no two do."""
    U, C = M.receivers, M.channels
    if live.size < 2:
        return None
    if _all_alike(vals, state, live, U, C):  # the usual case when any is: one view for all
        return Views(live, np.full(live.size, live[0]), live[0] * C + np.arange(C))
    inputs = np.ascontiguousarray(vals[:, live].T).view(np.int64)
    wr = state.wr.reshape(U, C)[live].view(np.int64)
    wi = state.wi.reshape(U, C)[live].view(np.int64)
    pend = state.pend.reshape(U, C)[live].astype(np.int64)
    key = np.concatenate([inputs, wr, wi, pend], axis=1)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    if first.size * 2 > live.size:  # little to share: walking each is cheaper
        return None
    walker_of = live[first][inverse.reshape(-1)]
    walkers = np.unique(walker_of)
    lanes = (walkers[:, None] * C + np.arange(C)).ravel()
    return Views(live, walker_of, lanes)


def _all_alike(vals: np.ndarray, state: BankState, live: np.ndarray, U: int, C: int) -> bool:
    """Whether the ``live`` receivers all start from the same lane states and hear the same
    input, bit for bit: on views of the arrays when every receiver is live (no copies), the
    first that differs ending the test."""
    pick = slice(None) if live.size == U else live
    grids = (
        np.ascontiguousarray(vals).view(np.int64)[:, pick].T,  # receivers × rows
        state.wr.reshape(U, C)[pick].view(np.int64),
        state.wi.reshape(U, C)[pick].view(np.int64),
        state.pend.reshape(U, C)[pick],
    )
    return all(bool((grid == grid[0]).all()) for grid in grids)


def spike_table(
    M: BankModel, spikes: np.ndarray, count: int, start: int, n: int, views: Views | None
) -> np.ndarray:
    """The first ``count`` spikes of a walk (``walk``'s (2, room)) as (sample, receiver,
    channel) rows, sorted by sample, receiver, channel; with ``views``, every live
    receiver's (its walker's)."""
    sample, lane = spikes[0, :count], spikes[1, :count]
    if count and views is not None:
        return views.spikes(sample, lane, start, n, M)
    table = np.empty((count, 3), dtype=np.int64)
    if count:
        if n < 2**15:
            # the lanes walk in ascending order, so a stable sort by sample keeps lane order
            # within one: on a 16-bit key numpy's stable sort is a radix sort
            order = np.argsort((sample - start).astype(np.int16), kind="stable")
        else:
            order = np.lexsort((lane, sample))
        lanes = lane[order]
        table[:, 0] = sample[order]
        table[:, 1] = M.lane_rec[lanes]
        table[:, 2] = M.lane_ch[lanes]
    return table
