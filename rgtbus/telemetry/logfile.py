"""A run's log file: created with its recorder, finished and closed, each failure one line
(``RgtbusError``). Used by ``rgtbus.run`` and every command that writes a log."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import stat
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

from rgtbus.errors import BadInput, IOFailure, RgtbusError

if TYPE_CHECKING:
    from rgtbus.telemetry.live import LiveView
    from rgtbus.telemetry.mcap_recorder import McapRecorder


def _lock_holder(fd: int) -> str:
    """Who holds the lock on the file ``fd`` is open on: " (pid N)" from /proc/locks (Linux),
    else nothing."""
    try:
        st = os.fstat(fd)
        here = (os.major(st.st_dev), os.minor(st.st_dev), st.st_ino)
        with open("/proc/locks") as f:
            for line in f:
                # "1: FLOCK  ADVISORY  WRITE 12345 08:01:123456 0 EOF" (a waiter has "->")
                fields = line.split()
                if len(fields) >= 6 and fields[1] == "FLOCK":
                    major, minor, inode = fields[5].split(":")
                    if (int(major, 16), int(minor, 16), int(inode)) == here:
                        return f" (pid {fields[4]})"
    except (OSError, ValueError):
        pass
    return ""


def _open_locked(path: Path) -> BinaryIO:
    """``path`` opened for writing, held by an exclusive lock for as long as it is open (so a
    second run given the same log is refused before it writes a byte), then emptied. A device
    or another file that is not a regular one (``/dev/full``, ``/proc/version``) is opened as
    it is: it holds no run's log."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o666)
    try:
        if stat.S_ISREG(os.fstat(fd).st_mode):
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                if exc.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
                    pass  # a file system without locks: written unguarded
                elif exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise
                else:
                    raise BadInput(
                        f"log {str(path)!r} is being written by another run"
                        f"{_lock_holder(fd)}: give this run another --log"
                    ) from None
            if os.fstat(fd).st_size:  # only now: the other run's file was never touched
                os.ftruncate(fd, 0)
        # unbuffered: the recorder hands over whole flushes, and after a failed write (a
        # full disk) no buffered bytes of it may reach the file later
        stream = os.fdopen(fd, "wb", buffering=0)
        stream.name = str(path)  # errors name the path
        return stream
    except BaseException:
        os.close(fd)
        raise


def refuse_if_being_written(path: str | os.PathLike[str], what: str) -> None:
    """One line (RgtbusError) when a run is writing ``path`` now: it holds the lock every log
    writer takes (``_open_locked``). ``what`` names the file in the line (``-o``, an input).
    A path that does not exist, or is no regular file, is nobody's log."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return  # nothing there (or unreadable: opening it for what it is used for says so)
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise BadInput(
                    f"{what} {str(path)!r}: a run is writing it{_lock_holder(fd)}; wait for "
                    "its end (or stop it)"
                ) from None
            return  # a file system without locks: nothing to tell
        fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def open_log(path: Path, live: LiveView | None = None) -> tuple[BinaryIO, McapRecorder]:
    """The log file and its recorder, or one line (RgtbusError) if it cannot be written: a
    directory, no permission, a target that takes no bytes (``/proc/version``, a full disk),
    a log another run is writing (each run holds an exclusive lock on its log file until
    ``close_log``). ``live``: a live view offered every message too."""
    from rgtbus.telemetry.mcap_recorder import McapRecorder

    for parent in path.parents:  # mkdir says "File exists" for a file on the way
        if parent.exists():
            if not parent.is_dir():
                raise IOFailure(f"cannot write log {str(path)!r}: {str(parent)!r} is a file")
            break
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        stream = _open_locked(path)  # closed by close_log (which ends the lock)
    except OSError as exc:
        raise IOFailure(f"cannot write log {str(path)!r}: {exc.strerror}") from None
    try:
        return stream, McapRecorder(stream, live=live)
    except RgtbusError:
        with contextlib.suppress(OSError):  # its buffer cannot be flushed: already reported
            stream.close()
        raise


def close_log(stream: BinaryIO, recorder: McapRecorder, *, finished: bool = True) -> None:
    """Finish the log and close its file; a write that fails here is one line too.
    ``finished=False``: the run was interrupted, the log ends cut (``McapRecorder.close``)."""
    try:
        recorder.close(finished=finished)
    finally:
        if recorder.failed:
            with contextlib.suppress(OSError):  # the recorder's error says it already
                stream.close()
        else:
            try:
                stream.close()
            except OSError as exc:
                raise IOFailure(
                    f"cannot write log {str(stream.name)!r}: {exc.strerror}"
                ) from None
