"""Shares with confidence: the Wilson score interval of a binomial proportion, the one rule every
curve with intervals uses (sweep plots, studies: docs/studies.md).

Of ``n`` independent runs ``k`` had the property; the share p̂ = k/n estimates its probability p.
The Wilson score interval (Wilson 1927) inverts the normal test of p̂ against p::

    lo, hi = (p̂ + z²/2n ∓ z·sqrt(p̂(1−p̂)/n + z²/4n²)) / (1 + z²/n),   z = 1.959964 (95 %)

Unlike p̂ ± z·sqrt(p̂(1−p̂)/n) it stays inside [0, 1], is not empty at k = 0 or k = n (0 of 20
gives [0, 0.161]), and covers p close to the nominal 95 % down to a few runs (Newcombe 1998,
"Two-sided confidence intervals for the single proportion", method 3: the values it tabulates
are in tests/test_stats.py).
"""

from __future__ import annotations

import math

Z95 = 1.959963984540054  # the 97.5 % quantile of N(0, 1): a two-sided 95 % interval


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float, float]:
    """The share k/n and its Wilson score interval: ``(p̂, lo, hi)``. ``ValueError`` for n < 1
    or k outside 0..n."""
    if n < 1:
        raise ValueError("no runs")
    if not 0 <= k <= n:
        raise ValueError(f"{k} successes of {n} runs")
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    # at k = 0 (k = n) the bound is 0 (1) exactly: rounding may leave it a hair off
    lo = 0.0 if k == 0 else max(0.0, centre - half)
    hi = 1.0 if k == n else min(1.0, centre + half)
    return p, lo, hi


def mean_interval(values: list[float], z: float = Z95) -> tuple[float, float, float]:
    """Mean of ``values`` and its interval (lo, hi), mean ± z·s/sqrt(n); one value: the value
    three times."""
    n = len(values)
    m = math.fsum(values) / n
    if n < 2:
        return m, m, m
    sd = math.sqrt(math.fsum((v - m) ** 2 for v in values) / (n - 1))
    return m, m - z * sd / math.sqrt(n), m + z * sd / math.sqrt(n)
