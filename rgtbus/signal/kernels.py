"""The receiver's loops: the compiled module (``_walk``, Cython), or its NumPy twin
(``walk_numpy``: the same bits, slower) where the compiled one is missing (an sdist installed
without a C compiler) or ``RGTBUS_WALK=numpy`` asks for it. Said once, on stderr, when the
twin stands in for a missing module."""

from __future__ import annotations

import os
import sys

from rgtbus.errors import BadInput

_ASKED = os.environ.get("RGTBUS_WALK", "").strip().lower()
if _ASKED not in ("", "compiled", "numpy"):
    raise BadInput(f"RGTBUS_WALK={_ASKED!r}: expected compiled or numpy (or unset)")

_TWIN = _ASKED == "numpy"
if not _TWIN:
    try:
        from rgtbus.signal._walk import (
            WalkModel,
            read_rows,
            score,
            score_many,
            score_matched,
            timings,
            walk_lanes,
        )
    except ImportError as exc:
        if _ASKED == "compiled":
            raise BadInput(f"RGTBUS_WALK=compiled: the compiled walk is missing ({exc})") from None
        _TWIN = True
        print(
            "rgtbus: the compiled receiver (rgtbus.signal._walk) is not installed (built without "
            "a C compiler?): using its NumPy twin, same results, several times slower",
            file=sys.stderr,
        )
if _TWIN:
    from rgtbus.signal.walk_numpy import (  # type: ignore[assignment]
        WalkModel,
        read_rows,
        score,
        score_many,
        score_matched,
        timings,
        walk_lanes,
    )  # fmt: skip
COMPILED = not _TWIN

__all__ = [
    "COMPILED", "WalkModel", "read_rows", "score", "score_many", "score_matched", "timings",
    "walk_lanes",
]  # fmt: skip
