"""What the units of one set of ears work out alike, done once for all of them: a shared listen
queue's decodes (``SharedQueues.decodes``: each position read once, for every receiver, by
whichever unit gets there first) and anything else built from one key (``SharedQueues.shared``).

A run of n units decodes 4n²(n−1) codes under the concurrent schedule: they are held as
(positions × receivers) arrays, a chunk of ``QUEUE_CHUNK`` positions at a time, each chunk
dropped once every listening unit has passed it; no Python object per decode.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar, cast

import numpy as np

# positions of a shared queue read (for every receiver) and kept together: a unit's batch takes
# its column of each chunk it spans, a copy a chunk and column (at 256 positions, a 300-unit
# batch spanned ~18 chunks; 1,024 cost 3.5 % fewer instructions at n = 100, and 16 MB per
# chunk at n = 1,000)
QUEUE_CHUNK = 1024
# decodes positions [q0, q1) of a queue for every receiver: (word, channel index, margin),
# (positions × receivers) each
QueueRead = Callable[[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]]
Columns = tuple[np.ndarray, np.ndarray, np.ndarray]

_T = TypeVar("_T")


class QueueDecodes:
    """One shared listen queue's decodes for every receiver: chunks of ``QUEUE_CHUNK``
    positions, each (positions × receivers) arrays of word, channel (4 bytes each) and
    margin, filled in order (as the ears hear each position whole, or as a unit reaches it)
    and dropped once every listening unit has passed them."""

    def __init__(self, queue: object, receivers: int) -> None:
        self.queue = queue  # kept alive: it is found by id
        self.receivers = receivers
        self.cursor = np.zeros(receivers, dtype=np.int64)  # each unit's next position
        self.chunks: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self.filled = 0  # every position before this one is read

    def fill(self, upto: int, read: QueueRead) -> None:
        """Read every position before ``upto`` not read yet, a chunk's part at a time."""
        while self.filled < upto:
            c, k = divmod(self.filled, QUEUE_CHUNK)
            chunk = self.chunks.get(c)
            if chunk is None:
                R = self.receivers
                chunk = self.chunks[c] = (
                    np.empty((QUEUE_CHUNK, R), dtype=np.int32),
                    np.empty((QUEUE_CHUNK, R), dtype=np.int32),
                    np.empty((QUEUE_CHUNK, R)),
                )
            b = min(QUEUE_CHUNK, upto - c * QUEUE_CHUNK)
            word, chan, margin = chunk
            base = c * QUEUE_CHUNK
            word[k:b], chan[k:b], margin[k:b] = read(base + k, base + b)
            self.filled = base + b

    def forget(self, low: int) -> None:
        """Drop the chunks every listening unit has passed (``low``: the least cursor)."""
        for c in [c for c in self.chunks if (c + 1) * QUEUE_CHUNK <= low]:
            del self.chunks[c]


class SharedQueues:
    """The shared work of the ``receivers`` units of one set of ears (see the module
    docstring)."""

    def __init__(self, receivers: int) -> None:
        self.receivers = receivers
        self._queues: dict[int, QueueDecodes] = {}
        self._shared: dict[int, tuple[object, object]] = {}
        self.listening = np.ones(receivers, dtype=bool)
        # queues read as the ears hear their positions whole: (decodes, boundaries, read)
        self._eager: dict[int, tuple[QueueDecodes, np.ndarray, QueueRead]] = {}

    @property
    def eager(self) -> bool:
        """Whether a queue is read as its positions are heard (``read_heard``)."""
        return bool(self._eager)

    def read_as_heard(self, queue: object, boundaries: np.ndarray, read: QueueRead) -> None:
        """Read ``queue``'s positions as soon as they are heard whole (position i once the
        ears are at ``boundaries[i]``), not when a unit first asks for them: a unit that
        takes its decodes a batch at a time then needs no readout kept for the batch."""
        if id(queue) not in self._eager:
            self._eager[id(queue)] = (self._cache(queue), boundaries, read)

    def read_heard(self, pos: int) -> None:
        """The ears are at sample ``pos``: every position of an eager queue whose samples have
        all been heard is read (``read_as_heard``)."""
        for cache, boundaries, read in self._eager.values():
            cache.fill(int(boundaries.searchsorted(pos, side="right")), read)

    def _cache(self, queue: object) -> QueueDecodes:
        cache = self._queues.get(id(queue))
        if cache is None:
            cache = self._queues[id(queue)] = QueueDecodes(queue, self.receivers)
        return cache

    def shared(self, key: object, build: Callable[[], _T]) -> _T:
        """What every unit works out alike from ``key`` (a listen queue, say), built once by
        the first that asks (``key`` is kept alive: it is found by id)."""
        got = self._shared.get(id(key))
        if got is None:
            got = self._shared[id(key)] = (key, build())
        return cast(_T, got[1])

    def decodes(self, i: int, queue: object, lo: int, hi: int, read: QueueRead) -> Columns:
        """Unit ``i``'s decodes of positions [lo, hi) of ``queue`` (all heard): each one's
        word, channel index and margin, as columns. ``read(q0, q1)`` decodes positions
        [q0, q1) for every receiver at once; each position is read once, and kept until
        every listening unit has taken it (``passed``)."""
        cache = self._cache(queue)
        cache.fill(hi, read)
        first, last = lo // QUEUE_CHUNK, (hi - 1) // QUEUE_CHUNK
        self.passed(i, queue, lo)
        chunks = cache.chunks
        if first == last:
            word, chan, margin = chunks[first]
            a, b = lo - first * QUEUE_CHUNK, hi - first * QUEUE_CHUNK
            return word[a:b, i], chan[a:b, i], margin[a:b, i]
        out: Columns = (  # receiver i's column of each chunk, into one array each
            np.empty(hi - lo, dtype=np.int32),
            np.empty(hi - lo, dtype=np.int32),
            np.empty(hi - lo),
        )
        for c in range(first, last + 1):
            base = c * QUEUE_CHUNK
            a, b = max(lo, base), min(hi, base + QUEUE_CHUNK)
            for col, part in zip(out, chunks[c], strict=True):
                col[a - lo : b - lo] = part[a - base : b - base, i]
        return out

    def passed(self, i: int, queue: object, q: int) -> None:
        """Unit ``i`` has taken every position of ``queue`` before ``q`` (it may ask again
        for any from ``q`` on: a batch it acted on only in part)."""
        cache = self._queues.get(id(queue))
        if cache is not None:
            cache.cursor[i] = max(int(cache.cursor[i]), q)
            cache.forget(int(cache.cursor[self.listening].min(initial=q)))

    def stop(self, i: int) -> None:
        """Unit ``i`` listens no more: the queues no longer wait for it."""
        self.listening[i] = False
