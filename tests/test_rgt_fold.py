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
