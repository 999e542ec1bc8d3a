"""The concurrent schedule (docs/protocol.md): rounds of n codes at once, one per channel, with
the same tables and decisions as the serial schedule in a fraction of the simulated time."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import pytest
from rgtbus.units.group import run_group

from rgtbus.errors import RgtbusError
from rgtbus.protocol import PHASES, plan_of, rounds
from rgtbus.scenario import parse_scenario
from rgtbus.telemetry import MemoryRecorder

ROOT = Path(__file__).parent.parent
RESULT_KEYS = ("polynomial", "relations", "agree", "influences", "units", "outcome", "error")


def group(n: int, schedule: str, seed: int = 1, extra: str = "") -> str:
    names = [f"u{i}" for i in range(n)]
    head = f'name = "g{n}"\nseed = {seed}\nunits = {json.dumps(names)}\n'
    head += 'actions = ["alpha", "beta"]\n'
    head += 'codebook = { kind = "generated", pulses = 4 }\nfrequencies = "auto"\n'
    return (
        head
        + f'[protocol]\nschedule = "{schedule}"\n'
        + '[relations]\npolicy = "cograph"\n'
        + '[influences]\npolicy = "random"\n'
        + extra
    )


@pytest.mark.parametrize("n", [2, 3, 4, 7, 10])
def test_rounds_cover_every_pair_once_and_each_channel_once_a_round(n):
    units = [f"u{i}" for i in range(n)]
    rs = rounds(units)
    assert len(rs) == 2 * (n - 1)
    pairs = {p: [] for p in PHASES}
    for rnd in rs:
        assert sorted(t.sender for t in rnd) == sorted(units)  # everyone sends once
        assert sorted(t.addressee for t in rnd) == sorted(units)  # everyone addressed once
        assert all(t.sender != t.addressee for t in rnd)
        for t in rnd:
            pairs[t.phase].append((t.sender, t.addressee))
    for p in PHASES:
        assert sorted(pairs[p]) == sorted(itertools.permutations(units, 2))
    assert [t.index for rnd in rs for t in rnd] == list(range(2 * n * (n - 1)))
    # relations first: the replay's phase rule (index < n(n-1)) holds
    assert all(t.phase == "relations" for rnd in rs[: n - 1] for t in rnd)


@pytest.mark.parametrize("n", [4, 10, 24])
def test_every_round_uses_each_sample_once_and_payloads_follow_every_id(n):
    units = tuple(f"u{i}" for i in range(n))
    omegas = tuple((u, 2.0 + 0.05 * i) for i, u in enumerate(units))
    plan = plan_of(units, omegas, 0.005, 4, 0.5, 0.5, 2, "concurrent", 0.001)
    prev_end = -math.inf
    for rnd in plan.timing():
        assert rnd.start >= prev_end - 1e-9  # rounds never overlap: the guard lies between
        samples = [k for p in rnd.placed for k in (*p.id_samples, *p.payload_samples)]
        assert len(samples) == len(set(samples))  # no two pulses ever add on the medium
        last_id = max(p.id_samples[-1] for p in rnd.placed)
        assert all(p.payload_samples[0] > last_id for p in rnd.placed)
        assert all(p.payload_start >= last_id * 0.005 + 0.5 - 1e-9 for p in rnd.placed)
        prev_end = rnd.end + 0.5


@pytest.mark.parametrize("n", [3, 7, 16])
def test_each_code_takes_the_first_free_shift_as_the_literal_search_finds_it(n):
    """``place_rounds`` screens shifts in blocks and goes on from the last shift a code of the
    same start and ω took: every code still gets the first shift j >= 0 whose exact instants
    are distinct and free, in the order IDs, then payloads (the literal search, here)."""
    from rgtbus.protocol import MAX_STAGGER, code_samples

    units = tuple(f"u{i}" for i in range(n))
    omegas = tuple((u, 2.0 + 0.37 * ((i * 7) % n)) for i, u in enumerate(units))
    plan = plan_of(units, omegas, 0.005, 4, 0.5, 0.5, 2, "concurrent", 0.001)
    tau = 0.005
    for rnd in plan.timing():
        used: set[int] = set()

        def first_free(start, omega, used=used):
            for j in range(MAX_STAGGER + 1):
                got = code_samples(start + j * tau, omega, 4, tau)
                if len(set(got)) == len(got) and not used & set(got):
                    used.update(got)
                    return start + j * tau, got
            raise AssertionError("no free shift")

        om = dict(omegas)
        ids = [first_free(rnd.start, om[p.turn.sender]) for p in rnd.placed]
        assert [(p.id_start, p.id_samples) for p in rnd.placed] == ids
        at = max(s[-1] for _, s in ids) * tau + 0.5
        for p in rnd.placed:
            assert (p.payload_start, p.payload_samples) == first_free(at, om[p.turn.addressee])


@pytest.mark.parametrize(("n", "seed"), [(4, 1), (4, 2), (6, 1), (6, 3), (10, 5)])
def test_concurrent_and_serial_reach_the_same_tables_and_decisions(n, seed):
    serial = run_group(parse_scenario(group(n, "serial", seed)), "memory", MemoryRecorder())
    conc = run_group(parse_scenario(group(n, "concurrent", seed)), "memory", MemoryRecorder())
    a, b = serial.summary, conc.summary
    assert (
        a["error"] is None
        and a["decode_errors"]["misread"] == 0
        and b["decode_errors"]["misread"] == 0
    )
    assert {k: a[k] for k in RESULT_KEYS} == {k: b[k] for k in RESULT_KEYS}
    if n == 10:  # the point of it: O(n) rounds instead of O(n^2) turns
        assert a["sim_seconds"] / b["sim_seconds"] >= 5


def test_the_gate_concurrent_checks_its_expectations_and_replays():
    text = (ROOT / "scenarios" / "gate.toml").read_text()
    sc = parse_scenario(text.replace("[timing]", '[protocol]\nschedule = "concurrent"\n[timing]'))
    rec = MemoryRecorder()
    out = run_group(sc, "memory", rec).summary
    assert out["outcome"] == "gate: open" and out["error"] is None
    assert out["sim_seconds"] < 50  # 6 rounds instead of 24 turns (162 s serial)


@pytest.mark.parametrize(
    ("edit", "pattern"),
    [
        ('[protocol]\nschedule = "parallel"', r"protocol\.schedule: unknown schedule 'parallel'"),
        ('[protocol]\nschedule = "concurrent"\nslots = 3', r"protocol\.slots: unknown key"),
        (
            '[protocol]\nschedule = "concurrent"\n[timing]\nanchor = "spike"',
            r'timing\.anchor: .spike. with the concurrent schedule: .* use anchor = "schedule"',
        ),
    ],
)
def test_schedule_mistakes_are_refused_by_key(edit, pattern):
    text = group(4, "serial").replace('[protocol]\nschedule = "serial"\n', edit + "\n")
    with pytest.raises(RgtbusError, match=pattern):
        parse_scenario(text)


@pytest.mark.slow
def test_two_hundred_units_are_placed_without_a_shared_sample():
    """The plan's upper end: the 200th ID starts ~640 samples late (beyond the old 512 limit)."""
    from rgtbus.signal.plan import make_plan

    units = tuple(f"u{i}" for i in range(200))
    p = make_plan(200, schedule="concurrent", crosstalk=False)
    plan = plan_of(units, tuple(zip(units, p.omegas, strict=True)), 0.005, 3, 0.5, 0.5, 2,
                   "concurrent", 0.001)  # fmt: skip
    for rnd in plan.timing()[:3]:
        samples = [k for q in rnd.placed for k in (*q.id_samples, *q.payload_samples)]
        assert len(samples) == len(set(samples))


@pytest.mark.parametrize("omega", [0.5, 0.3])
def test_slow_channels_codes_of_tens_of_seconds_are_read_whole(omega):
    """A unit keeps its readout for its longest code as well as for how late a code may be
    read (the concurrent schedule's, as the ears hear them whole: up to 10 s): channels of
    0.3 rad/s make 3-pulse codes of 42 s, and every one is read, none refused as outside
    the history."""
    from rgtbus.telemetry import NullRecorder

    text = f"""name = "slow"
seed = 3
units = ["a", "b", "c"]
actions = ["alpha", "beta"]
frequencies = {{ a = {omega}, b = {omega * 1.1:.4f}, c = {omega * 1.21:.4f} }}
[protocol]
schedule = "concurrent"
[relations]
policy = "random"
[influences]
policy = "random"
"""
    s = run_group(parse_scenario(text, "slow.toml"), "memory", NullRecorder()).summary
    assert s["error"] is None and s["decode_errors"]["misread"] == 0
