"""Stratification tree, diagonal form, folding and the decision function F.

The Polynomial Stratification Tree (PST) is the flattened polynomial itself: every non-leaf node
is a sum or a product of its children, levels alternating. In the diagonal form each non-leaf
node carries its children, joined by its operation, as its exponent, with ``P^W = P + not(W)``.

Folding, bottom-up::

    fold(x) = x                                   (a leaf)
    fold(N) = N + not(W),  W = op(fold(child) for child of N)

where N is the node's own (unfolded) polynomial and ``op`` its operation. ``F = fold(root)``.

Folding needs no truth table: ``N + not(W)`` is F's node whatever W is. Tables only make the
result shorter (W ≡ 1 gives N, W ≡ N gives 1), so they are used for nodes over at most
``EXACT_VARS`` subjects; a larger node is simplified structurally (constants, absorption,
x + not(x)), which is the same function and scales to groups of hundreds (docs/model.md).
F's own truth table (2^n bits) is built only when asked for: the inverse task (``control``)
needs it and is refused beyond ``EXACT_VARS`` subjects.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

from rgtbus.errors import BadInput
from rgtbus.rgt.expr import (
    MAX_TABLE_VARS,
    ONE,
    Expr,
    Not,
    Prod,
    Sum,
    Var,
    compile_masks,
    format_expr,
    minimal_sop,
    needs_star,
    readable,
    simplify,
    support,
    truth_table,
    variables,
)
from rgtbus.rgt.polynomial import is_polynomial

EXACT_VARS = MAX_TABLE_VARS  # nodes and groups up to this size use truth tables


def fold(poly: Expr) -> Expr:
    """The structural fold ``N + not(W)`` of every node, locally simplified."""
    if isinstance(poly, Var):
        return poly
    if isinstance(poly, Sum):
        w: Expr = Sum(tuple(fold(t) for t in poly.terms))
    elif isinstance(poly, Prod):
        w = Prod(tuple(fold(f) for f in poly.factors))
    else:
        raise BadInput(f"cannot fold {format_expr(poly)!r}: not a polynomial")
    w = simplify(w)
    if w == ONE:
        return poly  # N + not(1) = N
    if w == simplify(poly):
        return ONE  # N + not(N) = 1
    names = variables(poly)
    if len(names) <= EXACT_VARS:
        table = truth_table(w, names)
        if table == (1 << (1 << len(names))) - 1:
            return poly
        if table == truth_table(poly, names):
            return ONE
    return simplify(Sum((poly, Not(w))))


@dataclass(frozen=True)
class DecisionFunction:
    """F for one polynomial: structural and displayed forms, truth table, mask evaluator.

    ``display`` is the structural fold (``a(b+c)+not(a)``), except where folding eliminates
    subjects altogether: then the minimal sum of products shows it (``(a+b)c+d`` -> ``c+d``).
    """

    polynomial: Expr
    order: tuple[str, ...]
    structural: Expr
    _masks: dict[int, Callable[..., int]] = field(default_factory=dict, repr=False, compare=False)

    @cached_property
    def table(self) -> int:
        """F's truth table over ``order`` (2^n bits); RgtbusError beyond ``EXACT_VARS``."""
        if self.n > EXACT_VARS:
            raise BadInput(
                f"F's truth table over {self.n} subjects has 2^{self.n} entries: built only for "
                f"groups of at most {EXACT_VARS} (the inverse task needs it; the forward task "
                "does not)"
            )
        return truth_table(self.structural, self.order)

    @cached_property
    def display(self) -> Expr:
        """Computed on first use: minimisation is for people, not for the solvers."""
        names = self.order
        display = readable(self.structural, names)
        if self.n > EXACT_VARS:
            return display
        if len(support(self.table, len(names))) < len(names):
            # Folding eliminated subjects: show that rather than a form that hides it.
            reduced = minimal_sop(self.table, names)
            if reduced is not None:
                display = reduced
        return display

    @property
    def n(self) -> int:
        """The number of subjects."""
        return len(self.order)

    def text(self) -> str:
        """F as text (its display form)."""
        return format_expr(self.display, needs_star(self.order))

    def index(self, subject: str) -> int:
        """A subject's position in F's order; refused for an unknown subject."""
        try:
            return self.order.index(subject)
        except ValueError:
            raise BadInput(
                f"unknown subject {subject!r} (subjects: {', '.join(self.order)})"
            ) from None

    def mask_function(self, full: int) -> Callable[..., int]:
        """``f(*masks) -> mask`` for alternatives over a universe with mask ``full``."""
        fn = self._masks.get(full)
        if fn is None:
            fn = compile_masks(self.structural, self.order, full)
            self._masks[full] = fn
        return fn


def decision_function(poly: Expr, order: Sequence[str] | None = None) -> DecisionFunction:
    """F of a polynomial over the subjects in ``order`` (default: order of appearance).

    Pure and cached: every unit of a group that decoded the same polynomial shares one F.
    """
    if not is_polynomial(poly):
        raise BadInput(f"{format_expr(poly)!r} is not a polynomial of a relationship graph")
    names = tuple(order) if order is not None else tuple(variables(poly))
    if sorted(names) != sorted(variables(poly)):
        raise BadInput(f"subjects {list(names)} do not match the polynomial's variables")
    return _decision_function(poly, names)


@lru_cache(maxsize=512)
def _decision_function(poly: Expr, names: tuple[str, ...]) -> DecisionFunction:
    return DecisionFunction(poly, names, fold(poly))


# ---------------------------------------------------------------------------------------------
# Text renderings


def _bracket(e: Expr, star: bool) -> str:
    return f"[{format_expr(e, star)}]"


def stratification_text(poly: Expr) -> str:
    """The PST as an indented tree, root first."""
    star = needs_star(variables(poly))
    lines: list[str] = []

    def walk(x: Expr, depth: int) -> None:
        op = ""
        if isinstance(x, Sum):
            op = "  (+ conflict)"
        elif isinstance(x, Prod):
            op = "  (· alliance)"
        lines.append("  " * depth + _bracket(x, star) + op)
        if isinstance(x, Sum | Prod):
            for c in x.terms if isinstance(x, Sum) else x.factors:
                walk(c, depth + 1)

    walk(poly, 0)
    return "\n".join(lines)


def diagonal_text(poly: Expr, folded: Expr | None = None) -> str:
    """The diagonal form drawn the paper's way: each node's exponent up and to the right.

    ``ab+c`` becomes::

                [a][b]
            [ab]      +[c]
        [ab+c]

    With ``folded`` given, ``= F`` is written at the end of the root's line.
    """
    star = needs_star(variables(poly))
    cells: list[tuple[int, int, str]] = []  # (row from the bottom, column, text)

    def place(x: Expr, row: int, col: int) -> int:
        """Place node x at (row, col); return the first free column right of its drawing."""
        text = _bracket(x, star)
        cells.append((row, col, text))
        right = col + len(text)
        if isinstance(x, Sum | Prod):
            kids = x.terms if isinstance(x, Sum) else x.factors
            c = right
            for i, k in enumerate(kids):
                if i and isinstance(x, Sum):
                    cells.append((row + 1, c, "+"))
                    c += 1
                c = place(k, row + 1, c)
            right = max(right, c)
        return right

    end = place(poly, 0, 0)
    if folded is not None:
        cells.append((0, end + 1, f"= {format_expr(folded, star)}"))
    height = max(r for r, _, _ in cells) + 1
    rows = [[" "] * 0 for _ in range(height)]
    for r, c, text in sorted(cells, key=lambda t: (t[0], t[1])):
        line = rows[r]
        if len(line) < c:
            line.extend(" " * (c - len(line)))
        line[c : c + len(text)] = list(text)
    return "\n".join("".join(line).rstrip() for line in reversed(rows))


def diagonal_inline(poly: Expr) -> str:
    """One-line diagonal form: ``[ab+c]^([ab]^([a][b]) + [c])``."""
    star = needs_star(variables(poly))

    def d(x: Expr) -> str:
        if isinstance(x, Var):
            return _bracket(x, star)
        kids = x.terms if isinstance(x, Sum) else x.factors  # type: ignore[attr-defined]
        sep = " + " if isinstance(x, Sum) else ""
        return f"{_bracket(x, star)}^({sep.join(d(k) for k in kids)})"

    return d(poly)
