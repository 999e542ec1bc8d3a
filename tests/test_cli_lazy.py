"""The command line imports only what the command it runs needs (start-up time)."""

from __future__ import annotations

import subprocess
import sys

from rgtbus.cli import COMMANDS, build_parser


def _choices(parser) -> list[str]:
    sub = next(a for a in parser._actions if a.dest == "command")
    return list(sub.choices)


def test_the_command_map_is_what_the_modules_register_in_help_order():
    assert _choices(build_parser()) == list(COMMANDS)


def test_one_command_gets_the_same_parser_as_in_the_whole_one():
    whole = build_parser()
    sub = next(a for a in whole._actions if a.dest == "command")
    for name in COMMANDS:
        alone = build_parser(name)
        assert name in _choices(alone)
        one = next(a for a in alone._actions if a.dest == "command").choices[name]
        assert one.format_help() == sub.choices[name].format_help(), name


def test_an_unknown_command_is_refused_with_every_choice_named(capsys):
    from rgtbus.cli import main

    try:
        main(["frobnicate"])
    except SystemExit as e:
        assert e.code == 2
    err = capsys.readouterr().err
    assert "frobnicate" in err and "sweep-plot" in err and "launch" in err


def test_a_run_imports_no_other_command():
    code = (
        "import sys; from rgtbus.cli import COMMANDS, main; rc = main(['scenarios']); "
        "mods = [m for m in COMMANDS.values() if 'rgtbus.cli.' + m in sys.modules]; "
        "print(','.join(sorted(set(mods)))); sys.exit(rc)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    imported = out.stdout.strip().splitlines()[-1]
    assert imported == "scenarios_cmd", imported


def test_a_run_of_the_gate_loads_nothing_it_does_not_use():
    """What only some runs need is imported when first used (start-up time): a
    noise-free open run without goals never steers, validates, tags or draws noise."""
    code = (
        "import sys; from rgtbus.cli import main; "
        "rc = main(['run', 'gate', '--bus', 'memory', '--no-log', '--quiet']); "
        "lazy = ('rgtbus.rgt.control', 'fastjsonschema', 'jsonschema', 'hmac', 'numpy.random', "
        "'rgtbus.cli.proc_cmds', 'pandas', 'pyarrow', 'zenoh', 'matplotlib'); "
        "print(','.join(m for m in lazy if m in sys.modules)); sys.exit(rc)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert out.stdout.strip() == "", out.stdout  # --quiet: the line printed is the list


def test_what_is_imported_late_still_works_when_asked_for():
    import rgtbus.rgt as rgt

    assert rgt.steer.__module__ == "rgtbus.rgt.control"
    assert "steer" in rgt.__all__
    try:
        rgt.no_such_name  # noqa: B018
    except AttributeError as e:
        assert "no_such_name" in str(e)
    else:
        raise AssertionError("no AttributeError")
