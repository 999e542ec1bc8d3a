import itertools
import math
import random

import pytest

from rgtbus.rgt.cographs import (
    brute_force_cograph_edge_counts,
    cograph_count,
    cograph_edge_counts,
    cograph_probability,
    is_cograph,
)

# Labelled cographs on n = 1..7 vertices (2 * A000311(n) for n >= 2).
KNOWN_TOTALS = [1, 2, 8, 52, 472, 5504, 78416]
QS = [0.0, 1e-9, 0.05, 0.25, 0.61**2, 0.5, 0.75, 0.99, 1.0 - 1e-12, 1.0]


@pytest.mark.parametrize("n", range(7))
def test_recursion_matches_brute_force(n: int) -> None:
    assert cograph_edge_counts(n) == brute_force_cograph_edge_counts(n)


def test_known_totals() -> None:
    assert [cograph_count(n) for n in range(1, 8)] == KNOWN_TOTALS
    assert [sum(brute_force_cograph_edge_counts(n)) for n in range(1, 7)] == KNOWN_TOTALS[:6]
    assert cograph_count(0) == 1
    assert cograph_count(4) == 2**6 - math.factorial(4) // 2


@pytest.mark.parametrize("n", range(13))
def test_counts_shape_and_complement_symmetry(n: int) -> None:
    a = cograph_edge_counts(n)
    m = n * (n - 1) // 2
    assert len(a) == m + 1
    assert all(isinstance(c, int) and c >= 0 for c in a)
    assert a == a[::-1]
    assert a[0] == a[m] == 1  # empty and complete graphs
    if m:
        assert a[1] == m  # one edge: always a cograph
    assert sum(a) <= 2**m


def test_is_cograph_small_cases() -> None:
    assert is_cograph(4, [(0, 1), (1, 2), (2, 3)]) is False  # P4
    assert is_cograph(4, [(0, 1), (1, 2), (2, 3), (3, 0)]) is True  # C4
    assert is_cograph(5, [(0, 1), (1, 2), (2, 3), (3, 4), (4, 0)]) is False  # C5
    assert is_cograph(4, [(1, 0), (0, 2), (0, 3)]) is True  # star
    assert is_cograph(0, []) is True
    assert is_cograph(3, []) is True
    with pytest.raises(ValueError):
        is_cograph(3, [(0, 3)])
    with pytest.raises(ValueError):
        is_cograph(3, [(1, 1)])


@pytest.mark.parametrize("n", range(4))
@pytest.mark.parametrize("q", QS)
def test_probability_is_one_up_to_three_vertices(n: int, q: float) -> None:
    assert cograph_probability(n, q) == 1.0  # a[k] = C(M, k): the binomial sum is exactly 1


@pytest.mark.parametrize("q", QS)
def test_probability_four_vertices(q: float) -> None:
    assert cograph_probability(4, q) == pytest.approx(1 - 12 * q**3 * (1 - q) ** 3, abs=1e-15)


@pytest.mark.parametrize("n", range(13))
def test_probability_range_and_endpoints(n: int) -> None:
    assert cograph_probability(n, 0.0) == 1.0
    assert cograph_probability(n, 1.0) == 1.0
    assert cograph_probability(n, 0) == 1.0
    assert cograph_probability(n, 1) == 1.0
    for q in QS:
        assert 0.0 <= cograph_probability(n, q) <= 1.0


def test_probability_uniform_is_count_over_all_graphs() -> None:
    for n in range(1, 9):
        m = n * (n - 1) // 2
        assert cograph_probability(n, 0.5) == cograph_count(n) / 2**m


def test_probability_decreases_with_n_at_fixed_q() -> None:
    q = 0.61**2
    probs = [cograph_probability(n, q) for n in range(3, 13)]
    assert all(later < earlier for earlier, later in itertools.pairwise(probs))


def test_monte_carlo_agrees_with_exact() -> None:
    rng = random.Random(0)
    n, q, trials = 6, 0.5, 4000
    pairs = list(itertools.combinations(range(n), 2))
    hits = sum(is_cograph(n, [e for e in pairs if rng.random() < q]) for _ in range(trials))
    exact = cograph_probability(n, q)
    assert exact == 5504 / 2**15
    stderr = math.sqrt(exact * (1 - exact) / trials)
    assert abs(hits / trials - exact) < 4 * stderr


@pytest.mark.parametrize("n", [-1, 61])
def test_bad_n_rejected(n: int) -> None:
    with pytest.raises(ValueError, match=str(n)):
        cograph_edge_counts(n)
    with pytest.raises(ValueError, match=str(n)):
        cograph_probability(n, 0.5)


def test_brute_force_refuses_large_n() -> None:
    with pytest.raises(ValueError, match="7"):
        brute_force_cograph_edge_counts(7)
    with pytest.raises(ValueError, match="-1"):
        brute_force_cograph_edge_counts(-1)


@pytest.mark.parametrize(("q", "text"), [(1.5, "1.5"), (-0.1, "-0.1"), (math.nan, "nan")])
def test_bad_q_rejected(q: float, text: str) -> None:
    with pytest.raises(ValueError, match=text):
        cograph_probability(5, q)
