"""Benchmarks of the resonate-and-fire receiver: bank throughput and decoder symbol error rate.

Run: ``.venv/bin/python -m benchmarks.bench_signal [--quick]``.  Every ratio is against a
baseline measured in the same run, on the same input.
"""

from __future__ import annotations

import argparse
import math
import platform
import time

import numpy as np

from rgtbus.signal.codebook import paper_codebook
from rgtbus.signal.evaluate import noise_spike_rate, symbol_error_rate
from rgtbus.signal.plan import PAPER_OMEGAS
from rgtbus.signal.reference import reference_trajectory, simulate_python
from rgtbus.signal.resonator import ResonatorBank

TAU = 0.005


def traffic(omegas: np.ndarray, n: int, seed: int) -> np.ndarray:
    """Protocol-like medium: paper codes on random channels, one at a time, 0.5 s guard."""
    rng = np.random.default_rng(seed)
    words = list(paper_codebook().distinct_words().values())
    u = np.zeros(n)
    t = 0.001
    while True:
        w = float(omegas[rng.integers(len(omegas))])
        word = words[rng.integers(len(words))]
        idx = [round((t + j * 2 * math.pi / w) / TAU) for j in range(3)]
        if idx[-1] >= n:
            return u
        u[idx] += word
        t = idx[-1] * TAU + 0.5 + 0.5  # reaction-like gap, then the guard
        t += 2 * math.pi / w / 2  # inhibitory codes spike up to half a period later


def best_of(fn, repeat: int) -> tuple[float, object]:
    best, out = math.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def bank_omegas(c: int) -> np.ndarray:
    if c == 3:
        return np.array(PAPER_OMEGAS[:3])
    return np.geomspace(math.pi, 0.95 * 2 * math.pi, c)  # one octave inside Euler's band


def throughput(n: int, channels: tuple[int, ...], py_samples: int, repeat: int) -> None:
    print(
        f"## Bank throughput: {n:,} samples, paper mode, one core "
        f"({platform.processor() or platform.machine()}, numpy {np.__version__})"
    )
    print()
    print(
        "Medium 'traffic': paper codes (3 pulses) on random channels one at a time with "
        "guard gaps; 'noisy': the same plus white noise σ = 0.02 on every sample (dense)."
    )
    print(f"Pure-Python loop timed on the first {py_samples:,} samples (rate extrapolates).")
    print(
        "Rates in M samples×channels/s; spikes compared with the reference loop over the "
        "same input (Python loop: over its prefix)."
    )
    print()
    head = (
        "| C | medium | walk (whole) | walk (20-sample windows) | numpy per-sample loop "
        "| pure Python loop | walk / numpy loop | walk / Python loop | spikes | identical |"
    )
    print(head)
    print("|" + "---|" * 10)
    for c in channels:
        om = bank_omegas(c)
        fast_bank = ResonatorBank(om)  # tables are built once, outside the timing

        def fresh(b):
            b.reset()
            return b

        fresh(fast_bank).feed(np.zeros(2))  # load the compiled walk before timing
        base = traffic(om, n, seed=c)
        noisy = base + np.random.default_rng(100 + c).normal(0, 0.02, n)
        for label, u in (("traffic", base), ("noisy", noisy)):
            t_fast, r_fast = best_of(lambda u=u, b=fast_bank: fresh(b).feed(u), repeat)

            def windows(u=u, bank=fast_bank):
                b = fresh(bank)
                return [b.feed(u[i : i + 20]).spikes for i in range(0, n, 20)]

            t_win, r_win = best_of(windows, 1 if label == "noisy" else repeat)
            t_ref, r_ref = best_of(lambda u=u, om=om: reference_trajectory(om, u), 1)
            ref_spikes = np.argwhere(r_ref[1])  # (sample, receiver, channel), sorted
            m = min(py_samples, n)
            t_py, py = best_of(lambda u=u, m=m, om=om: simulate_python(om, u[:m]), 1)
            same = np.array_equal(r_fast.spikes, ref_spikes) and np.array_equal(
                np.concatenate(r_win), ref_spikes
            )
            pre = ref_spikes[ref_spikes[:, 0] < m]
            same_py = all(py[k] == pre[pre[:, 2] == k, 0].tolist() for k in range(c))
            rate = lambda t, s=n, c=c: s * c / t / 1e6  # noqa: E731
            print(
                f"| {c} | {label} | {rate(t_fast):,.0f} | {rate(t_win):,.0f} | "
                f"{rate(t_ref):,.1f} | {rate(t_py, m):,.2f} | {t_ref / t_fast:,.0f}× | "
                f"{rate(t_fast) / rate(t_py, m):,.0f}× | {len(ref_spikes)} | "
                f"{'yes' if same and same_py else 'NO'} |"
            )
    print()


def ser_table(trials: int) -> None:
    cb = paper_codebook()
    wa, wc = PAPER_OMEGAS[0], PAPER_OMEGAS[2]
    sigmas = (0.0, 0.02, 0.05, 0.1, 0.2)
    print(
        f"## Decoder symbol error rate (paper codebook, code on ω_a = 3pi/2, {trials} trials "
        "a cell, through the paper-mode bank)"
    )
    print()
    print(
        "Interferer: a random word of the same family on ω_c = 5pi/3 starting at the same "
        "time (first pulses on the same sample). 'joint' = least squares over the union of "
        "instants + exhaustive ML over word pairs; 'indep.' = the baseline that ignores the "
        "interferer. Last column: spikes per second per resonator on noise alone (false "
        "attention), ω_a, ω_b, ω_c."
    )
    print()
    print(
        "| σ | alternatives | alt. + interferer, joint | alt. + interferer, indep. | "
        "alliance/conflict | rel. + interferer, joint | rel. + interferer, indep. | "
        "noise spikes /s |"
    )
    print("|" + "---|" * 8)
    for j, s in enumerate(sigmas):
        seed = 1000 * j
        cells = [
            symbol_error_rate(cb.alternatives, wa, s, trials=trials, seed=seed),
            symbol_error_rate(cb.alternatives, wa, s, trials=trials, seed=seed + 1, interferer=wc),
            symbol_error_rate(
                cb.alternatives, wa, s, trials=trials, seed=seed + 1, interferer=wc, joint=False
            ),
            symbol_error_rate(cb.relations, wa, s, trials=trials, seed=seed + 2),
            symbol_error_rate(cb.relations, wa, s, trials=trials, seed=seed + 3, interferer=wc),
            symbol_error_rate(
                cb.relations, wa, s, trials=trials, seed=seed + 3, interferer=wc, joint=False
            ),
        ]
        rate = noise_spike_rate(PAPER_OMEGAS[:3], s, seconds=600.0, seed=seed + 4)
        print(f"| {s:g} | " + " | ".join(f"{c.ser:.4f}" for c in cells) + f" | {rate:.3f} |")
    print()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller runs (smoke test)")
    args = ap.parse_args()
    if args.quick:
        throughput(20_000, (3, 50), 2_000, 1)
        ser_table(300)
    else:
        throughput(100_000, (3, 50, 200), 10_000, 5)
        ser_table(2000)


if __name__ == "__main__":
    main()
