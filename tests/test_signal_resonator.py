"""Resonator bank: model semantics, the one walk vs the literal reference, chunking, stops."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rgtbus.errors import RgtbusError
from rgtbus.signal import lanes
from rgtbus.signal.reference import reference_trajectory, simulate_python
from rgtbus.signal.resonator import (
    BankState,
    ResonatorBank,
    euler_limit,
    resonate,
    shared_tables,
    transition,
)

PAPER = [3 * np.pi / 2, 4 * np.pi / 3, 5 * np.pi / 3]


def sparse_medium(n, count, seed, scale=0.7, receivers=None):
    rng = np.random.default_rng(seed)
    shape = (n,) if receivers is None else (n, receivers)
    u = np.zeros(shape)
    idx = rng.choice(n, count, replace=False)
    u[idx] = rng.uniform(-scale, scale, (count, *shape[1:]))
    return u


def test_transition_modes():
    a = transition(3 * np.pi / 2)
    assert a == complex(1 + 0.005 * -0.1, 0.005 * (3 * np.pi / 2))
    e = transition(3 * np.pi / 2, mode="exact")
    assert abs(e - np.exp(0.005 * complex(-0.1, 3 * np.pi / 2))) < 1e-15
    assert euler_limit() == pytest.approx(np.sqrt(40 - 0.01))


def test_update_and_spike_rule_by_hand():
    # One pulse of 0.4 then free rotation: z[k] = A^k·0.4i; a pulse of 1.2 at sample 3 spikes.
    w = 3 * np.pi / 2
    A = transition(w)
    u = np.zeros(6)
    u[0] = 0.4
    u[3] = 1.2
    r = ResonatorBank([w]).feed(u, record=True, readout=True)
    z = [0.4j]
    z.append(A * z[-1])
    z.append(A * z[-1])
    z.append(A * z[-1] + 1.2j)  # pre-spike state, y ≥ 1 → spike at 3
    z.append(complex((A * z[-1]).real, 0.1))  # x: Euler step of the pre-spike state, y = 0.1
    z.append(A * z[-1])
    np.testing.assert_allclose(r.z[:, 0, 0], z, rtol=1e-12, atol=1e-15)
    assert r.spikes.tolist() == [[3, 0, 0]]
    assert r.y[3, 0, 0] == 1.5  # recorded spike value
    assert r.y[2, 0, 0] == pytest.approx(z[2].imag)
    assert r.spiked[:, 0, 0].tolist() == [False, False, False, True, False, False]
    # the readout recovers the medium at the samples that carried input
    assert r.readout_rows.tolist() == [0, 3]
    assert r.readout[:, 0, 0].tolist() == [0.4, 1.2]


def test_reset_sample_still_hears_input_and_can_spike():
    w = 3 * np.pi / 2
    u = np.array([1.0, 0.95, 0.0])
    r = ResonatorBank([w]).feed(u, record=True)
    # sample 1 starts at y = 0.1, adds 0.95 → 1.05 ≥ 1: spikes again
    assert r.spikes[:, 0].tolist() == [0, 1]
    assert r.z[1, 0, 0].imag == pytest.approx(1.05)


def test_inhibitory_spike_between_inputs():
    # −0.4 ×3 on own frequency spikes half a period after the last pulse (paper Fig. resInh).
    w = 3 * np.pi / 2
    u = np.zeros(800)
    u[[0, 267, 534]] = -0.4
    r = ResonatorBank([w]).feed(u)
    assert r.spikes.shape == (1, 3)
    assert 534 + 100 < r.spikes[0, 0] < 534 + 140


CASES = [
    dict(u=sparse_medium(6000, 40, 1), om=np.linspace(3, 6, 12)),
    dict(u=sparse_medium(6000, 40, 2, receivers=3), om=np.linspace(3, 6, 5)),
    dict(u=np.random.default_rng(3).normal(0, 0.03, 4000), om=np.linspace(3, 6, 6)),
    dict(u=sparse_medium(5000, 60, 4, scale=3.0), om=PAPER, epoch=700),
    dict(u=np.random.default_rng(5).normal(0, 0.05, 3000), om=[12.0, 30.0, 55.0], mode="exact"),
    dict(u=sparse_medium(5000, 30, 6, scale=3.0), om=[2.0, 40.0], mode="exact", b=-2.0),
]


def _bank(kw, u):
    kw = dict(kw)
    kw.pop("u")
    om = kw.pop("om")
    return ResonatorBank(om, n_receivers=1 if u.ndim == 1 else u.shape[1], **kw)


@pytest.mark.parametrize("kw", CASES)
def test_walk_matches_the_literal_reference(kw):
    u = kw["u"]
    opts = {k: v for k, v in kw.items() if k in ("mode", "b")}
    z, spiked, d = reference_trajectory(kw["om"], u, **opts)
    rec = _bank(kw, u).feed(u, record=True, readout=True)
    skip = _bank(kw, u).feed(u)  # silence jumped, not recorded
    assert spiked.any()
    # Identical spikes; states agree to rounding (different association, same maths).
    assert np.array_equal(np.argwhere(spiked), rec.spikes)
    assert np.array_equal(skip.spikes, rec.spikes)
    scale = max(1.0, float(np.abs(z).max()))
    assert np.abs(z - rec.z).max() <= 1e-11 * scale
    assert np.array_equal(spiked, rec.spiked)
    got = np.zeros_like(d)
    got[rec.readout_rows] = rec.readout
    assert np.abs(got - d).max() <= 2e-12  # the readout, rounded to 12 decimals
    uu = u if u.ndim == 2 else u[:, None]
    assert np.abs(got - uu[:, :, None]).max() <= 1e-12  # it recovers what was heard


def test_pure_python_loop_agrees():
    u = sparse_medium(3000, 30, 7)
    spikes = ResonatorBank(PAPER).feed(u).spikes
    got = simulate_python(PAPER, u)
    for c in range(3):
        assert got[c] == spikes[spikes[:, 2] == c, 0].tolist()


def _feed_chunks(bank, u, sizes, record):
    outs, i, j = [], 0, 0
    while i < len(u):
        step = sizes[j % len(sizes)]
        outs.append(bank.feed(u[i : i + step], record=record, readout=True))
        i += step
        j += 1
    return outs


@pytest.mark.parametrize("medium", ["sparse", "dense"])
def test_chunked_equals_whole_bit_for_bit(medium):
    rng = np.random.default_rng(11)
    u = sparse_medium(9000, 70, 8, scale=0.9) if medium == "sparse" else rng.normal(0, 0.03, 3000)
    om = np.linspace(3, 6, 9)
    whole_b = ResonatorBank(om, epoch=1024)
    whole = whole_b.feed(u, record=True, readout=True)
    for sizes, record in (([20], True), ([1, 7, 333], False), ([4096, 5], True)):
        b = ResonatorBank(om, epoch=1024)
        outs = _feed_chunks(b, u, sizes, record)
        assert np.array_equal(np.concatenate([o.spikes for o in outs]), whole.spikes)
        assert np.array_equal(b.z, whole_b.z)
        assert np.array_equal(b.spiked_last, whole_b.spiked_last)
        assert np.array_equal(np.concatenate([o.readout for o in outs]), whole.readout)
        if record:
            assert np.array_equal(np.concatenate([o.z for o in outs]), whole.z)
            assert np.array_equal(np.concatenate([o.y for o in outs]), whole.y)


def _advance_stopping(bank, u, step, stop_lanes=None):
    """Sparse input, stopping at every spike (of ``stop_lanes``), in steps of ``step``."""
    uu = u if u.ndim == 2 else u[:, None]
    rows = np.flatnonzero(np.any(uu != 0, axis=1))
    spikes, readout, stops = [], [], 0
    while bank.n_fed < len(u):
        end = min(len(u), bank.n_fed + step)
        r = rows[(rows >= bank.n_fed) & (rows < end)]
        res = bank.advance(end, r, uu[r], stop=True, stop_lanes=stop_lanes, readout=True)
        stops += res.stopped
        if res.stopped:
            # it stopped right after a spike of a stop lane, and nothing later was processed
            last = res.start + res.n - 1
            assert res.spikes[-1, 0] == last
            if stop_lanes is not None:
                lane = res.spikes[res.spikes[:, 0] == last]
                assert stop_lanes[lane[:, 1] * bank.n_channels + lane[:, 2]].any()
        spikes.append(res.spikes)
        readout.append(res.readout)
    return np.concatenate(spikes), np.concatenate(readout), stops


@pytest.mark.parametrize("kw", CASES[:4])
def test_stopping_at_spikes_changes_nothing(kw):
    u = kw["u"]
    whole_b = _bank(kw, u)
    whole = whole_b.feed(u, readout=True)
    for step in (900, 37):
        b = _bank(kw, u)
        spikes, readout, stops = _advance_stopping(b, u, step)
        assert stops > 0
        assert np.array_equal(spikes, whole.spikes)
        assert np.array_equal(readout, whole.readout)
        assert np.array_equal(b.z, whole_b.z) and b.n_fed == whole_b.n_fed
    # stopping only at one lane's spikes: the others ring on, spikes all returned in order
    b = _bank(kw, u)
    lanes = np.zeros(b.model.lanes, dtype=bool)
    lanes[1] = True
    spikes, readout, stops = _advance_stopping(b, u, 5000, lanes)
    assert np.array_equal(spikes, whole.spikes)
    assert np.array_equal(readout, whole.readout)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 400), min_size=1, max_size=12), st.integers(0, 10_000))
def test_chunked_equals_whole_property(sizes, seed):
    u = sparse_medium(2500, 25, seed, scale=0.9, receivers=3)
    om = [3.0, 4.2, 5.5]
    whole_b = ResonatorBank(om, epoch=512, n_receivers=3)
    whole = whole_b.feed(u)
    b = ResonatorBank(om, epoch=512, n_receivers=3)
    outs = _feed_chunks(b, u, sizes, record=seed % 2 == 0)
    assert np.array_equal(np.concatenate([o.spikes for o in outs]), whole.spikes)
    assert np.array_equal(b.z, whole_b.z)
    stopped = ResonatorBank(om, epoch=512, n_receivers=3)
    spikes, _, _ = _advance_stopping(stopped, u, sizes[0])
    assert np.array_equal(spikes, whole.spikes)


def test_quench_one_receiver_and_picked_lanes():
    u = sparse_medium(3000, 30, 12, receivers=2)
    om = np.linspace(3, 6, 4)
    both = ResonatorBank(om, n_receivers=2)
    alone = ResonatorBank(om)
    both.feed(u[:1500])
    alone.feed(u[:1500, 1])
    both.quench(0)
    assert np.all(both.z[0] == 0) and np.array_equal(both.z[1], alone.z[0])
    # a few lanes picked out of the bank walk exactly as they do inside it
    model = both.model.pick(np.array([2, 0]), np.array([1, 1]))
    lanes = np.array([1 * 4 + 2, 1 * 4 + 0])
    s = both.state
    picked, res = resonate(
        model,
        BankState(s.wr[lanes], s.wi[lanes], s.pend[lanes], s.n),
        3000,
        np.flatnonzero(np.any(u[1500:] != 0, axis=1)) + 1500,
        u[1500:][np.any(u[1500:] != 0, axis=1)],
    )
    full = both.feed(u[1500:])
    sel = full.spikes[(full.spikes[:, 1] == 1) & np.isin(full.spikes[:, 2], [0, 2])]
    assert np.array_equal(res.spikes, sel)
    assert np.array_equal(picked.wr, both.state.wr[lanes])


def test_tables_are_shared_between_banks():
    a = ResonatorBank(PAPER)
    b = ResonatorBank(PAPER, n_receivers=5)
    assert a.model.tables is b.model.tables
    assert shared_tables(tuple(PAPER), "paper", 0.005, -0.1, None) is a.model.tables
    assert not a.model.tables.Pr.flags.writeable


def test_state_properties_and_reset():
    b = ResonatorBank(PAPER, n_receivers=2)
    assert b.z.shape == (2, 3) and b.n_fed == 0
    b.feed(np.r_[0.4, np.zeros(9)])
    assert b.n_fed == 10 and np.all(b.z != 0)
    b.reset()
    assert b.n_fed == 0 and np.all(b.z == 0)


def test_spike_times_helper():
    u = np.zeros(600)
    u[[0, 267, 534]] = 0.4
    r = ResonatorBank(PAPER).feed(u)
    assert r.spike_times(channel=0).tolist() == [534 * 0.005]
    per = r.spike_times()
    assert len(per) == 1 and per[0].tolist() == [534 * 0.005]


@pytest.mark.parametrize(
    "args, kw, needle",
    [
        ([[]], {}, "non-empty"),
        ([[3.0, -1.0]], {}, "omega[1]"),
        ([[3.0, float("nan")]], {}, "omega[1]"),
        ([PAPER], {"mode": "euler"}, "mode 'euler'"),
        ([PAPER], {"tau": 0}, "tau"),
        ([PAPER], {"tau": "x"}, "tau"),
        ([PAPER], {"b": float("inf")}, "b ="),
        ([PAPER], {"n_receivers": 0}, "n_receivers"),
        ([PAPER], {"epoch": 0}, "epoch"),
    ],
)
def test_bank_refusals(args, kw, needle):
    with pytest.raises(RgtbusError) as e:
        ResonatorBank(*args, **kw)
    assert needle in str(e.value)


def test_feed_and_advance_refusals():
    b = ResonatorBank(PAPER, n_receivers=2)
    with pytest.raises(RgtbusError, match=r"\(n, 2\)"):
        b.feed(np.zeros((5, 3)))
    with pytest.raises(RgtbusError, match="sample 3 is not finite"):
        b.feed(np.array([0, 0, 0, np.nan, 0.0]))
    with pytest.raises(RgtbusError, match="sorted, unique"):
        b.advance(20, [5, 3], [0.1, 0.2])
    b.feed(np.zeros(5))
    with pytest.raises(RgtbusError, match="already at"):
        b.advance(2)
    with pytest.raises(RgtbusError, match="mode"):
        transition(1.0, mode="x")


def test_a_spike_on_the_last_sample_is_a_stop():
    b = ResonatorBank(PAPER)
    res = b.advance(11, [10], [1.2], stop=True)  # spikes at sample 10, the last one asked for
    assert res.stopped and res.spikes.tolist() == [[10, 0, c] for c in range(3)]
    assert b.n_fed == 11 and b.spiked_last.all()
    lanes = np.zeros(3, dtype=bool)
    lanes[1] = True
    res = ResonatorBank(PAPER).advance(11, [10], [1.2], stop=True, stop_lanes=lanes)
    assert res.stopped and res.spikes[:, 2].tolist() == [0, 1, 2]


@pytest.mark.parametrize("n", [3000, 40_000])  # a short advance and one past the 16-bit sort
def test_spikes_come_in_sample_receiver_channel_order(n):
    u = sparse_medium(n, n // 60, 5, scale=0.9, receivers=3)
    om = np.linspace(3, 6, 5)
    res = ResonatorBank(om, n_receivers=3).feed(u)
    sp = res.spikes
    k, rec, ch = sp[:, 0], sp[:, 1], sp[:, 2]
    assert len(sp) > 100 and np.any(np.diff(k) == 0)  # samples where several lanes fire
    assert np.array_equal(sp, sp[np.lexsort((ch, rec, k))])
    # the same spikes walked in pieces (each sorted on its own)
    b = ResonatorBank(om, n_receivers=3)
    outs = _feed_chunks(b, u, [977, 5000, 20_000, n], record=False)
    assert np.array_equal(np.concatenate([o.spikes for o in outs]), sp)


def _walk_in_pieces(b, u, n, walking, share):
    """``b`` over ``u`` in three advances, receiver 0 quenched after the first."""
    rows = np.flatnonzero(np.any(u != 0.0, axis=1))
    outs, pos = [], 0
    for cut in sorted({n // 3, n // 2, n}):
        r = rows[(rows >= pos) & (rows < cut)]
        b.state, res = resonate(b.model, b.state, cut, r, u[r], receivers=walking, share=share)
        outs.append(res.spikes)
        if pos == 0:
            b.quench(0)  # receiver 0 back to rest: its view is its own now
        pos = cut
    return np.concatenate(outs), b.state


@settings(max_examples=30, deadline=None)
@given(
    st.lists(st.integers(0, 2), min_size=2, max_size=7),
    st.integers(0, 10_000),
    st.sampled_from([3000, 40_000]),
    st.booleans(),
)
def test_receivers_that_hear_alike_walk_once_with_the_same_results(views, seed, n, mask):
    """Receivers of one view (the same input column from the same state) walk once and share
    the walk (``share``): state and spikes (sorted by sample, receiver, channel) equal, bit
    for bit, those of every lane walking, stepped in pieces, after a quench of one receiver
    (which splits its view off), with some receivers standing still (``receivers``)."""
    rng = np.random.default_rng(seed)
    U, om = len(views), np.linspace(3, 6, 4)
    cols = sparse_medium(n, n // 80, seed, scale=0.9, receivers=3)
    u = cols[:, views]  # receivers of one view hear one column
    walking = rng.random(U) < 0.7 if mask else None
    banks = {share: ResonatorBank(om, n_receivers=U) for share in (True, False)}
    got = {}
    with pytest.MonkeyPatch.context() as mp:  # share however short the advance
        mp.setattr(lanes, "SHARE_MIN_WORK", 0)
        for share, b in banks.items():
            got[share] = _walk_in_pieces(b, u, n, walking, share)
    (sp, st_), (ref, ref_st) = got[True], got[False]

    assert np.array_equal(sp, ref)
    k, rec, ch = sp[:, 0], sp[:, 1], sp[:, 2]
    assert np.array_equal(sp, sp[np.lexsort((ch, rec, k))])
    for a, b in ((st_.wr, ref_st.wr), (st_.wi, ref_st.wi), (st_.pend, ref_st.pend)):
        assert np.array_equal(a.view(np.uint8), b.view(np.uint8))  # bit for bit
    if walking is not None:
        still = np.repeat(~walking, len(om))
        assert not np.isin(sp[:, 1], np.flatnonzero(~walking)).any()
        assert not st_.wr[still].any()  # never walked: still at rest


def test_quench_several_receivers_at_once_is_each_in_turn():
    """The ears quench every unit due at a sample with one copy of the state: the same state
    as quenching them one by one."""
    u = sparse_medium(2000, 30, 12, receivers=4)
    om = np.linspace(3, 6, 3)
    once, each = ResonatorBank(om, n_receivers=4), ResonatorBank(om, n_receivers=4)
    for bank in (once, each):
        bank.feed(u[:1200])
    once.quench([2, 0])
    each.quench(2)
    each.quench(0)
    for got, want in ((once.state.wr, each.state.wr), (once.state.wi, each.state.wi)):
        assert np.array_equal(got, want)
    assert np.array_equal(once.state.pend, each.state.pend)
    assert np.all(once.z[[0, 2]] == 0) and np.any(once.z[[1, 3]] != 0)
    with pytest.raises(RgtbusError, match="receiver 7"):
        once.quench([1, 7])
