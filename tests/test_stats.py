"""The Wilson score interval (rgtbus.stats), against the values Newcombe (1998, Table I, method
3) tabulates, and its edges."""

from __future__ import annotations

import pytest

from rgtbus.stats import wilson

# k, n, lower, upper (Newcombe 1998, "Two-sided confidence intervals for the single proportion:
# comparison of seven methods", Statistics in Medicine 17, Table I, method 3, to 4 places)
NEWCOMBE = [
    (81, 263, 0.2553, 0.3662),
    (15, 148, 0.0624, 0.1605),
    (0, 20, 0.0, 0.1611),
    (1, 29, 0.0061, 0.1718),
]


@pytest.mark.parametrize(("k", "n", "lo", "hi"), NEWCOMBE)
def test_the_interval_is_newcombes(k, n, lo, hi):
    p, got_lo, got_hi = wilson(k, n)
    assert p == k / n
    assert round(got_lo, 4) == lo
    assert round(got_hi, 4) == hi


def test_the_interval_is_symmetric_in_successes_and_failures():
    for n in (1, 7, 100):
        for k in range(n + 1):
            _, lo, hi = wilson(k, n)
            _, lo2, hi2 = wilson(n - k, n)
            assert lo == pytest.approx(1 - hi2, abs=1e-12)
            assert hi == pytest.approx(1 - lo2, abs=1e-12)
            assert 0.0 <= lo <= k / n <= hi <= 1.0


def test_all_or_none_reach_the_edge_exactly_and_no_runs_is_refused():
    assert wilson(0, 50)[1] == 0.0
    assert wilson(50, 50)[2] == 1.0
    with pytest.raises(ValueError, match="no runs"):
        wilson(0, 0)
    with pytest.raises(ValueError):
        wilson(3, 2)
