"""rgtbus info / cat / scenario: the log tools."""

from __future__ import annotations

import json
import tomllib
from collections import Counter
from pathlib import Path

import pytest
from mcap.reader import make_reader

from rgtbus.cli import main
from rgtbus.telemetry.logtools import with_seed_text

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def gate_log(tmp_path_factory) -> Path:
    log = tmp_path_factory.mktemp("logs") / "gate.mcap"
    gate = str(ROOT / "scenarios" / "gate.toml")
    code = main(["run", gate, "--bus", "memory", "--log", str(log), "--quiet", "--seed", "11"])
    assert code == 0
    return log


def _messages(log: Path) -> list[tuple[str, int, dict]]:
    with open(log, "rb") as f:
        return [
            (c.topic, m.log_time, json.loads(m.data))
            for _, c, m in make_reader(f).iter_messages(log_time_order=True)
        ]


def test_info_reads_the_summary(gate_log, capsys):
    capsys.readouterr()
    assert main(["info", str(gate_log), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    msgs = _messages(gate_log)
    assert {t: v["count"] for t, v in info["topics"].items()} == Counter(t for t, _, _ in msgs)
    assert info["topics"]["/rx/decode"]["schema"] == "rgtbus.Decode"
    assert info["messages"] == len(msgs)
    assert info["duration"] == pytest.approx(max(t for _, t, _ in msgs) / 1e9)
    assert (info["scenario"], info["seed"], info["units"]) == ("gate", 11, ["a", "b", "c", "d"])
    assert info["outcome"] == "gate: open" and info["agree"] is True and info["finished"]
    assert info["compression"] == ["zstd"] and info["chunks"] >= 1
    assert info["truncated"] is False and info["version"]
    assert main(["info", str(gate_log)]) == 0
    text = capsys.readouterr().out
    assert "seed:        11" in text and "outcome:     gate: open" in text
    assert "/rx/decode" in text and "[" not in text.split("units:")[1].splitlines()[0]


def test_info_on_a_log_cut_short(gate_log, tmp_path, capsys):
    data = gate_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    capsys.readouterr()
    assert main(["info", str(cut), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["truncated"] is True and "truncated" in info["note"]
    assert 0 < info["messages"] < len(_messages(gate_log))
    assert info["finished"] is False and info["scenario"] == "gate"


@pytest.mark.parametrize(
    "content, says",
    [(b"not an mcap file at all", "not an MCAP file"), (None, "is a directory")],
)
def test_info_refuses_what_is_no_log(tmp_path, capsys, content, says):
    path = tmp_path / "x.mcap"
    if content is None:
        path.mkdir()
    else:
        path.write_bytes(content)
    assert main(["info", str(path)]) == 2
    err = capsys.readouterr().err
    assert says in err and err.count("\n") == 1


def test_cat_filters_by_topic_unit_and_time(gate_log, capsys):
    capsys.readouterr()
    args = ["cat", str(gate_log), "--topic", "/rx/decode", "--unit", "b", "--from", "10"]
    assert main([*args, "--to", "40"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    want = [
        (t, m)
        for topic, t, m in _messages(gate_log)
        if topic == "/rx/decode" and m["unit"] == "b" and 10e9 <= t <= 40e9
    ]
    assert [(x["log_time"], x["message"]) for x in lines] == want and want
    assert all(x["topic"] == "/rx/decode" and x["t"] == x["log_time"] / 1e9 for x in lines)
    # several topics, every unit: log-time order
    assert main(["cat", str(gate_log), "--topic", "/unit/decision", "--topic", "/run"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert {x["topic"] for x in lines} == {"/unit/decision", "/run"}
    assert [x["log_time"] for x in lines] == sorted(x["log_time"] for x in lines)
    # a unit's log lines and traces count as its own; the medium is nobody's
    assert main(["cat", str(gate_log), "--unit", "d"]) == 0
    topics = {json.loads(x)["topic"] for x in capsys.readouterr().out.splitlines()}
    assert "/medium" not in topics and "/run" not in topics and "/log" in topics


@pytest.mark.parametrize(
    "args, says",
    [
        (["--topic", "/nope"], "--topic '/nope': not in this log"),
        (["--unit", "zz"], "--unit 'zz': not a unit of this log (a, b, c, d)"),
        (["--from", "500", "--to", "600"], "--from 500 --to 600: outside the run (0 to 162.05 s)"),
        (["--from", "50", "--to", "40"], "--from 50 --to 40: empty time range"),
        (["--to", "-1"], "--to -1: outside the run"),
        (["--from", "nan"], "--from nan: not a time"),
    ],
)
def test_cat_refuses_bad_filters(gate_log, capsys, args, says):
    capsys.readouterr()
    assert main(["cat", str(gate_log), *args]) == 2
    err = capsys.readouterr().err
    assert says in err and err.count("\n") == 1


def test_the_stored_scenario_repeats_the_run(gate_log, tmp_path, capsys):
    capsys.readouterr()
    assert main(["scenario", str(gate_log)]) == 0
    text = capsys.readouterr().out
    assert tomllib.loads(text)["seed"] == 11  # the run's --seed, not the file's
    assert text.startswith("# Example 3 of the paper")  # the file as written, comments kept
    again = tmp_path / "again.toml"
    again.write_text(text)
    log2 = tmp_path / "again.mcap"
    assert main(["run", str(again), "--bus", "memory", "--log", str(log2), "--quiet"]) == 0
    strip = ("/log",)  # log lines name the scenario's path
    first = [m for m in _messages(gate_log) if m[0] not in strip]
    second = [m for m in _messages(log2) if m[0] not in strip]
    assert first == second


@pytest.mark.parametrize(
    "text",
    [
        'name = "x"\nseed = 3 # the paper\nunits = ["a"]\n',
        'name = "x"\nunits = ["a"]\n[channel]\nnoise = 0.0\n',
        'name = "x"\n',
        'name = "x"\n[channel]\nseed = 4\n',
    ],
)
def test_with_seed_text_sets_only_the_top_level_seed(text):
    out = with_seed_text(text, 17)
    data = tomllib.loads(out)
    assert data["seed"] == 17 and data["name"] == "x"
    assert data.get("channel", {}) == tomllib.loads(text).get("channel", {})
