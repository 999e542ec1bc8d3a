"""Reading a run back from its MCAP log: the timeline, the run's summary, and verification.

``load_replay(source)`` organises a log (path or stream) into a ``Replay``: transmissions (the
logged pulses grouped into codes, with their meaning), spikes, decodes (each matched with the
transmission it read), the tables each unit built, decisions, the ``/run`` record and the
metadata; ``Replay.summary()`` rebuilds the fields ``rgtbus run --json`` prints, from the log
alone.

``verify(replay, rerun)`` compares the log with a re-run of its units on its own medium (the
re-run itself needs the units, so it lives in ``units/replay.py``; anything with ``messages``,
``summary`` and ``complete`` will do) and checks that the logged pulses add up, sample for
sample, to the logged medium. Every disagreement is a ``Mismatch``.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass
from typing import IO, Any

import numpy as np
import orjson

from rgtbus.errors import RgtbusError
from rgtbus.mind import noise_free, wrong_decisions
from rgtbus.scenario import Scenario, parse_scenario
from rgtbus.summary import agreement, decode_error, frustrated_units, outcome_of
from rgtbus.telemetry import topics
from rgtbus.telemetry.recorder import (
    LogContents,
    decode_log,
    encode_json,
    require_run_log,
    scan_log,
)

NS = 1_000_000_000

# Exit codes of ``rgtbus replay --verify`` (2 is every CLI's "bad input").
EXIT_VERIFIED = 0
EXIT_MISMATCH = 1
EXIT_TRUNCATED = 3  # everything read agrees, but the log ends early: the run is not verified


@dataclass
class Transmission:
    """One code on the medium: the logged pulses of one message, with what it means."""

    turn: int
    kind: str  # "id" | "payload"
    phase: str  # "relations" | "influences"
    sender: str
    addressee: str
    channel: str
    code: str
    meaning: str  # "ID", "alliance", "conflict", "influence {alpha}", ...
    start: float
    end: float
    pulses: list[tuple[float, float]]  # (t, magnitude)

    @property
    def label(self) -> str:
        return f"{self.sender} → {self.addressee}: {self.meaning}"


@dataclass
class DecodeRow:
    unit: str
    t: float
    sender: str
    addressee: str
    kind: str
    code: str
    margin: float
    accepted: bool
    turn: int | None  # of the transmission it read (None: no such transmission logged)
    sent: str | None  # the code that transmission carried
    matches: bool | None  # decoded what was sent (None: nothing to compare with)
    channel: str | None = None  # the unit whose channel carried it (None: an older log)


@dataclass
class Mismatch:
    """One disagreement between the log and what verification recomputed."""

    topic: str
    t: float | None
    unit: str | None
    field: str
    logged: Any
    recomputed: Any

    def text(self) -> str:
        when = "" if self.t is None else f" t={self.t:.3f}s"
        who = "" if self.unit is None else f" unit={self.unit}"
        return (
            f"{self.topic}{when}{who} {self.field}: logged {_short(self.logged)}, "
            f"recomputed {_short(self.recomputed)}"
        )


def _short(value: Any, limit: int = 120) -> str:
    text = json.dumps(value, ensure_ascii=False, default=str)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _phase_of(turn: int, n_units: int) -> str:
    return "relations" if turn < n_units * (n_units - 1) else "influences"


def _merge_notes(metadata: dict[str, dict[str, str]]) -> list[str]:
    """The truncation notes of a merged log's inputs (empty for a log that is no merge)."""
    out: list[str] = []
    for name, values in metadata.items():
        if name == "merge" or name.startswith("merge."):
            try:
                notes = json.loads(values.get("truncated", "[]"))
            except ValueError:
                notes = ["a merge record that does not parse"]
            if isinstance(notes, list):
                out += [str(n) for n in notes]
    return out


def _unit_process_ends(
    metadata: dict[str, dict[str, str]], units: Sequence[str]
) -> tuple[list[str], list[str]]:
    """(how the unit processes that did not end "done" ended, every unit process whose log is
    in this one). A unit process's log has a ``run`` record naming it (``process``) and, once
    it ended, an ``end.<unit>`` record; a killed one has none."""
    processes = [
        v["process"]
        for n, v in metadata.items()
        if (n == "run" or n.startswith("run.")) and v.get("process") in units
    ]
    early = []
    for unit in processes:
        end = metadata.get(topics.unit_end_record(unit))
        if end is None:
            early.append(f"unit {unit}'s process ended without a word (killed?)")
        elif end.get("status") != topics.UNIT_DONE:
            early.append(f"unit {unit} {topics.UNIT_ENDED_EARLY}: {end.get('detail', '')}")
    return early, processes


def _frequencies(metadata: dict[str, dict[str, str]]) -> dict[str, float]:
    """Channel frequencies from a log's ``frequencies`` metadata (values that are no number
    are left out: the verifier names a damaged scenario, this only labels spikes)."""
    out = {}
    for k, v in metadata.get("frequencies", {}).items():
        with contextlib.suppress(ValueError):
            out[k] = float(v)
    return out


def spike_rows(records: Iterable[dict], frequencies: dict[str, float]) -> list[dict]:
    """One row per resonator spike ({unit, channel, omega, t, sample}) from ``/rx/spike``
    records, which list every resonator of a unit that fired at one sample; ω comes from the
    log's frequencies (logs written before that change hold one spike a record, with its ω)."""
    rows = []
    for m in records:
        if "channels" not in m:
            rows.append(m)
            continue
        unit, t, k = m["unit"], m["t"], m["sample"]
        for ch in m["channels"]:
            om = frequencies.get(ch)
            rows.append({"unit": unit, "channel": ch, "omega": om, "t": t, "sample": k})
    return rows


class Replay:
    """A log organised for reading. Build with ``load_replay``."""

    def __init__(self, contents: LogContents, label: str = "<log>") -> None:
        self.contents = contents
        self.label = label
        self.metadata: dict[str, dict[str, str]] = contents.metadata
        self.truncated: bool = contents.truncated
        self.note: str = contents.note
        self.by_topic: dict[str, list[tuple[int, dict]]] = defaultdict(list)
        for topic, t, msg in contents.messages:
            self.by_topic[topic].append((t, msg))
        self.scenario: Scenario | None = None
        self.scenario_error: str | None = None
        self._load_scenario()
        self.units: tuple[str, ...] = self._units()
        # A merge of unit logs (launch, or ``rgtbus merge`` by hand) whose inputs ended early
        # (a killed unit) is as incomplete as a truncated file, though the file itself is whole.
        early, self.unit_processes = _unit_process_ends(self.metadata, self.units)
        self.cut_inputs: list[str] = _merge_notes(self.metadata) + early
        if self.cut_inputs:
            self.truncated = True
            self.note = "; ".join(filter(None, [self.note, *self.cut_inputs]))
        self.run: dict | None = self.by_topic["/run"][-1][1] if self.by_topic["/run"] else None
        self.transmissions = self._transmissions()
        self.decodes = self._decodes()
        self.frequencies = _frequencies(self.metadata)
        self.spikes = spike_rows((m for _, m in self.by_topic["/rx/spike"]), self.frequencies)
        self.relations = {m["unit"]: m for _, m in self.by_topic["/unit/relations"]}
        self.influences = {m["unit"]: m for _, m in self.by_topic["/unit/influences"]}
        self.decisions = [m for _, m in self.by_topic["/unit/decision"]]

    # -- construction ------------------------------------------------------------------------

    def _load_scenario(self) -> None:
        meta = self.metadata.get("scenario")
        if not meta or "text" not in meta:
            self.scenario_error = "the log has no scenario metadata"
            return
        try:
            sc = parse_scenario(meta["text"], meta.get("path", "<scenario>"))
            seed = self.metadata.get("run", {}).get("seed")
            if seed is not None:
                sc = sc.with_seed(int(seed))
        except (RgtbusError, ValueError) as e:
            self.scenario_error = f"the log's scenario does not load: {e}"
            return
        self.scenario = sc

    def require_scenario(self) -> Scenario:
        if self.scenario is None:
            raise RgtbusError(f"{self.label}: cannot re-run: {self.scenario_error}")
        return self.scenario

    def _units(self) -> tuple[str, ...]:
        if self.scenario is not None:
            return self.scenario.units
        seen: dict[str, None] = {}
        for topic in ("/tx/pulse", "/rx/spike", "/rx/decode", "/unit/relations"):
            for _, m in self.by_topic[topic]:
                seen.setdefault(m["unit"], None)
        return tuple(seen)

    def _transmissions(self) -> list[Transmission]:
        groups: dict[tuple[str, int], list[dict]] = {}
        for _, p in self.by_topic["/tx/pulse"]:
            groups.setdefault((p["unit"], p["message"]["id"]), []).append(p)
        out = []
        n = len(self.units)
        for (_, mid), pulses in groups.items():
            msg = pulses[0]["message"]
            turn = mid // 2
            phase = _phase_of(turn, n)
            if msg["kind"] == "id":
                meaning = "ID"
            elif phase == "relations":
                meaning = msg["code"]
            else:
                meaning = f"influence {msg['code']}"
            out.append(
                Transmission(
                    turn=turn,
                    kind=msg["kind"],
                    phase=phase,
                    sender=msg["sender"],
                    addressee=msg["addressee"],
                    channel=pulses[0]["channel"],
                    code=msg["code"],
                    meaning=meaning,
                    start=pulses[0]["t"],
                    end=pulses[-1]["t"],
                    pulses=[(p["t"], p["magnitude"]) for p in pulses],
                )
            )
        out.sort(key=lambda x: (x.start, x.turn, x.kind))
        return out

    def _decodes(self) -> list[DecodeRow]:
        # A decode reads the latest code of its class its sender started before it.
        starts: dict[tuple[str, str], list[Transmission]] = defaultdict(list)
        for sent in self.transmissions:
            starts[(sent.sender, sent.kind)].append(sent)
        rows = []
        for _, d in self.by_topic["/rx/decode"]:
            cls = "id" if d["kind"] == "id" else "payload"
            tx: Transmission | None = None
            for cand in starts[(d["sender"], cls)]:
                if ("turn" in d and cand.turn == d["turn"]) or (
                    "turn" not in d and cand.start <= d["t"] + 1e-9  # logs from before turns
                ):
                    tx = cand
            if tx is None:
                matches = None
            elif cls == "id":
                matches = d["code"] == "id"
            else:
                matches = d["code"] == tx.code and d["addressee"] == tx.addressee
            rows.append(
                DecodeRow(
                    unit=d["unit"],
                    t=d["t"],
                    sender=d["sender"],
                    addressee=d["addressee"],
                    kind=d["kind"],
                    code=d["code"],
                    margin=d["margin"],
                    accepted=d["accepted"],
                    turn=None if tx is None else tx.turn,
                    sent=None if tx is None else tx.code,
                    matches=matches,
                    channel=d.get("channel"),
                )
            )
        return rows

    # -- what the log says -------------------------------------------------------------------

    @property
    def window_seconds(self) -> float | None:
        if self.scenario is not None:
            t = self.scenario.timing
            return t.window_samples / t.sample_rate
        med = self.by_topic["/medium"]
        if med:
            return len(med[0][1]["samples"]) / med[0][1]["sample_rate"]
        return None

    @property
    def windows(self) -> int:
        return len(self.by_topic["/medium"])

    @property
    def sim_seconds(self) -> float:
        """The run's simulated length: from its ``/run`` record, else as far as the log goes."""
        if self.run is not None:
            return float(self.run["sim_seconds"])
        return round(max((m[1] for m in self.contents.messages), default=0) / NS, 6)

    def agree(self) -> bool:
        tables = [self.relations.get(u, {}).get("installed", {}) for u in self.units]
        polys = [self.relations.get(u, {}).get("polynomial") for u in self.units]
        return agreement(tables, polys, len(self.units))

    def decode_errors(self) -> list[dict[str, Any]]:
        """As ``summarise`` lists them: per unit (in unit order), decodes of a wrong code."""
        out = []
        order = {u: i for i, u in enumerate(self.units)}
        rows = sorted(self.decodes, key=lambda d: order.get(d.unit, len(order)))
        for d in rows:
            if d.matches is False:
                out.append(decode_error(d.unit, d.turn, d.kind, d.code, d.sent))
        return out

    def summary(self) -> dict[str, Any]:
        """The fields of ``rgtbus run --json`` (less wall time and log path), from the log."""
        units = self.units
        first = self.relations.get(units[0], {}) if units else {}
        first_infl = self.influences.get(units[0], {}) if units else {}
        own = {
            d["unit"]: d for d in self.decisions if d["unit"] == d["subject"]
        }  # each unit's own decision
        units_out = {}
        for u in units:
            d = own.get(u)
            units_out[u] = {
                "interval": None if d is None else d["interval"],
                "frustrated": False if d is None else bool(d["frustrated"]),
                "choice": None if d is None else d["choice"],
                "canonical": None if d is None else d["canonical"],
                "A": None if d is None else d["A"],
                "B": None if d is None else d["B"],
                "decided": d is not None,
            }
        run = self.run or {}
        seed = self.metadata.get("run", {}).get("seed")
        p4 = first.get("p4")
        complete = first.get("polynomial") is not None or p4 is not None
        return {
            "scenario": run.get("scenario", self.metadata.get("scenario", {}).get("name")),
            "seed": run.get("seed", None if seed is None else int(seed)),
            "schedule": None if self.scenario is None else self.scenario.schedule,
            "polynomial": first.get("polynomial"),
            "decomposable": (p4 is None) if complete else None,
            "p4": p4,
            "relations": first.get("installed", {}),
            "sent_relations": first.get("sent", {}),
            "unit_relations": {u: self.relations.get(u, {}).get("installed", {}) for u in units},
            "agree": self.agree(),
            "influences": first_infl.get("influences", {}),
            "units": units_out,
            "frustrated": frustrated_units(units_out),
            "wrong_decisions": self._wrong_decisions(units_out),
            "outcome": run.get("outcome", self._outcome()),
            "decode_errors": self.decode_errors(),
            "sim_seconds": self.sim_seconds,
            "error": run.get("error"),
        }

    def _wrong_decisions(self, units_out: dict[str, dict[str, Any]]) -> list[str] | None:
        """As ``summarise`` names them (``None``: the log stores no scenario to compare with)."""
        if self.scenario is None:
            return None
        if not any(r["decided"] for r in units_out.values()):
            return []
        return wrong_decisions(units_out, noise_free(self.scenario))

    def _outcome(self) -> Any:
        if self.scenario is None:
            return None
        own = {
            d["unit"]: {"choice": d["choice"], "decided": True}
            for d in self.decisions
            if d["unit"] == d["subject"]
        }
        return outcome_of(self.scenario, own)

    def spike_counts(
        self, span: tuple[float | None, float | None] | None = None
    ) -> dict[str, dict[str, int]]:
        counts: dict[str, Counter[str]] = {u: Counter() for u in self.units}
        for s in self.spikes:
            if in_span(s["t"], span):
                counts.setdefault(s["unit"], Counter())[s["channel"]] += 1
        return {u: dict(c) for u, c in counts.items()}

    def info(self) -> dict[str, Any]:
        """The run's metadata: scenario, seed, version, bus, run id, frequencies."""
        sc = self.metadata.get("scenario", {})
        run = self.metadata.get("run", {})
        return {
            "scenario": sc.get("name"),
            "path": sc.get("path"),
            "seed": None if run.get("seed") is None else int(run["seed"]),
            "version": run.get("version"),
            "bus": run.get("bus"),
            "run_id": run.get("run_id"),
            "python": run.get("python"),
            "frequencies": self.frequencies,
            "records": sorted(self.metadata),
        }

    def to_json(self) -> dict[str, Any]:
        """``rgtbus replay --json``: one object."""
        return {
            "log": self.label,
            "metadata": self.info(),
            "truncated": self.truncated,
            "note": self.note,
            "transmissions": [
                {k: v for k, v in asdict(tx).items() if k != "pulses"}
                | {"pulses": [{"t": t, "magnitude": m} for t, m in tx.pulses]}
                for tx in self.transmissions
            ],
            "spikes": self.spikes,
            "spike_counts": self.spike_counts(),
            "decodes": [asdict(d) for d in self.decodes],
            "tables": {
                u: {
                    "relations": self.relations.get(u),
                    "influences": self.influences.get(u),
                }
                for u in self.units
            },
            "agree": self.agree(),
            "decisions": self.decisions,
            "outcome": self.summary()["outcome"],
            "run": self.run,
            "summary": self.summary(),
        }

    # -- inputs for a re-run -----------------------------------------------------------------

    def _medium_windows(self) -> tuple[dict[int, np.ndarray], list[Mismatch]]:
        """The logged medium's windows (only windows that carried a pulse are logged), with
        repeated and malformed windows reported."""
        sc = self.require_scenario()
        L = sc.timing.window_samples
        ws = L / sc.timing.sample_rate
        out: dict[int, np.ndarray] = {}
        bad: list[Mismatch] = []
        for t_ns, m in self.by_topic["/medium"]:
            w = m["window"]
            if w in out:
                bad.append(Mismatch("/medium", t_ns / NS, None, f"window {w}", "twice", "once"))
                continue
            if len(m["samples"]) != L:
                bad.append(
                    Mismatch("/medium", t_ns / NS, None, f"window {w} length", len(m["samples"]), L)
                )
                continue
            if not math.isclose(m["t"], w * ws, abs_tol=1e-9) or t_ns != round(w * ws * NS):
                bad.append(Mismatch("/medium", t_ns / NS, None, f"window {w} t", m["t"], w * ws))
            if m["sample_rate"] != sc.timing.sample_rate:
                bad.append(
                    Mismatch(
                        "/medium",
                        t_ns / NS,
                        None,
                        f"window {w} sample_rate",
                        m["sample_rate"],
                        sc.timing.sample_rate,
                    )
                )
            out[w] = np.asarray(m["samples"], dtype=float)
        return out, bad

    def medium_pulses(self) -> tuple[np.ndarray, np.ndarray]:
        """The logged medium as (sample indexes, values) of its non-silent samples: what every
        unit heard, bit for bit (each unit's magnitudes added up, then the units in order)."""
        sc = self.require_scenario()
        L = sc.timing.window_samples
        windows, _ = self._medium_windows()
        rows, vals = [], []
        for w in sorted(windows):
            nz = np.flatnonzero(windows[w])
            rows.append(nz + w * L)
            vals.append(windows[w][nz])
        if not rows:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        return np.concatenate(rows).astype(np.int64), np.concatenate(vals)

    def sender_pulses(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Each unit's own transmissions, rebuilt from its logged pulses (in the order it sent
        them: the floats add up as the unit added them)."""
        rows: dict[str, list[int]] = {u: [] for u in self.units}
        vals: dict[str, list[float]] = {u: [] for u in self.units}
        for _, p in self.by_topic["/tx/pulse"]:
            if p["unit"] in rows:
                rows[p["unit"]].append(int(p["sample"]))
                vals[p["unit"]].append(float(p["magnitude"]))
        out = {}
        for u in self.units:
            r = np.array(rows[u], dtype=np.int64)
            order = np.argsort(r, kind="stable")
            out[u] = (r[order], np.array(vals[u])[order])
        return out

    def has_gains(self) -> bool:
        sc = self.require_scenario()
        return any(g != 1.0 for g in sc.gains.values())

    def units_until_ns(self) -> int | None:
        """The log time up to which the units' messages are complete (units write in time
        order; the medium and traces are logged ahead of them): None when nothing was. For a
        merge with inputs that ended early: the earliest of the units' last messages (each
        unit's log may end at another time)."""
        last: dict[str, int] = {}
        for topic, msgs in self.by_topic.items():
            if topic == "/medium" or _is_trace(topic) or topic == "/run":
                continue
            for t, m in msgs:
                who = str(m.get("unit", m.get("name", "")))
                if t > last.get(who, -1):
                    last[who] = t
        if not last:
            return None
        if self.cut_inputs:
            return min((v for u, v in last.items() if u in self.units), default=None)
        return max(last.values())

    def check_medium(self, until_ns: int | None = None) -> list[Mismatch]:
        """Every logged window exactly equals the sum of the logged pulses (each unit's
        magnitudes in the order sent, then the units in order), and every window that carries
        a pulse is logged; only windows that end before ``until_ns`` when given (a truncated
        log: the medium is logged ahead of the pulses)."""
        sc = self.require_scenario()
        L = sc.timing.window_samples
        tau = sc.timing.tau
        windows, bad = self._medium_windows()
        parts = self.sender_pulses()
        rows = np.unique(np.concatenate([p[0] for p in parts.values()] + [np.zeros(0, int)]))
        x = np.zeros((rows.size, len(self.units)))
        for j, u in enumerate(self.units):
            np.add.at(x[:, j], np.searchsorted(rows, parts[u][0]), parts[u][1])
        expected = np.cumsum(x, axis=1)[:, -1] if rows.size else np.zeros(0)
        want: dict[int, np.ndarray] = {}
        for k, v in zip(rows.tolist(), expected.tolist(), strict=True):
            if v != 0.0:
                want.setdefault(k // L, np.zeros(L))[k % L] = v
        end = self.sim_seconds / tau if self.run is not None else math.inf
        if until_ns is not None:
            end = min(end, until_ns / NS / tau - L)
        for w in sorted(set(windows) | set(want)):
            if until_ns is not None and (w + 1) * L * tau * NS > until_ns:
                continue
            logged = windows.get(w)
            exp = want.get(w, np.zeros(L))
            if logged is None:
                if w * L <= end:  # a run logs its medium up to its end
                    bad.append(
                        Mismatch("/medium", w * L * tau, None, f"window {w}", "missing", "present")
                    )
                continue
            for k in np.flatnonzero(logged != exp):
                bad.append(
                    Mismatch(
                        "/medium",
                        (w * L + int(k)) * tau,
                        None,
                        f"window {w} samples[{int(k)}]",
                        float(logged[k]),
                        float(exp[k]),
                    )
                )
        return bad

    def traced_units(self) -> list[str]:
        return [u for u in self.units if self.by_topic.get(f"/trace/{u}")]

    def trace_arrays(self, unit: str) -> dict[str, Any] | None:
        msgs = [m for _, m in self.by_topic.get(f"/trace/{unit}", [])]
        return self.stack_traces(msgs) if msgs else None

    def stack_traces(self, msgs: Sequence[dict | bytes]) -> dict[str, Any]:
        """Trace messages -> ``{"t": (n,), "y": (n, channels), "channels": [...]}``: one message
        a sample, or (logs of rgtbus before the per-sample layout) one a window."""
        if not msgs:
            return {"t": np.zeros(0), "y": np.zeros((0, 0)), "channels": []}
        ms = [orjson.loads(m) if isinstance(m, bytes | bytearray) else m for m in msgs]
        if "window" in ms[0]:
            ts, ys = [], []
            for m in ms:
                y = np.asarray(m["y"], dtype=float)  # channels × samples
                ts.append(m["t"] + np.arange(y.shape[1]) / m["sample_rate"])
                ys.append(y.T)
            t, yy = np.concatenate(ts), np.concatenate(ys)
            return {"t": t, "y": yy, "channels": ms[0]["channels"]}
        t = np.fromiter((m["t"] for m in ms), dtype=float, count=len(ms))
        yy = np.asarray([m["y"] for m in ms], dtype=float)
        return {"t": t, "y": yy, "channels": list(self.units)}


def _is_trace(topic: str) -> bool:
    return topic.startswith("/trace/")


def load_replay(source: str | os.PathLike[str] | IO[bytes]) -> Replay:
    """Read and organise a log (path or binary stream). Unreadable, not MCAP, corrupt, only a
    header, or not written by an rgtbus run: RgtbusError. A truncated log reads up to its cut.

    Resonator traces (the bulk of a traced log) stay undecoded until something needs them:
    verification compares them byte for byte, plots decode one unit's."""
    raw = scan_log(source)
    require_run_log(raw)
    contents = decode_log(raw, keep_raw=_is_trace)
    with explained(contents, raw.label):
        return Replay(contents, raw.label)


def schema_error(contents: LogContents) -> str | None:
    """The first message that breaks its topic's schema, in one line (None: all keep them).
    Run only once reading has failed: a log's messages are not validated on the way in."""
    from rgtbus.telemetry import validate

    for topic, t_ns, message in contents.messages:
        try:
            schema = topics.schema_for(topic)
        except RgtbusError:
            continue  # a topic of someone else's: not ours to read
        if isinstance(message, bytes | bytearray | memoryview):
            message = orjson.loads(message)
        errs = validate.errors(message, topics.load_schema(schema))
        if errs:
            return f"message on {topic} at t = {t_ns / NS:.3f} s breaks {schema}: {errs[0]}"
    return None


@contextlib.contextmanager
def explained(contents: LogContents, label: str) -> Iterator[None]:
    """Reading a log whose messages break their schemas (written by hand or tampered with,
    with valid CRCs) fails as RgtbusError naming the first such message, not with a KeyError
    from deep inside; any other failure is a bug and goes on as it is."""
    try:
        yield
    except (KeyError, TypeError, IndexError, AttributeError, ValueError) as exc:
        if isinstance(exc, RgtbusError):
            raise
        why = schema_error(contents)
        if why is None:
            raise
        raise RgtbusError(f"{label}: {why}") from None


# -- verification ---------------------------------------------------------------------------


def _json(value: Any) -> Any:
    """What the value becomes in a log: the JSON round trip (tuples -> lists, numpy -> plain)."""
    return orjson.loads(encode_json(value))


def _field_diffs(logged: Any, recomputed: Any, path: str = "") -> list[tuple[str, Any, Any]]:
    if isinstance(logged, dict) and isinstance(recomputed, dict):
        out = []
        for key in [*logged, *(k for k in recomputed if k not in logged)]:
            sub = f"{path}.{key}" if path else str(key)
            if key not in recomputed:
                out.append((sub, logged[key], "(absent)"))
            elif key not in logged:
                out.append((sub, "(absent)", recomputed[key]))
            else:
                out += _field_diffs(logged[key], recomputed[key], sub)
        return out
    # True == 1 in Python, not in a log; 3 == 3.0 is fine (JSON numbers)
    if logged == recomputed and isinstance(logged, bool) == isinstance(recomputed, bool):
        return []
    return [(path or "(message)", logged, recomputed)]


def _same_trace(logged: bytes | dict, recomputed: dict) -> bool:
    """Equal as the recorder would write them: JSON floats round-trip exactly, so comparing the
    numbers equals comparing the bytes, at half the cost of encoding the re-run's traces."""
    m = orjson.loads(logged) if isinstance(logged, bytes | bytearray) else logged
    if set(m) != set(recomputed):
        return False
    for key, value in recomputed.items():
        if key in ("y", "x"):
            if not np.array_equal(np.asarray(m[key], dtype=float), np.asarray(value, dtype=float)):
                return False
        elif m[key] != value:
            return False
    return True


def _trace_diff(logged: dict, recomputed: dict) -> list[tuple[str, Any, Any]]:
    out: list[tuple[str, Any, Any]] = []
    for key in ("y", "x"):
        a = np.asarray(logged.get(key), dtype=float)
        b = np.asarray(recomputed.get(key), dtype=float)
        if np.array_equal(a, b):
            continue
        if a.shape != b.shape:
            out.append((f"{key} shape", list(a.shape), list(b.shape)))
            continue
        where = tuple(int(i) for i in np.argwhere(a != b)[0])
        n = int(np.count_nonzero(a != b))
        more = f" (+{n - 1} more)" if n > 1 else ""
        index = "".join(f"[{i}]" for i in where)
        out.append((f"{key}{index}{more}", float(a[where]), float(b[where])))
    rest = {k: v for k, v in logged.items() if k not in ("y", "x")}
    rest_r = {k: v for k, v in recomputed.items() if k not in ("y", "x")}
    return out + _field_diffs(rest, _json(rest_r))


# topic -> key of a message (messages with equal keys are paired in order)
_KEYS: dict[str, Callable[[int, dict], tuple]] = {
    "/tx/pulse": lambda t, m: (m.get("unit"), m.get("sample"), m.get("channel")),
    "/rx/spike": lambda t, m: (m.get("unit"), m.get("sample")),
    "/rx/decode": lambda t, m: (m.get("unit"), m.get("kind"), m.get("sender"), t),
    "/unit/relations": lambda t, m: (m.get("unit"),),
    "/unit/influences": lambda t, m: (m.get("unit"), m.get("round", 1)),
    "/unit/decision": lambda t, m: (m.get("unit"), m.get("subject"), m.get("round", 1)),
    "/unit/goal": lambda t, m: (m.get("unit"), m.get("turn")),
    "/log": lambda t, m: (t, m.get("name"), m.get("level"), m.get("message")),
}


def _key_text(topic: str, key: tuple) -> str:
    """The paired messages' key in words (part of a mismatch's field)."""
    if topic == "/tx/pulse":
        return f"pulse on {key[2]} at sample {key[1]}"
    if topic == "/rx/spike":
        return f"spikes at sample {key[1]}"
    if topic == "/rx/decode":
        return f"{key[1]} from {key[2]}"
    if topic == "/unit/decision":
        return f"subject {key[1]}" if key[2] == 1 else f"subject {key[1]}, round {key[2]}"
    if topic == "/unit/goal":
        return f"goal choice of turn {key[1]}"
    if topic == "/log":
        return f"line {key[3]!r}"
    if _is_trace(topic):
        return f"trace at {key[0] / NS:.3f} s"
    return "table"


def diff_messages(
    logged: Iterable[tuple[str, int, dict]],
    recomputed: Iterable[tuple[str, int, dict]],
    units: Sequence[str],
    *,
    until_ns: int | None = None,
) -> tuple[list[Mismatch], Counter[str]]:
    """Pair logged and recomputed messages per topic by key; list what differs.

    /log: every line the re-run units write must be in the log; the log may hold more (the
    CLI and per-process wrappers write lines too, some under a unit's name);
    ``until_ns`` ignores messages at or after that time on both sides (a truncated log).
    Returns the mismatches and how many messages of each topic were compared.
    """
    unitset = set(units)

    traced: dict[str, bool] = {}

    def keyed(msgs: Iterable[tuple[str, int, dict]]) -> dict[str, dict[tuple, list]]:
        out: dict[str, dict[tuple, list]] = defaultdict(lambda: defaultdict(list))
        for topic, t, m in msgs:
            if until_ns is not None and t >= until_ns:
                continue
            trace = traced.get(topic)
            if trace is None:
                trace = traced[topic] = _is_trace(topic)
            if trace:  # logged traces may be undecoded bytes: key by time
                out[topic][(t,)].append((t, m))
            elif topic in _KEYS:
                if topic == "/log" and m.get("name") not in unitset:
                    continue  # not a unit's line
                out[topic][_KEYS[topic](t, m)].append((t, m))  # keys are plain scalars
        return out

    a = keyed(logged)
    b = keyed(recomputed)
    mismatches: list[Mismatch] = []
    checked: Counter[str] = Counter()
    for topic in sorted(set(a) | set(b)):
        la, lb = a.get(topic, {}), b.get(topic, {})
        for key in [*la, *(k for k in lb if k not in la)]:
            xs, ys = la.get(key, []), lb.get(key, [])
            for i in range(max(len(xs), len(ys))):
                x = xs[i] if i < len(xs) else None
                y = ys[i] if i < len(ys) else None
                checked[topic] += 1
                # Byte for byte as the recorder encodes; decode only to explain a difference.
                if _is_trace(topic) and x is not None and y is not None and _same_trace(x[1], y[1]):
                    continue
                t_ns, m = x if x is not None else y  # type: ignore[misc]
                if isinstance(m, bytes | bytearray):
                    m = orjson.loads(m)
                unit = m.get("unit", m.get("name"))
                what = _key_text(topic, key)
                if x is None:
                    mismatches.append(Mismatch(topic, t_ns / NS, unit, what, "(missing)", _json(m)))
                    continue
                if y is None:
                    if topic != "/log":  # other writers (CLI, process wrappers) add lines
                        mismatches.append(
                            Mismatch(topic, t_ns / NS, unit, what, m, "(not produced)")
                        )
                    continue
                if _is_trace(topic):
                    diffs = _trace_diff(m, y[1])
                else:
                    # the re-run's message as the recorder would log it; the same JSON is the
                    # same message (== alone would take true for 1)
                    mine = encode_json(y[1])
                    same = encode_json(x[1]) == mine
                    diffs = [] if same else _field_diffs(x[1], orjson.loads(mine))
                    if x[0] != y[0]:
                        diffs.append(("log_time", x[0], y[0]))
                for path, lv, rv in diffs:
                    field_name = (
                        path
                        if topic in ("/unit/relations", "/unit/influences")
                        else (f"{what}: {path}")
                    )
                    mismatches.append(Mismatch(topic, t_ns / NS, unit, field_name, lv, rv))
    mismatches.sort(key=lambda m: (m.t if m.t is not None else -1.0, m.topic))
    return mismatches, checked


@dataclass
class VerifyReport:
    label: str
    mismatches: list[Mismatch]
    checked: dict[str, int]
    truncated: bool
    note: str
    medium_windows: int  # non-silent windows of the medium in the log
    until: float | None = None  # compared up to this time (a truncated log)

    @property
    def ok(self) -> bool:
        return not self.mismatches and not self.truncated

    @property
    def exit_code(self) -> int:
        if self.mismatches:
            return EXIT_MISMATCH
        return EXIT_TRUNCATED if self.truncated else EXIT_VERIFIED

    def verdict(self) -> str:
        n = sum(self.checked.values())
        if self.mismatches:
            return f"MISMATCH: {len(self.mismatches)} disagreement(s) in {n} compared messages"
        if self.truncated:
            return (
                f"INCOMPLETE: the {n} messages before t = {self.until or 0.0:.3f} s agree, but "
                "the log is truncated, so the run is verified only that far"
            )
        return f"verified: {n} messages agree with the re-run"

    def to_json(self) -> dict[str, Any]:
        return {
            "log": self.label,
            "ok": self.ok,
            "exit_code": self.exit_code,
            "verdict": self.verdict(),
            "truncated": self.truncated,
            "note": self.note,
            "until": self.until,
            "medium_windows": self.medium_windows,
            "checked": dict(self.checked),
            "mismatches": [asdict(m) for m in self.mismatches],
        }


def verify(replay: Replay, rerun: Any, checks: Iterable[Mismatch] = ()) -> VerifyReport:
    """Compare a log with a re-run of its units (``rgtbus.units.replay.rerun_replay``).

    Checks: the metadata matches the scenario; the pulses add up to the medium; every spike,
    decode, table, decision, trace and unit log line recomputed equals the logged one (no
    more, no fewer); the ``/run`` record equals the re-run's summary; plus ``checks`` (e.g.
    decisions re-derived from the logged tables). ``rerun`` needs ``messages``, ``summary``
    and ``complete`` (every re-run unit ended within the logged medium).
    """
    sc = replay.require_scenario()
    mismatches: list[Mismatch] = []
    # The scenario rebuilt from its text must be the one that ran.
    freq = {u: repr(w) for u, w in sc.frequencies.items()}
    for name, want in (
        ("frequencies", freq),
        ("codebook", {k: json.dumps(v) for k, v in sc.codebook.to_dict().items()}),
    ):
        got = replay.metadata.get(name)
        if got is not None and got != want:
            mismatches.append(Mismatch(f"metadata {name}", None, None, "values", got, want))
    until_ns = None
    until = None
    if replay.truncated:
        # Units write in time order: what is logged before their last message is complete.
        until_ns = replay.units_until_ns() or 0
        until = until_ns / NS
    mismatches += replay.check_medium(until_ns)
    diffs, checked = diff_messages(
        replay.contents.messages, rerun.messages, sc.units, until_ns=until_ns
    )
    mismatches += diffs
    mismatches += list(checks)
    checked["/medium"] = replay.windows
    if not replay.truncated:
        if not rerun.complete:
            mismatches.append(
                Mismatch(
                    "/medium",
                    replay.sim_seconds,
                    None,
                    "the run's length",
                    "the logged medium",
                    "units still listening when it ends",
                )
            )
        run = replay.run
        if run is None and set(replay.unit_processes) >= set(sc.units):
            pass  # a merge of every unit's own log (no launcher wrote a /run): all ended done
        elif run is None:
            mismatches.append(Mismatch("/run", None, None, "record", "(missing)", "present"))
        else:
            checked["/run"] += 1
            s = rerun.summary
            want_run = {
                "scenario": s["scenario"],
                "seed": s["seed"],
                "outcome": s["outcome"],
                "agree": s["agree"],
                "sim_seconds": s["sim_seconds"],
                "error": s["error"],
            }
            for path, lv, rv in _field_diffs(run, want_run):
                mismatches.append(Mismatch("/run", run.get("sim_seconds"), None, path, lv, rv))
    mismatches.sort(key=lambda m: (m.t if m.t is not None else -1.0, m.topic))  # stable
    return VerifyReport(
        label=replay.label,
        mismatches=mismatches,
        checked=dict(checked),
        truncated=replay.truncated,
        note=replay.note,
        medium_windows=replay.windows,
        until=until,
    )


# -- CSV ------------------------------------------------------------------------------------


def sample_time(t: float, tau: float | None) -> float:
    """A time on the sample grid, without float noise: 162.04500000000002 -> 162.045."""
    if not tau:
        return round(t, 9)
    digits = min(9, max(0, math.ceil(-math.log10(tau)) + 1))
    return round(round(t / tau) * tau, digits)


def in_span(
    t: float, span: tuple[float | None, float | None] | None, until: float | None = None
) -> bool:
    """Whether the instant ``t`` (or the interval ``t``..``until``) meets ``span`` (from, to;
    None: unbounded), within a nanosecond."""
    if span is None:
        return True
    lo, hi = span
    end = t if until is None else until
    return (lo is None or end >= lo - 1e-9) and (hi is None or t <= hi + 1e-9)


def csv_tables(
    replay: Replay, span: tuple[float | None, float | None] | None = None
) -> dict[str, tuple[list[str], list[list[Any]]]]:
    """``{file name: (header, rows)}``: transmissions, decodes, decisions, spikes. Every row
    starts with the run's id, scenario and seed (tables of many runs concatenate); times are
    on the sample grid; ``span`` (from, to) keeps what happens in it (a transmission: any of
    its pulses)."""
    tau = replay.scenario.timing.tau if replay.scenario is not None else None
    info = replay.info()
    run_cols = ["run_id", "scenario", "seed"]
    run_vals = [info["run_id"], info["scenario"], info["seed"]]

    def ts(t: float) -> float:
        return sample_time(t, tau)

    tx_head = [
        *run_cols,
        "turn",
        "phase",
        "kind",
        "sender",
        "addressee",
        "channel",
        "code",
        "meaning",
        "start",
        "end",
        "pulses",
    ]
    tx_rows = [
        [
            *run_vals,
            x.turn,
            x.phase,
            x.kind,
            x.sender,
            x.addressee,
            x.channel,
            x.code,
            x.meaning,
            ts(x.start),
            ts(x.end),
            len(x.pulses),
        ]
        for x in replay.transmissions
        if in_span(x.start, span, until=x.end)
    ]
    dec_head = [
        *run_cols,
        "t",
        "unit",
        "sender",
        "addressee",
        "channel",
        "kind",
        "code",
        "margin",
        "accepted",
        "turn",
        "sent",
        "matches",
    ]
    dec_rows = [
        [
            *run_vals,
            ts(d.t),
            d.unit,
            d.sender,
            d.addressee,
            d.channel,
            d.kind,
            d.code,
            d.margin,
            d.accepted,
            d.turn,
            d.sent,
            d.matches,
        ]
        for d in replay.decodes
        if in_span(d.t, span)
    ]

    u = replay.scenario.universe if replay.scenario is not None else None

    def alt(v: Any) -> str:  # the text form (1, 0, {alpha}); empty when there is none
        if v is None:
            return ""
        return u.format(u.from_list(v)) if u is not None else "{" + ",".join(v) + "}"

    dn_head = [
        *run_cols,
        "t",
        "unit",
        "subject",
        "A",
        "B",
        "low",
        "high",
        "frustrated",
        "choice",
        "canonical",
    ]
    dn_rows = [
        [
            *run_vals,
            ts(d["t"]),
            d["unit"],
            d["subject"],
            alt(d["A"]),
            alt(d["B"]),
            alt(d["interval"][0]) if d["interval"] else "",
            alt(d["interval"][1]) if d["interval"] else "",
            d["frustrated"],
            alt(d["choice"]),
            d["canonical"],
        ]
        for d in replay.decisions
        if in_span(d["t"], span)
    ]
    sp_head = [*run_cols, "t", "unit", "channel", "omega", "sample"]
    sp_rows = [
        [*run_vals, ts(s["t"]), s["unit"], s["channel"], s["omega"], s["sample"]]
        for s in replay.spikes
        if in_span(s["t"], span)
    ]
    return {
        "transmissions.csv": (tx_head, tx_rows),
        "decodes.csv": (dec_head, dec_rows),
        "decisions.csv": (dn_head, dn_rows),
        "spikes.csv": (sp_head, sp_rows),
    }


def write_csv(header: list[str], rows: list[list[Any]], stream: IO[str]) -> None:
    """One table as CSV (booleans as true/false, None as empty)."""
    w = csv.writer(stream, lineterminator="\n")
    w.writerow(header)
    for row in rows:
        w.writerow(
            [
                "" if v is None else ("true" if v is True else "false" if v is False else v)
                for v in row
            ]
        )
