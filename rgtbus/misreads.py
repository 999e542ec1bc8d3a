"""Decode errors: what was sent (``SentTruth``), which decodes misread it (``Misreads``, one
unit's, as columns) and every unit's misreads with whether each stayed wrong
(``DecodeErrors``), as the run summary counts them and ``RunResult.decode_errors()`` and
``open_log(...).decode_errors()`` give them (a DataFrame).

A noisy run of n units misreads O(n³) decodes (about 2 million at n = 200, σ = 0.01): they are
held as integer columns (a number per text, ``SentTruth.number``), never as a Python object
each; the summary carries their counts and a bounded sample. Pure: no SimPy, zenoh or MCAP.

A decode is wrong when it differs from what was sent (``is_wrong_decode``); a misread stayed
wrong (``left_wrong``) unless the unit's last read of that turn's payload was what was sent (a
repair's copy read right, or, for a misread ID, the payload read right all the same).
"""

from __future__ import annotations

from array import array
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, cast

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

_T = TypeVar("_T")

DECODE_KINDS = ("id", "relation", "influence")  # the kinds of a decode, as the summary counts
MISREAD_SAMPLE = 10  # the misreads a summary lists (the first, in unit and decode order)
WHERE_THE_REST_ARE = "RunResult.decode_errors() or open_log(LOG).decode_errors()"


def is_wrong_decode(kind: str, code: str, addressee: str, sent: str, sent_to: str) -> bool:
    """Whether a decode differs from what was sent: an ID must read as the ID-code; a payload
    must be the code sent, found on its addressee's channel."""
    return (code != "id") if kind == "id" else (code != sent or addressee != sent_to)


class DecodeArrays(Protocol):
    """Decodes held as columns (a unit's ``DecodeColumns``): ``arrays()`` gives each
    decode's turn and the index of its (kind, addressee, code) among the distinct ones."""

    def arrays(self) -> tuple[np.ndarray, np.ndarray, Sequence[tuple[str, str, str]]]: ...


class HeldDecodes:
    """Decodes held as columns already (``DecodeArrays``): each one's turn, and the index
    of its (kind, addressee, code) in ``rows`` (a slice of a unit's, or a unit's decodes
    read from a log's columns)."""

    def __init__(self, turns: np.ndarray, what: np.ndarray, rows: Sequence[tuple[str, str, str]]):
        self._arrays = (turns, what, rows)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, Sequence[tuple[str, str, str]]]:
        return self._arrays

    def __len__(self) -> int:
        return len(self._arrays[0])

    def __iter__(self) -> Iterator[list[Any]]:
        """Each decode as a row: ``[turn, kind, addressee, code]``."""
        turns, what, rows = self._arrays
        for turn, w in zip(turns.tolist(), what.tolist(), strict=True):
            yield [turn, *rows[w]]


class SentTruth:
    """What was sent, per (turn, "id" | "payload"): (addressee, code), the ground truth of
    decode errors. Built once a run; its arrays (by turn) once, on first use by columns."""

    def __init__(self, sent: Mapping[tuple[int, str], tuple[str, str]]) -> None:
        self.sent = sent
        self._arrays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.names: dict[str, int] = {}  # every addressee, code and kind, as a number
        self.texts: list[str] = []  # a number's text
        self._shared: dict[int, tuple[object, Any]] = {}

    def shared(self, key: object, build: Callable[[], _T]) -> _T:
        """What every unit's decodes judge alike from ``key`` (a shared listen queue, say),
        built once with this truth by the first that asks (``key`` is kept alive: it is found
        by id)."""
        got = self._shared.get(id(key))
        if got is None:
            got = self._shared[id(key)] = (key, build())
        return cast(_T, got[1])

    def number(self, text: str) -> int:
        """``text``'s number (made on first use)."""
        i = self.names.get(text)
        if i is None:
            i = self.names[text] = len(self.names)
            self.texts.append(text)
        return i

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """[class (0: ID, 1: payload), turn] -> known, the addressee's and the code's number."""
        if self._arrays is None:
            self._arrays = self._by_turn(
                (turn, cls != "id", addressee, code)
                for (turn, cls), (addressee, code) in self.sent.items()
                if turn >= 0
            )
        return self._arrays

    @classmethod
    def of_sends(cls, sends: Iterable[Sequence[Any]]) -> SentTruth:
        """The truth of sends given as rows ``(turn, kind, addressee, code)`` (the last send
        of a key counts), held as arrays by turn: a run of n units sends 4n(n−1) codes, and a
        dict of tuples held about 190 bytes a send."""
        truth = cls({})
        other: dict[tuple[int, str], tuple[str, str]] = {}

        def of_turns() -> Iterator[tuple[int, bool, str, str]]:
            for turn, kind, addressee, code in sends:
                if isinstance(turn, int) and turn >= 0:
                    yield turn, kind != "id", addressee, code
                else:  # not a turn of the arrays: looked up as it is
                    other[(turn, "id" if kind == "id" else "payload")] = (addressee, code)

        truth._arrays = truth._by_turn(of_turns())
        truth.sent = _SentByTurn(truth, other)
        return truth

    def _by_turn(
        self, sends: Iterable[tuple[int, bool, str, str]]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``arrays`` of sends ``(turn, payload?, addressee, code)``, in order: the last of a
        key wins."""
        number = self.number
        turns, classes, to, codes = array("q"), array("q"), array("q"), array("q")
        for turn, payload, addressee, code in sends:
            turns.append(turn)
            classes.append(payload)
            to.append(number(addressee))
            codes.append(number(code))
        t, c = np.frombuffer(turns, dtype=np.int64), np.frombuffer(classes, dtype=np.int64)
        span = int(t.max()) + 1 if t.size else 0
        known = np.zeros((2, span), dtype=bool)
        to_of = np.full((2, span), -1)
        code_of = np.full((2, span), -1)
        known[c, t] = True
        to_of[c, t] = np.frombuffer(to, dtype=np.int64)
        code_of[c, t] = np.frombuffer(codes, dtype=np.int64)
        return known, to_of, code_of


def sent_truth(reports: Sequence[Mapping[str, Any]]) -> SentTruth:
    """The ground truth of decode errors: every report's sends (``SentTruth.of_sends``)."""
    return SentTruth.of_sends(row for r in reports for row in r["sends"])


class _SentByTurn(Mapping[tuple[int, str], tuple[str, str]]):
    """``SentTruth.sent`` read from its arrays: (turn, "id" | "payload") -> (addressee, code)."""

    def __init__(self, truth: SentTruth, other: dict[tuple[int, str], tuple[str, str]]) -> None:
        self._arrays = truth.arrays()
        self._names = truth.texts
        self._other = other

    def __getitem__(self, key: tuple[int, str]) -> tuple[str, str]:
        known, to_of, code_of = self._arrays
        turn, cls = key
        if isinstance(turn, int) and 0 <= turn < known.shape[1] and cls in ("id", "payload"):
            c = int(cls != "id")
            if known[c, turn]:
                return self._names[to_of[c, turn]], self._names[code_of[c, turn]]
        return self._other[key]

    def __iter__(self) -> Iterator[tuple[int, str]]:
        cls, turn = np.nonzero(self._arrays[0])
        for c, t in zip(cls.tolist(), turn.tolist(), strict=True):
            yield (t, "payload" if c else "id")
        yield from self._other

    def __len__(self) -> int:
        return int(self._arrays[0].sum()) + len(self._other)


@dataclass(frozen=True, eq=False)
class Misreads:
    """One unit's misread decodes as columns (int32), in decode order: each one's turn (-1:
    none) and the numbers (``SentTruth.number``) of its kind, of the word it read and of the
    word sent."""

    turn: np.ndarray
    kind: np.ndarray
    decoded: np.ndarray
    sent: np.ndarray

    @classmethod
    def of(cls, turn: Any, kind: Any, decoded: Any, sent: Any) -> Misreads:
        """Columns of integers (any sequences of them)."""
        # four bytes a value: two million misreads of a noisy 200-unit group in 32 MB
        col = [np.asarray(x, dtype=np.int32).reshape(-1) for x in (turn, kind, decoded, sent)]
        return cls(*col)

    @classmethod
    def concat(cls, parts: Sequence[Misreads]) -> Misreads:
        if len(parts) == 1:
            return parts[0]
        if not parts:
            return cls.of([], [], [], [])
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in _COLUMNS))

    def __len__(self) -> int:
        return int(self.turn.size)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Misreads) and all(
            np.array_equal(getattr(self, f), getattr(other, f)) for f in _COLUMNS
        )

    __hash__ = None  # type: ignore[assignment]


_COLUMNS = ("turn", "kind", "decoded", "sent")


def misreads_of(decodes: Iterable[Sequence[Any]] | DecodeArrays, truth: SentTruth) -> Misreads:
    """A unit's decodes that differ from what was sent (``is_wrong_decode``), in decode order;
    a decode of a turn with no known send is not judged. Rows (turn, kind, addressee, code)
    are judged one by one; columns (``DecodeArrays``) in one vectorised step (n³ decodes at n
    units); decodes that judge themselves (a unit's ``DecodeColumns``: ``misreads(truth)``)
    are asked."""
    judge = getattr(decodes, "misreads", None)
    if judge is not None:
        return cast(Misreads, judge(truth))
    sent_of = truth.sent
    number = truth.number
    arrays = getattr(decodes, "arrays", None)
    if arrays is None:
        cols: tuple[array[int], ...] = tuple(array("q") for _ in _COLUMNS)
        for turn, kind, addressee, code in cast(Iterable[Sequence[Any]], decodes):
            key = (turn, "id" if kind == "id" else "payload")
            if key in sent_of:
                sent_to, sent = sent_of[key]
                if is_wrong_decode(kind, code, addressee, sent, sent_to):
                    row = (-1 if turn is None else int(turn), number(kind), number(code))
                    for col, v in zip(cols, (*row, number(sent)), strict=True):
                        col.append(v)
        return Misreads.of(*cols)
    turns, what, rows = arrays()
    if not len(turns) or not sent_of:
        return Misreads.concat([])
    known, to_of, code_of = truth.arrays()
    row_cls = np.array([int(k != "id") for k, _, _ in rows])
    row_id_ok = np.array([k != "id" or c == "id" for k, _, c in rows])  # an ID read as the ID
    row_kind = np.array([number(k) for k, _, _ in rows])
    row_to = np.array([number(a) for _, a, _ in rows])
    row_code = np.array([number(c) for _, _, c in rows])
    cls, t = row_cls[what], turns.astype(np.int64)
    in_span = (t >= 0) & (t < known.shape[1])
    t = np.where(in_span, t, 0)
    judged = in_span & known[cls, t]
    bad = np.where(
        cls == 0,
        ~row_id_ok[what],
        (code_of[1, t] != row_code[what]) | (to_of[1, t] != row_to[what]),
    )
    at = np.flatnonzero(judged & bad)
    w = what[at]
    return Misreads.of(t[at], row_kind[w], row_code[w], code_of[cls[at], t[at]])


def payloads_read_right(
    decodes: Iterable[Sequence[Any]] | DecodeArrays, truth: SentTruth, turns: np.ndarray
) -> np.ndarray:
    """Which of ``turns`` have their payload last read by the unit as it was sent (code and
    addressee), sorted; the decodes of other turns are not looked at."""
    sent_of = truth.sent
    arrays = getattr(decodes, "arrays", None)
    if arrays is None:
        asked = set(turns.tolist())
        last: dict[int, bool] = {}
        for turn, kind, addressee, code in cast(Iterable[Sequence[Any]], decodes):
            key = (turn, "payload")
            if turn in asked and kind != "id" and key in sent_of:
                sent_to, sent = sent_of[key]
                last[turn] = not is_wrong_decode(kind, code, addressee, sent, sent_to)
        return np.array(sorted(t for t, ok in last.items() if ok), dtype=np.int64)
    held, what, rows = arrays()
    known, to_of, code_of = truth.arrays()
    number = truth.number
    row_pay = np.array([k != "id" for k, _, _ in rows] or [False])
    row_to = np.array([number(a) for _, a, _ in rows] or [-1])
    row_code = np.array([number(c) for _, _, c in rows] or [-1])
    at = np.flatnonzero(np.isin(held, turns) & row_pay[what])
    t = held[at].astype(np.int64)
    # the last read of each turn: the first in reverse order
    t_last, back = np.unique(t[::-1], return_index=True)
    w = what[at[t.size - 1 - back]]
    in_span = (t_last >= 0) & (t_last < known.shape[1])
    tt = np.where(in_span, t_last, 0)
    ok = in_span & known[1, tt] & (code_of[1, tt] == row_code[w]) & (to_of[1, tt] == row_to[w])
    return cast(np.ndarray, t_last[ok])


@dataclass(frozen=True, eq=False)
class DecodeErrors:
    """Every unit's misreads (``Misreads``, unit by unit in report order) and whether each
    stayed wrong in what its unit took from the turn (``left``). ``frame()`` gives them as a
    DataFrame, ``counts()`` as the summary's ``decode_errors``."""

    units: tuple[str, ...]  # the reporting units, as ``unit`` numbers them
    texts: tuple[str, ...]  # a number's text (kinds and words)
    unit: np.ndarray
    misread: Misreads
    left: np.ndarray  # bool

    def __len__(self) -> int:
        return len(self.misread)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, DecodeErrors):
            return NotImplemented
        return self.rows() == other.rows()

    __hash__ = None  # type: ignore[assignment]

    def word_errors(self) -> dict[str, int]:
        """The misreads of each kind (``DECODE_KINDS``) read as another word than the one sent:
        the symbol errors a bound on telling the words apart speaks of. The other misreads
        were read as the word sent, but on another unit's channel or for another turn (a
        misread ID moves its payload)."""
        other = self.misread.decoded != self.misread.sent
        return {
            kind: int(np.count_nonzero(other & (self.misread.kind == self._number(kind))))
            for kind in DECODE_KINDS
        }

    def counts(self, sample: int = MISREAD_SAMPLE) -> dict[str, Any]:
        """The summary's ``decode_errors``: how many decodes were misread, how many of them a
        later read set right and how many were left wrong, the same per kind of decode; the
        first ``sample`` misreads; where the rest are (``None``: the sample is all)."""
        n, left = len(self), int(np.count_nonzero(self.left))
        kinds = np.array([self.texts[k] for k in np.unique(self.misread.kind).tolist()])
        by_kind = {}
        for kind in [*DECODE_KINDS, *sorted(set(kinds.tolist()) - set(DECODE_KINDS))]:
            mine = self.misread.kind == (self._number(kind))
            k, k_left = int(np.count_nonzero(mine)), int(np.count_nonzero(mine & self.left))
            by_kind[kind] = {"misread": k, "set_right": k - k_left, "left_wrong": k_left}
        return {
            "misread": n,
            "set_right": n - left,
            "left_wrong": left,
            "by_kind": by_kind,
            "sample": self.rows(0, sample),
            "rest": None if n <= sample else f"{n - sample} more: {WHERE_THE_REST_ARE}",
        }

    def _number(self, text: str) -> int:
        try:
            return self.texts.index(text)
        except ValueError:
            return -2  # no such text: matches no number

    def rows(self, start: int = 0, stop: int | None = None) -> list[dict[str, Any]]:
        """Misreads [start, stop) as dicts (``decode_error`` entries and ``left_wrong``)."""
        m, texts = self.misread, self.texts
        part = slice(start, stop)
        return [
            {**decode_error(self.units[u], None if t < 0 else t, texts[k], texts[d], texts[s]),
             "left_wrong": bool(lw)}
            for u, t, k, d, s, lw in zip(
                self.unit[part].tolist(), m.turn[part].tolist(), m.kind[part].tolist(),
                m.decoded[part].tolist(), m.sent[part].tolist(), self.left[part].tolist(),
                strict=True,
            )
        ]  # fmt: skip

    def frame(self) -> pd.DataFrame:
        """One row a misread, in unit and decode order: ``unit``, ``kind``, ``decoded`` and
        ``sent`` (categoricals), ``turn`` (int64; -1: none), ``left_wrong`` (bool)."""
        import pandas as pd

        def categorical(numbers: np.ndarray) -> pd.Categorical:
            # categories in text order: the same frame however the texts were numbered
            used, codes = np.unique(numbers, return_inverse=True)
            texts = np.array([self.texts[i] for i in used.tolist()], dtype=object)
            order = np.argsort(texts, kind="stable")
            rank = np.empty_like(order)
            rank[order] = np.arange(order.size)
            kinds = pd.CategoricalDtype(texts[order].tolist())
            return pd.Categorical.from_codes(rank[codes.reshape(-1)], dtype=kinds)

        m = self.misread
        return pd.DataFrame(
            {
                "unit": pd.Categorical.from_codes(
                    self.unit, dtype=pd.CategoricalDtype(list(self.units))
                ),
                "turn": m.turn.astype(np.int64),
                "kind": categorical(m.kind),
                "decoded": categorical(m.decoded),
                "sent": categorical(m.sent),
                "left_wrong": self.left,
            }
        )


def decode_errors_of(reports: Sequence[Mapping[str, Any]]) -> DecodeErrors:
    """Every unit's misreads (``misreads_of``) against every report's sends (``sent_truth``),
    unit by unit in report order, and whether each stayed wrong (``payloads_read_right``)."""
    truth = sent_truth(reports)
    parts: list[Misreads] = []
    unit: list[np.ndarray] = []
    left: list[np.ndarray] = []
    for i, r in enumerate(reports):
        got = misreads_of(r["decodes"], truth)
        if not len(got):
            continue
        right = payloads_read_right(r["decodes"], truth, np.unique(got.turn))
        parts.append(got)
        unit.append(np.full(len(got), i, dtype=np.int32))
        left.append(~np.isin(got.turn, right))
    return DecodeErrors(
        tuple(r["unit"] for r in reports),
        tuple(truth.texts),
        np.concatenate(unit) if unit else np.zeros(0, dtype=np.int32),
        Misreads.concat(parts),
        np.concatenate(left) if left else np.zeros(0, dtype=bool),
    )


def wrong_decodes(
    unit: str, decodes: Iterable[Sequence[Any]] | DecodeArrays, truth: SentTruth
) -> list[dict[str, Any]]:
    """``misreads_of`` as ``decode_error`` entries, in decode order (a small run's, or a
    test's: a large run's are columns, ``DecodeErrors``)."""
    m, texts = misreads_of(decodes, truth), truth.texts
    return [
        decode_error(unit, None if t < 0 else t, texts[k], texts[d], texts[s])
        for t, k, d, s in zip(
            m.turn.tolist(), m.kind.tolist(), m.decoded.tolist(), m.sent.tolist(), strict=True
        )
    ]


def decode_error(
    unit: str, turn: int | None, kind: str, decoded: str, sent: str | None
) -> dict[str, Any]:
    """One misread as a dict (``DecodeErrors.rows``)."""
    return {"unit": unit, "turn": turn, "kind": kind, "decoded": decoded, "sent": sent}


def decode_errors_line(counts: Mapping[str, Any], shown: int = 5) -> str:
    """The summary's ``decode_errors`` in one line, as ``rgtbus run`` prints it: the count,
    those set right, the first ``shown`` of the sample and where the others are."""
    n, left = counts["misread"], counts["left_wrong"]
    text = f"decode errors: {n:,}"
    if left < n:
        text += f", {left:,} left wrong (the others set right)"
    sample = counts["sample"][:shown]
    if sample:
        text += "  (" + "; ".join(
            f"{e['unit']} turn {e['turn']}: {e['decoded']} for {e['sent']}" for e in sample
        )
        text += f"; {n - len(sample):,} more: {WHERE_THE_REST_ARE})" if n > len(sample) else ")"
    return text
