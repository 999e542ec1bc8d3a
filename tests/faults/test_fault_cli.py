"""Bad input on the command line (issue #10, item 3): an unwritable log, a bad zenoh endpoint,
a zenoh config file whose values must survive the options not given. One line, exit 2."""

from __future__ import annotations

import json
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from rgtbus.bus.config import make_config, zenoh_reason
from rgtbus.cli import build_parser, main
from rgtbus.cli.arguments import zenoh_options
from rgtbus.errors import RgtbusError

ROOT = Path(__file__).resolve().parent.parent.parent
GATE = str(ROOT / "scenarios" / "gate.toml")
EXE = [sys.executable, "-m", "rgtbus"]


def one_line_exit_2(code: int, out: str, err: str) -> str:
    assert code == 2 and out == "", (code, out, err)
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


# -- unwritable logs ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("target", "reason"),
    [
        ("/proc/version", "Input/output error"),  # opens for writing, takes no byte
        ("/dev/full", "No space left on device"),
    ],
)
def test_run_log_that_takes_no_bytes(capsys, target, reason):
    if not Path(target).exists():
        pytest.skip(f"{target} is not on this machine")
    code = main(["run", GATE, "--bus", "memory", "--log", target])
    err = one_line_exit_2(code, *capsys.readouterr())
    assert err == f"rgtbus run: error: cannot write log '{target}': {reason}\n"


def test_run_log_under_a_file_or_at_a_directory(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("")
    code = main(["run", GATE, "--bus", "memory", "--log", str(afile / "sub" / "x.mcap")])
    err = one_line_exit_2(code, *capsys.readouterr())
    assert f"'{afile}' is a file" in err
    code = main(["run", GATE, "--bus", "memory", "--log", str(tmp_path)])
    assert "Is a directory" in one_line_exit_2(code, *capsys.readouterr())


def _small_file_limit() -> None:
    # In the child: files stop growing at 30 kB (EFBIG, not the default SIGXFSZ kill).
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (30_000, 30_000))


def test_run_log_that_fills_up_mid_run(tmp_path):
    log = tmp_path / "x.mcap"
    proc = subprocess.run(
        [*EXE, "run", GATE, "--bus", "memory", "--log", str(log), "--quiet"],
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=_small_file_limit,
    )
    err = one_line_exit_2(proc.returncode, proc.stdout, proc.stderr)
    assert err == f"rgtbus run: error: cannot write log '{log}': File too large\n"


def test_unit_log_that_takes_no_bytes():
    proc = subprocess.run(
        [*EXE, "unit", "a", GATE, "--log", "/dev/full"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    err = one_line_exit_2(proc.returncode, proc.stdout, proc.stderr)
    assert "cannot write log '/dev/full': No space left on device" in err


# -- zenoh endpoints and config files ----------------------------------------------------------


def test_bad_connect_endpoint_is_one_line_naming_it(tmp_path):
    for argv, needle in [
        (["--connect", "nonsense"], "zenoh connect endpoint 'nonsense': Endpoints must be"),
        (
            ["--connect", "tcp/127.0.0.1:1", "--connect", "bad"],
            "zenoh connect endpoint 'bad': Endpoints must be",
        ),
        (["--listen", ""], "zenoh listen endpoint '': Endpoints must be"),
    ]:
        proc = subprocess.run(
            [*EXE, "unit", "a", GATE, *argv, "--log", str(tmp_path / "u.mcap")],
            capture_output=True,
            text=True,
            timeout=60,
        )
        err = one_line_exit_2(proc.returncode, proc.stdout, proc.stderr)
        assert needle in err and ".rs:" not in err and "Json5Err" not in err, err


def test_unreachable_router_message_has_no_rust_paths(tmp_path):
    net = ["--mode", "client", "--connect", "tcp/127.0.0.1:1"]
    proc = subprocess.run(
        [*EXE, "unit", "a", GATE, *net, "--log", str(tmp_path / "u.mcap")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    err = one_line_exit_2(proc.returncode, proc.stdout, proc.stderr)
    assert "cannot open zenoh session (mode client, connect ['tcp/127.0.0.1:1'])" in err
    assert ".rs:" not in err


def test_zenoh_reason_unwraps_json5_and_drops_rust_paths():
    raw = (
        'Json5Err(Message { msg: "Endpoints must be of the form <protocol>/<address>: x at '
        '/root/.cargo/git/checkouts/zenoh/src/core/endpoint.rs:615.", location: Some(Location '
        "{ line: 1, column: 2 }) }) at /root/.cargo/git/checkouts/zenoh/src/api/config.rs:86."
    )
    assert zenoh_reason(ValueError(raw)) == "Endpoints must be of the form <protocol>/<address>: x"
    assert zenoh_reason(ValueError("")) == "ValueError"


def _config(tmp_path: Path, *argv: str):
    args = build_parser().parse_args(["unit", "a", GATE, *argv])
    return make_config(**zenoh_options(args))


def test_config_file_values_survive_options_not_given(tmp_path):
    path = tmp_path / "zenoh.json5"
    path.write_text(
        json.dumps(
            {
                "mode": "client",
                "connect": {"endpoints": ["tcp/127.0.0.1:7999"]},
                "listen": {"endpoints": ["tcp/127.0.0.1:7998"]},
                "scouting": {"multicast": {"enabled": True}},
            }
        )
    )
    cfg = _config(tmp_path, "-c", str(path))
    assert json.loads(cfg.get_json("mode")) == "client"
    assert json.loads(cfg.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7999"]
    assert json.loads(cfg.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7998"]
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is True
    # what is given overrides just that
    cfg = _config(tmp_path, "-c", str(path), "--mode", "peer", "-e", "tcp/127.0.0.1:7000")
    assert json.loads(cfg.get_json("mode")) == "peer"
    assert json.loads(cfg.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7000"]
    assert json.loads(cfg.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7998"]
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is True


def test_without_a_config_file_the_defaults_hold(tmp_path):
    cfg = _config(tmp_path)
    assert json.loads(cfg.get_json("mode")) == "peer"
    assert json.loads(cfg.get_json("connect/endpoints")) == []
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is False
    cfg = _config(tmp_path, "--multicast")
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is True


def test_bad_config_file_is_one_line(tmp_path):
    path = tmp_path / "bad.json5"
    path.write_text("{ mode: ")
    with pytest.raises(RgtbusError) as err:
        _config(tmp_path, "-c", str(path))
    msg = str(err.value)
    assert msg.startswith(f"zenoh config '{path}': ") and "\n" not in msg and ".rs:" not in msg


# -- keys and closing -------------------------------------------------------------------------


@pytest.mark.parametrize("command", [["run", GATE], ["unit", "a", GATE], ["launch", GATE]])
def test_bad_key_files_are_one_line_naming_the_file(tmp_path, capsys, command):
    short = tmp_path / "short.key"
    short.write_bytes(b"0123456789abcde\n")  # 15 bytes of key
    big = tmp_path / "big.key"
    big.write_bytes(b"k" * 5000)
    for path, reason in [
        (tmp_path / "missing.key", "No such file or directory"),
        (tmp_path, "Is a directory"),
        (short, "15 bytes of key, need at least 16"),
        (big, "more than 4096 bytes"),
    ]:
        log = tmp_path / "never.mcap"
        argv = [*command, "--key-file", str(path)]
        argv += (
            ["--log-dir", str(tmp_path / "L")] if command[0] == "launch" else ["--log", str(log)]
        )
        err = one_line_exit_2(main(argv), *capsys.readouterr())
        assert f"key file '{path}': {reason}" in err, err
        assert not log.exists() and not (tmp_path / "L").exists()  # refused before anything ran


def test_a_slow_close_does_not_replace_the_real_error():
    from rgtbus.bus.memory import MemoryBus

    class SlowToClose(MemoryBus):
        def _close_transport(self) -> None:
            raise RgtbusError("closing timed out")

    with pytest.raises(RgtbusError, match="the real error") as err, SlowToClose("r", ["a"], 200.0):
        raise RgtbusError("the real error")
    assert any("closing timed out" in n for n in err.value.__notes__)
    # Alone, the close error is the one to see.
    with pytest.raises(RgtbusError, match="closing timed out"), SlowToClose("r", ["a"], 200.0):
        pass
