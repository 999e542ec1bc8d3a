"""Shell completion (``rgtbus completion SHELL``, argcomplete): commands, options and their
choices complete, and the shell code registers rgtbus in each shell."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest


def _complete(line: str, tmp_path) -> list[str]:
    out = tmp_path / "completions.txt"
    env = dict(os.environ, COMP_LINE=line, COMP_POINT=str(len(line)), _ARGCOMPLETE="1",
               _ARGCOMPLETE_STDOUT_FILENAME=str(out))  # fmt: skip
    done = subprocess.run([sys.executable, "-m", "rgtbus"], env=env, capture_output=True,
                          text=True, timeout=60)  # fmt: skip
    assert done.returncode == 0, done.stderr
    text = out.read_text()
    return [c.strip() for c in text.split("\x0b")] if text else []


@pytest.mark.parametrize(
    ("line", "want"),
    [
        ("rgtbus ru", {"run"}),
        ("rgtbus sweep", {"sweep", "sweep-plot", "sweeps"}),
        ("rgtbus run --bu", {"--bus"}),
        ("rgtbus run gate --bus ", {"memory", "zenoh"}),
        ("rgtbus completion ", {"bash", "zsh", "fish"}),
    ],
)
def test_commands_options_and_choices_complete(line, want, tmp_path):
    assert set(_complete(line, tmp_path)) >= want


@pytest.mark.parametrize("shell", ["bash", "zsh", "fish"])
def test_the_shell_code_registers_rgtbus(shell, capsys):
    from rgtbus.cli import main

    assert main(["completion", shell]) == 0
    code = capsys.readouterr().out
    assert "rgtbus" in code and "_ARGCOMPLETE" in code


def test_bash_takes_the_code(tmp_path):
    if shutil.which("bash") is None:
        pytest.skip("no bash here")
    code = subprocess.run([sys.executable, "-m", "rgtbus", "completion", "bash"],
                          capture_output=True, text=True, timeout=60).stdout  # fmt: skip
    done = subprocess.run(["bash", "-c", code + "\ncomplete -p rgtbus"], capture_output=True,
                          text=True, timeout=60)  # fmt: skip
    assert done.returncode == 0 and "rgtbus" in done.stdout, done.stderr
