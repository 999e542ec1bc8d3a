"""``replay --verify`` compares the hot topics as columns (rgtbus.telemetry.verify_columns):
on a log that agrees, the same verdict and the same counts as the comparison row by row, with
no row built; on a log that differs, the rows explain it as before. Spikes compare per unit,
whatever records hold them (a block cut in two, a record shared by units or one a unit)."""

from __future__ import annotations

import copy
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from rgtbus.units.rerun import check_reasoning, rerun_replay

import rgtbus
from rgtbus.telemetry import records, verify_columns
from rgtbus.telemetry import verify as verify_module
from rgtbus.telemetry.read import load_replay
from rgtbus.telemetry.verify import verify
from rgtbus.telemetry.verify_columns import compact, same_decodes, same_spikes

ROOT = Path(__file__).parent.parent


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("verify")
    out = {}
    for name in ("gate", "crowd10", "gate_noisy"):
        out[name] = folder / f"{name}.mcap"
        rgtbus.run(ROOT / "scenarios" / f"{name}.toml", log=out[name])
    return out


def _report(path: Path, monkeypatch, columns: bool, equal: bool = False):
    """``verify``'s report of a log, the hot topics compared as columns (or as rows), with
    (``equal``) or without the messages that are the same byte for byte left out first."""
    taken = []

    def spy(compare, *args):
        got = compare(*args) if columns else None
        taken.append(got)
        return got

    monkeypatch.setattr(verify_module, "_same", spy)
    if not equal:
        monkeypatch.setattr(verify_module, "equal_messages", lambda *a: (set(), set(), Counter()))
    replay = load_replay(path)
    report = verify(replay, rerun_replay(replay), check_reasoning(replay))
    monkeypatch.undo()
    return report, taken


@pytest.mark.parametrize("name", ["gate", "crowd10", "gate_noisy"])
def test_a_log_that_agrees_verifies_as_columns_with_the_counts_of_rows(logs, name, monkeypatch):
    by_columns, taken = _report(logs[name], monkeypatch, columns=True)
    assert taken and all(n is not None for n in taken)  # no row built for decodes and spikes
    by_rows, _ = _report(logs[name], monkeypatch, columns=False)
    # what is the same byte for byte is left out first: the counts are those of the rows
    by_bytes, _ = _report(logs[name], monkeypatch, columns=False, equal=True)
    assert by_columns.ok and by_rows.ok and by_bytes.ok
    assert by_columns.checked == by_rows.checked == by_bytes.checked
    assert by_columns.verdict() == by_rows.verdict() == by_bytes.verdict()


def test_only_what_differs_is_compared_field_by_field(logs):
    """The messages a re-run wrote byte for byte are left out of the field-by-field
    comparison (never decoded): on a log that agrees, all of them; one decision changed in
    the re-run, and that one (with its logged twin) is left in, and named."""
    replay = load_replay(logs["crowd10"])
    rerun = rerun_replay(replay)
    leave, keep, same = verify_module.equal_messages(replay, rerun.messages, replay.units)
    paired = {i for i, m in enumerate(rerun.messages) if m[0] in verify_module._PAIRED}
    assert len(keep) == len(leave) > 0.9 * len(paired) and same[records.RX_DECODE] == 3600
    # the rest: the units' last blocks of spikes, which the log holds as one record (its
    # recorder joins what it held for their time, the re-run's capture does not)
    assert {rerun.messages[i][0] for i in paired - keep} == {records.RX_SPIKE}
    i, (topic, t_ns, m) = next(
        (i, m) for i, m in enumerate(rerun.messages) if m[0] == records.UNIT_DECISION
    )
    rerun.messages[i] = (topic, t_ns, {**m, "frustrated": not m["frustrated"]})
    leave2, keep2, _ = verify_module.equal_messages(replay, rerun.messages, replay.units)
    assert keep - keep2 == {i} and len(leave - leave2) == 1
    report = verify(replay, rerun, check_reasoning(replay))
    assert not report.ok and report.checked[records.UNIT_DECISION] == same[records.UNIT_DECISION]
    assert [(x.topic, x.field) for x in report.mismatches] == [
        (records.UNIT_DECISION, f"subject {m['subject']}: frustrated")
    ]


def _decodes(path: Path):
    replay = load_replay(path)
    return [(t, compact(m)) for t, m in replay.by_topic.each(records.RX_DECODES)]


def _spikes(path: Path):
    replay = load_replay(path)
    return [(t, compact(m)) for t, m in replay.by_topic.each(records.RX_SPIKE)]


def test_a_decode_that_differs_is_left_to_the_rows(logs):
    a = _decodes(logs["crowd10"])
    n = same_decodes(a, a, None)
    assert n and n > 100
    for column, change in (("margin", 1e-12), ("turn", 1), ("times", 5e-3)):
        b = copy.deepcopy(a)
        b[3][1][column] = b[3][1][column] + change
        assert same_decodes(a, b, None) is None, column
    b = copy.deepcopy(a)
    b[3][1]["accepted"] = ~b[3][1]["accepted"]
    assert same_decodes(a, b, None) is None
    assert same_decodes(a, a[:-1], None) is None  # one record fewer
    # a cut: only decodes before it count, on both sides
    cut = int(np.median([t for t, _ in a]))
    assert same_decodes(a, [m for m in a if m[0] < cut] + a[-1:], cut) is not None


def _split(message, at):
    first, second = dict(message), dict(message)
    first["samples"], first["channel"] = message["samples"][:at], message["channel"][:at]
    second["samples"], second["channel"] = message["samples"][at:], message["channel"][at:]
    return first, second


def test_spikes_compare_per_unit_whatever_records_hold_them(logs):
    tau = 0.005
    a = _spikes(logs["crowd10"])
    n = same_spikes(a, a, tau, None)
    assert n and n > 100
    shared = next(i for i, (_, m) in enumerate(a) if "units" in m and len(m["samples"]) > 2)
    t, m = a[shared]
    # one record a unit, and the block cut in two: the same spikes, the same count
    own = [(t, {**{k: v for k, v in m.items() if k != "units"}, "unit": u}) for u in m["units"]]
    cut = [(t, part) for part in _split(m, 1)]
    assert same_spikes(a, a[:shared] + own + a[shared + 1 :], tau, None) == n
    assert same_spikes(a, a[:shared] + cut + a[shared + 1 :], tau, None) is not None
    # a spike on another channel, or one unit fewer: left to the rows
    other = dict(m)
    other["channel"] = np.array(m["channel"])
    other["channel"][0] = (other["channel"][0] + 1) % len(m["names"])
    assert same_spikes(a, [*a[:shared], (t, other), *a[shared + 1 :]], tau, None) is None
    fewer = {**m, "units": m["units"][1:]} if len(m["units"]) > 2 else {**m, "units": None}
    if fewer["units"] is None:
        fewer = {k: v for k, v in m.items() if k != "units"} | {"unit": m["units"][1]}
    assert same_spikes(a, [*a[:shared], (t, fewer), *a[shared + 1 :]], tau, None) is None


def test_a_tampered_log_is_explained_by_the_rows(logs, tmp_path, monkeypatch):
    """One decode's margin changed in the file: the columns disagree, the rows name it."""
    replay = load_replay(logs["gate"])
    rerun = rerun_replay(replay)
    for i, (topic, t_ns, m) in enumerate(rerun.messages):
        if topic == records.RX_DECODES:
            margin = np.array(m["margin"], dtype=float)
            margin[0] += 0.25
            rerun.messages[i] = (topic, t_ns, {**m, "margin": margin})
            break
    report = verify(replay, rerun, check_reasoning(replay))
    assert not report.ok and report.mismatches[0].topic == records.RX_DECODE
    assert "margin" in report.mismatches[0].field


def test_compact_keeps_what_it_cannot_hold_as_one_type():
    m = {"samples": [1, 2], "channel": [0, True], "t": 1.5, "names": ["a"], "x": [2**70]}
    got = compact(m)
    assert got["samples"].dtype == np.int64 and got["channel"] == [0, True]
    assert got["names"] == ["a"] and got["x"] == [2**70] and got["t"] == 1.5
    assert verify_columns.compact([1]) == [1]
