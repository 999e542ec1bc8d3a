"""Boolean expressions over subject variables: the terms RGT computes with.

A polynomial of a relationship graph uses only ``Var``, ``Sum`` (conflict, OR) and ``Prod``
(alliance, AND), each variable once. Folding adds ``Not`` and constants. Values are alternatives
(bitmasks), so every operation is bitwise and an expression is fully described by its two-valued
truth table; ``truth_table`` computes it bit-parallel as one Python integer with 2^n bits
(bit ``m`` = value at the assignment whose bit i is variable i).
"""

from __future__ import annotations

from collections.abc import Callable, Container, Sequence
from dataclasses import dataclass, field
from functools import cache

from rgtbus.errors import BadInput


class Expr:
    """Base of the expression tree (immutable, hashable, structural equality)."""

    __slots__ = ()

    def __str__(self) -> str:
        return format_expr(self)


@dataclass(frozen=True, slots=True)
class Var(Expr):
    """A subject variable."""

    name: str


@dataclass(frozen=True, slots=True)
class Const(Expr):
    """The constant 1 (True) or 0 (False)."""

    value: bool


def _hash_once(node: Not | Sum | Prod, operands: object) -> int:
    """A node's hash: its operands' (a tuple's hash walks the whole subtree), worked out once
    and kept (simplifying sets of subtrees hashed a 300-subject F's nodes 1.7 million times for
    its canonical forms). The value is the one the dataclass would give; it is never pickled
    (a string's hash differs from process to process: ``__reduce__`` leaves it out)."""
    h = node._hash
    if h is None:
        h = hash((operands,))
        object.__setattr__(node, "_hash", h)
    return h


@dataclass(frozen=True, slots=True)
class Not(Expr):
    """Negation (complement in the algebra of alternatives)."""

    arg: Expr
    _hash: int | None = field(default=None, init=False, repr=False, compare=False)

    def __hash__(self) -> int:
        return _hash_once(self, self.arg)

    def __reduce__(self) -> tuple[type[Not], tuple[Expr]]:
        return (Not, (self.arg,))


@dataclass(frozen=True, slots=True)
class Sum(Expr):
    """Disjunction: conflict between the terms."""

    terms: tuple[Expr, ...]
    _hash: int | None = field(default=None, init=False, repr=False, compare=False)

    def __hash__(self) -> int:
        return _hash_once(self, self.terms)

    def __reduce__(self) -> tuple[type[Sum], tuple[tuple[Expr, ...]]]:
        return (Sum, (self.terms,))


@dataclass(frozen=True, slots=True)
class Prod(Expr):
    """Conjunction: alliance between the factors."""

    factors: tuple[Expr, ...]
    _hash: int | None = field(default=None, init=False, repr=False, compare=False)

    def __hash__(self) -> int:
        return _hash_once(self, self.factors)

    def __reduce__(self) -> tuple[type[Prod], tuple[tuple[Expr, ...]]]:
        return (Prod, (self.factors,))


ONE = Const(True)
ZERO = Const(False)


def children(e: Expr) -> tuple[Expr, ...]:
    """The operands of a sum or a product (a leaf or a negation: none)."""
    if isinstance(e, Sum):
        return e.terms
    if isinstance(e, Prod):
        return e.factors
    if isinstance(e, Not):
        return (e.arg,)
    return ()


def variables(e: Expr, most: int | None = None) -> list[str]:
    """Variable names in order of first appearance (left to right); only the first ``most``
    when given (the walk stops there)."""
    out: list[str] = []
    seen: set[str] = set()

    def walk(x: Expr) -> None:
        if most is not None and len(out) >= most:
            return
        if isinstance(x, Var) and x.name not in seen:
            seen.add(x.name)
            out.append(x.name)
        for c in children(x):
            walk(c)

    walk(e)
    return out


def holders(e: Expr) -> dict[str, frozenset[int]]:
    """Per variable, the ids of the nodes of ``e`` whose subtree holds it (its leaves
    included): what ``substitute`` must visit to replace it (valid while ``e`` lives)."""
    found: dict[str, set[int]] = {}
    path: list[int] = []

    def walk(x: Expr) -> None:
        path.append(id(x))
        if isinstance(x, Var):
            found.setdefault(x.name, set()).update(path)
        for c in children(x):
            walk(c)
        path.pop()

    walk(e)
    return {name: frozenset(ids) for name, ids in found.items()}


def needs_star(names: Sequence[str]) -> bool:
    """Multi-letter names are written with an explicit ``*`` for products."""
    return any(len(n) > 1 for n in names)


def format_expr(e: Expr, star: bool | None = None) -> str:
    """Print in the paper's notation: ``ab+c``, ``a(b+c)+not(a)``, ``robot1*robot2+robot3``.

    Products of single-letter variables are juxtaposed; a ``not(...)`` factor is joined with
    ``·`` so it reads unambiguously; with multi-letter names every product uses ``*``.
    """
    if star is None:
        star = needs_star(variables(e))

    def fmt(x: Expr) -> str:
        if isinstance(x, Var):
            return x.name
        if isinstance(x, Const):
            return "1" if x.value else "0"
        if isinstance(x, Not):
            return f"not({fmt(x.arg)})"
        if isinstance(x, Sum):
            return "+".join(fmt(t) for t in x.terms)
        if isinstance(x, Prod):
            parts: list[str] = []
            prev: Expr | None = None
            for f in x.factors:
                text = f"({fmt(f)})" if isinstance(f, Sum) else fmt(f)
                if prev is not None:
                    if star:
                        parts.append("*")
                    elif isinstance(f, Not | Const) or isinstance(prev, Not | Const):
                        parts.append("·")
                parts.append(text)
                prev = f
            return "".join(parts)
        raise TypeError(f"not an expression: {x!r}")

    return fmt(e)


# ---------------------------------------------------------------------------------------------
# Local simplification (keeps the paper's shape; no global minimisation)


# simplify's answers by the very object asked (the object is held with its answer, so its id
# is not reused while the entry lives): for the subtrees of one large expression that many
# substitutions leave as they are (``substitute``'s ``memo``)
Memo = dict[int, tuple[Expr, Expr]]


def simplify(e: Expr, memo: Memo | None = None) -> Expr:
    """Constants, flattening, double negation, duplicates, ``x+not(x)=1``, ``x·not(x)=0``,
    and absorption (``x + x·y = x``, ``x·(x+y) = x``). ``memo``: answers kept by object
    (the same answers; a subtree asked again costs a lookup)."""
    if isinstance(e, Var | Const):
        return e
    if memo is not None:
        got = memo.get(id(e))
        if got is not None and got[0] is e:
            return got[1]
        out = _simplify(e, memo)
        memo[id(e)] = (e, out)
        return out
    return _simplify(e, None)


def _simplify(e: Expr, memo: Memo | None) -> Expr:
    if isinstance(e, Not):
        a = simplify(e.arg, memo)
        if isinstance(a, Const):
            return Const(not a.value)
        if isinstance(a, Not):
            return a.arg
        return Not(a)
    is_sum = isinstance(e, Sum)
    kind = Sum if is_sum else Prod
    absorbing = ONE if is_sum else ZERO
    neutral = ZERO if is_sum else ONE
    items: list[Expr] = []
    seen: set[Expr] = set()  # the items, for lookups (a sum of n terms: n, not n², compares)
    for c in children(e):
        s = simplify(c, memo)
        if s == absorbing:
            return absorbing
        if s == neutral:
            continue
        for part in children(s) if isinstance(s, kind) else (s,):
            if part not in seen:
                seen.add(part)
                items.append(part)
    for x in items:
        if isinstance(x, Not):
            y = x.arg
            # x + not(x) = 1 and x·not(x) = 0, also when x was flattened into the items.
            if y in seen or (isinstance(y, kind) and all(p in seen for p in children(y))):
                return absorbing
    dual = Prod if is_sum else Sum
    # Absorption: drop a dual term that contains another item as one of its parts (an item
    # is never a part of itself).
    kept = []
    for x in items:
        if isinstance(x, dual) and any(p in seen for p in children(x)):
            continue
        kept.append(x)
    if not kept:
        return neutral
    if len(kept) == 1:
        return kept[0]
    return kind(tuple(kept))


def substitute(
    e: Expr,
    values: dict[str, Expr],
    memo: Memo | None = None,
    within: Container[int] | None = None,
) -> Expr:
    """Replace variables by expressions (typically constants), then simplify. A subtree with
    no variable replaced stays the very same object, so with a ``memo`` kept for ``e``
    (every subject's canonical form substitutes into one F) it is simplified once.
    ``within``: the ids of the nodes that hold a replaced variable (``holders``); the others
    are not visited."""

    def sub(x: Expr) -> Expr:
        if within is not None and id(x) not in within:
            return x
        if isinstance(x, Var):
            return values.get(x.name, x)
        if isinstance(x, Not):
            a = sub(x.arg)
            return x if a is x.arg else Not(a)
        if isinstance(x, Sum | Prod):
            parts = children(x)
            new = tuple(sub(p) for p in parts)
            if all(a is b for a, b in zip(new, parts, strict=True)):
                return x
            return Sum(new) if isinstance(x, Sum) else Prod(new)
        return x

    return simplify(sub(e), memo)


# ---------------------------------------------------------------------------------------------
# Truth tables and evaluation


@cache
def variable_table(i: int, n: int) -> int:
    """Truth table of variable i over n variables: bit m set iff bit i of m is set."""
    width = 1 << i
    table = ((1 << width) - 1) << width
    period = width << 1
    total = 1 << n
    while period < total:
        table |= table << period
        period <<= 1
    return table


def truth_table(e: Expr, order: Sequence[str]) -> int:
    """Bit-parallel truth table of ``e`` over the variables in ``order`` (2^n bits)."""
    n = len(order)
    full = (1 << (1 << n)) - 1
    index = {name: i for i, name in enumerate(order)}

    def ev(x: Expr) -> int:
        if isinstance(x, Var):
            try:
                return variable_table(index[x.name], n)
            except KeyError:
                raise BadInput(f"variable {x.name!r} is not one of {list(order)}") from None
        if isinstance(x, Const):
            return full if x.value else 0
        if isinstance(x, Not):
            return full ^ ev(x.arg)
        if isinstance(x, Sum):
            acc = 0
            for t in x.terms:
                acc |= ev(t)
            return acc
        if isinstance(x, Prod):
            acc = full
            for f in x.factors:
                acc &= ev(f)
            return acc
        raise TypeError(f"not an expression: {x!r}")

    return ev(e)


def compile_masks(e: Expr, order: Sequence[str], full: int) -> Callable[..., int]:
    """Compile ``e`` into ``f(*masks) -> mask``: whole-alternative evaluation, one call.

    This is the straightforward set-level evaluator, independent of the truth-table path, so the
    two can cross-check each other.
    """
    index = {name: i for i, name in enumerate(order)}

    def src(x: Expr) -> str:
        if isinstance(x, Var):
            if x.name not in index:
                raise BadInput(f"variable {x.name!r} is not one of {list(order)}")
            return f"v{index[x.name]}"
        if isinstance(x, Const):
            return str(full if x.value else 0)
        if isinstance(x, Not):
            return f"({full} ^ {src(x.arg)})"
        if isinstance(x, Sum):
            return "(" + " | ".join(src(t) for t in x.terms) + ")"
        if isinstance(x, Prod):
            return "(" + " & ".join(src(f) for f in x.factors) + ")"
        raise TypeError(f"not an expression: {x!r}")

    params = ", ".join(f"v{i}" for i in range(len(order)))
    # The source is generated from our own tree: variable indexes and integers only.
    fn: Callable[..., int] = eval(f"lambda {params}: {src(e)}", {"__builtins__": {}})
    return fn


def support(table: int, n: int) -> list[int]:
    """Indexes of the variables the function really depends on."""
    out = []
    for i in range(n):
        v = variable_table(i, n)
        hi = (table & v) >> (1 << i)
        lo = table & (v >> (1 << i))
        if hi != lo:
            out.append(i)
    return out


# ---------------------------------------------------------------------------------------------
# Minimal sum of products (Quine-McCluskey with a greedy cover), for small supports


MAX_MINIMISE_VARS = 10
# Truth tables are built over at most this many variables (2^16 bits); larger expressions are
# handled structurally (rgtbus.rgt.diagonal).
MAX_TABLE_VARS = 16


def _prime_implicants(minterms: Sequence[int], m: int) -> set[tuple[int, int]]:
    """Every prime implicant of the function with these minterms, as (value, care-mask).

    Bit-parallel over the truth table: ``cubes[free]`` has bit v set when every minterm
    ``v | s`` (s within ``free``) is in the function, i.e. the cube (v, free) is an implicant;
    adding a free variable j keeps v when v's neighbour across j is there too. A cube is prime
    when no cube with one more free variable contains it."""
    size = 1 << m
    table = 0
    for t in minterms:
        table |= 1 << t
    low = [0] * m  # positions v with bit j clear
    for j in range(m):
        block = (1 << (1 << j)) - 1  # 2^j ones, then 2^j zeros, repeated
        pattern = 0
        for start in range(0, size, 2 << j):
            pattern |= block << start
        low[j] = pattern
    cubes = {0: table}
    for free in range(1, size):
        j = (free & -free).bit_length() - 1
        base = cubes.get(free & (free - 1))
        if base:
            both = base & (base >> (1 << j)) & low[j]
            if both:
                cubes[free] = both
    care_all = size - 1
    primes: set[tuple[int, int]] = set()
    for free, c in cubes.items():
        covered = 0
        for j in range(m):
            bigger = cubes.get(free | 1 << j) if not free >> j & 1 else None
            if bigger:
                covered |= bigger | (bigger << (1 << j))
        rest = c & ~covered
        while rest:
            bit = rest & -rest
            primes.add((bit.bit_length() - 1, care_all ^ free))
            rest ^= bit
    return primes


def minimal_sop(table: int, order: Sequence[str]) -> Expr | None:
    """A minimal-ish sum of products equal to ``table``; None if the support is too large.

    Terms are ordered by the positions of their variables in ``order``, so results read like
    the paper (``bc+d``, not ``d+bc``).
    """
    n = len(order)
    full = (1 << (1 << n)) - 1
    if table == 0:
        return ZERO
    if table == full:
        return ONE
    sup = support(table, n)
    if len(sup) > MAX_MINIMISE_VARS:
        return None
    m = len(sup)
    minterms = []
    for r in range(1 << m):
        idx = 0
        for j, var in enumerate(sup):
            if r >> j & 1:
                idx |= 1 << var
        if table >> idx & 1:
            minterms.append(r)
    primes = _prime_implicants(minterms, m)

    # Cover, with each prime's minterms as a bitset over the minterm list (same choices and
    # order as testing every pair, without the quadratic cost).
    pos = {t: i for i, t in enumerate(minterms)}
    prime_list = sorted(primes, key=lambda p: (-(m - p[1].bit_count()), p))
    free_bits = [1 << j for j in range(m)]
    cov_sets: list[int] = []
    for value, mask in prime_list:
        free = [b for b in free_bits if not mask & b]
        bits = 0
        for r in range(1 << len(free)):
            t = value
            for j, b in enumerate(free):
                if r >> j & 1:
                    t |= b
            bits |= 1 << pos[t]
        cov_sets.append(bits)
    chosen: list[int] = []
    # Essential primes first (in minterm order), then greedy by coverage.
    for i in range(len(minterms)):
        bit = 1 << i
        cov = [k for k, c in enumerate(cov_sets) if c & bit]
        if len(cov) == 1 and cov[0] not in chosen:
            chosen.append(cov[0])
    remaining = (1 << len(minterms)) - 1
    for k in chosen:
        remaining &= ~cov_sets[k]
    while remaining:
        best = max(
            range(len(prime_list)),
            key=lambda k: ((cov_sets[k] & remaining).bit_count(), -prime_list[k][1].bit_count()),
        )
        chosen.append(best)
        remaining &= ~cov_sets[best]

    terms: list[tuple[tuple[int, ...], Expr]] = []
    for value, mask in (prime_list[k] for k in chosen):
        lits: list[tuple[int, Expr]] = []
        for j, var in enumerate(sup):
            if mask >> j & 1:
                v: Expr = Var(order[var])
                lits.append((var, v if value >> j & 1 else Not(v)))
        lits.sort(key=lambda p: p[0])
        expr = lits[0][1] if len(lits) == 1 else Prod(tuple(x for _, x in lits))
        terms.append((tuple(p[0] for p in lits), expr))
    terms.sort(key=lambda p: p[0])
    if len(terms) == 1:
        return terms[0][1]
    return Sum(tuple(e for _, e in terms))


def readable(local: Expr, order: Sequence[str]) -> Expr:
    """``local`` (the paper-shaped form), unless a minimal sum of products is much shorter.

    Deeply nested folds simplify locally into long ``not(...)`` chains; a sum of products 1.5x
    shorter reads better, while the paper's own forms (``a(b+c)+not(a)``) are kept.
    """
    # Over the variables ``local`` holds only (in ``order``): the same minimal form, without a
    # table of 2^n bits for a large group.
    present = set(variables(local, most=MAX_TABLE_VARS + 1))
    if len(present) > MAX_TABLE_VARS:
        return local
    order = [v for v in order if v in present]
    table = truth_table(local, order)
    sop = minimal_sop(table, order)
    if sop is None:
        return local
    star = needs_star(order)
    if 1.5 * len(format_expr(sop, star)) < len(format_expr(local, star)):
        return sop
    return local
