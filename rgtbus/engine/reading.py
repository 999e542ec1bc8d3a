"""Every decode the ears make on their readout, in one place (``Readings``): a unit's decode of
one code (``decode_among``, ``read_code``: worked out for every listener of the ears at once,
since the units of a process decode each code at about the same time, and kept while the
readout's end stays put), and the column forms a unit's batch of a shared queue reads
(``id_columns``, ``among_columns``, ``block_columns``: one answer a receiver, no ``Decision``
each). Each decodes by the rule its word set carries (``rgtbus.signal.rules``); the unit's
listening (``rgtbus.units.listening``) decides what to read and when, never how.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rgtbus.signal.decoder import (
    Decision,
    ReadoutHistory,
    WordSet,
    decode_among_columns,
    decode_among_each,
    nearest_columns,
    nearest_each,
    nearest_many_columns,
)

_AmongKey = tuple[tuple[int, ...], float, WordSet, int]  # channels, start, words, search
_ReadKey = tuple[tuple[int, ...], int, WordSet]  # samples, channel, words


class Readings:
    """The decodes made on ``readout`` (every listener's, receivers in listener order), its
    channels on ``omegas`` at sample period ``tau`` (module docstring)."""

    def __init__(self, readout: ReadoutHistory, omegas: Sequence[float], tau: float) -> None:
        self.readout = readout
        self.omegas = omegas
        self.tau = tau
        # decodes asked at the present end of the readout: every unit of the process decodes
        # the same code at about the same time, so the first ask reads all of them
        self._among: dict[_AmongKey, list[tuple[Decision, int]]] = {}
        self._reads: dict[_ReadKey, list[Decision]] = {}
        self._end = -1

    @property
    def end(self) -> int:
        """The first sample the readout does not hold yet."""
        return self.readout.end

    @property
    def receivers(self) -> int:
        """The listeners whose readout it is."""
        return self.readout.receivers

    def _pairs(self, channels: Sequence[int]) -> tuple[tuple[int, float], ...]:
        return tuple((c, float(self.omegas[c])) for c in channels)

    # -- one code, for one unit (every listener's worked out at once) ------------------------

    def decode_among(
        self, i: int, channels: tuple[int, ...], start: float, words: WordSet, search: int
    ) -> tuple[Decision, int]:
        """Listener ``i``'s decode of a code that started at ``start`` on one of ``channels``
        (channel indexes), with a timing search of ``search`` samples either way: its word
        and the channel it came on (``decode_among_each``)."""
        self._forget()
        key = (channels, start, words, search)
        got = self._among.get(key)
        if got is None:
            got = self._among[key] = decode_among_each(
                self.readout, self._pairs(channels), start, words, tau=self.tau, search=search
            )
        return got[i]

    def read_code(self, i: int, samples: tuple[int, ...], channel: int, words: WordSet) -> Decision:
        """Listener ``i``'s word for its readout at ``samples`` on ``channel``."""
        self._forget()
        key = (samples, channel, words)
        got = self._reads.get(key)
        if got is None:
            got = self._reads[key] = nearest_each(self.readout, samples, channel, words)
        return got[i]

    def _forget(self) -> None:
        """The decodes kept for every unit are of the readout's present end: once it moves
        on, they are asked no more."""
        if self._end != self.readout.end:
            self._among.clear()
            self._reads.clear()
            self._end = self.readout.end

    # -- a batch's codes, every receiver at once ----------------------------------------------

    def id_columns(
        self, samples: Sequence[int], channel: int, words: WordSet
    ) -> tuple[np.ndarray, np.ndarray]:
        """Every receiver's word (an index into ``words``) and margin at ``samples`` on
        ``channel`` (``nearest_columns``)."""
        return nearest_columns(self.readout, samples, channel, words)

    def among_columns(
        self, channels: Sequence[int], start: float, words: WordSet, search: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every receiver's word, channel index and margin of a code that started at
        ``start`` on one of ``channels`` (``decode_among_columns``)."""
        return decode_among_columns(
            self.readout, self._pairs(channels), start, words, tau=self.tau, search=search
        )

    def block_columns(
        self, instants: np.ndarray, channels: np.ndarray, words: WordSet, rank: str
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """P codes at once, each with M candidate reads (``instants`` (P, M, N) on
        ``channels`` (P, M)): every receiver's candidate row, word and margin, (P, R) each
        (``nearest_many_columns``)."""
        return nearest_many_columns(self.readout, instants, channels, words, rank)
