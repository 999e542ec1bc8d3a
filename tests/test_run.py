"""End to end: the paper's scenarios on both buses, reproducibility, window size, noise, logs."""

import json
import math
import pickle
import random
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rgtbus.units.group import run_group
from rgtbus.units.listening import Listening
from rgtbus.units.unit import AutonomousUnit
from same_run import plain

from rgtbus.cli import main
from rgtbus.mind import choose_relations
from rgtbus.scenario import Timing, load_scenario, parse_scenario
from rgtbus.summary import check_expectations
from rgtbus.telemetry import McapRecorder, MemoryRecorder, NullRecorder, read_log, records
from rgtbus.telemetry.blocks import BLOCK_SECONDS, decode_record, schema_of
from rgtbus.telemetry.message_json import message_bytes
from rgtbus.telemetry.pulse_blocks import pulse_rows
from rgtbus.telemetry.record_rows import decode_rows, decode_units

ROOT = Path(__file__).parent.parent
PAPER = ["overview", "example1", "example2", "gate"]


def _bytes(messages) -> list[tuple[str, int, bytes]]:
    """A log's messages as the log holds them (``message_bytes``: a hot topic's block)."""
    return [(tp, t, message_bytes(tp, m)) for tp, t, m in messages]


def run(name_or_scenario, bus="memory", **kw):
    sc = name_or_scenario
    if isinstance(sc, str):
        sc = load_scenario(ROOT / "scenarios" / f"{sc}.toml")
    rec = MemoryRecorder()
    out = run_group(sc, bus, rec, **kw)
    return sc, out.summary, rec.read()


@pytest.mark.parametrize("bus", ["memory", "zenoh"])
@pytest.mark.parametrize("name", PAPER)
def test_paper_scenarios_end_to_end(name, bus):
    sc, summary, _ = run(name, bus)
    assert summary["error"] is None
    failed = [(w, d) for w, ok, d in check_expectations(sc, summary) if not ok]
    assert failed == []
    assert summary["agree"] and summary["decode_errors"]["misread"] == 0


def test_corrected_paper_values():
    _, s, _ = run("overview")
    assert s["polynomial"] == "a(b+c)" and s["units"]["a"]["frustrated"]
    assert s["units"]["b"]["interval"] == [["beta"], ["alpha", "beta"]]
    _, s, _ = run("example2")
    assert [s["units"][u]["interval"] for u in "abc"] == [
        [[], ["alpha", "beta"]],
        [["alpha"], ["alpha"]],
        [[], ["beta"]],
    ]
    _, s, _ = run("gate")
    assert s["outcome"] == "gate: open"
    assert all(s["units"][u]["choice"] == ["open"] for u in "abc")


def test_same_seed_same_log_and_buses_agree():
    _, s1, (m1, meta1) = run("example2", "memory")
    _, _s2, (m2, meta2) = run("example2", "memory")
    _, s3, (m3, meta3) = run("example2", "zenoh")
    # every pulse, spike, decode, table and decision, bit for bit
    assert _bytes(m1) == _bytes(m2) == _bytes(m3)
    assert meta1 == meta2
    assert {k: v for k, v in meta1["run"].items() if k != "bus"} == {
        k: v for k, v in meta3["run"].items() if k != "bus"
    }
    strip = ("wall_seconds", "bus", "steps", "sync")  # steps follow when frames happen to arrive
    assert {k: v for k, v in s1.items() if k not in strip} == {
        k: v for k, v in s3.items() if k not in strip
    }


def test_window_size_never_changes_a_result():
    base = load_scenario(ROOT / "scenarios" / "gate.toml")
    logs = []
    for window in (0.035, 0.1, 0.5):  # 7, 20 and 100 samples
        sc = replace(base, timing=replace(base.timing, window=window))
        _, summary, (messages, _) = run(sc)
        assert summary["outcome"] == "gate: open"
        # Same content; simultaneous messages may be written in another order.
        logs.append(
            sorted(
                (ns, t, json.dumps(m, sort_keys=True, default=plain))
                for t, ns, m in messages
                if t not in ("/medium", "/run")
            )
        )
    assert all(log == logs[0] for log in logs[1:])


def test_seed_changes_random_relations_reproducibly():
    text = (ROOT / "scenarios" / "example1.toml").read_text()
    start = text.index("[relations.draws]")
    end = text.index("[influences]")
    text = text[:start] + text[end:]  # no draws: relationships come from the seed
    sent = {}
    for seed in range(6):
        sc = replace(parse_scenario(text, "example1-random.toml"), seed=seed)
        _, s, _ = run(sc)
        assert s["error"] is None or "not decomposable" in s["error"]
        sent[seed] = s["sent_relations"]
        _, again, _ = run(sc)
        assert again["sent_relations"] == sent[seed]
    assert len({json.dumps(v, sort_keys=True) for v in sent.values()}) > 1


def test_alliance_probability_is_0_61():
    """p = 0.61 over many seeded draws: 12,000 relationship codes, within 4 standard errors."""
    text = (ROOT / "scenarios" / "example1.toml").read_text()
    text = text[: text.index("[relations.draws]")] + text[text.index("[influences]") :]
    base = parse_scenario(text, "random.toml")
    n = alliances = 0
    for seed in range(2000):
        sc = replace(base, seed=seed)
        for u in sc.units:
            choices = choose_relations(
                u,
                sc.units,
                seed=seed,
                fixed=sc.relations.fixed,
                draws=sc.relations.draws,
                p=sc.relations.p,
            )
            n += len(choices)
            alliances += sum(v == "alliance" for v in choices.values())
    se = math.sqrt(0.61 * 0.39 / n)
    assert abs(alliances / n - 0.61) < 4 * se


def test_paper_draws_give_the_papers_codes():
    _, s, _ = run("example1")
    assert s["sent_relations"] == {
        "a>b": "conflict",
        "a>c": "conflict",
        "b>a": "conflict",
        "b>c": "alliance",
        "c>a": "alliance",
        "c>b": "alliance",
    }


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_noisy_channel_still_decodes(seed):
    """Stated level: Gaussian noise sigma = 0.002 per sample on every unit's receiver.

    The resonators integrate white noise with a gain of about 1/sqrt(1 - |A|^2) = 31, so at
    sigma = 0.005 the ID-code's thin margin above threshold is lost and attention spikes fail;
    the increment readout itself stays exact up to the noise on the sample.
    """
    base = load_scenario(ROOT / "scenarios" / "gate.toml")
    sc = replace(base, channel=replace(base.channel, noise=0.002), seed=seed)
    _, s, (messages, _) = run(sc)
    assert (
        s["error"] is None and s["outcome"] == "gate: open" and s["decode_errors"]["misread"] == 0
    )
    margins = [x for t, _, m in messages if t == "/rx/decodes" for x in m["margin"]]
    assert min(margins) > 0.1


def test_cli_run_json_and_log(tmp_path, capsys):
    log = tmp_path / "gate.mcap"
    assert (
        main(
            [
                "run",
                str(ROOT / "scenarios/gate.toml"),
                "--bus",
                "memory",
                "--log",
                str(log),
                "--json",
                "--check",
                "--quiet",
            ]
        )
        == 0
    )
    out = json.loads(capsys.readouterr().out)
    for key in (
        "scenario",
        "seed",
        "polynomial",
        "relations",
        "agree",
        "influences",
        "units",
        "outcome",
        "sim_seconds",
        "wall_seconds",
        "log",
    ):
        assert key in out
    assert out["relations"]["a-b"] == "alliance" and out["influences"]["d>a"] == ["open"]
    assert out["units"]["d"] == {
        **out["units"]["d"],
        "interval": [[], ["open"]],
        "frustrated": False,
        "choice": ["open"],
    }
    assert all(c["ok"] for c in out["checks"])
    messages, metadata = read_log(log)
    topics = {t for t, _, _ in messages}
    assert {
        "/medium",
        "/tx/pulse",
        "/rx/spike",
        "/rx/decodes",
        "/unit/relations",
        "/unit/influences",
        "/unit/decision",
        "/log",
        "/run",
    } <= topics
    assert metadata["run"]["seed"] == "3" and "gate" in metadata["scenario"]["text"]
    assert [ns for _, ns, _ in messages] == sorted(ns for _, ns, _ in messages)
    pulses = [p for t, _, m in messages if t == "/tx/pulse" for p in pulse_rows(m)]
    assert len(pulses) == 24 * 2 * 3  # 24 turns, ID + payload, 3 pulses each


def test_cli_text_output(tmp_path, capsys):
    assert (
        main(
            [
                "run",
                str(ROOT / "scenarios/overview.toml"),
                "--bus",
                "memory",
                "--log",
                str(tmp_path / "o.mcap"),
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "polynomial: a(b+c)" in text and "all units agree: yes" in text
    assert "a = (b+c)a + not(a)" in text and "frustrated: no decision" in text
    assert "decode errors: 0" in text


def test_check_failure_exits_1(tmp_path, capsys):
    text = (
        (ROOT / "scenarios/gate.toml")
        .read_text()
        .replace('outcome = "gate: open"', 'outcome = "gate: closed"')
    )
    path = tmp_path / "gate.toml"
    path.write_text(text)
    assert (
        main(["run", str(path), "--bus", "memory", "--log", str(tmp_path / "g.mcap"), "--check"])
        == 1
    )
    assert "FAIL outcome: got 'gate: open', expected 'gate: closed'" in capsys.readouterr().out


def test_bad_scenario_exits_2(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text((ROOT / "scenarios/gate.toml").read_text().replace("seed = 3", "seed = -3"))
    assert main(["run", str(path), "--log", str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("seed: must be a non-negative integer, got -3") and "\n" not in err


def test_failed_run_still_leaves_a_readable_log(tmp_path, capsys):
    text = (ROOT / "scenarios/gate.toml").read_text().replace("noise = 0.0", "noise = 0.05")
    # the paper's threshold attention: its spikes come early, late or not at all at this noise
    text = text.replace("[timing]", '[timing]\nattention = "threshold"', 1)
    path = tmp_path / "noisy.toml"
    path.write_text(text)
    log = tmp_path / "noisy.mcap"
    assert main(["run", str(path), "--bus", "memory", "--log", str(log), "--quiet"]) == 1
    assert "run failed:" in capsys.readouterr().err
    messages, _ = read_log(log)
    run_msgs = [m for t, _, m in messages if t == "/run"]
    assert run_msgs and run_msgs[0]["error"]
    assert any(t == "/log" and m["level"] >= 4 for t, _, m in messages)


def test_crash_mid_run_still_closes_the_log(tmp_path, monkeypatch):
    def boom(self, listen):
        if listen.turn == 5:
            raise RuntimeError("decoder on fire")
        return original(self, listen)

    original = Listening.decode
    monkeypatch.setattr(Listening, "decode", boom)
    sc = load_scenario(ROOT / "scenarios" / "gate.toml")
    log = tmp_path / "crash.mcap"
    with open(log, "wb") as f:
        rec = McapRecorder(f)
        with pytest.raises(RuntimeError, match="decoder on fire"):
            try:
                run_group(sc, "memory", rec)
            finally:
                rec.close()
    messages, _ = read_log(log)
    assert any(t == "/medium" for t, _, _ in messages)


def test_timing_defaults_match_the_paper():
    t = Timing()
    assert (t.tau, t.window_samples, t.reaction_delay) == (0.005, 20, 0.5)
    assert random.Random("3:a:decision").random() == random.Random("3:a:decision").random()


def test_realtime_paces_the_run(tmp_path, capsys):
    argv = [
        "run",
        str(ROOT / "scenarios/overview.toml"),
        "--bus",
        "memory",
        "--quiet",
        "--log",
        str(tmp_path / "o.mcap"),
        "--json",
        "--realtime",
        "150",
    ]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["wall_seconds"] >= out["sim_seconds"] / 150 * 0.95
    assert main([*argv[:-1], "0"]) == 2
    assert "--realtime 0.0: must be a positive factor" in capsys.readouterr().err


def test_schedule_anchor_changes_nothing_on_a_clean_channel():
    base = load_scenario(ROOT / "scenarios" / "gate.toml")
    _, spike, (m_spike, _) = run(base)
    sched = replace(base, timing=replace(base.timing, anchor="schedule"))
    _, s, (m_sched, _) = run(sched)

    def content(ms):  # decodes one a row: on the schedule a unit takes them a batch a wake
        from rgtbus.telemetry.record_rows import decodes_per_row

        return sorted(
            (ns, t, json.dumps(m, sort_keys=True, default=plain))
            for t, ns, m in decodes_per_row(ms)
        )

    assert content(m_sched) == content(m_spike)
    assert s["units"] == spike["units"]


@pytest.mark.parametrize("seed", [1, 2])
def test_noisy_gate_decodes_at_sigma_0_05_when_anchored_on_the_schedule(seed):
    """Stated level for anchor = "schedule": sigma = 0.05 (25x what attention spikes stand)."""
    sc = load_scenario(ROOT / "scenarios" / "gate_noisy.toml").with_seed(seed)
    assert sc.channel.noise == 0.05 and sc.timing.anchor == "schedule"
    sc_, s, _ = run(sc)
    assert s["error"] is None and s["decode_errors"]["misread"] == 0
    assert [w for w, ok, _ in check_expectations(sc_, s) if not ok] == []


RANDOM5 = """
name = "rand5"
seed = 0
units = ["a", "b", "c", "d", "e"]
actions = ["alpha", "beta"]
frequencies = "auto"
[protocol]
schedule = "concurrent"
[relations]
policy = "random"
p = 0.8
[influences]
policy = "random"
"""


def test_a_random_group_that_installs_a_p4_is_a_result_not_an_error(tmp_path, capsys):
    """Seed 0 of this group installs c-b-e-d as an induced P4 (seed 1 a cograph): the run
    says so, decides nothing, and succeeds; its log's summary and replay say the same."""
    path = tmp_path / "rand5.toml"
    path.write_text(RANDOM5)
    log = tmp_path / "r.mcap"
    code = main(["run", str(path), "--bus", "memory", "--log", str(log)])
    out = capsys.readouterr().out
    assert code == 0
    assert "polynomial: (none): not decomposable: induced P4 c-b-e-d; no decisions" in out
    assert out.count(": no decision\n") == 5
    code = main(["run", str(path), "--bus", "memory", "--quiet", "--json", "--log", str(log)])
    s = json.loads(capsys.readouterr().out)
    assert code == 0 and s["error"] is None and s["agree"]
    assert s["decomposable"] is False and s["p4"] == ["c", "b", "e", "d"]
    assert s["polynomial"] is None and all(not u["decided"] for u in s["units"].values())
    assert main(["replay", str(log), "--json"]) == 0
    replayed = json.loads(capsys.readouterr().out)["summary"]
    assert replayed["decomposable"] is False and replayed["p4"] == ["c", "b", "e", "d"]
    assert main(["replay", str(log), "--verify"]) == 0
    capsys.readouterr()
    argv = ["run", str(path), "--bus", "memory", "--quiet", "--json", "--seed", "1"]
    code = main([*argv, "--log", str(tmp_path / "r1.mcap")])
    s = json.loads(capsys.readouterr().out)
    assert code == 0 and s["decomposable"] is True and s["p4"] is None and s["polynomial"]


def test_no_log_writes_nothing_and_summarises_the_same(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the default log would land in ./logs
    gate = str(ROOT / "scenarios/gate.toml")
    assert main(["run", gate, "--bus", "memory", "--no-log", "--json", "--check"]) == 0
    bare = json.loads(capsys.readouterr().out)
    assert bare["log"] is None and all(c["ok"] for c in bare["checks"])
    assert list(tmp_path.iterdir()) == []
    log = tmp_path / "g.mcap"
    assert main(["run", gate, "--bus", "memory", "--log", str(log), "--json"]) == 0
    logged = json.loads(capsys.readouterr().out)
    for key in set(bare) - {"wall_seconds", "log", "checks"}:
        assert bare[key] == logged[key], key
    assert main(["run", gate, "--no-log"]) == 0
    assert "log: none (--no-log)" in capsys.readouterr().out


@pytest.mark.parametrize("extra", [["--traces"], ["--live", "127.0.0.1:0"]])
def test_no_log_refuses_what_needs_a_log(tmp_path, capsys, extra):
    gate = str(ROOT / "scenarios/gate.toml")
    assert main(["run", gate, "--no-log", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert f"--no-log with {extra[0]}" in err and "\n" not in err


@pytest.mark.parametrize("name", ["example2", "overview", "coalition10"])
def test_decode_records_hold_a_block_of_time_each(name):
    """A unit's decodes go to the log one ``/rx/decodes`` record a block of
    ``DECODE_BLOCK_SECONDS`` (cut only where the unit writes another record of its own),
    whatever its wakes: every record's decodes lie in one block, at the last one's time; a
    unit's records leave in time order; and every decode is there once, as the unit made it,
    its names as indexes into the unit's tables (coalition10: batches of indexes joined with
    single decodes in one block; the serial runs: single decodes alone)."""
    from rgtbus.telemetry.unit_log import DECODE_BLOCK_SECONDS

    sc = load_scenario(ROOT / "scenarios" / f"{name}.toml")
    rec = MemoryRecorder()
    out = run_group(sc, "memory", rec)
    span = round(DECODE_BLOCK_SECONDS / sc.timing.tau)
    blocks = [m for topic, _, m in rec.messages if topic == "/rx/decodes"]
    for m in blocks:
        samples = [round(t / sc.timing.tau) for t in m["times"]]
        assert len({k // span for k in samples}) == 1 and m["t"] == m["times"][-1]
    assert any(len(m["times"]) > 1 for m in blocks)  # held across wakes
    for unit in out.units:  # its own records, as written (pulses and decodes: its group's)
        own = [
            t
            for topic, t, m in rec.messages
            if m.get("unit") == unit.name and topic not in ("/tx/pulse", "/rx/spike", "/rx/decodes")
        ]
        assert own == sorted(own)
        got = [
            (r["turn"], r["kind"], r["addressee"], r["code"])
            for m in blocks
            if unit.name in decode_units(m)
            for r in decode_rows(m)
            if r["unit"] == unit.name
        ]
        # the columns hold every decode but the IDs read as the ID, which they only count
        assert [r for r in got if r[1::2] != ("id", "id")] == list(unit.decoded)
        assert len(got) == len(unit.decoded) and any(r[1::2] == ("id", "id") for r in got)
    tables = {u.name: u.listening.log_tables for u in out.units}
    for m in blocks:
        for u in decode_units(m):
            assert (m["names"], m["kinds"], m["codes"]) == tuple(map(list, tables[u]))
    # the decodes units made alike: one record naming them (the serial runs' units decode
    # their own sends differently from the others: some records name one unit)
    assert any("units" in m for m in blocks)


def _block(data: bytes) -> dict[str, Any]:
    """A ``/rx/decodes`` block's bytes as a reader of the log gets the record."""
    return decode_record(schema_of(records.RX_DECODES), data, "a decode block")


def test_single_decodes_join_a_batch_as_its_indexes():
    """A unit's single decodes (names) held in a block with its batches (indexes) are written
    as indexes into the batches' tables, every column as it was (margins and times to the
    last bit); a name in none of the tables keeps the part in names."""
    from rgtbus.telemetry.unit_log import DecodePart, _indexed_part

    tables = (["a", "b", "c"], ["id", "relation", "influence"], ["id", "alliance", "conflict"])
    rows = [
        (3, "a", "b", "b", "relation", "conflict", 0.1 + 0.2, 1.005, True),
        (4, "c", "a", "b", "id", "id", 1 / 3, 2.0000000001, False),
    ]
    part = DecodePart(*(list(c) for c in zip(*rows, strict=True)))
    indexed = _indexed_part(part, tables)
    assert indexed is not None

    def read(*args: Any) -> list[Any]:  # as a reader of the log gets it
        data = message_bytes(records.RX_DECODES, records.decodes_of_columns("x", *args))
        return list(decode_rows(_block(data)))

    got = read(indexed, tables)
    assert got == read(part) and len(got) == 2
    assert [r["margin"] for r in got] == [0.1 + 0.2, 1 / 3]
    unknown = DecodePart(*([v] for v in (5, "z", "a", "a", "id", "id", 0.5, 3.0, True)))
    assert _indexed_part(unknown, tables) is None


def test_a_block_makes_one_record_however_its_decodes_were_taken():
    """The same decodes taken as one batch (indexes), one at a time (names) or both make the
    same record: indexes into the unit's tables, or, with a name in none of them (or no
    tables), into tables of the names the block uses, sorted."""
    from rgtbus.telemetry.unit_log import DecodePart, canonical

    own = (("b", "a", "c"), ("id", "relation", "influence"), ("id", "conflict", "alliance"))
    rows = [
        (3, "a", "b", "b", "relation", "conflict", 0.25, 1.0, True),
        (4, "c", "a", "b", "id", "id", 0.5, 2.0, False),
    ]
    named = DecodePart(*(list(c) for c in zip(*rows, strict=True)))
    idx = [{n: i for i, n in enumerate(t)} for t in own]
    batch = DecodePart(
        turn=np.array([3, 4]), sender=np.array([idx[0]["a"], idx[0]["c"]]),
        addressee=np.array([idx[0]["b"], idx[0]["a"]]), channel=np.array([0, 0]),
        kind=np.array([1, 0]), code=np.array([1, 0]), margin=np.array([0.25, 0.5]),
        times=np.array([1.0, 2.0]), accepted=np.array([True, False]),
    )  # fmt: skip

    def record(part: DecodePart, tables: Any, mine: Any) -> bytes:  # as the log holds it
        made = records.decodes_of_columns("x", *canonical(part, tables, mine))
        return message_bytes(records.RX_DECODES, made)

    one = record(named, None, own)
    assert record(batch, own, own) == one
    assert _block(one)["names"] == ["b", "a", "c"]  # the unit's tables, as they are
    # a batch with other tables (the same names in another order): the same record
    other = (("c", "b", "a"), own[1], own[2])
    moved = batch._replace(
        sender=np.array([2, 0]), addressee=np.array([1, 2]), channel=np.array([1, 1])
    )
    assert record(moved, other, own) == one
    # no tables of the unit's, or a name outside them: the block's own names, sorted
    alone = _block(record(named, None, None))
    assert (alone["names"], alone["kinds"], alone["codes"]) == (
        ["a", "b", "c"], ["id", "relation"], ["conflict", "id"],
    )  # fmt: skip
    assert record(batch, own, None) == record(named, None, None)
    odd = named._replace(code=["conflict", "?"])
    assert _block(record(odd, None, own))["codes"] == ["?", "conflict"]
    for part, tables in ((named, None), (batch, own)):  # every decode reads back as it was
        rows_back = list(decode_rows(_block(record(part, tables, own))))
        assert [(r["sender"], r["code"], r["margin"]) for r in rows_back] == [
            ("a", "conflict", 0.25), ("c", "id", 0.5),
        ]  # fmt: skip


def test_spike_records_are_columns_one_entry_a_spike():
    """A unit's spikes of a block are one record of columns (each spike's sample, and its
    channel as an index into the block's names), at the block's end as its log time: no
    record a sample, no list a sample."""
    _, _, (messages, _) = run("example2")
    blocks = [(t, m) for topic, t, m in messages if topic == "/rx/spike"]
    assert blocks and any(len(set(m["samples"].tolist())) > 1 for _, m in blocks)
    for t, m in blocks:
        samples, channel = m["samples"].tolist(), m["channel"].tolist()
        assert samples == sorted(samples) and m["sample"] == samples[0]
        assert len(channel) == len(samples)
        assert sorted(set(channel)) == list(range(len(m["names"])))
        block_end = (m["sample"] // 200 + 1) * 1_000_000_000  # τ = 5 ms: 200 samples a second
        assert samples[-1] * 5_000_000 < t <= block_end  # its end, or where a unit stopped
        assert samples[-1] < (m["sample"] // 200 + 1) * 200  # one block


def _judged_alike(cols, rows, truth):
    """The errors of a unit's decodes held as columns, checked against the same decodes
    judged as rows, and against the columns pickled (a unit process's report: its runs go
    as rows, their queue stays behind)."""
    from rgtbus.misreads import wrong_decodes

    got = wrong_decodes("u", cols, truth)
    assert got == wrong_decodes("u", [list(r) for r in rows], truth)
    again = pickle.loads(pickle.dumps(cols))
    assert list(again) == list(cols) and len(again) == len(cols)
    assert wrong_decodes("u", again, truth) == got
    return got


def test_wrong_decodes_judge_columns_as_rows():
    """The summary judges a unit's decodes held as columns (a live run) in one vectorised
    step, and rows (read from a log) one by one: the same errors, in decode order."""
    from rgtbus.units.listening import DecodeColumns

    from rgtbus.misreads import SentTruth, wrong_decodes

    truth = SentTruth({
        (0, "id"): ("b", "id"), (0, "payload"): ("b", "alliance"),
        (1, "id"): ("c", "id"), (1, "payload"): ("c", "{go}"),
        (7, "payload"): ("a", "conflict"),
    })  # fmt: skip
    rows = [
        (0, "id", "b", "id"),  # right
        (0, "relation", "b", "conflict"),  # wrong code
        (1, "id", "c", "alliance"),  # an ID misread
        (1, "influence", "a", "{go}"),  # right code on the wrong channel
        (1, "influence", "c", "{go}"),  # right
        (5, "relation", "b", "alliance"),  # no known send: not judged
        (7, "relation", "a", "conflict"),  # right
        (0, "relation", "b", "conflict"),  # wrong again, later
        (9, "relation", "b", "conflict"),  # a turn past every known send: not judged
    ]
    cols = DecodeColumns()
    for row in rows:
        cols.append(*row)
    got = _judged_alike(cols, rows, truth)
    assert [(e["turn"], e["decoded"], e["sent"]) for e in got] == [
        (0, "conflict", "alliance"),
        (1, "alliance", "id"),
        (1, "{go}", "{go}"),
        (0, "conflict", "alliance"),
    ]
    assert (
        wrong_decodes("u", DecodeColumns(), truth) == [] == wrong_decodes("u", cols, SentTruth({}))
    )


def test_a_units_batches_are_judged_as_the_same_decodes_held_as_rows():
    """A batch of a shared queue is held as one byte a payload (``extend_run``) and judged
    against the queue's truth (``DecodeColumns.wrong``): the same errors, in decode order, as
    the same decodes appended one by one and judged as rows; rows between batches keep
    their place."""
    import dataclasses

    import numpy as np
    from rgtbus.units.listening import KINDS, DecodeColumns, QueueReads

    from rgtbus.misreads import SentTruth, wrong_decodes

    units, names = ("a", "b", "c"), ("id", "alliance", "conflict", "{go}")
    # positions: (turn, kind, sender, expected addressee)
    queue = [
        (0, "id", "a", "b"), (0, "relation", "a", "b"), (1, "id", "b", "c"),
        (1, "relation", "b", "c"), (2, "id", "c", "a"), (2, "influence", "c", "a"),
        (3, "id", "a", "c"), (3, "influence", "a", "c"), (9, "id", "b", "a"),
        (9, "relation", "b", "a"),
    ]  # fmt: skip
    truth = SentTruth({
        (0, "id"): ("b", "id"), (0, "payload"): ("b", "alliance"),
        (1, "id"): ("c", "id"), (1, "payload"): ("c", "conflict"),
        (2, "id"): ("a", "id"), (2, "payload"): ("a", "{go}"),
        (3, "id"): ("b", "id"), (3, "payload"): ("b", "{go}"),  # sent to b, read on c's
    })  # fmt: skip
    kind = np.array([KINDS.index(k) for _, k, _, _ in queue])
    expected = np.array([units.index(e) for *_, e in queue])
    n = np.zeros(len(queue) + 1, dtype=np.int64)
    reads = QueueReads(
        bounds=n[1:], seq=np.arange(len(queue)), kind=kind,
        turn=np.array([t for t, *_ in queue]),
        sender=np.array([units.index(s) for *_, s, _ in queue]),
        expected=expected, slot=n[1:], rnd=n[1:], t_ready=n[1:] * 1.0, is_id=kind == 0,
        is_rel=kind == 1, is_inf=kind == 2, n_rel=n, n_inf=n,
        n_pay=np.concatenate(([0], np.cumsum(kind != 0))), unique=True,
        what=(kind * len(units) + expected) * len(names), channel=expected, names=names,
        alliance=np.array([1, 1, 0, 0]), value=np.array([-1, -1, -1, 1]), id_word=0,
        read=lambda q: (n, n, n), read_block=lambda a, b: (n, n, n), units=units,
    )  # fmt: skip
    assert dataclasses.is_dataclass(reads)
    read = ["id", "conflict", "id", "conflict", "id", "alliance", "id", "{go}", "id", "conflict"]
    word = np.array([names.index(w) for w in read])
    cols, rows = DecodeColumns(), []
    for lo, hi, loose in ((0, 4, (7, "relation", "a", "alliance")), (4, 10, None)):
        cols.extend_run(reads, lo, hi, word[lo:hi])
        for q in range(lo, hi):
            rows.append((queue[q][0], queue[q][1], queue[q][3], read[q]))
        if loose:
            cols.append(*loose)
            rows.append(loose)
    assert len(cols) == len(rows) and list(cols) == [r for r in rows if r[1::2] != ("id", "id")]
    got = _judged_alike(cols, rows, truth)
    assert [(e["turn"], e["decoded"], e["sent"]) for e in got] == [
        (0, "conflict", "alliance"), (2, "alliance", "{go}"), (3, "{go}", "{go}")
    ]  # fmt: skip
    again = pickle.loads(pickle.dumps(cols))  # runs pickled as rows
    assert list(again) == list(cols) and len(again) == len(cols)
    assert wrong_decodes("u", again, truth) == got


def test_units_that_agree_share_one_copy_of_the_tables_in_their_reports():
    """A run's reports keep one copy of tables the units agree on (n³ entries in all), and a
    unit's own table where it differs."""
    from rgtbus.units.group import shared_tables

    first = {"installed": {"a-b": "alliance"}, "sent_relations": {"a>b": "alliance"},
             "influences": {"a>b": ["go"]}}  # fmt: skip
    same = {k: dict(v) for k, v in first.items()}
    other = {**same, "influences": {"a>b": []}}
    assert all(shared_tables(same, first)[k] is first[k] for k in first)
    got = shared_tables(other, first)
    assert got["installed"] is first["installed"] and got["influences"] == {"a>b": []}
    assert shared_tables(dict(first), None) == first


def test_a_unit_batches_its_decodes_only_when_no_live_view_waits_for_its_records():
    """A live sink may be attached to the recorder after the unit is made (a unit process
    publishes its telemetry for ``rgtbus watch`` once its bus is open): the unit asks when
    the run begins whether it may batch."""
    from rgtbus.telemetry import NullRecorder

    # turns timed by confirmed attention log each decode as the threshold's do: no batches
    assert not AutonomousUnit("a", load_scenario("gate"), NullRecorder()).batching()
    sc = load_scenario(ROOT / "scenarios" / "gate_noisy.toml")  # timed by the schedule
    assert AutonomousUnit("a", sc, NullRecorder()).batching()
    rec = MemoryRecorder()
    unit = AutonomousUnit("a", sc, rec)
    assert unit.batching()
    assert not AutonomousUnit("a", sc, MemoryRecorder(), traces=True).batching()
    sink = _Sink(watched=False)  # a unit process's telemetry that nobody subscribes to
    rec.live = sink
    assert unit.batching()
    sink.is_watched = True
    assert not unit.batching()


def test_a_paced_run_batches_a_wall_second_of_its_log_at_most(monkeypatch):
    """A logged unit's records of a batch leave at its next wake: paced, a batch holds at
    most ``PACED_BATCH_WALL_SECONDS`` of wall time (a log cut by a kill trails the paced clock
    by little), unpaced its own (5 s on a noisy medium); the log holds the same records either
    way."""
    from rgtbus.units import unit as unit_module

    monkeypatch.setattr(unit_module, "PACED_BATCH_WALL_SECONDS", 0.01)  # a quick paced run
    sc = load_scenario(ROOT / "scenarios" / "gate_noisy.toml")  # timed by the schedule
    logs, batches = [], []
    for realtime in (None, 400.0):
        rec = MemoryRecorder()
        out = run_group(sc, "memory", rec, realtime=realtime)
        assert all(m.batching() for m in out.units)
        batches.append({m._batch_seconds for m in out.units})
        logs.append(_log_of(rec))
    assert not sc.channel.alike and unit_module.DIFFER_LOGGED_BATCH_SECONDS > 400.0 * 0.01
    assert batches == [
        {unit_module.DIFFER_LOGGED_BATCH_SECONDS},
        {400.0 * 0.01},
    ]
    assert logs[0] == logs[1]


class _Sink:
    """A live sink whose ``watched`` says what the test sets (once it was given ``flip``
    logged decodes or more: watched), counting what it is offered."""

    def __init__(self, *, watched: bool, flip: int | None = None) -> None:
        self.is_watched, self.flip, self.asked, self.decodes = watched, flip, 0, 0
        self.got: list[tuple[str, int, Any]] = []

    def put(self, topic: str, schema: str, data: bytes, t_ns: int) -> None:
        block = schema_of(topic)  # a hot topic's block, decoded as a reader of the log would
        m = json.loads(data) if block is None else decode_record(block, data, topic)
        self.got.append((topic, t_ns, m))
        if topic == "/rx/decodes":
            self.decodes += len(m["turn"])

    def watched(self) -> bool:
        self.asked += 1
        if self.flip is not None and self.decodes >= self.flip:
            self.is_watched = True
        return self.is_watched


def _log_of(rec: MemoryRecorder) -> list[tuple[str, int, bytes]]:
    return sorted(_bytes(rec.messages))


def _offered(sink: _Sink) -> list[tuple[int, str]]:
    """The decodes a live sink was offered alone (``/rx/decode``), as (time, JSON)."""
    return [(t, json.dumps(m, sort_keys=True)) for tp, t, m in sink.got if tp == "/rx/decode"]


def _rows(messages) -> list[str]:
    """The pulses of ``/tx/pulse`` blocks, one a pulse, as JSON (sorted)."""
    return sorted(
        json.dumps(p, sort_keys=True)
        for tp, _, m in messages
        if tp == "/tx/pulse"
        for p in pulse_rows(m)
    )


def test_a_live_view_gets_each_decode_on_time_and_the_same_log():
    """Watched by a live view, the units of a concurrent group (which batch their decodes
    when nobody watches) take no batch, and offer the view each decode as they make it
    (``/rx/decode``, never logged): each before any record of a later time (pulses and the
    medium are written ahead of the clock by design), and all of them the log's decodes,
    one a row. The log is the one written with no view."""
    from rgtbus.telemetry.record_rows import decodes_per_row

    sc = load_scenario(ROOT / "scenarios" / "random_group.toml")
    alone = MemoryRecorder()
    run_group(sc, "memory", alone)
    sink = _Sink(watched=True)
    rec = MemoryRecorder(live=sink)
    run_group(sc, "memory", rec)
    assert _log_of(rec) == _log_of(alone)
    rows = [
        (t, json.dumps(m, sort_keys=True, default=plain))
        for tp, t, m in decodes_per_row(rec.messages)
        if tp == "/rx/decode"
    ]
    assert sorted(_offered(sink)) == sorted(rows) and len(rows) > 20
    latest = lag = 0
    for tp, t, _ in sink.got:
        if tp == "/rx/decode":
            lag = max(lag, latest - t)
        elif tp not in ("/tx/pulse", "/medium"):
            latest = max(latest, t)
    assert lag <= 100_000_000  # ns: a sample or so, where a batch would be seconds late
    # the logged records reach the view too, as the file gets them; besides them, only each
    # pulse offered alone as it is made (a block of one), every pulse of the log's blocks
    got = Counter(_bytes((tp, t, m) for tp, t, m in sink.got if tp != "/rx/decode"))
    logged = Counter(_log_of(rec))
    assert not logged - got  # every logged record
    alone = list((got - logged).elements())
    assert {tp for tp, _, _ in alone} == {"/tx/pulse"}
    blocks = [(tp, t, decode_record(schema_of(tp), m, tp)) for tp, t, m in alone]
    assert all(len(pulse_rows(m)) == 1 for _, _, m in blocks)
    assert _rows(blocks) == _rows(rec.messages)


def test_a_watcher_that_comes_mid_run_gets_each_decode_on_time_from_then_on(monkeypatch):
    """A unit process's telemetry nobody watches lets its units batch and offers nothing
    alone; once a watcher subscribes (``watched`` turns True), each unit offers every decode
    it makes from its next wake on (a suffix of its decodes). The log is the same as ever."""
    from rgtbus.units import unit as unit_module

    from rgtbus.telemetry.record_rows import decodes_per_row

    # batches of 4 s: a short run's units wake several times (at a minute, once)
    monkeypatch.setattr(unit_module, "BATCH_SECONDS", 4.0)
    monkeypatch.setattr(unit_module, "LOGGED_BATCH_SECONDS", 4.0)

    sc = load_scenario(ROOT / "scenarios" / "random_group.toml")
    logs, offered = [], []
    unwatched = _Sink(watched=False)
    for live in (None, unwatched, "flip"):
        # a watcher comes once a quarter of the units' decodes are logged (not after a count
        # of asks: a unit asks for each pulse it sends too, and a group plans its sends early)
        if live == "flip":
            live = _Sink(watched=False, flip=unwatched.decodes // 4)
        rec = MemoryRecorder(live=live)
        run_group(sc, "memory", rec)
        logs.append(_log_of(rec))
        offered.append([] if live is None else _offered(live))
    assert logs[0] == logs[1] == logs[2]
    assert offered[1] == []
    rows = [(t, m) for tp, t, m in decodes_per_row(rec.messages) if tp == "/rx/decode"]
    suffixes = []
    for unit in sc.units:
        mine = [
            (t, json.dumps(m, sort_keys=True, default=plain)) for t, m in rows if m["unit"] == unit
        ]
        got = [o for o in offered[2] if json.loads(o[1])["unit"] == unit]
        assert got == mine[len(mine) - len(got) :]
        suffixes.append(len(got) / len(mine))
    assert 0 < min(suffixes) < 1, suffixes  # some decodes before the watcher came: not offered


class _Watching:
    """A live sink that is always watched and drops what it is offered."""

    def put(self, topic, schema, data, t_ns):
        pass

    def watched(self):
        return True


class _Offers(MemoryRecorder):
    """A memory recorder that keeps, in order, what it offers a live view alone."""

    def __init__(self, **kw) -> None:
        super().__init__(**kw)
        self.offered: list[tuple[str, int, Any]] = []

    def offer(self, topic, message, t_ns) -> None:
        self.offered.append((topic, t_ns, message))
        super().offer(topic, message, t_ns)


def _pulse_key(p) -> tuple:
    m = p["message"]
    return (p["sample"], m["kind"], m["sender"], m["addressee"], p["magnitude"])


@pytest.mark.parametrize("watched", [True, False])
@pytest.mark.parametrize("name", ["steering", "coalition10", "gate"])
def test_a_unit_s_transmitter_logs_every_pulse_of_every_send_on_time(name, watched):
    """With a live view, one transmitter process a unit offers the view each send as it goes
    on air: every pulse of every send the unit made (goal-driven ones chosen late, ahead of
    sends planned earlier, wake it), alone, at its sample's time, with its magnitude, in time
    order; a log line a send. Watched or not, the log holds the same pulses, the senders'
    pulses of one block (5 s) a ``/tx/pulse`` record at its time."""
    sc = load_scenario(ROOT / "scenarios" / f"{name}.toml")
    rec = _Offers(live=_Watching() if watched else None)
    out = run_group(sc, "memory", rec)
    blocks = [(t, m) for tp, t, m in rec.messages if tp == "/tx/pulse"]
    assert all(t == round(m["t"] * 1e9) for t, m in blocks)
    held = [len({p["sample"] // round(BLOCK_SECONDS / m["tau"]) for p in pulse_rows(m)})
            for _, m in blocks]  # fmt: skip
    assert held == [1] * len(blocks)  # one block of the senders' clock each
    windows = [int(m["sample"][0]) // round(BLOCK_SECONDS / m["tau"]) for _, m in blocks]
    assert len(set(windows)) == len(windows)  # every sender's pulses of a block: one record
    for unit in out.units:
        want = sorted(
            (k, send.kind, send.sender, send.addressee, float(m))
            for send in unit.sent
            for k, m in zip(send.samples, unit.transmitter.word(send), strict=True)
        )
        mine = [p for _, m in blocks for p in pulse_rows(m) if p["unit"] == unit.name]
        assert sorted(_pulse_key(p) for p in mine) == want
        alone = [
            (t, m)
            for tp, t, m in rec.offered
            if tp == "/tx/pulse" and pulse_rows(m)[0]["unit"] == unit.name
        ]
        if watched:
            assert [t for t, _ in alone] == sorted(t for t, _ in alone)  # on time, in order
            assert all(len(pulse_rows(m)) == 1 for _, m in alone)
            offered = sorted(_pulse_key(p) for _, m in alone for p in pulse_rows(m))
            assert offered == want and all(t == round(m["t"] * 1e9) for t, m in alone)
        else:
            assert alone == []  # nobody to offer them to
        lines = [m for tp, _, m in rec.messages if tp == "/log" and m["name"] == unit.name]
        assert sum(" -> " in m["message"] for m in lines) == len(unit.sent)


def test_the_truth_of_sends_is_held_as_arrays_and_read_as_a_mapping():
    """A run's sends, the ground truth of its decode errors, are held by turn as arrays; read
    as a mapping they are every (turn, kind) -> (addressee, code), the last send of a key
    counting, as a dict of them would be; a key that is no turn is kept as it is."""
    from rgtbus.misreads import SentTruth, sent_truth, wrong_decodes

    reports = [
        {"sends": [[0, "id", "b", "id"], [0, "payload", "b", "alliance"],
                   [3, "repeat", "c", "{go}"]]},
        {"sends": [[2, "id", "a", "id"], [2, "payload", "a", "{go}"],
                   [0, "payload", "b", "conflict"]]},  # turn 0's payload again: the last counts
        {"sends": [[-1, "payload", "a", "odd"]]},
    ]  # fmt: skip
    want = {}
    for r in reports:
        for turn, kind, addressee, code in r["sends"]:
            want[(turn, "id" if kind == "id" else "payload")] = (addressee, code)
    truth = sent_truth(reports)
    assert dict(truth.sent) == want and len(truth.sent) == len(want)
    assert (0, "payload") in truth.sent and (1, "id") not in truth.sent
    rows = [
        (0, "relation", "b", "alliance"),
        (2, "influence", "a", "{go}"),
        (3, "influence", "c", "x"),
    ]
    assert wrong_decodes("u", rows, truth) == wrong_decodes("u", rows, SentTruth(want))
    assert [e["turn"] for e in wrong_decodes("u", rows, truth)] == [0, 3]


def test_a_units_report_reads_its_sends_as_rows():
    """The summary's report of a unit reads its sends as rows as they are iterated (not a
    second copy of a group's 4n(n−1) sends): the rows of its ``/unit/report`` record, by index
    and slice, as JSON lists, and pickled as the list of them."""
    sc = load_scenario(ROOT / "scenarios" / "group6.toml")
    out = run_group(sc, "memory", NullRecorder())
    for unit, report in zip(out.units, out.reports, strict=True):
        rows = report["sends"]
        want = unit.report_record()["sends"]
        assert list(rows) == want and len(rows) == len(want) and rows == want
        assert rows[0] == want[0] and rows[1:3] == want[1:3] and rows.tolist() == want
        assert pickle.loads(pickle.dumps(rows)) == want
