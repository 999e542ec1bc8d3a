"""Resonator bank: model semantics, fast engine vs reference, streaming, refusals."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rgtbus.errors import RgtbusError
from rgtbus.signal.resonator import ResonatorBank, euler_limit, simulate_python, transition

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


@pytest.mark.parametrize("engine", ["fast", "reference"])
def test_update_and_spike_rule_by_hand(engine):
    # One pulse of 0.4 then free rotation: z[k] = A^k·0.4i; a pulse of 1.2 at sample 3 spikes.
    w = 3 * np.pi / 2
    A = transition(w)
    u = np.zeros(6)
    u[0] = 0.4
    u[3] = 1.2
    bank = ResonatorBank([w], engine=engine)
    r = bank.feed(u, record=True)
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


def test_reset_sample_still_hears_input_and_can_spike():
    w = 3 * np.pi / 2
    u = np.array([1.0, 0.95, 0.0])
    for engine in ("fast", "reference"):
        r = ResonatorBank([w], engine=engine).feed(u, record=True)
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


@pytest.mark.parametrize(
    "kw",
    [
        dict(u=sparse_medium(6000, 40, 1), om=np.linspace(3, 6, 12)),
        dict(u=sparse_medium(6000, 40, 2, receivers=3), om=np.linspace(3, 6, 5), U=3),
        dict(u=np.random.default_rng(3).normal(0, 0.03, 4000), om=np.linspace(3, 6, 6)),
        dict(u=sparse_medium(5000, 60, 4, scale=3.0), om=PAPER, epoch=700),
        dict(u=np.random.default_rng(5).normal(0, 0.05, 3000), om=[12.0, 30.0, 55.0], mode="exact"),
        dict(u=sparse_medium(5000, 30, 6, scale=3.0), om=[2.0, 40.0], mode="exact", b=-2.0),
    ],
)
def test_fast_matches_reference(kw):
    kw = dict(kw)
    u, om = kw.pop("u"), kw.pop("om")
    U = kw.pop("U", 1)
    ref = ResonatorBank(om, engine="reference", n_receivers=U, **kw).feed(u, record=True)
    fast = ResonatorBank(om, n_receivers=U, **kw).feed(u, record=True)
    skip = ResonatorBank(om, n_receivers=U, **kw).feed(u)  # event-driven path
    assert len(ref.spikes) > 0
    # Identical spikes; states agree to rounding (different association, same maths).
    assert np.array_equal(ref.spikes, fast.spikes)
    assert np.array_equal(skip.spikes, fast.spikes)
    scale = max(1.0, float(np.abs(ref.z).max()))
    assert np.abs(ref.z - fast.z).max() <= 1e-11 * scale
    assert np.array_equal(ref.spiked, fast.spiked)


def test_sparse_input_skips_the_block_scan(monkeypatch):
    bank = ResonatorBank(np.linspace(3, 6, 10))
    u = sparse_medium(20000, 30, 9)
    want = ResonatorBank(np.linspace(3, 6, 10), engine="reference").feed(u).spikes

    def no_block_scan(*a, **k):
        raise AssertionError("dense block scan used on sparse input")

    monkeypatch.setattr(bank, "_dense_segment", no_block_scan)
    assert np.array_equal(bank.feed(u).spikes, want)


def test_pure_python_loop_agrees():
    u = sparse_medium(3000, 30, 7)
    spikes = ResonatorBank(PAPER, engine="reference").feed(u).spikes
    got = simulate_python(PAPER, u)
    for c in range(3):
        assert got[c] == spikes[spikes[:, 2] == c, 0].tolist()


def _feed_chunks(bank, u, sizes, record):
    outs, i, j = [], 0, 0
    while i < len(u):
        step = sizes[j % len(sizes)]
        outs.append(bank.feed(u[i : i + step], record=record))
        i += step
        j += 1
    return outs


@pytest.mark.parametrize("engine", ["fast", "reference"])
@pytest.mark.parametrize("medium", ["sparse", "dense"])
def test_chunked_equals_whole_bit_for_bit(engine, medium):
    rng = np.random.default_rng(11)
    u = sparse_medium(9000, 70, 8, scale=0.9) if medium == "sparse" else rng.normal(0, 0.03, 3000)
    om = np.linspace(3, 6, 9)  # ≥ 8 lanes: the event-driven path is taken for sparse input
    whole_b = ResonatorBank(om, engine=engine, epoch=1024)
    whole = whole_b.feed(u, record=True)
    for sizes, record in (([20], True), ([1, 7, 333], False), ([4096, 5], True)):
        b = ResonatorBank(om, engine=engine, epoch=1024)
        outs = _feed_chunks(b, u, sizes, record)
        assert np.array_equal(np.concatenate([o.spikes for o in outs]), whole.spikes)
        assert np.array_equal(b.z, whole_b.z)
        assert np.array_equal(b.spiked_last, whole_b.spiked_last)
        if record:
            assert np.array_equal(np.concatenate([o.z for o in outs]), whole.z)
            assert np.array_equal(np.concatenate([o.y for o in outs]), whole.y)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 400), min_size=1, max_size=12), st.integers(0, 10_000))
def test_chunked_equals_whole_property(sizes, seed):
    u = sparse_medium(2500, 25, seed, scale=0.9)
    om = [3.0, 4.2, 5.5]
    whole_b = ResonatorBank(om, epoch=512, n_receivers=3)
    whole = whole_b.feed(u)
    b = ResonatorBank(om, epoch=512, n_receivers=3)
    outs = _feed_chunks(b, u, sizes, record=seed % 2 == 0)
    assert np.array_equal(np.concatenate([o.spikes for o in outs]), whole.spikes)
    assert np.array_equal(b.z, whole_b.z)


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
        ([PAPER], {"engine": "gpu"}, "engine 'gpu'"),
        ([PAPER], {"tau": 0}, "tau"),
        ([PAPER], {"tau": "x"}, "tau"),
        ([PAPER], {"b": float("inf")}, "b ="),
        ([PAPER], {"n_receivers": 0}, "n_receivers"),
        ([PAPER], {"epoch": 0}, "epoch"),
    ],
)
def test_bank_refusals(args, kw, needle):
    with pytest.raises(RgtbusError, match=None) as e:
        ResonatorBank(*args, **kw)
    assert needle in str(e.value)


def test_feed_refusals():
    b = ResonatorBank(PAPER, n_receivers=2)
    with pytest.raises(RgtbusError, match=r"\(n, 2\)"):
        b.feed(np.zeros((5, 3)))
    with pytest.raises(RgtbusError, match="sample 3 is not finite"):
        b.feed(np.array([0, 0, 0, np.nan, 0.0]))
    with pytest.raises(RgtbusError, match="mode"):
        transition(1.0, mode="x")
