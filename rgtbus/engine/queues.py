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

QUEUE_CHUNK = 256  # positions of a shared queue read (for every receiver) and kept together
# decodes positions [q0, q1) of a queue for every receiver: (word, channel index, margin),
# (positions × receivers) each
QueueRead = Callable[[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]]
Columns = tuple[np.ndarray, np.ndarray, np.ndarray]

_T = TypeVar("_T")


class QueueDecodes:
    """One shared listen queue's decodes for every receiver: chunks of ``QUEUE_CHUNK``
    positions, each (positions × receivers) arrays of word, channel and margin, filled in
    order as units reach them and dropped once every listening unit has passed them."""

    def __init__(self, queue: object, receivers: int) -> None:
        self.queue = queue  # kept alive: it is found by id
        self.receivers = receivers
        self.cursor = np.zeros(receivers, dtype=np.int64)  # each unit's next position
        self.chunks: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]] = {}

    def rows(self, c: int, lo: int, hi: int, read: QueueRead, i: int) -> Columns:
        """Receiver ``i``'s decodes of positions [lo, hi) within chunk ``c`` (the chunk read
        up to ``hi`` for every receiver first, in order)."""
        chunk = self.chunks.get(c)
        if chunk is None:
            R = self.receivers
            chunk = self.chunks[c] = (
                np.empty((QUEUE_CHUNK, R), dtype=np.int64),
                np.empty((QUEUE_CHUNK, R), dtype=np.int64),
                np.empty((QUEUE_CHUNK, R)),
                [0],  # positions filled
            )
        word, chan, margin, filled = chunk
        base = c * QUEUE_CHUNK
        a, b = max(lo, base) - base, min(hi, base + QUEUE_CHUNK) - base
        if filled[0] < b:  # in order: every position before is heard too
            k = filled[0]
            word[k:b], chan[k:b], margin[k:b] = read(base + k, base + b)
            filled[0] = b
        return word[a:b, i], chan[a:b, i], margin[a:b, i]

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
        cache = self._queues.get(id(queue))
        if cache is None:
            cache = self._queues[id(queue)] = QueueDecodes(queue, self.receivers)
        parts = [
            cache.rows(c, lo, hi, read, i)
            for c in range(lo // QUEUE_CHUNK, (hi - 1) // QUEUE_CHUNK + 1)
        ]
        self.passed(i, queue, lo)
        if len(parts) == 1:
            return parts[0]
        word, chan, margin = zip(*parts, strict=True)
        return np.concatenate(word), np.concatenate(chan), np.concatenate(margin)

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
