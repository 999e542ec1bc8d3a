"""The documentation's Python examples are tests (issue 36, item 1): every ```python block of
README.md and docs/*.md runs, in order, one namespace a document, in a fresh directory (``logs/``
there), with ``LOGS`` that directory's ``logs/`` and ``SCENARIOS`` the repository's scenarios.
A block that cannot run here says so in the document (``<!-- skip: next -->`` with the reason
beside it) and has a test of its own. Collected by Sybil (sybil.readthedocs.io)."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from sybil import Sybil
from sybil.parsers.markdown import PythonCodeBlockParser, SkipParser

ROOT = Path(__file__).resolve().parent


def _setup(namespace: dict[str, Any]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    tmp = Path(tempfile.mkdtemp(prefix="rgtbus-docs-"))
    (tmp / "logs").mkdir()
    namespace["_tmp"] = tmp
    namespace["_cwd"] = os.getcwd()
    os.chdir(tmp)  # the examples write logs/... where they run
    namespace.update(LOGS=tmp / "logs", SCENARIOS=ROOT / "scenarios")


def _teardown(namespace: dict[str, Any]) -> None:
    os.chdir(namespace["_cwd"])
    shutil.rmtree(namespace["_tmp"], ignore_errors=True)


pytest_collect_file = Sybil(
    parsers=[PythonCodeBlockParser(), SkipParser()],
    patterns=["README.md", "docs/*.md"],
    path=str(ROOT),
    setup=_setup,
    teardown=_teardown,
).pytest()
