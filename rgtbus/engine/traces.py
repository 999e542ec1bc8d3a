"""Resonator traces (``--traces``): each traced unit's states, handed to its sink a window of
samples at a time, whatever the lengths of the ears' advances."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from rgtbus.engine.listener import TraceSink


class _Traced(Protocol):
    trace: TraceSink | None


class TraceWindows:
    """The traces of ``listeners`` not yet handed over, cut at every multiple of ``window``."""

    def __init__(self, listeners: Sequence[_Traced], window: int) -> None:
        self.listeners = list(listeners)
        self.window = window
        self._buf: dict[int, list[tuple[int, np.ndarray, np.ndarray]]] = {}

    def add(self, n: int, lo: int, x: np.ndarray, y: np.ndarray) -> None:
        """Unit ``n``'s states from sample ``lo`` on (x, y: samples × channels); every window
        they complete goes to its sink."""
        buf = self._buf.setdefault(n, [])
        buf.append((lo, x, y))
        first = buf[0][0]
        end = lo + x.shape[0]
        w0 = first // self.window
        while (w0 + 1) * self.window <= end:
            self._emit(n, (w0 + 1) * self.window)
            buf = self._buf.get(n, [])
            if not buf:
                return
            w0 = buf[0][0] // self.window

    def _emit(self, n: int, upto: int) -> None:
        """Hand unit n the trace rows before ``upto`` (a window boundary, or where it stopped)."""
        buf = self._buf.get(n, [])
        if not buf:
            return
        first = buf[0][0]
        xs = np.concatenate([b[1] for b in buf])
        ys = np.concatenate([b[2] for b in buf])
        k = upto - first
        sink = self.listeners[n].trace
        assert sink is not None
        sink(first, xs[:k], ys[:k])
        rest = [(upto, xs[k:], ys[k:])] if xs.shape[0] > k else []
        self._buf[n] = rest

    def flush(self, n: int) -> None:
        """Unit ``n`` stopped: the rest of its traces go to its sink."""
        buf = self._buf.get(n, [])
        if buf:
            self._emit(n, buf[-1][0] + buf[-1][1].shape[0])
