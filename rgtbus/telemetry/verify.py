"""Verifying a run's log: ``verify(replay, rerun)`` compares the log with a re-run of its
units on its own medium (the re-run needs the units: ``rgtbus.units.rerun``; anything with
``messages``, ``summary`` and ``complete`` will do), and ``check_medium`` checks that the
logged pulses add up, sample for sample, to the logged medium (``rgtbus.signal.pulses``).
Every disagreement is a ``Mismatch``.
"""

from __future__ import annotations

import itertools
import json
import math
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import orjson

from rgtbus.errors import RgtbusError
from rgtbus.telemetry import records as r
from rgtbus.telemetry.blocks import BLOCK_SECONDS, TRACE, decode_record
from rgtbus.telemetry.logged_medium import check_medium
from rgtbus.telemetry.message_json import encode_json, message_bytes
from rgtbus.telemetry.mismatch import Mismatch
from rgtbus.telemetry.read import Replay
from rgtbus.telemetry.record_rows import (
    decode_units,
    decodes_per_row,
    pulses_per_row,
    spike_units,
    spikes_per_sample,
)
from rgtbus.telemetry.recorder import LogMessage
from rgtbus.telemetry.verify_columns import compact, same_decodes, same_spikes
from rgtbus.timebase import ns, seconds

# Exit codes of ``rgtbus replay --verify`` (2 is every CLI's "bad input").
EXIT_VERIFIED = 0
EXIT_MISMATCH = 1
EXIT_TRUNCATED = 3  # everything read agrees, but the log ends early: the run is not verified


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


def _trace_record(m: bytes | bytearray | dict[str, Any]) -> dict[str, Any]:
    """A trace as read (its block decoded, if still its bytes)."""
    if isinstance(m, bytes | bytearray):
        return decode_record(TRACE, bytes(m), "a logged trace")
    return m


def _same_trace(logged: bytes | dict[str, Any], recomputed: dict[str, Any]) -> bool:
    """Equal as the recorder would write them: JSON floats round-trip exactly, so comparing the
    numbers equals comparing the bytes, at half the cost of encoding the re-run's traces."""
    m = _trace_record(logged)
    if set(m) != set(recomputed):
        return False
    for key, value in recomputed.items():
        if key in ("y", "x"):
            if not np.array_equal(np.asarray(m[key], dtype=float), np.asarray(value, dtype=float)):
                return False
        elif m[key] != value:
            return False
    return True


def _trace_diff(logged: dict[str, Any], recomputed: dict[str, Any]) -> list[tuple[str, Any, Any]]:
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


# what pairs a logged message with its recomputed twin: plain scalars
MessageKey = tuple[Any, ...]

# Topics a later rgtbus added: a log that holds none of them was written before (nothing there
# to hold the re-run's to), so they are compared only where the log has them.
ADDED_LATER = (r.SCENE,)

# topic -> key of a message (messages with equal keys are paired in order)
_KEYS: dict[str, Callable[[int, dict[str, Any]], MessageKey]] = {
    r.TX_PULSE: lambda t, m: (m.get("unit"), m.get("sample"), m.get("channel")),
    r.RX_SPIKE: lambda t, m: (m.get("unit"), m.get("sample")),
    r.RX_DECODE: lambda t, m: (m.get("unit"), m.get("kind"), m.get("sender"), t),
    r.UNIT_RELATIONS: lambda t, m: (m.get("unit"),),
    r.UNIT_INFLUENCES: lambda t, m: (m.get("unit"), m.get("round", 1)),
    r.UNIT_DECISION: lambda t, m: (m.get("unit"), m.get("subject"), m.get("round", 1)),
    r.UNIT_GOAL: lambda t, m: (m.get("unit"), m.get("turn")),
    r.LOG: lambda t, m: (t, m.get("name"), m.get("level"), m.get("message")),
    r.SCENE: lambda t, m: (t, *(e.get("id") for e in m.get("entities", ()))),
    # a steered run's changes: the re-run applies each again at its sample, in its order
    r.CONTROL_PARAMETER: lambda t, m: (m.get("seq"),),
    r.CONTROL_SERVICE: lambda t, m: (m.get("seq"), *sorted(m.get("state") or ())),
}


def _key_text(topic: str, key: MessageKey) -> str:
    """The paired messages' key in words (part of a mismatch's field)."""
    if topic == r.TX_PULSE:
        return f"pulse on {key[2]} at sample {key[1]}"
    if topic == r.RX_SPIKE:
        return f"spikes at sample {key[1]}"
    if topic == r.RX_DECODE:
        return f"{key[1]} from {key[2]}"
    if topic == r.UNIT_DECISION:
        return f"subject {key[1]}" if key[2] == 1 else f"subject {key[1]}, round {key[2]}"
    if topic == r.UNIT_GOAL:
        return f"goal choice of turn {key[1]}"
    if topic == r.LOG:
        return f"line {key[3]!r}"
    if topic == r.SCENE:
        return f"entity {', '.join(map(str, key[1:]))}"
    if topic in (r.CONTROL_PARAMETER, r.CONTROL_SERVICE):
        return f"change {key[0]}"
    if r.is_trace_topic(topic):
        return f"trace at {seconds(key[0]):.3f} s"
    return "table"


# (log time, message) of one topic and key, in the order logged
Paired = dict[str, dict[MessageKey, list[tuple[int, Any]]]]


def _keyed(
    messages: Iterable[LogMessage],
    units: frozenset[str],
    until_ns: int | None,
    traced: dict[str, bool],
) -> Paired:
    """The messages by topic and key (``_KEYS``; a trace's by its time), those before
    ``until_ns`` only; a ``/log`` line only if a unit wrote it. ``traced`` remembers which
    topics are traces (asked once a topic, not once a message)."""
    out: Paired = defaultdict(lambda: defaultdict(list))
    keys, log = _KEYS, r.LOG
    for topic, t, m in messages:
        if until_ns is not None and t >= until_ns:
            continue
        trace = traced.get(topic)
        if trace is None:
            trace = traced[topic] = r.is_trace_topic(topic)
        if trace:  # logged traces may be undecoded bytes: key by time
            out[topic][(t,)].append((t, m))
        elif topic in keys:
            if topic == log and m.get("name") not in units:
                continue  # not a unit's line
            out[topic][keys[topic](t, m)].append((t, m))  # keys are plain scalars
    return out


def _topic_mismatches(
    topic: str,
    logged: dict[MessageKey, list[tuple[int, Any]]],
    recomputed: dict[MessageKey, list[tuple[int, Any]]],
) -> tuple[list[Mismatch], int]:
    """The mismatches of one topic's messages, paired by key (in order within a key), and how
    many pairs were compared. Equal as the recorder encodes them, and at the same log time, is
    the same; only a pair that differs is decoded and explained."""
    trace = r.is_trace_topic(topic)
    out: list[Mismatch] = []
    compared = 0
    for key in [*logged, *(k for k in recomputed if k not in logged)]:
        xs, ys = logged.get(key, []), recomputed.get(key, [])
        for i in range(max(len(xs), len(ys))):
            compared += 1
            x = xs[i] if i < len(xs) else None
            y = ys[i] if i < len(ys) else None
            if x is not None and y is not None:
                if trace:
                    if _same_trace(x[1], y[1]):
                        continue
                elif x[0] == y[0] and encode_json(x[1]) == encode_json(y[1]):
                    continue  # the same JSON is the same message (== alone takes true for 1)
            out += _pair_mismatches(topic, key, x, y, trace)
    return out, compared


def _pair_mismatches(
    topic: str,
    key: MessageKey,
    logged: tuple[int, Any] | None,
    recomputed: tuple[int, Any] | None,
    trace: bool,
) -> list[Mismatch]:
    """How the logged and the recomputed message of one topic and key differ (either may be
    missing; a trace decoded only now, to explain)."""
    x, y = logged, recomputed
    t_ns, m = x if x is not None else y  # type: ignore[misc]  # never both missing
    if isinstance(m, bytes | bytearray):  # a trace, read only now
        m = _trace_record(m)
    unit = m.get("unit", m.get("name"))
    what = _key_text(topic, key)
    if x is None:
        return [Mismatch(topic, seconds(t_ns), unit, what, "(missing)", _json(m))]
    if y is None:
        if topic == r.LOG:  # other writers (CLI, process wrappers) add lines
            return []
        return [Mismatch(topic, seconds(t_ns), unit, what, m, "(not produced)")]
    if trace:
        diffs = _trace_diff(m, _trace_record(y[1]))
    else:
        # the re-run's message as the recorder would log it
        mine = encode_json(y[1])
        diffs = [] if encode_json(x[1]) == mine else _field_diffs(x[1], orjson.loads(mine))
        if x[0] != y[0]:
            diffs.append(("log_time", x[0], y[0]))
    whole_table = topic in (r.UNIT_RELATIONS, r.UNIT_INFLUENCES)  # the key says nothing more
    return [
        Mismatch(topic, seconds(t_ns), unit, path if whole_table else f"{what}: {path}", lv, rv)
        for path, lv, rv in diffs
    ]


# the topics a message of which is compared whole: one pair a message (``_KEYS``), and the
# blocks, counted as the rows the comparison pairs (``_compared``)
_PAIRED = frozenset(_KEYS) | {r.RX_DECODES}


def equal_messages(
    replay: Replay, recomputed: Sequence[LogMessage], units: Sequence[str]
) -> tuple[set[int], set[int], Counter[str]]:
    """The messages of a whole log that a re-run wrote byte for byte (topic, log time and
    bytes as the recorder writes them), paired in order: their positions in the log
    (``Replay.messages``' order) and in ``recomputed``, and how many records they hold, as
    ``diff_messages`` counts what it compares. What is the same needs no decoding, no
    schema and no rows: only what is left is compared field by field (a healthy log's
    messages are all the same: group50's 19,663, 3.1 M records)."""
    wanted: dict[tuple[str, int, bytes], list[int]] = {}
    for i, (topic, t, m) in enumerate(recomputed):
        if topic in _PAIRED:
            wanted.setdefault((topic, t, message_bytes(topic, m)), []).append(i)
    for waiting in wanted.values():
        waiting.reverse()  # popped in order
    names = frozenset(units)
    leave: set[int] = set()
    keep: set[int] = set()
    same: Counter[str] = Counter()
    for k, (topic, t, m) in enumerate(replay.messages()):
        if topic not in _PAIRED:
            continue
        data = m if isinstance(m, bytes) else message_bytes(topic, m)
        twins = wanted.get((topic, t, data))
        if not twins:
            continue
        i = twins.pop()
        leave.add(k)
        keep.add(i)
        counted, n = _compared(topic, recomputed[i][2], names)
        same[counted] += n
    return leave, keep, same


def _compared(topic: str, m: Mapping[str, Any], units: frozenset[str]) -> tuple[str, int]:
    """How many records ``diff_messages`` compares for message ``m`` (as recorded), and
    under which topic it counts them: a pulse a row, a decode a row a unit, spikes one
    record a unit and sample, a unit's log line one (another writer's lines are not
    compared), any other message one."""
    if topic == r.TX_PULSE:
        return topic, len(m["sample"])
    if topic == r.RX_DECODES:
        return r.RX_DECODE, len(m["times"]) * len(decode_units(m))
    if topic == r.RX_SPIKE:
        samples = np.asarray(m["samples"])
        per_sample = int(np.count_nonzero(samples[1:] != samples[:-1])) + bool(samples.size)
        return topic, per_sample * len(spike_units(m))
    if topic == r.LOG:
        return topic, int(m.get("name") in units)
    return topic, 1


def diff_messages(
    logged: Iterable[LogMessage],
    recomputed: Iterable[LogMessage],
    units: Sequence[str],
    *,
    until_ns: int | None = None,
    tau: float | None = None,
) -> tuple[list[Mismatch], Counter[str]]:
    """Pair logged and recomputed messages per topic by key; list what differs.

    /log: every line the re-run units write must be in the log; the log may hold more (the
    CLI and per-process wrappers write lines too, some under a unit's name);
    ``until_ns`` ignores messages at or after that time on both sides (a truncated log).
    ``tau``: spikes are compared one sample at a time (``spikes_per_sample``).
    Returns the mismatches and how many messages of each topic were compared.
    """
    # the hot topics compared as columns first: rows are built only to explain a difference
    hot_a: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    hot_b: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    blocks_a: Counter[tuple[str, str, int]] = Counter()
    blocks_b: Counter[tuple[str, str, int]] = Counter()
    logged = _held_hot(_block_times(logged, blocks_a, until_ns), hot_a)
    recomputed = _held_hot(_block_times(recomputed, blocks_b, until_ns), hot_b)
    rest_a, rest_b = list(logged), list(recomputed)  # (the hot ones are held as they go)
    checked: Counter[str] = Counter()
    if not hot_a[r.RX_DECODE] and not hot_b[r.RX_DECODE]:
        n = _same(same_decodes, hot_a[r.RX_DECODES], hot_b[r.RX_DECODES], until_ns)
        if n is not None:
            checked[r.RX_DECODE] = n
            del hot_a[r.RX_DECODES], hot_b[r.RX_DECODES]
    if tau is not None:
        n = _same(same_spikes, hot_a[r.RX_SPIKE], hot_b[r.RX_SPIKE], tau, until_ns)
        if n is not None:
            checked[r.RX_SPIKE] = n
            del hot_a[r.RX_SPIKE], hot_b[r.RX_SPIKE]
    logged = itertools.chain(rest_a, _messages(hot_a))
    recomputed = itertools.chain(rest_b, _messages(hot_b))
    logged, recomputed = decodes_per_row(logged), decodes_per_row(recomputed)
    logged, recomputed = pulses_per_row(logged), pulses_per_row(recomputed)
    if tau is not None:
        logged = spikes_per_sample(logged, tau)
        recomputed = spikes_per_sample(recomputed, tau)
    traced: dict[str, bool] = {}
    unitset = frozenset(units)
    a = _keyed(logged, unitset, until_ns, traced)
    b = _keyed(recomputed, unitset, until_ns, traced)
    for topic in ADDED_LATER:
        if topic not in a:  # a log of an rgtbus before the topic
            b.pop(topic, None)
    mismatches: list[Mismatch] = []
    for topic in sorted(set(a) | set(b)):
        found, checked[topic] = _topic_mismatches(topic, a.get(topic, {}), b.get(topic, {}))
        mismatches += found
    mismatches += _block_mismatches(blocks_a, blocks_b)
    mismatches.sort(key=lambda m: (m.t if m.t is not None else -1.0, m.topic))
    return mismatches, checked


# the block topics whose rows are compared at their own times: each block's log time (and the
# rows it groups) is compared as well, as the unit that logged it and its log time
_BLOCK_TIMES = frozenset({r.TX_PULSE, r.RX_DECODES})


def _block_times(
    messages: Iterable[LogMessage], out: Counter[tuple[str, str, int]], until_ns: int | None
) -> Iterator[LogMessage]:
    """``messages`` as they are, each block of ``_BLOCK_TIMES`` counted in ``out`` by (topic,
    unit, log time): a block whose own time is not its log time counts under a key no re-run
    writes (its log time less one: named as a block at the wrong time). In a cut log, only
    the blocks whose block of time surely ended before ``until_ns`` (a block's span and a
    hundredth earlier): a block of time the cut runs through may hold what its units wrote
    as they stopped, less than a whole run's (its rows are compared all the same)."""
    whole = None if until_ns is None else until_ns - ns(BLOCK_SECONDS * 1.01)
    for topic, t_ns, m in messages:
        if topic in _BLOCK_TIMES and isinstance(m, dict) and (whole is None or t_ns < whole):
            t = m.get("t")
            own = ns(t) if isinstance(t, float) and math.isfinite(t) else None
            out[(topic, str(m.get("unit")), t_ns if own == t_ns else -1 - t_ns)] += 1
        yield topic, t_ns, m


def _block_mismatches(
    logged: Counter[tuple[str, str, int]], recomputed: Counter[tuple[str, str, int]]
) -> list[Mismatch]:
    out = []
    for key in sorted(set(logged) | set(recomputed)):
        a, b = logged.get(key, 0), recomputed.get(key, 0)
        if a == b:
            continue
        topic, unit, t_ns = key
        what = "block log time" if t_ns >= 0 else "block whose t is not its log time"
        at = t_ns if t_ns >= 0 else -1 - t_ns
        out.append(Mismatch(topic, seconds(at), unit, what, f"{a} block(s)", f"{b} block(s)"))
    return out


_HOT = frozenset({r.RX_DECODES, r.RX_DECODE, r.RX_SPIKE})


def _held_hot(
    messages: Iterable[LogMessage], hot: dict[str, list[tuple[int, Any]]]
) -> Iterator[LogMessage]:
    """``messages`` less those of the hot topics, which go into ``hot`` by topic, their
    columns as arrays (``compact``)."""
    for topic, t_ns, m in messages:
        if topic in _HOT:
            hot[topic].append((t_ns, compact(m)))
        else:
            yield topic, t_ns, m


def _messages(hot: dict[str, list[tuple[int, Any]]]) -> Iterator[LogMessage]:
    for topic, held in hot.items():
        for t_ns, m in held:
            yield topic, t_ns, m


def _same(compare: Callable[..., int | None], *args: Any) -> int | None:
    """``compare``'s count, or None where it cannot say (a record it cannot read as columns:
    the rows then say what is wrong with it)."""
    try:
        return compare(*args)
    except RgtbusError:
        return None


@dataclass
class VerifyReport:
    """What ``verify`` found: the mismatches, how many messages of each topic were compared, and
    whether the log was cut short (then compared up to ``until``)."""

    label: str
    mismatches: list[Mismatch]
    checked: dict[str, int]
    truncated: bool
    note: str
    medium_windows: int  # non-silent windows of the medium in the log
    until: float | None = None  # compared up to this time (a truncated log)
    messages: int | None = None  # the log's messages, as `info` and `replay` count them

    @property
    def compared(self) -> int:
        """How many records were compared: a decode, a sample's spikes of a unit, a pulse, a
        table, a line, a medium window each (a log's record of columns holds many)."""
        return sum(self.checked.values())

    @property
    def ok(self) -> bool:
        """Verified: no mismatch, and a whole log."""
        return not self.mismatches and not self.truncated

    @property
    def exit_code(self) -> int:
        """``rgtbus replay --verify``'s exit status: EXIT_MISMATCH, EXIT_TRUNCATED or
        EXIT_VERIFIED."""
        if self.mismatches:
            return EXIT_MISMATCH
        return EXIT_TRUNCATED if self.truncated else EXIT_VERIFIED

    def verdict(self) -> str:
        """The outcome in one line. Its counts say what they count: the log's messages (as
        ``info`` and ``replay`` count them) and the records compared (each decode and each
        sample's spikes on its own, where a message holds a block of them)."""
        n = self.compared
        held = "" if self.messages is None else f"the log's {self.messages} messages; "
        counted = f"{held}{n} records compared: decodes and spikes one by one"
        if self.mismatches:
            return f"MISMATCH: {len(self.mismatches)} disagreement(s) ({counted})"
        if self.truncated and not self.until:
            return (
                "INCOMPLETE: the log was cut before any unit's spikes or decodes reached it, "
                f"so nothing the units did is verified (what was written ahead of them, the "
                f"medium and the pulses, agrees; {counted})"
            )
        if self.truncated:
            return (
                f"INCOMPLETE: every unit's messages before t = {self.until:.3f} s agree "
                f"({counted}), but the log is truncated, so the run is verified only that far"
            )
        return f"verified: every message agrees with the re-run ({counted})"

    def to_json(self) -> dict[str, Any]:
        """``rgtbus replay --verify --json``: one object."""
        return {
            "log": self.label,
            "ok": self.ok,
            "exit_code": self.exit_code,
            "verdict": self.verdict(),
            "truncated": self.truncated,
            "note": self.note,
            "until": self.until,
            "messages": self.messages,
            "compared": self.compared,
            "medium_windows": self.medium_windows,
            "checked": dict(self.checked),
            "mismatches": [asdict(m) for m in self.mismatches],
        }


def verify(replay: Replay, rerun: Any, checks: Iterable[Mismatch] = ()) -> VerifyReport:
    """Compare a log with a re-run of its units (``rgtbus.units.rerun.rerun_replay``).

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
        # what every unit logged before its bound is complete (Replay.units_until_ns)
        until_ns = replay.units_until_ns() or 0
        until = seconds(until_ns)
    mismatches += check_medium(replay, until_ns)
    logged, recomputed, same = replay.every_message(), rerun.messages, Counter[str]()
    if until_ns is None:  # a whole log: what is the same, byte for byte, is left out first
        leave, keep, same = equal_messages(replay, rerun.messages, sc.units)
        logged = replay.every_message(leave)
        recomputed = [m for i, m in enumerate(rerun.messages) if i not in keep]
    diffs, checked = diff_messages(
        logged, recomputed, sc.units, until_ns=until_ns, tau=sc.timing.tau
    )
    checked.update(same)
    mismatches += diffs
    mismatches += list(checks)
    checked[r.MEDIUM] = replay.windows
    if not replay.truncated:
        if not rerun.complete:
            mismatches.append(
                Mismatch(
                    r.MEDIUM,
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
            mismatches.append(Mismatch(r.RUN, None, None, "record", "(missing)", "present"))
        else:
            checked[r.RUN] += 1
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
                mismatches.append(Mismatch(r.RUN, run.get("sim_seconds"), None, path, lv, rv))
    mismatches.sort(key=lambda m: (m.t if m.t is not None else -1.0, m.topic))  # stable
    return VerifyReport(
        label=replay.label,
        mismatches=mismatches,
        checked=dict(checked),
        truncated=replay.truncated,
        note=replay.note,
        medium_windows=replay.windows,
        until=until,
        messages=replay.message_count(),
    )
