"""The autonomous unit: transmitter + receiver + protocol + RGT reasoning + decision policy.

One unit is one SimPy process (driven by ``rgtbus.sim.World``). Each window it renders its own
scheduled pulses, then hears the whole medium (every member's samples, with its own link gains
and noise), feeds its resonators, turns spikes into protocol events, decodes what the protocol
asks for from its resonators' states, and reasons on what it decoded. It shares no Python object
with the other units: its knowledge comes only from the medium.
"""

from __future__ import annotations

import itertools
import random
from dataclasses import dataclass, field

import numpy as np
import simpy

from rgtbus.mind import Mind
from rgtbus.protocol import Listen, ProtocolState, Send, code_samples
from rgtbus.scenario import Scenario
from rgtbus.signal.decoder import BankReadout, decode_among, nearest
from rgtbus.signal.resonator import ResonatorBank
from rgtbus.sim import ns
from rgtbus.telemetry import Recorder

KEEP_SECONDS = 30.0  # readout history kept for decoding (longest code + reaction + search)


@dataclass
class Decoded:
    turn: int
    kind: str
    sender: str
    addressee: str
    code: str
    margin: float
    t: float
    accepted: bool


@dataclass
class AutonomousUnit:
    name: str
    scenario: Scenario
    recorder: Recorder
    traces: bool = False
    # state
    finished: bool = False
    failure: str | None = None
    decoded: list[Decoded] = field(default_factory=list)
    sent: list[Send] = field(default_factory=list)

    def __post_init__(self) -> None:
        sc = self.scenario
        self.units = sc.units
        self.tau = sc.timing.tau
        self.L = sc.timing.window_samples
        self.omegas = [sc.frequencies[u] for u in self.units]
        self.cb = sc.codebook
        self.bank = ResonatorBank(self.omegas, mode=sc.mode, tau=self.tau)
        keep = round(KEEP_SECONDS / self.tau)
        self.readout = BankReadout(self.bank, capacity=keep)
        self.protocol = ProtocolState(
            self.name,
            self.units,
            dict(sc.frequencies),
            self.tau,
            pulses=self.cb.pulses,
            start=sc.timing.start,
            reaction_delay=sc.timing.reaction_delay,
            guard=sc.timing.guard,
            anchor=sc.timing.anchor,
        )
        seed = sc.seed
        self.mind = Mind(
            self.name,
            self.units,
            sc.universe,
            sc.decisions[self.name],
            random.Random(f"{seed}:{self.name}:decision"),
        )
        self.noise_rng = np.random.default_rng([seed, self.units.index(self.name), 1])
        self.tx: dict[int, list[tuple[float, Send]]] = {}
        self.listens: list[Listen] = []
        self.quench: set[int] = set()  # samples at which the resonators are set back to rest
        self.relation_choice = self._choose_relations()
        self.env: simpy.Environment | None = None

    # -- policies --------------------------------------------------------------------------

    def _choose_relations(self) -> dict[str, str]:
        """What this unit sends to each peer: fixed, or alliance with probability p."""
        sc = self.scenario
        rng = random.Random(f"{sc.seed}:{self.name}:relations")
        out = {}
        for r in self.units:
            if r == self.name:
                continue
            key = (self.name, r)
            draw = rng.random()  # drawn for every peer, so fixing one never shifts the others
            if key in sc.fixed_relations:
                out[r] = "alliance" if sc.fixed_relations[key] else "conflict"
            else:
                d = sc.draws.get(key, draw)
                out[r] = "alliance" if d <= sc.alliance_p else "conflict"
        return out

    def _influence_codes(self) -> dict[str, str]:
        sc = self.scenario
        return {
            r: sc.universe.format(sc.influences[(self.name, r)])
            for r in self.units
            if r != self.name
        }

    def word(self, send: Send) -> tuple[float, ...]:
        if send.kind == "id":
            return self.cb.id_word
        if send.code in self.cb.relations:
            return self.cb.relations[send.code]
        return self.cb.alternatives[send.code]

    # -- the world's interface ---------------------------------------------------------------

    def begin(self, env: simpy.Environment) -> None:
        self.env = env
        sends, listens = self.protocol.begin(self.relation_choice, self._influence_codes())
        self._schedule(sends)
        self.listens.extend(listens)
        # Quench at every turn start known (all of them when anchored on the schedule).
        self.quench.update(round(t / self.tau) for t in self.protocol.turn_starts[1:])

    def _schedule(self, sends: list[Send]) -> None:
        for send in sends:
            magnitudes = self.word(send)
            for sample, m in zip(send.samples, magnitudes, strict=True):
                self.tx.setdefault(sample, []).append((float(m), send))
            self.sent.append(send)
            if self.env is not None:
                self.env.process(self._announce(send))

    def _announce(self, send: Send):
        """The reaction, at its exact time: logged when the code goes on the medium."""
        assert self.env is not None
        yield self.env.timeout(max(0.0, send.start - self.env.now))
        what = "ID" if send.kind == "id" else send.code
        self.recorder.log(
            "info",
            f"{send.sender} -> {send.addressee}: {what} on {send.channel}'s frequency",
            ns(send.start),
            name=self.name,
        )

    def render(self, window: int) -> np.ndarray:
        out = np.zeros(self.L)
        base = window * self.L
        for k in range(base, base + self.L):
            for m, send in self.tx.pop(k, ()):
                out[k - base] += m
                self.recorder.write(
                    "/tx/pulse",
                    {
                        "unit": self.name,
                        "channel": send.channel,
                        "omega": self.scenario.frequencies[send.channel],
                        "magnitude": m,
                        "t": k * self.tau,
                        "sample": k,
                        "message": {
                            "id": send.turn * 2 + (send.kind == "payload"),
                            "kind": send.kind,
                            "code": send.code,
                            "sender": send.sender,
                            "addressee": send.addressee,
                        },
                    },
                    ns(k * self.tau),
                )
        return out

    def hear(self, window: int, gathered: dict[str, np.ndarray]) -> None:
        sc = self.scenario
        heard = np.zeros(self.L)
        for s in self.units:
            heard += sc.gains.get((s, self.name), 1.0) * gathered[s]
        if sc.noise > 0:
            heard += self.noise_rng.normal(0.0, sc.noise, self.L)
        base = window * self.L
        cuts = sorted(k - base for k in self.quench if base <= k < base + self.L)
        self.quench -= {k + base for k in cuts}
        bounds = [0, *cuts, self.L]
        for lo, hi in itertools.pairwise(bounds):
            if lo in cuts:
                # Quench at a turn's start: the paper's b = -0.1 rings for ~10 s, longer than
                # any guard, and leftovers of the last turn could cancel or fake the next ID.
                self.bank.quench()
                self.readout.quench()
            if hi > lo:
                self._feed(heard[lo:hi], window, base + lo)

        last = (window + 1) * self.L - 1
        for listen in [x for x in self.listens if x.ready_sample <= last]:
            self.listens.remove(listen)
            self._decode(listen)
        if not self.finished and self.failure is None:
            err = self.protocol.check_deadline(last)
            if err:
                self.failure = err
                self.recorder.log("error", err, ns(last * self.tau), name=self.name)

    def _feed(self, heard: np.ndarray, window: int, first: int) -> None:
        # Most windows are silent (a code is 3 pulses over seconds): skip recording them.
        quiet = not self.traces and not heard.any()
        res = self.bank.feed(heard, record=not quiet)
        if quiet:
            self.readout.append_quiet(res.n, self.bank)
        else:
            self.readout.append(res)  # the increment readout: the medium as each resonator saw
        if self.traces:
            self.recorder.write(
                f"/trace/{self.name}",
                {
                    "unit": self.name,
                    "window": window,
                    "t": first * self.tau,
                    "sample_rate": 1 / self.tau,
                    "channels": list(self.units),
                    # arrays: the recorder encodes them; a verifying re-run compares them as is
                    "y": res.y[:, 0, :].T,
                    "x": res.z[:, 0, :].real.T,
                },
                ns(first * self.tau),
            )
        for sample, _rx, ch in res.spikes.tolist():
            channel = self.units[ch]
            self.recorder.write(
                "/rx/spike",
                {
                    "unit": self.name,
                    "channel": channel,
                    "omega": self.omegas[ch],
                    "t": sample * self.tau,
                    "sample": sample,
                },
                ns(sample * self.tau),
            )
            turn = self.protocol.turn
            sends, listens = self.protocol.on_spike(channel, sample)
            if self.protocol.turn != turn and not self.protocol.finished:
                self.quench.add(round(self.protocol.turn_start / self.tau))
            self._schedule(sends)
            self.listens.extend(listens)

    # -- decoding and reasoning --------------------------------------------------------------

    def _decode(self, listen: Listen) -> None:
        t_ready = listen.ready_sample * self.tau
        pulses = self.cb.pulses
        if listen.kind == "id":
            # An ID counts only if it reads as the ID-code on the sender's own frequency
            # (a↔c crosstalk makes resonators fire for other codes).
            ch = self.units.index(listen.sender)
            samples = code_samples(listen.start, self.omegas[ch], pulses, self.tau)
            dec = nearest(self.readout.values(samples, ch), self.cb.distinct_words())
            accepted = dec.name == "id"
            self._record(listen, listen.sender, dec.name, dec.margin, t_ready, accepted)
            if not accepted:
                self.failure = (
                    f"{self.name}: turn {listen.turn}: the ID of {listen.sender} "
                    f"decoded as {dec.name!r}"
                )
            return
        family = "relation" if listen.kind == "relation" else "alternative"
        words = self.cb.family(family)
        channels = [
            (self.units.index(r), self.omegas[self.units.index(r)]) for r in listen.channels
        ]
        dec, ch = decode_among(
            self.readout, channels, listen.start, words, tau=self.tau, search=self.protocol.search
        )
        addressee = self.units[ch]
        accepted = addressee == listen.expected_addressee
        self._record(listen, addressee, dec.name, dec.margin, t_ready, accepted)
        if not accepted:
            self.recorder.log(
                "warning",
                f"{self.name}: turn {listen.turn}: code from {listen.sender} found on "
                f"{addressee}'s channel, expected {listen.expected_addressee}",
                ns(t_ready),
                name=self.name,
            )
        self._learn(listen, dec.name, t_ready)

    def _record(
        self, listen: Listen, addressee: str, code: str, margin: float, t: float, accepted: bool
    ) -> None:
        d = Decoded(listen.turn, listen.kind, listen.sender, addressee, code, margin, t, accepted)
        self.decoded.append(d)
        value = code
        self.recorder.write(
            "/rx/decode",
            {
                "unit": self.name,
                "turn": listen.turn,
                "sender": listen.sender,
                "addressee": addressee,
                "kind": listen.kind,
                "code": code,
                "value": value,
                "margin": float(margin),
                "t": t,
                "accepted": accepted,
            },
            ns(t),
        )

    def _learn(self, listen: Listen, code: str, t: float) -> None:
        mind = self.mind
        universe = self.scenario.universe
        key = (listen.sender, listen.expected_addressee)
        if listen.kind == "relation":
            mind.sent[key] = code == "alliance"
            if mind.relations_complete():
                mind.build_group()
                self.recorder.write(
                    "/unit/relations",
                    {
                        "unit": self.name,
                        "t": t,
                        "sent": {
                            f"{s}>{r}": "alliance" if v else "conflict"
                            for (s, r), v in sorted(mind.sent.items())
                        },
                        "installed": mind.installed(),
                        "polynomial": mind.polynomial,
                    },
                    ns(t),
                )
                if mind.error:
                    self.recorder.log("error", f"{self.name}: {mind.error}", ns(t), self.name)
        else:
            mind.influences[key] = universe.parse_alternative(code)
            if mind.influences_complete():
                self.recorder.write(
                    "/unit/influences",
                    {
                        "unit": self.name,
                        "t": t,
                        "influences": {
                            f"{s}>{r}": universe.to_list(v)
                            for (s, r), v in sorted(mind.influences.items())
                        },
                    },
                    ns(t),
                )
                mind.decide()
                self._log_decisions(t)
                self.finished = True

    def _log_decisions(self, t: float) -> None:
        mind = self.mind
        u = self.scenario.universe
        if mind.results is None:
            self.recorder.log("error", f"{self.name}: no decision: {mind.error}", ns(t), self.name)
            return
        for s, r in mind.results.items():
            choice = mind.choice if s == self.name else None
            self.recorder.write(
                "/unit/decision",
                {
                    "unit": self.name,
                    "subject": s,
                    "t": t,
                    "A": u.to_list(r.A),
                    "B": u.to_list(r.B),
                    "interval": None if r.frustrated else [u.to_list(r.B), u.to_list(r.A)],
                    "frustrated": r.frustrated,
                    "choice": None if choice is None else u.to_list(choice),
                    "canonical": mind.canonical(s),
                },
                ns(t),
            )

    # -- what this unit knows, as plain data (one process's share of a run summary) ----------

    def report(self) -> dict:
        u = self.scenario.universe
        mind = self.mind
        r = mind.results[self.name] if mind.results else None
        return {
            "unit": self.name,
            "installed": mind.installed(),
            "polynomial": mind.polynomial,
            "sent_relations": {
                f"{s}>{t}": "alliance" if v else "conflict"
                for (s, t), v in sorted(mind.sent.items())
            },
            "influences": {
                f"{s}>{t}": u.to_list(v) for (s, t), v in sorted(mind.influences.items())
            },
            "result": {
                "interval": None if r is None or r.frustrated else [u.to_list(r.B), u.to_list(r.A)],
                "frustrated": bool(r.frustrated) if r else False,
                "choice": None if mind.choice is None else u.to_list(mind.choice),
                "canonical": mind.canonical(self.name) if mind.df else None,
                "A": u.to_list(r.A) if r else None,
                "B": u.to_list(r.B) if r else None,
                "decided": r is not None,
            },
            "sends": [[s.turn, s.kind, s.addressee, s.code] for s in self.sent],
            "decodes": [[d.turn, d.kind, d.addressee, d.code] for d in self.decoded],
            "failure": self.failure,
            "mind_error": mind.error,
        }
