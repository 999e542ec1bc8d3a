"""Format 1 and ``rgtbus convert`` (docs/format.md).

The format-1 logs are made as format 1 wrote them (``format1.as_format1``: every topic JSON,
one ``/tx/pulse`` record a pulse, no ``format`` record); at 59e06c0 the same test converted logs
that rgtbus of format 1 wrote itself, to the same bytes. ``tests/data/format1/frames.json``
holds, for every shipped scenario of up to 12 units, the DataFrames that format 1's own reader
(59e06c0) gave for its log (columns, dtypes, rows and a digest of the values): today's reader
must give the same ones for today's log of the same run. The decodes of one time are now in
the run's order of units (format 1 gave them in the order its units wrote their records): six
scenarios' ``decodes`` digests are of format 1's own frame so ordered (a stable sort by time,
then unit), the same rows. coalition10's ``spikes`` digest is of format 1's own frame ordered by
sample, then unit (stably), the same rows: its units that heard their last spikes alike are one
record now, on both engines (format 1 wrote the first unit done apart from the others)."""

from __future__ import annotations

import hashlib
import io
import json
import re
import shutil
from pathlib import Path

import pandas as pd
import pytest
from format1 import format1_log
from mcap.reader import make_reader

from rgtbus import open_log
from rgtbus.cli import main
from rgtbus.errors import RgtbusError
from rgtbus.telemetry.convert import convert_log
from rgtbus.telemetry.scan import scan_log
from rgtbus.telemetry.version import FORMAT_RECORD

ROOT = Path(__file__).parent.parent
DATA = Path(__file__).parent / "data" / "format1"
FRAMES = json.loads((DATA / "frames.json").read_text())
NAMES = ("crowd10", "gate")


@pytest.fixture(scope="module")
def old(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A format-1 log of gate and of crowd10 (each with its own seed)."""
    tmp = tmp_path_factory.mktemp("format1")
    return {name: format1_log(name, tmp / f"{name}.mcap") for name in NAMES}


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as f:
        reader = make_reader(f)
        return sorted((c.topic, m.log_time, bytes(m.data)) for _, c, m in reader.iter_messages())


def _run(name: str, log: Path) -> None:
    scenario = str(ROOT / "scenarios" / f"{name}.toml")
    assert main(["run", scenario, "--bus", "memory", "--log", str(log), "--quiet"]) == 0


@pytest.mark.parametrize("name", NAMES)
def test_a_converted_log_is_the_log_of_the_same_run_today(name, old, tmp_path, capsys):
    """old -> convert: every message byte for byte what a run of today writes for the same
    scenario and seed, the same summary, DataFrames and metadata; it verifies."""
    converted, today = tmp_path / "converted.mcap", tmp_path / "today.mcap"
    assert main(["convert", str(old[name]), "-o", str(converted)]) == 0
    assert "(format 1) into" in capsys.readouterr().out
    _run(name, today)
    assert _messages(converted) == _messages(today)
    a, b = open_log(converted), open_log(today)
    here = ("wall_seconds", "log")  # where and how fast, not what
    assert {k: v for k, v in a.summary().items() if k not in here} == {
        k: v for k, v in b.summary().items() if k not in here
    }
    for frame in ("decisions", "decodes", "spikes", "transmissions", "medium"):
        pd.testing.assert_frame_equal(getattr(a, frame)(), getattr(b, frame)())
    assert a.metadata["convert"]["from_format"] == "1"
    assert a.metadata[FORMAT_RECORD]["version"] == "2"
    assert main(["replay", str(converted), "--verify", "--quiet"]) == 0


def _digest(df: pd.DataFrame) -> dict:
    h = hashlib.sha256()
    h.update(json.dumps([list(map(str, df.columns)), [str(t) for t in df.dtypes]]).encode())
    h.update(pd.util.hash_pandas_object(df, index=True).values.tobytes())
    return {
        "columns": list(map(str, df.columns)),
        "dtypes": [str(t) for t in df.dtypes],
        "rows": len(df),
        "sha256": h.hexdigest(),
    }


_FAST = {"gate", "gate_repair", "crowd10"}


@pytest.mark.parametrize(
    "name", [n if n in _FAST else pytest.param(n, marks=pytest.mark.slow) for n in sorted(FRAMES)]
)
def test_the_dataframes_are_the_ones_format_1_gave(name, tmp_path):
    log = tmp_path / "run.mcap"
    scenario = str(ROOT / "scenarios" / f"{name}.toml")
    assert main(["run", scenario, "--bus", "memory", "--log", str(log), "--quiet"]) in (0, 1)
    got = open_log(log)
    for frame, want in FRAMES[name].items():
        assert _digest(getattr(got, frame)()) == want, (name, frame)


_READERS = [
    ["info", "{log}"],
    ["cat", "{log}"],
    ["scenario", "{log}"],
    ["replay", "{log}"],
    ["replay", "{log}", "--verify"],
    ["merge", "{log}", "-o", "{out}"],
    ["recover", "{log}", "-o", "{out}"],
]


@pytest.mark.parametrize("argv", _READERS, ids=lambda a: " ".join(a[:2]))
def test_every_reader_names_format_1_and_convert_in_one_line(argv, old, tmp_path, capsys):
    out = tmp_path / "out.mcap"
    code = main([a.format(log=old["gate"], out=out) for a in argv])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err, err
    assert "format 1" in err and f"rgtbus convert {old['gate']} -o NEW.mcap" in err
    assert not out.exists()


def test_open_log_names_format_1_and_convert(old):
    with pytest.raises(RgtbusError, match=r"format 1 .*rgtbus convert"):
        open_log(old["gate"])


def test_convert_refuses_what_it_cannot_convert_in_one_line(tmp_path, capsys):
    today = tmp_path / "today.mcap"
    _run("gate", today)
    out = tmp_path / "out.mcap"
    not_mcap = tmp_path / "x.mcap"
    not_mcap.write_bytes(b"not an mcap file at all")
    for src, says in (
        (today, "already an rgtbus log of format 2"),
        (not_mcap, "not an MCAP file"),
        (tmp_path / "missing.mcap", "missing.mcap"),
    ):
        assert main(["convert", str(src), "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert says in err and "\n" not in err, err
        assert not out.exists()


def _cut(path: Path, at: int, dest: Path) -> Path:
    dest.write_bytes(path.read_bytes()[:at])
    return dest


def _summary_start(path: Path) -> int:
    """Where a finished MCAP file's summary begins (its footer says; 0: no summary)."""
    data = path.read_bytes()
    footer = len(data) - 8 - 29  # the magic after it; opcode, length, then summary_start
    return int.from_bytes(data[footer + 9 : footer + 17], "little")


def test_a_cut_format_1_log_converts_up_to_its_cut_and_stays_cut(old, tmp_path, capsys):
    """Cut at its summary (every message whole): the same messages as the whole log's
    conversion, and a cut log still; cut in its one chunk: no message, and a cut log."""
    whole = tmp_path / "whole.mcap"
    assert main(["convert", str(old["crowd10"]), "-o", str(whole), "--quiet"]) == 0
    size = old["crowd10"].stat().st_size
    summary = _summary_start(old["crowd10"])
    assert 0 < summary < size
    for at, messages in ((summary, _messages(whole)), (size // 3, [])):
        cut = _cut(old["crowd10"], at, tmp_path / "cut.mcap")
        out = tmp_path / f"out{at}.mcap"
        assert main(["convert", str(cut), "-o", str(out), "--json"]) == 0
        res = json.loads(capsys.readouterr().out)
        assert "truncated" in res["ended"] and res["written"] == len(messages)
        assert _messages(out) == messages
        assert scan_log(out).truncated  # as its input was
    assert main(["replay", str(out), "--verify", "--quiet"]) == 3  # nothing verified: cut


def _hostile(src: Path, tmp_path: Path, topic: str, edit) -> Path:
    """The gate log with the first message of ``topic`` edited (``edit(record)``), every CRC
    valid: written again with mcap's own writer."""
    from mcap.writer import Writer

    out = tmp_path / "hostile.mcap"
    with open(src, "rb") as f, open(out, "wb") as g:
        reader = make_reader(f)
        w = Writer(g)
        w.start(profile="", library="test")
        schema_ids, channel_ids, done = {}, {}, False
        for schema, channel, message in reader.iter_messages():
            if schema.id not in schema_ids:
                schema_ids[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channel_ids:
                channel_ids[channel.id] = w.register_channel(
                    channel.topic, channel.message_encoding, schema_ids[schema.id]
                )
            data = message.data
            if channel.topic == topic and not done:
                record = json.loads(data)
                edit(record)
                data, done = json.dumps(record).encode(), True
            w.add_message(channel_ids[channel.id], message.log_time, data, message.publish_time)
        for m in reader.iter_metadata():
            w.add_metadata(m.name, dict(m.metadata))
        w.finish()
    return out


@pytest.mark.parametrize(
    ("topic", "edit", "says"),
    [
        ("/tx/pulse", lambda r: r.pop("sample"), "on /tx/pulse at t = .* no field 'sample'"),
        ("/tx/pulse", lambda r: r.update(magnitude="x"), "message on /tx/pulse at t = "),
        ("/rx/spike", lambda r: r.update(channel=[99]), "message on /rx/spike at t = "),
        ("/rx/decodes", lambda r: r.update(margin=[1e400]), "message on /rx/decodes at t = "),
        ("/medium", lambda r: r.update(window=True), "window: True is not an integer"),
    ],
)
def test_a_hostile_format_1_log_is_one_line_and_no_output(
    topic, edit, says, old, tmp_path, capsys
):
    src = _hostile(old["gate"], tmp_path, topic, edit)
    out = tmp_path / "out.mcap"
    assert main(["convert", str(src), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and re.search(says, err), err
    assert not out.exists() and not out.with_name("out.mcap.part").exists()


def test_convert_log_is_a_library_call(old, tmp_path):
    buf = io.BytesIO()
    res = convert_log(scan_log(old["gate"]), buf)
    assert res.read > res.written > 0 and res.ended == ""
    copy = tmp_path / "c.mcap"
    copy.write_bytes(buf.getvalue())
    assert open_log(copy).summary()["agree"]
    shutil.rmtree(tmp_path)
