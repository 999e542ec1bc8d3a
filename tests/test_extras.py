"""The core without its extras: what needs matplotlib (``rgtbus[plot]``), Dask's distributed
(``rgtbus[dask]``) or cryptography (``rgtbus[tls]``) says which extra, in one line, exit 2;
the rest runs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
# a process that cannot import the extras, as a venv without them
_CORE = (
    "import sys\n"
    "for m in ('matplotlib', 'distributed', 'dask', 'cryptography'): sys.modules[m] = None\n"
    "from rgtbus.cli import main\n"
    "sys.exit(main(sys.argv[1:]))\n"
)


def _core(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", _CORE, *args], cwd=cwd, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip


@pytest.fixture(scope="module")
def core_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A gate run, a log and a small local sweep, all without the extras."""
    where = tmp_path_factory.mktemp("core")
    done = _core("run", "gate", "--bus", "memory", "--log", "gate.mcap", "--check", cwd=where)
    assert done.returncode == 0, done.stderr
    sweep = where / "s.toml"
    sweep.write_text(
        f'name = "s"\nscenario = "{ROOT / "scenarios" / "random_group.toml"}"\nseeds = "0..1"\n'
        '[grid]\nn = [3]\n'
    )
    done = _core("sweep", str(sweep), "--out", "s", "--workers", "1", "--quiet", cwd=where)
    assert done.returncode == 0, done.stderr
    return where


@pytest.mark.parametrize(
    ("args", "extra"),
    [
        (["replay", "gate.mcap", "--plot", "a.png"], "plot"),
        (["resonate", "--on", "0", "--plot", "y.png"], "plot"),
        (["ser", "--sigma", "0.1", "--trials", "10", "--plot", "s.png"], "plot"),
        (["figures", "figs"], "plot"),
        (["sweep-plot", "s", "--x", "n", "--y", "failed"], "plot"),
        (["sweep", "s.toml", "--out", "s2", "--scheduler", "tcp://127.0.0.1:9"], "dask"),
        (["certs", "gate", "--out", "ids"], "tls"),
        (["launch", "gate", "--tls", "ids"], "tls"),
        (["unit", "a", "gate", "--tls", "ids"], "tls"),
    ],
)
def test_what_needs_an_extra_names_it_in_one_line(core_run, args, extra):
    done = _core(*args, cwd=core_run)
    assert done.returncode == 2, done.stderr
    err = done.stderr.strip()
    assert f"pip install 'rgtbus[{extra}]'" in err and "\n" not in err, err


def test_the_core_reads_its_logs_and_sweeps_without_the_extras(core_run):
    for args in (["info", "gate.mcap"], ["replay", "gate.mcap", "--verify", "--quiet"]):
        done = _core(*args, cwd=core_run)
        assert done.returncode == 0, (args, done.stderr)
    code = (
        "import sys; sys.modules['matplotlib'] = sys.modules['distributed'] = None\n"
        "import rgtbus\n"
        "log = rgtbus.open_log('gate.mcap'); assert len(log.decisions()) > 0\n"
        "from rgtbus.telemetry.sweep_tables import read_sweep\n"
        "assert len(read_sweep('s').results) == 2\n"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=core_run, capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
