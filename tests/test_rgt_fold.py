import random

import pytest

from rgtbus.errors import RgtbusError
from rgtbus.rgt import (
    decision_function,
    diagonal_inline,
    diagonal_text,
    parse_polynomial,
    random_polynomial,
    stratification_text,
)
from rgtbus.rgt.expr import Not, Var, truth_table

# docs/model.md: the fold table.
FOLDS = [
    ("a+b", "1"),
    ("ab", "1"),
    ("abc", "1"),
    ("a+b+c", "1"),
    ("ab+c", "ab+c"),
    ("abc+d", "abc+d"),
    ("a+bc", "a+bc"),
    ("(a+b)(c+d)", "(a+b)(c+d)"),
    ("a(b+c)", "a(b+c)+not(a)"),
    ("(a+b)c+d", "c+d"),
    ("a", "a"),
]


@pytest.mark.parametrize(("poly", "folded"), FOLDS)
def test_fold_table(poly, folded):
    assert decision_function(parse_polynomial(poly)).text() == folded


def reference_fold_table(poly, order):
    """docs/model.md's rule, on truth tables directly: fold(N) = N + not(op(fold(children)))."""
    from rgtbus.rgt.expr import Prod, Sum

    n = len(order)
    full = (1 << (1 << n)) - 1

    def fold(x):
        if isinstance(x, Var):
            return truth_table(x, order)
        kids = [fold(c) for c in (x.terms if isinstance(x, Sum) else x.factors)]
        w = 0 if isinstance(x, Sum) else full
        for k in kids:
            w = w | k if isinstance(x, Sum) else w & k
        return truth_table(x, order) | (full ^ w)

    assert isinstance(poly, Sum | Prod | Var)
    return fold(poly)


def test_fold_matches_the_rule_on_random_groups():
    rng = random.Random(3)
    for n in range(1, 9):
        order = [chr(97 + i) for i in range(n)]
        for _ in range(25):
            poly = random_polynomial(order, rng)
            df = decision_function(poly, order)
            expected = reference_fold_table(poly, order)
            assert df.table == expected
            assert truth_table(df.display, order) == expected  # the printed form is F too


def test_diagonal_form_of_ab_plus_c_is_drawn_as_in_the_paper():
    poly = parse_polynomial("ab+c")
    assert diagonal_text(poly).splitlines() == [
        "          [a][b]",
        "      [ab]      +[c]",
        "[ab+c]",
    ]
    assert diagonal_text(poly, decision_function(poly).display).splitlines()[-1].endswith("= ab+c")
    assert diagonal_inline(poly) == "[ab+c]^([ab]^([a][b]) + [c])"


def test_diagonal_form_of_the_gate():
    text = diagonal_text(parse_polynomial("abc+d"))
    assert text.splitlines() == ["            [a][b][c]", "       [abc]         +[d]", "[abc+d]"]


def test_stratification_tree_levels_alternate():
    text = stratification_text(parse_polynomial("(a+b)c+d"))
    assert text.splitlines() == [
        "[(a+b)c+d]  (+ conflict)",
        "  [(a+b)c]  (· alliance)",
        "    [a+b]  (+ conflict)",
        "      [a]",
        "      [b]",
        "    [c]",
        "  [d]",
    ]


def test_decision_function_refuses_non_polynomials():
    with pytest.raises(RgtbusError, match="not a polynomial"):
        decision_function(Not(Var("a")))
    with pytest.raises(RgtbusError, match="do not match"):
        decision_function(parse_polynomial("ab"), ["a", "c"])


def reference_fold_masks(poly, values, full):
    """The same rule evaluated at one point: alternatives (bit masks) for every subject, with
    no table and no simplification: fold(N) = N + not(op(fold(children)))."""
    from rgtbus.rgt.expr import Sum

    def plain(x):
        if isinstance(x, Var):
            return values[x.name]
        kids = [plain(c) for c in (x.terms if isinstance(x, Sum) else x.factors)]
        acc = 0 if isinstance(x, Sum) else full
        for k in kids:
            acc = acc | k if isinstance(x, Sum) else acc & k
        return acc

    def fold(x):
        if isinstance(x, Var):
            return values[x.name]
        kids = [fold(c) for c in (x.terms if isinstance(x, Sum) else x.factors)]
        w = 0 if isinstance(x, Sum) else full
        for k in kids:
            w = w | k if isinstance(x, Sum) else w & k
        return plain(x) | (full ^ w)

    return fold(poly)


@pytest.mark.parametrize("n", [17, 30, 50, 120])
def test_large_groups_fold_without_tables_to_the_same_function(n):
    """Beyond 16 subjects F is folded structurally (no 2^n table): still exactly the rule,
    checked at random points over a 3-action universe; the canonical forms agree with it."""
    from rgtbus.rgt import canonical_form
    from rgtbus.rgt.expr import compile_masks

    rng = random.Random(n)
    order = [f"u{i}" for i in range(n)]
    full = 0b111
    for _ in range(3):
        poly = random_polynomial(order, rng)
        df = decision_function(poly, order)
        f = df.mask_function(full)
        x = order[rng.randrange(n)]
        form = canonical_form(df, x)
        a = compile_masks(form.A, order, full)
        b = compile_masks(form.B, order, full)
        for _ in range(200):
            values = {s: rng.randrange(full + 1) for s in order}
            assert f(*(values[s] for s in order)) == reference_fold_masks(poly, values, full)
            with_x = dict(values, **{x: full})
            without = dict(values, **{x: 0})
            assert a(*(values[s] for s in order)) == f(*(with_x[s] for s in order))
            assert b(*(values[s] for s in order)) == f(*(without[s] for s in order))
        with pytest.raises(RgtbusError, match=r"2\^\d+ entries: built only for groups of at most"):
            df.table  # noqa: B018 - the inverse task's table is refused, by name
