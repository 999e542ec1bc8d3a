"""The readout history (all channels, any receivers) and the vectorised channel search."""

import math

import numpy as np
import pytest

from rgtbus.errors import RgtbusError
from rgtbus.signal.codebook import paper_codebook
from rgtbus.signal.decoder import (
    ReadoutHistory,
    WordSet,
    decode_among,
    decode_among_columns,
    decode_among_each,
    decode_code,
    nearest,
    nearest_columns,
    nearest_each,
    word_matrix,
)
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


def _three_receivers():
    """Three receivers of one bank: the same code, heard with different noise."""
    cb = paper_codebook()
    n = 1200
    u = superpose([Transmission(OMEGAS[1], 0.702, cb.alternatives["{alpha}"])], n)
    rng = np.random.default_rng(7)
    heard = np.stack([u, u + rng.normal(0, 0.05, n), u], axis=1)  # receivers 0 and 2 agree
    bank = ResonatorBank(OMEGAS, n_receivers=3)
    ro = ReadoutHistory.for_bank(bank, capacity=n)
    for lo in range(0, n, 37):
        ro.extend(bank.feed(heard[lo : lo + 37], readout=True))
    return cb, ro


def test_gather_reads_every_receiver_as_values_does():
    _, ro = _three_receivers()
    idx = np.array([[140, 141, 500], [10, 600, 1199]])
    chans = np.array([1, 3])
    every = ro.gather(idx, chans)
    assert every.shape == (3, 2, 3)
    for r in range(3):
        assert np.array_equal(every[r], ro.values(idx, chans[:, None], r))
    assert np.count_nonzero(every) > 0  # the code's instants are among them
    with pytest.raises(RgtbusError, match="outside the history"):
        ro.gather(np.array([[1200]]), np.array([0]))


def test_decoding_every_receiver_at_once_equals_one_by_one():
    cb, ro = _three_receivers()
    chans = tuple((c, w) for c, w in enumerate(OMEGAS))
    words = WordSet.of(cb.family("alternative"))
    each = decode_among_each(ro, chans, 0.7, words, search=2)
    for r in range(3):
        assert each[r] == decode_among(ro.of(r), chans, 0.7, words, search=2)
    assert each[0] == each[2] and each[0][0].values != each[1][0].values
    inst = each[0][0].instants
    near = nearest_each(ro, inst, 1, WordSet.of(cb.distinct_words()))
    for r in range(3):
        assert near[r] == nearest(ro.values(inst, 1, r), cb.distinct_words())


@pytest.mark.parametrize("noise", [0.0, 0.05, 0.4])
def test_decoding_as_columns_equals_a_decision_each(noise):
    """The columns a unit's batch of decodes reads (each receiver's word, channel, margin)
    are those of ``decode_among_each`` and ``nearest_each``, with every receiver alike,
    some alike and all apart, at several starts and searches."""
    cb = paper_codebook()
    n = 1200
    u = superpose([Transmission(OMEGAS[1], 0.702, cb.alternatives["{alpha}"])], n)
    rng = np.random.default_rng(11)
    heard = np.stack([u, u + rng.normal(0, noise, n), u, u + rng.normal(0, noise, n)], axis=1)
    bank = ResonatorBank(OMEGAS, n_receivers=4)
    ro = ReadoutHistory.for_bank(bank, capacity=n)
    ro.extend(bank.feed(heard, readout=True))
    chans = tuple((c, w) for c, w in enumerate(OMEGAS))
    for family in ("alternative", "relation"):
        words = WordSet.of(cb.family(family))
        for start, search in ((0.7, 2), (0.702, 0), (0.69, 5)):
            each = decode_among_each(ro, chans, start, words, search=search)
            word, chan, margin = decode_among_columns(ro, chans, start, words, search=search)
            assert [words.names[w] for w in word] == [d.name for d, _ in each]
            assert chan.tolist() == [c for _, c in each]
            assert margin.tolist() == [d.margin for d, _ in each]
    ids = WordSet.of(cb.distinct_words())
    for inst in ((140, 141, 500, 700), tuple(range(300, 340, 10))):
        for channel in range(len(OMEGAS)):
            near = nearest_each(ro, inst[: cb.pulses], channel, ids)
            word, margin = nearest_columns(ro, inst[: cb.pulses], channel, ids)
            assert [ids.names[w] for w in word] == [d.name for d in near]
            assert margin.tolist() == [d.margin for d in near]


def test_word_sets_are_equal_by_value():
    cb = paper_codebook()
    a, b = WordSet.of(cb.family("relation")), WordSet.of(dict(cb.family("relation")))
    assert a == b and hash(a) == hash(b)
    assert a is b  # one object while one lives: a cache keyed by it finds it by identity
    c = WordSet(*word_matrix(cb.family("relation"), None, "words"))  # made directly: not shared
    assert c == a and hash(c) == hash(a) and c is not a
    assert a != WordSet.of(cb.family("alternative"))


def test_a_history_that_outgrows_its_buffer_keeps_every_value_it_holds():
    """Stored a few rows at a time over a long run, a history moves what it holds to the
    front of its buffer in place when there is room (and grows when there is not): every
    sample still held reads what was stored, for every receiver, and the buffer stays within
    a few times the most it held."""
    rng = np.random.default_rng(5)
    hist = ReadoutHistory(2, capacity=300, receivers=3)
    stored: dict[int, np.ndarray] = {}
    end = most = 0
    for step in range(400):
        n = int(rng.integers(1, 40))
        rows = np.sort(rng.choice(np.arange(end, end + n), size=min(n, 5), replace=False))
        values = rng.normal(size=(rows.size, 3, 2))
        values[:, :, 1] = values[:, :, 0]  # every channel reads the same d
        hist.store(end, n, rows, values)
        for r, v in zip(rows.tolist(), values, strict=True):
            stored[r] = v[:, 0]
        end += n
        held = [r for r in stored if r >= end - 300]
        most = max(most, len(held))
        if step % 50 == 0 or step == 399:
            for receiver in range(3):
                got = hist.values(np.array(held), 0, receiver)
                assert got.tolist() == [stored[r][receiver] for r in held]
        assert hist._buf_rows.size <= 4 * max(16, most + 5)  # a few times the most held


def test_a_read_of_receivers_alike_reads_the_first_alone():
    """``gather_distinct``: each distinct receiver's values once and each receiver's set, the
    same as ``gather`` sorted into sets, whether the rows read hold values that differ
    between receivers or not (then only the first receiver's are read); -0.0 and 0.0 count
    as different, as the bytes do."""
    rng = np.random.default_rng(9)
    hist = ReadoutHistory(3, capacity=1000, receivers=4)
    same = rng.normal(size=(20, 1, 3)).repeat(4, axis=1)  # rows 0..19: every receiver alike
    mixed = rng.normal(size=(20, 4, 3))
    mixed[:, 2] = mixed[:, 0]  # receivers 0 and 2 alike
    signed = np.zeros((1, 4, 3))
    signed[0, 1] = -0.0  # bit for bit different
    hist.store(0, 20, np.arange(20), same)
    hist.store(20, 20, np.arange(20, 40), mixed)
    hist.store(40, 1, np.array([40]), signed)
    hist.store(41, 10, np.zeros(0, dtype=np.int64), np.zeros((0, 4, 3)))
    for span in ((0, 19), (3, 30), (25, 39), (38, 45), (44, 50)):
        idx = rng.integers(span[0], span[1] + 1, size=(7, 3))
        chans = rng.integers(0, 3, size=7)
        every = hist.gather(idx, chans)
        values, which = hist.gather_distinct(idx, chans)
        assert np.array_equal(values[which], every)
        assert len({every[r].tobytes() for r in range(4)}) == len(values)
        if span[1] < 20 or span[0] > 40:  # rows whose receivers are alike (or silence)
            assert len(values) == 1
