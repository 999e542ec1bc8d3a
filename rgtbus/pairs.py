"""Ordered pairs of units and their text key ``"s>r"`` (sender s, receiver r): the one place
that builds and reads them. Pure."""

from __future__ import annotations

import functools
from array import array
from collections.abc import ItemsView, Iterator, Mapping, MutableMapping, Sequence, ValuesView
from typing import TYPE_CHECKING, Any, NoReturn, TypeVar

if TYPE_CHECKING:
    import numpy as np

Pair = tuple[str, str]
_V = TypeVar("_V")


def ordered_pairs(units: Sequence[str]) -> list[Pair]:
    """Every ordered pair ``(s, r)`` of distinct units, senders in the given order."""
    return [(s, r) for s in units for r in units if s != r]


@functools.lru_cache(maxsize=1 << 17)
def pair_key(sender: str, receiver: str) -> str:
    """``"s>r"``: how records, summaries and scenario files name an ordered pair. One string
    a pair, shared: every unit's tables name every pair (n³ strings at n units otherwise)."""
    return f"{sender}>{receiver}"


@functools.lru_cache(maxsize=1 << 17)
def relation_key(a: str, b: str) -> str:
    """``"a-b"``: how tables name the relationship of an unordered pair (a before b in the
    group's order). One string a pair, shared, as ``pair_key``."""
    return f"{a}-{b}"


class SharedTable(dict[str, _V]):
    """A table keyed by pair text that the units holding an equal table share as one object
    (the mind's memo, ``rgtbus.mind``): read, never changed, so that whatever is worked out
    from it once holds for every unit that holds it (a log encodes it once, not once a unit:
    ``rgtbus.telemetry.recorder``). Changing one raises ``TypeError``."""

    __slots__ = ("__weakref__",)  # what is worked out from it may live as long as it does

    def _frozen(self, *args: object, **kwargs: object) -> NoReturn:
        raise TypeError("a SharedTable is shared by units: copy it (dict(table)) to change it")

    __setitem__ = __delitem__ = __ior__ = _frozen
    clear = pop = popitem = setdefault = update = _frozen

    def __reduce__(self) -> tuple[Any, ...]:  # pickled as the plain dict it holds
        return (dict, (dict(self),))


def parse_pair_key(key: str) -> Pair:
    """``"s>r"`` -> ``(s, r)`` (split at the first ``>``: unit names never hold one)."""
    s, _, r = key.partition(">")
    return s, r


_ABSENT = -(2**63)  # the value no table can hold (an empty slot, at the widest width)
# A table's widths, narrowest first: (array typecode, NumPy dtype, the empty slot's value, the
# largest value). A table starts at one byte an entry (the values of a group's tables: yes/no
# and alternatives of a few actions) and widens only when a value needs it.
_WIDTHS = (
    ("b", "int8", -(2**7), 2**7 - 1),
    ("h", "int16", -(2**15), 2**15 - 1),
    ("i", "int32", -(2**31), 2**31 - 1),
    ("q", "int64", _ABSENT, 2**63 - 1),
)


@functools.lru_cache(maxsize=64)
def _slots_of(units: tuple[str, ...]) -> dict[Pair, int]:
    """Each ordered pair's slot in a ``PairTable`` of ``units`` (one dict for every table of
    a group: a pair is found by one lookup)."""
    n = len(units)
    return {(s, r): i * n + j for i, s in enumerate(units) for j, r in enumerate(units)}


@functools.lru_cache(maxsize=64)
def unordered_slots(units: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every unordered pair a-b of ``units`` (a before b, in the group's order, as
    ``itertools.combinations``): the slots of a>b and of b>a in a ``PairTable`` of ``units``,
    and its ``relation_key`` (an object array of the shared strings). Once a group."""
    import numpy as np

    n = len(units)
    i, j = np.triu_indices(n, 1)
    keys = np.empty(i.size, dtype=object)  # (np.array of strings would copy them)
    keys[:] = [
        relation_key(units[a], units[b]) for a, b in zip(i.tolist(), j.tolist(), strict=True)
    ]
    return i * n + j, j * n + i, keys


@functools.lru_cache(maxsize=64)
def sorted_slots(units: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The slots of a ``PairTable`` of ``units`` in the order of their pairs ``(s, r)`` sorted
    as text (``sorted(table.items())``), and each one's ``pair_key`` (an object array of the
    shared strings). Once a group."""
    import numpy as np

    pairs = _pairs_of(units)
    order = sorted(range(len(pairs)), key=pairs.__getitem__)
    keys = np.empty(len(order), dtype=object)
    keys[:] = [pair_key(*pairs[k]) for k in order]
    return np.array(order, dtype=np.int64), keys


@functools.lru_cache(maxsize=64)
def _pairs_of(units: tuple[str, ...]) -> tuple[Pair, ...]:
    """The pair of each slot of a ``PairTable`` of ``units`` (one tuple for every table)."""
    return tuple((s, r) for s in units for r in units)


class _PairItems(ItemsView[Pair, int]):
    """A table's items without a lookup each: its slots in one pass over the array."""

    _mapping: PairTable

    def __iter__(self) -> Iterator[tuple[Pair, int]]:
        return self._mapping._items()


class _PairValues(ValuesView[int]):
    _mapping: PairTable

    def __iter__(self) -> Iterator[int]:
        return (v for _, v in self._mapping._items())


class PairTable(MutableMapping[Pair, int]):
    """A mapping ``(sender, receiver) -> int`` over the ordered pairs of one group, held in an
    array of n² small integers instead of a dict: each of n units holds the group's tables as
    it hears them, n³ entries in all: one byte an entry while every value fits in a byte (the
    array widens, to 2, 4 or 8 bytes, when a value needs it). Any int but -2⁶³ can be held.
    Iterates in the group's order (senders, then receivers), not in the order the values came.
    ``boolean``: values read back as bools (the relation codes: alliance or not). A unit name
    outside the group: KeyError."""

    __slots__ = ("_absent", "_bool", "_count", "_n", "_slots", "_top", "_units", "_vals", "_width")

    def __init__(self, units: Sequence[str], *, boolean: bool = False) -> None:
        self._units = tuple(units)
        self._slots = _slots_of(self._units)
        self._n = len(self._units)
        self._width = 0
        code, _, self._absent, self._top = _WIDTHS[0]
        self._vals = array(code, [self._absent]) * (self._n * self._n)
        self._count = 0
        self._bool = boolean

    def _widen(self, low: int, high: int) -> None:
        """Hold values from ``low`` to ``high`` too: the array at the narrowest width that
        does (its empty slots the new width's empty value)."""
        import numpy as np

        if low == _ABSENT:
            raise ValueError(f"{_ABSENT} cannot be held")
        w = self._width
        while w + 1 < len(_WIDTHS) and not (_WIDTHS[w][2] < low and high <= _WIDTHS[w][3]):
            w += 1
        code, dtype, absent, top = _WIDTHS[w]
        old = np.frombuffer(self._vals, dtype=_WIDTHS[self._width][1])
        new = old.astype(dtype)
        new[old == self._absent] = absent
        self._vals = array(code, new.tobytes())
        self._width, self._absent, self._top = w, absent, top

    def _fits(self, value: int) -> bool:
        return self._absent < value <= self._top

    def _slot(self, key: Pair) -> int:
        try:
            return self._slots[key]
        except (KeyError, TypeError):  # not a pair of the group (or not hashable)
            raise KeyError(key) from None

    def __getitem__(self, key: Pair) -> int:
        v = self._vals[self._slot(key)]
        if v == self._absent:
            raise KeyError(key)
        return bool(v) if self._bool else v

    def __setitem__(self, key: Pair, value: int) -> None:
        try:  # the lookup inline: a unit sets a value for every code it decodes
            i = self._slots[key]
        except (KeyError, TypeError):
            raise KeyError(key) from None
        if not self._absent < value <= self._top:  # also refuses what is no int
            self._widen(int(value), int(value))
        vals = self._vals
        empty = vals[i] == self._absent
        vals[i] = value  # an int (a bool is one): the array refuses anything else
        self._count += empty

    def __delitem__(self, key: Pair) -> None:
        i = self._slot(key)
        if self._vals[i] == self._absent:
            raise KeyError(key)
        self._vals[i] = self._absent
        self._count -= 1

    def holds_every_pair(self) -> bool:
        """Whether every ordered pair of two distinct units has a value (``ordered_pairs``):
        n(n−1) values off the diagonal (a unit paired with itself counts for none), n reads
        instead of n² lookups."""
        n, vals, absent = self._n, self._vals, self._absent
        diagonal = sum(vals[i * (n + 1)] != absent for i in range(n))
        return self._count - diagonal == n * (n - 1)

    def __contains__(self, key: object) -> bool:
        try:
            return self._vals[self._slot(key)] != self._absent  # type: ignore[arg-type]
        except KeyError:
            return False

    def __iter__(self) -> Iterator[Pair]:
        pairs = _pairs_of(self._units)
        absent = self._absent
        for i, v in enumerate(self._vals):
            if v != absent:
                yield pairs[i]

    def items(self) -> ItemsView[Pair, int]:
        """The (pair, value) items, in the group's order."""
        return _PairItems(self)

    def values(self) -> ValuesView[int]:
        """The values, in the group's order."""
        return _PairValues(self)

    @property
    def units(self) -> tuple[str, ...]:
        """The group, in order: the pair (units[i], units[j]) is slot i·n + j."""
        return self._units

    def _array(self) -> np.ndarray:
        import numpy as np

        return np.frombuffer(self._vals, dtype=_WIDTHS[self._width][1])

    def columns(self) -> tuple[np.ndarray, np.ndarray]:
        """Every slot's value (0 where none) and whether it holds one, as arrays (slot
        ``i·n + j``: the pair (units[i], units[j])): a whole table read in one step."""
        vals = self._array()
        held: np.ndarray = vals != self._absent
        return vals * held, held

    def absent(self, slots: np.ndarray) -> np.ndarray:
        """Whether each of these slots holds nothing yet (a bool array)."""
        empty: np.ndarray = self._array()[slots] == self._absent
        return empty

    def set_slots(self, slots: np.ndarray, values: np.ndarray, *, unique: bool = False) -> None:
        """``self[pair of slots[k]] = values[k]`` for every k, in order (the last of a slot
        given twice stays; ``unique``: the caller knows none is): a unit's batch of decodes at
        once. Slots are ``units``' i·n + j."""
        import numpy as np

        slots = np.asarray(slots, dtype=np.int64)
        values = np.asarray(values, dtype=np.int64)
        if not slots.size:
            return
        if slots.min() < 0 or slots.max() >= self._n * self._n:
            raise KeyError(f"slot outside the {self._n}-unit table")
        low, high = int(values.min()), int(values.max())
        if not (self._fits(low) and self._fits(high)):
            self._widen(low, high)
        if not unique:
            last = slots.size - 1 - np.unique(slots[::-1], return_index=True)[1]
            slots, values = slots[last], values[last]
        vals = self._array()
        self._count += int((vals[slots] == self._absent).sum())
        vals[slots] = values

    def snapshot(self) -> tuple[tuple[str, ...], bool, int, bytes]:
        """What the table holds, hashable: equal tables, equal snapshots (what a table
        derived from one is memoised on: the units of a group mostly hold equal ones)."""
        return self._units, self._bool, self._width, self._vals.tobytes()

    def _items(self) -> Iterator[tuple[Pair, int]]:
        # a report or a decision reads a whole table: n² items, n tables, each round
        pairs = _pairs_of(self._units)
        vals, absent = self._vals, self._absent
        if self._bool:
            return ((pairs[i], bool(v)) for i, v in enumerate(vals) if v != absent)
        return ((pairs[i], v) for i, v in enumerate(vals) if v != absent)

    def __len__(self) -> int:
        return self._count

    def __repr__(self) -> str:
        return f"PairTable({dict(self.items())!r})"


class PairTexts(Mapping[str, _V]):
    """A table keyed by pair text (``"s>r"``) read from a ``PairTable`` as it was when made:
    each held pair's value as ``texts`` names it (one shared object a value: ``"alliance"``,
    an alternative's list). What a unit's report holds of its own tables without n² dict
    entries a unit: in a noisy group no two units hold equal tables, and 200 units' tables as
    dicts held 384 MB, as these 8 MB. Read, never changed; iterates sorted by pair, as
    ``sorted(table.items())``; equal to a dict of the same items (``to_dict()`` is one, as
    JSON wants it)."""

    __slots__ = ("_held", "_texts", "_units", "_vals")

    def __init__(self, table: PairTable, texts: Mapping[int, _V]) -> None:
        vals, held = table.columns()
        self._units = table.units
        self._vals = vals.copy()  # as it is now: the table may still change
        self._held = held.copy()
        self._texts = dict(texts)

    def __getitem__(self, key: str) -> _V:
        slot = _slots_of(self._units).get(parse_pair_key(key)) if isinstance(key, str) else None
        if slot is None or not self._held[slot]:
            raise KeyError(key)
        return self._texts[int(self._vals[slot])]

    def _sorted(self) -> tuple[list[str], list[int]]:
        order, keys = sorted_slots(self._units)
        mine = self._held[order]
        return keys[mine].tolist(), self._vals[order][mine].tolist()

    def __iter__(self) -> Iterator[str]:
        return iter(self._sorted()[0])

    def __len__(self) -> int:
        return int(self._held.sum())

    def to_dict(self) -> dict[str, _V]:
        """The table as a dict, in the same order (its values the same shared objects)."""
        keys, vals = self._sorted()
        return dict(zip(keys, map(self._texts.__getitem__, vals), strict=True))

    def __eq__(self, other: object) -> bool:
        if isinstance(other, PairTexts):
            import numpy as np

            if other._units != self._units:
                return self.to_dict() == other.to_dict()
            if not np.array_equal(self._held, other._held):
                return False  # a pair one holds and the other does not
            # equal when every pair's two values name equal texts: a few distinct couples
            mine = self._vals[self._held].astype(np.int64)
            theirs = other._vals[self._held].astype(np.int64)
            if not mine.size:
                return True
            lo = min(int(mine.min()), int(theirs.min()))
            span = max(int(mine.max()), int(theirs.max())) - lo + 1
            couples = np.unique((mine - lo) * span + (theirs - lo))  # no sort by rows
            return all(
                self._texts[a + lo] == other._texts[b + lo]
                for a, b in zip(*divmod(couples, span), strict=True)
            )
        if isinstance(other, Mapping):
            return self.to_dict() == dict(other.items())
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"PairTexts({self.to_dict()!r})"
