"""Every output readable (issue 13): ``rgtbus unit`` prints a decision as ``rgtbus run`` does,
through the one rule ``rgtbus.cli.run_cmd.decision_text``."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest
import rgtbus.units.process
from rgtbus.units.group import run_group

from rgtbus.cli import main
from rgtbus.cli.proc_cmds import free_ports
from rgtbus.cli.run_cmd import decision_text
from rgtbus.scenario import load_scenario
from rgtbus.telemetry import MemoryRecorder

ROOT = Path(__file__).parent.parent
EXAMPLE2 = ROOT / "scenarios" / "example2.toml"


@pytest.fixture(scope="module")
def example2():
    """example2 run on the memory bus, and the decision lines ``rgtbus run`` prints for it."""
    sc = load_scenario(EXAMPLE2)
    summary = run_group(sc, "memory", MemoryRecorder()).summary
    return sc, summary


def run_lines(capsys, sc, summary) -> dict[str, str]:
    """What ``rgtbus run``'s summary prints after each unit's canonical form, by unit (``run``
    pads the canonical forms to one column; ``unit`` prints one)."""
    from rgtbus.cli.run_cmd import print_summary

    print_summary(sc, {**summary, "log": "x"})
    text = capsys.readouterr().out
    block = text.split("decisions:\n")[1].split("outcome:")[0].split("decode errors")[0]
    lines = [line.strip() for line in block.splitlines() if line.strip()]
    out = {}
    for name in sc.units:
        canonical = summary["units"][name]["canonical"]
        line = next(x for x in lines if x.startswith(canonical))
        out[name] = f"{canonical}   {line[len(canonical) :].lstrip()}"
    return out


@pytest.mark.parametrize(
    ("fields", "expected"),
    [
        ({"decided": False, "frustrated": False}, "no decision"),
        ({"decided": True, "frustrated": True, "interval": None}, "frustrated: no decision"),
        (
            {"decided": True, "frustrated": False, "interval": [["alpha"], ["alpha"]]},
            "b = {alpha}        choice {alpha}",
        ),
        (
            {"decided": True, "frustrated": False, "interval": [[], ["alpha", "beta"]]},
            "1 ⊇ b ⊇ 0          choice {alpha}",
        ),
    ],
)
def test_decision_text_uses_set_notation(fields, expected):
    u = load_scenario(EXAMPLE2).universe
    v = {"choice": ["alpha"], "canonical": "b = b", **fields}
    assert decision_text(u, "b", v) == expected


def test_unit_prints_the_decision_line_of_run(example2, capsys, monkeypatch, tmp_path):
    """``rgtbus unit``'s own code path, its zenoh run replaced by the memory run's report."""
    sc, summary = example2
    expected = run_lines(capsys, sc, summary)
    previous = signal.getsignal(signal.SIGTERM)  # run_unit_cmd installs its own handler
    try:
        for name in sc.units:
            result = {
                "report": {"result": summary["units"][name], "polynomial": "a+bc", "p4": None},
                "steps": 1,
                "sim_seconds": 76.0,
                "wall_seconds": 0.1,
                "error": None,
            }
            monkeypatch.setattr(rgtbus.units.process, "run_unit", lambda *a, _r=result, **k: _r)
            code = main(["unit", name, str(EXAMPLE2), "--log", str(tmp_path / f"{name}.mcap")])
            text = capsys.readouterr().out
            assert code == 0
            first, second = text.splitlines()
            assert first == f"unit {name}: {expected[name]}"
            assert second.startswith("  polynomial a+bc; 1 steps")
            assert "['" not in text and "[[" not in text and "None" not in text
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_unit_over_zenoh_prints_like_run(example2, capsys, procs, tmp_path):
    """Three ``rgtbus unit`` processes on loopback: each prints run's decision line."""
    sc, summary = example2
    expected = run_lines(capsys, sc, summary)
    ports = free_ports(len(sc.units))
    started = {}
    for i, name in enumerate(sc.units):
        net = ["--listen", f"tcp/127.0.0.1:{ports[i]}"]
        for j in range(i):
            net += ["--connect", f"tcp/127.0.0.1:{ports[j]}"]
        started[name] = procs(
            "unit", name, str(EXAMPLE2), *net, "--log", str(tmp_path / f"{name}.mcap"),
            "--run-id", "outputs",
        )  # fmt: skip
    for name, p in started.items():
        out, err = p.communicate(timeout=120)
        assert p.returncode == 0, err
        assert out.splitlines()[0] == f"unit {name}: {expected[name]}"
        assert "['" not in out and "[[" not in out, out
