"""Increment readout, nearest codeword, joint decoding, timing search, ID acceptance, SER."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rgtbus.errors import RgtbusError
from rgtbus.signal.codebook import paper_codebook
from rgtbus.signal.decoder import (
    ReadoutHistory,
    accept_id,
    candidate_instants,
    decode_code,
    nearest,
    start_from_spike,
)
from rgtbus.signal.evaluate import symbol_error_rate
from rgtbus.signal.joint import decode_joint
from rgtbus.signal.plan import PAPER_OMEGAS
from rgtbus.signal.resonator import ResonatorBank
from rgtbus.signal.waveform import Transmission, hear, pulse_instants, superpose

OM = list(PAPER_OMEGAS)
CB = paper_codebook()


def run(transmissions, n=1300, channels=OM, sigma=0.0, seed=0, chunk=None):
    u = hear(transmissions, n, sigma=sigma, seed=seed)[:, 0]
    bank = ResonatorBank(channels)
    ro = ReadoutHistory.for_bank(bank)
    step = chunk or n
    for i in range(0, n, step):
        ro.extend(bank.feed(u[i : i + step], readout=True))
    return u, bank, ro


def test_readout_recovers_medium_on_every_channel_through_spikes():
    tx = [Transmission(OM[0], 0.001, (0.4, 0.4, 0.4)), Transmission(OM[2], 3.5, (0.7, 0.3, 0.2))]
    u, _bank, ro = run(tx, n=1300 + 700, chunk=20)
    for c in range(len(OM)):
        np.testing.assert_allclose(ro.values(range(800, 2000), c), u[800:], atol=1e-12)
    # spikes happened, so the reset branch of the readout was exercised
    res = ResonatorBank(OM).feed(u, record=True, readout=True)
    assert res.spiked[:, 0, 0].any() and res.spiked[:, 0, 2].any()
    d = np.zeros((len(u), len(OM)))
    d[res.readout_rows] = res.readout[:, 0, :]
    np.testing.assert_allclose(d, np.repeat(u[:, None], 4, axis=1), atol=1e-12)


@pytest.mark.parametrize("family", ["relation", "alternative"])
@pytest.mark.parametrize("on", range(4))
def test_decoder_exact_at_zero_noise(family, on):
    words = CB.family(family)
    for name, w in words.items():
        _, _, ro = run([Transmission(OM[on], 0.001, w)], n=1400)
        dec = decode_code(ro, OM[on], 0.001, words, channel=on)
        assert dec.name == name
        assert dec.distance < 1e-12 and dec.confidence == pytest.approx(1.0)


def test_joint_decoding_with_overlapping_interferer():
    # Same start: first pulses share sample 0; each decoded exactly by the joint decoder.
    for a_name, a in CB.alternatives.items():
        for c_name, c in CB.alternatives.items():
            tx = [Transmission(OM[0], 0.001, a), Transmission(OM[2], 0.001, c)]
            _, _, ro = run(tx)
            got = decode_joint(
                ro,
                [(tx[0].instants(), CB.alternatives), (tx[1].instants(), CB.alternatives)],
                channel=1,
            )
            assert [g.name for g in got] == [a_name, c_name]
            assert got[0].distance < 1e-12 and got[0].margin > 0.1


def test_joint_decoding_coordinate_descent_path(monkeypatch):
    import rgtbus.signal.joint as dec

    monkeypatch.setattr(dec, "MAX_EXHAUSTIVE", 1)
    a, c = CB.alternatives["{alpha}"], CB.alternatives["1"]
    tx = [Transmission(OM[0], 0.001, a), Transmission(OM[2], 0.001, c)]
    _, _, ro = run(tx)
    got = dec.decode_joint(ro, [(t.instants(), CB.alternatives) for t in tx], channel=0)
    assert [g.name for g in got] == ["{alpha}", "1"]


def test_independent_decoding_fails_where_joint_succeeds():
    a, c = CB.alternatives["{beta}"], CB.alternatives["0"]
    tx = [Transmission(OM[0], 0.001, a), Transmission(OM[2], 0.001, c)]
    _, _, ro = run(tx)
    assert decode_code(ro, OM[0], 0.001, CB.alternatives, channel=0).name != "{beta}"


@pytest.mark.parametrize("start", [0.4137, 0.2, 1.0031, 0.0777])
@pytest.mark.parametrize("ch", [0, 2, 3])
def test_timing_search_from_a_spike(start, ch):
    tx = [Transmission(OM[ch], start, CB.id_word)]
    u, _bank, ro = run(tx, n=1500)
    res = ResonatorBank(OM).feed(u)
    spike = int(res.spikes[res.spikes[:, 2] == ch, 0][0])
    ok, dec = accept_id(ro, spike, OM[ch], CB, channel=ch)
    assert ok and dec.name == "id" and dec.distance < 1e-12
    assert dec.instants == tuple(pulse_instants(OM[ch], start, 3))


def test_timing_search_is_needed():
    # The start implied by the spike puts the middle pulse one sample off for this start.
    misses = 0
    for start in np.linspace(0.1, 0.2, 21):
        spike = int(pulse_instants(OM[0], start, 3)[-1])
        guess = start_from_spike(spike, OM[0], 3)
        if tuple(pulse_instants(OM[0], guess, 3)) != tuple(pulse_instants(OM[0], start, 3)):
            misses += 1
    assert misses > 0


def test_candidate_instants_cover_all_distinct_timings():
    cands = candidate_instants(OM[0], 1.0, 3, search=2)
    insts = [c[1] for c in cands]
    assert len(set(insts)) == len(insts)
    for t in np.linspace(1.0 - 0.01, 1.0 + 0.01, 97):
        assert tuple(pulse_instants(OM[0], t, 3)) in insts
    assert cands[0][0] == 0


@pytest.mark.parametrize("word", ["1", "{beta}"])
def test_crosstalk_spike_is_not_accepted_as_an_id(word):
    # docs/model.md: these codes on ω_c fire ω_a; the ID check must refuse a's "ID".
    tx = [Transmission(OM[2], 0.001, CB.alternatives[word])]
    u, _, ro = run(tx, n=800)
    spikes = ResonatorBank(OM).feed(u).spikes
    on_a = spikes[spikes[:, 2] == 0, 0]
    assert len(on_a) == 1
    ok, dec = accept_id(ro, int(on_a[0]), OM[0], CB, channel=0)
    assert not ok and dec.distance > 0.3
    ok_c, _ = accept_id(ro, int(spikes[spikes[:, 2] == 2, 0][0]), OM[2], CB, channel=2)
    assert not ok_c  # an alternative on c is not c's ID either


def test_nearest_margin_and_ties():
    d = nearest([0.4, 0.4, 0.4], CB.all_words())
    assert d.name in ("id", "alliance") and d.margin == pytest.approx(
        math.dist((0.4, 0.4, 0.4), (0.5, 0.2, 0.5))
    )
    half = nearest([0.45, 0.3, 0.45], {"x": (0.4, 0.4, 0.4), "y": (0.5, 0.2, 0.5)})
    assert half.confidence == pytest.approx(0.0, abs=1e-9)


def test_ser_bounds_at_stated_noise():
    # Alternatives (min distance 0.374): σ = 0.05 → essentially error-free; σ = 0.1 → a few %.
    wa, wc = OM[0], OM[2]
    low = symbol_error_rate(CB.alternatives, wa, 0.05, trials=1500, seed=1)
    assert low.ser <= 0.005
    mid = symbol_error_rate(CB.alternatives, wa, 0.1, trials=1500, seed=2)
    assert 0.01 <= mid.ser <= 0.07
    joint = symbol_error_rate(CB.alternatives, wa, 0.05, trials=1500, seed=3, interferer=wc)
    assert joint.ser <= 0.005
    zero = symbol_error_rate(CB.relations, wa, 0.0, trials=200, interferer=wc)
    assert zero.errors == 0


def test_decoder_refusals():
    _, _, ro = run([Transmission(OM[0], 0.001, CB.id_word)], n=600)
    with pytest.raises(RgtbusError, match="outside the history"):
        ro.values([599, 600], 0)
    with pytest.raises(RgtbusError, match="outside the readout"):
        decode_code(np.zeros(10), OM[0], 0.001, CB.relations)
    with pytest.raises(RgtbusError, match="no candidate words"):
        nearest([0.1], {})
    with pytest.raises(RgtbusError, match="expected 3"):
        nearest([0.1, 0.2, 0.3], {"x": (0.1, 0.2)})
    with pytest.raises(RgtbusError, match="different lengths"):
        decode_code(np.zeros(1000), OM[0], 0.001, {"x": (0.1, 0.2), "y": (0.1, 0.2, 0.3)})
    with pytest.raises(RgtbusError, match="no transmissions"):
        decode_joint(np.zeros(10), [])
    bank = ResonatorBank(OM)
    with pytest.raises(RgtbusError, match="receiver 7"):
        ReadoutHistory.for_bank(bank).of(7)
    r = ReadoutHistory.for_bank(bank)
    with pytest.raises(RgtbusError, match="readout=True"):
        r.extend(bank.feed(np.zeros(5)))
    res = bank.feed(np.zeros(5), readout=True)
    with pytest.raises(RgtbusError, match="expected 0"):
        r.extend(res)
    with pytest.raises(RgtbusError, match="capacity"):
        ReadoutHistory(4, capacity=0)
    with pytest.raises(RgtbusError, match="trials"):
        symbol_error_rate(CB.relations, OM[0], 0.1, trials=0)
    with pytest.raises(RgtbusError, match="sigma"):
        symbol_error_rate(CB.relations, OM[0], -0.1)
    assert superpose([], 3).tolist() == [0, 0, 0]


@settings(max_examples=300, deadline=None)
@given(
    st.floats(0.5, 40.0),
    st.one_of(st.floats(-0.05, 5.0), st.integers(0, 400_000).map(lambda k: k * 0.005 + 0.5)),
    st.integers(1, 7),
    st.sampled_from([0.005, 0.001, 0.0005]),
    st.integers(0, 4),
)
def test_timing_candidates_equal_the_literal_rule(omega, start, pulses, tau, search):
    from rgtbus.signal.reference import reference_timings

    assert candidate_instants(omega, start, pulses, tau, search) == reference_timings(
        omega, start, pulses, tau, search
    )


_READ = st.floats(-1.0, 1.0, allow_nan=False, width=32)


@given(
    st.lists(st.tuples(_READ, _READ), min_size=1, max_size=6),
    st.sampled_from([0.0, 0.5, 0.25, 1.0]),
)
@settings(max_examples=300, deadline=None)
def test_nearer_than_silence_is_nearest_between_a_word_and_silence(pairs, half):
    """The one-word test confirmed attention makes of an ID is ``nearest``'s answer between
    that word and silence, to the last bit, ties (silence's) included."""
    from rgtbus.repair import SILENCE
    from rgtbus.signal.decoder import WordSet, nearer_than_silence, nearest

    word = [w for _, w in pairs]
    values = [v for v, _ in pairs]
    if half:  # exactly half way, or on the word: ties and sure answers
        values = [w * half for w in word]
    words = WordSet.of({"id": word, SILENCE: [0.0] * len(word)})
    assert nearer_than_silence(values, word) == (nearest(values, words).name == "id")


_GRID = st.sampled_from([-0.4, 0.0, 0.2, 0.3, 0.35, 0.4, 0.45, 0.5, 0.7])


@settings(max_examples=400, deadline=None)
@given(st.data())
def test_the_compiled_nearest_word_is_the_numpy_rule(data):
    """``_walk.score`` (``nearest_word``) is the compiled twin of the nearest-codeword rule
    ``nearest_words``: the same row, word, distance, margin and separation, to the last bit,
    ties included (reads on a coarse grid, words repeated under other names, rows repeated)."""
    from rgtbus.signal.nearest import nearest_word, nearest_words

    n = data.draw(st.integers(1, 9), label="pulses")
    word = st.lists(_GRID, min_size=n, max_size=n)
    mat = np.array(data.draw(st.lists(word, min_size=1, max_size=6), label="words"))
    rank = np.array(data.draw(st.permutations(range(len(mat))), label="rank"), dtype=np.int64)
    read = st.one_of(
        st.sampled_from(mat.tolist()),  # exactly on a word
        word,  # on the grid: often half-way between words
        st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=n, max_size=n),
    )
    rows = data.draw(st.integers(1, 4), label="rows")
    decodes = data.draw(st.lists(st.lists(read, min_size=rows, max_size=rows), min_size=1))
    reads = np.array(decodes, dtype=np.float64)
    every = nearest_words(reads, mat, rank)
    for d in range(len(reads)):
        twin = nearest_word(np.ascontiguousarray(reads[d]), mat, rank)
        assert twin == tuple(column[d].item() for column in every)


@settings(max_examples=400, deadline=None)
@given(st.data())
def test_the_matched_filter_rule_s_three_forms_are_one_rule(data):
    """The second rule (``rgtbus.signal.rules.MATCHED``): its NumPy form (``many``) and its
    compiled form (``one``; the NumPy twin: tests/test_signal_twin.py) give the same row,
    word, distance, margin and separation to the last bit, ties included, the zero word
    among the words."""
    from rgtbus.signal.rules import MATCHED

    n = data.draw(st.integers(1, 9), label="pulses")
    word = st.lists(_GRID, min_size=n, max_size=n)
    words = st.lists(st.one_of(word, st.just([0.0] * n)), min_size=1, max_size=6)
    mat = np.array(data.draw(words, label="words"))
    rank = np.array(data.draw(st.permutations(range(len(mat))), label="rank"), dtype=np.int64)
    read = st.one_of(
        st.sampled_from(mat.tolist()),
        word,
        st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=n, max_size=n),
    )
    rows = data.draw(st.integers(1, 4), label="rows")
    decodes = data.draw(st.lists(st.lists(read, min_size=rows, max_size=rows), min_size=1))
    reads = np.array(decodes, dtype=np.float64)
    every = MATCHED.many(reads, mat, rank)
    for d in range(len(reads)):
        one = MATCHED.one(np.ascontiguousarray(reads[d]), mat, rank)
        assert one == tuple(column[d].item() for column in every)


def test_the_matched_filter_rule_needs_no_gain_and_is_sure_at_its_word():
    """Any gain a > 0 of a word is read as that word (the nearest rule needs the gain); at
    the word the confidence is 1; a near-silent read weighs less than a loud one when the
    timing search chooses a row."""
    from rgtbus.signal.nearest import in_order
    from rgtbus.signal.rules import MATCHED, NEAREST, rule_named

    mat = np.array([[0.4, 0.4, 0.4], [-0.4, -0.4, -0.4], [0.2, 0.3, 0.7], [0.7, 0.3, 0.2]])
    rank = in_order(4)
    for j in range(4):
        for gain in (0.05, 0.5, 1.0, 3.0):
            read = np.ascontiguousarray(gain * mat[j : j + 1])
            _, word, _, margin, sep = MATCHED.one(read, mat, rank)
            assert word == j
            if gain == 1.0:
                assert MATCHED.confidence(margin, sep) == pytest.approx(1.0)
    faint = np.ascontiguousarray(0.3 * mat[2:3])  # '1' heard faintly: nearest takes 'id'
    assert NEAREST.one(faint, mat, rank)[1] == 0 and MATCHED.one(faint, mat, rank)[1] == 2
    rows = np.ascontiguousarray(np.vstack([0.01 * mat[3], 0.8 * mat[2]]))  # silence, the code
    assert MATCHED.one(rows, mat, rank)[:2] == (1, 2)
    assert rule_named("matched-filter") is MATCHED
    with pytest.raises(RgtbusError, match=r"unknown decoding rule 'ml' \(nearest, matched-"):
        rule_named("ml")
