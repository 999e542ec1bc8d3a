"""docs/api.md's examples run as written (in one namespace, in order, with ``LOGS`` a
temporary directory and ``SCENARIOS`` the repository's scenarios)."""

from __future__ import annotations

import re
from pathlib import Path

import matplotlib

ROOT = Path(__file__).resolve().parent.parent


def blocks() -> list[str]:
    text = (ROOT / "docs" / "api.md").read_text()
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_every_example_of_the_api_doc_runs(tmp_path):
    matplotlib.use("Agg")
    found = blocks()
    assert len(found) >= 5
    namespace = {"LOGS": tmp_path, "SCENARIOS": ROOT / "scenarios"}
    for code in found:
        exec(compile(code, "docs/api.md", "exec"), namespace)
    assert (tmp_path / "tug.mcap").exists() and (tmp_path / "gate.mcap").exists()


def test_every_public_name_has_an_example():
    import rgtbus

    text = "\n".join(blocks())
    for name in ("load_scenario", "run", "launch", "open_log", "sweep"):
        assert f"rgtbus.{name}(" in text, name
        assert name in rgtbus.__all__
