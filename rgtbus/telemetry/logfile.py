"""A run's log file: created with its recorder, finished and closed, each failure one line
(``RgtbusError``). Used by ``rgtbus.run`` and every command that writes a log."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

from rgtbus.errors import RgtbusError

if TYPE_CHECKING:
    from rgtbus.telemetry.live import LiveView
    from rgtbus.telemetry.recorder import McapRecorder


def open_log(path: Path, live: LiveView | None = None) -> tuple[BinaryIO, McapRecorder]:
    """The log file and its recorder, or one line (RgtbusError) if it cannot be written: a
    directory, no permission, a target that takes no bytes (``/proc/version``, a full disk).
    ``live``: a live view offered every message too."""
    from rgtbus.telemetry.recorder import McapRecorder

    for parent in path.parents:  # mkdir says "File exists" for a file on the way
        if parent.exists():
            if not parent.is_dir():
                raise RgtbusError(f"cannot write log {str(path)!r}: {str(parent)!r} is a file")
            break
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        stream = open(path, "wb")  # noqa: SIM115 - closed by close_log
    except OSError as exc:
        raise RgtbusError(f"cannot write log {str(path)!r}: {exc.strerror}") from None
    try:
        return stream, McapRecorder(stream, live=live)
    except RgtbusError:
        with contextlib.suppress(OSError):  # its buffer cannot be flushed: already reported
            stream.close()
        raise


def close_log(stream: BinaryIO, recorder: McapRecorder) -> None:
    """Finish the log and close its file; a write that fails here is one line too."""
    try:
        recorder.close()
    finally:
        if recorder.failed:
            with contextlib.suppress(OSError):  # the recorder's error says it already
                stream.close()
        else:
            try:
                stream.close()
            except OSError as exc:
                raise RgtbusError(
                    f"cannot write log {str(stream.name)!r}: {exc.strerror}"
                ) from None
