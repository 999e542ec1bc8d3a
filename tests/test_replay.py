"""Replay of MCAP logs: summary round trip, verification (clean, tampered, truncated), merge,
plots, CSV, Foxglove layout, refusals."""

from __future__ import annotations

import csv
import io
import itertools
import json
import re
import struct
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from format1 import as_format1
from rgtbus.units.group import run_group
from rgtbus.units.rerun import rerun, traces_for, verify_log
from same_run import plain

import rgtbus
from rgtbus.cli import main
from rgtbus.errors import RgtbusError
from rgtbus.scenario import load_scenario, parse_scenario
from rgtbus.telemetry import McapRecorder, blocks, read_log, records, schema_for
from rgtbus.telemetry import topics as topics_mod
from rgtbus.telemetry import validate as validate_mod
from rgtbus.telemetry.codec import encode
from rgtbus.telemetry.convert import convert_log
from rgtbus.telemetry.plots import DPI, activity_figure, figure_size
from rgtbus.telemetry.read import load_replay
from rgtbus.telemetry.record_rows import decode_rows, each_unit_spikes, spike_samples, spike_units
from rgtbus.telemetry.scan import scan_log
from rgtbus.telemetry.verify import EXIT_TRUNCATED
from rgtbus.telemetry.version import FORMAT_RECORD

ROOT = Path(__file__).resolve().parent.parent
RUN_KEYS = (
    "scenario",
    "seed",
    "polynomial",
    "relations",
    "agree",
    "influences",
    "units",
    "outcome",
    "sim_seconds",
    "decode_errors",
    "error",
)


@cache
def _run(name: str, traces: bool = False, text: str | None = None) -> tuple[bytes, str]:
    """(MCAP bytes, ``rgtbus run --json``-style summary as JSON) of a scenario run."""
    sc = (
        parse_scenario(text, f"{name}.toml")
        if text is not None
        else load_scenario(ROOT / "scenarios" / f"{name}.toml")
    )
    buf = io.BytesIO()
    rec = McapRecorder(buf, chunk_size=4 * 1024)  # many chunks, to cut short
    out = run_group(sc, "memory", rec, traces=traces)
    rec.close()
    return buf.getvalue(), json.dumps(out.summary)


def log_bytes(name: str = "example2", traces: bool = False) -> bytes:
    return _run(name, traces)[0]


def write(tmp_path: Path, data: bytes, name: str = "run.mcap") -> Path:
    p = tmp_path / name
    p.write_bytes(data)
    return p


def rewrite(data: bytes, edit) -> bytes:
    """The log with its messages passed through ``edit(list) -> list`` (a hand-altered log)."""
    messages, metadata = read_log(io.BytesIO(data))
    buf = io.BytesIO()
    rec = McapRecorder(buf)  # (it writes the format record itself, first)
    for name, values in metadata.items():
        if name != FORMAT_RECORD:
            rec.metadata(name, values)
    as_json = [(tp, t, json.loads(json.dumps(m, default=plain))) for tp, t, m in messages]
    for topic, t, m in edit(as_json):
        rec.write(topic, m, t)
    rec.close()
    return buf.getvalue()


def copied(data: bytes, edit, retime=lambda topic, t: t) -> bytes:
    """The log copied record for record with mcap's own writer, each message's bytes passed
    through ``edit(topic, log time, data) -> data`` and its log time through
    ``retime(topic, log time)``: a hostile writer's bytes, which rgtbus's recorder would never
    write."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    assert summary is not None
    buf = io.BytesIO()
    writer = Writer(buf, compression=CompressionType.ZSTD)
    writer.start(profile="", library="rgtbus (by hand)")
    for record in reader.iter_metadata():  # (first, as rgtbus writes them)
        writer.add_metadata(record.name, dict(record.metadata))
    channels = {}
    for cid, c in summary.channels.items():
        s = summary.schemas[c.schema_id]
        sid = writer.register_schema(s.name, s.encoding, s.data)
        channels[cid] = writer.register_channel(c.topic, c.message_encoding, sid, c.metadata)
    for _, channel, message in reader.iter_messages(log_time_order=False):
        body = edit(channel.topic, message.log_time, message.data)
        t = retime(channel.topic, message.log_time)
        writer.add_message(channels[channel.id], t, body, t)
    writer.finish()
    return buf.getvalue()


def first_block(topic: str, change, where=lambda record: True):
    """A ``copied`` edit: the first block on ``topic`` whose record (as a reader gets it) is
    ``where`` replaced by ``change(record, data) -> data``; asserted to find one."""
    done = []

    def edit(tp: str, t: int, data: bytes) -> bytes:
        if tp != topic or done:
            return data
        record = blocks.decode_record(blocks.schema_of(topic), data, "the log")
        if not where(record):
            return data
        done.append(tp)
        return change(record, data)

    edit.done = done  # type: ignore[attr-defined]
    return edit


def converted(tmp_path: Path, old: Path, name: str = "converted.mcap") -> Path:
    """``old`` (a format-1 log) as ``rgtbus convert`` writes it: format 2."""
    out = tmp_path / name
    with open(out, "wb") as f:
        done = convert_log(scan_log(old), f)
    assert done.ended == "" and done.written > 0
    return out


def refused_as_format1(capsys, path: Path) -> None:
    """Every reader refuses a format-1 log in one line naming ``rgtbus convert`` (exit 2)."""
    for extra in ([], ["--verify"], ["--json"]):
        code, out, err = cli(capsys, "replay", path, *extra)
        assert code == 2 and out == "" and err.count("\n") == 1, err
        assert "an rgtbus log of format 1" in err and f"rgtbus convert {path}" in err, err
    for command in ("info", "cat"):
        code, _, err = cli(capsys, command, path)
        assert code == 2 and err.count("\n") == 1 and "rgtbus convert" in err, err
    import rgtbus

    with pytest.raises(RgtbusError, match=r"format 1 .*rgtbus convert"):
        rgtbus.open_log(path)


def cli(capsys, *args) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


# -- round trip ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["overview", "example2", "gate"])
def test_summary_round_trip_and_clean_verify(name):
    data, summary_json = _run(name)
    summary = json.loads(summary_json)
    rp = load_replay(io.BytesIO(data))
    got = rp.summary()
    assert {k: got[k] for k in RUN_KEYS} == {k: summary[k] for k in RUN_KEYS}
    assert got["unit_relations"] == summary["unit_relations"]
    report = verify_log(rp)
    assert report.ok and report.exit_code == 0 and report.mismatches == []
    assert report.checked["/rx/decode"] > 0 and report.checked["/unit/decision"] > 0


@pytest.mark.parametrize("name", ["gate_repair", "crowd10"])
def test_the_summary_reads_each_units_decodes_as_columns(name):
    """What the summary judges decode errors on, read from the blocks as columns
    (``HeldDecodes``: no Python object per decode), holds each unit's decodes in the order
    and with the values of the rows (by time, stable as logged), and gives the run's
    decode errors."""
    from rgtbus.misreads import HeldDecodes

    data, summary_json = _run(name)
    rp = load_replay(io.BytesIO(data))
    held = rp._unit_decodes()
    assert set(held) == set(rp.units) and all(type(h) is HeldDecodes for h in held.values())
    rows: dict[str, list[tuple[int, list]]] = {}
    for t, d in rp._each_decode():
        row = [d["turn"], d["kind"], d["addressee"], d["code"]]
        rows.setdefault(d["unit"], []).append((t, row))
    for unit, got in held.items():
        want = [row for _, row in sorted(rows[unit], key=lambda r: r[0])]
        assert list(got) == want and len(got) == len(want)
    summary = json.loads(summary_json)
    assert rp.summary()["decode_errors"] == summary["decode_errors"]
    assert (summary["decode_errors"]["misread"] > 0) == (name == "gate_repair")


def test_a_log_from_a_path_keeps_each_topic_in_the_file_until_it_is_asked_for(tmp_path):
    """Opening a log reads every chunk (CRCs, counts) but keeps only its /run record; a topic
    is read from the file when first asked for, and the log reads as one read whole from a
    stream. A file replaced since it was opened is refused, in one line, when a topic not
    read yet is asked for."""
    path = tmp_path / "gate.mcap"
    rgtbus.run(ROOT / "scenarios" / "gate.toml", log=path)
    rp = load_replay(path)
    whole = load_replay(io.BytesIO(path.read_bytes()))
    assert records.RUN not in rp.by_topic.in_file and whole.by_topic.in_file == {}
    assert {records.RX_SPIKE, records.RX_DECODES, records.TX_PULSE} <= set(rp.by_topic.in_file)
    assert rp.topic_counts() == whole.topic_counts() and set(rp.by_topic) == set(whole.by_topic)
    summary = rp.summary()
    assert {k: v for k, v in summary.items() if k != "log"} == {
        k: v for k, v in whole.summary().items() if k != "log"
    }
    assert records.RX_SPIKE in rp.by_topic.in_file  # the summary needs no spike

    def by_topic(replay):
        out: dict[str, list] = {}
        for topic, t, m in replay.messages():  # every topic read now, as held
            out.setdefault(topic, []).append((t, m))
        return out

    assert by_topic(rp) == by_topic(whole)
    traced = log_bytes(traces=True)  # a log read whole holds its traces; from a path, not
    assert load_replay(io.BytesIO(traced)).trace_arrays("c") is not None
    (tmp_path / "traced.mcap").write_bytes(traced)
    from_path = load_replay(tmp_path / "traced.mcap")
    assert "/trace/c" not in from_path.by_topic and from_path.trace_arrays("c") is not None
    again = load_replay(path)
    rgtbus.run(ROOT / "scenarios" / "gate.toml", seed=5, log=path)  # another run's log there
    with pytest.raises(RgtbusError, match=r"gate.mcap: changed since it was opened"):
        again.by_topic[records.RX_SPIKE]


def test_rerun_summary_equals_the_runs_own():
    data, summary_json = _run("example2")
    rp = load_replay(io.BytesIO(data))
    out = rerun(rp.scenario, {rp.scenario.units[0]: rp.medium_pulses()})
    strip = ("wall_seconds", "bus", "steps", "sync")  # the log serves the whole medium at once
    assert {k: v for k, v in out.summary.items() if k not in strip} == {
        k: v for k, v in json.loads(summary_json).items() if k not in strip
    }


def test_replay_cli_text_and_json(tmp_path, capsys):
    path = write(tmp_path, log_bytes("gate"))
    code, out, _ = cli(capsys, "replay", path)
    assert code == 0
    assert "a → b: ID" in out and "d → c: influence 1" in out and "outcome: gate: open" in out
    assert "all units agree: yes" in out and "seed 3" in out
    code, out, _ = cli(capsys, "replay", path, "--json")
    doc = json.loads(out)
    assert {"transmissions", "decodes", "decisions", "agree", "metadata"} <= set(doc)
    assert len(doc["transmissions"]) == 48 and doc["agree"] is True
    assert doc["metadata"]["scenario"] == "gate" and doc["metadata"]["seed"] == 3
    assert all(d["matches"] for d in doc["decodes"]) and len(doc["decodes"]) == 192
    first = doc["transmissions"][0]
    assert (first["sender"], first["addressee"], first["meaning"]) == ("a", "b", "ID")
    assert first["start"] == 0.0 and first["end"] > first["start"]


# -- verification -------------------------------------------------------------------------


def test_verify_cli_clean(tmp_path, capsys):
    code, out, _ = cli(capsys, "replay", write(tmp_path, log_bytes()), "--verify")
    assert code == 0 and out.startswith("verified:")
    code, out, _ = cli(capsys, "replay", write(tmp_path, log_bytes()), "--verify", "--json")
    doc = json.loads(out)
    assert code == 0 and doc["ok"] and doc["mismatches"] == []


def _tamper_choice(msgs):
    for _, _, m in msgs:
        if m.get("subject") == "b" and m.get("unit") == "b" and "choice" in m:
            m["choice"] = ["beta"] if m["choice"] != ["beta"] else []
            return msgs
    raise AssertionError("no decision to tamper with")


def _tamper_sample(msgs):
    for tp, _, m in msgs:
        if tp == "/medium" and any(m["samples"]):
            i = next(i for i, v in enumerate(m["samples"]) if v)
            m["samples"][i] += 0.001
            return msgs
    raise AssertionError("no medium window to tamper with")


def _tamper_delete_decode(msgs):
    """One decode (not an ID's) taken out of its /rx/decodes record."""
    for tp, _, m in msgs:
        if tp != "/rx/decodes":
            continue
        kinds = [m["kinds"][k] for k in m["kind"]] if "kinds" in m else m["kind"]
        if "relation" in kinds:
            i = kinds.index("relation")
            for column in records.DECODE_COLUMNS:
                del m[column][i]
            return msgs
    raise AssertionError("no relation decode to delete")


def _tamper_pulse_time(msgs):
    """A pulse logged a sample later than it was sent (a pulse's time is its sample on its
    sender's clock: its row of a /tx/pulse block)."""
    for tp, _, m in msgs:
        if tp == "/tx/pulse" and len(m["sample"]) > 1:
            m["sample"][1] += 1
            return msgs
    raise AssertionError("no pulse block to tamper with")


def _tamper_flag(record, data: bytes) -> bytes:
    """``true`` logged as ``2`` in a block's bool column (a byte, 0 or 1 in a log): the
    ``accepted`` column is a /rx/decodes block's last field, so its bytes end the block."""
    accepted = record["accepted"]
    at = len(data) - len(accepted) + int(np.argmax(accepted))
    assert data[at] == 1, "the accepted column ends the block"
    return data[:at] + b"\x02" + data[at + 1 :]


@pytest.mark.parametrize(
    "edit, topic, field",
    [
        (_tamper_choice, "/unit/decision", "choice"),
        (_tamper_sample, "/medium", "samples["),
        (_tamper_delete_decode, "/rx/decode", "from"),
        (_tamper_pulse_time, "/tx/pulse", "at sample"),
    ],
    ids=["decision-choice", "medium-sample", "deleted-decode", "pulse-time"],
)
def test_tampering_is_caught(tmp_path, capsys, edit, topic, field):
    path = write(tmp_path, rewrite(log_bytes(), edit))
    code, out, _ = cli(capsys, "replay", path, "--verify")
    assert code == 1 and "MISMATCH" in out
    lines = [ln for ln in out.splitlines() if ln.startswith(topic)]
    assert lines and any(field in ln for ln in lines), out


def test_a_tampered_message_that_breaks_its_schema_is_named_before_it_is_used(tmp_path, capsys):
    """``true`` logged as ``2`` (true to a byte, not to a bool column): every block is checked
    against its type before a reader uses it, so it is refused in one line naming the topic,
    the time and the field (exit 2), not compared as a decode."""
    edit = first_block("/rx/decodes", _tamper_flag, lambda rec: rec["accepted"].any())
    path = write(tmp_path, copied(log_bytes(), edit))
    assert edit.done
    for extra in (["--verify"], [], ["--json"]):
        code, out, err = cli(capsys, "replay", path, *extra)
        assert code == 2 and not out
        assert len(err.strip().splitlines()) == 1
        assert "message on /rx/decodes at t = " in err and "rgtbus.DecodeBlock: " in err, err
        assert "field 'accepted': a bool column holds a value other than 0 and 1" in err, err


def test_tampered_decision_names_logged_and_recomputed(tmp_path):
    report = verify_log(io.BytesIO(rewrite(log_bytes(), _tamper_choice)))
    mm = [m for m in report.mismatches if m.topic == "/unit/decision"]
    # caught twice: by the re-run units and by re-deriving from the logged tables
    assert {m.unit for m in mm} == {"b"} and len(mm) == 2
    assert any("from its tables" in m.field for m in mm)
    assert all(m.logged == ["beta"] and m.recomputed == ["alpha"] for m in mm)


def test_log_lines_of_units_must_be_there_extra_lines_may_be():
    def drop_announcement(msgs):
        i = next(i for i, (tp, _, m) in enumerate(msgs) if tp == "/log" and m["name"] == "b")
        return msgs[:i] + msgs[i + 1 :]

    def add_wrapper_line(msgs):
        line = {
            "timestamp": {"sec": 1, "nsec": 0},
            "level": 3,
            "message": "dropped: x",
            "name": "b",
            "file": "",
            "line": 0,
        }
        return [*msgs, ("/log", 1_000_000_000, line)]

    report = verify_log(io.BytesIO(rewrite(log_bytes(), drop_announcement)))
    assert [m.topic for m in report.mismatches] == ["/log"]
    assert report.mismatches[0].logged == "(missing)" and report.mismatches[0].unit == "b"
    assert verify_log(io.BytesIO(rewrite(log_bytes(), add_wrapper_line))).ok


def test_medium_sample_mismatch_points_at_the_sample():
    report = verify_log(io.BytesIO(rewrite(log_bytes(), _tamper_sample)))
    med = [m for m in report.mismatches if m.topic == "/medium"]
    assert len(med) == 1 and re.fullmatch(r"window \d+ samples\[\d+\]", med[0].field)
    assert med[0].logged == pytest.approx(med[0].recomputed + 0.001)


def test_a_log_cut_inside_a_units_decisions_verifies_as_far_as_it_goes():
    """Cut between two decisions a unit wrote at one time: the one cut off is no mismatch
    (it is at the log's bound), the log is incomplete, and what is there agrees."""
    from mcap.reader import make_reader

    sc = load_scenario(ROOT / "scenarios" / "example2.toml")
    buf = io.BytesIO()
    rec = McapRecorder(buf, chunk_size=64)  # a message a chunk: a cut anywhere
    run_group(sc, "memory", rec)
    rec.close()
    data = buf.getvalue()
    summary = make_reader(io.BytesIO(data)).get_summary()
    assert summary is not None
    ends = []  # (end of the chunk, its message's topic and unit), in file order
    for index in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
        cut = data[: index.chunk_start_offset + index.chunk_length]
        (topic, t, m), *_ = read_log(io.BytesIO(cut)).messages[-1:] or [(None, 0, {})]
        ends.append((len(cut), topic, m.get("unit"), t))
    at = next(
        size
        for (size, topic, unit, t), (_, topic2, unit2, t2) in itertools.pairwise(ends)
        if topic == topic2 == "/unit/decision" and unit == unit2 and t == t2
    )
    report = verify_log(io.BytesIO(data[:at]))
    assert report.truncated and not report.ok and report.mismatches == []


def test_truncated_log_verified_as_far_as_it_goes(tmp_path, capsys):
    data = log_bytes()
    cut = data[: len(data) // 2]
    path = write(tmp_path, cut, "cut.mcap")
    code, out, _ = cli(capsys, "replay", path, "--verify")
    assert code == EXIT_TRUNCATED == 3
    assert "log truncated" in out and "INCOMPLETE" in out and "verified only that far" in out
    report = verify_log(io.BytesIO(cut))
    assert report.truncated and not report.ok and report.mismatches == []
    assert 0 < report.until < 76 and report.checked["/rx/decode"] > 0
    # the timeline reads the truncated log too, says so, and exits 3 (it ends early)
    code, out, _ = cli(capsys, "replay", path)
    assert code == EXIT_TRUNCATED and "NOTE:" in out and "no /run record" in out
    # tampering before the cut is still caught
    bad = rewrite(data, _tamper_delete_decode)
    report = verify_log(io.BytesIO(bad[: len(bad) * 2 // 3]))
    assert report.exit_code == 1 and any(m.topic == "/rx/decode" for m in report.mismatches)


def test_gains_and_noise_verify_from_per_sender_pulses():
    text = (ROOT / "scenarios" / "example2.toml").read_text()
    text = text.replace(
        "[relations]", '[channel]\nnoise = 0.001\n[channel.gain]\n"a>b" = 0.98\n\n[relations]', 1
    )
    data, summary = _run("example2-gains", text=text)
    assert json.loads(summary)["error"] is None
    rp = load_replay(io.BytesIO(data))
    assert rp.has_gains()
    assert verify_log(rp).ok
    # fed the summed medium instead, b's receiver hears a's codes 2 % too loud: caught
    from rgtbus.telemetry.verify import verify

    wrong = verify(rp, rerun(rp.scenario, {rp.scenario.units[0]: rp.medium_pulses()}))
    assert wrong.mismatches and {m.unit for m in wrong.mismatches if m.unit} <= {"b"}


# -- merge --------------------------------------------------------------------------------


def _split(data: bytes, unit: str) -> tuple[bytes, bytes]:
    """Two per-process logs: one with ``unit``'s messages (and the medium), one with the rest."""
    messages, metadata = read_log(io.BytesIO(data))

    def mine(topic, m):
        return m.get("unit", m.get("name")) == unit or topic in ("/medium", "/run")

    out = []
    for keep in (True, False):
        buf = io.BytesIO()
        rec = McapRecorder(buf)
        for name, values in metadata.items():
            rec.metadata(
                name, values | ({"process": unit if keep else "rest"} if name == "run" else {})
            )
        if keep:  # a unit's own process says how it ended
            rec.metadata(
                topics_mod.unit_end_record(unit),
                {"status": "done", "detail": "", "sim_seconds": "1"},
            )
        for topic, t, m in messages:
            # both processes log the medium and the summary; the merge keeps one copy
            if mine(topic, m) == keep or topic in ("/medium", "/run"):
                rec.write(topic, m, t)
        rec.close()
        out.append(buf.getvalue())
    return out[0], out[1]


def test_merge_two_process_logs(tmp_path, capsys):
    data = log_bytes()
    a, rest = _split(data, "a")
    pa, pr = write(tmp_path, a, "a.mcap"), write(tmp_path, rest, "rest.mcap")
    out = tmp_path / "merged.mcap"
    code, text, _ = cli(capsys, "merge", pa, pr, "-o", out)
    assert code == 0 and "duplicates dropped" in text
    merged = read_log(out)
    orig = read_log(io.BytesIO(data))
    key = lambda m: (m[1], m[0], json.dumps(m[2], sort_keys=True, default=plain))  # noqa: E731
    assert sorted(map(key, merged.messages)) == sorted(map(key, orig.messages))
    assert [m[1] for m in merged.messages] == sorted(m[1] for m in merged.messages)
    assert merged.metadata["run"]["process"] == "a"
    assert merged.metadata["run.2"]["process"] == "rest"
    assert merged.metadata["scenario"] == orig.metadata["scenario"]
    assert "scenario.2" not in merged.metadata  # identical records kept once
    assert json.loads(merged.metadata["merge"]["inputs"]) == [str(pa), str(pr)]
    assert cli(capsys, "replay", out, "--verify")[0] == 0
    # channels deduplicated: one per topic
    from mcap.reader import make_reader

    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    topics = [c.topic for c in summary.channels.values()]
    assert len(topics) == len(set(topics)) and len(summary.schemas) == len(
        {s.name for s in summary.schemas.values()}
    )


def test_merge_refusals(tmp_path, capsys):
    good = write(tmp_path, log_bytes())
    bad = write(tmp_path, b"not an mcap file at all", "bad.mcap")
    code, _, err = cli(capsys, "merge", good, bad, "-o", tmp_path / "o.mcap")
    assert code == 2 and "bad.mcap" in err and "not an MCAP file" in err
    code, _, err = cli(capsys, "merge", good, "-o", good)
    assert code == 2 and "also an input" in err
    assert read_log(good).messages  # the input is untouched


def test_merge_keeps_a_truncated_input_as_far_as_it_goes(tmp_path, capsys):
    data = log_bytes()
    cut = write(tmp_path, data[: len(data) // 2], "cut.mcap")
    out = tmp_path / "m.mcap"
    code, _, err = cli(capsys, "merge", cut, "-o", out)
    assert code == 0 and "warning" in err and "truncated" in err
    assert len(read_log(out).messages) == len(read_log(cut).messages)


# -- plots, CSV, Foxglove -----------------------------------------------------------------


def _png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", head[16:24])


@pytest.mark.slow  # a few seconds: CI's slow pass (the fast suite stays near 3 min)
def test_plot_writes_png_with_the_expected_panels(tmp_path, capsys):
    path = write(tmp_path, log_bytes(traces=True))
    png = tmp_path / "a.png"
    code, _, err = cli(
        capsys, "replay", path, "--plot", png, "--unit", "b", "--from", "10", "--to", "40"
    )
    assert code == 0 and "logged resonator trace" in err
    w, h = figure_size(3, 3)
    assert _png_size(png) == (round(w * DPI), round(h * DPI))
    rp = load_replay(path)
    fig = activity_figure(rp, "b", traces_for(rp, "b"), t_from=10, t_to=40)
    titles = [ax.get_title(loc="left") for ax in fig.axes]
    assert len(fig.axes) == 4
    assert [t.split(" (")[0] for t in titles[:3]] == ["channel a", "channel b", "channel c"]
    assert titles[3].startswith("decision timeline")
    texts = [t.get_text() for ax in fig.axes[:3] for t in ax.texts]
    shown = {tx.label for tx in rp.transmissions if 10 <= tx.start <= 40}
    assert "a → b: ID" in shown and shown <= set(texts)
    assert fig.axes[0].get_xlim() == (10, 40)


@pytest.mark.slow  # a re-run of a unit for its trace: seconds
def test_plot_recomputes_the_trace_when_not_logged(tmp_path, capsys):
    path = write(tmp_path, log_bytes())
    png = tmp_path / "c.png"
    code, _, err = cli(capsys, "replay", path, "--plot", png, "--unit", "c")
    assert code == 0 and "recomputed" in err and png.stat().st_size > 10_000
    rp = load_replay(path)
    logged = traces_for(load_replay(io.BytesIO(log_bytes(traces=True))), "c")
    again = traces_for(rp, "c")
    assert again["recomputed"] and not logged["recomputed"]
    assert (again["y"] == logged["y"]).all()  # the re-run bank is the logged bank


def test_plot_refusals(tmp_path, capsys):
    path = write(tmp_path, log_bytes())
    code, _, err = cli(capsys, "replay", path, "--plot", tmp_path / "x.png", "--unit", "zz")
    assert code == 2 and "'zz'" in err
    code, _, err = cli(
        capsys, "replay", path, "--plot", tmp_path / "x.png", "--from", "5", "--to", "5"
    )
    assert code == 2 and "empty time range" in err
    code, _, err = cli(capsys, "replay", path, "--unit", "a")
    assert code == 2 and "--plot" in err


def test_csv_tables(tmp_path, capsys):
    path = write(tmp_path, log_bytes())
    out = tmp_path / "tables"
    assert cli(capsys, "replay", path, "--csv", out)[0] == 0
    rows = {}
    for name in ("transmissions", "decodes", "decisions", "spikes"):
        with open(out / f"{name}.csv", newline="", encoding="utf-8") as f:
            rows[name] = list(csv.DictReader(f))
    assert len(rows["transmissions"]) == 24 and rows["transmissions"][0]["meaning"] == "ID"
    head = ["run_id", "scenario", "seed", "turn", "phase", "kind", "sender", "addressee"]
    assert list(rows["transmissions"][0])[:8] == head
    # every row says which run it is from, so tables of many runs concatenate
    for table in rows.values():
        assert {(r["run_id"], r["scenario"], r["seed"]) for r in table} == {
            ("example2-2", "example2", "2")
        }
    assert len(rows["decodes"]) == 72 and {r["matches"] for r in rows["decodes"]} == {"true"}
    assert float(rows["decodes"][0]["margin"]) > 0
    own = [r for r in rows["decisions"] if r["unit"] == r["subject"]]
    assert [(r["unit"], r["low"], r["high"]) for r in own] == [
        ("a", "0", "1"),
        ("b", "{alpha}", "{alpha}"),
        ("c", "0", "{beta}"),
    ]
    assert rows["spikes"] and list(rows["spikes"][0]) == [
        "run_id",
        "scenario",
        "seed",
        "t",
        "unit",
        "channel",
        "omega",
        "sample",
    ]
    # times on the sample grid, printed without float noise
    for r in rows["spikes"] + rows["decodes"]:
        assert len(r["t"].partition(".")[2]) <= 4, r["t"]
    for r in rows["spikes"]:
        assert float(r["t"]) == round(int(r["sample"]) * 0.005, 4)
    # an ID is decoded for the turn's addressee, on the sender's channel
    ids = [r for r in rows["decodes"] if r["kind"] == "id"]
    assert ids and all(r["channel"] == r["sender"] != r["addressee"] for r in ids)
    # --from/--to keep what happens in the span
    part = tmp_path / "part"
    assert cli(capsys, "replay", path, "--csv", part, "--from", "10", "--to", "20")[0] == 0
    with open(part / "decodes.csv", newline="", encoding="utf-8") as f:
        some = list(csv.DictReader(f))
    assert some and all(10 <= float(r["t"]) <= 20 for r in some) and len(some) < 72


def _library_class(schema):
    """The protobuf library's message class of a channel's schema, from the
    ``FileDescriptorSet`` the file stores with it alone (what Foxglove reads a block by)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


@pytest.mark.slow  # every message of a traced run decoded twice: ~2 s (CI's slow pass)
def test_every_logged_message_validates_against_its_schema():
    """A JSON topic's messages against the JSON Schema its channel carries; a hot topic's
    blocks against the protobuf type its channel carries: the protobuf library reads each
    from the file's own descriptor and writes back the very bytes logged, and rgtbus reads it
    with every check."""
    from mcap.reader import make_reader

    reader = make_reader(io.BytesIO(log_bytes(traces=True)))
    classes: dict[int, type] = {}
    seen = set()
    for schema, channel, message in reader.iter_messages():
        topic = channel.topic
        assert schema.name == schema_for(topic), topic
        assert schema.data == topics_mod.schema_bytes(schema.name), topic
        block = blocks.schema_of(topic)
        if block is None:
            assert (schema.encoding, channel.message_encoding) == ("jsonschema", "json"), topic
            m = json.loads(message.data)
            assert validate_mod.errors(m, json.loads(schema.data)) == [], topic
        else:
            assert (schema.encoding, channel.message_encoding) == ("protobuf", "protobuf")
            assert schema.name == block.name, topic
            if schema.id not in classes:
                classes[schema.id] = _library_class(schema)
            parsed = classes[schema.id].FromString(message.data)
            assert parsed.SerializeToString() == message.data, topic
            blocks.decode_record(block, message.data, topic)  # raises on anything wrong
        seen.add(topic)
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
        "/trace/a",
    } <= seen


def _layout_topics(node, out):
    if isinstance(node, dict):
        for k, v in node.items():
            if k in ("value", "topicPath", "topicToRender") and isinstance(v, str):
                out.append(re.match(r"^(/[^.{\[]*)", v).group(1))
            else:
                _layout_topics(v, out)
    elif isinstance(node, list):
        for v in node:
            _layout_topics(v, out)
    return out


@pytest.mark.slow  # a traced run read whole: ~3 s (CI's slow pass)
def test_foxglove_layout_names_only_existing_topics():
    layout = json.loads((ROOT / "docs" / "foxglove-layout.json").read_text())
    panels = set(layout["configById"])
    kinds = {p.split("!")[0] for p in panels}
    assert {"Plot", "Log", "RawMessages"} <= kinds

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert set(leaves(layout["layout"])) == panels
    topics = _layout_topics(layout["configById"], [])
    logged = {t for t, _, _ in read_log(io.BytesIO(log_bytes(traces=True))).messages}
    for topic in topics:
        schema_for(topic)  # a topic the recorder registers
        assert topic in logged, topic
    assert {"/medium", "/log", "/unit/decision", "/trace/a"} <= set(topics)
    # the trace plot draws every sample: one number a message per path, not a block
    paths = [p["value"] for p in layout["configById"]["Plot!rgtbus-traces"]["paths"]]
    traces = [
        m for t, _, m in read_log(io.BytesIO(log_bytes(traces=True))).messages if t == "/trace/a"
    ]
    channels = len(traces[0]["y"])  # 3 here; a path past the run's channels draws nothing
    for path in paths:
        index = int(path.removeprefix("/trace/a.y[").removesuffix("]"))
        assert index >= channels or all(isinstance(m["y"][index], float) for m in traces)
    samples = [m["sample"] for m in traces]
    assert samples == list(range(samples[0], samples[0] + len(samples)))  # no sample left out


def test_unreadable_input_exit_2(tmp_path, capsys):
    for data in (b"", b"hello, not mcap", b"\x89MCAP0\r\n"):
        code, out, err = cli(capsys, "replay", write(tmp_path, data, "x.mcap"), "--verify")
        assert code == 2 and out == "" and len(err.strip().splitlines()) == 1
        assert "not an MCAP file" in err
    code, _, err = cli(capsys, "replay", tmp_path / "missing.mcap")
    assert code == 2 and "missing.mcap" in err


def test_log_without_scenario_cannot_be_verified(tmp_path, capsys):
    buf = io.BytesIO()
    rec = McapRecorder(buf)
    rec.write("/medium", {"window": 0, "t": 0.0, "sample_rate": 200.0, "samples": [0.0]}, 0)
    rec.metadata("run", {"seed": "1"})
    rec.close()
    path = write(tmp_path, buf.getvalue())
    assert cli(capsys, "replay", path)[0] == 0
    code, _, err = cli(capsys, "replay", path, "--verify")
    assert code == 2 and "no scenario metadata" in err
    # with no run metadata at all it is no rgtbus run log: refused before reading on
    buf = io.BytesIO()
    rec = McapRecorder(buf)
    rec.write("/medium", {"window": 0, "t": 0.0, "sample_rate": 200.0, "samples": [0.0]}, 0)
    rec.close()
    code, _, err = cli(capsys, "replay", write(tmp_path, buf.getvalue(), "bare.mcap"))
    assert code == 2 and "not an rgtbus run log: no scenario or run metadata" in err


def test_a_format1_log_is_refused_naming_convert_and_converted_verifies(tmp_path, capsys):
    """A log of format 1 (no ``format`` record, every topic JSON, one ``/tx/pulse`` record a
    pulse) is refused by every reader in one line naming ``rgtbus convert`` (exit 2), never
    read as format 2; the log ``convert`` writes of it holds the same messages, block for
    block, as the run's own, and verifies."""
    import rgtbus

    new = tmp_path / "new.mcap"
    rgtbus.run("gate", bus="memory", log=new)
    old = write(tmp_path, as_format1(new.read_bytes()), "old.mcap")
    assert FORMAT_RECORD not in dict(scan_log(old).metadata) and scan_log(old).messages
    refused_as_format1(capsys, old)
    conv = converted(tmp_path, old)
    ours, theirs = read_log(new).messages, read_log(conv).messages
    for topic in ("/tx/pulse", "/rx/spike", "/rx/decodes", "/medium", "/unit/decision", "/log"):
        a = [(t, m) for tp, t, m in ours if tp == topic]
        b = [(t, m) for tp, t, m in theirs if tp == topic]
        assert len(a) == len(b) > 0, topic
        assert json.dumps(a, default=plain) == json.dumps(b, default=plain), topic
    assert len(ours) == len(theirs)
    before, after = rgtbus.open_log(new), rgtbus.open_log(conv)
    assert {**before.summary(), "log": None} == {**after.summary(), "log": None}
    assert main(["replay", str(conv), "--verify", "--quiet"]) == 0


def test_a_format1_log_of_one_spike_record_a_sample_converted_verifies(tmp_path, capsys):
    """Format-1 logs before the columnar /rx/spike held one record per unit and sample, and
    before shared records one per unit and block: refused as format 1 naming ``convert``,
    and converted, the same run written either way reads to the same spikes and summary,
    and verifies."""
    import pandas as pd

    import rgtbus

    new = tmp_path / "new.mcap"
    rgtbus.run("gate", bus="memory", log=new)  # a few blocks hold more than one sample
    tau = rgtbus.open_log(new).replay.scenario.timing.tau

    def per_sample(t_ns, m):
        out = []
        for k, chans in spike_samples(m):
            for unit in spike_units(m):
                one = {"unit": unit, "t": k * tau, "sample": k, "channels": chans}
                out.append(("/rx/spike", round(k * tau * 1e9), one))
        return out

    def per_unit(t_ns, m):  # the columnar records before units shared them
        return [("/rx/spike", t_ns, one) for one in each_unit_spikes(m)]

    assert any("units" in m for m in rgtbus.open_log(new).messages("/rx/spike"))
    for form in (per_sample, per_unit):
        old = write(tmp_path, as_format1(new.read_bytes(), spikes=form), f"{form.__name__}.mcap")
        refused_as_format1(capsys, old)
        conv = converted(tmp_path, old, f"{form.__name__}-2.mcap")
        before, after = rgtbus.open_log(new), rgtbus.open_log(conv)
        assert len(after.messages("/rx/spike")) > len(before.messages("/rx/spike"))
        pd.testing.assert_frame_equal(before.spikes(), after.spikes())
        assert {**before.summary(), "log": None} == {**after.summary(), "log": None}
        assert main(["replay", str(conv), "--verify", "--quiet"]) == 0  # compared per sample


def test_a_format1_log_of_one_decode_record_a_decode_converted_verifies(tmp_path, capsys):
    """Format-1 logs before the columnar /rx/decodes held one /rx/decode per decode: refused
    as format 1 naming ``convert``, and converted (a unit's decodes of 5 s one /rx/decodes block,
    as a run writes them), the same run reads to the same decodes and summary, and verifies."""
    import pandas as pd

    import rgtbus

    new = tmp_path / "new.mcap"
    rgtbus.run("random_group", bus="memory", log=new)

    def per_decode(t_ns, m):
        return [("/rx/decode", round(row["t"] * 1e9), row) for row in decode_rows(m)]

    old = write(tmp_path, as_format1(new.read_bytes(), decodes=per_decode), "old.mcap")
    refused_as_format1(capsys, old)
    conv = converted(tmp_path, old)
    before, after = rgtbus.open_log(new), rgtbus.open_log(conv)
    topics = [tp for tp, _, _ in read_log(conv).messages]
    assert "/rx/decode" not in topics
    blocks_of = [tp for tp, _, _ in read_log(new).messages].count("/rx/decodes")
    assert topics.count("/rx/decodes") == blocks_of > 0  # the blocks a run writes
    pd.testing.assert_frame_equal(before.decodes(), after.decodes())
    assert {**before.summary(), "log": None} == {**after.summary(), "log": None}
    assert main(["replay", str(conv), "--verify", "--quiet"]) == 0  # decodes compare one by one


def test_a_damaged_decodes_record_is_named_in_one_line(tmp_path, capsys):
    """Columns of unequal length in a /rx/decodes block (one ``code`` too many): every reader
    says which, in one line, exit 2."""

    def damage(record, data: bytes) -> bytes:
        return encode(blocks.DECODE, {**record, "code": np.append(record["code"], 0)})

    edit = first_block("/rx/decodes", damage)
    path = write(tmp_path, copied(log_bytes(), edit), "bad.mcap")
    assert edit.done
    for extra in ([], ["--json"], ["--verify"]):
        code, _, err = cli(capsys, "replay", path, *extra)
        assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
        assert "message on /rx/decodes at t = " in err and "rgtbus.DecodeBlock: " in err, err
        found = re.search(r"table 'rows': column 'turn' has (\d+) rows, 'code' (\d+)", err)
        assert found and int(found[2]) == int(found[1]) + 1, err


def _units(units: list[str], unit: str = ""):
    """A ``first_block`` change: a shared /rx/spike block's units (and unit) replaced."""

    def change(record, data: bytes) -> bytes:
        rest = {k: v for k, v in record.items() if k not in ("unit", "units")}
        return encode(blocks.SPIKE, {**rest, "unit": unit, "units": units})

    return change


def _units_not_utf8(record, data: bytes) -> bytes:
    """A shared /rx/spike block whose first unit's name is not text."""
    rest = {k: v for k, v in record.items() if k not in ("unit", "units")}
    name = b"\xff\xfe"
    return b"\x12" + bytes([len(name)]) + name + encode(blocks.SPIKE, {**rest, "units": ["b"]})


@pytest.mark.parametrize(
    "change, says",
    [
        (_units(["ab"]), r"units \['ab'\]: not two or more unit names alone"),
        (_units([]), r"no unit$"),
        (_units(["a", "a"]), r"units \['a', 'a'\]: not two or more unit names alone"),
        (_units(["a", "b"], "a"), r"units \['a', 'b'\]: not two or more unit names alone"),
        (_units_not_utf8, r"field 'units': not UTF-8"),
    ],
    ids=["one-name", "no-unit", "twice", "unit-and-units", "not-text"],
)
@pytest.mark.parametrize("extra", [[], ["--verify"], ["--json"]])
def test_a_tampered_shared_spike_record_is_named_not_read(tmp_path, capsys, change, says, extra):
    """A shared /rx/spike block whose ``units`` is not two or more distinct unit names (or
    that names a ``unit`` too, or no unit at all) is refused in one line naming the message
    and what is wrong with it, exit 2: never read as one unit's spikes, or as nobody's."""
    edit = first_block("/rx/spike", change, lambda record: "units" in record)
    log = write(tmp_path, copied(log_bytes("gate"), edit))
    assert edit.done
    code, _, err = cli(capsys, "replay", log, "--quiet", *extra)
    assert code == 2 and err.count("\n") == 1, err
    assert re.search("message on /rx/spike at t = [0-9.]+ s: rgtbus.SpikeBlock: .*" + says, err), (
        err
    )


@pytest.mark.slow  # a traced log through every tool: ~3 s (CI's slow pass)
def test_every_tool_counts_a_logs_messages_alike(tmp_path, capsys):
    """info, replay, open_log and replay --verify give one number of messages for a traced
    log (the traces left in the file until asked for count too); verify says apart how many
    records it compared (a decode and a sample's spikes each)."""
    import rgtbus

    for traces in (True, False):
        log = tmp_path / f"gate-{traces}.mcap"
        rgtbus.run("gate", log=log, traces=traces)
        capsys.readouterr()
        assert cli(capsys, "info", log, "--json")[0] == 0
        counted = json.loads(cli(capsys, "info", log, "--json")[1])["messages"]
        code, out, _ = cli(capsys, "replay", log)
        assert code == 0 and f"; {counted} messages" in out
        assert sum(rgtbus.open_log(log).replay.topic_counts().values()) == counted
    report = verify_log(log)  # the untraced one: a traced verify re-runs every trace (slow)
    assert report.messages == counted and report.compared > counted
    assert f"the log's {counted} messages; {report.compared} records compared" in report.verdict()


@pytest.mark.parametrize("what", ["log time", "own time"])
def test_a_block_moved_in_time_is_named_by_verify(what, tmp_path, capsys):
    """A block's rows are compared at their own times; the block's log time (and its own
    ``t``) is compared too: a pulse block moved by 1 ms is a mismatch naming the block."""
    first: list[int] = []

    def retime(topic: str, t: int) -> int:
        if topic == "/tx/pulse" and not first:
            first.append(t)
            return t + 1_000_000 if what == "log time" else t
        return t

    def later(record, data: bytes) -> bytes:
        record["t"] += 0.001
        return blocks.encode_record(blocks.PULSE, record)

    edit = first_block("/tx/pulse", later) if what == "own time" else lambda tp, t, d: d
    path = write(tmp_path, copied(log_bytes("gate"), edit, retime), "moved.mcap")
    assert main(["replay", str(path), "--verify"]) == 1
    out = capsys.readouterr().out
    assert "/tx/pulse" in out and ("block log time" in out or "its log time" in out), out
