"""The all-channel readout and the vectorised channel search agree with the per-channel ones."""

import math

import numpy as np
import pytest

from rgtbus.errors import RgtbusError
from rgtbus.signal.codebook import paper_codebook
from rgtbus.signal.decoder import DIGITS, BankReadout, Readout, decode_among, decode_code
from rgtbus.signal.resonator import ResonatorBank
from rgtbus.signal.waveform import Transmission, superpose

OMEGAS = [3 * math.pi / 2, 4 * math.pi / 3, 5 * math.pi / 3, 7 * math.pi / 6]


def fed(words, start=0.7, channel=2, n=2000, quench_at=None, sigma=0.0):
    cb = paper_codebook()
    u = superpose([Transmission(OMEGAS[channel], start, cb.alternatives[words])], n)
    u = u + np.random.default_rng(1).normal(0, sigma, n) if sigma else u
    bank = ResonatorBank(OMEGAS)
    bank_ro = BankReadout(bank, capacity=n)
    singles = [Readout.for_bank(bank, c, capacity=n) for c in range(len(OMEGAS))]
    for lo in range(0, n, 20):
        if quench_at is not None and lo == quench_at:
            bank.quench()
            bank_ro.quench()
            for r in singles:
                r.quench()
        res = bank.feed(u[lo : lo + 20], record=True)
        bank_ro.append(res)
        for r in singles:
            r.append(res)
    return cb, bank_ro, singles


@pytest.mark.parametrize("quench_at", [None, 100])
def test_bank_readout_equals_per_channel_readouts(quench_at):
    _, bank_ro, singles = fed("{beta}", quench_at=quench_at)
    idx = np.arange(0, 2000)
    for c, r in enumerate(singles):
        assert np.array_equal(bank_ro.values(idx, c), np.round(r.values(idx), DIGITS))


@pytest.mark.parametrize("word", ["1", "0", "{alpha}", "{beta}"])
def test_decode_among_finds_channel_and_word(word):
    cb, bank_ro, singles = fed(word, start=0.702, sigma=0.02)
    words = cb.family("alternative")
    dec, ch = decode_among(bank_ro, [(c, w) for c, w in enumerate(OMEGAS)], 0.7, words, search=2)
    assert (dec.name, ch) == (word, 2)
    ref = decode_code(singles[2], OMEGAS[2], 0.7, words, search=2)
    assert (dec.name, dec.shift, dec.instants) == (ref.name, ref.shift, ref.instants)
    assert dec.distance == pytest.approx(ref.distance) and dec.margin == pytest.approx(ref.margin)


def test_out_of_history_is_refused():
    cb, bank_ro, _ = fed("1")
    with pytest.raises(RgtbusError, match="outside the history"):
        bank_ro.values([5000], 0)
    with pytest.raises(RgtbusError, match="no pulse instants"):
        decode_among(bank_ro, [(0, OMEGAS[0])], 50.0, cb.family("alternative"))


def test_quiet_windows_read_exactly_like_computed_ones():
    """Skipping the recording of silent windows changes no readout value."""
    cb = paper_codebook()
    u = superpose([Transmission(OMEGAS[1], 0.3, cb.alternatives["1"])], 1200)
    recorded = {}
    for quiet_path in (False, True):
        bank = ResonatorBank(OMEGAS)
        ro = BankReadout(bank, capacity=1200)
        for lo in range(0, 1200, 20):
            chunk = u[lo : lo + 20]
            if quiet_path and not chunk.any():
                ro.append_quiet(bank.feed(chunk).n, bank)
            else:
                ro.append(bank.feed(chunk, record=True))
        recorded[quiet_path] = ro.values(np.arange(1200), slice(None))
    assert np.array_equal(recorded[False], recorded[True])
    assert np.count_nonzero(recorded[True][:, 1]) == 3
