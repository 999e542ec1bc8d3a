import pytest

from rgtbus.errors import RgtbusError
from rgtbus.rgt import Universe

U = Universe(("alpha", "beta"))


@pytest.mark.parametrize(
    ("text", "mask"),
    [
        ("1", 0b11),
        ("0", 0),
        ("{}", 0),
        ("{alpha}", 0b01),
        ("{beta}", 0b10),
        ("{alpha,beta}", 0b11),
        ("{ beta , alpha }", 0b11),
        ("alpha", 0b01),
    ],
)
def test_parse(text, mask):
    assert U.parse_alternative(text) == mask


@pytest.mark.parametrize(("mask", "text"), [(0b11, "1"), (0, "0"), (1, "{alpha}"), (2, "{beta}")])
def test_format(mask, text):
    assert U.format(mask) == text
    assert U.parse_alternative(U.format(mask)) == mask


def test_json_form_is_sorted_names():
    u = Universe(("zeta", "alpha"))
    assert u.to_list(0b11) == ["alpha", "zeta"]
    assert u.to_list(0) == []
    assert u.from_list(["alpha"]) == 0b10


def test_operations_are_bitwise():
    a, b = U.parse_alternative("{alpha}"), U.parse_alternative("{beta}")
    assert a | b == U.full
    assert a & b == 0
    assert U.neg(a) == b


def test_subsets_between():
    assert [U.format(x) for x in U.subsets_between(0b10, 0b11)] == ["{beta}", "1"]
    assert U.subsets_between(0b01, 0b10) == []
    assert len(Universe(("x", "y", "z")).subsets_between(0, 0b111)) == 8


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("{gamma}", "'gamma'"),
        ("{alpha,gamma}", "'gamma'"),
        ("gamma", "'gamma'"),
        ("2", "'2'"),
        ("{alpha,}", "empty"),
        ("{alpha", "'{alpha'"),
    ],
)
def test_parse_errors_name_the_token(text, needle):
    with pytest.raises(RgtbusError, match=needle):
        U.parse_alternative(text)


@pytest.mark.parametrize(
    ("actions", "needle"), [((), "at least one"), (("a", "a"), "twice"), (("a b",), "bad action")]
)
def test_universe_errors(actions, needle):
    with pytest.raises(RgtbusError, match=needle):
        Universe(actions)
