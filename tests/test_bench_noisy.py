"""The noisy medium's compiled reference (benchmarks/noisy_reference.py, issue 53): it decodes
what the run's units decode, decode for decode, and its check fails on a decode that differs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from rgtbus.units.group import run_group

from rgtbus.scenario import parse_scenario
from rgtbus.telemetry import NullRecorder


@pytest.fixture(autouse=True)
def _numba() -> None:
    """The bench extra (rgtbus[bench]; make test installs it), imported by the tests that run
    (not at collection: numba would weigh on every test's process)."""
    pytest.importorskip("numba")


def _run(n: int, noise: float):
    from benchmarks.bench_scale import scale_toml

    sc = parse_scenario(scale_toml(n, "concurrent", noise=noise), f"<noisy{n}>")
    out = run_group(sc, "memory", NullRecorder())
    assert out.summary["error"] is None
    return sc, out


def test_the_reference_decodes_as_the_run_and_its_check_can_fail():
    from benchmarks.noisy_reference import compare, reference

    sc, out = _run(30, 0.02)
    ref = reference(sc, out.units, out.summary["sim_seconds"])
    got = compare(ref, out.units, out.misreads)
    assert got["decodes"] == got["ref_decodes"] == 4 * 30 * 30 * 29 and got["mismatches"] == 0
    assert ref["ref_lanes"] == 900 and ref["ref_spikes"] > 0  # every lane walked: noise spikes
    # one decode of the reference read otherwise: the check sees it
    words = ref["words"].copy()
    words[3, 5] = (words[3, 5] + 1) % len(ref["families"][ref["codes"][5][1]])
    assert compare({**ref, "words": words}, out.units, out.misreads)["mismatches"] == 1


@pytest.mark.slow
def test_a_noisy_hundred_unit_group_misreads_exactly_what_the_reference_misreads():
    """At n = 100 and σ = 0.01 the timing search over a crowded medium misreads 37,412
    payloads: every one of them is the reference's, and no other."""
    from benchmarks.noisy_reference import compare, reference

    sc, out = _run(100, 0.01)
    got = compare(reference(sc, out.units, out.summary["sim_seconds"]), out.units, out.misreads)
    assert got["misreads"] == got["ref_misreads"] > 1000 and got["mismatches"] == 0


def test_the_reference_refuses_what_it_does_not_model():
    from benchmarks.noisy_reference import reference

    sc, out = _run(6, 0.0)
    faded = dataclasses.replace(sc, channel=dataclasses.replace(sc.channel, fading="rayleigh"))
    with pytest.raises(SystemExit, match="white noise and static gains"):
        reference(faded, out.units, out.summary["sim_seconds"])
    assert np.isfinite(out.summary["sim_seconds"])
