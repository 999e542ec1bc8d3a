"""The readout history (all channels, any receivers) and the vectorised channel search."""

import math

import numpy as np
import pytest

from rgtbus.errors import RgtbusError
from rgtbus.signal.codebook import paper_codebook
from rgtbus.signal.decoder import ReadoutHistory, decode_among, decode_code
from rgtbus.signal.resonator import READOUT_DIGITS, ResonatorBank
from rgtbus.signal.waveform import Transmission, superpose

OMEGAS = [3 * math.pi / 2, 4 * math.pi / 3, 5 * math.pi / 3, 7 * math.pi / 6]


def fed(words, start=0.7, channel=2, n=2000, quench_at=None, sigma=0.0, step=20):
    cb = paper_codebook()
    u = superpose([Transmission(OMEGAS[channel], start, cb.alternatives[words])], n)
    u = u + np.random.default_rng(1).normal(0, sigma, n) if sigma else u
    bank = ResonatorBank(OMEGAS)
    ro = ReadoutHistory.for_bank(bank, capacity=n)
    for lo in range(0, n, step):
        if quench_at is not None and lo == quench_at:
            bank.quench()
        ro.extend(bank.feed(u[lo : lo + step], readout=True))
    return cb, ro, u


@pytest.mark.parametrize("quench_at", [None, 100])
def test_readout_is_the_medium_on_every_channel(quench_at):
    _, ro, u = fed("{beta}", quench_at=quench_at)
    idx = np.arange(0, 2000)
    for c in range(len(OMEGAS)):
        assert np.array_equal(ro.values(idx, c), np.round(u, READOUT_DIGITS))


@pytest.mark.parametrize("word", ["1", "0", "{alpha}", "{beta}"])
def test_decode_among_finds_channel_and_word(word):
    cb, ro, _ = fed(word, start=0.702, sigma=0.02)
    words = cb.family("alternative")
    dec, ch = decode_among(ro, [(c, w) for c, w in enumerate(OMEGAS)], 0.7, words, search=2)
    assert (dec.name, ch) == (word, 2)
    ref = decode_code(ro, OMEGAS[2], 0.7, words, search=2, channel=2)
    assert (dec.name, dec.shift, dec.instants) == (ref.name, ref.shift, ref.instants)
    assert dec.distance == pytest.approx(ref.distance) and dec.margin == pytest.approx(ref.margin)


def test_out_of_history_is_refused():
    cb, ro, _ = fed("1")
    with pytest.raises(RgtbusError, match="outside the history"):
        ro.values([5000], 0)
    with pytest.raises(RgtbusError, match="no pulse instants"):
        decode_among(ro, [(0, OMEGAS[0])], 50.0, cb.family("alternative"))


@pytest.mark.parametrize("step", [7, 20, 100, 2000])
def test_readout_does_not_depend_on_how_the_medium_was_fed(step):
    """Silent stretches read exactly 0 whether fed sample by sample or jumped."""
    want = fed("1", step=2000)[1].values(np.arange(2000), slice(None))
    got = fed("1", step=step)[1].values(np.arange(2000), slice(None))
    assert np.array_equal(got, want)
    assert np.count_nonzero(got[:, 2]) == 3


def test_a_shared_history_keeps_each_receivers_view():
    cb = paper_codebook()
    a = superpose([Transmission(OMEGAS[0], 0.2, cb.alternatives["1"])], 900)
    b = superpose([Transmission(OMEGAS[1], 0.4, cb.alternatives["0"])], 900)
    bank = ResonatorBank(OMEGAS, n_receivers=2)
    ro = ReadoutHistory.for_bank(bank, capacity=500)  # shorter than the run: a ring
    ro.extend(bank.feed(np.stack([a, b], axis=1), readout=True))
    idx = np.arange(400, 900)
    assert np.array_equal(ro.of(0).values(idx, 1), np.round(a[400:], READOUT_DIGITS))
    assert np.array_equal(ro.of(1).values(idx, 3), np.round(b[400:], READOUT_DIGITS))
    assert ro.of(1).end == 900
