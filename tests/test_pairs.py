"""Ordered pairs and the tables a unit keeps of them (rgtbus.pairs)."""

from __future__ import annotations

import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rgtbus.pairs import PairTable, ordered_pairs, pair_key

UNITS = ("ann", "bob", "cy", "dee")


def test_a_pair_table_is_a_mapping_of_the_groups_pairs():
    t = PairTable(UNITS)
    assert len(t) == 0 and dict(t) == {} and ("ann", "bob") not in t
    t[("cy", "ann")] = 5
    t[("ann", "bob")] = 0
    t[("ann", "bob")] = 3  # again: replaced, not counted twice
    assert len(t) == 2 and t[("ann", "bob")] == 3 and t.get(("bob", "ann")) is None
    assert list(t) == [("ann", "bob"), ("cy", "ann")]  # the group's order
    assert t == {("cy", "ann"): 5, ("ann", "bob"): 3}  # equal to the same dict
    del t[("cy", "ann")]
    assert len(t) == 1 and ("cy", "ann") not in t
    with pytest.raises(KeyError):
        del t[("cy", "ann")]


def test_a_boolean_table_reads_back_bools():
    t = PairTable(UNITS, boolean=True)
    t[("ann", "bob")] = True
    t[("bob", "ann")] = False
    assert t[("ann", "bob")] is True and t[("bob", "ann")] is False
    assert dict(t.items()) == {("ann", "bob"): True, ("bob", "ann"): False}


@pytest.mark.parametrize(
    "key", [("ann", "zed"), ("zed", "ann"), "ann>bob", ("ann",), ("ann", "bob", "cy"), None]
)
def test_a_key_outside_the_group_is_a_key_error_and_changes_nothing(key):
    t = PairTable(UNITS)
    t[("ann", "bob")] = 1
    assert key not in t
    with pytest.raises(KeyError):
        t[key]
    with pytest.raises(KeyError):
        t[key] = 2
    assert t == {("ann", "bob"): 1}


@pytest.mark.parametrize(
    "value, error",
    [(1.5, TypeError), ("1", TypeError), (2**63, OverflowError), (-(2**63), ValueError)],
)
def test_a_value_it_cannot_hold_is_refused_and_changes_nothing(value, error):
    t = PairTable(UNITS)
    t[("ann", "bob")] = 7
    with pytest.raises(error):
        t[("ann", "bob")] = value
    with pytest.raises(error):
        t[("bob", "ann")] = value
    assert t == {("ann", "bob"): 7} and len(t) == 1


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32), st.integers(2, 7))
def test_a_pair_table_behaves_as_a_dict(seed, n):
    rng = random.Random(seed)
    units = [f"u{i}" for i in rng.sample(range(50), n)]
    pairs = ordered_pairs(units)
    t, d = PairTable(units), {}
    for _ in range(40):
        p = rng.choice(pairs)
        if rng.random() < 0.2 and p in d:
            del t[p], d[p]
        else:
            v = rng.randrange(-(2**62), 2**62)
            t[p], d[p] = v, v
        assert len(t) == len(d) and t == d and set(t) == set(d)
    assert sorted(t.items()) == sorted(d.items()) and len(t.items()) == len(d)
    assert sorted(t.values()) == sorted(d.values()) and list(t) == [p for p, _ in t.items()]
    b = PairTable(units, boolean=True)
    b.update({p: v % 2 for p, v in d.items()})
    assert all(type(v) is bool for v in b.values()) and dict(b.items()) == {
        p: bool(v % 2) for p, v in d.items()
    }
    assert pair_key(*pairs[0]) == f"{pairs[0][0]}>{pairs[0][1]}"


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32), st.integers(2, 6), st.booleans())
def test_a_batch_of_slots_set_at_once_is_each_set_in_order(seed, n, boolean):
    """``set_slots`` (a unit's batch of decodes) leaves the table as setting each pair in
    order would, a slot given twice keeping the last; ``absent`` says which slots are empty."""
    import numpy as np

    rng = random.Random(seed)
    units = [f"u{i}" for i in range(n)]
    pairs = ordered_pairs(units)
    slot = {p: units.index(p[0]) * n + units.index(p[1]) for p in pairs}
    t, d = PairTable(units, boolean=boolean), PairTable(units, boolean=boolean)
    for _ in range(4):
        batch = [rng.choice(pairs) for _ in range(rng.randint(0, 8))]
        values = [rng.randrange(2) if boolean else rng.randrange(-99, 99) for _ in batch]
        slots = np.array([slot[p] for p in batch], dtype=np.int64)
        assert t.absent(slots).tolist() == [p not in t for p in batch]
        t.set_slots(slots, np.array(values, dtype=np.int64))
        for p, v in zip(batch, values, strict=True):
            d[p] = v
        assert t == d and len(t) == len(d)
    with pytest.raises(KeyError):
        t.set_slots(np.array([n * n]), np.array([1]))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32), st.integers(2, 6))
def test_a_pair_table_holds_every_pair_once_each_pair_of_two_units_has_a_value(seed, n):
    """``holds_every_pair``: every ordered pair of two distinct units has a value, however
    many values the table holds on its diagonal (a unit paired with itself counts for none)."""
    rng = random.Random(seed)
    units = [f"u{i}" for i in range(n)]
    pairs = ordered_pairs(units)
    t = PairTable(units)
    for p in rng.sample(pairs, rng.randrange(len(pairs) + 1)):
        t[p] = 1
    for u in rng.sample(units, rng.randrange(n + 1)):
        t[(u, u)] = 2
    want = all(p in t for p in pairs)
    assert t.holds_every_pair() == want
    for u in units:  # off the diagonal again: only the pairs count
        t.pop((u, u), None)
    assert t.holds_every_pair() == want


def test_a_table_takes_a_byte_an_entry_and_widens_only_when_a_value_needs_it():
    """n³ entries in all at n units: a group's yes/no and few-action tables take one byte an
    entry; a value past a byte (one by one, or in a batch) widens the array, keeping every
    value and every empty slot."""
    import numpy as np

    units = [f"u{i}" for i in range(5)]
    t, d = PairTable(units), {}
    assert t._vals.itemsize == 1
    for (p, v), size in zip(
        [(("u0", "u1"), 5), (("u1", "u2"), -127), (("u2", "u3"), 300), (("u3", "u4"), -(2**20)),
         (("u4", "u0"), 2**40), (("u0", "u2"), -(2**63) + 1)],
        [1, 1, 2, 4, 8, 8],
        strict=True,
    ):  # fmt: skip
        t[p] = d[p] = v
        assert t._vals.itemsize == size and t == d and len(t) == len(d)
        assert ("u1", "u0") not in t
    b = PairTable(units)
    b.set_slots(np.array([1, 7]), np.array([1, 2**33]))
    assert b._vals.itemsize == 8 and b == {("u0", "u1"): 1, ("u1", "u2"): 2**33}
    assert b.absent(np.array([0, 1, 2])).tolist() == [True, False, True]


def test_pair_texts_read_a_table_as_the_dict_of_its_texts_and_compare_as_dicts():
    """``PairTexts``: what a report holds of a unit's table; equal to another view or a dict
    exactly when the dicts of their texts are equal, whatever the values behind the texts."""
    import random

    from rgtbus.pairs import PairTable, PairTexts

    rng = random.Random(3)
    units = ("zed", "a1", "B", "m_2")
    for _ in range(200):
        a, b = PairTable(units), PairTable(units)
        for s in units:
            for r in units:
                if s != r and rng.random() < 0.9:
                    a[(s, r)] = rng.randrange(3)
                    if rng.random() < 0.95:
                        b[(s, r)] = a[(s, r)] if rng.random() < 0.97 else rng.randrange(3)
        texts_a = {0: "x", 1: "y", 2: "z"}
        texts_b = {0: "x", 1: "y", 2: "y"} if rng.random() < 0.3 else texts_a  # two values alike
        va, vb = PairTexts(a, texts_a), PairTexts(b, texts_b)
        da, db = va.to_dict(), vb.to_dict()
        assert list(da) == sorted(da, key=lambda k: tuple(k.split(">")))  # sorted by pair
        assert da == {f"{s}>{r}": texts_a[v] for (s, r), v in a.items()}
        assert (va == vb) == (da == db) == (vb == va)
        assert (va == db) == (da == db) and (da == vb) == (da == db)
        assert len(va) == len(a) and all(va[k] == da[k] for k in da)
