"""The permission probe (once a session) and the wall-time table of tests/hosts."""

from __future__ import annotations

import json
import os
import time

import pytest

from hosts import netns

# check -> the clean check its wall time is compared with (same tls)
BASELINE = {"tbf": "gate", "relay": "gate", "link-flap": "gate-paced"}
WALLS: list[dict] = []  # {"check", "tls", "wall_s", "unit_s", "link_kb", ...}: a run each
OUT = netns.ROOT / "logs" / "hosts-walls.json"


@pytest.fixture(scope="session")
def hosts_permitted() -> None:
    """Skip, in one line, where this process may not make network namespaces."""
    why = netns.probe()
    if why is not None:
        pytest.skip(f"network namespaces not permitted here: {why}")


@pytest.fixture
def record_wall():
    """``record(check, tls, run)``: a run's wall time (and the bytes over its links), for the
    table at the end."""

    def record(check: str, tls: bool, run, **more) -> None:
        kb = round(run.link_bytes / 1000, 1)
        unit_s = max(out["wall_seconds"] for out in run.outs.values())
        row = {"check": check, "tls": tls, "wall_s": round(run.wall, 2), "unit_s": unit_s,
               "link_kb": kb}  # fmt: skip
        WALLS.append({**row, **more})

    return record


def table() -> list[dict]:
    """Each run with its ratios to the clean run of its baseline (same tls): ``vs_clean`` of
    the wall times, ``unit_vs_clean`` of the units' own."""
    rows = []
    for row in WALLS:
        base = BASELINE.get(row["check"])
        ref = next((r for r in WALLS if r["check"] == base and r["tls"] == row["tls"]), None)
        ratios = {"vs_clean": None, "unit_vs_clean": None}
        if ref is not None:
            ratios["vs_clean"] = round(row["wall_s"] / ref["wall_s"], 2)
            ratios["unit_vs_clean"] = round(row["unit_s"] / ref["unit_s"], 2)
        rows.append({**row, "baseline": base, **ratios})
    return rows


def pytest_terminal_summary(terminalreporter) -> None:
    if not WALLS:
        return
    rows = table()
    tr = terminalreporter
    tr.section("tests/hosts: the wall time of each run")
    head = f"{'check':<11} {'tls':<5} {'wall s':>6}  {'vs clean':<18} {'unit s':>6} {'vs':>6}"
    tr.write_line(f"{head} {'link kB':>8}")
    for r in rows:
        vs, unit_vs = "-", "-"
        if r["vs_clean"] is not None:
            vs, unit_vs = f"{r['vs_clean']:.2f}x {r['baseline']}", f"{r['unit_vs_clean']:.2f}x"
        cells = f"{r['check']:<11} {r['tls']!s:<5} {r['wall_s']:>6.2f}  {vs:<18}"
        tr.write_line(f"{cells} {r['unit_s']:>6.2f} {unit_vs:>6} {r['link_kb']:>8}")
    tr.write_line(
        "wall s: the first unit's start to the last one's end; unit s: the longest a unit "
        "process says it ran (its session, join and run: no interpreter start); vs: the clean "
        "run's (same tls); link kB: both ways over every host's link"
    )
    record = {
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "cpus": os.cpu_count(),
        "loadavg": os.getloadavg(),
        "rows": rows,
    }
    try:
        OUT.parent.mkdir(exist_ok=True)
        OUT.write_text(json.dumps(record, indent=1) + "\n")
        tr.write_line(f"written to {OUT}")
    except OSError as exc:
        tr.write_line(f"not written to {OUT}: {exc}")
