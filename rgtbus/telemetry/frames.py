"""A run's log as pandas DataFrames: ``rgtbus.open_log(path)`` returns a ``Log``.

Every table comes from the same reading of the log as ``rgtbus replay`` (``Replay``), and
``Log.summary()`` is the summary ``rgtbus run --json`` printed for the run, computed from the
log alone by the one summary function. Alternatives are plain Python values (sorted lists of
action names), never text to parse. See docs/api.md.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Mapping
from dataclasses import asdict
from typing import IO, TYPE_CHECKING, Any, TypeVar, cast

from rgtbus.summary import summary_json
from rgtbus.telemetry.read import Replay, explained, load_replay
from rgtbus.timebase import seconds, times_of

if TYPE_CHECKING:
    import pandas as pd

    from rgtbus.scenario import Scenario

DECISION_COLUMNS = ["round", "unit", "low", "high", "choice", "frustrated", "t", "wrong"]


_Method = TypeVar("_Method", bound=Callable[..., Any])


def _explained(method: _Method) -> _Method:
    """A ``Log`` method that reads a message breaking its schema, or a number out of range,
    raises RgtbusError naming it (``read.explained``), never a KeyError from deep inside."""

    @functools.wraps(method)
    def wrapper(self: Log, *args: Any, **kwargs: Any) -> Any:
        with explained(self.replay.contents, self.replay.label):
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
        return sorted(t for t, msgs in self.replay.by_topic.items() if msgs)

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
    def decodes(self) -> pd.DataFrame:
        """One row per decode: ``unit, t, turn, kind, sender, addressee, channel, code, value,
        margin, accepted, sent, matches`` (``value``: the code as a plain value, a list of
        action names for an influence)."""
        import pandas as pd

        rows = [asdict(d) for d in self.replay.decodes]
        sc = self.scenario
        for r in rows:
            r["value"] = _value(sc, r["kind"], r["code"])
        cols = ["unit", "t", "turn", "kind", "sender", "addressee", "channel", "code", "value",
                "margin", "accepted", "sent", "matches"]  # fmt: skip
        return pd.DataFrame(rows, columns=cols)

    @_explained
    def spikes(self) -> pd.DataFrame:
        """One row per unit, sample and channel that fired: ``unit, sample, t, channel,
        omega``."""
        import pandas as pd

        return pd.DataFrame(self.replay.spikes, columns=["unit", "sample", "t", "channel", "omega"])

    @_explained
    def transmissions(self) -> pd.DataFrame:
        """One row per code on the medium: ``turn, kind, phase, sender, addressee, channel,
        code, value, meaning, start, end, pulses`` (``pulses``: how many)."""
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
        """Every message of ``topic`` (e.g. ``"/unit/goal"``, ``"/log"``), one row each:
        ``log_time`` (integer ns), ``log_seconds``, then the message's fields."""
        import pandas as pd

        msgs = self.replay.by_topic.get(topic, [])
        rows = [{"log_time": t, "log_seconds": seconds(t), **_fields(m)} for t, m in msgs]
        return pd.DataFrame(rows)


def decisions_frame(summary: Mapping[str, Any]) -> pd.DataFrame:
    """A run summary's ``decisions`` as a DataFrame (``DECISION_COLUMNS``): what
    ``Log.decisions()`` and ``RunResult.decisions()`` both give."""
    import pandas as pd

    return pd.DataFrame(summary.get("decisions") or [], columns=DECISION_COLUMNS)


def _fields(message: Any) -> dict[str, Any]:
    return message if isinstance(message, dict) else {"data": message}


def _value(sc: Scenario | None, kind: str, code: str | None) -> Any:
    """A decoded or sent code as a plain value: an alternative as its sorted action names."""
    if sc is None or code is None or kind not in ("influence", "payload", "repeat"):
        return code
    if code in ("alliance", "conflict", "id"):
        return code
    try:
        return sc.universe.to_list(sc.universe.parse_alternative(code))
    except Exception:  # a misread that names no alternative stays as read
        return code


def open_log(source: str | os.PathLike[str] | IO[bytes]) -> Log:
    """Read a run's log (a path or a binary stream). Raises ``RgtbusError`` with one line on
    a file that is no readable rgtbus log."""
    return Log(load_replay(source))
