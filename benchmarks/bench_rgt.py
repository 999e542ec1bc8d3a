"""Inverse task: per-action solver against brute force, n = 4..12 subjects, k = 1..3 actions.

    python -m benchmarks.bench_rgt [--budget EVALUATIONS] [--seed N]

Each row builds one random decomposable group (seeded), controls its first subject towards a
reachable target interval (the ``[B, A]`` of a random influence tuple)
in mode ``exact``, and times the per-action count (best of several runs) and, where
(2^k)^(n-1) evaluations fit the budget, brute force in the same run. Goal (issue 2): n = 12,
k = 3 counts in under 50 ms, and per-action is at least 1000x faster than brute force at the
largest n brute force finishes.
"""

from __future__ import annotations

import argparse
import random
import time
from functools import partial

from rgtbus.rgt import (
    Universe,
    decision_function,
    evaluate,
    random_polynomial,
    solve_brute_force,
    solve_per_action,
)
from rgtbus.rgt.diagonal import _decision_function


def best_of(fn, repeats: int) -> tuple[float, object]:
    best = float("inf")
    out = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def build_uncached(poly, order):
    """F from scratch: decision_function caches per group, which would time a dict lookup."""
    _decision_function.cache_clear()
    return decision_function(poly, order)


def reachable_target(df, universe, subject, rng) -> tuple[int, int]:
    """The interval [B, A] some random influence tuple gives: a target with solutions."""
    for _ in range(1000):
        on = {s: rng.randrange(1 << universe.k) for s in df.order if s != subject}
        r = evaluate(df, universe, subject, on)
        if not r.frustrated:
            return r.B, r.A
    return 0, 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--budget",
        type=int,
        default=2_200_000,
        help="largest brute-force evaluation count to run (default 2.2e6: a few seconds)",
    )
    ap.add_argument("--seed", type=int, default=2026)
    args = ap.parse_args()

    header = (
        f"{'n':>3} {'k':>2} {'brute evals':>12} {'F build ms':>10} {'per-action ms':>13} "
        f"{'brute ms':>10} {'speed-up':>10} {'count':>22} agree"
    )
    print(header)
    print("-" * len(header))
    for k in (1, 2, 3):
        universe = Universe(tuple(f"x{j}" for j in range(k)))
        for n in range(4, 13):
            rng = random.Random(args.seed * 100 + n * 10 + k)
            order = [f"s{i}" for i in range(n)]
            poly = random_polynomial(order, rng)
            build_s, df = best_of(partial(build_uncached, poly, tuple(order)), 3)
            subject = order[0]
            lo, hi = reachable_target(df, universe, subject, rng)
            problem = (df, universe, subject, lo, hi, "exact")
            per_s, res = best_of(lambda p=problem: solve_per_action(*p).count, 7)
            evals = (1 << k) ** (n - 1)
            brute_ms = speed = "-"
            agree = "-"
            if evals <= args.budget:
                brute = partial(solve_brute_force, *problem, max_evaluations=args.budget)
                brute_s, sols = best_of(brute, 1)
                brute_ms = f"{brute_s * 1e3:10.1f}"
                speed = f"{brute_s / per_s:9.0f}x"
                agree = "yes" if len(sols) == res else "NO"
            print(
                f"{n:>3} {k:>2} {evals:>12} {build_s * 1e3:>10.2f} {per_s * 1e3:>13.3f} "
                f"{brute_ms:>10} {speed:>10} {res:>22} {agree}"
            )


if __name__ == "__main__":
    main()
