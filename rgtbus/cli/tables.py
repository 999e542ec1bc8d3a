"""Terminal tables for the commands' text output, rendered by ``tabulate`` (plain text: no
colours, no box lines, so a table reads the same on a terminal, in a pipe and in a file).

``table_lines`` is one table; ``fitted_table_lines`` gives up the columns when they do not fit
the terminal; ``wrapped_table_lines`` splits a wide one into blocks of columns that fit (a matrix
of 12 units does not fit 80 columns); ``relations_lines`` is the relationship table every unit
holds, as a table when it fits and one line a pair when not.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

INDENT = "  "


def terminal_width() -> int:
    """The terminal's columns (``COLUMNS`` when set; 80 in a pipe or a file)."""
    import shutil  # imported when asked: not before a run starts

    return shutil.get_terminal_size((80, 24)).columns


def table_lines(
    rows: Sequence[Sequence[Any]],
    headers: Sequence[str] = (),
    *,
    align: Sequence[str] | None = None,
    indent: str = INDENT,
) -> list[str]:
    """``rows`` under ``headers`` as aligned lines, two spaces between columns, each line
    indented by ``indent`` and without trailing spaces. ``align``: per column ``"left"``,
    ``"right"`` or ``"center"`` (default left). Cells are shown as given (``"0"`` stays text).
    The headers are aligned as their columns are, and widen them only by their own length."""
    from tabulate import tabulate  # slow to import: only for a command that prints a table

    body = [list(headers)] if headers else []
    body += [list(r) for r in rows]
    if not body:
        return []
    ncols = max(len(r) for r in body)
    text = tabulate(
        body,
        tablefmt="plain",
        disable_numparse=True,
        colalign=tuple(align) if align is not None else ("left",) * ncols,
        missingval="",
    )
    return [(indent + line).rstrip() for line in text.splitlines()]


def plain_width(
    rows: Sequence[Sequence[Any]], headers: Sequence[str] = (), *, indent: str = INDENT
) -> int:
    """The width of the widest line ``table_lines`` gives for ``rows`` under ``headers``
    (left-aligned), without rendering it: each column as wide as its widest cell, two spaces
    between columns, trailing blanks cut. Never more than the rendered width (equal for cells
    of one line each, left-aligned), so a table it finds too wide is too wide: the
    relationship tables of a large group (50 units: 1,225 pairs) are not rendered only to
    find they do not fit."""
    body = [list(headers), *rows] if headers else [list(r) for r in rows]
    if not body:
        return 0
    width = _cell_width()
    # a cell of several lines is as wide as its widest line (tabulate strips each cell)
    texts = [[[line.strip() for line in str(c).splitlines()] or [""] for c in r] for r in body]
    ncols = max(len(r) for r in texts)
    widths = [0] * ncols
    for r in texts:
        for c, cell in enumerate(r):
            widths[c] = max(widths[c], *map(width, cell))
    starts, at = [], len(indent)
    for w in widths:
        starts.append(at)
        at += w + 2
    widest = len(indent.rstrip())
    for r in texts:
        for c in range(len(r) - 1, -1, -1):
            cut = max(map(width, r[c]))
            if cut:
                widest = max(widest, starts[c] + cut)
                break
    return widest


def _cell_width() -> Callable[[str], int]:
    """How tabulate measures a cell's text: its length, or (with the ``wcwidth`` package
    installed) its display width, as tabulate's own padding does."""
    import tabulate

    if not tabulate.WIDE_CHARS_MODE:
        return len
    import importlib  # wcwidth is tabulate's optional companion, not ours: no stubs needed

    wcswidth = importlib.import_module("wcwidth").wcswidth
    return lambda text: int(wcswidth(text))


def fitted_table_lines(
    rows: Sequence[Sequence[Any]], *, width: int | None = None, indent: str = INDENT
) -> list[str]:
    """``table_lines`` of ``rows`` (no headers) when they fit ``width`` (the terminal's by
    default); else each row on its line as it comes, its cells three spaces apart (a column
    of long canonical forms would push the rest of every line off the screen)."""
    width = terminal_width() if width is None else width
    if plain_width(rows, indent=indent) <= width:
        lines = table_lines(rows, indent=indent)
        if max((len(line) for line in lines), default=0) <= width:
            return lines
    return [indent + "   ".join(str(c) for c in row if c != "") for row in rows]


def wrapped_table_lines(
    rows: Sequence[Sequence[Any]],
    headers: Sequence[str],
    *,
    width: int | None = None,
    align: Sequence[str] | None = None,
    indent: str = INDENT,
) -> list[str]:
    """``table_lines``, cut into blocks of columns that each fit ``width`` (the terminal's by
    default), the first column (the row names) repeated in every block; blocks are separated
    by an empty line. A table that fits is one block."""
    width = terminal_width() if width is None else width
    ncols = len(headers)
    if ncols <= 2 or plain_width(rows, headers, indent=indent) <= width:
        whole = table_lines(rows, headers, align=align, indent=indent)
        if ncols <= 2 or max((len(line) for line in whole), default=0) <= width:
            return whole

    def block(cols: list[int]) -> list[str]:
        return table_lines(
            [[r[c] for c in cols] for r in rows],
            [headers[c] for c in cols],
            align=None if align is None else [align[c] for c in cols],
            indent=indent,
        )

    # left-aligned cells of one line each: plain_width is the rendered width, no trial renders
    exact = (align is None or all(a == "left" for a in align)) and all(
        len(str(cell).splitlines()) <= 1 for r in rows for cell in r
    )

    def too_wide(cols: list[int]) -> bool:
        sub = [[r[c] for c in cols] for r in rows]
        if plain_width(sub, [headers[c] for c in cols], indent=indent) > width:
            return True
        return not exact and max(len(line) for line in block(cols)) > width

    out: list[str] = []
    cols = [0]
    for c in range(1, ncols):
        if len(cols) > 1 and too_wide([*cols, c]):
            out += [*([""] if out else []), *block(cols)]
            cols = [0, c]
        else:
            cols.append(c)
    out += [*([""] if out else []), *block(cols)]
    return out


def relations_lines(
    units: Sequence[str],
    tables: Mapping[str, Mapping[str, str] | None],
    *,
    missing: str | Mapping[str, str],
    extra: Mapping[str, Sequence[str]] | None = None,
    extra_headers: Sequence[str] = (),
    width: int | None = None,
) -> list[str]:
    """The relationship tables the units hold: one row a unit, one column a pair (``a-b``),
    names aligned to the longest. ``tables[u]`` None: unit ``u`` holds no table (its row says
    ``missing``, or ``missing[u]``). ``extra[u]``: more cells for unit ``u``'s row, under
    ``extra_headers``. Too wide for ``width`` (the terminal's by default): one line a pair
    instead, with the relation every unit holds (or which units hold which), then a line a
    unit for its extra cells."""
    width = terminal_width() if width is None else width
    pairs = [f"{a}-{b}" for i, a in enumerate(units) for b in units[i + 1 :]]
    extra = extra or {}

    def why(u: str) -> str:
        return f"({missing if isinstance(missing, str) else missing.get(u, 'no table')})"

    def fits(lines: list[str]) -> bool:
        return max((len(line) for line in lines), default=0) <= width

    def table(extra_cells: bool) -> list[str] | None:
        """The table (None: it cannot fit ``width``)."""
        headers = ["", *pairs, *(extra_headers if extra_cells else ())]
        rows = [
            [u, *(t.get(p, "?") for p in pairs), *(extra.get(u, ()) if extra_cells else ())]
            for u in units
            if (t := tables.get(u)) is not None
        ]
        if pairs and plain_width(rows, headers) > width:
            return None
        lines = table_lines(rows, headers)
        # a unit without a table is a row of its own, not cut to the columns
        by_unit = dict(zip([r[0] for r in rows], lines[1:], strict=True))
        name_width = max(len(u) for u in units)
        return lines[:1] + [by_unit.get(u) or f"{INDENT}{u:<{name_width}}  {why(u)}" for u in units]

    def extra_lines() -> list[str]:
        texts = {
            u: ", ".join(
                f"{h} {v}" if h else str(v) for h, v in zip(extra_headers, cells, strict=True)
            )
            for u, cells in extra.items()
            if tables.get(u) is not None and cells
        }
        if len(texts) > 1 and len(set(texts.values())) == 1 and len(texts) == len(units):
            return [f"{INDENT}every unit: {next(iter(texts.values()))}"]
        return [f"{INDENT}{u}: {texts[u]}" for u in units if u in texts]

    if all(tables.get(u) is None for u in units):
        return [f"{INDENT}{u}: {why(u)}" for u in units]
    whole = table(extra_cells=True)
    if whole is not None and (fits(whole) or not pairs):
        return whole
    narrow = table(extra_cells=False)
    if narrow is not None and fits(narrow):
        return narrow + extra_lines()
    out = []
    holders = [u for u in units if tables.get(u) is not None]
    for p in pairs:
        held: dict[str, list[str]] = {}
        for u in holders:
            held.setdefault((tables.get(u) or {}).get(p, "?"), []).append(u)
        if len(held) == 1:
            out.append([p, next(iter(held))])
        else:
            out.append([p, "; ".join(f"{rel}: {', '.join(us)}" for rel, us in held.items())])
    lines = [
        f"{INDENT}(one line a pair: a table of {len(pairs)} pairs is wider than {width} columns)",
        *table_lines(out),
    ]
    lines += [f"{INDENT}{u}: {why(u)}" for u in units if tables.get(u) is None]
    return lines + extra_lines()
