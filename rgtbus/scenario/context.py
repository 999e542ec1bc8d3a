"""Where a scenario's value came from, for one-line errors: ``file:line: key: reason``."""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from rgtbus.errors import BadInput, RgtbusError


class Ctx:
    """The file (its name and lines) a scenario is parsed from: errors name the line of a key."""

    def __init__(self, path: str, text: str) -> None:
        self.path = path
        self.lines = text.splitlines()

    def line_of(self, section: str, key: str | None) -> int | None:
        """The line of ``key`` in ``section`` (the section's header line for no key), or None where
        it is not found."""
        header = (
            re.compile(r"\s*\[+\s*" + re.escape(section) + r"\s*\]+\s*(#.*)?\Z")
            if section
            else None
        )
        in_section = section == ""
        for i, line in enumerate(self.lines, 1):
            stripped = line.strip()
            if stripped.startswith("["):
                in_section = bool(header and header.match(line))
                if in_section and key is None:
                    return i
                continue
            if in_section and key is not None:
                m = re.match(r'\s*"?([^"=\s]+)"?\s*=', line)
                if m and m.group(1) == key:
                    return i
        if section:
            # An inline table (``codebook = {...}``): the line that opens it.
            parent, _, last = section.rpartition(".")
            found = self.line_of(parent, last)
            if found is not None:
                return found
        if section and key is not None and "." not in section:
            # Dotted keys: fall back to any line naming the key.
            for i, line in enumerate(self.lines, 1):
                if re.match(r'\s*"?' + re.escape(key) + r'"?\s*=', line):
                    return i
        return None

    def error(self, section: str, key: str | None, reason: str) -> RgtbusError:
        """A one-line error ``file:line: section.key: reason`` to raise."""
        line = self.line_of(section, key)
        where = f"{self.path}:{line}" if line else self.path
        name = ".".join(p for p in (section, key) if p)
        return BadInput(f"{where}: {name or 'scenario'}: {reason}")


def check_keys(ctx: Ctx, table: Mapping[str, Any], allowed: set[str], section: str) -> None:
    """Refuse the first key of ``table`` (in file order) that is not ``allowed``."""
    for key in table:
        if key not in allowed:
            raise ctx.error(section, key, f"unknown key (allowed: {', '.join(sorted(allowed))})")


def sub_table(ctx: Ctx, data: Mapping[str, Any], name: str) -> dict[str, Any]:
    """Top-level table ``name`` (empty when absent)."""
    value = data.get(name, {})
    if not isinstance(value, dict):
        raise ctx.error("", name, "must be a table")
    return value
