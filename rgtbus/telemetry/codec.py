"""Columnar blocks: protobuf messages whose columns are packed repeated fixed-width fields.

The hot topics of the log (issue 51: pulses, spikes, decodes, the medium, traces) are written
as blocks, each a flat protobuf message that any protobuf library decodes from the schema
stored in the file (a ``FileDescriptorSet``, ``file_descriptor_set``). A column is a packed
repeated field of a fixed-width type (``double``, ``float``, ``fixed32``, ``sfixed32``,
``fixed64``, ``sfixed64``; ``bool`` is one byte an element, 0 or 1), so on the wire it is

    tag(number, LEN) · varint(len(array) × itemsize) · array.astype('<dtype').tobytes()

and a reader gets it back with ``np.frombuffer``: array speed both ways, no per-element work.
Varints and the protobuf library's per-element conversion are kept off this path.

``encode`` writes exactly what protobuf's own serializer writes for the same message (fields
in number order, proto3: a zero, empty or false scalar and an empty column left out), so a
block's bytes are canonical: a function of its values alone.

``decode`` trusts nothing: every length is checked against what is left of the message, every
column's row count against ``max_rows`` and against the other columns of its table, before
an array is made (``np.frombuffer`` makes views of the message's own bytes, so a block costs
no more memory than its size). Anything wrong is one ``RgtbusError`` naming where (the
caller's ``where``: a file, topic and log time), the message type and the field.
"""

from __future__ import annotations

import functools
import re
import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, NoReturn, TypeAlias

import numpy as np

from rgtbus.errors import BadInput, BadLog

Kind: TypeAlias = Literal[
    "double", "float", "fixed32", "sfixed32", "fixed64", "sfixed64", "bool", "string"
]

# protobuf's wire types
VARINT, I64, LEN, I32 = 0, 1, 2, 5

# each numeric kind: its NumPy dtype on the wire (little-endian) and its scalar wire type
_NUMERIC: dict[str, tuple[np.dtype[Any], int]] = {
    "double": (np.dtype("<f8"), I64),
    "float": (np.dtype("<f4"), I32),
    "fixed32": (np.dtype("<u4"), I32),
    "sfixed32": (np.dtype("<i4"), I32),
    "fixed64": (np.dtype("<u8"), I64),
    "sfixed64": (np.dtype("<i8"), I64),
    "bool": (np.dtype("u1"), VARINT),
}
KINDS: tuple[str, ...] = (*_NUMERIC, "string")

_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_MAX_NUMBER = (1 << 29) - 1
_RESERVED = range(19000, 20000)  # protobuf keeps these numbers for itself

Value: TypeAlias = "np.ndarray | list[str] | float | int | bool | str"
Block: TypeAlias = dict[str, Value]


@dataclass(frozen=True)
class Field:
    """One field of a block: a column (``repeated``) or a scalar. ``table`` groups columns
    that hold the rows of one table: they must have one length (``decode`` checks it)."""

    name: str
    number: int
    kind: Kind
    repeated: bool = False
    table: str | None = None

    @property
    def dtype(self) -> np.dtype[Any]:
        """The NumPy dtype of a numeric field on the wire (little-endian)."""
        return _NUMERIC[self.kind][0]


@dataclass(frozen=True)
class BlockSchema:
    """A block's message type: ``name`` fully qualified (``rgtbus.PulseBlock``), its fields.
    Checked when made: names are identifiers, numbers unique and in protobuf's range, a
    table's fields are columns."""

    name: str
    fields: tuple[Field, ...]

    def __post_init__(self) -> None:
        package, _, message = self.name.rpartition(".")
        if not _NAME.match(message) or not all(_NAME.match(p) for p in package.split(".")):
            raise BadInput(f"block type {self.name!r}: not a package-qualified name")
        names: set[str] = set()
        numbers: set[int] = set()
        for f in self.fields:
            where = f"block type {self.name}, field {f.name!r}"
            if not _NAME.match(f.name) or f.name in names:
                raise BadInput(f"{where}: not an identifier, or named twice")
            if not 1 <= f.number <= _MAX_NUMBER or f.number in _RESERVED or f.number in numbers:
                raise BadInput(f"{where}: number {f.number} out of range or used twice")
            if f.kind not in KINDS:
                raise BadInput(f"{where}: kind {f.kind!r} is none of {', '.join(KINDS)}")
            if f.table is not None and not f.repeated:
                raise BadInput(f"{where}: a scalar in table {f.table!r}")
            names.add(f.name)
            numbers.add(f.number)
        object.__setattr__(self, "_by_number", {f.number: f for f in self.fields})
        object.__setattr__(self, "_in_order", tuple(sorted(self.fields, key=lambda f: f.number)))
        object.__setattr__(self, "_names", frozenset(names))

    def field(self, number: int) -> Field | None:
        """The field numbered ``number``, or None (an unknown field: skipped when read)."""
        by_number: dict[int, Field] = self.__dict__["_by_number"]
        return by_number.get(number)

    @property
    def package(self) -> str:
        return self.name.rpartition(".")[0]

    @property
    def message(self) -> str:
        return self.name.rpartition(".")[2]


_ONE_BYTE = [bytes((i,)) for i in range(0x80)]


def _varint(value: int) -> bytes:
    if value < 0x80:
        return _ONE_BYTE[value]
    out = bytearray()
    while value > 0x7F:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


@functools.cache
def _tag(number: int, wire: int) -> bytes:
    return _varint(number << 3 | wire)


# a repeated string's bytes, kept by (field number, its texts): a block's tables of names are the
# same in most blocks of a run (a unit's own units, kinds and codes), and cost more to encode than
# its columns do
_TEXTS: dict[tuple[int, tuple[str, ...]], bytes] = {}
_TEXTS_SIZE = 256


def _texts(number: int, values: Sequence[Any]) -> bytes:
    key = (number, values if type(values) is tuple else tuple(values))
    got = _TEXTS.get(key)
    if got is None:
        tag = _tag(number, LEN)
        parts: list[bytes] = []
        for text in key[1]:
            raw = str(text).encode()
            parts += (tag, _varint(len(raw)), raw)
        got = b"".join(parts)
        if len(_TEXTS) >= _TEXTS_SIZE:
            del _TEXTS[next(iter(_TEXTS))]
        _TEXTS[key] = got
    return got


def _column(f: Field, values: Any) -> np.ndarray:
    if type(values) is np.ndarray and values.dtype == f.dtype and values.ndim == 1:
        return values  # as the wire holds it already (a block builder's own)
    array = np.asarray(values)
    if array.ndim != 1:
        raise BadInput(f"column {f.name!r}: {array.ndim}-dimensional, a column is 1")
    if f.kind == "bool":
        if array.dtype != np.bool_:
            raise BadInput(f"column {f.name!r}: {array.dtype}, a bool column takes bool")
        return array.view(np.uint8) if array.flags.c_contiguous else array.astype(np.uint8)
    if array.dtype.kind not in "iuf" or (array.dtype.kind == "f") != (f.dtype.kind == "f"):
        raise BadInput(f"column {f.name!r}: {array.dtype} values for a {f.kind} column")
    out = array.astype(f.dtype, copy=False)
    if f.dtype.kind in "iu" and array.dtype != f.dtype:
        # a narrowing cast wraps silently: refuse what the column cannot hold
        info = np.iinfo(f.dtype)
        if array.size and (array.min() < info.min or array.max() > info.max):
            raise BadInput(f"column {f.name!r}: values outside {f.kind}")
    return out


_CODES = {"double": "d", "float": "f", "fixed32": "I", "sfixed32": "i", "fixed64": "Q",
          "sfixed64": "q"}  # fmt: skip
_SMALL = 64  # a list this short is packed by struct: NumPy's fixed cost is the larger


_STRUCTS: dict[tuple[int, str], struct.Struct] = {}


def _small_column(f: Field, values: list[Any]) -> bytes | None:
    """A short list's packed bytes, or None when it holds what only ``_column`` says well
    (a value of another type, one out of range: struct refuses a float for an integer, text
    and None for any number)."""
    key = (len(values), f.kind)
    packer = _STRUCTS.get(key)
    if packer is None:
        packer = _STRUCTS[key] = struct.Struct(f"<{len(values)}{_CODES[f.kind]}")
    if f.dtype.kind != "f" and any(type(v) is bool for v in values):
        return None
    try:
        return packer.pack(*values)
    except (struct.error, OverflowError, TypeError):
        return None


_PACK = {
    "double": struct.Struct("<d"),
    "float": struct.Struct("<f"),
    "fixed32": struct.Struct("<I"),
    "sfixed32": struct.Struct("<i"),
    "fixed64": struct.Struct("<Q"),
    "sfixed64": struct.Struct("<q"),
}


def _scalar(f: Field, value: Any) -> bytes:
    """A scalar's bytes (tag included), or b"" for proto3's default (left out)."""
    if f.kind == "string":
        text = str(value).encode()
        return _tag(f.number, LEN) + _varint(len(text)) + text if text else b""
    if f.kind == "bool":
        return _tag(f.number, VARINT) + b"\x01" if value else b""
    pack = _PACK[f.kind]
    if f.kind in ("float", "double"):
        if type(value) is not float and not isinstance(value, int | float | np.number):
            raise BadInput(f"field {f.name!r}: {value!r} is not a number")
        try:
            raw = pack.pack(float(value))
        except OverflowError:
            raise BadInput(f"field {f.name!r}: {value!r} outside {f.kind}") from None
    else:
        if isinstance(value, float | np.floating) and not float(value).is_integer():
            raise BadInput(f"field {f.name!r}: {value!r} is not an integer")
        try:
            raw = pack.pack(int(value))
        except (struct.error, OverflowError, TypeError, ValueError):
            raise BadInput(f"field {f.name!r}: {value!r} outside {f.kind}") from None
    # protobuf writes a scalar whose bits are not all zero (so -0.0 too, not 0.0)
    return _tag(f.number, _NUMERIC[f.kind][1]) + raw if any(raw) else b""


def encode(schema: BlockSchema, values: Mapping[str, Any]) -> bytes:
    """``values`` (a field's name -> a 1-D array or sequence for a column, a list of str for
    a repeated string, a number, bool or str for a scalar) as ``schema``'s message: the bytes
    protobuf's serializer writes for it. A missing field is its default (empty, zero). A
    name that is no field of ``schema``, or a value the field cannot hold: RgtbusError."""
    names: frozenset[str] = schema.__dict__["_names"]
    unknown = values.keys() - names
    if unknown:
        raise BadInput(f"{schema.name}: no field {sorted(unknown)[0]!r}")
    parts: list[bytes] = []
    in_order: tuple[Field, ...] = schema.__dict__["_in_order"]
    for f in in_order:
        if f.name not in values:
            continue
        value = values[f.name]
        if not f.repeated:
            parts.append(_scalar(f, value))
        elif f.kind == "string":
            parts.append(_texts(f.number, value))
        else:
            if type(value) is list and 0 < len(value) <= _SMALL and f.kind != "bool":
                raw = _small_column(f, value)
                if raw is not None:
                    parts += (_tag(f.number, LEN), _varint(len(raw)), raw)
                    continue
            column = _column(f, value)
            if column.size:
                parts += (_tag(f.number, LEN), _varint(column.nbytes), column.tobytes())
    return b"".join(parts)


class _Reader:
    """A walk over one message's bytes; every read checked against what is left."""

    def __init__(self, data: bytes | memoryview, fail: Callable[[str], NoReturn]) -> None:
        self.data = memoryview(data).cast("B")
        self.pos = 0
        self.fail = fail

    def varint(self, what: str) -> int:
        value = shift = 0
        for _ in range(10):
            if self.pos >= len(self.data):
                self.fail(f"{what}: the message ends inside a varint")
            byte = self.data[self.pos]
            self.pos += 1
            value |= (byte & 0x7F) << shift
            if byte < 0x80:
                return value
            shift += 7
        self.fail(f"{what}: a varint longer than 10 bytes")

    def take(self, n: int, what: str) -> tuple[int, int]:
        """The offset and length of the next ``n`` bytes, skipped over."""
        if n > len(self.data) - self.pos:
            self.fail(f"{what}: {n} bytes announced, {len(self.data) - self.pos} left")
        start = self.pos
        self.pos += n
        return start, n


def decode(
    schema: BlockSchema,
    data: bytes,
    *,
    max_rows: int,
    max_text: int = 1 << 16,
    where: str = "a block",
) -> Block:
    """``data`` read as ``schema``'s message, every field present or at its default.

    A column comes back as a read-only NumPy array viewing ``data`` (``bool`` columns as
    ``bool``), a repeated string as a list of str, a scalar as a Python value. Bounds, all
    checked before any array is made: each column holds at most ``max_rows`` rows, the columns
    of one table the same number, each string at most ``max_text`` bytes of UTF-8 and a
    repeated string at most ``max_rows`` of them; a bool column holds only 0 and 1; every
    length fits in what is left. A column may come in several packed pieces (protobuf allows
    it: they are joined); an unknown field is skipped. Anything else wrong: RgtbusError
    naming ``where``, the message type and the field."""

    def fail(why: str) -> NoReturn:
        raise BadLog(f"{where}: {schema.name}: {why}")

    reader = _Reader(data, fail)
    pieces: dict[str, list[tuple[int, int]]] = {}
    rows: dict[str, int] = {}
    texts: dict[str, list[str]] = {}
    scalars: dict[str, Any] = {}
    while reader.pos < len(reader.data):
        key = reader.varint("a field's tag")
        number, wire = key >> 3, key & 7
        f = schema.field(number)
        if f is None:
            _skip(reader, number, wire)
            continue
        what = f"field {f.name!r}"
        if f.kind == "string":
            if wire != LEN:
                fail(f"{what}: wire type {wire}, a string is {LEN}")
            start, n = reader.take(reader.varint(what), what)
            if n > max_text:
                fail(f"{what}: a text of {n} bytes, more than {max_text}")
            try:
                text = bytes(reader.data[start : start + n]).decode()
            except UnicodeDecodeError:
                fail(f"{what}: not UTF-8")
            if f.repeated:
                got = texts.setdefault(f.name, [])
                if len(got) >= max_rows:
                    fail(f"{what}: more than {max_rows} texts")
                got.append(text)
            else:
                scalars[f.name] = text
            continue
        dtype, scalar_wire = _NUMERIC[f.kind]
        if f.repeated:
            if wire != LEN:
                fail(f"{what}: wire type {wire}, a column is packed ({LEN})")
            start, n = reader.take(reader.varint(what), what)
            if n % dtype.itemsize:
                fail(f"{what}: {n} bytes, not a whole number of {f.kind} ({dtype.itemsize} B)")
            count = rows.get(f.name, 0) + n // dtype.itemsize
            if count > max_rows:
                fail(f"{what}: {count} rows, more than {max_rows}")
            rows[f.name] = count
            pieces.setdefault(f.name, []).append((start, n))
            continue
        if wire != scalar_wire:
            fail(f"{what}: wire type {wire}, a {f.kind} is {scalar_wire}")
        if wire == VARINT:
            scalars[f.name] = reader.varint(what) != 0
        else:
            start, n = reader.take(dtype.itemsize, what)
            value = np.frombuffer(reader.data, dtype, 1, start)[0]
            scalars[f.name] = value.item()
    tables: dict[str, tuple[str, int]] = {}
    for f in schema.fields:
        if f.table is None:
            continue
        count = len(texts.get(f.name, ())) if f.kind == "string" else rows.get(f.name, 0)
        first = tables.setdefault(f.table, (f.name, count))
        if first[1] != count:
            fail(f"table {f.table!r}: column {first[0]!r} has {first[1]} rows, {f.name!r} {count}")
    block: Block = {}
    for f in schema.fields:
        if f.kind == "string":
            block[f.name] = texts.get(f.name, []) if f.repeated else scalars.get(f.name, "")
        elif not f.repeated:
            block[f.name] = scalars.get(f.name, _default(f))
        else:
            column = _join(reader.data, f.dtype, pieces.get(f.name, []))
            if f.kind == "bool":
                if column.size and column.max() > 1:
                    fail(f"field {f.name!r}: a bool column holds a value other than 0 and 1")
                column = column.view(np.bool_)
            block[f.name] = column
    return block


def _default(f: Field) -> float | int | bool:
    return False if f.kind == "bool" else 0.0 if f.dtype.kind == "f" else 0


def _join(data: memoryview, dtype: np.dtype[Any], pieces: Sequence[tuple[int, int]]) -> np.ndarray:
    if len(pieces) == 1:
        start, n = pieces[0]
        return np.frombuffer(data, dtype, n // dtype.itemsize, start)
    if not pieces:
        return np.empty(0, dtype)
    out = np.concatenate(
        [np.frombuffer(data, dtype, n // dtype.itemsize, start) for start, n in pieces]
    )
    out.flags.writeable = False
    return out


def _skip(reader: _Reader, number: int, wire: int) -> None:
    what = f"unknown field {number}"
    if wire == VARINT:
        reader.varint(what)
    elif wire == I64:
        reader.take(8, what)
    elif wire == I32:
        reader.take(4, what)
    elif wire == LEN:
        reader.take(reader.varint(what), what)
    else:  # groups (3, 4) are proto2's, 6 and 7 are no wire type
        reader.fail(f"{what}: wire type {wire}, which no block uses")


# The schema as protobuf describes it: what the log stores with each hot topic's channel.

_TYPE_NAMES = {
    "double": "TYPE_DOUBLE",
    "float": "TYPE_FLOAT",
    "fixed32": "TYPE_FIXED32",
    "sfixed32": "TYPE_SFIXED32",
    "fixed64": "TYPE_FIXED64",
    "sfixed64": "TYPE_SFIXED64",
    "bool": "TYPE_BOOL",
    "string": "TYPE_STRING",
}


def file_name(schema: BlockSchema) -> str:
    """The ``.proto`` file that declares ``schema`` (``rgtbus/PulseBlock.proto``)."""
    return f"{schema.package.replace('.', '/')}/{schema.message}.proto"


def file_descriptor_set(schema: BlockSchema) -> bytes:
    """``schema`` as a serialized ``google.protobuf.FileDescriptorSet`` of one proto3 file:
    the schema data of an MCAP channel whose encoding is ``protobuf`` (what Foxglove, Rerun and
    every protobuf library read a message by)."""
    from google.protobuf import descriptor_pb2  # only here: a log's reader needs no protobuf

    fds = descriptor_pb2.FileDescriptorSet()
    proto = fds.file.add(name=file_name(schema), package=schema.package, syntax="proto3")
    message = proto.message_type.add(name=schema.message)
    for f in schema.fields:
        label = "LABEL_REPEATED" if f.repeated else "LABEL_OPTIONAL"
        message.field.add(
            name=f.name,
            number=f.number,
            label=descriptor_pb2.FieldDescriptorProto.Label.Value(label),
            type=descriptor_pb2.FieldDescriptorProto.Type.Value(_TYPE_NAMES[f.kind]),
            json_name=_json_name(f.name),
        )
    return fds.SerializeToString(deterministic=True)


def _json_name(name: str) -> str:
    head, *rest = name.split("_")
    return head + "".join(part[:1].upper() + part[1:] for part in rest)


def proto_text(schema: BlockSchema) -> str:
    """``schema`` as ``.proto`` source (for the documentation: what ``file_descriptor_set``
    stores, as a person reads it)."""
    lines = [
        'syntax = "proto3";',
        "",
        f"package {schema.package};",
        "",
        f"message {schema.message} {{",
    ]
    for f in schema.fields:
        repeated = "repeated " if f.repeated else ""
        table = f"  // table {f.table}" if f.table else ""
        lines.append(f"  {repeated}{f.kind} {f.name} = {f.number};{table}")
    lines.append("}")
    return "\n".join(lines) + "\n"
