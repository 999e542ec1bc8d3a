"""Errors a caller can catch by kind (rgtbus.errors): a bad value, a log that cannot be read,
a silent peer (a TimeoutError too; tests/test_bus.py times a join out), a file that cannot be
read or written (an OSError too). Each is an RgtbusError, one line, and the CLI's exit codes
stay as they were."""

from __future__ import annotations

import io
from pathlib import Path

import pytest

import rgtbus
from rgtbus.cli import main
from rgtbus.errors import BadInput, BadLog, IOFailure, MembersSilent, PeerSilent, RgtbusError

ROOT = Path(__file__).resolve().parent.parent
GATE = (ROOT / "scenarios" / "gate.toml").read_text()


def test_the_kinds_are_rgtbus_errors_and_the_builtin_kinds_they_are():
    for kind in (BadInput, BadLog, PeerSilent, IOFailure):
        assert issubclass(kind, RgtbusError) and issubclass(kind, ValueError)
    assert issubclass(PeerSilent, TimeoutError) and issubclass(MembersSilent, PeerSilent)
    assert issubclass(IOFailure, OSError) and not issubclass(BadLog, OSError)
    assert rgtbus.BadInput is BadInput and rgtbus.IOFailure is IOFailure


def test_bad_input_is_a_bad_input(tmp_path):
    with pytest.raises(BadInput, match=r"<text>:\d+: channel\.noise: must be a standard dev"):
        rgtbus.load_scenario(GATE.replace("noise = 0.0", "noise = -1", 1))
    with pytest.raises(BadInput, match="bus 'nope'"):
        rgtbus.run("gate", bus="nope")


def test_a_log_that_cannot_be_read_is_a_bad_log_and_a_missing_file_an_io_failure(tmp_path):
    rgtbus.run("gate", seed=3, log=tmp_path / "gate.mcap")
    good = (tmp_path / "gate.mcap").read_bytes()
    with pytest.raises(BadLog, match="not an MCAP file"):
        rgtbus.open_log(io.BytesIO(b"not a log at all, not even close"))
    flipped = bytearray(good)
    flipped[len(good) // 2] ^= 0xFF  # inside a chunk: its CRC fails
    (tmp_path / "bad.mcap").write_bytes(bytes(flipped))
    with pytest.raises(BadLog):
        rgtbus.open_log(tmp_path / "bad.mcap")
    with pytest.raises(IOFailure) as missing:
        rgtbus.open_log(tmp_path / "nowhere.mcap")
    assert isinstance(missing.value, OSError) and "nowhere.mcap" in str(missing.value)
    (tmp_path / "file").write_text("x")
    with pytest.raises(IOFailure, match="cannot write log"):
        rgtbus.run("gate", seed=3, log=tmp_path / "file" / "run.mcap")


def test_the_cli_still_says_one_line_and_exits_2_for_every_kind(tmp_path, capsys):
    (tmp_path / "bad.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\0" * 40)
    for argv in (["info", str(tmp_path / "bad.mcap")], ["info", str(tmp_path / "none.mcap")],
                 ["run", str(tmp_path / "none.toml")]):  # fmt: skip
        capsys.readouterr()
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "error:" in err, err
