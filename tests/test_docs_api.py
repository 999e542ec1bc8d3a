"""docs/api.md names every public function of the library in an example. Its examples (and
every other ```python block of README.md and docs/) run as tests through Sybil: conftest.py at
the repository's root."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_every_public_name_has_an_example():
    import rgtbus

    text = (ROOT / "docs" / "api.md").read_text()
    for name in ("load_scenario", "run", "launch", "open_log", "sweep"):
        assert f"rgtbus.{name}(" in text, name
        assert name in rgtbus.__all__


def test_the_documents_examples_are_collected():
    """Sybil collects README.md and docs/*.md (pytest's testpaths): a document whose blocks
    stopped being collected would pass unseen."""
    import tomllib

    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]
    assert {"README.md", "docs"} <= set(config["ini_options"]["testpaths"])
    assert (ROOT / "conftest.py").read_text().count("PythonCodeBlockParser") >= 1
