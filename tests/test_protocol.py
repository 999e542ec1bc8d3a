"""The protocol state machine and the reasoning, pure (no SimPy, no bus)."""

import math
import random

import pytest

from rgtbus.mind import Mind, choose, choose_relations
from rgtbus.protocol import NEVER, ProtocolState, code_samples, turns
from rgtbus.rgt import Universe, decision_function, evaluate, parse_polynomial

W = {"a": 3 * math.pi / 2, "b": 4 * math.pi / 3, "c": 5 * math.pi / 3}
TAU = 0.005


def test_turn_order_is_sender_major_per_phase():
    t = turns(("a", "b", "c"))
    assert [(x.phase, x.sender, x.addressee) for x in t[:6]] == [
        ("relations", "a", "b"),
        ("relations", "a", "c"),
        ("relations", "b", "a"),
        ("relations", "b", "c"),
        ("relations", "c", "a"),
        ("relations", "c", "b"),
    ]
    assert [x.phase for x in t[6:]] == ["influences"] * 6
    assert [x.index for x in t] == list(range(12))


def test_code_samples_one_period_apart():
    # ω_a = 3π/2: period 4/3 s; the paper's codes start 1 ms after onset.
    assert code_samples(0.001, W["a"], 3, TAU) == (0, 267, 534)
    assert code_samples(1.0, 2 * math.pi, 3, TAU) == (200, 400, 600)


def machine(me: str) -> ProtocolState:
    """The paper's machine: turns timed by the attention spike's threshold crossing."""
    p = ProtocolState(
        me, ("a", "b", "c"), W, TAU, start=0.001, reaction_delay=0.5, guard=0.5,
        attention="threshold",
    )  # fmt: skip
    return p


def test_sender_reacts_to_its_own_id_spike():
    p = machine("a")
    acts = p.begin({"b": "alliance", "c": "conflict"}, {"b": "1", "c": "0"})
    assert acts.listens == [] and acts.quench == []
    assert acts.deadline == p.id_deadline() == 534 + 267  # the ID's last pulse + a period
    assert [(s.kind, s.channel, s.code, s.samples) for s in acts.sends] == [
        ("id", "a", "id", (0, 267, 534))
    ]
    # A spike on another channel, or before the ID's first pulse, is not the ID spike.
    assert not p.on_spike("b", 300)
    acts = p.on_spike("a", 534)
    sends, listens = acts.sends, acts.listens
    payload = sends[0]
    assert (payload.kind, payload.channel, payload.code) == ("payload", "b", "alliance")
    assert payload.start == pytest.approx(534 * TAU + 0.5)
    assert payload.samples == code_samples(534 * TAU + 0.5, W["b"], 3, TAU)
    assert [x.kind for x in listens] == ["id", "relation"]
    assert listens[1].channels == ("b", "c") and listens[1].expected_addressee == "b"
    # The next turn (a -> c) starts a guard after the payload's last pulse; a sends its ID.
    end = 534 * TAU + 0.5 + 2 * 2 * math.pi / W["b"]
    assert p.turn == 1 and p.turn_start == pytest.approx(end + 0.5)
    assert sends[1].kind == "id" and sends[1].addressee == "c"
    # The protocol names the quench (the next turn's start) and the new turn's deadline.
    assert acts.quench == [round(p.turn_start / TAU)]
    assert acts.deadline == p.id_deadline() > acts.quench[0]


def test_listener_follows_the_chain_without_sending():
    p = machine("c")
    acts = p.begin({"a": "alliance", "b": "alliance"}, {"a": "1", "b": "1"})
    assert acts.sends == [] and acts.listens == [] and acts.deadline is not None
    acts = p.on_spike("a", 534)
    assert acts.sends == [] and len(acts.listens) == 2 and len(acts.quench) == 1
    assert p.turn == 1


def test_deadline_names_the_missing_id():
    p = machine("b")
    p.begin({"a": "alliance", "c": "alliance"}, {"a": "1", "c": "1"})
    assert p.check_deadline(p.id_deadline()) is None
    msg = p.check_deadline(p.id_deadline() + 1)
    assert msg.startswith("b: no ID spike on a's channel for turn 0 (a -> b, relations)")


U = Universe(("alpha", "beta"))


@pytest.mark.parametrize(
    ("policy", "expected"),
    [
        ("max", "1"),
        ("min", "{beta}"),
        ("{beta}", "{beta}"),
        ("{alpha}", "1"),
    ],  # {alpha} is not in [{beta}, 1]: falls back to max
)
def test_decision_policies(policy, expected):
    df = decision_function(parse_polynomial("ab+c"))
    r = evaluate(df, U, "b", {"a": 0b01, "c": 0b10})  # interval [{beta}, 1]
    assert U.format(choose(policy, r, U, random.Random(0))) == expected


def test_seeded_random_policy_is_reproducible_and_stays_in_the_interval():
    df = decision_function(parse_polynomial("ab+c"))
    r = evaluate(df, U, "b", {"a": 0b01, "c": 0b10})
    picks = [choose("seeded-random", r, U, random.Random(s)) for s in range(50)]
    assert set(picks) == {0b10, 0b11}
    assert picks == [choose("seeded-random", r, U, random.Random(s)) for s in range(50)]


def test_frustrated_unit_makes_no_choice():
    df = decision_function(parse_polynomial("a(b+c)"))
    r = evaluate(df, U, "a", {"b": 0b10, "c": 0b10})
    assert r.frustrated and choose("max", r, U, random.Random(0)) is None


def test_mind_installs_by_and_and_reports_non_decomposable_groups():
    m = Mind("a", ("a", "b", "c", "d"), Universe(("x",)), "max", random.Random(0))
    for s, r in [(s, r) for s in "abcd" for r in "abcd" if s != r]:
        m.sent[(s, r)] = {frozenset(p) for p in ("ab", "bc", "cd")} >= {frozenset(s + r)}
    assert m.relations_complete()
    m.sent[("b", "a")] = True
    m.build_group()
    assert m.error is None and m.p4 is not None  # a result, not an error
    assert set(m.p4) == set("abcd") and m.p4 in (tuple("abcd"), tuple("dcba"))
    m.decide()  # no group: no decision, no crash
    assert m.results is None and m.choice is None


def test_schedule_anchor_plans_the_whole_run_from_the_start():
    p = ProtocolState("b", ("a", "b", "c"), W, TAU, anchor="schedule")
    acts = p.begin({"a": "alliance", "c": "conflict"}, {"a": "1", "c": "0"})
    sends, listens = acts.sends, acts.listens
    assert p.finished and len(p.turn_starts) == 12
    assert len(acts.quench) == 11 and acts.deadline is None  # no spike is waited for
    assert p.send_bound(0) == NEVER and p.awaited() is None
    assert [(s.turn, s.kind) for s in sends if s.kind == "id"] == [
        (2, "id"),
        (3, "id"),
        (8, "id"),
        (9, "id"),
    ]  # b's turns: b>a, b>c in both phases
    assert len(listens) == 2 * 12
    # The reaction counts from the ID's last pulse: on a clean channel the spike is there.
    first_payload = next(s for s in sends if s.kind == "payload")
    spike_p = ProtocolState("b", ("a", "b", "c"), W, TAU, attention="threshold")
    spike_p.begin({"a": "alliance", "c": "conflict"}, {"a": "1", "c": "0"})
    for _ in range(first_payload.turn + 1):
        ids = spike_p.id_samples()
        out = spike_p.on_spike(spike_p.current().sender, ids[-1]).sends
    assert next(s for s in out if s.kind == "payload") == first_payload
    assert not p.on_spike("a", 10**6) and p.check_deadline(10**9) is None


def test_confirmed_attention_reacts_at_the_expected_spike_moved_by_the_ids_shift():
    """Confirmed attention awaits no spike: after the expected reaction plus the timing search
    the unit decodes the ID and reacts at the expected reaction moved by the decode's shift;
    with a shift of 0 that is the reaction the threshold machine makes to a spike there."""
    late = {"a": 2}  # a's ID fires its resonator 2 samples after its last pulse (say)

    def expect(sender, ids, deadline):
        assert deadline > ids[-1]
        return ids[-1] + late.get(sender, 0) if sender != "c" else None  # c's never fires

    conf = ProtocolState("b", ("a", "b", "c"), W, TAU, expect_spike=expect)
    paper = ProtocolState("b", ("a", "b", "c"), W, TAU, attention="threshold")
    codes = ({"a": "alliance", "c": "conflict"}, {"a": "1", "c": "0"})
    acts = conf.begin(*codes)
    paper.begin(*codes)
    assert conf.awaited() is None and paper.awaited() is not None
    assert not conf.on_spike("a", conf.id_samples()[-1])  # spikes are for attention alone
    ids = conf.id_samples()
    assert conf.expected_reaction() == ids[-1] + 2 and acts.deadline == ids[-1] + 2 + conf.search
    assert conf.send_bound(0) <= paper.send_bound(ids[-1])  # a promise it keeps
    for shift in (0,):
        got = conf.on_attention(shift)
        want = paper.on_spike("a", ids[-1] + 2)
        assert got.sends == want.sends and list(got.listens) == list(want.listens)
        assert got.quench == want.quench
    while conf.current().sender != "c":
        conf.on_attention(0)
    # no spike expected: the reaction counts from the ID's last pulse, moved by the shift
    ids = conf.id_samples()
    assert conf.expected_reaction() == ids[-1]
    moved = conf.on_attention(1)
    payload = next(li for li in moved.listens if li.kind != "id")
    assert payload.start == pytest.approx((ids[-1] + 1) * TAU + 0.5)


def test_unknown_anchor_is_refused():
    from rgtbus.errors import RgtbusError

    with pytest.raises(RgtbusError, match="unknown anchor 'sometimes'"):
        ProtocolState("a", ("a", "b"), W, TAU, anchor="sometimes")


@pytest.mark.parametrize("me", ["a", "b", "c"])
@pytest.mark.parametrize("seed", range(4))
def test_send_bound_is_never_later_than_a_send(me, seed):
    """The promise behind the event engine: whatever spikes come, and whenever, every send a
    reaction plans is at or after the bound computed before it (for any horizon before it)."""
    rng = random.Random(seed)
    p = machine(me)
    acts = p.begin({u: "alliance" for u in "abc" if u != me}, {u: "1" for u in "abc" if u != me})
    h = 0
    while not p.finished:
        ids = p.id_samples()
        spike = max(h, ids[0]) + rng.choice([0, 1, rng.randrange(600)])
        bound = p.send_bound(h)
        aw = p.awaited()
        assert aw == (p.current().sender, ids[0], p.id_deadline())
        acts = p.on_spike(p.current().sender, spike)
        for s in acts.sends:
            assert s.samples[0] >= bound
        assert not [s for s in acts.sends if s.samples[0] < spike + 99]  # the reaction delay
        h = spike + rng.randrange(50)
    assert p.send_bound(h) == NEVER and p.awaited() is None


def test_relation_choice_is_seeded_fixed_or_drawn():
    units = ("a", "b", "c", "d")
    fixed = {("a", "b"): False}
    draws = {("a", "c"): 0.9}
    one = choose_relations("a", units, seed=3, fixed=fixed, draws=draws, p=0.61)
    assert one == choose_relations("a", units, seed=3, fixed=fixed, draws=draws, p=0.61)
    assert one["b"] == "conflict" and one["c"] == "conflict" and set(one) == {"b", "c", "d"}
    assert choose_relations("a", units, seed=3, fixed={}, draws={}, p=1.0) == dict.fromkeys(
        "bcd", "alliance"
    )
    # fixing one peer never shifts the others' draws
    free = choose_relations("a", units, seed=3, fixed={}, draws={}, p=0.61)
    assert free["d"] == one["d"]


def test_a_shared_listen_queue_is_its_listens_as_columns():
    """The concurrent schedule's queue holds its listens as columns: each one made back is
    the listen the plan lays out, and a queue made of ``Listen`` objects holds the same."""
    units = ("a", "b", "c", "d")
    omegas = {u: (3 + i) * math.pi / 2 for i, u in enumerate(units)}
    ps = ProtocolState("b", units, omegas, 0.005, anchor="schedule", kind="concurrent")
    acts = ps.begin({u: "alliance" for u in units}, {u: "0" for u in units})
    queue = acts.queue
    assert queue is not None and acts.listens == [] and len(queue) == 4 * 4 * 3
    listens = queue.listens
    again = type(queue).of(listens, units)
    assert again.listens == listens
    for name in ("turn", "kind", "sender", "addressee", "channel", "start", "ready", "order"):
        assert getattr(again, name).tolist() == getattr(queue, name).tolist()
    due = [listens[i] for i in queue.order.tolist()]
    assert [li.ready_sample for li in due] == sorted(li.ready_sample for li in listens)
    assert queue.boundaries.tolist() == [li.ready_sample + 1 for li in due]
    assert {li.kind for li in listens} == {"id", "relation", "influence"}
    assert all(li.channels == ((li.sender,) if li.kind == "id" else (li.expected_addressee,))
               for li in listens)  # fmt: skip
