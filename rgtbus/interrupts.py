"""Commands stopped by a signal: SIGTERM (a launcher, a scheduler, a supervisor) like Ctrl-C.

A Python signal handler runs between two bytecodes of the main thread, wherever that is. When
that is inside a weakref callback or a ``__del__`` (the import system's module locks have one),
the ``KeyboardInterrupt`` it raises cannot propagate: Python prints "Exception ignored in ..."
with a traceback and goes on, and the stop is lost. A unit process that lost its stop ran on
until the launcher gave it up as stalled.

:func:`interrupted_by` installs a handler that raises ``KeyboardInterrupt`` and an unraisable
hook that, for such a lost interrupt, sends the same signal again a moment later: its handler
runs then, outside the callback, where the command catches it. Nothing is printed for it. The
signal is sent again by a thread started beforehand (the hook puts the stop on a queue and
returns: it never waits on a thread's start, which on a busy machine can outlast the moment),
and a signal that lands inside the hook itself is held and sent again in the same way.
"""

from __future__ import annotations

import contextlib
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from types import CodeType, FrameType
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    # what sys.unraisablehook is: it is handed what could not be raised (the type exists for
    # the type checker only)
    UnraisableHook = Callable[[sys.UnraisableHookArgs], object]

_last_signal: int | None = None  # the signal whose KeyboardInterrupt is under way
_AGAIN_SECONDS = 0.01  # a lost stop is raised again this much later (time to leave the hook)
# Stops to raise again, for the resender thread. SimpleQueue.put is reentrant (safe in a signal
# handler, a weakref callback or a __del__) and never waits on another thread.
_resends: queue.SimpleQueue[int] = queue.SimpleQueue()
_resender: threading.Thread | None = None
_resender_lock = threading.Lock()


def last_signal() -> int | None:
    """The signal of the latest stop ``interrupted_by`` raised (None: none yet)."""
    return _last_signal


def _raise_interrupt(signum: int, frame: FrameType | None) -> None:
    """The handler: ``KeyboardInterrupt`` in the main thread, except inside the unraisable hook
    (a stop raised there is lost, and the hook's own words "Exception ignored in
    sys.unraisablehook" printed): there it asks for the signal again and returns."""
    global _last_signal
    _last_signal = signum
    if _inside_the_hook(frame):
        _resends.put(signum)
        return None
    raise KeyboardInterrupt


def _hook_unraisable(default: UnraisableHook) -> UnraisableHook:
    def hook(unraisable: sys.UnraisableHookArgs) -> None:
        # A signal landing anywhere in here is held by the handler (it sees this frame), so no
        # stop is raised inside the hook and nothing here waits on a thread.
        sig = _last_signal
        if (
            sig is not None
            and isinstance(unraisable.exc_value, KeyboardInterrupt)
            and signal.getsignal(sig) is _raise_interrupt
        ):
            _resends.put(sig)
        else:
            default(unraisable)

    return hook


_HOOK_CODE: CodeType = _hook_unraisable(sys.__unraisablehook__).__code__


def _inside_the_hook(frame: FrameType | None) -> bool:
    while frame is not None:
        if frame.f_code is _HOOK_CODE:
            return True
        frame = frame.f_back
    return False


def _resend_forever() -> None:
    """The resender: each stop lost in a callback (or held in the hook) is sent to the main
    thread again a moment later, from here, while its handler is still ours. One that lands in
    a callback again is lost again, and sent again."""
    while True:
        sig = _resends.get()
        time.sleep(_AGAIN_SECONDS)
        main = threading.main_thread().ident
        if main is not None and signal.getsignal(sig) is _raise_interrupt:
            with contextlib.suppress(ProcessLookupError, OSError):
                signal.pthread_kill(main, sig)


def _start_resender() -> None:
    """Start the resender once a process (again after a fork), here, outside any callback:
    starting a thread waits for it, which the hook must never do."""
    global _resender
    with _resender_lock:
        if _resender is None or not _resender.is_alive():
            _resender = threading.Thread(
                target=_resend_forever, name="rgtbus-resend-stop", daemon=True
            )
            _resender.start()


@contextlib.contextmanager
def interrupted_by(*signals: signal.Signals) -> Iterator[None]:
    """While inside: each of ``signals`` raises ``KeyboardInterrupt`` in the main thread, and one
    raised where Python cannot propagate it (a weakref callback, a ``__del__``, the unraisable
    hook itself) is raised again after it rather than lost. Handlers and hook are put back on
    leaving. Outside the main thread (where no handler can be set) nothing changes."""
    if signal.getsignal(signal.SIGINT) is None:  # pragma: no cover - embedded interpreters
        yield
        return
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _start_resender()
    try:
        old = {sig: signal.signal(sig, _raise_interrupt) for sig in signals}
    except ValueError:  # pragma: no cover - not the main interpreter
        yield
        return
    old_hook = sys.unraisablehook
    sys.unraisablehook = _hook_unraisable(old_hook)
    try:
        yield
    finally:
        sys.unraisablehook = old_hook
        for sig, handler in old.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
