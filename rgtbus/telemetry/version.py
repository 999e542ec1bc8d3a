"""The log's format version: written first in every file rgtbus writes, checked by every reader.

Format 2 (docs/format.md) writes the hot topics as protobuf blocks; format 1 (rgtbus before it)
wrote every topic as JSON and carried no ``format`` record. A reader refuses any other format in
one line that names it and ``rgtbus convert`` (which writes format 2 from format 1).
"""

from __future__ import annotations

from collections.abc import Iterable

from rgtbus.errors import BadLog

FORMAT_RECORD = "format"  # the metadata record's name
FORMAT_NAME = "rgtbus"
FORMAT_VERSION = 2


def format_metadata() -> dict[str, str]:
    """The ``format`` metadata record every file rgtbus writes begins with."""
    return {"name": FORMAT_NAME, "version": str(FORMAT_VERSION)}


def format_of(metadata: Iterable[tuple[str, dict[str, str]]]) -> int | str:
    """The format a log's metadata records say it has: 1 when they hold no ``format`` record
    (rgtbus before format 2), else its version as written (an int when it is one)."""
    found: dict[str, str] | None = None
    for name, values in metadata:
        if name == FORMAT_RECORD:
            found = values
    if found is None:
        return 1
    version = found.get("version", "")
    return int(version) if version.isdigit() and len(version) < 6 else version


def require_format(label: str, metadata: Iterable[tuple[str, dict[str, str]]]) -> None:
    """Refuse (one line) a log of a format this reader does not read: format 1 names
    ``rgtbus convert``; a later or unknown one names itself."""
    version = format_of(metadata)
    if version == FORMAT_VERSION:
        return
    if version == 1:
        raise BadLog(
            f"{label}: an rgtbus log of format 1 (before 2: every topic JSON); this rgtbus "
            f"reads format 2: convert it with `rgtbus convert {label} -o NEW.mcap`"
        )
    from rgtbus.telemetry.untrusted import printable

    raise BadLog(
        f"{label}: an rgtbus log of format {printable(repr(version))}; this rgtbus reads "
        f"format {FORMAT_VERSION} (and converts format 1)"
    )
