"""The one time base: simulated seconds in the core, a sample index on a unit's own clock, and
integer nanoseconds at the MCAP boundary (``log_time``), converted here and nowhere else. Pure.

* ``sample_of(t, tau)``: the sample at (or nearest to) ``t`` seconds, ``round(t / tau)``
  (halves to even, as ``numpy.rint``); ``samples_of`` the same over an array;
* ``time_of(k, tau)``: the time of sample ``k``, ``k * tau``; ``times_of`` the same over an
  array;
* ``ns(t)`` / ``seconds(t_ns)``: seconds to integer nanoseconds and back.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

NS_PER_SECOND = 1_000_000_000


def ns(seconds: float) -> int:
    """Simulated seconds -> integer nanoseconds (the MCAP ``log_time``)."""
    return round(seconds * 1e9)


def seconds(t_ns: int) -> float:
    """Integer nanoseconds (an MCAP ``log_time``) -> seconds."""
    return t_ns / NS_PER_SECOND


def sample_of(t: float, tau: float) -> int:
    """The sample index of time ``t`` on a clock of period ``tau``: ``round(t / tau)``."""
    return round(t / tau)


def samples_of(t: np.ndarray, tau: float) -> np.ndarray:
    """``sample_of`` of every time in ``t``, as int64."""
    import numpy as np

    return np.rint(t / tau).astype(np.int64)


def time_of(k: int, tau: float) -> float:
    """The time in seconds of sample ``k`` on a clock of period ``tau``: ``k * tau``."""
    return k * tau


def times_of(k: np.ndarray, tau: float) -> np.ndarray:
    """``time_of`` of every sample index in ``k``, as float64."""
    return k * tau
