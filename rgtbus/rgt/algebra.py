"""Boolean algebra of alternatives over a named universal set of actions.

An alternative is a subset of the k actions, held as a k-bit integer (bit j = action j):
``+`` is OR, ``·`` is AND, ``not(x)`` is ``x XOR full``. ``1`` is the full set, ``0`` the empty one.

Text forms: ``1``, ``0``, ``{}``, ``{alpha}``, ``{alpha,beta}``; JSON form: the sorted list of
action names (``[]`` for 0).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field

from rgtbus.errors import BadInput

_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


@dataclass(frozen=True)
class Universe:
    """The universal set: k named actions, in a fixed order (bit j = ``actions[j]``)."""

    actions: tuple[str, ...]
    _index: dict[str, int] = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        actions = tuple(self.actions)
        object.__setattr__(self, "actions", actions)
        if not actions:
            raise BadInput("the universal set needs at least one action")
        seen: dict[str, int] = {}
        for j, name in enumerate(actions):
            if not _NAME.match(name):
                raise BadInput(
                    f"bad action name {name!r}: a name is ASCII letters A-Z a-z, digits 0-9 "
                    "and _, not starting with a digit"
                )
            if name in seen:
                raise BadInput(f"action {name!r} is listed twice")
            seen[name] = j
        object.__setattr__(self, "_index", seen)

    @classmethod
    def parse(cls, text: str) -> Universe:
        """``"alpha,beta"`` -> Universe(("alpha", "beta"))."""
        names = [part.strip() for part in text.split(",")]
        if any(not n for n in names):
            raise BadInput(f"empty action name in {text!r}")
        return cls(tuple(names))

    @property
    def k(self) -> int:
        """The number of actions."""
        return len(self.actions)

    @property
    def full(self) -> int:
        """The full set of actions as a mask (the alternative 1)."""
        return (1 << len(self.actions)) - 1

    def __len__(self) -> int:
        return 1 << len(self.actions)

    def __iter__(self) -> Iterator[int]:
        """Every alternative, as masks 0 .. 2^k - 1."""
        return iter(range(1 << len(self.actions)))

    def bit(self, action: str) -> int:
        """The mask of one action; refused for an unknown name."""
        try:
            return 1 << self._index[action]
        except KeyError:
            raise BadInput(
                f"unknown action {action!r} (actions: {', '.join(self.actions)})"
            ) from None

    def check(self, mask: int) -> int:
        """``mask`` if it is an alternative of this algebra; refused otherwise."""
        if not (0 <= mask <= self.full):
            raise BadInput(f"alternative {mask} is outside the algebra of {self.k} actions")
        return mask

    def neg(self, mask: int) -> int:
        """The complement not(mask)."""
        return mask ^ self.full

    def from_names(self, names: Iterable[str]) -> int:
        """The mask of these action names (their union)."""
        mask = 0
        for name in names:
            mask |= self.bit(name)
        return mask

    def parse_alternative(self, text: str) -> int:
        """Parse ``1``, ``0``, ``{}``, ``{alpha}``, ``{alpha,beta}`` (a bare action name too)."""
        s = text.strip()
        if s == "1":
            return self.full
        if s == "0":
            return 0
        if s.startswith("{") and s.endswith("}"):
            inner = s[1:-1].strip()
            if not inner:
                return 0
            names = [part.strip() for part in inner.split(",")]
            if any(not n for n in names):
                raise BadInput(f"empty action name in alternative {text!r}")
            return self.from_names(names)
        if _NAME.match(s) and s in self._index:
            return self.bit(s)
        if _NAME.match(s):
            raise BadInput(
                f"unknown action {s!r} in alternative {text!r} (actions: {', '.join(self.actions)})"
            )
        raise BadInput(f"bad alternative {text!r}: write 1, 0, {{}}, or {{action,...}}")

    def parse_interval(self, text: str) -> tuple[int, int]:
        """``{alpha}`` -> (lo, hi) = ({alpha}, {alpha}); ``[{beta},1]`` -> ({beta}, 1)."""
        s = text.strip()
        if not (s.startswith("[") and s.endswith("]")):
            v = self.parse_alternative(s)
            return v, v
        inner = s[1:-1]
        depth = 0
        for i, ch in enumerate(inner):
            depth += ch == "{"
            depth -= ch == "}"
            if ch == "," and depth == 0:
                return self.parse_alternative(inner[:i]), self.parse_alternative(inner[i + 1 :])
        raise BadInput(f"bad interval {text!r}: write [LOW,HIGH], e.g. [{{beta}},1]")

    def to_list(self, mask: int) -> list[str]:
        """JSON form: sorted action names."""
        return sorted(a for j, a in enumerate(self.actions) if mask >> j & 1)

    def from_list(self, names: Sequence[str]) -> int:
        """The mask of a JSON form (a list of action names)."""
        return self.from_names(names)

    def format(self, mask: int) -> str:
        """Text form; the paper writes 1 and 0 for the full and the empty set."""
        if mask == self.full:
            return "1"
        if mask == 0:
            return "0"
        return "{" + ",".join(a for j, a in enumerate(self.actions) if mask >> j & 1) + "}"

    def subsets_between(self, low: int, high: int) -> list[int]:
        """All x with low ⊆ x ⊆ high (empty if low ⊄ high), in increasing mask order."""
        if low & ~high:
            return []
        free = high & ~low
        out = []
        sub = free
        while True:
            out.append(low | sub)
            if sub == 0:
                break
            sub = (sub - 1) & free
        out.reverse()
        return out
