"""What ``rgtbus info``, ``rgtbus cat`` and ``rgtbus scenario`` read from a run's MCAP log.

Every reader opens the log with ``check_log`` (rgtbus.telemetry.log_check), which checks it
whole first: a damaged log is refused in one line (``RgtbusError``), never read as if it were
whole. ``log_info`` reads a finished log from its summary section (statistics, schemas,
channels, chunk indexes, metadata index) and the ``/run`` record through the chunk index, once
its data-section and summary CRCs have vouched for every byte (a CRC-32 pass over the file, no
decompression). A log without a summary or CRCs, or cut short (the run
was killed), is scanned record by record instead, every chunk's CRC checked, and says so.

``log_cat.cat_messages`` yields messages as JSON-ready dicts, filtered by topic, unit and time
(the index narrows the chunks read). ``stored_scenario`` gives the scenario text a log was run
with, its seed set to the run's, so ``rgtbus run`` repeats the run.
"""

from __future__ import annotations

import os
import re
import struct
import tomllib
from collections import Counter
from collections.abc import Sequence
from typing import IO, Any

import numpy as np
import orjson
from mcap.reader import make_reader

from rgtbus.errors import BadLog
from rgtbus.scenario.limits import nesting_error
from rgtbus.telemetry import topics as topics_mod
from rgtbus.telemetry.log_check import CheckedLog, check_log
from rgtbus.telemetry.log_parts import logged_seed
from rgtbus.telemetry.records import (
    RUN,
)
from rgtbus.telemetry.scan import RawLog, require_run_log, scan_log
from rgtbus.telemetry.untrusted import message as checked
from rgtbus.telemetry.untrusted import printable
from rgtbus.telemetry.version import format_of
from rgtbus.timebase import seconds


def log_info(log: str | os.PathLike[str] | CheckedLog) -> dict[str, Any]:
    """Duration, messages per topic, schemas, compression, scenario, seed, version, units and
    outcome of a log (a path, or a log ``check_log`` opened; see the module docstring), and
    ``problems``: one line each, what the log says of itself that its records contradict
    (statistics that disagree with the messages indexed, two ``/run`` records, a metadata
    record written twice). Where the statistics disagree with the file, the figures given
    are those measured, record by record."""
    if not isinstance(log, CheckedLog):
        with check_log(log) as checked:
            return log_info(checked)
    if log.raw is not None:
        return _scanned_info(log, log.raw)
    label, size, summary, f = log.label, log.size, log.summary, log.stream
    stats = summary.statistics
    channels = summary.channels
    # CRCs vouch for the bytes, not for what they say: the statistics are checked against the
    # message indexes (no decompression), and the file read record by record when they differ
    held = _index_figures(f, summary, size)
    problems = _statistics_problems(log, held) if held is not None else ["?"]
    if problems:
        f.seek(0)
        raw = scan_log(f)
        require_run_log(raw)
        problems = _statistics_problems(log, _raw_figures(raw)) + _summary_twice(f, size)
        return _scanned_info(log, raw, problems)
    problems = _summary_twice(f, size)
    counts: Counter[str] = Counter()
    for cid, n in sorted(stats.channel_message_counts.items()):
        counts[channels[cid].topic] += n
    schema_of = {
        ch.topic: summary.schemas[ch.schema_id].name
        for ch in channels.values()
        if ch.schema_id in summary.schemas
    }
    runs = []
    if any(ch.topic == RUN for ch in channels.values()):
        f.seek(0)
        runs = [_run_record(label, m.log_time, m.data)
                for _, _, m in make_reader(f).iter_messages(topics=[RUN])]  # fmt: skip
    compression = sorted({c.compression or "none" for c in summary.chunk_indexes})
    return _info(
        label,
        size,
        library=log.library,
        start=stats.message_start_time if stats.message_count else None,
        end=stats.message_end_time if stats.message_count else None,
        counts=dict(counts),
        schemas=schema_of,
        compression=compression,
        chunks=len(summary.chunk_indexes),
        metadata=log.metadata,
        runs=runs,
        truncated=False,
        note="",
        problems=problems,
    )


# (messages, first log time, last log time) of each channel id
_Figures = dict[int, tuple[int, int, int]]

_MESSAGE_INDEX = 0x07
_STATISTICS = 0x0B


def _index_figures(f: IO[bytes], summary: Any, size: int) -> _Figures | None:
    """Each channel's messages as the message indexes the chunk indexes point at hold them;
    None when they cannot be read as such (an offset to no message index of that channel, a
    time outside its chunk's range): the file is then read record by record."""
    out: _Figures = {}
    for ci in summary.chunk_indexes:
        for cid, offset in ci.message_index_offsets.items():
            if not 0 <= offset <= size - 15:
                return None
            f.seek(offset)
            opcode, length, channel, n_bytes = struct.unpack("<BQHI", f.read(15))
            if (opcode, channel) != (_MESSAGE_INDEX, cid) or n_bytes % 16 or length != n_bytes + 6:
                return None
            if offset + 15 + n_bytes > size:
                return None
            times = np.frombuffer(f.read(n_bytes), dtype="<u8")[::2]  # (log time, offset) pairs
            if not len(times):
                continue
            lo, hi = int(times.min()), int(times.max())
            if lo < ci.message_start_time or hi > ci.message_end_time:
                return None
            n, first, last = out.get(cid, (0, lo, hi))
            out[cid] = (n + len(times), min(first, lo), max(last, hi))
    return out


def _raw_figures(raw: RawLog) -> _Figures:
    """Each channel's messages as the file holds them, record by record."""
    out: _Figures = {}
    for cid, t, *_ in raw.messages:
        n, first, last = out.get(cid, (0, t, t))
        out[cid] = (n + 1, min(first, t), max(last, t))
    return out


def _statistics_problems(log: CheckedLog, held: _Figures) -> list[str]:
    """Where the summary's Statistics record contradicts ``held`` (what the file holds) or the
    summary itself, in one line (empty when they agree)."""
    summary = log.summary
    stats, channels = summary.statistics, summary.channels
    total = sum(n for n, _, _ in held.values())
    said = []
    if stats.message_count != total:
        said.append(f"says {stats.message_count} messages, it holds {total}")
    per_channel = sum(stats.channel_message_counts.values())
    if per_channel != stats.message_count:
        said.append(f"its counts per channel add up to {per_channel}, not {stats.message_count}")
    wrong = []
    for cid in sorted(set(stats.channel_message_counts) | set(held)):
        says, holds = stats.channel_message_counts.get(cid, 0), held.get(cid, (0,))[0]
        if says != holds:
            topic = channels[cid].topic if cid in channels else f"channel {cid}"
            wrong.append(f"{says} on {topic}, it holds {holds}")
    if wrong:
        more = f" (and {len(wrong) - 3} more channels)" if len(wrong) > 3 else ""
        said.append("says " + ", ".join(wrong[:3]) + more)
    a, b = stats.message_start_time, stats.message_end_time
    if a > b:
        said.append(
            f"says its messages start at {seconds(a):g} s, after they end at {seconds(b):g} s"
        )
    if total:
        first = min(t for _, t, _ in held.values())
        last = max(t for _, _, t in held.values())
        if (a, b) != (first, last):
            said.append(
                f"says log time {seconds(a):g} to {seconds(b):g} s, its messages span "
                f"{seconds(first):g} to {seconds(last):g} s"
            )
    for what, says, holds in (
        ("chunks", stats.chunk_count, len(summary.chunk_indexes)),
        ("channels", stats.channel_count, len(channels)),
        ("schemas", stats.schema_count, len(summary.schemas)),
        ("metadata records", stats.metadata_count, len(log.metadata)),
    ):
        if says != holds:
            said.append(f"says {says} {what}, it holds {holds}")
    return [f"statistics disagree with the file: {'; '.join(said)}"] if said else []


def _summary_twice(f: IO[bytes], size: int) -> list[str]:
    """A Statistics record the summary section holds more than once (mcap's reader takes one
    and says nothing), in one line; the records are walked by their lengths, nothing parsed."""
    try:
        f.seek(size - 8 - 29)  # the footer: opcode, length, summary start, offset start, CRC
        opcode, _, start, _, _ = struct.unpack("<BQQQI", f.read(29))
        if opcode != 0x02 or not 0 < start < size - 8 - 29:
            return []
        f.seek(start)
        body = f.read(size - 8 - 29 - start)
    except (OSError, struct.error):
        return []
    at, seen = 0, 0
    while at + 9 <= len(body):
        opcode, length = struct.unpack_from("<BQ", body, at)
        seen += opcode == _STATISTICS
        at += 9 + length
    return [f"its summary holds {seen} Statistics records (a log writes one)"] if seen > 1 else []


def _scanned_info(log: CheckedLog, raw: RawLog, problems: Sequence[str] = ()) -> dict[str, Any]:
    label, size = log.label, log.size
    topics = {cid: ch.topic for cid, ch in raw.channels.items()}
    counts: Counter[str] = Counter(topics[cid] for cid, *_ in raw.messages)
    schema_of = {
        ch.topic: raw.schemas[ch.schema_id].name
        for ch in raw.channels.values()
        if ch.schema_id in raw.schemas
    }
    times = [t for _, t, *_ in raw.messages]
    runs = [_run_record(label, t, data) for cid, t, _, _, data in raw.messages
            if topics[cid] == RUN]  # fmt: skip
    if problems:  # a whole file whose summary is not to be believed: read without it
        note = "read record by record"
    else:
        note = raw.note or "no summary section or CRCs to check it by: read record by record"
    return _info(
        label,
        size,
        library=raw.library,
        start=min(times) if times else None,
        end=max(times) if times else None,
        counts=dict(sorted(counts.items())),
        schemas=schema_of,
        compression=[],
        chunks=None,
        metadata=raw.metadata,
        runs=runs,
        truncated=bool(raw.note),
        note=note,
        problems=list(problems),
    )


def _run_record(label: str, log_time: int, data: bytes) -> dict[str, Any]:
    run = checked(RUN, log_time, data, label, check=False)  # not JSON, or too deep: refused
    if not isinstance(run, dict):
        raise BadLog(f"{label}: its /run record is not a JSON object")
    return run


def _info(
    label: str,
    size: int,
    *,
    library: str | None,
    start: int | None,
    end: int | None,
    counts: dict[str, int],
    schemas: dict[str, str],
    compression: list[str],
    chunks: int | None,
    metadata: Sequence[tuple[str, dict[str, str]]],
    runs: list[dict[str, Any]],
    truncated: bool,
    note: str,
    problems: list[str],
) -> dict[str, Any]:
    twice = [name for name, n in Counter(name for name, _ in metadata).items() if n > 1]
    problems += [f"{len(runs)} /run records (a run writes one): its outcome is not known"] * (
        len(runs) > 1
    )
    problems += [f"metadata record {name!r} written {sum(n == name for n, _ in metadata)} times "
                 "(a log writes each once)" for name in twice]  # fmt: skip
    run = runs[0] if len(runs) == 1 else None
    by_name = dict(metadata)  # a name written twice is named in problems; the last one read
    sc = by_name.get("scenario", {})
    meta_run = by_name.get("run", {})
    units = _units_of(sc.get("text"), by_name.get("frequencies"))
    ends = unit_process_ends(by_name, units)
    return {
        "log": label,
        "bytes": size,
        "library": library,
        "format": format_of(metadata),
        "start": None if start is None else seconds(start),
        "end": None if end is None else seconds(end),
        "duration": None if start is None or end is None else seconds(end - start),
        "messages": sum(counts.values()),
        "topics": {t: {"count": n, "schema": schemas.get(t)} for t, n in counts.items()},
        "compression": compression,
        "chunks": chunks,
        "scenario": sc.get("name"),
        "scenario_path": sc.get("path"),
        "seed": logged_seed(by_name, label),
        "version": meta_run.get("version"),
        "bus": meta_run.get("bus"),
        "engine": meta_run.get("engine"),
        "run_id": meta_run.get("run_id"),
        "codebook": _codebook_name(by_name),
        "units": units,
        "outcome": None if run is None else run.get("outcome"),
        "agree": None if run is None else run.get("agree"),
        "error": run.get("error") if run is not None else _unit_error(ends),
        # A run's log ends with its /run record; a merge of unit processes' logs (rgtbus unit
        # and merge by hand) has none, and is finished when every unit's process ended "done".
        "finished": bool(runs) or _all_done(ends, units),
        "unit_processes": ends,
        "truncated": truncated,
        "note": note,
        "run_records": len(runs),
        "problems": problems,
    }


def unit_process_ends(
    metadata: dict[str, dict[str, str]], units: Sequence[str]
) -> dict[str, dict[str, str] | None]:
    """How each unit process whose log is in this one ended, by unit: its ``end.<unit>``
    record (``status`` done or ended early, ``detail``), None when it has none (killed, or
    still running when its log was read). A unit process's log names it in its ``run``
    record (``process``); a merge keeps every input's ``run`` record as ``run.K``. Empty for
    the log of a single-process run."""
    processes = [
        v["process"]
        for n, v in metadata.items()
        if (n == "run" or n.startswith("run.")) and v.get("process") in units
    ]
    return {u: metadata.get(topics_mod.unit_end_record(u)) for u in dict.fromkeys(processes)}


def _all_done(ends: dict[str, dict[str, str] | None], units: Sequence[str]) -> bool:
    return bool(units) and all(
        (ends.get(u) or {}).get("status") == topics_mod.UNIT_DONE for u in units
    )


def _unit_error(ends: dict[str, dict[str, str] | None]) -> str | None:
    """The first failure a unit process that ended "done" reports (a unit that failed on its
    own, e.g. a missing ID spike, still ends its process "done", the failure as detail)."""
    for unit, end in ends.items():
        if end and end.get("status") == topics_mod.UNIT_DONE and end.get("detail"):
            return f"unit {unit}: {end['detail']}"
    return None


def _units_of(text: str | None, frequencies: dict[str, str] | None) -> list[str]:
    """The run's units, in order: the scenario's ``units`` list; else (no scenario stored) the
    frequencies metadata, which names one channel per unit."""
    if text:
        try:
            data = tomllib.loads(text)
            units = data.get("units")
            if isinstance(units, list) and all(isinstance(u, str) for u in units):
                return list(units)
        except (tomllib.TOMLDecodeError, RecursionError):
            pass
    return list(frequencies or {})


def info_text(info: dict[str, Any]) -> str:
    """``rgtbus info`` as text, in the manner of ``mcap info``: every line printable
    (``untrusted.printable``: a log's names and values cannot forge lines on a terminal),
    what the log contradicts first."""
    lines = [f"log:         {info['log']} ({_size(info['bytes'])})"]
    lines += [f"problem:     {p}" for p in info.get("problems", ())]
    if info["note"]:
        lines.append(f"note:        {info['note']}")
    lines += [
        f"scenario:    {info['scenario']} ({info['scenario_path']})",
        f"seed:        {info['seed']}",
        f"rgtbus:      {info['version']} (bus {info['bus']}, engine {info['engine'] or 'event'}, "
        f"run {info['run_id']}), log format {info['format']}",
        f"units:       {', '.join(map(printable, info['units']))} ({len(info['units'])})",
        f"codebook:    {info.get('codebook') or '-'}",
    ]
    if info["duration"] is not None:
        lines.append(
            f"duration:    {info['duration']:.6g} s (log time {info['start']:.6g} to "
            f"{info['end']:.6g} s)"
        )
    lines.append(
        f"compression: {', '.join(info['compression']) or '-'}"
        + ("" if info["chunks"] is None else f" ({info['chunks']} chunks)")
    )
    lines.append(f"outcome:     {_outcome_text(info)}")
    lines.append(f"messages:    {info['messages']}")
    from tabulate import tabulate  # slow to import: only for the text

    rows = [[printable(topic), str(v["count"]), printable(v["schema"] or "")]
            for topic, v in info["topics"].items()]  # fmt: skip
    table = tabulate(
        rows, tablefmt="plain", disable_numparse=True, colalign=("left", "right", "left")
    )
    lines += [f"  {line}".rstrip() for line in table.splitlines()]
    return "\n".join(printable(line) for line in lines)


def _codebook_name(metadata: dict[str, dict[str, str]]) -> str | None:
    """The name of the codebook a run's codes came from (its ``codebook`` metadata record holds
    each field as JSON); None when the log does not say."""
    name = metadata.get("codebook", {}).get("name")
    if name is None:
        return None
    try:
        value = orjson.loads(name)  # no recursion, whatever the metadata holds
    except ValueError:
        return name
    return value if isinstance(value, str) else name


def _outcome_text(info: dict[str, Any]) -> str:
    ends = info.get("unit_processes") or {}
    if info.get("run_records", 0) > 1:
        return f"(not known: the log holds {info['run_records']} /run records, a run writes one)"
    if info["finished"] and info["error"]:
        return f"failed: {info['error']}"
    if info["finished"] and info["outcome"] is None and info["agree"] is None and ends:
        return (
            "every unit finished (a merge of unit logs has no /run summary: "
            f"rgtbus replay {info['log']} gives the outcome)"
        )
    if info["finished"]:
        agree = "all units agree" if info["agree"] else "units DISAGREE"
        return f"{info['outcome'] or '(no outcome rule)'}; {agree}"
    if not ends:
        return "(no /run record: the run did not finish its log)"
    said = []
    for unit, end in ends.items():
        if end is None:
            said.append(f"unit {unit}'s process did not end its log (killed?)")
        elif end.get("status") != topics_mod.UNIT_DONE:
            said.append(f"unit {unit} {end.get('status')}: {end.get('detail', '')}")
    absent = [u for u in info["units"] if u not in ends]
    if absent:
        said.append(
            f"no log of {'unit' if len(absent) == 1 else 'units'} {', '.join(absent)} in this "
            "one: rgtbus merge takes every unit's log"
        )
    return f"({'; '.join(said)})"


def _size(n: int) -> str:
    if n < 1024:
        return f"{n} B"
    size = float(n)
    for unit in ("KiB", "MiB", "GiB"):
        size /= 1024
        if size < 1024 or unit == "GiB":
            break
    return f"{size:.1f} {unit}"


# -- scenario ------------------------------------------------------------------------------------

_SEED_LINE = re.compile(r"^(\s*seed\s*=\s*)(\d+)(.*)$")


def stored_scenario(log: str | os.PathLike[str] | CheckedLog) -> str:
    """The scenario TOML a log was run with (a path, or a log ``check_log`` opened), its
    top-level seed set to the run's seed (a run with ``--seed`` stores the file's text as
    written): ``rgtbus run`` on it repeats the run."""
    if not isinstance(log, CheckedLog):
        with check_log(log) as checked:
            return stored_scenario(checked)
    label = log.label
    metadata = {name: values for name, values in log.metadata}  # a repeated name: last wins
    text = metadata.get("scenario", {}).get("text")
    if text is None:
        raise BadLog(f"{label}: stores no scenario (not an rgtbus run log, or a unit's part)")
    too_deep = nesting_error(text, f"{label}: its stored scenario")  # before tomllib recurses
    if too_deep is not None:
        raise BadLog(too_deep)
    seed = logged_seed(metadata, label)
    try:
        return printable_toml(text if seed is None else with_seed_text(text, seed))
    except (ValueError, RecursionError):  # TOMLDecodeError is a ValueError; dotted keys deep
        raise BadLog(
            f"{label}: its stored scenario (run seed {seed!r}) is not a scenario's TOML"
        ) from None


def printable_toml(text: str) -> str:
    """``text`` (TOML) as it may be printed: as it is when it holds no character a terminal
    acts on (tabs and newlines aside; CRLF ends lines as LF); else its data written anew with
    every such character escaped (``\\uXXXX``, inside the strings that hold them), so it
    still parses to the same data, comments lost. Not TOML: ValueError."""
    text = text.replace("\r\n", "\n")
    if all(c.isprintable() or c in "\n\t" for c in text):
        return text
    import tomli_w

    data = tomllib.loads(text)
    # tomli_w writes every string as a basic string, where an escape reads as its character
    out = "".join(
        c if c.isprintable() or c == "\n" else f"\\u{ord(c):04x}" if ord(c) < 0x10000
        else f"\\U{ord(c):08x}"
        for c in tomli_w.dumps(data)
    )  # fmt: skip
    if tomllib.loads(out) != data:
        raise ValueError("no printable TOML for it")
    return "# written anew by rgtbus scenario: the stored text held control characters\n" + out


def with_seed_text(text: str, seed: int) -> str:
    """``text`` with its top-level ``seed`` set to ``seed`` (comments and layout kept)."""
    data = tomllib.loads(text)
    if data.get("seed") == seed:
        return text
    lines = text.splitlines(keepends=True)
    for i, line in enumerate(lines):
        if line.lstrip().startswith("["):  # past the top level: insert before the first table
            lines.insert(i, f"seed = {seed}\n")
            break
        m = _SEED_LINE.match(line.rstrip("\n"))
        if m:
            lines[i] = f"{m.group(1)}{seed}{m.group(3)}\n"
            break
    else:
        lines.append(f"\nseed = {seed}\n")
    out = "".join(lines)
    if tomllib.loads(out).get("seed") != seed:  # a layout the line edit cannot handle
        import tomli_w

        data["seed"] = seed
        return tomli_w.dumps(data)
    return out
