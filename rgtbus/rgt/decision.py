"""Decision equations, canonical forms and the forward task.

For subject x the decision equation is ``x = F(x, others)``. Because every operation is bitwise,
``F(x) = A·x + B·not(x)`` with ``A = F(x=1)`` and ``B = F(x=0)`` (the canonical form). Its
solutions are exactly the alternatives with ``B ⊆ x ⊆ A``; if ``B ⊄ A`` the subject is
frustrated (no decision). The other variables take the influences *on x*: column x of the
influence matrix, whose row is the influencing subject.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from functools import lru_cache

from rgtbus.errors import BadInput, RgtbusError
from rgtbus.pairs import parse_pair_key
from rgtbus.rgt.algebra import Universe
from rgtbus.rgt.diagonal import DecisionFunction
from rgtbus.rgt.expr import (
    ONE,
    ZERO,
    Expr,
    Memo,
    Sum,
    format_expr,
    holders,
    needs_star,
    readable,
    substitute,
)


@dataclass(frozen=True)
class CanonicalForm:
    """``x = A·x + B·not(x)`` with A and B as expressions in the other subjects."""

    subject: str
    A: Expr
    B: Expr

    def text(self, star: bool = False) -> str:
        """The form as text, ``x = A·x + B·not(x)`` (``star``: products written with ``*``)."""
        x = self.subject

        def factor(e: Expr, var: str) -> str | None:
            if e == ZERO:
                return None
            if e == ONE:
                return var
            body = format_expr(e, star)
            if isinstance(e, Sum):
                body = f"({body})"
            if star:
                return f"{body}*{var}"
            # "(b+c)a" reads as the paper does; elsewhere "·" keeps names apart ("bc·a").
            joint = "" if body.endswith(")") and not var.startswith("not(") else "·"
            return f"{body}{joint}{var}"

        parts = [p for p in (factor(self.A, x), factor(self.B, f"not({x})")) if p]
        return f"{x} = " + (" + ".join(parts) if parts else "0")


def canonical_form(df: DecisionFunction, subject: str) -> CanonicalForm:
    """Subject's canonical form ``x = A·x + B·not(x)`` of F, with A = F(x=1) and B = F(x=0),
    minimised (cached per F and subject)."""
    df.index(subject)
    return _canonical_form(df, subject)


@lru_cache(maxsize=4096)
def _canonical_form(df: DecisionFunction, subject: str) -> CanonicalForm:
    # Minimising A and B is the costly part; units holding the same group share the result.
    memo = _memo(df)  # the subtrees without the subject: simplified once for every subject
    # the displayed form of the first F equal to this one (the memo's and the holders' nodes
    # are its own), and its nodes on the way to the subject: the others are not visited
    display, held = _holders(df)
    within = held.get(subject, frozenset())
    a = readable(substitute(display, {subject: ONE}, memo, within), df.order)
    b = readable(substitute(display, {subject: ZERO}, memo, within), df.order)
    return CanonicalForm(subject, a, b)


@lru_cache(maxsize=8)
def _holders(df: DecisionFunction) -> tuple[Expr, dict[str, frozenset[int]]]:
    """F's displayed form and, per subject, the ids of its nodes that hold it (kept with the
    form they name; an equal F met later gets this same form)."""
    display = df.display
    return display, holders(display)


@lru_cache(maxsize=8)
def _memo(df: DecisionFunction) -> Memo:
    """``simplify``'s answers for the subtrees of F's displayed form (kept with F)."""
    return {}


def canonical_forms(df: DecisionFunction) -> dict[str, CanonicalForm]:
    """Every subject's canonical form, in F's order."""
    return {s: canonical_form(df, s) for s in df.order}


# ---------------------------------------------------------------------------------------------
# Influences


class InfluenceMatrix:
    """``matrix[src, dst]``: the alternative subject ``src`` urges on subject ``dst``."""

    def __init__(self, subjects: Iterable[str], universe: Universe) -> None:
        self.subjects = tuple(subjects)
        self.universe = universe
        self._values: dict[tuple[str, str], int] = {}
        self._known = frozenset(self.subjects)  # a lookup, not a scan: n² influences a matrix

    def set(self, src: str, dst: str, value: int, origin: str = "") -> None:
        """Set the influence of ``src`` on ``dst``; refused for an unknown subject, a subject on
        itself or a value outside the algebra (``origin``: where the value came from, for the
        message)."""
        where = f" in {origin}" if origin else ""
        for s in (src, dst):
            if s not in self._known:
                raise BadInput(
                    f"unknown subject {s!r}{where} (subjects: {', '.join(self.subjects)})"
                )
        if src == dst:
            raise BadInput(f"influence {src}>{dst}{where}: a subject does not influence itself")
        self._values[(src, dst)] = self.universe.check(value)

    def get(self, src: str, dst: str) -> int | None:
        """The influence of ``src`` on ``dst``, or None if not set."""
        return self._values.get((src, dst))

    def items(self) -> Iterable[tuple[tuple[str, str], int]]:
        """Every ((src, dst), value) set."""
        return self._values.items()

    def on(self, dst: str) -> dict[str, int]:
        """Column ``dst``: every other subject's influence on it; missing ones are an error."""
        out: dict[str, int] = {}
        for src in self.subjects:
            if src == dst:
                continue
            v = self._values.get((src, dst))
            if v is None:
                raise BadInput(f"missing influence {src}>{dst} (on subject {dst})")
            out[src] = v
        return out

    @classmethod
    def parse(
        cls, specs: Iterable[str], subjects: Iterable[str], universe: Universe
    ) -> InfluenceMatrix:
        """From ``SRC>DST=VALUE`` strings, e.g. ``a>b={alpha}``."""
        m = cls(subjects, universe)
        for spec in specs:
            if "=" not in spec or ">" not in spec.split("=", 1)[0]:
                raise BadInput(
                    f"bad influence {spec!r}: write SRC>DST=VALUE, e.g. a>b={{alpha}}"
                )
            lhs, value = spec.split("=", 1)
            src, dst = (p.strip() for p in parse_pair_key(lhs))
            if m.get(src, dst) is not None:
                raise BadInput(f"influence {src}>{dst} is given twice")
            try:
                mask = universe.parse_alternative(value)
            except RgtbusError as exc:
                raise BadInput(f"{exc} (influence {spec!r})") from None
            m.set(src, dst, mask, origin=repr(spec))
        return m

    @classmethod
    def from_mapping(
        cls, values: Mapping[tuple[str, str], int], subjects: Iterable[str], universe: Universe
    ) -> InfluenceMatrix:
        """A matrix of ``values`` by (src, dst), each checked as ``set`` checks it."""
        m = cls(subjects, universe)
        known, put, check = m._known, m._values.__setitem__, universe.check
        for (src, dst), v in values.items():  # each unit decides on n² of them, every round
            if src in known and dst in known and src != dst:
                put((src, dst), check(v))
            else:
                m.set(src, dst, v)  # which one is wrong, said as ``set`` says it
        return m


# ---------------------------------------------------------------------------------------------
# Forward task


@dataclass(frozen=True)
class SubjectResult:
    """A and B under the influences on the subject; interval ``[B, A]`` or frustration."""

    subject: str
    A: int
    B: int

    @property
    def frustrated(self) -> bool:
        """Whether B ⊄ A: the equation has no solution."""
        return bool(self.B & ~self.A)

    @property
    def interval(self) -> tuple[int, int] | None:
        """The solutions' interval (B, A), or None when frustrated."""
        return None if self.frustrated else (self.B, self.A)

    def choices(self, universe: Universe) -> list[int]:
        """Every alternative x with B ⊆ x ⊆ A."""
        return universe.subsets_between(self.B, self.A)


def evaluate(
    df: DecisionFunction, universe: Universe, subject: str, on: Mapping[str, int]
) -> SubjectResult:
    """A = F(x=1, others=on), B = F(x=0, others=on)."""
    f = df.mask_function(universe.full)
    args_a = []
    args_b = []
    for s in df.order:
        if s == subject:
            args_a.append(universe.full)
            args_b.append(0)
        else:
            try:
                v = on[s]
            except KeyError:
                raise BadInput(
                    f"missing influence {s}>{subject} (on subject {subject})"
                ) from None
            args_a.append(v)
            args_b.append(v)
    return SubjectResult(subject, f(*args_a), f(*args_b))


def forward(
    df: DecisionFunction, universe: Universe, matrix: InfluenceMatrix
) -> dict[str, SubjectResult]:
    """The forward task for every subject."""
    if tuple(sorted(matrix.subjects)) != tuple(sorted(df.order)):
        raise BadInput(
            f"influence matrix subjects {list(matrix.subjects)} differ from {list(df.order)}"
        )
    return {s: evaluate(df, universe, s, matrix.on(s)) for s in df.order}


def canonical_text(form: CanonicalForm, order: Iterable[str]) -> str:
    """``form`` as text, products written with ``*`` where the names of ``order`` need it."""
    return form.text(needs_star(list(order)))


__all__ = [
    "CanonicalForm",
    "InfluenceMatrix",
    "SubjectResult",
    "canonical_form",
    "canonical_forms",
    "canonical_text",
    "evaluate",
    "forward",
]
