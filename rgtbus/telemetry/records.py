"""The log's records: one TypedDict per topic and one function that builds each.

Every writer (the units, the world, the runners) builds its messages here, and the reader,
the verifier and the live view read them as these types; each topic's JSON Schema
(``schemas/``, the table in ``topics.py``) states the same fields, and a test checks every
builder's output against its schema. Alternatives are sorted lists of action names; pair keys
are ``"s>r"`` (``rgtbus.pairs``); ``t`` is simulated seconds (the MCAP ``log_time`` is its
integer nanoseconds, ``rgtbus.timebase.ns``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, Required, TypeAlias, TypedDict, cast

from rgtbus.errors import BadInput
from rgtbus.timebase import time_of

if TYPE_CHECKING:
    import numpy as np

    from rgtbus.summary import DecisionRow

# The topics: each named here once; every writer, reader and tool uses these names.
MEDIUM = "/medium"
TX_PULSE = "/tx/pulse"
RX_SPIKE = "/rx/spike"
RX_DECODE = "/rx/decode"  # one decode a record: logs written before /rx/decodes
RX_DECODES = "/rx/decodes"
UNIT_RELATIONS = "/unit/relations"
UNIT_INFLUENCES = "/unit/influences"
UNIT_DECISION = "/unit/decision"
UNIT_GOAL = "/unit/goal"
UNIT_REPORT = "/unit/report"
LOG = "/log"
RUN = "/run"
CONTROL_PARAMETER = "/control/parameter"  # a steered run's parameter changes (docs/foxglove.md)
CONTROL_SERVICE = "/control/service"  # ... and its service calls
SCENE = "/scene"  # foxglove.SceneUpdate: a spatial scenario's units and links (3D panel)
TRACE_PREFIX = "/trace/"  # a family: one topic a traced unit


# one message as read back: (topic, log time in ns, the message)
LogMessage = tuple[str, int, dict[str, Any]]


def trace_topic(unit: str) -> str:
    """The topic of ``unit``'s resonator traces."""
    return f"{TRACE_PREFIX}{unit}"


def is_trace_topic(topic: str) -> bool:
    """Whether ``topic`` is one of the ``/trace/<unit>`` family."""
    return topic.startswith(TRACE_PREFIX)


# a column of integers: a numpy array as a writer builds it (the encoder takes it whole), a
# list as a reader gets it back
IntColumn: TypeAlias = "Sequence[int] | np.ndarray"
FloatColumn: TypeAlias = "Sequence[float] | np.ndarray"
BoolColumn: TypeAlias = "Sequence[bool] | np.ndarray"

Alternative = list[str]


class MessageRef(TypedDict, total=False):
    """Which message a pulse belongs to (``message_ref``)."""

    id: Required[int]  # turn * 2 (+1 for the payload, a request's or a repeat's)
    kind: Required[str]  # "id" | "payload" | "request" | "repeat"
    code: Required[str]
    sender: Required[str]
    addressee: Required[str]
    block: int  # a request's or a repeat's repair block (1..K); absent otherwise


class PulseRecord(TypedDict):
    """``/tx/pulse``: one transmitted pulse."""

    unit: str
    channel: str
    omega: float
    magnitude: float
    t: float
    sample: int
    message: MessageRef


class PulseBlockRecord(TypedDict):
    """``/tx/pulse``: the pulses of one 5 s block (every sender's that one process runs; after
    ``merge``, every sender's), one row a pulse, in order of sample, then sender
    (``pulse_blocks.PulseBatch``; ``pulse_blocks.pulse_rows`` reads them as ``PulseRecord``s)."""

    t: float  # the last pulse's time
    tau: float  # the senders' sample period: a pulse's t is its sample × tau
    channels: list[str]  # the channels its pulses are on
    omegas: FloatColumn  # each channel's ω
    names: list[str]  # the units sender and addressee index
    kinds: list[str]  # the message kinds kind indexes
    codes: list[str]  # the code names code indexes
    sample: IntColumn
    channel: IntColumn  # into channels
    magnitude: FloatColumn
    message: IntColumn  # the message's id (``MessageRef.id``)
    kind: IntColumn  # into kinds
    code: IntColumn  # into codes
    sender: IntColumn  # into names
    addressee: IntColumn  # into names
    block: IntColumn  # a request's or repeat's repair block, else 0


class SpikeRecord(TypedDict, total=False):
    """``/rx/spike``: a block of resonator spikes of one unit (or of units that heard the same), as
    columns (``spikes``)."""

    unit: str  # the one unit whose spikes these are, or
    units: list[str]  # the units (two or more) that heard these same spikes
    t: float
    sample: int  # the first spike's
    samples: IntColumn  # one per spike
    channel: IntColumn  # one per spike: an index into names
    names: list[str]


class DecodeRecord(TypedDict):
    """``/rx/decode``: one decoded code (logs before ``/rx/decodes``; ``decode_rows`` reads a
    ``/rx/decodes`` record as these)."""

    unit: str
    turn: int
    sender: str
    addressee: str
    channel: str
    kind: str
    code: str
    value: str
    margin: float
    t: float
    accepted: bool


class DecodesRecord(TypedDict, total=False):
    """``/rx/decodes``: a unit's decodes of one block, as columns (``decodes``); or the
    decodes two or more units made alike (``units``, sorted, in place of ``unit``:
    ``group_log.GroupLog``)."""

    unit: str
    units: list[str]
    t: Required[float]  # the last decode's time: the record's log time
    turn: Required[IntColumn]  # each decode's, in the order the unit made them
    # names, or (with ``names``, ``kinds`` and ``codes``) indexes into those tables
    sender: Required[list[str] | IntColumn]
    addressee: Required[list[str] | IntColumn]
    channel: Required[list[str] | IntColumn]
    kind: Required[list[str] | IntColumn]
    code: Required[list[str] | IntColumn]
    margin: Required[FloatColumn]
    times: Required[FloatColumn]
    accepted: Required[BoolColumn]
    names: Sequence[str]  # the units sender, addressee and channel index
    kinds: Sequence[str]  # the kinds kind indexes
    codes: Sequence[str]  # the code names code indexes


# a record's tables of names, when its name columns hold indexes: (units, kinds, codes)
DecodeTables = tuple[Sequence[str], Sequence[str], Sequence[str]]


# the columns of a /rx/decodes record, in the order ``decodes`` takes a row's fields
DECODE_COLUMNS = (
    "turn", "sender", "addressee", "channel", "kind", "code", "margin", "times", "accepted",
)  # fmt: skip


class RelationsRecord(TypedDict):
    """``/unit/relations``: a unit's relationship table, what it sent, and the polynomial it
    derives."""

    unit: str
    t: float
    sent: dict[str, str]
    installed: Required[dict[str, str]]
    polynomial: Required[str | None]
    p4: Required[list[str] | None]


class InfluencesRecord(TypedDict):
    """``/unit/influences``: the influence table a unit holds, per influence round."""

    unit: str
    t: float
    influences: Required[dict[str, Alternative]]
    round: int


class DecisionRecord(TypedDict):
    """``/unit/decision``: a unit's forward task on one subject and its choice, per round."""

    unit: str
    subject: str
    t: float
    interval: list[Alternative] | None
    frustrated: bool
    choice: Alternative | None
    A: Alternative | None
    B: Alternative | None
    canonical: str
    round: int


class GoalRecord(TypedDict):
    """``/unit/goal``: a goal-driven unit's influence on a target, chosen by the inverse task."""

    unit: str
    t: float
    round: int
    turn: int
    target: str
    want: list[Alternative]
    mode: str
    heard: dict[str, Alternative]
    predicted: dict[str, Alternative]
    rule: str
    solutions: int | None
    reached: int | None
    of: int | None
    value: Alternative | None
    sent: Alternative
    reason: str


class RepairCounts(TypedDict):
    """What a unit's repair did (``/unit/report`` ``repair``; docs/protocol.md, "Repair")."""

    requests: int  # requests it sent
    repeats: int  # repeats it sent, as a sender that heard a request
    copies: int  # copies it read of payloads it was unsure of
    missing: int  # copies it asked for and heard nothing of (its request was not heard)
    resolved: int  # payloads it was unsure of and then sure of
    unresolved: int  # payloads still unsure after the last block: taken as they read best
    seconds: float  # simulated time the repair blocks add to the run


class SteeredFields(TypedDict):
    """A steered unit's share of its run's changes (``rgtbus.steering.steered_in``): the
    influences injected into its sends, [turn, alternative], and the relation codes it was
    made to hold, [sender, receiver, alliance?, first round decided with it]."""

    injected: list[list[int]]
    held: list[list[Any]]


class UnitReportRecord(TypedDict, total=False):
    """``/unit/report``: what a unit knows at the end of its run, its share of the run summary.
    Its tables (``RELATIONS_FIELDS``, ``influences``) are left out where the unit's last
    ``/unit/relations`` (``/unit/influences``) record holds them as they are at its end
    (``slim_report``; ``full_report`` puts them back)."""

    unit: Required[str]
    installed: dict[str, str]
    polynomial: str | None
    p4: list[str] | None
    sent_relations: dict[str, str]
    influences: dict[str, Alternative]
    result: Required[dict[str, Any]]
    decisions: Required[list[DecisionRow]]
    sends: Required[list[list[Any]]]
    sent_influences: Required[list[dict[str, str]]]
    failure: Required[str | None]
    failed_at: Required[int | None]
    done_at: Required[int | None]
    mind_error: Required[str | None]
    repair: RepairCounts  # with [protocol] repair = "arq" only
    steered: SteeredFields  # a steered run's units only (``--control``)


class RunRecord(TypedDict):
    """``/run``: how the run ended, written last."""

    scenario: str
    seed: int
    outcome: Any
    agree: bool
    sim_seconds: float
    error: str | None


class SceneUpdateRecord(TypedDict):
    """``/scene``: a ``foxglove.SceneUpdate`` (Foxglove's own schema, JSON-encoded) holding one
    unit's entity: its sphere, its label and its half of each link (``scene_update``)."""

    deletions: list[dict[str, Any]]
    entities: list[dict[str, Any]]


class MediumRecord(TypedDict):
    """``/medium``: one window of the shared medium that carries a pulse."""

    window: int
    t: float
    sample_rate: float
    samples: list[float]


class TraceRecord(TypedDict):
    """``/trace/<unit>``: a unit's resonator states at one sample."""

    unit: str
    sample: int
    t: float
    y: list[float]
    x: list[float]


# A steered run's changes (``rgtbus.steering``), each at the window boundary it was applied or
# refused at: ``seq`` orders those of one sample; ``who`` is the client; ``text`` says what it
# did, or why not ("refused: ...").
ControlParameterRecord = TypedDict(
    "ControlParameterRecord",
    {
        "t": float,
        "sample": int,
        "seq": int,
        "who": str,
        "name": str,
        "value": Any,  # as the client sent it
        "from": Any,  # the value before (None: refused before it was read)
        "to": Any,  # the value after (the value before, if refused)
        "applied": bool,
        "text": str,
    },
)


class ControlServiceRecord(TypedDict):
    """``/control/service``: a service call on a steered run."""

    t: float
    sample: int
    seq: int
    who: str
    service: str
    request: dict[str, Any]  # its arguments, as the client sent them
    applied: bool
    text: str
    round: int | None  # influence: the round it changed; relation: the first round decided with it
    turn: int | None  # influence: the schedule turn whose code it changed
    value: int | None  # influence: the alternative (a mask of the universe's actions)
    until: int | None  # step: the sample the run pauses at
    state: dict[str, Any] | None  # mark: every unit's state there


KEPT_BYTES = 4096  # of what a client sent, a control record keeps at most this much JSON


def loggable(value: Any, limit: int = KEPT_BYTES) -> Any:
    """What a control record keeps of a value a client sent (anything): plain JSON (bytes as
    hex, tuples as lists, keys as text, a number that is not finite and any other object as
    its text), or, when that is longer than ``limit`` bytes, a line saying how long it was: a
    client can neither break the log nor fill it."""

    def plain(v: Any) -> Any:
        if v is None or isinstance(v, bool | int | str):
            return v
        if isinstance(v, float):
            return v if math.isfinite(v) else repr(v)
        if isinstance(v, bytes | bytearray):
            return bytes(v).hex()
        if isinstance(v, list | tuple):
            return [plain(x) for x in v]
        if isinstance(v, Mapping):
            return {str(k): plain(x) for k, x in v.items()}
        return repr(v)

    out = plain(value)
    size = len(json.dumps(out))
    return out if size <= limit else f"(a value of {size} bytes, not kept)"


def control_parameter(
    t: float, sample: int, seq: int, who: str, name: str, value: Any, before: Any, after: Any,
    applied: bool, text: str,
) -> ControlParameterRecord:  # fmt: skip
    """A ``/control/parameter`` record: ``name`` set to ``value`` by ``who`` at ``sample``
    (what a client sent kept as ``loggable``)."""
    return {
        "t": t, "sample": sample, "seq": seq, "who": str(loggable(who, 200)),
        "name": str(loggable(name, 200)), "value": loggable(value), "from": before,
        "to": after, "applied": applied, "text": text,
    }  # fmt: skip


def control_service(
    t: float, sample: int, seq: int, who: str, service: str, request: Any,
    applied: bool, text: str, *, rnd: int | None = None, turn: int | None = None,
    value: int | None = None, until: int | None = None, state: dict[str, Any] | None = None,
) -> ControlServiceRecord:  # fmt: skip
    """A ``/control/service`` record: ``service`` called by ``who`` with ``request`` (a JSON
    object; anything else is kept as ``{"sent": ...}``; what a client sent kept as
    ``loggable``)."""
    kept = loggable(request)
    return {
        "t": t, "sample": sample, "seq": seq, "who": str(loggable(who, 200)),
        "service": str(loggable(service, 200)),
        "request": kept if isinstance(kept, dict) else {"sent": kept}, "applied": applied,
        "text": text, "round": rnd, "turn": turn, "value": value, "until": until,
        "state": state,
    }  # fmt: skip


# topic -> its record type (``/trace/<unit>`` is a family: ``TraceRecord``)
RECORD_TYPES: dict[str, type] = {
    MEDIUM: MediumRecord,
    TX_PULSE: PulseBlockRecord,
    RX_SPIKE: SpikeRecord,
    RX_DECODE: DecodeRecord,
    RX_DECODES: DecodesRecord,
    UNIT_RELATIONS: RelationsRecord,
    UNIT_INFLUENCES: InfluencesRecord,
    UNIT_DECISION: DecisionRecord,
    UNIT_GOAL: GoalRecord,
    UNIT_REPORT: UnitReportRecord,
    RUN: RunRecord,
    SCENE: SceneUpdateRecord,
    CONTROL_PARAMETER: ControlParameterRecord,
    CONTROL_SERVICE: ControlServiceRecord,
}


def message_ref(
    turn: int, kind: str, code: str, sender: str, addressee: str, block: int = 0
) -> MessageRef:
    """Which message a pulse belongs to (``id``: two per turn, the ID-code first; a repair
    block's request and repeat carry the turn's payload id and their ``block``)."""
    ref: MessageRef = {
        "id": turn * 2 + (kind != "id"),
        "kind": kind,
        "code": code,
        "sender": sender,
        "addressee": addressee,
    }
    if block:
        ref["block"] = block
    return ref


def pulse(
    unit: str, channel: str, omega: float, magnitude: float, tau: float, sample: int,
    message: MessageRef,
) -> PulseRecord:  # fmt: skip
    """A ``/tx/pulse`` record: ``unit`` sends ``magnitude`` on ``channel`` (its ω) at ``sample``
    (its time on a clock of period ``tau``), part of ``message``."""
    return {
        "unit": unit,
        "channel": channel,
        "omega": omega,
        "magnitude": magnitude,
        "t": time_of(sample, tau),
        "sample": sample,
        "message": message,
    }


def spikes(
    unit: str | Sequence[str],
    tau: float,
    samples: IntColumn,
    channel: IntColumn,
    names: list[str],
) -> SpikeRecord:
    """Every spike of ``unit`` in one block, as columns, one entry per spike: at
    ``samples[i]`` the resonator of ``names[channel[i]]`` fired. Numpy arrays are written as
    they are (the encoder takes them whole: a large run's receivers fire millions of times).
    ``unit`` a list of two or more names: each of those units heard exactly these spikes in
    the block (units of one process on a noise-free medium hear alike), one record for all
    (``units``, in sorted order: the merge of several processes' logs makes their records of
    one block one record so, ``merge.shared_blocks``); a list of one is that unit's own
    record. ``spike_units`` reads either.
    Logs before it held the block as ``samples`` and per-sample lists of names, and before
    that one record a sample; ``read.spike_table`` reads them all."""
    first = int(samples[0])
    record: SpikeRecord
    if isinstance(unit, str) or len(unit) == 1:
        record = {"unit": unit if isinstance(unit, str) else unit[0]}
    elif not unit:
        raise BadInput("a block of spikes of no unit")
    else:
        record = {"units": sorted(unit)}
    record.update(
        {
            "t": time_of(first, tau),
            "sample": first,
            "samples": samples,
            "channel": channel,
            "names": names,
        }
    )
    return record


def decode(
    unit: str, turn: int, sender: str, addressee: str, channel: str, kind: str, code: str,
    margin: float, t: float, accepted: bool,
) -> DecodeRecord:  # fmt: skip
    """A ``/rx/decode`` record: what ``unit`` read at ``t`` of a code of ``sender`` to
    ``addressee`` on ``channel``, its margin and whether it took it."""
    return {
        "unit": unit,
        "turn": turn,
        "sender": sender,
        "addressee": addressee,
        "channel": channel,
        "kind": kind,
        "code": code,
        "value": code,
        "margin": float(margin),
        "t": t,
        "accepted": accepted,
    }


DecodeFields = tuple[int, str, str, str, str, str, float, float, bool]


def decodes(unit: str, rows: Sequence[DecodeFields]) -> DecodesRecord:
    """A unit's decodes of one wake (at least one), as columns (``/rx/decodes``): each row is
    (turn, sender, addressee, channel, kind, code, margin, t, accepted), the fields of
    ``decode``. One record a wake, not one a decode: a run of n units decodes 4n²(n−1)
    codes. Logs before it held one ``/rx/decode`` a decode; ``decode_rows`` reads both."""
    return decodes_of_columns(unit, [list(c) for c in zip(*rows, strict=True)])


def decodes_of_columns(
    unit: str | list[str], cols: Sequence[Any], tables: DecodeTables | None = None
) -> DecodesRecord:
    """``decodes`` from its nine columns, in the order of a row (``unit`` a list of two or more
    names, sorted: the decodes each of them made, alike); a unit that takes a batch of
    decodes as arrays gives them so: turn, margin, times and accepted may be numpy arrays,
    which the encoder writes whole, with no Python object per decode. ``tables``: sender,
    addressee and channel are indexes into its units, kind into its kinds and code into its
    codes (integer arrays: a 50-unit run decodes 490,000 codes, five names each, and the
    names cost more to make, write and compress than the rest of the record). The columns
    are the record's own from then on (they are not copied)."""
    if not len(cols) or not len(cols[7]):
        raise BadInput(f"{RX_DECODES} of {unit!r}: no decode to log")
    margin = cols[6]
    record: DecodesRecord = {
        **({"unit": unit} if isinstance(unit, str) else {"units": unit}),  # type: ignore[typeddict-item]
        "t": float(cols[7][-1]),
        "turn": cols[0],
        "sender": cols[1],
        "addressee": cols[2],
        "channel": cols[3],
        "kind": cols[4],
        "code": cols[5],
        "margin": margin if hasattr(margin, "dtype") else [float(m) for m in margin],
        "times": cols[7],
        "accepted": cols[8],
    }
    if tables is not None:  # a tuple as it is: the unit's own, the same in every record
        for key, table in zip(DECODE_TABLES, tables, strict=True):
            record[key] = table if type(table) is tuple else list(table)  # type: ignore[literal-required]
    return record


# the columns of names that a record with tables holds as indexes: the table each indexes
NAMED_COLUMNS = {"sender": "names", "addressee": "names", "channel": "names", "kind": "kinds",
                 "code": "codes"}  # fmt: skip
DECODE_TABLES = ("names", "kinds", "codes")  # the order of ``DecodeTables``


# a report's fields that a /unit/relations record holds: (report field, relations field)
RELATIONS_FIELDS = (("sent_relations", "sent"), ("installed", "installed"),
                    ("polynomial", "polynomial"), ("p4", "p4"))  # fmt: skip


def slim_report(
    report: UnitReportRecord,
    relations: Mapping[str, Any] | None,
    influences: Mapping[str, Any] | None,
) -> UnitReportRecord:
    """``report`` less the tables that the unit's last ``/unit/relations`` record
    (``relations``) and ``/unit/influences`` record (``influences``) hold as they are (all
    of the relations fields or none, so a reader never mixes the two)."""
    out = dict(report)
    if relations is not None and all(
        report.get(mine) == relations.get(theirs) for mine, theirs in RELATIONS_FIELDS
    ):
        for mine, _ in RELATIONS_FIELDS:
            del out[mine]
    if influences is not None and report.get("influences") == influences.get("influences"):
        del out["influences"]
    return cast(UnitReportRecord, out)


def full_report(
    report: Mapping[str, Any],
    relations: Mapping[str, Any] | None,
    influences: Mapping[str, Any] | None,
) -> dict[str, Any]:
    """A ``/unit/report`` as read, with the tables ``slim_report`` left out put back from the
    unit's last ``/unit/relations`` and ``/unit/influences`` records (empty where the log
    holds none: a log cut before them)."""
    out = dict(report)
    if "sent_relations" not in out:
        rel = relations or {}
        for mine, theirs in RELATIONS_FIELDS:
            out[mine] = rel.get(theirs, {} if mine in ("sent_relations", "installed") else None)
    if "influences" not in out:
        out["influences"] = (influences or {}).get("influences", {})
    return out


def relations(
    unit: str, t: float, sent: dict[str, str], installed: dict[str, str],
    polynomial: str | None, p4: Sequence[str] | None,
) -> RelationsRecord:  # fmt: skip
    """A ``/unit/relations`` record: the relations ``unit`` sent and the table it installed, with
    its polynomial (and P4, when there is one)."""
    return {
        "unit": unit,
        "t": t,
        "sent": sent,
        "installed": installed,
        "polynomial": polynomial,
        "p4": None if p4 is None else list(p4),
    }


def influences(unit: str, t: float, table: dict[str, Alternative], rnd: int) -> InfluencesRecord:
    """An ``/unit/influences`` record: the influence table ``unit`` holds at ``t`` in round
    ``rnd``."""
    return {"unit": unit, "t": t, "influences": table, "round": rnd}


def decision(
    unit: str, subject: str, t: float, fields: Mapping[str, Any], canonical: str, rnd: int
) -> DecisionRecord:
    """``fields``: ``rgtbus.mind.decision_fields`` (interval, frustrated, choice, A, B)."""
    return {
        "unit": unit,
        "subject": subject,
        "t": t,
        "interval": fields["interval"],
        "frustrated": fields["frustrated"],
        "choice": fields["choice"],
        "A": fields["A"],
        "B": fields["B"],
        "canonical": canonical,
        "round": rnd,
    }


def goal(
    unit: str, t: float, rnd: int, turn: int, target: str, want: list[Alternative], mode: str,
    heard: dict[str, Alternative], predicted: dict[str, Alternative], rule: str,
    solutions: int | None, reached: int | None, of: int | None, value: Alternative | None,
    sent: Alternative, reason: str,
) -> GoalRecord:  # fmt: skip
    """A ``/unit/goal`` record: the influence on ``target`` a goal-driven unit chose at ``t`` (the
    inverse task's rule, solutions and how many it reached) and why."""
    return {
        "unit": unit,
        "t": t,
        "round": rnd,
        "turn": turn,
        "target": target,
        "want": want,
        "mode": mode,
        "heard": heard,
        "predicted": predicted,
        "rule": rule,
        "solutions": solutions,
        "reached": reached,
        "of": of,
        "value": value,
        "sent": sent,
        "reason": reason,
    }


def run_record(summary: Mapping[str, Any]) -> RunRecord:
    """How the run ended (``/run``), from its summary."""
    return {
        "scenario": summary["scenario"],
        "seed": summary["seed"],
        "outcome": summary["outcome"],
        "agree": summary["agree"],
        "sim_seconds": summary["sim_seconds"],
        "error": summary["error"],
    }


def medium_window(window: int, t: float, sample_rate: float, samples: list[float]) -> MediumRecord:
    """A ``/medium`` record: window ``window`` of the medium from ``t``, its samples."""
    return {"window": window, "t": t, "sample_rate": sample_rate, "samples": samples}


def trace(unit: str, sample: int, t: float, y: list[float], x: list[float]) -> TraceRecord:
    """A ``/trace/<unit>`` record: ``unit``'s resonator states ``y`` and ``x`` at ``sample``."""
    return {"unit": unit, "sample": sample, "t": t, "y": y, "x": x}
