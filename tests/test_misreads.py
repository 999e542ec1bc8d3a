"""Decode errors as columns (rgtbus.misreads): the summary's counts and sample, the frame of
every misread from the run and from its log, and the column forms against the row forms."""

from __future__ import annotations

import json
import random
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import rgtbus
from rgtbus.misreads import (
    MISREAD_SAMPLE,
    HeldDecodes,
    SentTruth,
    decode_errors_of,
    misreads_of,
    payloads_read_right,
    sent_truth,
    wrong_decodes,
)
from rgtbus.scenario import parse_scenario

ROOT = Path(__file__).resolve().parent.parent


def _noisy_repair(noise: float = 0.3) -> str:
    """gate_repair on a noisier channel: at 0.3 and seed 1, 116 misreads, a repair's copies
    set most of them right, 4 stay wrong (a run that finishes)."""
    text = (ROOT / "scenarios" / "gate_repair.toml").read_text()
    return text.replace("noise = 0.1", f"noise = {noise}")


def _left_by_rows(reports: list[dict]) -> list[tuple[str, int | None, bool]]:
    """Every misread and whether it stayed wrong, judged row by row (the rows path of each
    function, on each unit's decodes as plain rows)."""
    truth = sent_truth(reports)
    out = []
    for r in reports:
        rows = [list(x) for x in r["decodes"]]
        errs = wrong_decodes(r["unit"], rows, truth)
        turns = np.array(sorted({e["turn"] for e in errs}), dtype=np.int64)
        right = set(payloads_read_right(rows, truth, turns).tolist())
        out += [(e["unit"], e["turn"], e["turn"] not in right) for e in errs]
    return out


def test_counts_sample_and_frame_agree_from_the_run_and_from_its_log(tmp_path):
    from rgtbus.units.group import run_group

    from rgtbus.telemetry import NullRecorder

    sc = parse_scenario(_noisy_repair()).with_seed(1)
    res = rgtbus.run(sc, log=tmp_path / "run.mcap")
    counts = res.summary["decode_errors"]
    frame = res.decode_errors()
    n, left = counts["misread"], counts["left_wrong"]
    assert 0 < left < n == len(frame)  # some set right, some not: both fates are counted
    assert counts["set_right"] == n - left == int((~frame["left_wrong"]).sum())
    for kind, c in counts["by_kind"].items():
        mine = frame[frame["kind"] == kind]
        assert (c["misread"], c["left_wrong"]) == (len(mine), int(mine["left_wrong"].sum()))
    assert sum(c["misread"] for c in counts["by_kind"].values()) == n
    # the sample is the frame's first rows, as dicts
    head = frame.head(MISREAD_SAMPLE).astype(
        {"unit": str, "kind": str, "decoded": str, "sent": str}
    )
    assert counts["sample"] == head.to_dict("records")
    assert (counts["rest"] is None) == (n <= MISREAD_SAMPLE)
    # columns of integers and categoricals
    assert frame["turn"].dtype == np.int64 and frame["left_wrong"].dtype == bool
    assert all(
        isinstance(frame[c].dtype, pd.CategoricalDtype) for c in ("unit", "kind", "decoded", "sent")
    )
    # the log gives the same frame and the same summary
    log = rgtbus.open_log(tmp_path / "run.mcap")
    pd.testing.assert_frame_equal(log.decode_errors(), frame)
    assert log.summary()["decode_errors"] == counts
    # judged row by row, each misread's fate is the same
    out = run_group(sc, "memory", NullRecorder())
    want = _left_by_rows(out.reports)
    got = list(
        zip(
            frame["unit"].astype(str),
            frame["turn"].tolist(),
            frame["left_wrong"].tolist(),
            strict=True,
        )
    )
    assert got == want


def _random_case(rng: random.Random) -> tuple[SentTruth, list[list]]:
    units = ["a", "b", "c", "d"]
    words = ["id", "alliance", "conflict", "{x}", "{y}"]
    sent = {}
    for turn in range(rng.randint(0, 12)):
        sent[(turn, "id")] = (rng.choice(units), "id")
        sent[(turn, "payload")] = (rng.choice(units), rng.choice(words[1:]))
    rows = []
    for _ in range(rng.randint(0, 60)):
        turn = rng.randint(-1, 13)
        kind = rng.choice(["id", "relation", "influence"])
        rows.append([turn, kind, rng.choice(units), rng.choice(words)])
    return SentTruth(sent), rows


def _as_columns(rows: list[list]) -> HeldDecodes:
    """The same decodes held as columns (each one's turn and its distinct row's index)."""
    distinct = sorted({tuple(r[1:]) for r in rows})
    index = {k: i for i, k in enumerate(distinct)}
    return HeldDecodes(
        np.array([r[0] for r in rows], dtype=np.intc),
        np.array([index[tuple(r[1:])] for r in rows], dtype=np.int64),
        distinct,
    )


@pytest.mark.parametrize("seed", range(40))
def test_the_column_forms_judge_as_the_row_forms(seed):
    """misreads_of and payloads_read_right on columns (HeldDecodes) against the same decodes
    as rows, on random sends and decodes (turns out of span, repeats, unknown turns)."""
    rng = random.Random(seed)
    truth_rows, rows = _random_case(rng)
    truth_cols = SentTruth(truth_rows.sent)
    held = _as_columns(rows)
    assert wrong_decodes("u", held, truth_cols) == wrong_decodes("u", rows, truth_rows)
    m = misreads_of(held, truth_cols)
    turns = np.unique(m.turn)
    assert payloads_read_right(held, truth_cols, turns).tolist() == (
        payloads_read_right(rows, truth_rows, turns).tolist()
    )


def test_reports_of_rows_and_of_columns_give_equal_decode_errors():
    rng = random.Random(7)
    truth, rows = _random_case(rng)
    while not wrong_decodes("u", rows, truth):
        truth, rows = _random_case(rng)
    sends = [(t, k, *v) for (t, k), v in truth.sent.items()]
    reports = [{"unit": "u", "decodes": rows, "sends": sends}]
    held = _as_columns(rows)
    a = decode_errors_of(reports)
    b = decode_errors_of([{**reports[0], "decodes": held}])
    assert len(a) > 0 and a == b and a.counts() == b.counts()
    pd.testing.assert_frame_equal(a.frame(), b.frame())


def test_json_prints_counts_and_a_bounded_sample(tmp_path):
    path = tmp_path / "noisy.toml"
    path.write_text(_noisy_repair(0.2))  # 69 misreads at seed 3
    proc = subprocess.run(
        [sys.executable, "-m", "rgtbus", "run", str(path), "--seed", "3", "--json", "--no-log"],
        capture_output=True, text=True, cwd=ROOT, timeout=300,
    )  # fmt: skip
    s = json.loads(proc.stdout)
    counts = s["decode_errors"]
    assert counts["misread"] > MISREAD_SAMPLE and len(counts["sample"]) == MISREAD_SAMPLE
    assert (
        "decode_errors()" in counts["rest"]
        and str(counts["misread"] - MISREAD_SAMPLE) in counts["rest"]
    )
    assert "decode_errors_left" not in s


def test_word_errors_are_the_misreads_read_as_another_word():
    res = rgtbus.run(parse_scenario(_noisy_repair()).with_seed(1))
    assert res.misreads is not None
    frame = res.decode_errors()
    other = frame[frame["decoded"].astype(str) != frame["sent"].astype(str)]
    other = other.groupby("kind", observed=True).size()
    got = res.misreads.word_errors()
    assert set(got) == {"id", "relation", "influence"}
    for kind, n in got.items():
        assert n == int(other.get(kind, 0))
    # some misreads here are the word sent, read for another turn or unit: no symbol error
    assert sum(got.values()) < len(frame)
