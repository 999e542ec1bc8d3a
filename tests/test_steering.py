"""Steering a running group (issue 55; docs/foxglove.md, "Steer a live run"): the checks of
``rgtbus.steering``, the changes applied in the world at window boundaries, logged, accounted
for by the truth, and re-run to agreement by ``replay --verify``. The Foxglove client's side
(the official @foxglove/ws-protocol client) is tests/test_steer_live.py."""

from __future__ import annotations

import json
import math

import pytest
from rgtbus.units.rerun import verify_log

import rgtbus
from rgtbus.engine.steering import RequestSource
from rgtbus.scenario import load_scenario
from rgtbus.steering import (
    Refused,
    Request,
    Steered,
    boundary,
    check_call,
    check_setting,
    parameter_names,
    steered_in,
    step_target,
)
from rgtbus.truth import Truth, clean_timeline


class Script(RequestSource):
    """A run's requests, handed over at its ``at``-th look (the world looks once a round), and
    what ``wait`` hands over while it is paused (``on_wait``); the clock's calls kept."""

    def __init__(self, requests: list[Request], at: int = 1, on_wait: list[Request] | None = None):
        self.requests, self.at, self.looks = list(requests), at, 0
        self.on_wait = list(on_wait or [])
        self.clocks: list[tuple[int, float | None, bool]] = []
        self.closed = False
        self.waits = 0

    def take(self) -> list[Request]:
        self.looks += 1
        if (self.looks >= self.at or self.closed) and self.requests:
            out, self.requests = self.requests, []
            return out
        return []

    def wait(self, timeout: float) -> None:
        self.waits += 1
        assert self.waits < 1000, "a paused run never resumed"
        if self.on_wait:
            self.requests.append(self.on_wait.pop(0))
            self.at = 0

    def clock(self, t_ns: int, pace: float | None, running: bool) -> None:
        self.clocks.append((t_ns, pace, running))

    def close(self) -> None:
        self.closed = True


def svc(name: str, who: str = "test", **args: object) -> Request:
    return Request("service", name, dict(args), who)


def par(name: str, value: object, who: str = "test") -> Request:
    return Request("parameter", name, value, who)


def _records(path: object, topic: str) -> list[dict]:
    from rgtbus.telemetry.read import load_replay

    return [m for _, m in load_replay(str(path)).by_topic[topic]]


# -- the checks (pure) ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def gate():
    return load_scenario("gate")


def test_settings_are_checked_naming_the_bad_value(gate):
    assert check_setting(gate, "channel.noise", 0.1).value == 0.1
    s = check_setting(gate, "channel.gain.a>b", 2)  # the scenario file's spelling
    assert (s.name, s.link, s.value) == ("channel.gains.a>b", ("a", "b"), 2.0)
    bad = {
        ("channel.noise", -1): "standard deviation",
        ("channel.noise", math.nan): "not a finite number",
        ("channel.noise", "0.1"): "not a finite number",
        ("channel.noise", True): "not a finite number",
        ("channel.gains.a>zz", 1.0): "unknown unit 'zz'",
        ("channel.gains.a>a", 1.0): "not a pair of two units",
        ("channel.gains.ab", 1.0): "not a pair",
        ("channel.gains.a>b", 0.0): "gain in (0",
        ("repair.budget", 1): "has no repair",
        ("pace", 0): "not a pace",
        ("channel.nois", 1): "unknown parameter 'channel.nois'",
    }
    for (name, value), why in bad.items():
        with pytest.raises(Refused, match=why.replace("(", r"\(")):
            check_setting(gate, name, value)


def test_repair_budget_is_a_parameter_of_a_repaired_run_only(gate):
    rep = load_scenario("gate_repair")
    k = rep.protocol.repairs_per_phase
    assert "repair.budget" in parameter_names(rep) and "repair.budget" not in parameter_names(gate)
    assert check_setting(rep, "repair.budget", k).value == k
    for value in (k + 1, -1, 1.5):
        with pytest.raises(Refused, match=r"repair\.budget"):
            check_setting(rep, "repair.budget", value)
    names = parameter_names(gate)
    assert names[0] == "channel.noise" and names[-1] == "pace"
    assert len([n for n in names if n.startswith("channel.gains.")]) == 12


def test_calls_are_checked_naming_the_bad_value(gate):
    assert check_call(gate, "influence", {"influence": "d>a={open}"}).value == 1
    assert check_call(gate, "influence", {"influence": "d>a=0"}).value == 0
    c = check_call(gate, "relation", {"unit": "a", "pair": "d>a", "relation": "alliance"})
    assert (c.unit, c.pair, c.alliance) == ("a", ("d", "a"), True)
    assert check_call(gate, "step", {}).by == "window"
    bad = [
        ("influence", {"influence": "d>a"}, "not SRC>DST=VALUE"),
        ("influence", {"influence": "x>a=1"}, "unknown unit 'x'"),
        ("influence", {"influence": "d>a={fly}"}, "not an alternative"),
        ("relation", {"unit": "a", "pair": "d>a", "relation": "friends"}, "alliance or conflict"),
        ("relation", {"unit": "q", "pair": "d>a", "relation": "alliance"}, "unknown unit 'q'"),
        ("step", {"by": "year"}, "not one of window, turn, round"),
        ("pause", {"now": 1}, "unknown key 'now'"),
        ("mark", {"label": "x" * 201}, "at most 200"),
        ("mark", [], "not a JSON object"),
        ("explode", {}, "unknown service 'explode'"),
    ]
    for name, args, why in bad:
        with pytest.raises(Refused, match=why):
            check_call(gate, name, args)


def test_boundaries_and_steps():
    assert [boundary(k, 20) for k in (0, 1, 19, 20, 21)] == [0, 20, 20, 20, 40]
    starts = {"turn": [0, 100, 250], "round": [0, 250]}
    assert step_target("window", 40, 20, starts) == 60
    assert step_target("turn", 40, 20, starts) == 100
    assert step_target("turn", 100, 20, starts) == 260  # on a boundary at or after 250
    assert step_target("round", 250, 20, starts) is None  # none left: to the end


def test_the_truth_accounts_for_an_injected_influence(gate):
    plain = Truth(gate)
    assert plain.decisions["a"]["choice"] == ["open"]
    turns = {
        (t.sender, t.addressee): t.index for t in clean_timeline(gate)[0].schedule if t.round == 1
    }
    steered = Truth(gate, Steered(injected={turns["d", "a"]: 0, turns["d", "b"]: 0}))
    assert steered.trajectory[0][("d", "a")] == 0
    assert steered.decisions["a"]["choice"] == [] and steered.decisions["c"]["choice"] == ["open"]
    reports = [
        {"unit": "d", "steered": {"injected": [[turns["d", "a"], 0]], "held": []}},
        {"unit": "a", "steered": {"injected": [], "held": [["d", "a", True, 1]]}},
        {"unit": "b"},  # a report without it: a unit that took nothing of it
    ]
    got = steered_in(reports)
    assert got is not None and got.injected == {turns["d", "a"]: 0}
    assert got.relations == [("a", ("d", "a"), True, 1)]
    assert steered_in([{"unit": "a"}]) is None  # no report says the run was steered
    assert got.held_by("a", 1) == {("d", "a"): True} and got.held_by("b", 1) == {}


# -- in the world: applied at window boundaries, logged, re-run to agreement ------------------


def run(tmp_path, requests, at=1, scenario="gate", name="steered", **options):
    log = tmp_path / f"{name}.mcap"
    source = options.pop("source", None) or Script(requests, at)
    result = rgtbus.run(scenario, log=log, control=source, **options)
    return result.summary, log, source


def test_injected_influences_change_the_decisions_as_the_forward_task_says(tmp_path):
    summary, log, source = run(
        tmp_path, [svc("influence", influence="d>a=0"), svc("influence", influence="d>b=0")]
    )
    assert summary["error"] is None
    assert summary["outcome"] == "gate: closed"  # a and b were talked out of opening
    assert {u: r["choice"] for u, r in summary["units"].items()} == {
        "a": [], "b": [], "c": ["open"], "d": ["open"],
    }  # fmt: skip
    assert summary["wrong_decisions"] == []  # the truth knows what was injected
    assert summary["steered"] == {"influences": 2, "relations": 0}
    assert source.closed
    calls = _records(log, "/control/service")
    assert [(c["service"], c["applied"], c["round"], c["seq"]) for c in calls] == [
        ("influence", True, 1, 0), ("influence", True, 1, 1),
    ]  # fmt: skip
    assert calls[0]["sample"] % 20 == 0 and calls[0]["t"] == calls[0]["sample"] * 0.005
    assert calls[0]["text"].startswith("influence d>a = 0 in round 1")
    report = verify_log(log)
    assert report.ok, report.verdict()
    assert rgtbus.open_log(log).summary()["steered"] == summary["steered"]
    assert rgtbus.open_log(log).summary()["outcome"] == "gate: closed"


def test_an_unsteered_run_is_unchanged_by_the_machinery(tmp_path):
    plain = rgtbus.run("gate", log=tmp_path / "plain.mcap").summary
    steered, log, _ = run(tmp_path, [])
    for key in ("units", "decisions", "outcome", "sim_seconds", "decode_errors"):
        assert steered[key] == plain[key], key
    assert plain["steered"] is None and steered["steered"] == {"influences": 0, "relations": 0}
    assert verify_log(log).ok


def test_a_noise_change_takes_effect_at_its_boundary_and_not_before(tmp_path):
    base = rgtbus.open_log(rgtbus.run("gate", log=tmp_path / "base.mcap").summary["log"])
    _, log, _ = run(tmp_path, [par("channel.noise", 0.05)], at=4)
    rec = _records(log, "/control/parameter")
    assert [(r["name"], r["from"], r["to"], r["applied"]) for r in rec] == [
        ("channel.noise", 0.0, 0.05, True)
    ]
    t = rec[0]["t"]
    assert t > 0
    before, after = base.decodes(), rgtbus.open_log(log).decodes()
    early = before[before.t < t].reset_index(drop=True)
    assert early.equals(after[after.t < t].reset_index(drop=True))  # not one sample early
    late = after[after.t >= t]
    assert (late.margin.to_numpy() != before[before.t >= t].margin.to_numpy()).any()
    assert verify_log(log).ok


def test_a_gain_change_is_re_run_from_each_senders_pulses(tmp_path):
    summary, log, _ = run(tmp_path, [par("channel.gains.d>a", 0.8)], at=3)
    assert summary["error"] is None
    assert _records(log, "/control/parameter")[0]["applied"]
    assert verify_log(log).ok


def test_refusals_are_answered_and_logged_and_re_run_as_logged(tmp_path):
    requests = [
        svc("influence", influence="q>a=0"),
        par("channel.noise", -3),
        Request("service", "pause", {}, "client 7", refused="not allowed: this run is keyed"),
        svc("resume"),  # not paused
        svc("step"),  # not paused
        par("pace", 5.0),  # an unpaced run (a scripted source)
    ]
    summary, log, _ = run(tmp_path, requests)
    assert summary["error"] is None and summary["outcome"] == "gate: open"
    texts = [r["text"] for r in _records(log, "/control/service")]
    texts += [r["text"] for r in _records(log, "/control/parameter")]
    assert all(t.startswith("refused: ") for t in texts), texts
    assert any("unknown unit 'q'" in t for t in texts)
    assert any("not allowed" in t for t in texts)
    assert any("not paused" in t for t in texts)
    assert any("not paced" in t for t in texts)
    assert verify_log(log).ok


def test_a_late_influence_is_refused_and_a_finished_run_refuses_the_rest(tmp_path):
    _, _, dry = run(tmp_path, [], name="dry")
    late = [svc("influence", influence="d>a=0")]
    # the world's last looks but two (the run's end takes two): d sent all it had to send
    summary, log, _ = run(tmp_path, late, at=dry.looks - 3, name="late")
    (rec,) = _records(log, "/control/service")
    assert rec["text"] == "refused: influence: d has no round left in which to influence a"
    # one that comes as the run ends is refused at its end
    summary, log, _ = run(tmp_path, late, at=10_000, name="ended")
    rec = _records(log, "/control/service")
    assert [r["applied"] for r in rec] == [False]
    assert rec[0]["text"] == "refused: the run ended before it applied"
    assert summary["outcome"] == "gate: open"
    assert verify_log(log).ok


def test_a_relation_a_unit_is_made_to_hold_changes_its_decisions_by_the_truth(tmp_path):
    requests = [svc("relation", unit="a", pair="d>a", relation="alliance"),
                svc("relation", unit="a", pair="a>d", relation="alliance")]  # fmt: skip
    summary, log, _ = run(tmp_path, requests, at=6)
    calls = _records(log, "/control/service")
    assert [c["applied"] for c in calls] == [True, True] and calls[0]["round"] == 1
    assert summary["steered"] == {"influences": 0, "relations": 2}
    assert summary["wrong_decisions"] == []
    held = [m for m in _records(log, "/unit/relations") if m["unit"] == "a"]
    assert held[-1]["installed"]["a-d"] == "alliance"  # its group, as it holds it now
    assert summary["units"]["a"] != rgtbus.run("gate").summary["units"]["a"]
    assert verify_log(log).ok


def test_a_goal_driven_units_influence_can_be_overridden(tmp_path):
    sc = load_scenario("gate_goal")
    goal = sc.goals[0]
    requests = [svc("influence", influence=f"{goal.unit}>{goal.target}=0")]
    summary, log, _ = run(tmp_path, requests, scenario="gate_goal")
    assert summary["wrong_decisions"] == [] and summary["error"] is None
    assert _records(log, "/control/service")[0]["applied"]
    assert verify_log(log).ok


def test_mark_logs_every_units_state(tmp_path):
    _, log, _ = run(tmp_path, [svc("mark", label="here")], at=12)
    marks = _records(log, "/control/service")  # a record a unit, however the run is laid out
    assert [list(m["state"]) for m in marks] == [["a"], ["b"], ["c"], ["d"]]
    assert {m["seq"] for m in marks} == {0} and all(m["text"].endswith(": here") for m in marks)
    assert {"done", "relations", "influences", "decisions", "choice"} <= set(marks[0]["state"]["a"])
    assert verify_log(log).ok


def test_pause_resume_and_step_hold_the_clock_and_change_no_result(tmp_path):
    plain = rgtbus.run("gate").summary
    source = Script([svc("pause")], at=3, on_wait=[svc("step", by="turn"), svc("resume")])
    summary, log, _ = run(tmp_path, [], source=source, realtime=2000.0)
    assert summary["units"] == plain["units"] and summary["outcome"] == plain["outcome"]
    calls = _records(log, "/control/service")
    assert [(c["service"], c["applied"]) for c in calls] == [
        ("pause", True), ("step", True), ("resume", True),
    ]  # fmt: skip
    pause, step, resume = calls
    assert step["sample"] == pause["sample"] and step["until"] > step["sample"]
    assert step["until"] % 20 == 0 and resume["sample"] == step["until"]
    running = [r for _, _, r in source.clocks]
    assert running == [False, True, False, True]  # paused, stepped, paused at its end, resumed
    assert verify_log(log).ok


def test_the_repair_budget_stops_the_asking(tmp_path):
    sc = load_scenario("gate_repair")  # σ = 0.1: a dozen requests
    base = rgtbus.run(sc).summary["repair"]
    summary, log, _ = run(tmp_path, [par("repair.budget", 0)], scenario=sc)
    assert _records(log, "/control/parameter")[0]["to"] == 0
    assert summary["repair"]["requests"] == 0 < base["requests"]
    assert verify_log(log).ok


def test_engines_agree_on_a_steered_run(tmp_path):
    def requests():
        return [par("channel.noise", 0.03), svc("influence", influence="d>c=0")]

    event, log_e, _ = run(tmp_path, requests(), at=5, name="event")
    sample = _records(log_e, "/control/parameter")[0]["sample"]
    # the dense engine gets them placed at that sample (as a run across processes does)
    placed = [r.placed(sample, k) for k, r in enumerate(requests())]
    dense, log_d, _ = run(tmp_path, placed, name="dense", engine="dense")
    assert _records(log_d, "/control/parameter")[0]["sample"] == sample
    assert dense["units"] == event["units"] and dense["decode_errors"] == event["decode_errors"]
    assert [m for m in _records(log_d, "/control/service")] == _records(log_e, "/control/service")
    assert verify_log(log_d).ok


@pytest.mark.parametrize(
    ("extra", "why"),
    [
        (["--control"], "--control goes with --live"),
        (["--control", "--live", "127.0.0.1:0"], "--control goes with --realtime"),
    ],
)
def test_control_without_a_live_paced_run_is_a_one_line_error(tmp_path, extra, why):
    import subprocess
    import sys

    p = subprocess.run(
        [sys.executable, "-m", "rgtbus", "run", "gate", "--log", str(tmp_path / "x.mcap"), *extra],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert p.returncode == 2
    assert why in p.stderr and len(p.stderr.strip().splitlines()) == 1


def test_a_served_steered_log_shows_its_controls_as_they_happened(tmp_path):
    import json

    from rgtbus.telemetry.serve import iter_log

    _, log, _ = run(tmp_path, [svc("influence", influence="d>a=0"), par("channel.noise", 0.01)])
    served = [(topic, t, json.loads(d)) for topic, t, d in iter_log(log) if "/control/" in topic]
    assert [(topic, m["seq"]) for topic, _, m in served] == [
        ("/control/service", 0), ("/control/parameter", 1),
    ]  # fmt: skip
    assert all(t == round(m["t"] * 1e9) for _, t, m in served)  # at the log's own times


# -- the live view's side: the Controller, without a server ----------------------------------


class Client:
    def __init__(self, id: int) -> None:
        self.id = id


def test_the_controller_checks_at_once_and_hands_everything_to_the_run(gate):
    import json

    from foxglove.websocket import Parameter

    from rgtbus.telemetry.control import MAX_REQUEST, Controller

    c = Controller(gate, pace=5.0)
    ok = json.loads(c.call("influence", 3, b'{"influence": "d>a=0"}'))
    assert ok["ok"] is True
    for payload, why in [
        (b"{not json", "not JSON"),
        (b"[1, 2]", "not a JSON object"),
        (b'{"influence": "d>zz=0"}', "unknown unit 'zz'"),
        (b"x" * (MAX_REQUEST + 1), "more than"),
    ]:
        with pytest.raises(Refused, match=why):
            c.call("influence", 3, payload)
    values = c.on_set_parameters(
        Client(3),
        [
            Parameter("channel.noise", value=0.25),
            Parameter("pace", value=-1.0),
            Parameter("x" * 50, value="y" * (2 * MAX_REQUEST)),
        ],
    )
    assert {p.name: p.get_value() for p in values}["channel.noise"] == 0.25
    assert {p.name: p.get_value() for p in values}["pace"] == 5.0
    got = c.take()
    assert [(r.kind, r.name, r.refused is None) for r in got][:2] == [
        ("service", "influence", True), ("service", "influence", False),
    ]  # fmt: skip
    assert [r.who for r in got] == ["client 3"] * len(got)
    huge = got[-1]
    assert huge.refused is not None and "not kept" in huge.value  # the log stays small
    assert c.take() == []
    c.close()
    with pytest.raises(Refused, match="stopping"):
        c.call("pause", 3, b"{}")


def test_a_keyed_controller_lets_only_a_proven_client_steer(gate):
    from foxglove.websocket import Parameter

    from rgtbus.telemetry.control import Controller, control_proof

    key = b"k" * 32
    c = Controller(gate, key=key)
    with pytest.raises(Refused, match="not allowed: this run is keyed"):
        c.call("pause", 1, b"{}")
    with pytest.raises(Refused, match="wrong proof"):
        c.call("auth", 1, b'{"proof": "00"}')
    proof = control_proof(key, c.session)
    assert control_proof(key, "another session") != proof  # a proof is good for one server
    c.call("auth", 2, f'{{"proof": "{proof}"}}'.encode())
    c.call("pause", 2, b"{}")  # the client that proved it
    with pytest.raises(Refused, match="not allowed"):
        c.call("pause", 1, b"{}")  # not the one that did not
    c.on_set_parameters(Client(1), [Parameter("channel.noise", value=0.5)])
    assert {p.name: p.get_value() for p in c.parameters()}["channel.noise"] == 0.0
    got = [(r.name, r.refused is None, r.who) for r in c.take()]
    assert got == [
        ("pause", False, "client 1"), ("auth", False, "client 1"), ("auth", True, "client 2"),
        ("pause", True, "client 2"), ("pause", False, "client 1"),
        ("channel.noise", False, "client 1"),
    ]  # fmt: skip


def test_a_units_clock_drifts_from_its_sample_on_and_the_re_run_agrees(tmp_path):
    sc = load_scenario("robots_on_a_plane")  # clocks of their own, sound delays
    assert "channel.clock.drift.b" in parameter_names(sc)
    assert "channel.clock.drift.b" not in parameter_names(load_scenario("gate"))
    with pytest.raises(Refused, match="share one clock"):
        check_setting(load_scenario("gate"), "channel.clock.drift.b", 10)
    with pytest.raises(Refused, match="within"):
        check_setting(sc, "channel.clock.drift.b", 5000)
    base = rgtbus.run(sc, log=tmp_path / "base.mcap")
    _, log, _ = run(tmp_path, [par("channel.clock.drift.b", 900.0)], at=4, scenario=sc)
    (rec,) = _records(log, "/control/parameter")
    assert (rec["from"], rec["to"], rec["applied"]) == (-35.0, 900.0, True)
    t = rec["t"]
    before = rgtbus.open_log(base.log).decodes()
    after = rgtbus.open_log(log).decodes()
    assert (
        before[before.t < t]
        .reset_index(drop=True)
        .equals(after[after.t < t].reset_index(drop=True))
    )
    heard_by_b = after[(after.t >= t) & (after.unit == "b")]
    was = before[(before.t >= t) & (before.unit == "b")]
    assert len(heard_by_b) and not heard_by_b.reset_index(drop=True).equals(
        was.reset_index(drop=True)
    )  # b hears otherwise from there on
    assert verify_log(log).ok


def test_a_resume_during_a_step_lets_the_run_go_on(tmp_path):
    plain = rgtbus.run("gate").summary
    source = Script([svc("pause"), svc("step", by="round"), svc("resume")], at=3)
    summary, log, _ = run(tmp_path, [], source=source, realtime=2000.0)
    assert summary["units"] == plain["units"]
    calls = _records(log, "/control/service")
    assert [(c["service"], c["applied"]) for c in calls] == [
        ("pause", True), ("step", True), ("resume", True),
    ]  # fmt: skip
    assert calls[2]["text"].endswith("(the step's pause is off)")
    assert verify_log(log).ok


def test_whatever_a_source_sends_the_run_goes_on_and_its_log_stays_small(tmp_path):
    huge = "x" * 1_000_000
    requests = [
        par("channel.noise", math.inf),
        par("channel.noise", math.nan),
        par("channel.noise", huge),
        par(huge, 1.0),
        par("channel.gains.a>b", {"k": (1, b"\xff")}),
        Request("service", "influence", ["not", "an", "object"], "test"),
        Request("service", "mark", {"label": 1e309}, "test"),
        svc("influence", influence="d>a=" + huge),
    ]
    summary, log, _ = run(tmp_path, requests)
    assert summary["error"] is None and summary["outcome"] == "gate: open"
    recs = _records(log, "/control/parameter") + _records(log, "/control/service")
    assert len(recs) == len(requests) and not any(r["applied"] for r in recs)
    assert max(len(json.dumps(r)) for r in recs) < 2000  # what was sent, bounded
    assert [r["value"] for r in recs[:2]] == ["inf", "nan"]
    assert recs[5]["request"] == {"sent": ["not", "an", "object"]}
    assert log.stat().st_size < 200_000
    assert verify_log(log).ok
