"""The documentation's examples are tests (issue 36, item 1): every ```python and ```sh block of
README.md and docs/*.md runs, in order, one namespace and one fresh directory a document
(``logs/`` there, and ``scenarios`` a link to the repository's), with ``LOGS`` that directory's
``logs/`` and ``SCENARIOS`` the repository's scenarios. Collected by Sybil
(sybil.readthedocs.io).

A shell block runs command by command (a line ending in a backslash goes on; a here-document is
part of its command) under bash with ``pipefail``, the installed ``rgtbus`` first on PATH, and
each must exit 0. Comment lines that begin ``#   `` right after a command are output it shows:
each must be a line of what the command printed, in that order (spaces between words as
wide as they like). Other comment lines are prose.

A block that cannot run here (it needs other machines, Foxglove, a cluster) says so in the
document, beside ``<!-- skip: next -->``, and has a test of its own; one that takes minutes
follows ``<!-- slow: why -->``, which marks it slow (the slow pass, CI, runs it)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import pytest
from sybil import Example, Sybil
from sybil.integration.pytest import SybilItem
from sybil.parsers.markdown import CodeBlockParser, PythonCodeBlockParser, SkipParser

ROOT = Path(__file__).resolve().parent


def _setup(namespace: dict[str, Any]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    tmp = Path(tempfile.mkdtemp(prefix="rgtbus-docs-"))
    (tmp / "logs").mkdir()
    namespace["_tmp"] = tmp
    namespace["_cwd"] = os.getcwd()
    (tmp / "scenarios").symlink_to(ROOT / "scenarios")  # as in a checkout: scenarios/gate.toml
    os.chdir(tmp)  # the examples write logs/... where they run
    namespace.update(LOGS=tmp / "logs", SCENARIOS=ROOT / "scenarios")


def _teardown(namespace: dict[str, Any]) -> None:
    os.chdir(namespace["_cwd"])
    shutil.rmtree(namespace["_tmp"], ignore_errors=True)


COMMAND_SECONDS = 900  # the longest command of a block (a shipped sweep on 2 cores: minutes)
_HEREDOC = re.compile(r"<<-?\s*'?\"?(\w+)'?\"?")
_SLOW = re.compile(r"<!--\s*slow:\s*(.+?)\s*-->\s*$")


def shell_commands(source: str) -> list[tuple[str, list[str]]]:
    """A shell block as its commands, each with the output lines it shows (see above)."""
    commands: list[tuple[str, list[str]]] = []
    lines = source.splitlines()
    i = 0
    shows = False  # the line before was a command or output it shows
    while i < len(lines):
        line = lines[i]
        i += 1
        if line.startswith("#   ") and shows:
            commands[-1][1].append(line[4:])
            continue
        shows = False
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        shows = True
        text = [line]
        while text[-1].endswith("\\") and i < len(lines):
            text.append(lines[i])
            i += 1
        heredoc = _HEREDOC.search(text[0])
        if heredoc:
            while i < len(lines):
                text.append(lines[i])
                i += 1
                if text[-1].strip() == heredoc.group(1):
                    break
        commands.append(("\n".join(text), []))
    return commands


def _words(line: str) -> str:
    return " ".join(line.split())


def run_shell_block(example: Example) -> str | None:
    """Run a shell block's commands where its document runs (``_setup``); None when every
    command exits 0 and prints what the block shows, else what went wrong."""
    cwd = example.namespace["_tmp"]
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    env["MPLBACKEND"] = "Agg"
    for command, shown in shell_commands(example.parsed):
        try:
            done = subprocess.run(
                ["bash", "-c", f"set -o pipefail\n{command}"], cwd=cwd, env=env,
                capture_output=True, text=True, timeout=COMMAND_SECONDS,
            )  # fmt: skip
        except subprocess.TimeoutExpired:
            return f"{command!r}: not done after {COMMAND_SECONDS} s"
        printed = done.stdout + done.stderr
        if done.returncode != 0:
            return f"{command!r} exited {done.returncode}:\n{printed[-3000:]}"
        got = [_words(line) for line in printed.splitlines()]
        at = 0
        for want in shown:
            try:
                at = got.index(_words(want), at) + 1
            except ValueError:
                return f"{command!r} did not print {want!r} (in order); it printed:\n{printed}"
    return None


@pytest.hookimpl(tryfirst=True)  # before -m picks the items by their marks
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A documentation example after ``<!-- slow: why -->`` is marked slow."""
    for item in items:
        if not isinstance(item, SybilItem):
            continue
        before = item.example.document.text[: item.example.start].rstrip().splitlines()
        if before and _SLOW.search(before[-1]):
            item.add_marker(pytest.mark.slow)


pytest_collect_file = Sybil(
    parsers=[
        PythonCodeBlockParser(),
        CodeBlockParser(language="sh", evaluator=run_shell_block),
        SkipParser(),
    ],
    patterns=["README.md", "docs/*.md"],
    excludes=["*/README.md"],  # the repository's own README only (not tests/hosts/README.md)
    path=str(ROOT),
    setup=_setup,
    teardown=_teardown,
).pytest()
