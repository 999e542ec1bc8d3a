"""The event engine and the time-stepped reference give identical runs.

Every shipped scenario and random groups (noisy, with link gains, with failing units) run on both
engines; every logged message must be the same — pulses, spikes (sample index), decodes, tables,
decisions, log lines and the medium — and so must the summary, and the summary of the same run
without a log (whose units decode in batches, and whose ears may walk no resonator).
"""

from __future__ import annotations

import json
import random
from pathlib import Path

import pytest
from rgtbus.units.group import run_group
from same_run import plain

from rgtbus.scenario import Scenario, load_scenario, parse_scenario
from rgtbus.telemetry import MemoryRecorder, NullRecorder
from rgtbus.telemetry.record_rows import spikes_per_unit

ROOT = Path(__file__).parent.parent
# The dense engine walks every window of every unit: a reference for groups of up to 12 (the
# large concurrent groups are checked against the forward task in tests/test_scale.py).
SCENARIOS = sorted(
    p.stem for p in (ROOT / "scenarios").glob("*.toml") if len(load_scenario(p).units) <= 12
)
# ten units over the dense engine take ~10 s each, six units 4 s; the robots are held to both
# engines (and verified) in tests/test_channel.py: CI's slow pass
SLOW_SCENARIOS = ("coalition10", "crowd10", "group6", "robots_on_a_plane")
NOT_RESULTS = ("wall_seconds", "engine", "steps", "bus", "sync")


def run(sc: Scenario, engine: str):
    rec = MemoryRecorder()
    out = run_group(sc, "memory", rec, engine=engine)
    return out.summary, rec.read()[0]


def _json(m) -> str:
    """A record as JSON (a block's columns as lists): records compare by it."""
    return json.dumps(m, sort_keys=True, default=plain)


def content(messages):
    """The log's content, order-free among messages of the same time; a block of spikes
    units shared as each unit's own (the dense engine's ears are a unit's own)."""
    return sorted((ns, t, _json(m)) for t, ns, m in spikes_per_unit(messages))


def assert_same_run(sc: Scenario):
    event, ev_msgs = run(sc, "event")
    dense, de_msgs = run(sc, "dense")
    # and without a log: no spike logged (no walk when none is awaited), decodes in batches
    bare = run_group(sc, "memory", NullRecorder()).summary
    for other in (dense, bare):
        assert {k: v for k, v in event.items() if k not in NOT_RESULTS} == {
            k: v for k, v in other.items() if k not in NOT_RESULTS
        }
    a, b = content(ev_msgs), content(de_msgs)
    if a != b:  # name the first difference, not a wall of JSON
        first = next(i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y)
        raise AssertionError(f"logs differ at message {first}: {a[first]} != {b[first]}")
    assert len(a) == len(b)
    topics = {t for _, t, _ in a}
    assert {"/tx/pulse", "/rx/spike", "/rx/decodes", "/medium", "/run"} <= topics
    return event


@pytest.mark.parametrize(
    "name",
    [pytest.param(n, marks=pytest.mark.slow) if n in SLOW_SCENARIOS else n for n in SCENARIOS],
)
def test_every_scenario_is_the_same_on_both_engines(name):
    assert_same_run(load_scenario(ROOT / "scenarios" / f"{name}.toml"))


def random_group(seed: int, *, noise: float = 0.0, gains: bool = False, anchor: str = "spike"):
    """A few units with other names, random relationships and influences, a seed of its own.
    ``anchor`` "threshold": the spike anchor with the paper's threshold attention."""
    attention = "threshold" if anchor == "threshold" else "confirmed"
    anchor = "spike" if anchor == "threshold" else anchor
    rng = random.Random(seed)
    n = rng.choice([3, 4])
    names = rng.sample(["ann", "bob", "cy", "dee", "eve", "fox", "gus"], n)
    lines = [
        f'name = "random{seed}"',
        f"seed = {seed}",
        f"units = {json.dumps(names)}",
        'actions = ["go", "stay"]',
        'frequencies = "auto"',
        "[timing]",
        f'anchor = "{anchor}"',
        f'attention = "{attention}"',
        "[channel]",
        f"noise = {noise}",
    ]
    if gains:
        lines.append("[channel.gain]")
        for s in names:
            for r in names:
                if s != r and rng.random() < 0.5:
                    lines.append(f'"{s}>{r}" = {rng.uniform(0.9, 1.1):.4f}')
    lines += ["[relations]", 'policy = "random"', "p = 0.61", "[influences]"]
    alts = ["0", "1", "{go}", "{stay}"]
    for s in names:
        for r in names:
            if s != r:
                lines.append(f'"{s}>{r}" = "{rng.choice(alts)}"')
    lines += ["[decision]", 'policy = "seeded-random"']
    return parse_scenario("\n".join(lines) + "\n", f"<random{seed}>")


@pytest.mark.parametrize(
    "seed, noise, gains, anchor",
    [
        (1, 0.0, False, "threshold"),
        (2, 0.0, True, "threshold"),
        (3, 0.002, False, "threshold"),
        (4, 0.002, True, "threshold"),
        (5, 0.03, True, "schedule"),
        (6, 0.02, False, "threshold"),  # attention spikes break at once: every unit fails
        (11, 0.004, True, "threshold"),  # one unit fails in turn 10, the others go on
        (12, 0.006, True, "threshold"),  # IDs misread: decode errors, a unit fails in turn 3
        # confirmed attention (the spike anchor's default): where the threshold's fail, clean
        (6, 0.02, False, "spike"),
        pytest.param(13, 0.04, True, "spike", marks=pytest.mark.slow),
        (14, 0.0, True, "spike"),
        pytest.param(15, 0.1, False, "spike", marks=pytest.mark.slow),  # IDs misread among
        # all words, yet found against silence
        (16, 0.3, False, "spike"),  # an ID is not found: the unit fails
    ],
)
def test_random_groups_are_the_same_on_both_engines(seed, noise, gains, anchor):
    s = assert_same_run(random_group(seed, noise=noise, gains=gains, anchor=anchor))
    if anchor == "spike":  # confirmed attention: clean where the ID reads as the ID-code
        assert (s["error"] is None) is (noise < 0.3), s["error"]
        if s["error"]:
            assert "no ID heard" in s["error"]
        return
    if seed in (6, 11, 12):  # failing units are covered, not only clean runs
        assert s["error"]
    if seed == 11:
        assert "turn 10" in s["error"] and s["sim_seconds"] > 100  # the others went on
    if seed == 12:
        assert s["decode_errors"]["misread"]


@pytest.mark.parametrize("engine", ["event", "dense"])
def test_replay_verifies_and_plots_either_engines_log(engine, tmp_path, capsys):
    from rgtbus.cli import main

    log = tmp_path / f"{engine}.mcap"
    scenario = str(ROOT / "scenarios" / "example2.toml")
    argv = ["run", scenario, "--bus", "memory", "--engine", engine, "--log", str(log), "--quiet"]
    assert main(argv) == 0
    capsys.readouterr()
    assert main(["replay", str(log), "--verify"]) == 0
    assert "verified:" in capsys.readouterr().out
    png = tmp_path / "p.png"
    assert main(["replay", str(log), "--plot", str(png), "--unit", "b"]) == 0
    assert png.stat().st_size > 10_000


@pytest.mark.parametrize("seed", [21, 22, 23, 24])
def test_promises_hold_however_frames_arrive(seed):
    """Over zenoh a unit's own frames come back late, so rounds fall differently than on the
    memory bus; every promise must still hold (the bus refuses one that goes back or is
    broken) and the run is the same."""
    sc = random_group(seed, noise=0.002 * (seed % 2), gains=seed % 2 == 0)
    mem = MemoryRecorder()
    zen = MemoryRecorder()
    a = run_group(sc, "memory", mem).summary
    b = run_group(sc, "zenoh", zen).summary
    assert {k: v for k, v in a.items() if k not in NOT_RESULTS} == {
        k: v for k, v in b.items() if k not in NOT_RESULTS
    }
    assert content(mem.read()[0]) == content(zen.read()[0])


@pytest.mark.parametrize(
    ("source", "noise", "gains"),
    [("crowd10", None, None), ("gate_noisy", None, None), (7, 0.0, True), (8, 0.01, True)],
)
def test_a_run_that_walks_no_resonator_is_the_same_run(monkeypatch, source, noise, gains):
    """Timed by the schedule and without a log, no unit awaits or logs a spike, so the event
    engine's ears never walk a resonator (the readout a decode needs is the input itself):
    the run's summary is the logged run's (which the dense reference's equals: above), and
    no walk happened."""
    from rgtbus.signal.resonator import ResonatorBank

    if isinstance(source, str):
        sc = load_scenario(ROOT / "scenarios" / f"{source}.toml")
    else:
        sc = random_group(source, noise=noise, gains=gains, anchor="schedule")
    assert sc.timing.anchor == "schedule"
    logged, _ = run(sc, "event")
    walks = []
    real = ResonatorBank.advance
    monkeypatch.setattr(
        ResonatorBank, "advance", lambda self, *a, **k: walks.append(1) or real(self, *a, **k)
    )
    bare = run_group(sc, "memory", NullRecorder()).summary
    assert walks == []
    assert {k: v for k, v in bare.items() if k not in NOT_RESULTS} == {
        k: v for k, v in logged.items() if k not in NOT_RESULTS
    }
    assert bare["decisions"] and (not bare["error"] or noise)


def _unit_rows(messages, tau):
    """A log's unit records as comparable rows (topic, log time, JSON), decodes, spikes and
    pulses one a row: what a cut log must hold in full before its bound."""
    from rgtbus.telemetry.record_rows import decodes_per_row, pulses_per_row, spikes_per_sample

    skip = {"/log", "/medium", "/run", "/unit/report"}
    rows = spikes_per_sample(pulses_per_row(decodes_per_row(messages)), tau)
    return [(tp, t, _json(m)) for tp, t, m in rows if tp not in skip]


@pytest.mark.parametrize(
    "seed, noise, schedule",
    [(5, 0.03, "serial"), (7, 0.0, "concurrent"), (8, 0.01, "concurrent"), (11, 0.004, "serial")],
)
def test_a_log_cut_anywhere_is_complete_before_its_bound(seed, noise, schedule):
    """A logged unit's decodes go out a batch a wake, behind the clock, with the spike blocks
    held for that wake, while its pulses go out on time from a process of their own; the
    group's records of pulses and decodes once every unit is past their block: each unit's
    own records still leave in time order, and a log cut after any write holds every unit
    record before ``Replay.units_until_ns`` (what --verify compares)."""
    import dataclasses

    from rgtbus.telemetry.read import Replay
    from rgtbus.telemetry.recorder import LogContents

    sc = random_group(seed, noise=noise, gains=True, anchor="schedule")
    sc = dataclasses.replace(sc, protocol=dataclasses.replace(sc.protocol, schedule=schedule))
    rec = MemoryRecorder()
    run_group(sc, "memory", rec)
    written = rec.messages  # in the order they were written
    per_unit: dict[str, int] = {}
    for tp, t, m in written:
        if tp in ("/unit/relations", "/unit/influences", "/unit/decision"):
            assert t >= per_unit.get(m["unit"], 0), (tp, t, m["unit"])
            per_unit[m["unit"]] = t
    if schedule == "concurrent":  # no spike awaited: decodes of different times share a wake
        assert any(len(set(m["times"])) > 1 for tp, _, m in written if tp == "/rx/decodes")
    meta = {k: dict(v) for k, v in rec.metadata_records.items()}
    whole = _unit_rows(written, sc.timing.tau)
    for cut in range(0, len(written), max(1, len(written) // 40)):
        kept = sorted(written[:cut], key=lambda x: x[1])
        bound = Replay(LogContents(kept, meta, truncated=True)).units_until_ns() or 0
        want = sorted(r for r in whole if r[1] < bound)
        got = sorted(r for r in _unit_rows(kept, sc.timing.tau) if r[1] < bound)
        assert got == want, f"cut after {cut} of {len(written)} writes, bound {bound}"


@pytest.mark.parametrize("seed, noise", [(5, 0.0), (9, 0.01), (12, 0.004)])
def test_a_unit_that_batches_logs_what_it_logs_waking_for_each_decode(seed, noise):
    """A batching unit learns it is done only at its wake, after the ears have walked on and
    handed it blocks of spikes past that sample: it holds them until the wake and cuts them
    there. Its log then equals that of the same run with a live view (a wake a decode, the
    spikes written as handed), message for message."""
    import dataclasses

    class Looking:
        def put(self, topic: str, schema: str, data: bytes, t_ns: int) -> None:
            pass

        def watched(self) -> bool:
            return True

    sc = random_group(seed, noise=noise, gains=True, anchor="schedule")
    sc = dataclasses.replace(sc, protocol=dataclasses.replace(sc.protocol, schedule="concurrent"))
    logs = []
    for live in (None, Looking()):
        rec = MemoryRecorder(live=live)
        run_group(sc, "memory", rec)
        logs.append(sorted((t, tp, _json(m)) for tp, t, m in rec.messages))
    assert logs[0] == logs[1]


@pytest.mark.parametrize("small", [False, True])
def test_the_ears_hand_each_unit_its_spikes_a_block_at_a_time(small, monkeypatch):
    """The hand-over alone: random spikes (sample, walker, channel) of two advances, the first
    walked by two receivers for all (one stood still), the second by each on its own, come
    out a block at a time, in the order (block, first unit): each unit exactly its walker's
    spikes in each advance, through the channels that fired and each spike's index among
    them; units whose spikes in a block are equal (however they walked) as one shared block.
    A unit that stops gets the rest of its own and no more. The same with the grouping in
    arrays and in plain Python (``small``: a hand-over of a few spikes)."""
    import types

    import rgtbus.engine.spike_log

    monkeypatch.setattr(rgtbus.engine.spike_log, "SMALL_HAND_OVER", 10**9 if small else 0)

    import numpy as np

    from rgtbus.engine.spike_log import SharedSpikes, SpikeKeeper, SpikePiece

    rng = np.random.default_rng(3)
    units, channels, block = 5, 7, 50
    got: list[tuple[tuple[int, ...], int, list[tuple[int, int]], int]] = []

    def spikes_of(samples, index, fired):
        assert list(fired) == sorted(set(fired)) and sorted(set(index)) == list(range(len(fired)))
        return [(int(k), int(fired[i])) for k, i in zip(samples, index, strict=True)]

    def sink(u):
        def spikes(samples, index, fired, end):
            got.append(((u,), int(samples[0]) // block, spikes_of(samples, index, fired), end))

        def shared_spikes(share):
            assert isinstance(share, SharedSpikes) and u in share.members
            assert share.names == [f"u{m}" for m in share.members]
            if u == share.members[0]:
                got.append((
                    tuple(share.members), int(share.samples[0]) // block,
                    spikes_of(share.samples, share.index, share.fired), share.end,
                ))  # fmt: skip

        # each settles what it is handed (as a unit that takes batches does)
        return types.SimpleNamespace(
            spikes=spikes, shared_spikes=shared_spikes, keeps_now=lambda: False, block=block
        )

    def rows(lo, hi, walkers):
        drawn = rng.integers((lo, 0, 0), (hi, len(walkers), channels), (400, 3))
        return sorted({(int(k), walkers[int(w)], int(c)) for k, w, c in drawn})

    first_walker = [0, 0, 2, 0, -1]  # unit 4 stood still through the first advance
    first, second = rows(0, 210, [0, 2]), rows(210, 420, list(range(units)))
    # unit 3 walked on its own and heard what unit 1 heard: one block of theirs all the same
    second = sorted([r for r in second if r[1] != 3] + [(k, 3, c) for k, w, c in second if w == 1])
    kept = SpikeKeeper(
        [types.SimpleNamespace(spike_log=sink(u), name=f"u{u}") for u in range(units)]
    )
    kept.pieces = [
        SpikePiece(*(np.array([r[j] for r in part]) for j in range(3)), walker_of=wo)
        for part, wo in ((first, np.array(first_walker)), (second, None))
    ]
    kept.hand(200, 400)  # the blocks before sample 200
    kept.hand(None, 400, only=2)  # unit 2 stops: the rest of its spikes
    kept.hand(None, 400, only=2)  # and its end: nothing more
    kept.hand(None, 400)  # the run ends

    def mine(u, b):
        return [(k, c) for k, w, c in first if w == first_walker[u] and k // block == b] + [
            (k, c) for k, w, c in second if w == u and k // block == b
        ]

    def groups(b, who):
        out: dict[tuple, list[int]] = {}
        for u in who:
            if mine(u, b):
                out.setdefault(tuple(mine(u, b)), []).append(u)
        return sorted((tuple(us), b, list(sp)) for sp, us in out.items())

    everyone = list(range(units))
    want = [g for b in range(4) for g in groups(b, everyone)]
    want += [g for b in range(4, 9) for g in groups(b, [2])]
    want += [g for b in range(4, 9) for g in groups(b, [0, 1, 3, 4])]
    assert [g[:3] for g in got] == want
    assert any(len(g[0]) > 1 for g in got) and any(len(g[0]) == 1 for g in got)
    assert any(g[0] == (1, 3) and g[1] >= 5 for g in got)
    for _, b, _, end in got:
        assert end == min((b + 1) * block, 400)


@pytest.mark.parametrize("seed", range(6))
def test_the_hand_over_of_units_that_walked_as_one_equals_the_general_one(seed):
    """Where every member took one and the same walk in each piece (``_hand_as_one``), the
    blocks handed are exactly those the general grouping hands (which it skips): the same
    groups, spikes, ends and order; the others' spikes in a piece are not theirs."""
    import types

    import numpy as np

    import rgtbus.engine.spike_log
    from rgtbus.engine.spike_log import SpikeKeeper, SpikePiece

    rng = np.random.default_rng(seed)
    units, channels, block = 4, 6, 40
    n_pieces = int(rng.integers(1, 4))
    bounds = np.sort(rng.choice(np.arange(1, 300), n_pieces - 1, replace=False)).tolist()
    pieces = []
    for lo, hi in zip([0, *bounds], [*bounds, 300], strict=True):
        walkers = [int(rng.integers(0, units)), int(rng.integers(0, units))]
        drawn = rng.integers((lo, 0, 0), (hi, 2, channels), (int(rng.integers(0, 120)), 3))
        rows = sorted({(int(k), walkers[int(w)], int(c)) for k, w, c in drawn})
        wo = np.full(units, walkers[0])  # every unit took the first walker's walk
        pieces.append(
            SpikePiece(*(np.array([r[j] for r in rows], dtype=np.int64) for j in range(3)), wo)
        )

    keeps = False

    def handed(fast: bool, members: np.ndarray, heard: int) -> list:
        got: list = []

        def sink(u):
            def spikes(samples, index, fired, end):
                got.append(((u,), samples.tolist(), fired[index].tolist(), end))

            def shared_spikes(share):
                if u == share.members[0]:
                    got.append((
                        tuple(share.members), share.samples.tolist(),
                        share.fired[share.index].tolist(), share.end,
                    ))  # fmt: skip

            def shared_kept(names, samples, index, fired, end):
                got.append((
                    tuple(int(n[1:]) for n in names), samples.tolist(),
                    fired[index].tolist(), end,
                ))  # fmt: skip

            return types.SimpleNamespace(
                spikes=spikes,
                shared_spikes=shared_spikes,
                shared_kept=shared_kept,
                keeps_now=lambda: keeps,
                block=block,
            )

        kept = SpikeKeeper(
            [types.SimpleNamespace(spike_log=sink(u), name=f"u{u}") for u in range(units)]
        )
        if not fast:
            kept._hand_as_one = lambda *a: False  # type: ignore[method-assign]
        kept._hand_blocks([p for p in pieces if len(p.k)], members, heard)
        return got

    for members in (np.arange(units), np.array([2])):
        fast = handed(True, members, 290)
        assert fast == handed(False, members, 290)
        small = rgtbus.engine.spike_log.SMALL_HAND_OVER
        rgtbus.engine.spike_log.SMALL_HAND_OVER = 10**9  # the general grouping in plain Python
        try:
            assert handed(False, members, 290) == fast
        finally:
            rgtbus.engine.spike_log.SMALL_HAND_OVER = small
        keeps = True  # units that keep each block at once: the same records, none settled
        assert handed(True, members, 290) == fast == handed(False, members, 290)
        keeps = False
    assert any(len(g[0]) == units for g in handed(True, np.arange(units), 290)) or not any(
        len(p.k) for p in pieces
    )


def _one_decode_at_a_time(self, queue, reads, a, b):
    """The reference for a unit's batch of queued decodes: each on its own, read from the
    unit's own readout (``decode``: the ears' per-decode path, no column of the queue)."""
    listen = queue.listen(int(reads.seq[a]))
    self.decode(listen)
    self.settle(int(reads.bounds[a]) - 1)
    return a + 1


@pytest.mark.parametrize(
    "seed, noise, rounds, goals",
    [(3, 0.0, 1, False), (4, 0.02, 2, False), (6, 0.05, 3, True), (10, 0.3, 1, False)],
)
def test_a_batch_of_decodes_as_columns_is_each_decode_on_its_own(
    monkeypatch, seed, noise, rounds, goals
):
    """A unit takes the decodes of a shared queue a batch at a time as columns (read once
    for every unit, recorded and learned from as arrays, one at a time only where a code is
    refused or a table completes): its log and summary equal those of each decode taken on
    its own, on noisy groups (refused codes, wrong channels), rounds, goals."""
    from rgtbus.units import unit as unit_module
    from rgtbus.units.listening import Listening

    from rgtbus.telemetry.record_rows import decodes_per_row

    base = random_group(seed, noise=noise, gains=True, anchor="schedule")
    text = base.text + f'[protocol]\nschedule = "concurrent"\ninfluence_rounds = {rounds}\n'
    if goals:  # the last unit steers the first: its influences wait for a choice
        text += f'[goals.{base.units[-1]}]\n{base.units[0]} = "1"\n'
    sc = parse_scenario(text, f"<batch{seed}>")
    got = []
    for reference in (False, True):
        if reference:
            monkeypatch.setattr(Listening, "_take_decodes", _one_decode_at_a_time)
            # read at the batch's wake, from the unit's own readout: kept a batch longer
            monkeypatch.setattr(unit_module, "KEEP_SECONDS", 30.0 + unit_module.BATCH_SECONDS)
        rec = MemoryRecorder()
        out = run_group(sc, "memory", rec)
        rows = decodes_per_row(rec.messages)
        summary = {k: v for k, v in out.summary.items() if k not in ("wall_seconds", "sync")}
        got.append((summary, sorted((t, tp, _json(m)) for tp, t, m in rows)))
    assert got[0] == got[1]


def test_each_queued_code_is_read_once_for_every_unit_and_dropped_when_all_passed(
    monkeypatch,
):
    """The ears read each position of a shared queue once, for every receiver, whichever
    unit gets there first, and drop a chunk once every listening unit has passed it: the
    run is the same with chunks of 8 positions."""
    from rgtbus.units import unit as unit_module

    from rgtbus.engine import queues

    sc = random_group(7, noise=0.01, gains=True, anchor="schedule")
    text = sc.text + '[protocol]\nschedule = "concurrent"\ninfluence_rounds = 3\n'
    sc = parse_scenario(text, "<chunks>")
    whole = run_group(sc, "memory", MemoryRecorder()).summary
    monkeypatch.setattr(queues, "QUEUE_CHUNK", 8)
    # several batches in this short run
    monkeypatch.setattr(unit_module, "BATCH_SECONDS", 4.0)
    monkeypatch.setattr(unit_module, "LOGGED_BATCH_SECONDS", 4.0)
    reads: list[int] = []
    held: list[int] = []
    fill = queues.QueueDecodes.fill

    def counted(self, upto, read):
        fill(self, upto, lambda q0, q1: (reads.extend(range(q0, q1)), read(q0, q1))[1])
        held.append(len(self.chunks))

    monkeypatch.setattr(queues.QueueDecodes, "fill", counted)
    summary = run_group(sc, "memory", MemoryRecorder()).summary
    assert {k: v for k, v in summary.items() if k not in ("wall_seconds", "sync")} == {
        k: v for k, v in whole.items() if k not in ("wall_seconds", "sync")
    }
    assert sorted(reads) == list(range(len(reads))) and len(reads) > 80
    # read as heard, held until every unit has taken them (a batch of 4 s here): a few chunks
    # at a time, never the whole queue (12 chunks)
    assert max(held) <= 4 < len(reads) // 8


@pytest.mark.parametrize("seed", [3, 8])
def test_a_block_of_queued_codes_decodes_as_each_code_alone(monkeypatch, seed):
    """The ears decode a shared queue a block of positions at a time, every receiver at
    once (``read_block``): on a noisy medium heard through unequal gains (every receiver's
    values differ) the run and its log are those of decoding one position at a time."""
    import dataclasses

    import numpy as np
    from rgtbus.units.listening import Listening

    sc = random_group(seed, noise=0.1, gains=True, anchor="schedule")
    sc = parse_scenario(sc.text + '[protocol]\nschedule = "concurrent"\n', "<blocks>")
    got = []
    for alone in (False, True):
        if alone:
            build = Listening._queue_reads

            def one_at_a_time(self, queue, build=build):
                reads = build(self, queue)

                def block(q0, q1):
                    cols = zip(*(reads.read(q) for q in range(q0, q1)), strict=True)
                    return tuple(np.stack(c) for c in cols)

                return dataclasses.replace(reads, read_block=block)

            monkeypatch.setattr(Listening, "_queue_reads", one_at_a_time)
        rec = MemoryRecorder()
        out = run_group(sc, "memory", rec)
        summary = {k: v for k, v in out.summary.items() if k not in ("wall_seconds", "sync")}
        got.append((summary, sorted((tp, t, _json(m)) for tp, t, m in rec.messages)))
    assert got[0] == got[1]
    assert got[0][0]["decode_errors"]["misread"]  # noisy enough that some codes are misread
    # a unit judges its batches against the queue's truth: as its decodes judged row by row
    from rgtbus.misreads import sent_truth, wrong_decodes

    truth = sent_truth(out.reports)
    for unit in out.units:
        rows = [list(row) for row in unit.decoded]
        assert wrong_decodes(unit.name, unit.decoded, truth) == wrong_decodes(
            unit.name, rows, truth
        )
        assert unit.decoded._runs  # its batches were held as runs


def test_a_run_says_what_keeping_its_clock_cost():
    """``details["sync"]``: the rounds of the horizon (the steps), the frames published (those
    with no pulse: null messages), the seconds blocked in the bus's wait, and the rounds the
    ears ran past the horizon (none in one process: the binding member is always local)."""
    import rgtbus

    result = rgtbus.run(ROOT / "scenarios" / "gate.toml")
    sync = result.details["sync"]
    assert sync["members"] == 4 and sync["rounds"] == result.details["steps"] > 0
    assert sync["frames"] >= sync["null_frames"] >= 0 and sync["frames"] >= 4
    assert sync["wait_seconds"] >= 0 and sync["ahead_rounds"] == 0


def test_a_logged_batch_of_any_length_writes_the_same_log(monkeypatch):
    """A unit with a log takes its decodes a batch of ``batch_seconds`` at a wake (shorter in
    a large group, where what a batch holds weighs most): the records are the same whatever
    the batch, only the wakes and the file's order differ."""
    from rgtbus.units import unit as unit_module

    assert unit_module.batch_seconds(10, logged=False) == unit_module.BATCH_SECONDS
    small = unit_module.batch_seconds(unit_module.LARGE_GROUP, logged=True)
    large = unit_module.batch_seconds(unit_module.LARGE_GROUP + 1, logged=True)
    assert large < small < unit_module.BATCH_SECONDS
    # paced: at most PACED_BATCH_WALL_SECONDS of wall time (a log cut by a kill trails little)
    wall = unit_module.PACED_BATCH_WALL_SECONDS
    assert unit_module.batch_seconds(10, logged=True, realtime=4.0) == 4.0 * wall
    assert unit_module.batch_seconds(10, logged=True, realtime=1e6) == small
    assert unit_module.batch_seconds(10, logged=False, realtime=4.0) == unit_module.BATCH_SECONDS
    # receivers that hear the medium differently each hold their own spikes: shorter batches
    differ = unit_module.DIFFER_LOGGED_BATCH_SECONDS
    assert differ < small and unit_module.batch_seconds(10, logged=True, alike=False) == differ
    assert unit_module.batch_seconds(10, logged=True, realtime=1.0, alike=False) == 1.0 * wall
    assert unit_module.batch_seconds(10, logged=False, alike=False) == unit_module.BATCH_SECONDS

    sc = random_group(5, noise=0.02, gains=True, anchor="schedule")
    sc = parse_scenario(sc.text + '[protocol]\nschedule = "concurrent"\n', "<batches>")
    logs = []
    # a noisy group (its receivers hear differently): each batch as asked, and its own
    for seconds, large_group, differ_s in (
        (small, 10**6, 10**6), (4.0, 10**6, 10**6), (small, 0, 10**6), (small, 10**6, differ),
    ):  # fmt: skip
        monkeypatch.setattr(unit_module, "LOGGED_BATCH_SECONDS", seconds)
        monkeypatch.setattr(unit_module, "LARGE_GROUP", large_group)  # 0: every group is large
        monkeypatch.setattr(unit_module, "DIFFER_LOGGED_BATCH_SECONDS", differ_s)
        rec = MemoryRecorder()
        run_group(sc, "memory", rec)
        logs.append(sorted((tp, t, _json(m)) for tp, t, m in rec.messages))
    assert logs[0] == logs[1] == logs[2] == logs[3] and len(logs[0]) > 100
