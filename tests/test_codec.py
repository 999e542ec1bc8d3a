"""The block codec (rgtbus.telemetry.codec): columns as packed fixed-width protobuf fields.

The other side's tools are the judge: the protobuf library, given only the file descriptor set
the codec writes, must read the codec's bytes to the same values and write the same bytes for
the same message; and the codec must read what the library writes."""

from __future__ import annotations

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from rgtbus.errors import RgtbusError
from rgtbus.telemetry.codec import (
    BlockSchema,
    Field,
    decode,
    encode,
    file_descriptor_set,
    proto_text,
)

BLOCK = BlockSchema(
    "rgtbus.test.Block",
    (
        Field("unit", 1, "string"),
        Field("t", 2, "double"),
        Field("count", 3, "fixed32"),
        Field("offset", 4, "sfixed64"),
        Field("done", 5, "bool"),
        Field("gain", 6, "float"),
        Field("time", 10, "double", repeated=True, table="rows"),
        Field("channel", 11, "fixed32", repeated=True, table="rows"),
        Field("value", 12, "float", repeated=True, table="rows"),
        Field("sample", 13, "sfixed64", repeated=True, table="rows"),
        Field("accepted", 14, "bool", repeated=True, table="rows"),
        Field("names", 15, "string", repeated=True),
        Field("flags", 16, "fixed64", repeated=True),
        Field("offsets", 17, "sfixed32", repeated=True),
    ),
)


def library_class(schema: BlockSchema) -> type:
    """The protobuf library's message class for ``schema``, built from the codec's own file
    descriptor set alone (what a reader of the log has)."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(file_descriptor_set(schema))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


LIBRARY = library_class(BLOCK)

finite64 = st.floats(allow_nan=False, width=64)
finite32 = st.floats(allow_nan=False, width=32)
text = st.text(max_size=20)


@st.composite
def blocks(draw: st.DrawFn) -> dict[str, object]:
    n = draw(st.integers(0, 40))

    def column(dtype: str, elements: st.SearchStrategy[object]) -> np.ndarray:
        return draw(hnp.arrays(np.dtype(dtype), n, elements=elements))

    return {
        "unit": draw(text),
        "t": draw(finite64),
        "count": draw(st.integers(0, 2**32 - 1)),
        "offset": draw(st.integers(-(2**63), 2**63 - 1)),
        "done": draw(st.booleans()),
        "gain": draw(finite32),
        "time": column("f8", finite64),
        "channel": column("u4", st.integers(0, 2**32 - 1)),
        "value": column("f4", finite32),
        "sample": column("i8", st.integers(-(2**63), 2**63 - 1)),
        "accepted": column("?", st.booleans()),
        "names": draw(st.lists(text, max_size=5)),
        "flags": draw(hnp.arrays(np.dtype("u8"), draw(st.integers(0, 5)))),
        "offsets": draw(hnp.arrays(np.dtype("i4"), draw(st.integers(0, 5)))),
    }


def same(got: object, want: object) -> bool:
    if isinstance(want, np.ndarray):
        return np.array_equal(np.asarray(got), want)
    return list(got) == want if isinstance(want, list) else got == want  # type: ignore[call-overload]


@settings(max_examples=60, deadline=None)
@given(blocks())
def test_the_library_reads_the_codecs_bytes_and_writes_the_same(values):
    data = encode(BLOCK, values)
    message = LIBRARY.FromString(data)
    for name, want in values.items():
        got = getattr(message, name)
        assert same(got if not isinstance(want, np.ndarray) else list(got), want), name
    assert message.SerializeToString(deterministic=True) == data


@settings(max_examples=60, deadline=None)
@given(blocks())
def test_the_codec_reads_back_what_it_wrote_and_what_the_library_wrote(values):
    data = encode(BLOCK, values)
    for raw in (data, LIBRARY.FromString(data).SerializeToString()):
        block = decode(BLOCK, raw, max_rows=40)
        assert set(block) == {f.name for f in BLOCK.fields}
        for name, want in values.items():
            assert same(block[name], want), name


def test_columns_are_views_of_the_message_and_keep_their_dtypes():
    values = {"time": np.arange(5.0), "channel": np.arange(5, dtype=np.uint32),
              "value": np.ones(5, np.float32), "sample": np.arange(5),
              "accepted": np.ones(5, bool)}  # fmt: skip
    data = encode(BLOCK, values)
    block = decode(BLOCK, data, max_rows=5)
    for name, dtype in [("time", "<f8"), ("channel", "<u4"), ("value", "<f4"),
                        ("sample", "<i8"), ("accepted", "?")]:  # fmt: skip
        column = block[name]
        assert isinstance(column, np.ndarray) and column.dtype == np.dtype(dtype)
        assert not column.flags.writeable and not column.flags.owndata  # no copy made
    # the bytes are the arrays' own: a column is its tag, its length and tobytes()
    assert np.arange(5.0).tobytes() in data


def test_nan_and_negative_zero_survive():
    values = {"t": -0.0, "time": np.array([np.nan, -0.0, np.inf]), "channel": np.zeros(3, "u4"),
              "value": np.array([np.nan, 1, -np.inf], "f4"), "sample": np.zeros(3, "i8"),
              "accepted": np.zeros(3, bool)}  # fmt: skip
    block = decode(BLOCK, encode(BLOCK, values), max_rows=3)
    assert np.signbit(block["t"]) and np.isnan(block["time"][0]) and np.signbit(block["time"][1])
    assert np.isneginf(block["value"][2])
    assert encode(BLOCK, {"t": 0.0}) == b""  # proto3: a default is left out


def test_missing_fields_are_defaults_and_unknown_fields_are_skipped():
    extra = BlockSchema(
        "rgtbus.test.Block",
        (*BLOCK.fields, Field("later", 99, "double", repeated=True), Field("note", 98, "string")),
    )
    data = encode(extra, {"later": np.arange(3.0), "note": "x", "count": 7, "done": True})
    block = decode(BLOCK, data, max_rows=10)
    assert block["count"] == 7 and block["done"] is True and block["unit"] == ""
    assert block["t"] == 0.0 and block["names"] == [] and block["time"].size == 0


def test_a_column_in_pieces_is_joined():
    piece = encode(BLOCK, {"flags": np.array([1, 2], "u8")})
    block = decode(BLOCK, piece + piece, max_rows=4)
    assert block["flags"].tolist() == [1, 2, 1, 2]
    with pytest.raises(RgtbusError, match="'flags': 6 rows, more than 4"):
        decode(BLOCK, piece * 3, max_rows=4)


def test_encode_refuses_what_a_field_cannot_hold():
    with pytest.raises(RgtbusError, match="no field 'nope'"):
        encode(BLOCK, {"nope": 1})
    with pytest.raises(RgtbusError, match="'channel': values outside fixed32"):
        encode(BLOCK, {"channel": np.array([-1])})
    with pytest.raises(RgtbusError, match="'channel': float64 values"):
        encode(BLOCK, {"channel": np.array([1.5])})
    with pytest.raises(RgtbusError, match="'accepted': int64"):
        encode(BLOCK, {"accepted": np.array([0, 1])})
    with pytest.raises(RgtbusError, match="'count': -1 outside fixed32"):
        encode(BLOCK, {"count": -1})
    with pytest.raises(RgtbusError, match="2-dimensional"):
        encode(BLOCK, {"time": np.zeros((2, 2))})


def _bad(data: bytes, match: str, max_rows: int = 100) -> None:
    with pytest.raises(RgtbusError, match=match) as info:
        decode(BLOCK, data, max_rows=max_rows, where="run.mcap: message on /x at t = 1.000 s")
    line = str(info.value)
    assert "\n" not in line and line.startswith("run.mcap: message on /x at t = 1.000 s: ")
    assert "rgtbus.test.Block" in line


def test_hostile_bytes_are_one_line_naming_the_field():
    good = encode(BLOCK, {"time": np.arange(3.0), "channel": np.arange(3, dtype="u4"),
                          "value": np.ones(3, "f4"), "sample": np.arange(3),
                          "accepted": np.ones(3, bool)})  # fmt: skip
    _bad(good[:-1], "'accepted': 3 bytes announced, 2 left")
    _bad(b"\x52\xff\xff\xff\xff\x0f", "'time': 4294967295 bytes announced, 0 left")
    _bad(b"\x52\x05" + bytes(5), r"'time': 5 bytes, not a whole number of double")
    _bad(b"\x52" + b"\xff" * 11, "'time': a varint longer than 10 bytes")
    _bad(b"\x52", "'time': the message ends inside a varint")
    _bad(b"\x51" + bytes(8), "'time': wire type 1, a column is packed")
    _bad(b"\x11" + bytes(3), "'t': 8 bytes announced, 3 left")
    _bad(b"\x10\x00", "'t': wire type 0, a double is 1")
    _bad(b"\x0a\x02\xff\xfe", "'unit': not UTF-8")
    _bad(encode(BLOCK, {"time": [0.0], "channel": np.zeros(1, "u4"), "value": np.zeros(1, "f4"),
                        "sample": [0]}) + b"\x72\x01\x02",
         "'accepted': a bool column holds a value other than 0 and 1")  # fmt: skip
    _bad(b"\x52\x08" + bytes(8), "table 'rows': column 'time' has 1 rows, 'channel' 0")
    _bad(b"\x52\x10" + bytes(16), "'time': 2 rows, more than 1", max_rows=1)
    _bad(b"\x7a\x00" * 3, "'names': more than 2 texts", max_rows=2)
    _bad(b"\xfb\x01", "unknown field 31: wire type 3")
    _bad(b"\xfa\x01\x05ab", "unknown field 31: 5 bytes announced, 2 left")
    with pytest.raises(RgtbusError, match="a text of 5 bytes, more than 4"):
        decode(BLOCK, b"\x0a\x05hello", max_rows=1, max_text=4)


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=200))
def test_any_bytes_are_a_block_or_one_error(data):
    try:
        block = decode(BLOCK, data, max_rows=64)
    except RgtbusError as e:
        assert "\n" not in str(e)
        return
    assert all(len(block[f.name]) <= 64 for f in BLOCK.fields if f.repeated)


def test_a_schema_is_checked_when_made():
    for fields, match in [
        ((Field("a", 1, "double"), Field("a", 2, "double")), "named twice"),
        ((Field("a", 1, "double"), Field("b", 1, "double")), "used twice"),
        ((Field("a", 19500, "double"),), "out of range"),
        ((Field("a", 0, "double"),), "out of range"),
        ((Field("a-b", 1, "double"),), "not an identifier"),
        ((Field("a", 1, "int32"),), "kind 'int32'"),  # type: ignore[arg-type]
        ((Field("a", 1, "double", table="t"),), "a scalar in table 't'"),
    ]:
        with pytest.raises(RgtbusError, match=match):
            BlockSchema("rgtbus.X", fields)
    with pytest.raises(RgtbusError, match="not a package-qualified name"):
        BlockSchema("rgtbus.1X", ())


def test_proto_text_declares_what_the_descriptor_holds():
    text = proto_text(BLOCK)
    assert 'syntax = "proto3";' in text and "package rgtbus.test;" in text
    assert "repeated double time = 10;  // table rows" in text
    message = LIBRARY.DESCRIPTOR
    for f in BLOCK.fields:
        assert message.fields_by_name[f.name].number == f.number
