"""The core without its extras: what needs matplotlib (``rgtbus[plot]``), Dask's distributed
(``rgtbus[dask]``), cryptography (``rgtbus[tls]``) or pyarrow (``rgtbus[parquet]``) says
which extra, in one line, exit 2; the rest runs (a sweep without pyarrow: its JSON Lines and
CSV tables, no Parquet)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
# a process that cannot import the extras, as a venv without them
_CORE = (
    "import sys\n"
    "for m in ('matplotlib', 'distributed', 'dask', 'cryptography', 'pyarrow'):\n"
    "    sys.modules[m] = None\n"
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
    done = _core("sweep", str(sweep), "--out", "s", "--workers", "2", "--quiet", cwd=where)
    assert done.returncode == 0, done.stderr
    assert "pip install 'rgtbus[parquet]'" in done.stderr  # said once: no Parquet
    written = sorted(p.name for p in (where / "s").iterdir() if "." in p.name[1:])
    assert [n for n in written if n.endswith(".parquet")] == []
    assert {"results.jsonl", "decisions.jsonl", "results.csv", "columns.json"} <= set(written)
    assert "results.jsonl" in done.stdout and "results.parquet" not in done.stdout
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
        "import sys\n"
        "for m in ('matplotlib', 'distributed', 'pyarrow'): sys.modules[m] = None\n"
        "import rgtbus\n"
        "log = rgtbus.open_log('gate.mcap'); assert len(log.decisions()) > 0\n"
        "from rgtbus.telemetry.sweep_read import read_sweep\n"
        "results, decisions = read_sweep('s')\n"
        "assert len(results) == 2 and len(decisions) > 0\n"
        "assert results['n'].dtype == 'int64' and results.groupby('relations').size().sum() == 2\n"
        f"df = rgtbus.sweep({str(ROOT / 'scenarios' / 'random_group.toml')!r}, grid={{'n': [3]}},\n"
        "                  seeds=2, workers=2)\n"
        "assert df.drop(columns=['wall_seconds', 'sweep', 'run_id']).equals(\n"
        "    results.drop(columns=['wall_seconds', 'sweep', 'run_id']))\n"
        "assert 'pyarrow' not in {k for k, v in sys.modules.items() if v is not None}\n"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=core_run, capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr


@pytest.mark.slow
def test_a_sweep_rewritten_without_pyarrow_leaves_no_stale_parquet(core_run):
    """A sweep written with pyarrow, then resumed where pyarrow is missing: its Parquet
    tables (which would no longer match the JSON Lines) are gone, the rest written anew."""
    from rgtbus.cli import main

    out = core_run / "p"
    assert main(["sweep", str(core_run / "s.toml"), "--out", str(out), "--workers", "1",
                 "--quiet"]) == 0  # fmt: skip
    assert (out / "results.parquet").is_file() and (out / "decisions.parquet").is_file()
    done = _core("sweep", "s.toml", "--out", "p", "--resume", "--workers", "1", "--quiet",
                 cwd=core_run)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert not (out / "results.parquet").exists() and not (out / "decisions.parquet").exists()
    assert len((out / "results.jsonl").read_text().splitlines()) == 2
