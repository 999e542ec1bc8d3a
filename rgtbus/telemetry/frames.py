"""A run's log as pandas DataFrames: ``rgtbus.open_log(path)`` returns a ``Log``.

Every table comes from the same reading of the log as ``rgtbus replay`` (``Replay``), and
``Log.summary()`` is the summary ``rgtbus run --json`` printed for the run, computed from the
log alone by the one summary function. Alternatives are plain Python values, never text to
parse: in a summary (JSON) sorted lists of action names, in a DataFrame tuples of them (cells
pandas can group, sort, deduplicate and merge on). See docs/api.md.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict
from typing import IO, TYPE_CHECKING, Any, TypeVar, cast

import numpy as np
import orjson

from rgtbus.errors import BadLog
from rgtbus.summary import summary_json
from rgtbus.telemetry.decode_table import decode_table, match_sent
from rgtbus.telemetry.read import Replay, load_replay
from rgtbus.telemetry.records import RX_DECODE, RX_DECODES
from rgtbus.telemetry.untrusted import explained
from rgtbus.timebase import NS_PER_SECOND, times_of

if TYPE_CHECKING:
    import pandas as pd

    from rgtbus.scenario import Scenario

DECISION_COLUMNS = ["round", "unit", "low", "high", "choice", "frustrated", "t", "wrong"]


_Method = TypeVar("_Method", bound=Callable[..., Any])


def _explained(method: _Method) -> _Method:
    """A ``Log`` method that reads a message breaking its schema, or a number out of range,
    raises RgtbusError naming it (``untrusted.explained``), never a KeyError from deep inside."""

    @functools.wraps(method)
    def wrapper(self: Log, *args: Any, **kwargs: Any) -> Any:
        with explained(self.replay.messages, self.replay.label):
            return method(self, *args, **kwargs)

    return cast(_Method, wrapper)


class Log:
    """A run's MCAP log, read once (CRC-checked as ``rgtbus replay`` reads it).

    ``metadata`` holds the log's metadata records (scenario text, seed, bus, engine, ...);
    ``truncated`` says the log ends early (``note`` says why)."""

    def __init__(self, replay: Replay) -> None:
        self.replay = replay
        self.path = replay.label
        self.metadata: dict[str, dict[str, str]] = replay.metadata
        self.truncated: bool = replay.truncated
        self.note: str = replay.note
        self._summary: dict[str, Any] | None = None

    def __repr__(self) -> str:
        return f"Log({self.path!r}, units={list(self.units)}, truncated={self.truncated})"

    @property
    def units(self) -> tuple[str, ...]:
        """The run's units, in scenario order."""
        return self.replay.units

    @property
    def scenario(self) -> Scenario | None:
        """The scenario the run ran (from the log's metadata, with the run's seed)."""
        return self.replay.scenario

    @property
    def topics(self) -> list[str]:
        """Every topic that holds a message."""
        return sorted(self.replay.topic_counts())

    @_explained
    def summary(self) -> dict[str, Any]:
        """The run's summary: the keys and values ``rgtbus run --json`` printed (a log does
        not time its writer: ``wall_seconds`` is ``None``; ``log`` is this log)."""
        if self._summary is None:
            self._summary = summary_json(self.replay.summary())
        return dict(self._summary)

    @_explained
    def decisions(self) -> pd.DataFrame:
        """One row per unit and influence round: ``round, unit, low, high, choice,
        frustrated, t, wrong`` (``low``/``high`` the interval's ends, ``None`` when
        frustrated; ``wrong``: not what a perfect medium gives)."""
        return decisions_frame(self.summary())

    @_explained
    def decode_errors(self) -> pd.DataFrame:
        """Every misread decode, one row each in unit and decode order: ``unit, turn, kind,
        decoded, sent`` (categoricals but ``turn``, int64) and ``left_wrong`` (what the unit
        took from that turn stayed wrong); the summary's ``decode_errors`` counts them."""
        return self.replay.decode_errors().frame()

    @_explained
    def decodes(self) -> pd.DataFrame:
        """One row per decode: ``unit, t, turn, kind, sender, addressee, channel, code, value,
        margin, accepted, sent, matches`` (``value``: the alternative an influence's code
        names, a tuple of action names; None where the code names none)."""
        import pandas as pd

        if self.replay.by_topic.count(RX_DECODE):  # a log of one record a decode: as rows
            return self._decodes_of_rows()
        table = decode_table(self.replay.by_topic.each(RX_DECODES), self.replay.units)
        txs = self.replay.transmissions
        sent = match_sent(table, [(x.sender, x.kind, x.turn, x.code, x.addressee) for x in txs])
        names, kinds, codes = (
            np.array(t, dtype=object) for t in (table.names, table.kinds, table.codes)
        )
        found = sent.tx >= 0
        sc = self.scenario
        values = np.array(
            [_value(sc, kind, code) for kind in table.kinds for code in table.codes] or [None],
            dtype=object,
        )  # every (kind, code) pair's value, worked out once
        if not found.all():  # as rows give them: None where no transmission was logged
            turn: Any = [
                int(v) if f else None for v, f in zip(table.turn.tolist(), found, strict=True)
            ]
            matches: Any = [
                bool(m) if f else None for m, f in zip(sent.matches.tolist(), found, strict=True)
            ]
            sent_codes: Any = [txs[i].code if i >= 0 else None for i in sent.tx.tolist()]
        else:
            turn, matches = table.turn, sent.matches
            tx_codes = np.array([x.code for x in txs] or [""], dtype=object)
            sent_codes = tx_codes[sent.tx]
        return pd.DataFrame(
            {
                "unit": names[table.unit],
                "t": table.t,
                "turn": turn,
                "kind": kinds[table.kind],
                "sender": names[table.sender],
                "addressee": names[table.addressee],
                "channel": names[table.channel],
                "code": codes[table.code],
                "value": values[table.kind.astype(np.int64) * len(table.codes) + table.code],
                "margin": table.margin,
                "accepted": table.accepted,
                "sent": sent_codes,
                "matches": matches,
            }
        )

    def _decodes_of_rows(self) -> pd.DataFrame:
        """``decodes`` of a log that holds one record a decode (before ``/rx/decodes``)."""
        import pandas as pd

        decodes = self.replay.decodes
        sc = self.scenario
        values: dict[tuple[str, str], Any] = {}  # a run decodes the same few codes again and again
        cols: dict[str, list[Any]] = {}
        for name in ("unit", "t", "turn", "kind", "sender", "addressee", "channel", "code"):
            cols[name] = [getattr(d, name) for d in decodes]
        cols["value"] = [
            values[key] if (key := (d.kind, d.code)) in values
            else values.setdefault(key, _value(sc, d.kind, d.code))
            for d in decodes
        ]  # fmt: skip
        for name in ("margin", "accepted", "sent", "matches"):
            cols[name] = [getattr(d, name) for d in decodes]
        return pd.DataFrame(cols)

    @_explained
    def spikes(self, units: str | Sequence[str] | None = None) -> pd.DataFrame:
        """One row per unit, sample and channel that fired: ``unit, sample, t, channel,
        omega`` (``unit`` and ``channel`` categorical: a large run's receivers fire tens of
        millions of times; ``omega`` NaN where the log names no frequency). ``units``: a
        unit's name, or several, for their rows alone (a 100-unit run's spikes are 14.8 GB
        as one frame, a unit's 1 % of that); a name the log has no unit of: RgtbusError."""
        import pandas as pd

        if units is None:
            table = self.replay.spikes
        else:
            wanted = [units] if isinstance(units, str) else list(units)
            unknown = [u for u in wanted if u not in self.replay.units]
            if unknown:
                raise BadLog(
                    f"{self.path}: spikes(units=...): {unknown[0]!r} is not one of the log's "
                    f"{len(self.replay.units)} units"
                )
            table = self.replay.spikes_of(frozenset(wanted))
        who = pd.Categorical.from_codes(table.unit, categories=pd.Index(table.units))
        channels = pd.Categorical.from_codes(table.channel, categories=pd.Index(table.channels))
        return pd.DataFrame(
            copy=False,  # the table's columns as they are: a large run fires tens of millions
            data={
                "unit": who,
                "sample": table.sample,
                "t": table.t,
                "channel": channels,
                "omega": table.omega,
            },
        )

    @_explained
    def transmissions(self) -> pd.DataFrame:
        """One row per code on the medium: ``turn, kind, phase, sender, addressee, channel,
        code, value, meaning, start, end, pulses`` (``value``: the alternative an influence
        names, a tuple of action names, None for other codes; ``pulses``: how many)."""
        import pandas as pd

        sc = self.scenario
        rows = []
        for tx in self.replay.transmissions:
            r = asdict(tx)
            r["pulses"] = len(tx.pulses)
            r["value"] = _value(sc, "influence" if tx.phase == "influences" else tx.kind, tx.code)
            rows.append(r)
        cols = ["turn", "kind", "phase", "sender", "addressee", "channel", "code", "value",
                "meaning", "start", "end", "pulses"]  # fmt: skip
        return pd.DataFrame(rows, columns=cols)

    @_explained
    def medium(self) -> pd.DataFrame:
        """The shared medium's non-silent samples: ``sample, t, value`` (what every unit
        heard before its own noise)."""
        import pandas as pd

        samples, values = self.replay.medium_pulses()
        tau = self.replay.require_scenario().timing.tau
        return pd.DataFrame({"sample": samples, "t": times_of(samples, tau), "value": values})

    @_explained
    def messages(self, topic: str) -> pd.DataFrame:
        """Every message of ``topic`` (e.g. ``"/unit/goal"``, ``"/log"``, ``"/trace/a"``), one
        row each: ``log_time`` (integer ns), ``log_seconds``, then the message's fields.

        A topic left in the file until asked for (a unit's resonator traces) is read now,
        straight into columns (``message_frame``); nothing of it is kept once the frame is
        built."""
        return message_frame(self.replay.topic_messages(topic))


def decisions_frame(summary: Mapping[str, Any]) -> pd.DataFrame:
    """A run summary's ``decisions`` as a DataFrame (``DECISION_COLUMNS``): what
    ``Log.decisions()`` and ``RunResult.decisions()`` both give."""
    import pandas as pd

    rows = [{k: hashable(v) for k, v in row.items()} for row in summary.get("decisions") or []]
    return pd.DataFrame(rows, columns=DECISION_COLUMNS)


def hashable(value: Any) -> Any:
    """A value as a DataFrame cell pandas can group, sort, deduplicate and merge on: a list
    (an alternative's action names) as a tuple, nested lists too; anything else as it is."""
    if isinstance(value, list):
        return tuple(hashable(v) for v in value)
    return value


def message_frame(messages: Sequence[tuple[int, Any]]) -> pd.DataFrame:
    """``(log_time, message)`` pairs as one DataFrame: ``log_time``, ``log_seconds``, then the
    messages' fields (a field a message lacks: missing). Built a column at a time, a message
    decoded (from its JSON, where it is still bytes) and let go at a time: no row is held as
    an object, so the frame costs about its own size. (pyarrow's JSON reader, measured on a
    unit's traces, 54 MB of JSON, peaked 2.7 times as far above the messages as this.)"""
    import numpy as np
    import pandas as pd

    n = len(messages)
    times = np.fromiter((t for t, _ in messages), dtype=np.int64, count=n)
    cols: dict[str, list[Any]] = {}
    for i, (_, m) in enumerate(messages):
        for key, value in _fields(m).items():
            col = cols.get(key)
            if col is None:
                col = cols[key] = [None] * n
            col[i] = value
    if not n:
        return pd.DataFrame()
    return pd.DataFrame({"log_time": times, "log_seconds": times / NS_PER_SECOND, **cols})


def _fields(message: Any) -> dict[str, Any]:
    if isinstance(message, bytes | bytearray):
        message = orjson.loads(message)
    return message if isinstance(message, dict) else {"data": message}


def _value(sc: Scenario | None, kind: str, code: str | None) -> tuple[str, ...] | None:
    """The alternative a decoded or sent code names, as the tuple of its sorted action names;
    None for a code that names none (an ID, a relation, a request, a misread): ``code`` holds
    its text. One type a column, so pandas can group and sort on it."""
    if sc is None or code is None or kind not in ("influence", "payload", "repeat"):
        return None
    if code in ("alliance", "conflict", "id"):
        return None
    try:
        return tuple(sc.universe.to_list(sc.universe.parse_alternative(code)))
    except Exception:  # a misread that names no alternative
        return None


def open_log(source: str | os.PathLike[str] | IO[bytes]) -> Log:
    """Read a run's log (a path or a binary stream). Raises ``RgtbusError`` with one line on
    a file that is no readable rgtbus log."""
    return Log(load_replay(source))
