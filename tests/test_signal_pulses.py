"""The medium sum (rgtbus.signal.pulses): each sender's pulses at a sample added in the order
sent, then the senders left to right, bit for bit as a plain Python loop adds them."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from rgtbus.signal.pulses import medium_sum

floats = st.floats(-2.0, 2.0, allow_nan=False, allow_subnormal=False)
sender = st.lists(st.tuples(st.integers(0, 40), floats), max_size=30)


def loop_sum(parts):
    per = [{} for _ in parts]
    for j, pulses in enumerate(parts):
        for k, v in pulses:
            per[j][k] = per[j].get(k, 0.0) + v
    rows = sorted({k for p in per for k in p})
    out = []
    for k in rows:
        total = 0.0
        for p in per:
            total = total + p.get(k, 0.0)
        out.append(total)
    return rows, out


@settings(max_examples=200, deadline=None)
@given(st.lists(sender, min_size=1, max_size=5))
def test_medium_sum_is_the_loop_bit_for_bit(parts):
    arrays = []
    for pulses in parts:
        pulses = sorted(pulses, key=lambda p: p[0])  # a sender's pulses come in sample order
        arrays.append(
            (np.array([k for k, _ in pulses], dtype=np.int64), np.array([v for _, v in pulses]))
        )
    rows, values = medium_sum(arrays)
    want_rows, want = loop_sum([sorted(p, key=lambda p: p[0]) for p in parts])
    assert rows.tolist() == want_rows
    assert values.tolist() == want  # exact: same order of additions


def test_no_senders_no_medium():
    rows, values = medium_sum([])
    assert rows.size == 0 and values.size == 0


@settings(max_examples=200, deadline=None)
@given(st.lists(sender, min_size=1, max_size=5), st.integers(1, 12))
def test_the_medium_summed_in_slices_is_the_loop_bit_for_bit(parts, cells):
    """A long run's medium is summed a few samples at a time (``MEDIUM_CELLS``): the same
    numbers, whatever the slice."""
    import rgtbus.signal.pulses as pulses_mod

    arrays = []
    for pulses in parts:
        pulses = sorted(pulses, key=lambda p: p[0])
        arrays.append(
            (np.array([k for k, _ in pulses], dtype=np.int64), np.array([v for _, v in pulses]))
        )
    kept = pulses_mod.MEDIUM_CELLS
    pulses_mod.MEDIUM_CELLS = cells
    try:
        rows, values = medium_sum(arrays)
    finally:
        pulses_mod.MEDIUM_CELLS = kept
    want_rows, want = loop_sum([sorted(p, key=lambda p: p[0]) for p in parts])
    assert rows.tolist() == want_rows
    assert values.tolist() == want
