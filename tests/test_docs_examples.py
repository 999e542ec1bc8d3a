"""The runner of the documentation's shell examples (conftest.py at the repository's root):
what it takes from a block, and that a block whose output or exit drifts from the code fails."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

ROOT = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("docs_conftest", ROOT / "conftest.py")
assert _spec is not None and _spec.loader is not None
docs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(docs)


def test_a_block_is_its_commands_each_with_the_output_it_shows():
    block = (
        "# prose: not a command\n"
        "rgtbus solve 'a' \\\n"
        "    --actions x   # goes on\n"
        "#   line one\n"
        "#   line  two\n"
        "\n"
        "#   after a blank line: prose\n"
        "cat > f.json5 <<'EOF'\n"
        "{ mode: 1 }\n"
        "EOF\n"
        "echo done\n"
    )
    got = docs.shell_commands(block)
    assert got == [
        ("rgtbus solve 'a' \\\n    --actions x   # goes on", ["line one", "line  two"]),
        ("cat > f.json5 <<'EOF'\n{ mode: 1 }\nEOF", []),
        ("echo done", []),
    ]


def _run(block: str, tmp_path: Path) -> str | None:
    example = SimpleNamespace(parsed=block, namespace={"_tmp": tmp_path})
    return docs.run_shell_block(example)


def test_a_block_passes_only_when_it_prints_what_it_shows_and_exits_0(tmp_path):
    assert _run("printf 'a  b\\nc\\n'\n#   a b\n#   c\n", tmp_path) is None
    wrong = _run("printf 'a\\nc\\n'\n#   c\n#   a\n", tmp_path)  # out of order
    assert wrong is not None and "did not print 'a'" in wrong
    failed = _run("true\nfalse\necho never\n", tmp_path)
    assert failed is not None and "'false' exited 1" in failed
    piped = _run("yes | false | cat\n", tmp_path)  # pipefail: a failure inside a pipe counts
    assert piped is not None and "exited 1" in piped
    # rgtbus is the installed one, run where the document runs
    block = "rgtbus --version\ncat > x.txt <<'EOF'\nhi\nEOF\ncat x.txt\n#   hi\n"
    assert _run(block, tmp_path) is None
    assert (tmp_path / "x.txt").read_text() == "hi\n"


def test_every_block_of_the_docs_is_run_or_is_data():
    """A block the documentation's tests would not run must say what it is: python and sh
    blocks run; toml, json, text and sql blocks are data (a block with no language, or with
    another, such as bash or console, would be left out silently)."""
    import re

    runs, data = {"python", "sh"}, {"toml", "json", "text", "sql"}
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = path.read_text(encoding="utf-8")
        for m in re.finditer(r"^```(\S*)\n.*?^```\s*$", text, re.M | re.S):
            line = text[: m.start()].count("\n") + 1
            assert m.group(1) in runs | data, f"{path.name}:{line}: a ```{m.group(1)} block"
