"""Exact probability that a random group is decomposable (its alliance graph is a cograph).

A group of n units is decomposable iff its alliance graph (undirected, vertices labelled 1..n)
has no induced path on four vertices (P4), i.e. it is a *cograph*. In a randomly socialised
group every unordered pair becomes an alliance independently with probability q (q = p·p when
each direction sends "alliance" with probability p), so the alliance graph is G(n, q).

Edge-counting polynomials (y marks an edge; M = C(n, 2)):

* A_n(y) = Σ_k a_n[k] y^k counts all labelled cographs on n vertices by edges,
* Conn_n(y) counts the connected ones, D_n(y) the disconnected ones.

Recursion (cographs are closed under complement and under disjoint union, and every cograph on
two or more vertices is either disconnected or has a disconnected complement, never both):

    A_0 = 1,   A_1 = 1,   Conn_1 = 1,
    for n >= 2:
        D_n(y)    = Σ_{k=1}^{n-1} C(n-1, k-1) · Conn_k(y) · A_{n-k}(y)
                    (vertex 1 lies in a component of k < n vertices; the rest is any cograph),
        Conn_n(y) = y^M · D_n(1/y)
                    (connected iff the complement is disconnected; the complement of a graph
                    with k edges has M - k edges),
        A_n(y)    = D_n(y) + Conn_n(y).

The probability that G(n, q) is a cograph is

    P_n(q) = Σ_{k=0}^{M} a_n[k] · q^k · (1 - q)^(M - k),

evaluated here exactly in integer arithmetic for the binary value of the float q and then
rounded once to the nearest float.

Totals A_n(1) for n = 1, 2, ... are 1, 2, 8, 52, 472, 5504, 78416, 1320064, ...
(2 · A000311(n) for n >= 2). For n = 4: 2^6 = 64 graphs, 4!/2 = 12 of them are labelled P4s,
every other graph is a cograph, so 52; and P_4(q) = 1 - 12 q^3 (1 - q)^3.
"""

from __future__ import annotations

import functools
import itertools
import math
import operator
from collections.abc import Iterable

__all__ = [
    "MAX_BRUTE_FORCE_N",
    "MAX_N",
    "brute_force_cograph_edge_counts",
    "cograph_count",
    "cograph_edge_counts",
    "cograph_probability",
    "is_cograph",
]

MAX_N = 60
"""Largest n accepted by the recursion."""

MAX_BRUTE_FORCE_N = 6
"""Largest n accepted by the brute-force enumeration (2^15 graphs at n = 6)."""

_Poly = tuple[int, ...]  # coefficient of y^k at index k, nonnegative ints


def _check_n(n: int, limit: int) -> int:
    try:
        value = operator.index(n)
    except TypeError:
        raise TypeError(f"n must be an integer, got {n!r}") from None
    if value < 0 or value > limit:
        raise ValueError(f"n must be in 0..{limit}, got {n!r}")
    return value


def _pack(poly: _Poly, width: int) -> int:
    """Kronecker substitution: the polynomial evaluated at y = 256^width."""
    return int.from_bytes(b"".join(c.to_bytes(width, "little") for c in poly), "little")


def _unpack(value: int, width: int) -> list[int]:
    raw = value.to_bytes((value.bit_length() + 8 * width - 1) // (8 * width) * width, "little")
    return [int.from_bytes(raw[i : i + width], "little") for i in range(0, len(raw), width)]


@functools.cache  # lru_cache(maxsize=None)
def _connected(n: int) -> _Poly:
    """Conn_n(y): labelled connected cographs on n >= 1 vertices by edge count."""
    if n == 1:
        return (1,)
    m = n * (n - 1) // 2
    d = _disconnected(n)
    padded = list(d) + [0] * (m + 1 - len(d))
    return tuple(reversed(padded))


@functools.cache  # lru_cache(maxsize=None)
def _disconnected(n: int) -> _Poly:
    """D_n(y): labelled disconnected cographs on n >= 2 vertices by edge count.

    The sum of products is formed on packed big ints (Kronecker substitution): every
    coefficient of D_n is at most D_n(1), so slots of that many bits never carry into each other.
    """
    terms = [(math.comb(n - 1, k - 1), _connected(k), _all(n - k)) for k in range(1, n)]
    bound = sum(binom * sum(conn) * sum(rest) for binom, conn, rest in terms)
    width = (bound.bit_length() + 7) // 8 or 1  # bytes per slot
    packed = sum(binom * _pack(conn, width) * _pack(rest, width) for binom, conn, rest in terms)
    return tuple(_unpack(packed, width))


@functools.cache  # lru_cache(maxsize=None)
def _all(n: int) -> _Poly:
    """A_n(y): all labelled cographs on n >= 0 vertices by edge count."""
    if n <= 1:
        return (1,)
    conn = _connected(n)
    d = _disconnected(n)
    return tuple(c + (d[i] if i < len(d) else 0) for i, c in enumerate(conn))


def cograph_edge_counts(n: int) -> list[int]:
    """a[k] = number of labelled cographs on n vertices with exactly k edges, k = 0..C(n, 2).

    Computed by the recursion in the module docstring (cached); exact Python ints.
    Raises ValueError unless 0 <= n <= 60.
    """
    n = _check_n(n, MAX_N)
    m = n * (n - 1) // 2
    a = list(_all(n))
    return a + [0] * (m + 1 - len(a))


def cograph_count(n: int) -> int:
    """Number of labelled cographs on n vertices: 1, 1, 2, 8, 52, 472, 5504, ... (n = 0, 1, ...)."""
    return sum(cograph_edge_counts(n))


def cograph_probability(n: int, q: float) -> float:
    """Probability that G(n, q) is a cograph: Σ_k a[k] q^k (1 - q)^(M - k), M = C(n, 2).

    The binary value of q is m / 2^e exactly, so the sum equals
    Σ_k a[k] m^k (2^e - m)^(M - k) / 2^(eM); that integer numerator is computed exactly and
    divided once (correctly rounded). q = 0 and q = 1 give 1.0.
    Raises ValueError for q outside [0, 1] or NaN, and for n outside 0..60.
    """
    a = cograph_edge_counts(n)
    qf = float(q)
    if math.isnan(qf) or not 0.0 <= qf <= 1.0:
        raise ValueError(f"q must be a probability in [0, 1], got {q!r}")
    num, den = qf.as_integer_ratio()  # den is a power of two
    x, y = num, den - num
    # U_j = Σ_{k<=j} a[k] x^k y^(j-k);  U_j = y·U_{j-1} + a[j]·x^j;  result U_M / den^M.
    total = 0
    xpow = 1
    for coef in a:
        total = total * y + coef * xpow
        xpow *= x
    shift = (den.bit_length() - 1) * (len(a) - 1)  # den^M = 2^(eM)
    return total / (1 << shift)


def _quads(n: int) -> list[tuple[int, int, int, int]]:
    return list(itertools.combinations(range(n), 4))


def _has_induced_p4(adj: list[int], quads: Iterable[tuple[int, int, int, int]]) -> bool:
    """adj[v] is the neighbour bitmask of v. A 4-set induces a P4 iff its induced degrees are
    1, 1, 2, 2 (the only graph on 4 vertices with that degree sequence)."""
    for a, b, c, d in quads:
        s = (1 << a) | (1 << b) | (1 << c) | (1 << d)
        degs = sorted(
            (
                (adj[a] & s).bit_count(),
                (adj[b] & s).bit_count(),
                (adj[c] & s).bit_count(),
                (adj[d] & s).bit_count(),
            )
        )
        if degs == [1, 1, 2, 2]:
            return True
    return False


def is_cograph(n: int, edges: Iterable[tuple[int, int]]) -> bool:
    """True iff the simple undirected graph on vertices 0..n-1 has no induced P4.

    Checks every 4-subset directly. Self-loops and out-of-range vertices raise ValueError;
    repeated edges are ignored.
    """
    if operator.index(n) < 0:
        raise ValueError(f"n must be >= 0, got {n!r}")
    adj = [0] * n
    for u, v in edges:
        if u == v or not (0 <= u < n and 0 <= v < n):
            raise ValueError(f"bad edge {(u, v)!r} for n = {n}")
        adj[u] |= 1 << v
        adj[v] |= 1 << u
    return not _has_induced_p4(adj, _quads(n))


def brute_force_cograph_edge_counts(n: int) -> list[int]:
    """Same as cograph_edge_counts, by enumerating all 2^C(n, 2) labelled graphs (n <= 6)."""
    n = _check_n(n, MAX_BRUTE_FORCE_N)
    pairs = list(itertools.combinations(range(n), 2))
    counts = [0] * (len(pairs) + 1)
    for mask in range(1 << len(pairs)):
        edges = [pair for i, pair in enumerate(pairs) if mask >> i & 1]
        if is_cograph(n, edges):
            counts[len(edges)] += 1
    return counts
