"""A read log's parts before ``Replay`` organises them: its messages by topic (``Topics``, each
topic decoded and checked when first asked for), what its metadata says of how it was
written (a merge's cut inputs, unit processes that ended early, channel frequencies, the
seed: ``logged_seed``), how far a log cut short is whole (``units_until_ns``), a unit's
report rebuilt for a log from before ``/unit/report`` (``legacy_report``), and its traces as
arrays (``stack_traces``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Container, Iterable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np
import orjson

from rgtbus.errors import BadLog
from rgtbus.telemetry import topics, untrusted
from rgtbus.telemetry.blocks import block_samples
from rgtbus.telemetry.recorder import DeferredTopics, LogMessage
from rgtbus.telemetry.records import (
    LOG,
    MEDIUM,
    RUN,
    RX_DECODE,
    RX_SPIKE,
    TX_PULSE,
    UNIT_REPORT,
    is_trace_topic,
)
from rgtbus.telemetry.transmissions import Transmission
from rgtbus.timebase import ns, sample_of, seconds, time_of


class Topics(Mapping[str, list[tuple[int, Any]]]):
    """A log's messages by topic, ``(log_time, message)`` in log-time order: a topic held as
    its undecoded JSON is decoded, and each message checked against its schema, the first
    time it is asked for (``checked_message``: a large run's decodes and spikes are tens of
    megabytes of JSON, and many times that as Python objects); a topic that holds none is an
    empty list. A topic left in the file (``later``: a log read from a path) is read from it
    the first time it is asked for, and held from then on (traces aside: ``Replay`` reads
    them from the file each time and never holds them); the topics keep one order."""

    def __init__(
        self,
        messages: Iterable[LogMessage],
        label: str,
        current: frozenset[str] = frozenset(),
        later: DeferredTopics | None = None,
    ) -> None:
        self.current = current  # topics checked against their schema (LogContents.current)
        self._held: dict[str, list[tuple[int, Any]]] = {}
        self._raw: set[str] = set()  # topics still held (at least partly) as JSON bytes
        self.label = label
        for topic, t, m in messages:
            self._held.setdefault(topic, []).append((t, m))
            if isinstance(m, bytes):
                self._raw.add(topic)
        self._later = later
        self._waiting: dict[str, int] = {}  # left in the file: how many messages each holds
        for topic, n in (later.held() if later is not None else {}).items():
            if not is_trace_topic(topic) and topic not in self._held:
                self._waiting[topic] = n
        self._order = [*self._held, *self._waiting]

    @property
    def in_file(self) -> dict[str, int]:
        """The topics still left in the file (none read yet), and how many messages each
        holds."""
        return dict(self._waiting)

    def _read(self, topic: str) -> None:
        """A topic left in the file, read now (its messages' bytes, CRC-checked) and held."""
        if topic in self._waiting and self._later is not None:
            del self._waiting[topic]
            self._held[topic] = list(self._later.read(topic))
            self._raw.add(topic)

    def __getitem__(self, topic: str) -> list[tuple[int, Any]]:
        self._read(topic)
        held = self._held.get(topic)
        if held is None:
            return []
        if topic in self._raw:
            check = topic in self.current
            tables = topics.SharedTables()  # a table the units hold alike: checked once
            held[:] = [
                (t, untrusted.message(topic, t, m, self.label, check, tables)) for t, m in held
            ]
            self._raw.discard(topic)
        return held

    def __iter__(self) -> Iterator[str]:
        return iter(self._order)

    def __len__(self) -> int:
        return len(self._order)

    def __contains__(self, topic: object) -> bool:
        return topic in self._held or topic in self._waiting

    def each(
        self, topic: str, leave: Container[int] = (), at: int = 0
    ) -> Iterator[tuple[int, Any]]:
        """``topic``'s messages one at a time, decoded (and checked) as ``[topic]`` gives
        them, but none kept decoded: a large run's decodes are read into columns a record at
        a time (``decode_table``), never all held as Python objects. ``leave``: positions
        (in ``messages()``'s order; this topic's first is ``at``) of messages left out,
        undecoded."""
        self._read(topic)
        held = self._held.get(topic, [])
        check = topic in self.current
        for k, (t, m) in enumerate(held, at):
            if k in leave:
                continue
            if isinstance(m, bytes) and topic in self._raw:
                m = untrusted.message(topic, t, m, self.label, check)
            yield t, m

    def count(self, topic: str) -> int:
        """How many messages ``topic`` holds (nothing read or decoded)."""
        held = self._held.get(topic)
        return len(held) if held is not None else self._waiting.get(topic, 0)

    def messages(self) -> Iterator[LogMessage]:
        """Every message as ``(topic, log_time, message)``, as held (decoded or JSON bytes),
        topic by topic in their order (a topic left in the file read now)."""
        for topic in self._order:
            self._read(topic)
            for t, m in self._held.get(topic, ()):
                yield topic, t, m


def merge_notes(metadata: dict[str, dict[str, str]]) -> list[str]:
    """The truncation notes of a merged log's inputs (empty for a log that is no merge)."""
    out: list[str] = []
    for name, values in metadata.items():
        if name == "merge" or name.startswith("merge."):
            try:  # orjson, and the one depth rule: str() of a note recurses
                notes = orjson.loads(values.get("truncated", "[]"))
                if untrusted.depth_error(notes) is not None:
                    raise ValueError
            except ValueError:
                notes = ["a merge record that does not parse"]
            if isinstance(notes, list):
                out += [str(n) for n in notes]
    return out


def unit_process_ends(
    metadata: dict[str, dict[str, str]], units: Sequence[str]
) -> tuple[list[str], list[str]]:
    """(how the units of unit processes that did not end "done" ended, every unit whose
    process's log is in this one). A unit process's log has a ``run`` record naming it
    (``process``; and ``units``, comma-separated, when it ran several) and, once each unit
    ended, an ``end.<unit>`` record; a killed process has none."""
    processes = []
    for n, v in metadata.items():
        if (n == "run" or n.startswith("run.")) and v.get("process") in units:
            hosted = v["units"].split(",") if v.get("units") else [v["process"]]
            processes += [u for u in hosted if u in units]
    early = []
    for unit in processes:
        end = metadata.get(topics.unit_end_record(unit))
        if end is None:
            early.append(f"unit {unit}'s process ended without a word (killed?)")
        elif end.get("status") != topics.UNIT_DONE:
            early.append(f"unit {unit} {topics.UNIT_ENDED_EARLY}: {end.get('detail', '')}")
    return early, processes


def frequencies_of(metadata: dict[str, dict[str, str]]) -> dict[str, float]:
    """Channel frequencies from a log's ``frequencies`` metadata (values that are no number
    are left out: the verifier names a damaged scenario, this only labels spikes)."""
    out = {}
    for k, v in metadata.get("frequencies", {}).items():
        with contextlib.suppress(ValueError):
            out[k] = float(v)
    return out


def logged_seed(metadata: Mapping[str, Mapping[str, str]], label: str = "log") -> int | None:
    """The seed a log's ``run`` metadata record names (None when it names none); a value
    that is no integer (a log written by hand or tampered with): RgtbusError in one line."""
    seed = metadata.get("run", {}).get("seed")
    if seed is None:
        return None
    try:
        return int(str(seed).strip(), 10)
    except ValueError:
        raise BadLog(f"{label}: metadata run: seed {seed!r} is not an integer") from None


_NOT_PROGRESS = frozenset({MEDIUM, RUN, UNIT_REPORT, LOG})
# logged as each send is planned (or, with a live view or a paced run, by a unit's transmitter
# as the clock reaches each pulse), not in step with the unit's other records: what a unit
# logged before its last record or spike block holds every pulse before that time as well
_ON_TIME = frozenset({TX_PULSE})


def units_until_ns(
    by_topic: Topics,
    decodes: Iterable[tuple[int, Mapping[str, Any]]],
    units: Sequence[str],
    tau: float | None,
) -> int | None:
    """The log time before which every unit's messages are complete in a log cut short
    (a truncated file, or a merge whose inputs ended early): the earliest, over the units,
    of each unit's last record and last block of spikes (a unit's records leave in its own
    time order; spikes as the ears hear them; pulses, the medium and traces ahead); None
    when nothing was logged."""
    last: dict[str, int] = {}
    # what is logged ahead of time (the medium, traces) or once the run is over (the run's
    # and units' reports, and log lines, which a stopped unit writes at its end) says
    # nothing of how far its records are complete
    skip = _NOT_PROGRESS | _ON_TIME
    every = [(t, by_topic[t]) for t in by_topic if t not in skip]
    for topic, msgs in [*every, (RX_DECODE, decodes)]:
        if is_trace_topic(topic):
            continue
        stream = "spikes" if topic == RX_SPIKE else "records"
        for t, m in msgs:
            if "units" in m:  # one record for several units (spikes, decodes)
                whos = [str(u) for u in m["units"]]
            else:
                whos = [str(m.get("unit", m.get("name", "")))]
            for who in whos:
                if t > last.get(f"{who}\0{stream}", -1):
                    last[f"{who}\0{stream}"] = t
    if not last:
        return None
    # A unit's spikes go to the log in blocks as its ears hear them, which runs ahead of
    # its other records (logged at their own time) and behind them within a block not yet
    # heard through: its log is complete before the earlier of the two streams, and a unit
    # with either stream still empty (e.g. killed before its first flush, or stopped
    # before its first decode) only before the start. In one file cut short, the records
    # written last need not be the latest in log time either. Its pulses go out a block
    # at a time, a block once its records are past it (``PulseBlocks.before``): complete
    # before the start of its last record's block, or whole once it reported (at its end).
    reported = {m.get("unit") for _, m in by_topic[UNIT_REPORT]}

    def bound(u: str) -> int:
        records = last.get(f"{u}\0records", 0)
        out = min(records, last.get(f"{u}\0spikes", 0))
        return out if u in reported else min(out, _pulse_bound(records, tau))

    return min((bound(u) for u in units), default=None)


def _pulse_bound(t_ns: int, tau: float | None) -> int:
    """Before which log time a unit's pulses are all in a log that holds its records up
    to ``t_ns`` (``PulseBlocks.before``, blocks of ``BLOCK_SECONDS``)."""
    if tau is None:
        return 0
    block = block_samples(tau)
    done = sample_of(seconds(t_ns), tau) // block
    return max(0, ns(time_of(done * block, tau)))


def legacy_report(
    unit: str,
    relations: Mapping[str, Any] | None,
    influences: Mapping[str, Any] | None,
    decisions: Sequence[Mapping[str, Any]],
    transmissions: Sequence[Transmission],
) -> dict[str, Any]:
    """A unit's ``/unit/report`` rebuilt for a log from before that topic: from its last
    relations and influences records, its own decisions and the codes it sent."""
    rel: Mapping[str, Any] = relations or {}
    infl: Mapping[str, Any] = influences or {}
    own = [d for d in decisions if d["unit"] == unit and d["subject"] == unit]
    last = own[-1] if own else None
    result = {
        "interval": None if last is None else last["interval"],
        "frustrated": False if last is None else bool(last["frustrated"]),
        "choice": None if last is None else last["choice"],
        "canonical": None if last is None else last["canonical"],
        "A": None if last is None else last["A"],
        "B": None if last is None else last["B"],
        "decided": last is not None,
    }
    rows = []
    for d in own:
        low, high = d["interval"] or (None, None)
        rows.append(
            {"round": d.get("round", 1), "unit": unit, "low": low, "high": high,
             "choice": d["choice"], "frustrated": bool(d["frustrated"]), "t": d["t"]}
        )  # fmt: skip
    return {
        "unit": unit,
        "installed": rel.get("installed", {}),
        "polynomial": rel.get("polynomial"),
        "p4": rel.get("p4"),
        "sent_relations": rel.get("sent", {}),
        "influences": infl.get("influences", {}),
        "result": result,
        "decisions": rows,
        "sends": [
            [tx.turn, tx.kind, tx.addressee, tx.code]
            for tx in transmissions
            if tx.sender == unit
        ],
        "sent_influences": [],
        "failure": None,
        "failed_at": None,
        "done_at": None,
        "mind_error": None,
    }


def stack_traces(msgs: Sequence[dict[str, Any] | bytes], units: Sequence[str]) -> dict[str, Any]:
    """Trace messages -> ``{"t": (n,), "y": (n, channels), "channels": [...]}``: one message
    a sample (its channels the run's ``units``), or (logs of rgtbus before the per-sample
    layout) one a window."""
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
    return {"t": t, "y": yy, "channels": list(units)}
