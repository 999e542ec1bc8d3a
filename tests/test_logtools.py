"""rgtbus info / cat / scenario: the log tools."""

from __future__ import annotations

import json
import tomllib
from collections import Counter
from pathlib import Path

import pytest
from mcap.reader import make_reader
from same_run import plain, read_message

from rgtbus.cli import main
from rgtbus.telemetry.logtools import with_seed_text
from rgtbus.telemetry.record_rows import decode_rows, decode_units, each_unit_spikes

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def gate_log(tmp_path_factory) -> Path:
    """The gate's log, in small chunks (to be cut short)."""
    from conftest import small_chunk_logs

    log = tmp_path_factory.mktemp("logs") / "gate.mcap"
    gate = str(ROOT / "scenarios" / "gate.toml")
    with small_chunk_logs():
        code = main(["run", gate, "--bus", "memory", "--log", str(log), "--quiet", "--seed", "11"])
    assert code == 0
    return log


def _messages(log: Path) -> list[tuple[str, int, dict]]:
    with open(log, "rb") as f:
        return [
            (c.topic, m.log_time, read_message(c.topic, m.data))
            for _, c, m in make_reader(f).iter_messages(log_time_order=True)
        ]


def test_info_reads_the_summary(gate_log, capsys):
    capsys.readouterr()
    assert main(["info", str(gate_log), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    msgs = _messages(gate_log)
    assert {t: v["count"] for t, v in info["topics"].items()} == Counter(t for t, _, _ in msgs)
    assert info["topics"]["/rx/decodes"]["schema"] == "rgtbus.DecodeBlock"
    assert info["messages"] == len(msgs)
    assert info["duration"] == pytest.approx(max(t for _, t, _ in msgs) / 1e9)
    assert (info["scenario"], info["seed"], info["units"]) == ("gate", 11, ["a", "b", "c", "d"])
    assert info["outcome"] == "gate: open" and info["agree"] is True and info["finished"]
    assert info["compression"] == ["zstd"] and info["chunks"] >= 1
    assert info["truncated"] is False and info["version"]
    assert main(["info", str(gate_log)]) == 0
    text = capsys.readouterr().out
    assert "seed:        11" in text and "outcome:     gate: open" in text
    assert "/rx/decodes" in text and "[" not in text.split("units:")[1].splitlines()[0]


def test_info_on_a_log_cut_short(gate_log, tmp_path, capsys):
    data = gate_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    capsys.readouterr()
    assert main(["info", str(cut), "--json"]) == 3  # truncated: read to its cut (as replay)
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
    # a window that holds some of b's decode records and leaves one out on either side
    times = [
        t
        for topic, t, m in _messages(gate_log)
        if topic == "/rx/decodes" and "b" in decode_units(m)
    ]
    assert len(times) >= 3
    lo, hi = times[0] + 1_000_000, times[-1] - 1_000_000  # ns
    args = ["cat", str(gate_log), "--topic", "/rx/decodes", "--unit", "b", "--from", str(lo / 1e9)]
    assert main([*args, "--to", str(hi / 1e9), "--blocks"]) == 0  # the records as stored
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    want = [  # a record b shares with others: shown as b's own
        (t, {"unit": "b", **{k: v for k, v in m.items() if k not in ("unit", "units")}})
        for topic, t, m in _messages(gate_log)
        if topic == "/rx/decodes" and "b" in decode_units(m) and lo <= t <= hi
    ]
    assert [(x["log_time"], x["message"]) for x in lines] == want
    assert 0 < len(want) == len(times) - 2
    assert all(x["topic"] == "/rx/decodes" and x["t"] == x["log_time"] / 1e9 for x in lines)
    # by default one decode a line, at its own time, which --from/--to filter on
    assert main([*args, "--to", str(hi / 1e9)]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    every = [dict(r) for topic, _, m in _messages(gate_log) if topic == "/rx/decodes"
             for r in decode_rows(m)]  # fmt: skip
    mine = [r for r in every if r["unit"] == "b" and lo <= round(r["t"] * 1e9) <= hi]
    assert [x["message"] for x in lines] == sorted(mine, key=lambda r: r["t"]) != []
    assert all(x["log_time"] == round(x["message"]["t"] * 1e9) for x in lines)
    assert main(["cat", str(gate_log), "--topic", "/rx/decodes", "--from", "10", "--to", "40"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert lines and all(10 <= x["t"] <= 40 for x in lines)  # the README's example: decodes
    assert len(lines) == sum(1 for r in every if 10 <= r["t"] <= 40)
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


# -- a cross-process run merged by hand ------------------------------------------------------------

EXAMPLE2 = ROOT / "scenarios" / "example2.toml"


def _unit_log(path: Path, unit: str, status: str | None, detail: str = "") -> Path:
    """A unit process's log as ``rgtbus unit`` writes its metadata: the scenario, a ``run``
    record naming the process, and (unless killed) the ``end.<unit>`` record."""
    from rgtbus.telemetry import McapRecorder

    with open(path, "wb") as f, McapRecorder(f) as rec:
        rec.metadata("scenario", {"name": "example2", "path": "x", "text": EXAMPLE2.read_text()})
        rec.metadata("run", {"seed": "2", "version": "0.1.0", "bus": "zenoh", "process": unit})
        rec.log("info", f"{unit} here", 1_000_000_000, name=unit)
        if status is not None:
            rec.metadata(f"end.{unit}", {"status": status, "detail": detail, "sim_seconds": "1"})
    return path


def _merged(tmp_path: Path, ends: dict[str, tuple[str | None, str]]) -> Path:
    logs = [str(_unit_log(tmp_path / f"{u}.mcap", u, *end)) for u, end in ends.items()]
    out = tmp_path / "merged.mcap"
    assert main(["merge", *logs, "-o", str(out), "--quiet"]) == 0
    return out


@pytest.mark.parametrize(
    "ends, finished, says",
    [
        (
            {"a": ("done", ""), "b": ("done", ""), "c": ("done", "")},
            True,
            "every unit finished (a merge of unit logs has no /run summary",
        ),
        (
            {"a": ("done", ""), "b": ("done", "b: no ID spike"), "c": ("done", "")},
            True,
            "failed: unit b: b: no ID spike",
        ),
        ({"a": ("done", ""), "b": ("done", "")}, False, "no log of unit c in this one"),
        (
            {"a": ("done", ""), "b": (None, ""), "c": ("ended early", "a went silent")},
            False,
            "unit b's process did not end its log (killed?); unit c ended early: a went silent",
        ),
    ],
)
def test_info_judges_a_merge_of_unit_logs_by_their_ends(tmp_path, capsys, ends, finished, says):
    merged = _merged(tmp_path, ends)
    capsys.readouterr()
    assert main(["info", str(merged), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["finished"] is finished and set(info["unit_processes"]) == set(ends)
    assert main(["info", str(merged)]) == 0
    out = capsys.readouterr().out
    assert says in out and "did not finish its log" not in out


def test_router_units_and_merge_by_hand_is_a_finished_run(tmp_path, capsys, procs):
    """The README's run on several machines, on loopback: a router, a client unit process per
    unit, their logs merged by hand. Every unit finished, so neither ``info`` nor ``replay``
    says the run did not finish its log."""
    from rgtbus.units.launch import free_ports

    from rgtbus.scenario import load_scenario

    units = load_scenario(EXAMPLE2).units
    router_at = f"tcp/127.0.0.1:{free_ports(1)[0]}"
    router = procs("router", "--listen", router_at)
    assert router.stdout is not None and "router listening" in router.stdout.readline()
    started = {
        u: procs(
            "unit", u, str(EXAMPLE2), "--mode", "client", "--connect", router_at,
            "--log", str(tmp_path / f"{u}.mcap"), "--run-id", "by-hand", "--quiet",
        )
        for u in units
    }  # fmt: skip
    for u, p in started.items():
        out, err = p.communicate(timeout=120)
        assert p.returncode == 0 and out == "", (u, err)
    merged = tmp_path / "run.mcap"
    logs = [str(tmp_path / f"{u}.mcap") for u in units]
    assert main(["merge", *logs, "-o", str(merged)]) == 0
    capsys.readouterr()
    assert main(["info", str(merged), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["finished"] is True and info["error"] is None
    assert all(e and e["status"] == "done" for e in info["unit_processes"].values())
    assert main(["info", str(merged)]) == 0
    assert "did not finish" not in capsys.readouterr().out
    assert main(["replay", str(merged)]) == 0
    out = capsys.readouterr().out
    assert "no /run record" not in out and "did not finish" not in out and "NOTE" not in out
    # one unit's log alone is not the whole run, and says so
    assert main(["info", logs[0]]) == 0
    assert f"no log of units {', '.join(units[1:])} in this one" in capsys.readouterr().out


def test_cat_of_one_unit_shows_the_spike_records_it_shares_as_its_own(gate_log, capsys):
    """The units of a process that heard the same spikes share one /rx/spike record: cat
    --unit shows each as that unit's own (``unit``, no ``units``), every spike of it once."""

    capsys.readouterr()
    shared = [(t, m) for topic, t, m in _messages(gate_log) if topic == "/rx/spike"]
    assert any("units" in m for _, m in shared)
    want = [(t, one) for t, m in shared for one in each_unit_spikes(m) if one["unit"] == "c"]
    assert main(["cat", str(gate_log), "--topic", "/rx/spike", "--unit", "c"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert (
        sorted((x["log_time"], json.dumps(x["message"], sort_keys=True)) for x in lines)
        == (sorted((t, json.dumps(m, sort_keys=True, default=plain)) for t, m in want))
        and want
    )


def test_cat_and_info_read_the_log_of_a_unit_whose_join_failed(tmp_path, capsys):
    """A unit whose join failed writes its lines at 0 s and nothing later: ``cat`` prints
    them (its run is one instant long, which no range excludes) and ``info`` reads it."""
    from rgtbus.units.group import write_metadata

    from rgtbus.scenario import load_scenario
    from rgtbus.telemetry import McapRecorder

    sc = load_scenario(Path(__file__).parent.parent / "scenarios" / "gate.toml")
    path = tmp_path / "a.mcap"
    with path.open("wb") as f:
        rec = McapRecorder(f)
        write_metadata(rec, sc, "zenoh", "claims", process="a")
        rec.log("error", "a: join failed: two processes claim unit 'b'", 0, name="a")
        rec.close()
    capsys.readouterr()
    assert main(["cat", str(path)]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [(x["topic"], x["t"]) for x in lines] == [("/log", 0.0)]
    assert "join failed" in lines[0]["message"]["message"]
    assert main(["cat", str(path), "--to", "0"]) == 0 and capsys.readouterr().out
    assert main(["cat", str(path), "--from", "1"]) == 2
    assert "outside the run (0 to 0 s)" in capsys.readouterr().err
    assert main(["info", str(path)]) == 0
