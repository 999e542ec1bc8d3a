"""Reading a run back from its MCAP log (CRC-checked): ``load_replay(source)`` organises a
log (path or stream) into a ``Replay``: transmissions (the logged pulses grouped into codes,
with their meaning), spikes, decodes (each matched with the transmission it read), the tables
each unit built, decisions, the ``/run`` record and the metadata. ``Replay.summary()`` is the
run's summary computed from the log alone by the one summary function
(``rgtbus.summary.summarise``). Verifying a log is ``rgtbus.telemetry.verify``; exporting it
(CSV) ``rgtbus.telemetry.export``; DataFrames ``rgtbus.telemetry.frames``. Every disagreement
found while reading or verifying is a ``Mismatch``.
"""

from __future__ import annotations

import functools
import os
from collections import defaultdict
from collections.abc import Collection, Container, Iterable, Iterator, Mapping
from dataclasses import asdict
from typing import IO, Any, cast

import numpy as np

from rgtbus.errors import BadLog, RgtbusError
from rgtbus.misreads import DecodeErrors, decode_errors_of
from rgtbus.scenario import Scenario, parse_scenario
from rgtbus.steering import Request
from rgtbus.summary import (
    HOW_IT_RAN,
    RunEnd,
    agreement,
    summarise,
    summary_json,
)
from rgtbus.telemetry import logged_medium, untrusted
from rgtbus.telemetry.decode_table import held_decodes
from rgtbus.telemetry.log_parts import (
    Topics,
    frequencies_of,
    legacy_report,
    logged_seed,
    merge_notes,
    stack_traces,
    unit_process_ends,
    units_until_ns,
)
from rgtbus.telemetry.mismatch import Mismatch
from rgtbus.telemetry.pulse_blocks import pulse_rows
from rgtbus.telemetry.record_rows import decode_rows, decode_units, spike_units
from rgtbus.telemetry.recorder import DeferredTopics, LogContents, LogMessage
from rgtbus.telemetry.records import (
    CONTROL_PARAMETER,
    CONTROL_SERVICE,
    MEDIUM,
    RUN,
    RX_DECODE,
    RX_DECODES,
    RX_SPIKE,
    TX_PULSE,
    UNIT_DECISION,
    UNIT_INFLUENCES,
    UNIT_RELATIONS,
    UNIT_REPORT,
    DecisionRecord,
    InfluencesRecord,
    PulseRecord,
    RelationsRecord,
    RunRecord,
    full_report,
    is_trace_topic,
    trace_topic,
)
from rgtbus.telemetry.scan import decode_log, require_run_log, scan_log
from rgtbus.telemetry.spike_table import SpikeTable, spike_table
from rgtbus.telemetry.transmissions import (
    DecodeRow,
    Transmission,
    matched_decodes,
    transmissions_of,
)
from rgtbus.telemetry.untrusted import explained
from rgtbus.timebase import ns, seconds

# Two logged times of one instant agree to within this (a log time is whole nanoseconds).
_NANOSECOND = seconds(1)


class Replay:
    """A log organised for reading. Build with ``load_replay``."""

    def __init__(self, contents: LogContents, label: str = "<log>") -> None:
        self.label = label
        self.metadata: dict[str, dict[str, str]] = contents.metadata
        self.truncated: bool = contents.truncated
        self.note: str = contents.note
        self.deferred: DeferredTopics | None = contents.deferred
        self.end_ns: int | None = contents.end_ns
        self.by_topic = Topics(contents.messages, label, contents.current, contents.deferred)
        self.scenario: Scenario | None = None
        self.scenario_error: str | None = None
        self._load_scenario()
        self.units: tuple[str, ...] = self._units()
        # A merge of unit logs (launch, or ``rgtbus merge`` by hand) whose inputs ended early
        # (a killed unit) is as incomplete as a truncated file, though the file itself is whole.
        early, self.unit_processes = unit_process_ends(self.metadata, self.units)
        self.cut_inputs: list[str] = merge_notes(self.metadata) + early
        if self.cut_inputs:
            self.truncated = True
            self.note = "; ".join(filter(None, [self.note, *self.cut_inputs]))
        # the records as their writers built them (rgtbus.telemetry.records)
        self.run: RunRecord | None = (
            cast(RunRecord, self.by_topic[RUN][-1][1]) if self.by_topic[RUN] else None
        )
        self.frequencies = frequencies_of(self.metadata)

    # -- what is read when first asked for (a topic a reader does not use stays undecoded) -----

    def read_tables(self) -> None:
        """Read every table of the log now, not when first asked for: a reader that shows
        them all (``rgtbus replay``) refuses a bad log before it prints a line."""
        for table in ("transmissions", "relations", "influences", "decisions", "decodes"):
            getattr(self, table)

    @functools.cached_property
    def transmissions(self) -> list[Transmission]:
        """The logged pulses grouped into codes, with their meaning, in start order."""
        with explained(self.by_topic.messages, self.label):
            return transmissions_of(self.pulses(), self.units)

    @functools.cached_property
    def relations(self) -> dict[str, RelationsRecord]:
        """Each unit's last ``/unit/relations`` record (a 200-unit run's are 200 tables of
        39,800 pairs: read only when asked for)."""
        with explained(self.by_topic.messages, self.label):
            return {m["unit"]: cast(RelationsRecord, m) for _, m in self.by_topic[UNIT_RELATIONS]}

    @functools.cached_property
    def influences(self) -> dict[str, InfluencesRecord]:
        """Each unit's last ``/unit/influences`` record."""
        with explained(self.by_topic.messages, self.label):
            return {m["unit"]: cast(InfluencesRecord, m) for _, m in self.by_topic[UNIT_INFLUENCES]}

    @functools.cached_property
    def decisions(self) -> list[DecisionRecord]:
        """Every ``/unit/decision`` record, in log-time order."""
        with explained(self.by_topic.messages, self.label):
            return [cast(DecisionRecord, m) for _, m in self.by_topic[UNIT_DECISION]]

    # -- construction ------------------------------------------------------------------------

    def pulses(self) -> Iterator[PulseRecord]:
        """Every pulse sent, one record each (``records.pulse``), block by block as logged
        (a sender's in the order it sent them)."""
        for _, block in self.by_topic[TX_PULSE]:
            yield from pulse_rows(block)

    def _each_decode(self) -> Iterator[tuple[int, dict[str, Any]]]:
        """Every decode as one ``/rx/decode`` message at its own time, however the log holds
        it (one a decode, or columns a wake in ``/rx/decodes``), in file order: not yet
        sorted by time (``decode_records``), and never all held at once."""
        yield from self.by_topic.get(RX_DECODE, [])
        for _, m in self.by_topic.get(RX_DECODES, []):
            for row in decode_rows(m):
                yield ns(row["t"]), cast(dict[str, Any], row)

    @functools.cached_property
    def decode_records(self) -> list[tuple[int, dict[str, Any]]]:
        """Every decode as one ``/rx/decode`` message, in log-time order: what every reader
        reads (built when first asked for: a large run decodes millions of times)."""
        # by time, then unit (in the run's order), stable: a unit's decodes of one time keep
        # their order
        rank = {u: i for i, u in enumerate(self.units)}
        last = len(rank)
        return sorted(self._each_decode(), key=lambda r: (r[0], rank.get(r[1]["unit"], last)))

    @functools.cached_property
    def decodes(self) -> list[DecodeRow]:
        """Every decode, matched with the transmission it read."""
        return matched_decodes(self.transmissions, self.decode_records)

    @functools.cached_property
    def spikes(self) -> SpikeTable:
        """Every resonator spike, as columns (``SpikeTable``)."""
        return self.spikes_of(None)

    def spikes_of(self, units: Collection[str] | None) -> SpikeTable:
        """The spikes of ``units`` (None: every unit's), as columns (not kept)."""
        tau = self.scenario.timing.tau if self.scenario is not None else None
        records = (m for _, m in self.by_topic[RX_SPIKE])
        return spike_table(records, self.frequencies, tau, self.units, units)

    def topic_messages(self, topic: str) -> list[tuple[int, Any]]:
        """``topic``'s messages as ``(log_time, message)`` in log-time order, decoded and
        checked against their schema (``checked_message``); a topic left in the file until
        asked for (traces) is read from the file now and not kept."""
        if topic == RX_DECODE:
            return self.decode_records
        if not is_trace_topic(topic) or topic in self.by_topic:  # (a log read whole holds
            return self.by_topic[topic]  # its traces)
        deferred = self.deferred  # a trace: read from the file each time, never held
        if deferred is not None and topic in deferred.held():
            label, check = self.label, topic in self.by_topic.current
            msgs = deferred.read(topic)
            return [(t, untrusted.message(topic, t, m, label, check)) for t, m in msgs]
        return []

    def topic_counts(self) -> dict[str, int]:
        """How many messages each topic holds (topics with none left out)."""
        out = {t: self.by_topic.count(t) for t in self.by_topic if self.by_topic.count(t)}
        if self.deferred is not None:  # traces, counted where they are
            out.update({t: n for t, n in self.deferred.held().items() if is_trace_topic(t)})
        return out

    def message_count(self) -> int:
        """How many messages the log holds (those left in the file too)."""
        return sum(self.topic_counts().values())

    def messages(self) -> Iterator[LogMessage]:
        """Every message read when the log was opened, as held (decoded, or JSON bytes not yet
        asked for): what ``explained`` looks through once reading has failed."""
        return self.by_topic.messages()

    def every_message(self, leave: Container[int] = ()) -> Iterator[tuple[str, int, Any]]:
        """Every message of the log as ``(topic, log_time, message)``, decoded (traces
        excepted: JSON bytes), topic by topic in log-time order: those read when the log was
        opened, then those left in the file until now. Decoded as they go (``Topics.each``):
        what the caller keeps is up to it. ``leave``: the positions, in ``messages()``'s
        order, of messages the caller has no use for (never decoded)."""
        at = 0
        for topic in self.by_topic:  # none kept decoded: a large run's spikes and decodes
            for t, m in self.by_topic.each(topic, leave, at):  # as Python lists are gigabytes
                yield topic, t, m
            at += self.by_topic.count(topic)
        if self.deferred is not None:  # traces: read from the file now
            for topic in self.deferred.held():
                if is_trace_topic(topic):
                    for t, m in self.deferred.read(topic):
                        yield topic, t, m

    def _load_scenario(self) -> None:
        meta = self.metadata.get("scenario")
        if not meta or "text" not in meta:
            self.scenario_error = "the log has no scenario metadata"
            return
        try:
            sc = parse_scenario(meta["text"], meta.get("path", "<scenario>"))
            seed = logged_seed(self.metadata, self.label)
            if seed is not None:
                sc = sc.with_seed(seed)
        except (RgtbusError, ValueError) as e:
            self.scenario_error = f"the log's scenario does not load: {e}"
            return
        self.scenario = sc

    def require_scenario(self) -> Scenario:
        """The log's scenario, or RgtbusError saying why it cannot be re-run."""
        if self.scenario is None:
            raise BadLog(f"{self.label}: cannot re-run: {self.scenario_error}")
        return self.scenario

    def _units(self) -> tuple[str, ...]:
        if self.scenario is not None:
            return self.scenario.units
        # no scenario to name them (a log damaged or written by hand): the units its records
        # name, in the order first named
        seen: dict[str, None] = {}
        for topic in (TX_PULSE, RX_SPIKE, RX_DECODE, RX_DECODES, UNIT_RELATIONS):
            for _, m in self.by_topic[topic]:
                if topic == TX_PULSE:
                    names = [m["names"][i] for i in np.unique(m["sender"]).tolist()]
                elif topic in (RX_SPIKE, RX_DECODES):
                    names = spike_units(m) if topic == RX_SPIKE else decode_units(m)
                else:
                    names = [m.get("unit")]
                for name in names:
                    if isinstance(name, str):
                        seen.setdefault(name, None)
        return tuple(seen)

    # -- what the log says -------------------------------------------------------------------

    @property
    def window_seconds(self) -> float | None:
        """The length of a medium window in seconds (from the scenario, else from a logged window);
        None when the log says nothing of it."""
        if self.scenario is not None:
            t = self.scenario.timing
            return t.window_samples / t.sample_rate
        med = self.by_topic[MEDIUM]
        if med:
            rate: float = med[0][1]["sample_rate"]
            return len(med[0][1]["samples"]) / rate
        return None

    @property
    def windows(self) -> int:
        """How many windows of the medium are logged (the ones that carry a pulse)."""
        return len(self.by_topic[MEDIUM])

    @property
    def sim_seconds(self) -> float:
        """The run's simulated length: from its ``/run`` record, else as far as the log goes."""
        if self.run is not None:
            return float(self.run["sim_seconds"])
        return round(seconds(self.end_ns or 0), 6)

    def agree(self) -> bool:
        """Whether every unit ended with the same relationship table and polynomial."""
        held = [self.relations.get(u) for u in self.units]
        tables = [{} if r is None else r["installed"] for r in held]
        polys = [None if r is None else r["polynomial"] for r in held]
        return agreement(tables, polys, len(self.units))

    def decode_errors(self) -> DecodeErrors:
        """Every unit's misreads, as the summary counts them (``decode_errors_of`` on the
        reports the summary is computed from)."""
        return decode_errors_of(self.unit_reports())

    def unit_reports(self) -> list[dict[str, Any]]:
        """Each unit's share of the run summary, from its ``/unit/report`` and its
        ``/rx/decode`` records: what the live run's summary is computed from. A unit without
        a report (its process died) is left out, as the live run leaves it out. Logs from
        before ``/unit/report`` get reports rebuilt from their tables and decisions."""
        decodes = self._unit_decodes()
        reports = {
            m["unit"]: full_report(m, self.relations.get(m["unit"]), self.influences.get(m["unit"]))
            for _, m in self.by_topic[UNIT_REPORT]
        }
        if not reports:
            reports = {
                u: legacy_report(
                    u, self.relations.get(u), self.influences.get(u), self.decisions,
                    self.transmissions,
                )
                for u in self.units
            }  # fmt: skip
        return [{**reports[u], "decodes": decodes.get(u, [])} for u in self.units if u in reports]

    def _unit_decodes(self) -> Mapping[str, Iterable[Any]]:
        """Each unit's decodes in time order (stable: as logged within one time), as the
        summary judges them: columns (``HeldDecodes``) read from the ``/rx/decodes`` blocks
        with no Python object per decode (a 100-unit run's 3.96 M decodes were 18 s and
        2 GB as rows); rows for a log of one record a decode (before the blocks)."""
        if self.by_topic.count(RX_DECODE):
            timed: dict[str, list[tuple[int, list[Any]]]] = defaultdict(list)
            for t, d in self._each_decode():
                row = [d.get("turn"), d["kind"], d["addressee"], d["code"]]
                timed[d["unit"]].append((t, row))
            return {u: [row for _, row in sorted(rows, key=lambda r: r[0])]
                    for u, rows in timed.items()}  # fmt: skip
        return held_decodes(self.by_topic.each(RX_DECODES), self.units)

    def summary(self) -> dict[str, Any]:
        """The run's summary computed from the log alone by the one summary function
        (``rgtbus.summary.summarise``) on the records the live run used: every key of
        ``rgtbus run --json`` with the same values, and the rest of the live summary but for
        what a log does not keep (steps, bus statistics). ``wall_seconds`` is ``None`` (a log
        does not time its writer) and ``log`` is this log."""
        run: Mapping[str, Any] = self.run or {}
        sc = self.scenario
        if sc is None:  # no scenario to judge with: what the /run record says
            out = summary_json(run)
            out["sim_seconds"] = self.sim_seconds
        else:
            end = RunEnd(sim_seconds=self.sim_seconds, failure=run.get("error"))
            engine = self.metadata.get("run", {}).get("engine", "event")
            out = summarise(sc, self.unit_reports(), end, engine=engine)
            for key in HOW_IT_RAN:
                out.pop(key, None)
        out["wall_seconds"] = None
        out["log"] = self.label
        return out

    @property
    def steered(self) -> bool:
        """Whether the run was steered (``--control``): its units took changes as it ran."""
        return self.metadata.get("run", {}).get("steered") == "yes" or bool(
            self.by_topic[CONTROL_PARAMETER] or self.by_topic[CONTROL_SERVICE]
        )

    def control_requests(self) -> list[tuple[int, int, Request]]:
        """A steered run's changes as its log holds them, in the order they applied:
        (sample, seq, the request with its record) for a re-run to apply again."""
        out: list[tuple[int, int, Request]] = []
        for _, m in self.by_topic[CONTROL_PARAMETER]:
            req = Request("parameter", m["name"], m["value"], m["who"], logged=m)
            out.append((int(m["sample"]), int(m["seq"]), req))
        seen: set[int] = set()
        for _, m in self.by_topic[CONTROL_SERVICE]:
            if m["seq"] in seen:  # a mark's: a record a unit, one call
                continue
            seen.add(m["seq"])
            req = Request("service", m["service"], m["request"], m["who"], logged=m)
            out.append((int(m["sample"]), int(m["seq"]), req))
        return sorted(out, key=lambda e: (e[0], e[1]))

    def spike_counts(
        self, span: tuple[float | None, float | None] | None = None
    ) -> dict[str, dict[str, int]]:
        """Spikes per unit and channel (within ``span``, from and to in seconds, when given)."""
        counts: dict[str, dict[str, int]] = {u: {} for u in self.units}
        table = self.spikes
        keep = table.within(span)
        pairs = table.unit[keep].astype(np.int64) * len(table.channels) + table.channel[keep]
        found, n = np.unique(pairs, return_counts=True)
        for pair, k in zip(found.tolist(), n.tolist(), strict=True):
            unit, channel = divmod(pair, len(table.channels))
            counts.setdefault(table.units[unit], {})[table.channels[channel]] = k
        return counts

    def info(self) -> dict[str, Any]:
        """The run's metadata: scenario, seed, version, bus, run id, frequencies."""
        sc = self.metadata.get("scenario", {})
        run = self.metadata.get("run", {})
        return {
            "scenario": sc.get("name"),
            "path": sc.get("path"),
            "seed": logged_seed(self.metadata, self.label),
            "version": run.get("version"),
            "bus": run.get("bus"),
            "run_id": run.get("run_id"),
            "python": run.get("python"),
            "frequencies": self.frequencies,
            "records": sorted(self.metadata),
        }

    def to_json(self) -> dict[str, Any]:
        """``rgtbus replay --json``: one object. Its ``summary`` is what ``rgtbus run --json``
        printed for the run, key by key (``summary_json``); the per-unit views of the
        relations go beside it (``unit_relations``: each unit's installed table;
        ``sent_relations``: what the first unit to report sent)."""
        summary = self.summary()
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
            "spikes": list(self.spikes.rows()),
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
            "outcome": summary["outcome"],
            "run": self.run,
            "summary": summary_json(summary),
            "unit_relations": summary.get("unit_relations"),
            "sent_relations": summary.get("sent_relations"),
        }

    # -- inputs for a re-run -----------------------------------------------------------------

    def medium_windows(self) -> tuple[dict[int, np.ndarray], list[Mismatch]]:
        """The logged medium's windows (only windows that carried a pulse are logged), with
        repeated and malformed windows reported (``logged_medium.medium_windows``)."""
        return logged_medium.medium_windows(self.require_scenario(), self.by_topic[MEDIUM])

    def medium_pulses(self) -> tuple[np.ndarray, np.ndarray]:
        """The logged medium as (sample indexes, values) of its non-silent samples: what every
        unit heard, bit for bit."""
        windows, _ = self.medium_windows()
        return logged_medium.medium_pulses(self.require_scenario(), windows)

    def sender_pulses(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Each unit's own transmissions, rebuilt from its logged pulses."""
        return logged_medium.sender_pulses(self.units, self.pulses())

    def has_gains(self) -> bool:
        """Whether units hear the senders differently (link gains, or delays and clocks):
        a re-run then needs each sender's own pulses, not the summed medium. A steered run's
        gain set by a client counts too."""
        ch = self.require_scenario().channel
        steered = any(
            m.get("applied") and str(m.get("name", "")).startswith("channel.gain")
            for _, m in self.by_topic[CONTROL_PARAMETER]
        )
        return not ch.unit_gains or ch.timed or steered

    def units_until_ns(self) -> int | None:
        """The log time before which every unit's messages are complete in a log cut short
        (``log_parts.units_until_ns``); None when nothing was logged."""
        tau = self.scenario.timing.tau if self.scenario is not None else None
        return units_until_ns(self.by_topic, self._each_decode(), self.units, tau)

    def traced_units(self) -> list[str]:
        """The units whose resonator traces the log holds."""
        held = self.topic_counts()
        return [u for u in self.units if held.get(trace_topic(u))]

    def trace_arrays(self, unit: str) -> dict[str, Any] | None:
        """``unit``'s logged traces stacked as arrays (``stack_traces``); None when none were
        logged."""
        msgs = [m for _, m in self.topic_messages(trace_topic(unit))]
        return stack_traces(msgs, self.units) if msgs else None


def in_span(
    t: float, span: tuple[float | None, float | None] | None, until: float | None = None
) -> bool:
    """Whether the instant ``t`` (or the interval ``t``..``until``) meets ``span`` (from, to;
    None: unbounded), within a nanosecond."""
    if span is None:
        return True
    lo, hi = span
    end = t if until is None else until
    return (lo is None or end >= lo - _NANOSECOND) and (hi is None or t <= hi + _NANOSECOND)


def _left_in_file(topic: str) -> bool:
    """Whether a log read from a path leaves ``topic``'s messages in the file until asked for
    (``Topics``): every topic but ``/run``, which opening a log reads. A topic holds its
    messages' bytes decompressed once read: a 100-unit run's 6.6 MB log holds 142 MB."""
    return topic != RUN


def load_replay(source: str | os.PathLike[str] | IO[bytes]) -> Replay:
    """Read and organise a log (path or binary stream). Unreadable, not MCAP, corrupt, only a
    header, or not written by an rgtbus run: RgtbusError. A truncated log reads up to its cut.

    A log read from a path is scanned whole (every chunk's CRC checked) but keeps only its
    ``/run`` record: every other topic stays in the file until something asks for it
    (``Topics``), and resonator traces (the bulk of a traced log) are read from it each time
    (``Replay.topic_messages``: verification compares them byte for byte, plots decode one
    unit's). A stream of no file is read whole."""
    raw = scan_log(source, defer=_left_in_file)
    require_run_log(raw)
    label = raw.label
    contents = decode_log(raw, keep_raw=lambda topic: True)  # decoded topic by topic (Topics)
    del raw
    with explained(lambda: contents.messages, label):
        return Replay(contents, label)


# -- verification ---------------------------------------------------------------------------
