"""The golden logs: every shipped scenario (group50 aside) on both engines, and the paths none
takes on its own (threshold attention, traces, a paced run), give the logs recorded before the
house was rebuilt, message by message (``tests/golden.py``)."""

from __future__ import annotations

import pytest
from golden import CASES, log_digests, recorded, run_case

RECORDED = recorded()


@pytest.mark.parametrize(
    "case",
    [pytest.param(c, id=c.name, marks=[pytest.mark.slow] if c.slow else []) for c in CASES],
)
def test_log_is_golden(case) -> None:
    got = log_digests(run_case(case))
    want = RECORDED[case.name]
    changed = {k: (want.get(k), got.get(k)) for k in sorted(set(want) | set(got))
               if want.get(k) != got.get(k)}  # fmt: skip
    assert not changed, f"{case.name}: the log changed in {changed}"


def test_every_case_is_recorded() -> None:
    assert set(RECORDED) == {c.name for c in CASES}


def test_both_engines_write_the_same_messages() -> None:
    """The log is a function of the scenario and seed, not of the engine: every topic's
    messages on the dense engine are the event engine's, byte for byte (the engine is named
    in the metadata alone). Spikes that units heard alike are one record on both, whichever
    way the ears handed them over (``Recorder.advance`` joins them as ``merge`` does)."""
    pairs = [(c.name, c.name.removesuffix("-dense") + "-event") for c in CASES
             if c.name.endswith("-dense")]  # fmt: skip
    assert pairs
    for dense, event in pairs:
        a, b = RECORDED[dense], RECORDED[event]
        differ = {k for k in set(a) | set(b) if a.get(k) != b.get(k)} - {"all", "metadata"}
        assert not differ, f"{dense} and {event} differ in {sorted(differ)}"
