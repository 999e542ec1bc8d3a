"""The run options are declared and checked in one place (rgtbus/cli/arguments.py) by the
library's rules (rgtbus.checks): a bad value is one line naming the flag and the value, exit
code 2, before the command does anything."""

from __future__ import annotations

import argparse

import pytest

from rgtbus.cli import main
from rgtbus.cli.arguments import (
    add_join_timeout_argument,
    add_realtime_argument,
    add_seed_argument,
    add_timeout_argument,
    check_arguments,
)
from rgtbus.errors import RgtbusError

SEED = "must be a non-negative integer"
PACE = "must be a positive factor"


@pytest.mark.parametrize(
    ("argv", "flag", "value", "rule"),
    [
        (["run", "gate", "--no-log"], "--seed", "-3", SEED),
        (["run", "gate", "--no-log"], "--realtime", "0", PACE),
        (["run", "gate", "--no-log"], "--realtime", "nan", PACE),
        (["run", "gate", "--no-log"], "--realtime", "inf", PACE),
        (["resonate"], "--seed", "-1", SEED),
        (["ser"], "--seed", "-1", SEED),
        (["figures", "out"], "--seed", "-1", SEED),
        (["watch"], "--idle-exit", "0", "must be positive seconds"),
    ],
)
def test_a_bad_run_option_is_one_line_and_exit_2(
    argv, flag, value, rule, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)  # nothing may be written: figures' OUTDIR, a log
    assert main([*argv, flag, value]) == 2
    shown = repr(float(value)) if flag != "--seed" else value  # the value as parsed
    line = f"rgtbus {argv[0]}: error: {flag} {shown}: {rule}\n"
    assert capsys.readouterr() == ("", line)
    assert not any(tmp_path.iterdir())


def test_the_checked_values_are_what_the_rules_give():
    p = argparse.ArgumentParser()
    add_seed_argument(p)
    add_realtime_argument(p)
    add_timeout_argument(p)
    add_join_timeout_argument(p)
    args = p.parse_args(["--seed", "7", "--realtime", "2"])
    check_arguments(args)
    assert (args.seed, args.realtime, args.timeout, args.join_timeout) == (7, 2.0, 10.0, None)
    args = p.parse_args([])
    check_arguments(args)  # an option not given (None) is not checked
    assert (args.seed, args.realtime) == (None, None)
    for argv, text in (
        (["--timeout", "-1"], "--timeout -1.0: must be positive seconds"),
        (["--join-timeout", "inf"], "--join-timeout inf: must be positive seconds"),
    ):
        with pytest.raises(RgtbusError) as exc:
            check_arguments(p.parse_args(argv))
        assert str(exc.value) == text


def test_a_parser_without_checked_options_is_left_alone():
    args = argparse.Namespace(seed=-1)
    check_arguments(args)  # declared without a rule: not this module's to judge
    assert args.seed == -1


def test_every_command_that_prints_a_result_prints_it_as_json_too(tmp_path, capsys):
    """``--json`` on every command but ``cat`` (JSON lines already), ``scenario`` (a TOML
    file's text) and ``completion`` (shell code); merge's and recover's objects say what they
    wrote."""
    import json

    import rgtbus
    from rgtbus.cli import build_parser

    parser = build_parser()
    commands = next(a for a in parser._actions if a.dest == "command").choices
    lacking = [name for name, sub in commands.items()
               if not any("--json" in a.option_strings for a in sub._actions)]  # fmt: skip
    assert sorted(lacking) == ["cat", "completion", "scenario"]
    log = tmp_path / "gate.mcap"
    rgtbus.run("gate", log=log)
    capsys.readouterr()
    assert main(["merge", str(log), "-o", str(tmp_path / "m.mcap"), "--json"]) == 0
    merged = json.loads(capsys.readouterr().out)
    assert merged["output"] == str(tmp_path / "m.mcap") and merged["messages"] > 0
    assert main(["recover", str(log), "-o", str(tmp_path / "r.mcap"), "--json"]) == 0
    recovered = json.loads(capsys.readouterr().out)
    assert recovered["messages"] == merged["messages"] and recovered["ended"] == ""
