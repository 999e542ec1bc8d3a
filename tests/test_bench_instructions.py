"""The scale benchmark's instruction counts (issue 38): the run and the NumPy reference's two
sections, each counted alone in a process run under callgrind."""

from __future__ import annotations

import shutil

import pytest

pytestmark = [
    pytest.mark.slow,  # two processes under callgrind, ~15 s each
    pytest.mark.skipif(
        shutil.which("valgrind") is None or shutil.which("callgrind_control") is None,
        reason="needs valgrind (callgrind)",
    ),
]


def test_each_section_is_counted_alone():
    from benchmarks.bench_scale import callgrind_counts

    small, large = callgrind_counts(4), callgrind_counts(6)
    for counts in (small, large):
        assert {"run", "ref_bank", "ref_decode"} <= set(counts)
        assert all(v > 0 for v in counts.values())
        # each dump starts from zero: counts that ran on would put the run inside the decode
        assert counts["ref_decode"] < counts["run"]
    assert large["run"] > small["run"]  # more units, more work
    assert large["ref_bank"] > small["ref_bank"]
