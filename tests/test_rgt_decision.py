"""The paper's worked examples through the API, with the corrected values of docs/errata.md."""

import copy
import dataclasses
import random

import pytest

from rgtbus.errors import RgtbusError
from rgtbus.rgt import (
    InfluenceMatrix,
    Universe,
    canonical_form,
    decision_function,
    evaluate,
    forward,
    parse_polynomial,
    random_polynomial,
)
from rgtbus.rgt.expr import truth_table, variable_table

AB = Universe(("alpha", "beta"))
GATE = Universe(("open",))

# Overview influence matrix (row influences column): a>b={α}, a>c={β}, everything else {β}.
OVERVIEW = ["a>b={alpha}", "a>c={beta}", "b>a={beta}", "b>c={beta}", "c>a={beta}", "c>b={beta}"]


def solve(poly, specs, universe=AB):
    df = decision_function(parse_polynomial(poly))
    return df, forward(df, universe, InfluenceMatrix.parse(specs, df.order, universe))


def interval(universe, r):
    return None if r.frustrated else (universe.format(r.B), universe.format(r.A))


def test_overview_a_b_plus_c_printed_results_hold_for_a_times_b_plus_c():
    _, res = solve("a(b+c)", OVERVIEW)
    assert res["a"].frustrated  # A = {β}, B = 1
    assert (AB.format(res["a"].A), AB.format(res["a"].B)) == ("{beta}", "1")
    assert interval(AB, res["b"]) == ("{beta}", "1")
    assert interval(AB, res["c"]) == ("1", "1")


def test_overview_ab_plus_c_with_the_same_matrix():
    df, res = solve("ab+c", OVERVIEW)
    assert interval(AB, res["a"]) == ("{beta}", "{beta}")
    assert interval(AB, res["b"]) == ("{beta}", "1")
    assert interval(AB, res["c"]) == ("{beta}", "1")
    forms = {s: canonical_form(df, s).text() for s in df.order}
    assert forms == {  # the paper's (5)-(7)
        "a": "a = (b+c)a + c·not(a)",
        "b": "b = (a+c)b + c·not(b)",
        "c": "c = c + ab·not(c)",
    }


def test_example2_influence_table():
    df, res = solve(
        "a+bc", ["a>b={alpha}", "a>c=0", "b>a={alpha}", "b>c={beta}", "c>a={beta}", "c>b=0"]
    )
    assert interval(AB, res["a"]) == ("0", "1")
    assert interval(AB, res["b"]) == ("{alpha}", "{alpha}")
    assert interval(AB, res["c"]) == ("0", "{beta}")
    forms = {s: canonical_form(df, s).text() for s in df.order}
    assert forms == {
        "a": "a = a + bc·not(a)",
        "b": "b = (a+c)b + a·not(b)",
        "c": "c = (a+b)c + a·not(c)",
    }


@pytest.mark.parametrize("delta", ["0", "1"])
def test_example3_gate(delta):
    specs = [f"{s}>{d}=0" for s in "abc" for d in "abcd" if s != d]
    specs += [f"d>{x}={delta}" for x in "abc"]
    df, res = solve("abc+d", specs, GATE)
    assert df.text() == "abc+d"
    for x in "abc":
        assert interval(GATE, res[x]) == (delta, delta)
    assert interval(GATE, res["d"]) == ("0", "1")
    forms = {s: canonical_form(df, s).text() for s in df.order}
    assert forms == {
        "a": "a = (bc+d)a + d·not(a)",
        "b": "b = (ac+d)b + d·not(b)",  # docs/errata.md: the paper prints (ad+c)
        "c": "c = (ab+d)c + d·not(c)",
        "d": "d = d + abc·not(d)",
    }


def test_choices_and_frustration():
    df = decision_function(parse_polynomial("ab+c"))
    r = evaluate(df, AB, "b", {"a": 0b01, "c": 0b10})
    assert [AB.format(c) for c in r.choices(AB)] == ["{beta}", "1"]
    r = evaluate(df, AB, "a", {"b": 0, "c": 0b11})
    assert not r.frustrated and r.choices(AB) == [AB.full]


def test_symbolic_canonical_forms_equal_the_cofactors_on_random_groups():
    rng = random.Random(11)
    for n in range(1, 8):
        order = [chr(97 + i) for i in range(n)]
        for _ in range(15):
            df = decision_function(random_polynomial(order, rng), order)
            full = (1 << (1 << n)) - 1
            for i, x in enumerate(order):
                form = canonical_form(df, x)
                xt = variable_table(i, n)
                # A(x=anything) must equal F with x forced to 1; B with x forced to 0.
                a_expected = (df.table & xt) | ((df.table & xt) >> (1 << i))
                b_expected = (df.table & (full ^ xt)) | ((df.table & (full ^ xt)) << (1 << i))
                assert truth_table(form.A, order) == a_expected
                assert truth_table(form.B, order) == b_expected


def test_forward_matches_per_action_truth_table_lookup():
    rng = random.Random(5)
    u = Universe(("p", "q", "r"))
    for n in range(2, 7):
        order = [chr(97 + i) for i in range(n)]
        for _ in range(10):
            df = decision_function(random_polynomial(order, rng), order)
            x = rng.choice(order)
            on = {s: rng.randrange(8) for s in order if s != x}
            res = evaluate(df, u, x, on)
            for j in range(u.k):
                idx = sum((on[s] >> j & 1) << order.index(s) for s in on)
                xi = 1 << order.index(x)
                assert res.A >> j & 1 == df.table >> (idx | xi) & 1
                assert res.B >> j & 1 == df.table >> idx & 1


@pytest.mark.parametrize(
    ("specs", "needle"),
    [
        (["a>b={alpha}"], "missing influence b>a \\(on subject a\\)"),
        (["a>a=1"], "does not influence itself"),
        (["a>z=1"], "unknown subject 'z'"),
        (["a>b=1", "a>b=0"], "given twice"),
        (["a-b=1"], "bad influence"),
        (["a>b"], "bad influence"),
        (["a>b={gamma}"], "unknown action 'gamma'"),
    ],
)
def test_influence_errors(specs, needle):
    df = decision_function(parse_polynomial("ab+c"))
    with pytest.raises(RgtbusError, match=needle):
        forward(df, AB, InfluenceMatrix.parse(specs, df.order, AB))


def test_an_influence_matrix_from_a_mapping_refuses_what_set_refuses():
    """The mapping is read in one pass (a unit decides on n² influences a round), each bad
    entry still named as ``set`` names it."""
    from rgtbus.pairs import PairTable

    u = Universe(["alpha", "beta"])
    t = PairTable(["a", "b", "c"])
    t.update({("a", "b"): 1, ("b", "a"): 3, ("c", "a"): 0})
    m = InfluenceMatrix.from_mapping(t, ["a", "b", "c"], u)
    assert dict(m.items()) == dict(t.items())
    for bad, message in [
        ({("a", "a"): 1}, "does not influence itself"),
        ({("a", "z"): 1}, "unknown subject 'z'"),
        ({("a", "b"): 9}, "outside the algebra"),
    ]:
        with pytest.raises(RgtbusError, match=message):
            InfluenceMatrix.from_mapping(bad, ["a", "b", "c"], u)


def test_an_equal_f_built_apart_gets_the_same_canonical_forms():
    """Units build equal Fs apart: each subject's form is worked out on the first one's
    displayed form (its nodes are the ones the memo and the holders name), and is right."""
    rng = random.Random(23)
    order = [chr(97 + i) for i in range(7)]
    full = (1 << (1 << 7)) - 1
    for _ in range(5):
        poly = random_polynomial(order, rng)
        first = decision_function(poly, order)
        second = dataclasses.replace(  # built apart: nodes of its own
            first,
            polynomial=copy.deepcopy(first.polynomial),
            structural=copy.deepcopy(first.structural),
        )
        assert first == second and first is not second
        assert second.display == first.display and second.display is not first.display
        canonical_form(first, order[0])  # the first F asked first
        for i, x in enumerate(order[1:], start=1):
            form = canonical_form(second, x)
            xt = variable_table(i, 7)
            assert truth_table(form.A, order) == (second.table & xt) | (
                (second.table & xt) >> (1 << i)
            )
            assert truth_table(form.B, order) == (second.table & (full ^ xt)) | (
                (second.table & (full ^ xt)) << (1 << i)
            )


def test_substitute_within_the_holders_visits_only_them():
    from rgtbus.rgt.expr import ONE, ZERO, holders, substitute, variables

    rng = random.Random(5)
    order = [chr(97 + i) for i in range(8)]
    for _ in range(20):
        e = decision_function(random_polynomial(order, rng), order).display
        held = holders(e)
        assert sorted(held) == sorted(variables(e))
        for x in variables(e):
            for value in (ONE, ZERO):
                assert substitute(e, {x: value}, within=held[x]) == substitute(e, {x: value})
        # a variable the form does not hold: nothing to visit, the form itself
        assert substitute(e, {"zz": ONE}, within=frozenset()) == substitute(e, {})
        assert variables(e, most=2) == variables(e)[:2]


def test_an_expression_pickles_without_its_hash():
    """A node keeps its hash once worked out; a string's hash differs from process to
    process, so a pickled node works its own out again."""
    import pickle

    from rgtbus.rgt.expr import Not, Prod, Sum, Var

    e = Sum((Prod((Var("a"), Not(Var("b")))), Var("c")))
    h = hash(e)
    assert h == hash((e.terms,))  # the dataclass's own value
    back = pickle.loads(pickle.dumps(e))
    assert back == e and back._hash is None and hash(back) == h
    assert {e: 1}[back] == 1
