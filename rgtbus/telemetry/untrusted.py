"""What a log holds is not to be trusted, even with every CRC valid (a file written by hand or
tampered with): the one rule for how deep a message may nest (``message``, ``depth_error``)
and the one way text from a log reaches a terminal (``printable``). Every reader of a log
(``rgtbus info``, ``cat``, ``scenario``, ``replay`` and ``rgtbus.open_log``) goes through them.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TextIO

import numpy as np
import orjson

from rgtbus.errors import BadLog, RgtbusError
from rgtbus.telemetry import topics
from rgtbus.telemetry.blocks import schema_of
from rgtbus.telemetry.records import LogMessage
from rgtbus.timebase import seconds

# The deepest a message may nest (lists and objects): what rgtbus's own writer (orjson) writes
# at most. orjson reads 1024 levels, but what walks a message after it (json.dumps, ==, a
# recursive check, orjson.dumps when a message is compared) gives up sooner, with a
# RecursionError or a TypeError; rgtbus's own records nest 6 deep at most.
MAX_DEPTH = 254


def depth_error(value: Any, limit: int = MAX_DEPTH) -> str | None:
    """``nests deeper than N levels`` when ``value`` (decoded JSON) holds lists and objects
    more than ``limit`` deep, else None. Walked with a stack, not by recursion."""
    stack: list[tuple[Any, int]] = [(value, 1)]
    while stack:
        node, depth = stack.pop()
        if isinstance(node, dict):
            children: Any = node.values()
        elif isinstance(node, list):
            children = node
        else:
            continue
        if depth > limit:
            return f"nests deeper than {limit} levels"
        stack.extend((v, depth + 1) for v in children if isinstance(v, dict | list))
    return None


def text_depth(data: bytes) -> int:
    """How deep the lists and objects of a JSON text nest (0: a bare value), from its bytes:
    the brackets outside its strings counted as arrays, not walked object by object (a
    100-unit run's tables hold 10,000 entries each). Exact for valid JSON: a quote is escaped
    by an odd run of backslashes before it, and nothing else opens or closes a string."""
    b = np.frombuffer(data, dtype=np.uint8)
    if not b.size:
        return 0
    slash = np.concatenate(([False], b == 0x5C, [False]))
    edges = np.flatnonzero(slash[1:] != slash[:-1])  # run starts and ends, alternately
    starts, ends = edges[0::2], edges[1::2]
    escaped = np.zeros(b.size, dtype=bool)
    odd = ends[(ends - starts) % 2 == 1]  # the byte after an odd run of backslashes
    escaped[odd[odd < b.size]] = True
    quote = (b == 0x22) & ~escaped
    inside = np.cumsum(quote) % 2 == 1  # in a string (its opening quote included)
    step = np.zeros(b.size, dtype=np.int32)
    step[((b == 0x5B) | (b == 0x7B)) & ~inside] = 1
    step[((b == 0x5D) | (b == 0x7D)) & ~inside] = -1
    return int(np.cumsum(step).max(initial=0))


def message(
    topic: str,
    t_ns: int,
    data: Any,
    label: str,
    check: bool = True,
    tables: topics.SharedTables | None = None,
) -> Any:
    """A message as a reader may use it: decoded and, with ``check``, checked against its
    topic's schema (``topics.checked_message``), and no deeper than ``MAX_DEPTH``. Not JSON,
    breaking its schema or nesting deeper: RgtbusError naming the log, topic and log time.
    A hot topic's block nests nothing: it is decoded and checked as it is read."""
    if schema_of(topic) is not None:
        return topics.checked_message(topic, t_ns, data, label, check, tables)
    if isinstance(data, bytes | bytearray | memoryview):
        data = bytes(data)
        # no JSON nests deeper than it has brackets: most messages need no count
        deep = data.count(b"[") + data.count(b"{") > MAX_DEPTH
    else:
        deep = True
    if deep:
        # before the schema check, whose walk compares values (==, which recurses)
        decoded = topics.checked_message(topic, t_ns, data, label, check=False)
        if isinstance(data, bytes):  # JSON (it parsed): its brackets tell
            why = None
            if text_depth(data) > MAX_DEPTH:
                why = f"nests deeper than {MAX_DEPTH} levels"
        else:
            why = depth_error(decoded)
        if why is not None:
            where = printable(f"{label}: message on {topic} at t = {seconds(t_ns):.3f} s")
            raise BadLog(f"{where} {why}")
        data = decoded
    return topics.checked_message(topic, t_ns, data, label, check, tables)


# Unicode's bidi controls (U+202A-U+202E, U+2066-U+2069) are format characters (Cf), as are
# the zero-width ones: str.isprintable says no to them, as to C0 and C1 controls, DEL and line
# and paragraph separators.


def printable(text: Any) -> str:
    """``text`` (made a str) safe to print on a terminal: every character that is not
    printable (C0 and C1 controls, DEL, escape sequences' ESC, ``\\r``, ``\\b``, tabs and
    newlines, bidi overrides and other format characters) written as ``repr`` writes it
    (``\\x1b``, ``\\r``, ``\\u202e``); letters of every script, and spaces, kept as they are.
    Anything read from a log goes through it before it reaches a terminal: a log cannot
    forge lines on the screen."""
    s = text if isinstance(text, str) else str(text)
    if s.isprintable():
        return s
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in s)


@contextlib.contextmanager
def printable_errors() -> Iterator[None]:
    """An ``RgtbusError`` raised meanwhile goes on with its text ``printable``: an error may
    quote a log (a topic, a field, a value)."""
    try:
        yield
    except RgtbusError as e:
        text = str(e)
        if text.isprintable():
            raise
        raise BadLog(printable(text)) from None


class _PrintableLines:
    """A text stream that writes every line ``printable`` (the newlines between kept)."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream

    def write(self, text: str) -> int:
        self.stream.write("\n".join(printable(part) for part in text.split("\n")))
        return len(text)

    def flush(self) -> None:
        self.stream.flush()


@contextlib.contextmanager
def printable_lines() -> Iterator[None]:
    """What is printed meanwhile (stdout and stderr) goes out ``printable`` line by line: a
    report whose every value comes from a log (``rgtbus replay``'s timeline) can forge no
    line but by a newline in a value, which the report escapes itself where it may hold one."""
    out, err = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = _PrintableLines(out), _PrintableLines(err)
    try:
        yield
    finally:
        sys.stdout, sys.stderr = out, err


# -- what a failed read was about ------------------------------------------------------------


def schema_error(messages: Iterable[LogMessage]) -> str | None:
    """The first message that breaks its topic's schema, in one line (None: all keep them).
    Run only once reading has failed: a log's messages are not validated on the way in."""
    from rgtbus.telemetry import validate

    for topic, t_ns, message in messages:
        if schema_of(topic) is not None:
            continue  # a block: checked whole as it is read (``blocks.decode_record``)
        try:
            schema = topics.schema_for(topic)
        except RgtbusError:
            continue  # a topic of someone else's: not ours to read
        message, why = _decoded(message)
        if why is not None:
            return f"message on {topic} at t = {seconds(t_ns):.3f} s {why}"
        errs = validate.errors(message, topics.load_schema(schema))
        if errs:
            return f"message on {topic} at t = {seconds(t_ns):.3f} s breaks {schema}: {errs[0]}"
    return None


def _decoded(message: Any) -> tuple[Any, str | None]:
    """A message held as JSON bytes decoded, and (None, why) when it is not JSON or nests
    deeper than any reader walks (``untrusted.depth_error``: the walks below recurse)."""
    if isinstance(message, bytes | bytearray | memoryview):
        try:
            message = orjson.loads(message)
        except ValueError:
            return None, "is not JSON"
    return message, depth_error(message)


INT64 = 2**63  # the first number no 64-bit integer holds


def _beyond_int64(value: Any, path: str = "$") -> str | None:
    """The first number in ``value`` no 64-bit integer holds (as a sample index, a count or a
    log time must be), as ``$.path: N``; None when there is none."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int | float):  # JSON's 1e30 is an integer to a schema, a float here
        inside = -INT64 <= value < INT64
        return None if inside else f"{path}: {value:g} is beyond a 64-bit integer"
    if isinstance(value, dict):
        for k, v in value.items():
            if (why := _beyond_int64(v, f"{path}.{k}")) is not None:
                return why
    elif isinstance(value, list):
        for i, v in enumerate(value):
            if (why := _beyond_int64(v, f"{path}[{i}]")) is not None:
                return why
    return None


def range_error(messages: Iterable[LogMessage]) -> str | None:
    """The first message holding a number out of every reader's range, in one line (None:
    none). Run only once reading has failed, as ``schema_error``."""
    for topic, t_ns, message in messages:
        if schema_of(topic) is not None:
            continue  # a block: its ranges checked as it is read
        message, why = _decoded(message)
        if why is not None:
            return f"message on {topic} at t = {seconds(t_ns):.3f} s {why}"
        why = _beyond_int64(message)
        if why is not None:
            return f"message on {topic} at t = {seconds(t_ns):.3f} s: {why}"
    return None


@contextlib.contextmanager
def explained(messages: Callable[[], Iterable[LogMessage]], label: str) -> Iterator[None]:
    """Reading a log whose messages break their schemas or hold numbers beyond any reader's
    range (written by hand or tampered with, with valid CRCs) fails as RgtbusError naming
    the first such message, not with a KeyError or an OverflowError from deep inside; any
    other failure is a bug and goes on as it is."""
    try:
        yield
    except (KeyError, TypeError, IndexError, AttributeError, ValueError, OverflowError) as exc:
        if isinstance(exc, RgtbusError):
            raise
        why = schema_error(messages()) or range_error(messages())
        if why is None:
            raise
        raise BadLog(f"{label}: {why}") from None
