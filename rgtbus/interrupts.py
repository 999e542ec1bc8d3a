"""Commands stopped by a signal: SIGTERM (a launcher, a scheduler, a supervisor) like Ctrl-C.

A Python signal handler runs between two bytecodes of the main thread, wherever that is. When
that is inside a weakref callback or a ``__del__`` (the import system's module locks have one),
the ``KeyboardInterrupt`` it raises cannot propagate: Python prints "Exception ignored in ..."
with a traceback and goes on, and the stop is lost. A unit process that lost its stop ran on
until the launcher gave it up as stalled.

:func:`interrupted_by` installs a handler that raises ``KeyboardInterrupt`` and an unraisable
hook that, for such a lost interrupt, sends the same signal again a moment later: its handler
runs then, outside the callback, where the command catches it. Nothing is printed for it.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from types import FrameType
from typing import TYPE_CHECKING, NoReturn

if TYPE_CHECKING:
    # what sys.unraisablehook is: it is handed what could not be raised (the type exists for
    # the type checker only)
    UnraisableHook = Callable[[sys.UnraisableHookArgs], object]

_last_signal: int | None = None  # the signal whose KeyboardInterrupt is under way
_AGAIN_SECONDS = 0.01  # a lost stop is raised again this much later (time to leave the hook)


def last_signal() -> int | None:
    """The signal of the latest stop ``interrupted_by`` raised (None: none yet)."""
    return _last_signal


def _raise_interrupt(signum: int, _frame: FrameType | None) -> NoReturn:
    global _last_signal
    _last_signal = signum
    raise KeyboardInterrupt


def _hook_unraisable(default: UnraisableHook) -> UnraisableHook:
    def hook(unraisable: sys.UnraisableHookArgs) -> None:
        try:
            sig = _last_signal
            ours = sig is not None and signal.getsignal(sig) is _raise_interrupt
            if not (ours and isinstance(unraisable.exc_value, KeyboardInterrupt)):
                default(unraisable)
                return
        except KeyboardInterrupt:  # another stop, inside this hook: as lost as the first
            sig = _last_signal
        _raise_again(sig)

    return hook


def _raise_again(sig: int | None) -> None:
    """Send ``sig`` to the main thread from another thread, a moment from now: not from here,
    where its handler would run at once, still inside the hook (Python checks for signals after
    every call). One that lands in a callback again is lost again, and raised again."""
    if sig is None:
        return
    main = threading.main_thread().ident
    if main is None:  # pragma: no cover - the main thread is always started
        return
    with contextlib.suppress(RuntimeError):  # no new thread at interpreter shutdown
        timer = threading.Timer(_AGAIN_SECONDS, signal.pthread_kill, (main, sig))
        timer.daemon = True
        timer.start()


@contextlib.contextmanager
def interrupted_by(*signals: signal.Signals) -> Iterator[None]:
    """While inside: each of ``signals`` raises ``KeyboardInterrupt`` in the main thread, and one
    raised where Python cannot propagate it (a weakref callback, a ``__del__``) is raised again
    after it rather than lost. Handlers and hook are put back on leaving. Outside the main thread
    (where no handler can be set) nothing changes."""
    if signal.getsignal(signal.SIGINT) is None:  # pragma: no cover - embedded interpreters
        yield
        return
    try:
        old = {sig: signal.signal(sig, _raise_interrupt) for sig in signals}
    except ValueError:  # not the main thread
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
