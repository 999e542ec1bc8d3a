"""The spikes of the logged units of one set of ears, kept as arrays and handed to each unit's
log a block at a time (``SpikeKeeper``).

The ears keep every spike of the units they log (sample, walker, channel: no Python object per
spike) and hand each unit a block of ``block`` samples once they have heard the whole block, or
as far as they heard when the unit stops (or up to the sample it names then), or when the run
ends: a unit wakes only for the spike it awaits, and records written at its wake could trail
the run's clock. Units that heard a block's spikes alike, bit for bit, get them as one
``SharedSpikes``, so a log holds one record of them, not one copy a unit. Which records a log
holds, and their order (block, first unit), depend only on the blocks, never on how the ears
advanced (docs/engine.md, "Spikes").
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple, Protocol, cast

import numpy as np

from rgtbus.errors import BadInput

_GROUPS_KEPT = 64  # groups of units whose names and logs a keeper keeps made (``_group``)
SMALL_HAND_OVER = 4096  # spikes of a hand-over grouped in plain Python (``_hand_blocks_small``)


class SpikeLog(Protocol):
    """Where a unit's spikes go for its log, a block of ``block`` samples at a time. The ears
    keep the spikes of the units they log in arrays (no call per spike: a large run's
    receivers fire for every code of every turn) and hand each unit a block's spikes once they
    have heard the whole block, or as far as they heard when the unit stops (or up to the
    sample it names then) or the run ends: a unit wakes only for the spike it awaits, and
    records written at its wake could trail the run's clock by seconds."""

    block: int

    def spikes(self, samples: np.ndarray, index: np.ndarray, fired: np.ndarray, end: int) -> None:
        """The spikes of one block: at ``samples[i]`` (ascending) the resonator of channel
        ``fired[index[i]]`` fired (a sample's channels ascending; ``fired``: the channels
        that fired in the block, ascending); heard up to sample ``end`` (the block's end, or
        less for the last block of a unit that stopped)."""
        ...

    def shared_spikes(self, block: SharedSpikes) -> None:
        """The spikes of one block that this unit and others heard alike (``SharedSpikes``):
        the unit settles it (``SharedSpikes.settle``) once it knows whether it listened
        through the block's end."""
        ...

    def keeps_now(self) -> bool:
        """Whether this unit would keep a block handed now at once (it holds none for a
        later wake, which may find it was done before the block's end)."""
        ...

    def shared_kept(
        self, names: list[str], samples: np.ndarray, index: np.ndarray, fired: np.ndarray, end: int
    ) -> None:
        """The record of one block that the units ``names`` (this one among them) heard alike
        and every one keeps at once (``keeps_now``): written as handed, with nothing to settle
        (a serial 10-unit run hands ~750 blocks of ~2 spikes each to all ten units)."""
        ...


class SharedSpikes:
    """One block's spikes that several logged units of one process heard alike, bit for bit
    (a noise-free medium through equal link gains: they walk as one, ``resonate``'s share),
    for a single ``/rx/spike`` record of them all instead of one copy a unit (fields as
    ``SpikeLog.spikes``; ``members`` the units' indices among the listeners, ``names`` theirs).

    Each member settles it once: it kept the block (it listened through its end) or it left
    it (it was done before: its own record holds its spikes up to there). The last to settle
    learns which members kept it, and writes their record."""

    __slots__ = ("_kept", "_member_set", "end", "fired", "index", "members", "names", "samples")

    def __init__(
        self,
        samples: np.ndarray,
        index: np.ndarray,
        fired: np.ndarray,
        end: int,
        members: Sequence[int],
        names: Sequence[str],
        member_set: frozenset[int] | None = None,
    ) -> None:
        self.samples, self.index, self.fired, self.end = samples, index, fired, end
        # read, never changed: a keeper hands every block of one group the same lists
        self.members, self.names = members, names
        self._member_set = frozenset(members) if member_set is None else member_set
        self._kept: dict[int, bool] = {}

    def settle(self, member: int, kept: bool) -> list[str] | None:
        """Member ``member`` kept the block, or left it; once every member has settled, the
        names of those that kept it (member order), else None."""
        if member not in self._member_set:
            raise BadInput(f"unit {member} settles a block of units {self.members}")
        if member in self._kept:
            raise BadInput(f"unit {member} settles a block of units {self.members} again")
        self._kept[member] = kept
        if len(self._kept) < len(self.members):
            return None
        return [n for m, n in zip(self.members, self.names, strict=True) if self._kept[m]]


class SpikePiece(NamedTuple):
    """The kept spikes of one advance: ``k`` sample, ``w`` walker (the receiver that walked),
    ``c`` channel, in the walk's order (sample, walker, channel); ``walker_of`` each
    receiver's walker (-1: it stood still), None when every receiver walked on its own."""

    k: np.ndarray
    w: np.ndarray
    c: np.ndarray
    walker_of: np.ndarray | None

    def cut(self, a: int, b: int) -> SpikePiece:
        return SpikePiece(self.k[a:b], self.w[a:b], self.c[a:b], self.walker_of)


class _Logged(Protocol):
    """What the keeper reads of a listener: its name and where its spikes go."""

    name: str
    spike_log: SpikeLog | None


class SpikeKeeper:
    """The kept spikes of the logged ``listeners`` (each with a ``spike_log``; all log in
    blocks of one size), a piece an advance, and their hand-over (see the module docstring)."""

    def __init__(self, listeners: Sequence[_Logged]) -> None:
        self.listeners = list(listeners)
        blocks = {lst.spike_log.block for lst in self.listeners if lst.spike_log is not None}
        if len(blocks) > 1:
            raise BadInput(f"the units log spikes in blocks of different sizes: {blocks}")
        self.block = blocks.pop() if blocks else 1
        self.pieces: list[SpikePiece] = []  # kept and not yet handed, an advance a piece
        self._pending: list[np.ndarray] = []  # advances' spikes not yet made a piece
        self._pending_of: np.ndarray | None = None  # their walkers (None: each its own)
        self.due = self.block  # the next block boundary to hand blocks over at
        # which units' spikes are kept: logged and still listening (``stop``)
        self.log_mask = np.array([lst.spike_log is not None for lst in self.listeners])
        self.ended = np.zeros(len(self.listeners), dtype=bool)  # its last block handed
        self.logging = bool(self.log_mask.any())  # whether any listener logs its spikes
        # the units of a group that heard blocks alike: their names, logs and set, made once
        # for the thousands of blocks a large group hears alike (``_hand_block``)
        self._groups: dict[tuple[int, ...], tuple[list[str], list[SpikeLog], frozenset[int]]] = {}

    def stop(self, i: int) -> None:
        """Listener ``i`` listens no more: its spikes are no longer kept."""
        self.log_mask[i] = False

    def keep(self, spikes: np.ndarray, walker_of: np.ndarray | None) -> None:
        """Keep what a logged unit takes of one advance's ``spikes`` (rows of sample, walker,
        channel; ``walker_of``: each receiver's walker, None when each walked alone): a walk
        is kept while a logged unit took it."""
        if not len(spikes):
            return
        if walker_of is None:
            serves = self.log_mask
        else:
            serves = np.zeros(len(self.listeners), dtype=bool)
            serves[walker_of[self.log_mask & (walker_of >= 0)]] = True
        kept = spikes if serves.all() else spikes[serves[spikes[:, 1]]]
        if len(kept):  # as columns, walker and channel in 4 bytes: 16 bytes a spike
            self._keep_piece(kept, walker_of)

    def heard_to(self, end: int) -> None:
        """The ears have heard every sample before ``end``: the blocks it completes go out."""
        if end >= self.due:
            upto = end // self.block * self.block
            self.hand(upto, end)
            self.due = upto + self.block

    def _keep_piece(self, keep: np.ndarray, walker_of: np.ndarray | None) -> None:
        """Keep one advance's spikes (sample, walker, channel) for the logs. Advances that
        walked alike (the same walker for each receiver) make one piece: a serial run
        advances a few samples at a time, and a piece each made the hand-over's work grow
        with the advances, not the spikes."""
        same = self._pending_of is walker_of or (
            self._pending_of is not None
            and walker_of is not None
            and np.array_equal(self._pending_of, walker_of)
        )
        if self._pending and not same:
            self.close_pending()
        self._pending.append(keep)
        self._pending_of = walker_of

    def close_pending(self) -> None:
        """The spikes kept since the walkers last changed, as one piece."""
        if not self._pending:
            return
        rows = np.concatenate(self._pending) if len(self._pending) > 1 else self._pending[0]
        self._pending = []
        self.pieces.append(
            SpikePiece(
                rows[:, 0].copy(),
                rows[:, 1].astype(np.int32),
                rows[:, 2].astype(np.int32),
                self._pending_of,
            )
        )

    def end(self, i: int, heard: int, at: int | None = None) -> None:
        """Hand unit ``i`` every spike kept for its log (it stopped, or the run ended): its
        last block as far as the ears heard, or up to sample ``at`` (the rest is dropped)."""
        self.hand(at, heard, only=i)

    def hand(self, upto: int | None, heard: int, only: int | None = None) -> None:
        """Each logged unit's kept spikes before sample ``upto`` (None: all), a block at a
        time, in the order (block, unit): which records a log holds, and their order, depend
        only on the blocks, not on how the ears advanced. Units that heard the same spikes in
        a block get them as one ``SharedSpikes``. ``only``: unit ``only``'s last spikes, its
        last block ending at ``upto`` (or as far as the ears heard); its spikes at or after
        ``upto`` are dropped, and it gets no more."""
        self.close_pending()
        if not self.pieces:
            return
        if only is None:  # a block boundary: the spikes before it, slices (no copy)
            mine, rest = [], []
            for p in self.pieces:
                cut = len(p.k) if upto is None else int(p.k.searchsorted(upto))
                mine.append(p.cut(0, cut))
                if cut < len(p.k):
                    rest.append(p.cut(cut, len(p.k)))
            self.pieces = rest
            members = np.flatnonzero(self.log_mask)
        else:  # the others still need the walks it took: read, not taken
            if self.ended[only]:  # handed its last already
                return
            self.ended[only] = True
            if upto is not None:
                heard = min(heard, upto)
            mine = [
                p if upto is None else p.cut(0, int(p.k.searchsorted(upto))) for p in self.pieces
            ]
            members = np.array([only])
            self.log_mask[only] = False
        self._hand_blocks([p for p in mine if len(p.k)], members, heard)

    def _hand_blocks(self, pieces: list[SpikePiece], members: np.ndarray, heard: int) -> None:
        """Hand the ``members`` their spikes in ``pieces`` (in time order), a block at a time:
        a unit's spikes in a block are its walker's in each piece. Units whose spikes in a
        block are equal share one ``SharedSpikes``, whichever walks they came from."""
        if not pieces or not members.size:
            return
        if self._hand_as_one(pieces, members, heard):
            return
        if sum(len(p.k) for p in pieces) <= SMALL_HAND_OVER:
            self._hand_blocks_small(pieces, members, heard)
            return
        U = len(self.listeners)
        B = self.block
        k = np.concatenate([p.k for p in pieces])
        w = np.concatenate([p.w for p in pieces])
        c = np.concatenate([p.c for p in pieces])
        piece = np.repeat(np.arange(len(pieces)), [len(p.k) for p in pieces])
        block = k // B
        # segments: one piece within one block (in time order); sorted by (segment, walker),
        # stable, each walker's spikes of a segment are one run, in (sample, channel) order
        new = np.concatenate(([True], (block[1:] != block[:-1]) | (piece[1:] != piece[:-1])))
        seg = np.cumsum(new) - 1
        n_seg = int(seg[-1]) + 1
        if n_seg * U < 2**15:  # numpy's stable sort of a 16-bit key is a radix sort
            order = np.argsort((seg * U + w).astype(np.int16), kind="stable")
        else:
            order = np.lexsort((w, seg))
        k, w, c, seg = k[order], w[order], c[order], seg[order]
        starts = np.flatnonzero(np.concatenate(([True], (seg[1:] != seg[:-1]) | (w[1:] != w[:-1]))))
        ends = np.append(starts[1:], len(k))
        run = np.full((n_seg, U), -1, dtype=np.int64)  # (segment, walker) -> its run
        run[seg[starts], w[starts]] = np.arange(starts.size)
        seg_first = np.flatnonzero(new)  # in the unsorted order: each segment's block, piece
        seg_block, seg_piece = block[seg_first], piece[seg_first]
        # each segment's walker of every member (a piece where every receiver walked alone:
        # the member itself)
        src = np.empty((n_seg, members.size), dtype=np.int64)
        for p in np.unique(seg_piece).tolist():
            wo = pieces[p].walker_of
            src[seg_piece == p] = members if wo is None else wo[members]
        runs_of = np.where(src >= 0, run[np.arange(n_seg)[:, None], np.maximum(src, 0)], -1)
        blocks, first = np.unique(seg_block, return_index=True)
        bounds = [*first.tolist(), n_seg]
        starts_l, ends_l = starts.tolist(), ends.tolist()
        for b, s0, s1 in zip(blocks.tolist(), bounds, bounds[1:], strict=False):
            # a member's runs in this block, one per segment: equal rows, equal spikes
            if s1 - s0 == 1:  # one piece in this block (the usual case): a run a member
                sigs, inverse = np.unique(runs_of[s0], return_inverse=True)
                sigs = sigs[:, None]
            else:
                sigs, inverse = np.unique(runs_of[s0:s1].T, axis=0, return_inverse=True)
            groups: dict[tuple[int, ...], list[int]] = {}  # equal spikes, from whichever walks
            arrays: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]] = {}
            for g, sig in enumerate(sigs.tolist()):
                cuts = [(starts_l[r], ends_l[r]) for r in sig if r >= 0]
                if not cuts:
                    continue
                samples = np.concatenate([k[x:y] for x, y in cuts])
                channel = np.concatenate([c[x:y] for x, y in cuts])
                key: tuple[int, ...] = (len(samples), int(samples.sum()), int(channel.sum()))
                while key in arrays and not (
                    np.array_equal(arrays[key][0], samples)
                    and np.array_equal(arrays[key][1], channel)
                ):
                    key = (*key, g)  # the same sums, other spikes: a group of its own
                arrays.setdefault(key, (samples, channel))
                groups.setdefault(key, []).extend(
                    members[np.flatnonzero(inverse.reshape(-1) == g)].tolist()
                )
            end = min((b + 1) * B, heard)
            for key in sorted(groups, key=lambda key: min(groups[key])):
                samples, channel = arrays[key]
                self._hand_block(sorted(groups[key]), samples, channel, end)

    def _hand_blocks_small(self, pieces: list[SpikePiece], members: np.ndarray, heard: int) -> None:
        """``_hand_blocks`` for a few spikes (a serial run hands a block or two of a few
        spikes at a time, from receivers that each walked alone since their own quench):
        the same blocks, groups and order, grouped in plain Python: for a few spikes the
        arrays' fixed cost per call outweighs their work (docs/engine.md, "Measured")."""
        B = self.block
        mine: dict[int, dict[int, list[tuple[int, int]]]] = {}  # block -> member -> spikes
        for p in pieces:
            walks: dict[int, dict[int, list[tuple[int, int]]]] = {}  # walker -> block -> spikes
            for k, w, c in zip(p.k.tolist(), p.w.tolist(), p.c.tolist(), strict=True):
                walks.setdefault(w, {}).setdefault(k // B, []).append((k, c))
            of = None if p.walker_of is None else p.walker_of.tolist()
            for m in members.tolist():
                for b, spikes in walks.get(m if of is None else of[m], {}).items():
                    mine.setdefault(b, {}).setdefault(m, []).extend(spikes)
        for b in sorted(mine):
            groups: dict[tuple[tuple[int, int], ...], list[int]] = {}
            for m, spikes in mine[b].items():
                groups.setdefault(tuple(spikes), []).append(m)
            end = min((b + 1) * B, heard)
            for heard_alike, units in sorted(groups.items(), key=lambda g: min(g[1])):
                samples = np.array([k for k, _ in heard_alike], dtype=np.int64)
                channel = np.array([c for _, c in heard_alike], dtype=np.int32)
                self._hand_block(sorted(units), samples, channel, end)

    def _hand_as_one(self, pieces: list[SpikePiece], members: np.ndarray, heard: int) -> bool:
        """``_hand_blocks`` where every member took one and the same walk in each piece (a
        noise-free medium through equal gains: the usual case), so all have the same spikes
        in every block: one group a block, with no grouping to do. False (nothing handed)
        otherwise."""
        parts = []
        for p in pieces:
            wo = p.walker_of
            if wo is None:
                if members.size != 1:
                    return False
                walker = int(members[0])
            else:
                walkers = wo[members]
                walker = int(walkers[0])
                if walker < 0 or not (walkers == walker).all():
                    return False
            mine = p.w == walker
            parts.append((p.k, p.c) if mine.all() else (p.k[mine], p.c[mine]))
        k = np.concatenate([a for a, _ in parts]) if len(parts) > 1 else parts[0][0]
        c = np.concatenate([b for _, b in parts]) if len(parts) > 1 else parts[0][1]
        if not k.size:
            return True
        B = self.block
        units = sorted(members.tolist())
        blocks = k // B
        cuts = [*np.flatnonzero(blocks[1:] != blocks[:-1]) + 1, k.size]
        a = 0
        for z in cuts:
            z = int(z)
            self._hand_block(units, k[a:z], c[a:z], min((int(blocks[a]) + 1) * B, heard))
            a = z
        return True

    def _group(self, units: list[int]) -> tuple[list[str], list[SpikeLog], frozenset[int]]:
        """The names, logs and set of ``units``, made once a group (a few groups at a time:
        a noisy run's groups change from block to block)."""
        key = tuple(units)
        got = self._groups.get(key)
        if got is None:
            if len(self._groups) >= _GROUPS_KEPT:
                self._groups.clear()
            got = self._groups[key] = (
                [self.listeners[u].name for u in units],
                [cast(SpikeLog, self.listeners[u].spike_log) for u in units],
                frozenset(units),
            )
        return got

    def _hand_block(
        self, units: list[int], samples: np.ndarray, channel: np.ndarray, end: int
    ) -> None:
        """One block's spikes (sample order, then channel) that ``units`` heard alike, heard
        up to ``end``: a unit's own ``spikes``, or one ``SharedSpikes`` for two or more."""
        # the channels that fired and each spike's index among them
        present = np.zeros(int(channel.max()) + 1, dtype=bool)
        present[channel] = True
        fired = np.flatnonzero(present)
        index = (np.cumsum(present, dtype=np.int32) - 1)[channel]
        if len(units) == 1:
            log = self.listeners[units[0]].spike_log
            assert log is not None
            log.spikes(samples, index, fired, end)
            return
        names, logs, member_set = self._group(units)
        if all(log.keeps_now() for log in logs):  # as the last of them to settle would write
            logs[-1].shared_kept(list(names), samples, index, fired, end)
            return
        share = SharedSpikes(samples, index, fired, end, units, names, member_set)
        for log in logs:
            log.shared_spikes(share)
