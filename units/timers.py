"""A unit's timers: what it must do once every sample before a boundary has been heard.

Timers are ordered by (boundary, rank, seq): at one boundary the decodes and checks (rank 0)
come before the choices and repair steps (rank 1), which act on what those decoded; seq keeps
the order in which they were set. A shared listen queue is one cursor on the heap, not a timer
per listen: when its position is taken, the next goes on (``queue_next``) with the seq it would
have had as a timer of its own, so the order is the same.
"""

from __future__ import annotations

import heapq
from typing import NamedTuple

from rgtbus.protocol import Listen, ListenQueue

# a repair block's steps, each a timer: choose the requests, choose the repeats, read the copies
REPAIR_STEPS = ("request", "repeat", "copies")
_LATE = frozenset(("choose", *REPAIR_STEPS))  # after the decodes due at their boundary


class Timer(NamedTuple):
    """A unit's timer. A plain tuple, so the heap orders timers in C: by boundary, then rank,
    then seq (unique, so the fields after it are never compared)."""

    boundary: int  # act once every sample before this one has been heard
    rank: int  # at one boundary: decodes and checks (0) before choices (1)
    seq: int
    at: int  # the sample it belongs to (its time)
    kind: str  # "listen" | "deadline" | "limit" | "choose" | "request" | "repeat" | "copies"
    listen: Listen | None = None
    # a listen from a shared queue: (queue, its first seq, its place in the queue)
    queued: tuple[ListenQueue, int, int] | None = None


class Timers:
    """A unit's timers as a heap (see the module docstring), and the boundaries of those that
    are not listens (``others``: how far a batch of decodes may go)."""

    def __init__(self) -> None:
        self.heap: list[Timer] = []
        self._others: list[int] = []
        self.seq = 0  # the next timer's seq
        self._deadline: Timer | None = None

    def __bool__(self) -> bool:
        return bool(self.heap)

    @property
    def first(self) -> Timer:
        """The timer that falls due first."""
        return self.heap[0]

    def add(self, boundary: int, at: int, kind: str, listen: Listen | None = None) -> Timer:
        """A timer of ``kind`` for sample ``at``, due once every sample before ``boundary``
        has been heard."""
        timer = Timer(boundary, int(kind in _LATE), self.seq, at, kind, listen)
        self.seq += 1
        heapq.heappush(self.heap, timer)
        if kind != "listen":
            heapq.heappush(self._others, boundary)
        return timer

    def add_queue(self, queue: ListenQueue) -> None:
        """A shared listen queue: a cursor at its first position (its listens take the next
        ``len(queue)`` seqs)."""
        self.queue_next(queue, self.seq, 0)
        self.seq += len(queue)

    def queue_next(self, queue: ListenQueue, first_seq: int, i: int) -> None:
        """The i-th listen of ``queue`` to fall due goes on the heap, with the seq it would
        have had as a timer of its own."""
        if i < len(queue):
            n = int(queue.order[i])
            b = int(queue.boundaries[i])
            listen = queue.listen(n)
            heapq.heappush(
                self.heap,
                Timer(b, 0, first_seq + n, b - 1, "listen", listen, (queue, first_seq, i)),
            )

    def set_deadline(self, sample: int) -> None:
        """The current turn's deadline at ``sample`` (one at a time: it replaces the last)."""
        if self._deadline is not None:
            self.heap.remove(self._deadline)
            heapq.heapify(self.heap)
        self._deadline = self.add(sample + 1, sample, "deadline")

    def deadline_passed(self) -> None:
        """The deadline's timer was taken."""
        self._deadline = None

    def pop_due(self, pos: int) -> Timer | None:
        """The first timer whose samples have all been heard (every sample before ``pos``),
        taken off the heap; None if there is none."""
        if self.heap and self.heap[0][0] <= pos:
            return heapq.heappop(self.heap)
        return None

    def batch_end(self, first: int, span: int) -> int:
        """How far a batch of decodes may go from boundary ``first``: to the next timer that is
        not a listen (a deadline, a goal's choice, the limit), at most ``span`` samples on."""
        others = self._others
        while others and others[0] < first:  # timers of the past (taken, or replaced)
            heapq.heappop(others)
        far = first + span
        if others and others[0] < far:
            far = others[0]
        return max(first, far)
