"""Relationship graphs and their polynomials.

A group is a complete graph over its subjects, each edge an alliance (``·``) or a conflict (``+``).
The graph is decomposable exactly when its alliance graph has no induced P4 (it is a cograph);
the polynomial is then built by recursion on a vertex set S:

* one vertex -> the variable;
* the alliance graph on S falls into several components -> the **sum** of their polynomials;
* else the conflict graph on S falls into several components -> their **product**;
* else S holds an induced P4 -> not decomposable (the error names the four subjects).

Nested sums and products are flattened, so levels alternate + and · (the stratification tree).
"""

from __future__ import annotations

import itertools
import random
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from rgtbus.errors import BadInput, NotDecomposable
from rgtbus.pairs import PairTable, unordered_slots
from rgtbus.rgt.expr import Const, Expr, Not, Prod, Sum, Var, format_expr, variables

_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def parse_polynomial(text: str) -> Expr:
    """Parse ``ab+c``, ``a(b+c)``, ``(a+b)c+d`` or ``robot1*robot2+robot3``.

    Without ``*`` every letter is a variable; with ``*`` anywhere, names are whole identifiers
    and every product is written with ``*`` (or by juxtaposing parentheses). Each variable must
    appear exactly once, as in the polynomial of a relationship graph.
    """
    if not text.strip():
        raise BadInput("empty polynomial")
    parser = _PolynomialParser(_tokens(text), text)
    expr = parser.sum()
    if parser.pos != len(parser.tokens):
        raise BadInput(f"unexpected {parser.where()} in polynomial {text!r}")
    seen: set[str] = set()
    for name in _all_var_occurrences(expr):
        if name in seen:
            raise BadInput(
                f"variable {name!r} appears twice in polynomial {text!r}: each subject appears once"
            )
        seen.add(name)
    return expr


_Token = tuple[str, str, int]  # (kind: "name" or the character, its text, its position)


def _tokens(text: str) -> list[_Token]:
    """The tokens of a polynomial: names (letters, or identifiers where ``*`` is written),
    ``+``, ``*`` and parentheses; refused at the first character that is none of them."""
    star = "*" in text
    tokens: list[_Token] = []
    i = 0
    while i < len(text):
        ch = text[i]
        if ch.isspace():
            i += 1
            continue
        if ch in "+*()":
            tokens.append((ch, ch, i))
            i += 1
            continue
        if star:
            m = _IDENT.match(text, i)
            if m:
                tokens.append(("name", m.group(), i))
                i = m.end()
                continue
        elif ch.isalpha():
            tokens.append(("name", ch, i))
            i += 1
            continue
        hint = ""
        if not star and (ch.isdigit() or ch == "_"):
            hint = " (multi-letter names need '*', e.g. robot1*robot2+robot3)"
        raise BadInput(f"bad token {ch!r} at position {i} in polynomial {text!r}{hint}")
    return tokens


class _PolynomialParser:
    """Recursive descent over a polynomial's tokens: sum := prod ('+' prod)*,
    prod := factor ('*'? factor)*, factor := name | '(' sum ')'."""

    def __init__(self, tokens: list[_Token], text: str) -> None:
        self.tokens = tokens
        self.text = text
        self.pos = 0

    def peek(self) -> _Token | None:
        """The next token (None at the end)."""
        return self.tokens[self.pos] if self.pos < len(self.tokens) else None

    def where(self) -> str:
        """The next token and its position, for an error."""
        t = self.peek()
        return f"{t[1]!r} at position {t[2]}" if t else "end of input"

    def sum(self) -> Expr:
        """A sum of products (one product: itself), nested sums flattened."""
        terms = [self.prod()]
        while (t := self.peek()) and t[0] == "+":
            self.pos += 1
            terms.append(self.prod())
        return terms[0] if len(terms) == 1 else Sum(tuple(_flatten(terms, Sum)))

    def prod(self) -> Expr:
        """A product of factors (one factor: itself), nested products flattened."""
        factors = [self.factor()]
        while (t := self.peek()) and t[0] in ("*", "name", "("):
            if t[0] == "*":
                self.pos += 1
            factors.append(self.factor())
        return factors[0] if len(factors) == 1 else Prod(tuple(_flatten(factors, Prod)))

    def factor(self) -> Expr:
        """A variable, or a parenthesised sum."""
        t = self.peek()
        if t is None or t[0] in ("+", "*", ")"):
            raise BadInput(f"expected a variable or '(' but found {self.where()} in {self.text!r}")
        self.pos += 1
        if t[0] == "name":
            return Var(t[1])
        inner = self.sum()  # after "("
        close = self.peek()
        if close is None or close[0] != ")":
            raise BadInput(f"missing ')' for '(' at position {t[2]} in {self.text!r}")
        self.pos += 1
        return inner


def _all_var_occurrences(e: Expr) -> list[str]:
    if isinstance(e, Var):
        return [e.name]
    if isinstance(e, Sum | Prod):
        out: list[str] = []
        for c in e.terms if isinstance(e, Sum) else e.factors:
            out.extend(_all_var_occurrences(c))
        return out
    return []


def _flatten(items: Iterable[Expr], kind: type) -> list[Expr]:
    out: list[Expr] = []
    for x in items:
        if isinstance(x, kind):
            out.extend(x.terms if isinstance(x, Sum) else x.factors)  # type: ignore[attr-defined]
        else:
            out.append(x)
    return out


def is_polynomial(e: Expr) -> bool:
    """Only variables, sums and products, each variable once."""
    if isinstance(e, Const | Not):
        return False
    if isinstance(e, Sum | Prod):
        kids = e.terms if isinstance(e, Sum) else e.factors
        if not all(is_polynomial(c) for c in kids):
            return False
    names = _all_var_occurrences(e)
    return len(names) == len(set(names))


def canonical(e: Expr, order: Sequence[str] | None = None) -> Expr:
    """The same polynomial with children sorted by their first subject in ``order``."""
    rank = {n: i for i, n in enumerate(order if order is not None else sorted(variables(e)))}

    def key(x: Expr) -> int:
        return min(rank[n] for n in variables(x))

    def canon(x: Expr) -> Expr:
        if isinstance(x, Sum):
            return Sum(tuple(sorted((canon(t) for t in x.terms), key=key)))
        if isinstance(x, Prod):
            return Prod(tuple(sorted((canon(f) for f in x.factors), key=key)))
        return x

    return canon(e)


# ---------------------------------------------------------------------------------------------
# Graphs


def _pair(a: str, b: str) -> frozenset[str]:
    return frozenset((a, b))


@dataclass(frozen=True)
class RelationGraph:
    """A complete graph over ``subjects``; listed pairs are alliances, all others conflicts."""

    subjects: tuple[str, ...]
    alliances: frozenset[frozenset[str]]

    @classmethod
    def from_pairs(
        cls, subjects: Sequence[str], alliances: Iterable[tuple[str, str]]
    ) -> RelationGraph:
        """The graph over ``subjects`` with these alliances; refused for a bad or repeated subject
        name, an unknown subject or a subject allied with itself."""
        subs = tuple(subjects)
        if not subs:
            raise BadInput("a group needs at least one subject")
        for s in subs:
            if not _IDENT.fullmatch(s):
                raise BadInput(f"bad subject name {s!r}: use letters, digits and _")
        dup = [s for s in subs if subs.count(s) > 1]
        if dup:
            raise BadInput(f"subject {dup[0]!r} is listed twice")
        known = set(subs)
        pairs: set[frozenset[str]] = set()
        for a, b in alliances:
            for s in (a, b):
                if s not in known:
                    raise BadInput(f"unknown subject {s!r} in alliance {a}-{b}")
            if a == b:
                raise BadInput(f"alliance {a}-{b} joins a subject to itself")
            pairs.add(_pair(a, b))
        return cls(subs, frozenset(pairs))

    def allied(self, a: str, b: str) -> bool:
        """Whether ``a`` and ``b`` are allied."""
        return _pair(a, b) in self.alliances

    def edges(self) -> dict[tuple[str, str], str]:
        """``{(a, b): "alliance" | "conflict"}`` for every pair, in subject order."""
        return {
            (a, b): "alliance" if self.allied(a, b) else "conflict"
            for a, b in itertools.combinations(self.subjects, 2)
        }


def _components(vertices: Sequence[str], adjacent: Callable[[str, str], bool]) -> list[list[str]]:
    remaining = list(vertices)
    comps: list[list[str]] = []
    while remaining:
        start = remaining.pop(0)
        comp = [start]
        frontier = [start]
        while frontier:
            v = frontier.pop()
            for w in list(remaining):
                if adjacent(v, w):
                    remaining.remove(w)
                    comp.append(w)
                    frontier.append(w)
        order = {s: i for i, s in enumerate(vertices)}
        comps.append(sorted(comp, key=order.__getitem__))
    return comps


def find_p4(graph: RelationGraph, within: Sequence[str] | None = None) -> tuple[str, ...] | None:
    """An induced path a-b-c-d of alliances (a-c, a-d, b-d in conflict), or None."""
    vertices = list(within if within is not None else graph.subjects)
    for quad in itertools.combinations(vertices, 4):
        edges = [(x, y) for x, y in itertools.combinations(quad, 2) if graph.allied(x, y)]
        if len(edges) != 3:
            continue
        degree = {v: 0 for v in quad}
        for x, y in edges:
            degree[x] += 1
            degree[y] += 1
        if sorted(degree.values()) != [1, 1, 2, 2]:
            continue
        # Three edges with degrees 1,1,2,2 on four vertices is exactly a path: walk it.
        path = [next(v for v in quad if degree[v] == 1)]
        while len(path) < 4:
            path.append(next(v for v in quad if v not in path and graph.allied(path[-1], v)))
        return tuple(path)
    return None


def graph_to_polynomial(graph: RelationGraph) -> Expr:
    """The polynomial of a decomposable relationship graph (see the module docstring)."""

    def build(vs: list[str]) -> Expr:
        if len(vs) == 1:
            return Var(vs[0])
        comps = _components(vs, graph.allied)
        if len(comps) > 1:
            return Sum(tuple(build(c) for c in comps))
        comps = _components(vs, lambda a, b: not graph.allied(a, b))
        if len(comps) > 1:
            return Prod(tuple(build(c) for c in comps))
        p4 = find_p4(graph, vs)
        assert p4 is not None, "a prime graph on >= 2 vertices always holds an induced P4"
        a, b, c, d = p4
        raise NotDecomposable(
            f"relationship graph is not decomposable: induced P4 {a}-{b}-{c}-{d} "
            f"(alliances {a}-{b}, {b}-{c}, {c}-{d}; conflicts {a}-{c}, {a}-{d}, {b}-{d})",
            (a, b, c, d),
        )

    return build(list(graph.subjects))


def polynomial_to_graph(poly: Expr, subjects: Sequence[str] | None = None) -> RelationGraph:
    """Two subjects are allied iff their lowest common node is a product."""
    names = variables(poly)
    alliances: list[tuple[str, str]] = []

    def walk(x: Expr) -> None:
        if isinstance(x, Sum | Prod):
            kids = x.terms if isinstance(x, Sum) else x.factors
            if isinstance(x, Prod):
                for f1, f2 in itertools.combinations(kids, 2):
                    alliances.extend((a, b) for a in variables(f1) for b in variables(f2))
            for k in kids:
                walk(k)

    walk(poly)
    order = list(subjects) if subjects is not None else names
    if sorted(order) != sorted(names):
        raise BadInput(f"subjects {order} do not match the polynomial's variables {names}")
    return RelationGraph.from_pairs(order, alliances)


def polynomial_text(poly: Expr) -> str:
    """A polynomial as text (``format_expr``)."""
    return format_expr(poly)


def install_relations(
    subjects: Sequence[str], sent: Mapping[tuple[str, str], bool]
) -> RelationGraph:
    """The installed graph: a pair is allied iff both sent alliance to each other (AND).

    ``sent[(s, r)]`` is True when s sent the alliance code to r, False for conflict; every
    ordered pair of distinct subjects is needed.
    """
    if isinstance(sent, PairTable) and sent.units == tuple(subjects):  # a table: as arrays
        return _installed_of_table(sent)
    pairs = []
    for a, b in itertools.combinations(subjects, 2):
        for key in ((a, b), (b, a)):
            if key not in sent:
                raise BadInput(f"missing relationship code {key[0]}>{key[1]}")
        if sent[(a, b)] and sent[(b, a)]:
            pairs.append((a, b))
    return RelationGraph.from_pairs(subjects, pairs)


def _installed_of_table(sent: PairTable) -> RelationGraph:
    """``install_relations`` of a ``PairTable`` (n² slots read as arrays): the same graph, or
    the same refusal of the first missing code in pair order."""
    units = sent.units
    vals, held = sent.columns()
    ab, ba, _ = unordered_slots(units)
    missing = np.flatnonzero(~(held[ab] & held[ba]))
    if missing.size:
        k = int(missing[0])
        slot = int(ab[k]) if not held[ab[k]] else int(ba[k])
        s, r = divmod(slot, len(units))
        raise BadInput(f"missing relationship code {units[s]}>{units[r]}")
    allied = np.flatnonzero((vals[ab] != 0) & (vals[ba] != 0))
    graph = RelationGraph.from_pairs(units, ())  # the subjects checked
    n = len(units)
    pairs = frozenset(frozenset((units[i // n], units[i % n])) for i in ab[allied].tolist())
    return RelationGraph(graph.subjects, pairs)


def random_polynomial(subjects: Sequence[str], rng: random.Random) -> Expr:
    """A random decomposable group over ``subjects`` (a random cotree), flattened."""
    names = list(subjects)
    rng.shuffle(names)

    def build(vs: list[str], op: type[Sum] | type[Prod]) -> Expr:
        if len(vs) == 1:
            return Var(vs[0])
        parts = rng.randint(2, len(vs))
        cuts = sorted(rng.sample(range(1, len(vs)), parts - 1))
        groups = [vs[i:j] for i, j in zip([0, *cuts], [*cuts, len(vs)], strict=True)]
        other = Prod if op is Sum else Sum
        kids = [build(g, other) for g in groups]
        return op(tuple(kids))

    if not names:
        raise BadInput("a group needs at least one subject")
    return build(names, rng.choice((Sum, Prod)))
