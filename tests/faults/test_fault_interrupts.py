"""A stop by signal is never lost: one whose KeyboardInterrupt is raised inside a weakref
callback (where Python cannot propagate it) is raised again after it (``interrupted_by``).
CI once saw a unit process lose its SIGTERM so, inside the import system's module-lock callback,
and run on until its launcher named it stalled."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import weakref

import pytest

from rgtbus import interrupts
from rgtbus.interrupts import interrupted_by


class _Thing:
    pass


def _stop_inside_a_callback(sig: signal.Signals) -> str:
    """Raise ``sig`` inside a weakref callback, then wait (bounded) for the KeyboardInterrupt
    outside it. Where it was caught: "after the callback", or "never"."""

    def callback(_ref: object) -> None:
        signal.raise_signal(sig)  # the handler runs here, inside the callback

    try:
        thing = _Thing()
        ref = weakref.ref(thing, callback)
        del thing  # the callback runs now
        assert ref() is None
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            time.sleep(0.001)
        return "never"
    except KeyboardInterrupt:
        return "after the callback"


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_stop_raised_inside_a_callback_is_raised_again_after_it(sig, capsys):
    with interrupted_by(sig):
        caught = _stop_inside_a_callback(sig)
    assert caught == "after the callback"
    assert "Exception ignored" not in capsys.readouterr().err


def test_handlers_and_the_hook_are_put_back():
    term, hook = signal.getsignal(signal.SIGTERM), sys.unraisablehook
    with interrupted_by(signal.SIGTERM):
        assert signal.getsignal(signal.SIGTERM) is not term
        assert sys.unraisablehook is not hook
    assert signal.getsignal(signal.SIGTERM) is term
    assert sys.unraisablehook is hook


def test_other_lost_errors_still_reach_the_hook_before(monkeypatch):
    seen: list[BaseException] = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: seen.append(u.exc_value))

    def callback(_ref: object) -> None:
        raise ValueError("a bug in a callback")

    with interrupted_by(signal.SIGTERM):
        thing = _Thing()
        ref = weakref.ref(thing, callback)
        del thing
        assert ref() is None
    assert [str(e) for e in seen] == ["a bug in a callback"]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_stop_landing_inside_the_hook_itself_is_raised_after_it(sig, monkeypatch, capsys):
    """The hook's own code is a place a signal can land (the re-sent one, or a second Ctrl-C):
    a KeyboardInterrupt raised there would be lost with "Exception ignored in
    sys.unraisablehook". Here the hook before ours raises the signal while it runs."""
    landed: list[bool] = []

    def before(_unraisable: sys.UnraisableHookArgs) -> None:
        signal.raise_signal(sig)  # the handler runs here, inside the hook
        landed.append(True)

    monkeypatch.setattr(sys, "unraisablehook", before)

    def callback(_ref: object) -> None:
        raise ValueError("a bug in a callback")  # to the hook: not a stop, so to `before`

    caught = "never"
    with interrupted_by(sig):
        try:
            thing = _Thing()
            ref = weakref.ref(thing, callback)
            del thing
            assert ref() is None
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline:
                time.sleep(0.001)
        except KeyboardInterrupt:
            caught = "after the hook"
    assert landed == [True]  # the handler held the stop: `before` ran on to its end
    assert caught == "after the hook"
    assert "Exception ignored" not in capsys.readouterr().err


@pytest.fixture
def cpu_hogs():
    """Busy processes, two per core: the re-sent signal may come before anything else runs."""
    hogs = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"])
        for _ in range(2 * (os.cpu_count() or 1))
    ]
    try:
        yield
    finally:
        for hog in hogs:
            hog.kill()
        for hog in hogs:
            hog.wait(timeout=30)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_no_stop_is_lost_beside_cpu_hogs_fifty_times_in_a_row(sig, cpu_hogs, monkeypatch, capsys):
    """On a busy machine: 50 stops in a row raised inside a callback, each raised again after
    it; also with no delay before the re-send, so that it lands while the hook still runs."""
    for again in (interrupts._AGAIN_SECONDS, 0.0):
        monkeypatch.setattr(interrupts, "_AGAIN_SECONDS", again)
        for _ in range(50):
            with interrupted_by(sig):
                assert _stop_inside_a_callback(sig) == "after the callback"
    assert "Exception ignored" not in capsys.readouterr().err
