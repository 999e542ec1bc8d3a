"""A unit's transmitter: its sends become pulses on the medium, and its log's ``/tx/pulse``
records and send lines.

A send of code c at samples k_1..k_P puts magnitude w_c[j] at sample k_j (the codebook's word
for c); the world takes the pulses planned since its last look (``take_outbox``), ahead of
their time. Where nobody looks on while the run goes, each send's log line and pulse records
are written as it is planned, each at its own log time (as the medium is). Where someone may (a
live view, a paced run), one SimPy process writes them as the run's clock reaches each: a line
at the send's start, then each pulse at its sample, in time order, then planning order.
"""

from __future__ import annotations

import heapq
from array import array
from collections.abc import Generator
from typing import Any

import numpy as np
import simpy

from rgtbus.errors import BadInput
from rgtbus.protocol import Send
from rgtbus.signal.codebook import Codebook
from rgtbus.signal.pulses import Pulses
from rgtbus.telemetry import records
from rgtbus.telemetry.unit_log import UnitLog
from rgtbus.timebase import time_of

AWAKE = -1.0  # the on-air process is not asleep: it reads the next send before it sleeps

# a send waiting to be logged on air: (time, seq, pulse index or -1 for its line, send, word,
# and once on air its pulses' message and ω)
_OnAir = tuple[float, int, int, Send, tuple[float, ...], tuple[records.MessageRef, float] | None]


def send_text(send: Send) -> str:
    """The log line of a send going on air."""
    if send.kind == "request":
        return (
            f"{send.sender}: asks {send.addressee} for turn {send.turn} again (repair block "
            f"{send.block}) on {send.channel}'s frequency"
        )
    what = "ID" if send.kind == "id" else send.code
    again = f" again (repair block {send.block})" if send.kind == "repeat" else ""
    return f"{send.sender} -> {send.addressee}: {what}{again} on {send.channel}'s frequency"


class Transmitter:
    """Unit ``name``'s transmitter (see the module docstring): ``sent``, every send but a
    repair's (those are counted by the repair book); ``payload_code``, the code it sent in
    each turn it sent a payload."""

    def __init__(
        self, codebook: Codebook, frequencies: dict[str, float], tau: float, log: UnitLog
    ) -> None:
        self.cb = codebook
        self.frequencies = frequencies
        self.tau = tau
        self.log = log
        self.sent: list[Send] = []
        self.payload_code: dict[int, str] = {}  # turn -> the payload code it sent
        # the pulses planned since the world last looked: samples and magnitudes, 16 bytes a
        # pulse (a run plans every pulse of its schedule at once: n² codes)
        self._out_at = array("q")
        self._out_value = array("d")
        self._air: list[_OnAir] = []
        self._air_seq = 0
        self._air_until = AWAKE  # when the on-air process sleeps until (AWAKE: it will look)
        self._process: simpy.Process | None = None
        self.env: simpy.Environment | None = None
        self.on_time = True  # pulses logged as the clock reaches them (``begin``)

    def begin(self, env: simpy.Environment, on_time: bool) -> None:
        """The world its pulses go to; ``on_time``: someone may look on while the run goes."""
        self.env, self.on_time = env, on_time

    def word(self, send: Send) -> tuple[float, ...]:
        """The magnitudes of a send's pulses: its code's word (the codebook's own tuple)."""
        if send.kind in ("id", "request"):
            return self.cb.id_word
        if send.code in self.cb.relations:
            return self.cb.relations[send.code]
        return self.cb.alternatives[send.code]

    def take_outbox(self) -> Pulses:
        """The pulses planned since the last call (sample order; one sample's magnitudes in
        the order they were planned)."""
        at = np.frombuffer(self._out_at, dtype=np.int64)
        value = np.frombuffer(self._out_value, dtype=np.float64)
        self._out_at, self._out_value = array("q"), array("d")  # the views keep the old ones
        order = np.argsort(at, kind="stable")  # stable: planning order within a sample
        return at[order], value[order]  # copies: arrays of their own

    def emit(self, send: Send) -> None:
        """Plan a send: its pulses go out to the bus now (ahead of time), and to the log."""
        word = self.word(send)
        if len(word) != len(send.samples):
            raise BadInput(
                f"{send.code!r}: {len(word)} magnitudes for {len(send.samples)} pulses"
            )
        self._out_at.extend(send.samples)
        self._out_value.extend(word)
        if not send.block:  # a repair's sends are counted (``RepairBook``), not listed
            self.sent.append(send)
            if send.kind == "payload":
                self.payload_code[send.turn] = send.code
        assert self.env is not None
        if not self.log.enabled:
            return
        if not self.on_time:  # a message's pulses at once (nobody looks on)
            message, omega = self._log_line(send)
            self.log.send(send.samples, word, send.channel, omega, message)
            return
        at = min(send.start, time_of(send.samples[0], self.tau))
        heapq.heappush(self._air, (at, self._air_seq, -1, send, word, None))
        self._air_seq += 1
        if self._process is None:
            self._process = self.env.process(self._on_air())
        elif at < self._air_until:  # it sleeps until later: wake it for this one
            self._process.interrupt()

    def _log_line(self, send: Send) -> tuple[records.MessageRef, float]:
        """A send's log line; what each of its pulses names (built once a send)."""
        self.log.log("info", send_text(send), send.start)
        message = records.message_ref(
            send.turn, send.kind, send.code, send.sender, send.addressee, send.block
        )
        return message, self.frequencies[send.channel]

    def _log_pulse(
        self,
        send: Send,
        word: tuple[float, ...],
        j: int,
        ref: tuple[records.MessageRef, float],
    ) -> None:
        """Pulse ``j`` of a send, at its sample's time."""
        k = send.samples[j]
        record = records.pulse(
            self.log.name, send.channel, ref[1], float(word[j]), self.tau, k, ref[0]
        )
        self.log.pulse(record)

    def _on_air(self) -> Generator[simpy.Event, Any, None]:
        """The on-air process: one SimPy process a unit (not one a send: a large group plans
        all its sends at once) that logs each planned send as it goes on air."""
        env = self.env
        assert env is not None
        air, tau = self._air, self.tau
        while air:
            at, seq, j, send, word, ref = air[0]
            if at > env.now:
                self._air_until = at
                try:
                    yield env.timeout(at - env.now)
                except simpy.Interrupt:  # a send planned meanwhile goes out earlier
                    continue
                finally:
                    self._air_until = AWAKE
            heapq.heappop(air)
            if j < 0:
                ref = self._log_line(send)
            else:
                assert ref is not None
                self._log_pulse(send, word, j, ref)
            if j + 1 < len(send.samples):
                at = time_of(send.samples[j + 1], tau)
                heapq.heappush(air, (at, seq, j + 1, send, word, ref))
        self._process = None
