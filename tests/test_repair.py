"""The repair ([protocol] repair = "arq"; docs/protocol.md, "Repair"): the blocks' layout, the
scenario keys, and runs on noisy channels that end as the noise-free run ends, the same on both
engines, with logs that replay and verify."""

from __future__ import annotations

import io
import math
from pathlib import Path

import pytest

from rgtbus.errors import RgtbusError
from rgtbus.protocol import ProtocolState, phases
from rgtbus.scenario import parse_scenario

ROOT = Path(__file__).resolve().parent.parent
GROUP = (ROOT / "scenarios" / "random_group.toml").read_text()
SKIP = {"wall_seconds", "engine", "steps", "bus", "sync", "log", "scenario"}  # not results


def group(n: int = 4, schedule: str = "concurrent", repair: str = "arq", noise: float = 0.06,
          extra: str = "", name: str = "repair.toml"):  # fmt: skip
    units = ", ".join(f'"r{i}"' for i in range(n))  # other names than the base's
    text = GROUP.replace('units = ["u1", "u2", "u3"]', f"units = [{units}]").replace(
        'schedule = "concurrent"', f'schedule = "{schedule}"\nrepair = "{repair}"\n{extra}'
    )
    text = text.replace("[relations]", f"[channel]\nnoise = {noise}\n\n[relations]")
    return parse_scenario(text, name)


def _state(me: str, schedule: str, rounds: int = 2, influence_rounds: int = 1):
    units = ("a", "b", "c")
    omegas = {"a": 3 * math.pi / 2, "b": 4 * math.pi / 3, "c": 5 * math.pi / 3}
    return ProtocolState(
        me, units, omegas, 0.005, anchor="schedule", kind=schedule, repair_rounds=rounds,
        influence_rounds=influence_rounds,
    )  # fmt: skip


@pytest.mark.parametrize("schedule", ["serial", "concurrent"])
def test_repair_blocks_follow_each_phase_and_hold_a_slot_for_each_of_its_payloads(schedule):
    """K blocks after every phase, each with a request and a repeat slot for every payload of
    the phase; no two pulses of a block share a sample; every choice comes after what it
    depends on (the phase's decodes, the requests); the next phase starts after the blocks."""
    ps = _state("a", schedule, rounds=2, influence_rounds=2)
    acts = ps.begin({"b": "alliance", "c": "conflict"}, {"b": "0", "c": "1"})
    blocks = acts.repairs
    assert [(b.phase, b.number) for b in blocks] == [(p, k) for p in range(3) for k in (1, 2)]
    sends = sorted(acts.sends, key=lambda s: s.samples[0])
    for b in blocks:
        phase, rnd = phases(2)[b.phase]
        turns = [t.index for t in ps.schedule if (t.phase, t.round) == (phase, rnd)]
        assert [s.turn for s in b.slots] == turns  # a slot for every payload of the phase
        pulses = [k for s in b.slots for k in (*s.request, *s.repeat)]
        assert len(pulses) == len(set(pulses))
        listens = acts.listens if acts.queue is None else acts.queue.listens
        last_decode = max(li.ready_sample for li in listens if li.turn in turns)
        assert b.request_choice > last_decode
        assert b.repeat_choice > max(s.request[-1] for s in b.slots)
        assert b.request_choice < b.first_request and b.repeat_choice < b.first_repeat
        assert b.ready == max(s.repeat[-1] for s in b.slots)
        later = [s for s in sends if s.samples[0] > b.ready]
        nxt = [t.index for t in ps.schedule if (t.phase, t.round) != (phase, rnd)]
        # the phase's own codes all come before its blocks; the next phase's after them
        assert all(s.turn not in turns for s in later)
        if b.number == 2 and b.phase < 2:
            assert {s.turn for s in later} >= {t for t in nxt if t > turns[-1]} & {
                s.turn for s in sends
            }


def test_the_book_holds_what_is_unsure_asks_for_it_and_decodes_the_mean_of_its_reads():
    """``RepairBook``: a read far from every word is held and asked for; a silent copy adds
    nothing; copies add up and the mean is decoded (noise falls as 1/√reads), and once sure
    the payload leaves the book; after the last block the rest leaves as it reads best."""
    import numpy as np

    from rgtbus.repair import SILENCE, RepairBook
    from rgtbus.signal.codebook import paper_codebook
    from rgtbus.signal.decoder import Decision, nearest

    cb = paper_codebook(["alpha", "beta"])
    book = RepairBook(cb, 0.65, blocks=2)
    ps = _state("a", "concurrent", rounds=2)
    acts = ps.begin({"b": "alliance", "c": "alliance"}, {"b": "0", "c": "1"})
    first, second = acts.repairs[2], acts.repairs[3]  # the influence phase's blocks
    listens = acts.listens if acts.queue is None else acts.queue.listens
    listen = next(li for li in listens if li.kind == "influence" and li.turn == 6)
    words = cb.family("alternative")
    sent = np.array(words["{alpha}"])
    first_read = np.array([0.42, 0.17, 0.6])  # nearest {alpha}, by a small margin
    exact = nearest(first_read, book.families["alternative"])
    assert exact.name == "{alpha}" and exact.margin < book.below["alternative"]
    assert not book.sure("alternative", exact.name, True, exact.margin, exact)
    book.hold(listen, 2, exact)
    assert [s.turn for s in book.requests(first)] == [6] and book.counts["requests"] == 1
    ((slot, held),) = book.awaited(first)
    silent = Decision(SILENCE, 0.0, 1.0, 1.0, (0.0, 0.0, 0.0))
    assert book.copy(slot, held, silent) is None and book.counts["missing"] == 1
    noisy_copy = np.array([0.65, 0.28, 0.27])  # alone it reads as "0": the mean does not
    assert nearest(noisy_copy, book.families["alternative"]).name == "0"
    best = book.copy(slot, held, Decision("0", 0.0, 1.0, 1.0, tuple(noisy_copy)))
    assert best is not None and best.name == "{alpha}" and held.reads == 2
    assert 6 in book.held  # the mean is not sure yet (margin below the bound)
    book.requests(second)
    best = book.copy(slot, held, Decision("{alpha}", 0.0, 1.0, 1.0, tuple(sent)))
    assert best is not None and best.name == "{alpha}" and best.margin >= book.below["alternative"]
    assert 6 not in book.held and book.counts["resolved"] == 1
    book.hold(listen, 2, exact)  # unsure again, and never answered
    assert [h.best for h in book.last(second)] == [exact.name] and not book.held
    assert book.counts["unresolved"] == 1 and book.last(first) == []


def test_without_repair_the_protocol_plans_no_block():
    ps = _state("a", "concurrent", rounds=0)
    assert ps.begin({"b": "alliance", "c": "alliance"}, {"b": "0", "c": "1"}).repairs == []
    assert group(repair="none").protocol.repairs_per_phase == 0
    assert group(extra="repair_rounds = 5").protocol.repairs_per_phase == 5


def test_repair_needs_turns_timed_by_the_schedule():
    with pytest.raises(RgtbusError, match="anchor schedule"):
        ProtocolState("a", ("a", "b"), {"a": 3.0, "b": 4.0}, 0.005, anchor="spike",
                      repair_rounds=1)  # fmt: skip
    # serial turns default to the schedule's timing with a repair, and refuse the spike's
    assert group(schedule="serial").timing.anchor == "schedule"


@pytest.mark.parametrize(
    "extra, says",
    [
        ('repair = "fec"', "protocol.repair: unknown repair 'fec'"),
        ("repair_rounds = 0", "protocol.repair_rounds: must be an integer 1..20"),
        ("repair_rounds = 21", "protocol.repair_rounds: must be an integer 1..20"),
        ("repair_rounds = true", "protocol.repair_rounds"),
        ("repair_margin = -0.1", "protocol.repair_margin: must be a number 0..2"),
        ('repair_margin = "wide"', "protocol.repair_margin"),
        ("repair_margin = nan", "protocol.repair_margin"),
    ],
)
def test_bad_repair_keys_are_one_line_naming_file_line_and_key(extra, says):
    text = GROUP.replace('schedule = "concurrent"', f'schedule = "concurrent"\n{extra}')
    with pytest.raises(RgtbusError) as e:
        parse_scenario(text, "bad.toml")
    msg = str(e.value)
    assert says in msg and msg.startswith("bad.toml:") and "\n" not in msg, msg


def test_a_repair_with_the_spike_s_timing_is_refused_naming_the_anchor():
    text = GROUP.replace('schedule = "concurrent"', 'schedule = "serial"\nrepair = "arq"')
    text = text.replace("[relations]", '[timing]\nanchor = "spike"\n\n[relations]')
    with pytest.raises(RgtbusError) as e:
        parse_scenario(text, "bad.toml")
    assert "timing.anchor" in str(e.value) and "repair" in str(e.value)


def test_on_a_clean_channel_a_repair_asks_for_nothing_and_decides_as_without():
    """Nothing is unsure on a perfect medium: no request, no repeat; the blocks only add
    their time, and every unit decides as it does without them."""
    import rgtbus

    for schedule in ("serial", "concurrent"):
        with_ = rgtbus.run(group(3, schedule, "arq", 0.0), seed=2).summary
        without = rgtbus.run(group(3, schedule, "none", 0.0), seed=2).summary
        assert with_["units"] == without["units"] and with_["error"] is None
        assert without["repair"] is None
        r = with_["repair"]
        assert r["mode"] == "arq" and r["blocks_per_phase"] == 3
        assert all(r[k] == 0 for k in ("requests", "repeats", "copies", "unresolved"))
        # what the blocks add after each phase's last payload is what the run is longer by
        # (the last phase's decisions come up to a guard before the end of its last pulse)
        longer = with_["sim_seconds"] - without["sim_seconds"]
        assert r["seconds"] > 0 and abs(longer - r["seconds"]) <= 0.5


@pytest.mark.parametrize("schedule", ["serial", pytest.param("concurrent", marks=pytest.mark.slow)])
def test_a_noisy_run_that_dies_without_repair_ends_as_the_noise_free_run_with_it(
    schedule, logged_run
):
    """σ = 0.06: without repair a misread ID ends the run; with it, unsure payloads are asked
    for and repeated, and every unit decides what the noise-free run decides. Both engines
    make the same run, and its log (requests and repeats in it) replays and verifies."""
    from rgtbus.units.rerun import verify_log

    import rgtbus
    from rgtbus.telemetry.read import load_replay

    seed = 3
    timed = '[timing]\nanchor = "schedule"\n'  # without repair: timed by the schedule too
    plain = parse_scenario(group(4, schedule, "none").text + "\n" + timed, "none.toml")
    assert rgtbus.run(plain, seed=seed).summary["error"] is not None
    sc = group(4, schedule, "arq").with_seed(seed)
    results = []
    for engine in ("event", "dense"):
        summary, data = logged_run(sc, engine)
        results.append({k: v for k, v in summary.items() if k not in SKIP})
        rp = load_replay(io.BytesIO(data))
        assert verify_log(rp).ok
    assert results[0] == results[1]
    s = results[0]
    assert s["error"] is None and s["wrong_decisions"] == [] and s["agree"]
    r = s["repair"]
    assert r["requests"] > 0 and r["repeats"] > 0 and r["copies"] == r["requests"]
    kinds = {t.kind for t in rp.transmissions}
    assert {"request", "repeat"} <= kinds
    # every repeat carries the code its sender sent in the turn it repeats
    sent = {(t.turn, t.sender): t.code for t in rp.transmissions if t.kind == "payload"}
    repeats = [t for t in rp.transmissions if t.kind == "repeat"]
    assert repeats and all(sent[(t.turn, t.sender)] == t.code for t in repeats)


@pytest.mark.slow
def test_goal_driven_rounds_repair_too_and_equal_across_engines():
    """The tug of war (two goal-driven units, three influence rounds, serial) at σ = 0.06: a
    block after every phase; the run ends as the noise-free one, the same on both engines."""
    import rgtbus

    text = (ROOT / "scenarios" / "tug_of_war.toml").read_text()
    text = text.replace("[protocol]\n", '[protocol]\nrepair = "arq"\n', 1)
    noisy = parse_scenario(text.replace("noise = 0.0", "noise = 0.06", 1), "tug.toml")
    clean = parse_scenario(text, "tug.toml")
    assert noisy.timing.anchor == "schedule" and noisy.goals
    runs = [
        {k: v for k, v in rgtbus.run(noisy, seed=1, engine=e).summary.items() if k not in SKIP}
        for e in ("event", "dense")
    ]
    assert runs[0] == runs[1]
    s = runs[0]
    assert s["error"] is None and s["repair"]["requests"] > 0
    c = rgtbus.run(clean, seed=1).summary
    assert s["units"] == c["units"] and s["goals"] == c["goals"]
    assert s["rounds"]["influences"] == c["rounds"]["influences"]


def _checked(seed: int, text: str | None = None) -> tuple[dict, list]:
    import rgtbus
    from rgtbus.scenario import load_scenario, parse_scenario
    from rgtbus.summary import check_expectations

    sc = (load_scenario("gate_repair") if text is None else parse_scenario(text)).with_seed(seed)
    s = rgtbus.run(sc).summary
    return s, check_expectations(sc, s)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_check_judges_what_the_run_decided_misreads_set_right_are_no_error(seed):
    """gate_repair's --check passes: its misreads (IDs, and payloads a repair's copy read
    right) are listed, and none is left wrong in what the units took."""
    s, lines = _checked(seed)
    assert s["decode_errors"]["misread"] and s["decode_errors"]["left_wrong"] == 0
    assert all(ok for _, ok, _ in lines), [x for x in lines if not x[1]]
    label = next(w for w, _, _ in lines if w.startswith("no decode error left wrong"))
    assert f"({s['decode_errors']['misread']} misread, set right)" in label


def test_gate_repair_checks_in_every_seed_1_to_20():
    for seed in range(1, 21):
        _, lines = _checked(seed)
        assert all(ok for _, ok, _ in lines), (seed, [x for x in lines if not x[1]])


def test_a_misread_left_wrong_fails_the_check():
    """Without its repair and on a noisier channel, misreads stay wrong: --check says so."""
    text = (ROOT / "scenarios" / "gate_repair.toml").read_text()
    text = text.replace("noise = 0.1", "noise = 0.13").replace('repair = "arq"', 'repair = "none"')
    s, lines = _checked(3, text)
    assert 0 < s["decode_errors"]["left_wrong"] < s["decode_errors"]["misread"]
    left = [x for x in lines if x[0].startswith("no decode error left wrong")]
    assert (
        left
        and not left[0][1]
        and left[0][2] == f"got {s['decode_errors']['left_wrong']}, expected 0"
    )


def test_a_large_concurrent_group_keeps_its_readout_as_far_back_as_its_repair_reads():
    # ten units on the concurrent schedule: a phase and its blocks outlast the default history
    # (30 s and more); the blocks re-read the phase's payloads, so the units keep them
    from rgtbus.units.group import run_group

    from rgtbus.telemetry import NullRecorder

    sc = group(10, noise=0.0)
    plan = ProtocolState("r0", sc.units, dict(sc.frequencies), sc.timing.tau, anchor="schedule",
                         kind="concurrent", repair_rounds=3).plan  # fmt: skip
    assert plan.repair_reach() > 30.0
    out = run_group(sc, "memory", NullRecorder())
    assert out.summary["error"] is None
    assert out.summary["repair"]["requests"] == 0
