"""The medium as a log holds it: its windows checked (``medium_windows``), its non-silent
samples (``medium_pulses``), and each sender's own pulses rebuilt (``sender_pulses``): what a
re-run of the units hears; and the verifier's check that the pulses add up to the medium
(``check_medium``)."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Protocol

import numpy as np

from rgtbus.scenario import Scenario
from rgtbus.signal.pulses import medium_sum
from rgtbus.telemetry import records as r
from rgtbus.telemetry.mismatch import Mismatch
from rgtbus.telemetry.records import MEDIUM, PulseRecord
from rgtbus.telemetry.untrusted import INT64
from rgtbus.timebase import NS_PER_SECOND, ns, seconds, time_of


class MediumLog(Protocol):
    """What ``check_medium`` reads of a log (``read.Replay`` is one)."""

    units: tuple[str, ...]
    run: Any

    @property
    def sim_seconds(self) -> float: ...

    def require_scenario(self) -> Scenario: ...

    def medium_windows(self) -> tuple[dict[int, np.ndarray], list[Mismatch]]: ...

    def sender_pulses(self) -> dict[str, tuple[np.ndarray, np.ndarray]]: ...

# Two logged times of one instant agree to within this (a log time is whole nanoseconds).
_NANOSECOND = seconds(1)


def medium_windows(
    sc: Scenario, messages: Iterable[tuple[int, Any]]
) -> tuple[dict[int, np.ndarray], list[Mismatch]]:
    """The logged medium's windows (only windows that carried a pulse are logged), with
    repeated and malformed windows reported."""
    L = sc.timing.window_samples
    ws = L / sc.timing.sample_rate
    out: dict[int, np.ndarray] = {}
    bad: list[Mismatch] = []
    for t_ns, m in messages:
        w = m["window"]
        if not (isinstance(w, int) and 0 <= w < INT64 // L):  # no sample index is there
            bad.append(Mismatch(MEDIUM, seconds(t_ns), None, "window", w, "a window index"))
            continue
        if w in out:
            bad.append(Mismatch(MEDIUM, seconds(t_ns), None, f"window {w}", "twice", "once"))
            continue
        if len(m["samples"]) != L:
            bad.append(
                Mismatch(
                    MEDIUM, seconds(t_ns), None, f"window {w} length", len(m["samples"]), L
                )
            )
            continue
        if not math.isclose(m["t"], w * ws, abs_tol=_NANOSECOND) or t_ns != ns(w * ws):
            bad.append(Mismatch(MEDIUM, seconds(t_ns), None, f"window {w} t", m["t"], w * ws))
        if m["sample_rate"] != sc.timing.sample_rate:
            bad.append(
                Mismatch(
                    MEDIUM,
                    seconds(t_ns),
                    None,
                    f"window {w} sample_rate",
                    m["sample_rate"],
                    sc.timing.sample_rate,
                )
            )
        out[w] = np.asarray(m["samples"], dtype=float)
    return out, bad


def medium_pulses(
    sc: Scenario, windows: Mapping[int, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """The logged medium as (sample indexes, values) of its non-silent samples: what every
    unit heard, bit for bit (each unit's magnitudes added up, then the units in order)."""
    L = sc.timing.window_samples
    rows, vals = [], []
    for w in sorted(windows):
        nz = np.flatnonzero(windows[w])
        rows.append(nz + w * L)
        vals.append(windows[w][nz])
    if not rows:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    return np.concatenate(rows).astype(np.int64), np.concatenate(vals)


def sender_pulses(
    units: Sequence[str], pulses: Iterable[PulseRecord]
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each unit's own transmissions, rebuilt from its logged pulses (in the order it sent
    them: the floats add up as the unit added them)."""
    rows: dict[str, list[int]] = {u: [] for u in units}
    vals: dict[str, list[float]] = {u: [] for u in units}
    for p in pulses:
        if p["unit"] in rows:
            rows[p["unit"]].append(int(p["sample"]))
            vals[p["unit"]].append(float(p["magnitude"]))
    out = {}
    for u in units:
        r = np.array(rows[u], dtype=np.int64)
        order = np.argsort(r, kind="stable")
        out[u] = (r[order], np.array(vals[u])[order])
    return out


def check_medium(replay: MediumLog, until_ns: int | None = None) -> list[Mismatch]:
    """Every logged window exactly equals the sum of the logged pulses (each unit's
    magnitudes in the order sent, then the units in order), and every window that carries
    a pulse is logged; only windows that end before ``until_ns`` when given (a truncated
    log: the medium is logged ahead of the pulses)."""
    sc = replay.require_scenario()
    L = sc.timing.window_samples
    tau = sc.timing.tau
    windows, bad = replay.medium_windows()
    parts = replay.sender_pulses()
    rows, expected = medium_sum([parts[u] for u in replay.units])
    want: dict[int, np.ndarray] = {}
    for k, v in zip(rows.tolist(), expected.tolist(), strict=True):
        if v != 0.0:
            want.setdefault(k // L, np.zeros(L))[k % L] = v
    end = replay.sim_seconds / tau if replay.run is not None else math.inf
    if until_ns is not None:
        end = min(end, seconds(until_ns) / tau - L)
    for w in sorted(set(windows) | set(want)):
        if until_ns is not None and time_of((w + 1) * L, tau) * NS_PER_SECOND > until_ns:
            continue
        logged = windows.get(w)
        exp = want.get(w, np.zeros(L))
        if logged is None:
            if w * L <= end:  # a run logs its medium up to its end
                bad.append(
                    Mismatch(
                        r.MEDIUM, time_of(w * L, tau), None, f"window {w}", "missing", "present"
                    )
                )
            continue
        for k in np.flatnonzero(logged != exp):
            bad.append(
                Mismatch(
                    r.MEDIUM,
                    time_of(w * L + int(k), tau),
                    None,
                    f"window {w} samples[{int(k)}]",
                    float(logged[k]),
                    float(exp[k]),
                )
            )
    return bad
