"""``Log.decodes()`` built as columns (rgtbus.telemetry.decode_table), with no Python object per
decode: the same frame, cell for cell and dtype for dtype, as the frame of row objects it
replaces (``Log._decodes_of_rows``), on shipped scenarios that decode every kind of code,
misread, repair, and on a log missing transmissions; a damaged record is one line."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import rgtbus
from rgtbus.errors import RgtbusError
from rgtbus.telemetry import records
from rgtbus.telemetry.decode_table import decode_table

ROOT = Path(__file__).parent.parent


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("decodes")
    out = {}
    for name in ("gate", "gate_noisy", "gate_repair", "tug_of_war", "example2", "crowd10"):
        path = folder / f"{name}.mcap"
        rgtbus.run(ROOT / "scenarios" / f"{name}.toml", log=path)
        out[name] = path
    # noisier: an ID misread (the run fails on it; its log holds what was decoded)
    text = (ROOT / "scenarios" / "gate_noisy.toml").read_text()
    misread = folder / "misread.toml"
    misread.write_text(re.sub(r"(?m)^noise = .*$", "noise = 0.1", text))
    rgtbus.run(misread, log=folder / "misread.mcap")
    out["misread"] = folder / "misread.mcap"
    return out


@pytest.mark.parametrize(
    "name", ["gate", "gate_noisy", "gate_repair", "tug_of_war", "example2", "crowd10", "misread"]
)
def test_the_columnar_frame_is_the_frame_of_rows(logs, name):
    log = rgtbus.open_log(logs[name])
    got = log.decodes()
    assert len(got) > 10
    pd.testing.assert_frame_equal(got, log._decodes_of_rows())
    if name == "misread":
        assert not got["matches"].all()  # the comparison is not all one way


def test_decodes_whose_transmission_is_not_logged_have_none(logs):
    """A log that lacks some transmissions (cut, or its pulses lost): those decodes read
    nothing (None), as rows give them, and the columns' types follow."""
    log = rgtbus.open_log(logs["gate"])
    log.replay.transmissions = log.replay.transmissions[::2]
    got = log.decodes()
    assert got["sent"].isna().any() and got["sent"].notna().any()
    pd.testing.assert_frame_equal(got, log._decodes_of_rows())


def _record() -> dict:
    cols = [
        np.array([1, 2]), np.array([0, 0]), np.array([1, 2]), np.array([0, 2]),
        np.array([0, 1]), np.array([1, 0]), np.array([0.5, 0.25]), np.array([1.25, 2.5]),
        np.array([True, True]),
    ]  # fmt: skip
    tables = (("a", "b", "c"), ("id", "relation", "influence"), ("conflict", "id"))
    rec = rgtbus.telemetry.MemoryRecorder(validate=True)
    rec.write("/rx/decodes", records.decodes_of_columns("b", cols, tables), 2_500_000_000)
    ((_, _, back),) = rec.messages
    return back


def test_a_damaged_record_is_one_line_naming_it():
    good = _record()
    table = decode_table([(0, good)])
    assert [table.names[i] for i in table.sender] == ["a", "a"]
    assert [table.codes[i] for i in table.code] == ["id", "conflict"]
    for change, says in (
        ({"code": [1, 2]}, "code 2 is no index into its 2 codes"),
        ({"sender": [0, -1]}, "sender -1 is no index into its 3 names"),
        ({"kind": [0, True]}, "kind True is no index into its 3 kinds"),
        ({"kind": [0, 2**70]}, "kind 1180591620717411303424 is no index into its 3 kinds"),
        ({"kinds": "id"}, "'kinds' is not a list of names"),
        ({"names": None}, "'names' is not a list of names"),
        ({"code": []}, "column 'code' is 0 entries, not 2 entries like times"),
        ({"margin": None}, "column 'margin' is missing, not 2 entries like times"),
        ({"times": 1.25}, "column 'times' is float, not a list"),
        ({"turn": [1, 1.5]}, "column 'turn' holds other than numbers"),
        ({"turn": [1, 2**70]}, "column 'turn' holds a number out of range"),
        ({"accepted": [True, 1]}, "column 'accepted' holds other than true and false"),
    ):
        with pytest.raises(RgtbusError, match="^/rx/decodes of 'b' at t = 2.5: " + says):
            decode_table([(0, {**good, **change})])
    with pytest.raises(RgtbusError, match=r"^/rx/decodes at log time 7 ns: not an object"):
        decode_table([(7, [good])])
