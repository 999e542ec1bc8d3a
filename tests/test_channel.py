"""The channel's geometry: unit positions and the path loss of the distances between them
(``rgtbus.signal.channel``, ``[channel] positions / path_loss / reference_distance``)."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pytest

from rgtbus.errors import RgtbusError
from rgtbus.scenario import parse_scenario
from rgtbus.signal.channel import link_gains, path_loss_gain

ROOT = Path(__file__).resolve().parent.parent
GATE = (ROOT / "scenarios" / "gate.toml").read_text()
CHANNEL = "[channel]\nnoise = 0.0\n"
assert CHANNEL in GATE


def gate_with(lines: str, name: str = "geo.toml"):
    return parse_scenario(GATE.replace(CHANNEL, CHANNEL + lines, 1), name)


def test_path_loss_is_the_root_of_the_power_law_beyond_the_reference_distance():
    d = np.array([0.0, 0.5, 1.0, 2.0, 10.0])
    assert path_loss_gain(d, 2.0, 1.0).tolist() == [1.0, 1.0, 1.0, 0.5, 0.1]  # free space
    assert np.allclose(path_loss_gain(d, 4.0, 1.0), [1, 1, 1, 0.25, 0.01])
    assert np.allclose(path_loss_gain(d * 3, 3.0, 3.0), path_loss_gain(d, 3.0, 1.0))  # scale
    assert path_loss_gain(d, 0.0, 1.0).tolist() == [1.0] * 5  # n = 0: no loss


def test_link_gains_multiply_the_given_gain_by_the_loss_and_are_symmetric_without_it():
    units = ("a", "b", "c")
    pos = {"a": (0.0, 0.0, 0.0), "b": (3.0, 4.0, 0.0), "c": (0.0, 0.0, 20.0)}
    g = link_gains(units, {("a", "b"): 0.9}, pos, 2.0, 1.0)
    assert set(g) == {(s, r) for s in units for r in units if s != r}  # never a unit to itself
    assert g[("a", "b")] == pytest.approx(0.9 / 5) and g[("b", "a")] == pytest.approx(1 / 5)
    assert g[("a", "c")] == g[("c", "a")] == pytest.approx(1 / 20)
    assert g[("b", "c")] == pytest.approx(1 / math.sqrt(9 + 16 + 400))
    # no positions, or no loss: exactly the given gains, nothing added
    assert link_gains(units, {("a", "b"): 0.9}, {}, 2.0, 1.0) == {("a", "b"): 0.9}
    assert link_gains(units, {("a", "b"): 0.9}, pos, 0.0, 1.0) == {("a", "b"): 0.9}


def test_a_scenario_places_its_units_and_their_links_lose_with_distance():
    sc = gate_with(
        'path_loss = "free-space"\nreference_distance = 5.0\n'
        "positions = { a = [0, 0], b = [10, 0], c = [0, 0, 5], d = [3, 4] }\n"
    )
    ch = sc.channel
    assert ch.positions["c"] == (0.0, 0.0, 5.0) and ch.positions["a"] == (0.0, 0.0, 0.0)
    assert ch.distance("a", "b") == 10.0 and ch.path_loss == 2.0 and ch.reference_distance == 5
    assert ch.gains[("a", "b")] == pytest.approx(0.5) and ch.gains[("a", "d")] == 1.0
    assert ch.gain_row(sc.units, "a").tolist()[0] == 1.0  # a unit hears itself at 1
    assert not ch.unit_gains


def test_without_positions_the_channel_is_as_before():
    plain = parse_scenario(GATE, "gate.toml").channel
    assert plain.positions == {} and plain.path_loss == 0.0 and plain.gains == {}
    assert plain.unit_gains
    near = gate_with(  # all within the reference distance: no link loses anything
        "path_loss = 3.5\nreference_distance = 50\n"
        "positions = { a = [0, 0], b = [1, 2], c = [-3, 4], d = [5, 5] }\n"
    ).channel
    assert near.unit_gains and set(near.gains.values()) == {1.0}


@pytest.mark.parametrize(
    "lines, says",
    [
        ("path_loss = 2.0\n", "channel.path_loss: needs [channel.positions]"),
        ("reference_distance = 2.0\n", "channel.reference_distance: needs [channel.positions]"),
        ("positions = [1, 2]\n", "channel.positions: must be a table"),
        ("positions = { a = [0, 0] }\n", "b, c, d have none"),
        ("positions = { a = [0, 0], b = [0, 0], c = [1, 1] }\n", "d has none"),
        ("positions = { a = [0, 0], b = [1, 1], c = [2, 2], d = [3, 3], e = [1, 1] }\n",
         "channel.positions.e: unknown unit 'e'"),
        ("positions = { a = [0], b = [1, 1], c = [2, 2], d = [3, 3] }\n",
         "channel.positions.a: must be [x, y] or [x, y, z]"),
        ("positions = { a = [0, 0, 0, 0], b = [1, 1], c = [2, 2], d = [3, 3] }\n",
         "channel.positions.a"),
        ("positions = { a = [0, nan], b = [1, 1], c = [2, 2], d = [3, 3] }\n",
         "channel.positions.a"),
        ("positions = { a = [0, 1e7], b = [1, 1], c = [2, 2], d = [3, 3] }\n",
         "channel.positions.a"),
        ('positions = { a = [0, "x"], b = [1, 1], c = [2, 2], d = [3, 3] }\n',
         "channel.positions.a"),
        ('positions = { a = [0, 0], b = [1, 1], c = [2, 2], d = [3, 3] }\npath_loss = "air"\n',
         'channel.path_loss: must be "free-space" or an exponent in [0, 10], got \'air\''),
        ("positions = { a = [0, 0], b = [1, 1], c = [2, 2], d = [3, 3] }\npath_loss = -1\n",
         "channel.path_loss"),
        ("positions = { a = [0, 0], b = [1, 1], c = [2, 2], d = [3, 3] }\npath_loss = true\n",
         "channel.path_loss"),
        ("positions = { a = [0, 0], b = [1, 1], c = [2, 2], d = [3, 3] }\n"
         "reference_distance = 0\n", "channel.reference_distance: must be a distance"),
        ("positions = { a = [0, 0], b = [1, 1], c = [2, 2], d = [3, 3] }\n"
         "reference_distance = inf\n", "channel.reference_distance"),
        ("place = 1\n", "channel.place"),
    ],
)  # fmt: skip
def test_bad_geometry_is_one_line_naming_file_line_and_key(lines, says):
    with pytest.raises(RgtbusError) as e:
        gate_with(lines, "geo.toml")
    msg = str(e.value)
    assert says in msg and msg.startswith("geo.toml:") and "\n" not in msg, msg


@pytest.mark.parametrize(
    "positions, opens",
    [
        # a square of 2.9 m: the diagonals (4.1 m) lose 2.5 % under free space from 4 m
        ("a = [0, 0], b = [2.9, 0], c = [0, 2.9], d = [2.9, 2.9, 0.1]", True),
        # 6 m apart: pulses at two thirds (the diagonals a half) of their strength never fire
        # the attention spike; confirmed attention finds each ID against silence at its
        # link's gain and the gate opens; the paper's threshold attention ends the run in one
        # line naming the missed spike
        ("a = [0, 0], b = [6, 0], c = [0, 6], d = [6, 6]", True),
        ("a = [0, 0], b = [6, 0], c = [0, 6], d = [6, 6]", "threshold"),
    ],
)
def test_a_placed_run_is_the_run_of_its_link_gains_on_both_engines_and_verifies(
    positions, opens, logged_run
):
    """Units a few metres apart under free-space loss: the run equals the one whose
    [channel.gain] lists the same gains, on either engine, and its log (which carries the
    scenario, positions and all) replays and verifies, whether the gate opens or not."""
    from rgtbus.units.rerun import verify_log

    from rgtbus.telemetry.read import load_replay

    placed = gate_with(
        f'path_loss = "free-space"\nreference_distance = 4.0\npositions = {{ {positions} }}\n'
    )
    threshold = opens == "threshold"
    if threshold:
        text = placed.text.replace("[timing]", '[timing]\nattention = "threshold"', 1)
        placed, opens = parse_scenario(text, "geo.toml"), False
    assert min(placed.channel.gains.values()) < 1.0  # the links do lose
    table = "".join(f'"{s}>{r}" = {g!r}\n' for (s, r), g in placed.channel.gains.items())
    listed = parse_scenario(
        placed.text.replace(CHANNEL, CHANNEL + "[channel.gain]\n" + table, 1)
        .replace('path_loss = "free-space"', "")
        .replace("reference_distance = 4.0", "")
        .replace(f"positions = {{ {positions} }}", ""),
        "listed.toml",
    )
    summaries = {}
    for engine in ("event", "dense"):
        summary, data = logged_run(placed, engine)
        summaries[engine] = summary
        rp = load_replay(io.BytesIO(data))
        assert rp.scenario.channel.gains == placed.channel.gains
        assert rp.scenario.channel.positions == placed.channel.positions
        assert verify_log(rp).ok
    same, _ = logged_run(listed)
    skip = {"wall_seconds", "engine", "steps", "bus", "sync", "log", "scenario"}  # not results
    assert (summaries["event"]["error"] is None) is opens
    if threshold:
        assert "no ID spike" in summaries["event"]["error"]
    for other in (summaries["dense"], same):
        assert {k: v for k, v in summaries["event"].items() if k not in skip} == {
            k: v for k, v in other.items() if k not in skip
        }


# -- noise in bursts (Gilbert–Elliott) ---------------------------------------------------------


def _states(seed: int = 4):
    from rgtbus.signal.channel import Burst, BurstStates

    return BurstStates(Burst(0.3, every=2.0, length=0.5), 0.01, np.random.default_rng(seed))


def test_bursts_are_the_same_however_the_samples_are_asked_for():
    whole = _states().in_burst(0, 20_000)
    rng = np.random.default_rng(9)
    cuts = np.sort(rng.choice(np.arange(1, 20_000), 40, replace=False)).tolist()
    states, pieces = _states(), []
    for lo, hi in zip([0, *cuts], [*cuts, 20_000], strict=True):
        pieces.append(states.in_burst(lo, hi))
    assert np.array_equal(np.concatenate(pieces), whole)
    again = _states()  # asking again from a later sample, the earlier ones dropped
    again.in_burst(0, 5000)
    assert np.array_equal(again.in_burst(5000, 20_000), whole[5000:])


def test_bursts_come_as_often_and_last_as_long_as_asked():
    bursting = _states().in_burst(0, 2_000_000)  # 20,000 s of 10 ms samples
    assert not bursting[0]  # calm at the start
    assert bursting.mean() == pytest.approx(0.5 / 2.5, rel=0.05)  # length / (every + length)
    starts = np.flatnonzero(np.diff(bursting.astype(int)) == 1)
    assert len(starts) / 20_000 == pytest.approx(1 / 2.5, rel=0.05)  # one each 2.5 s


def test_a_receiver_s_noise_in_bursts_is_its_calm_noise_scaled_where_it_bursts():
    from rgtbus.engine.hearing import Listener
    from rgtbus.signal.channel import noise_rng

    def listener(bursts):
        return Listener("a", np.ones(2), 0.01, noise_rng(7, 0), keep=10, bursts=bursts)

    calm = listener(None).noise_for(0, 30_000)
    burst = listener(_states()).noise_for(0, 30_000)
    where = _states().in_burst(0, 30_000)
    assert where.any() and not where.all()
    assert np.array_equal(burst[~where], calm[~where])  # the same draws
    assert np.allclose(burst[where], calm[where] * 30)  # σ_b = 0.3 instead of 0.01
    noiseless = Listener("a", np.ones(2), 0.0, noise_rng(7, 0), keep=10, bursts=_states())
    assert noiseless.noisy and not listener(None).bursts
    assert set(np.flatnonzero(noiseless.noise_for(0, 30_000))) == set(np.flatnonzero(where))


@pytest.mark.parametrize(
    "lines, says",
    [
        ("burst = 3\n", "channel.burst: must be a table"),
        ("[channel.burst]\nnoise = 0.1\nevery = 2\n", "channel.burst: needs 'length'"),
        ("[channel.burst]\nnoise = 0\nevery = 2\nlength = 1\n", "channel.burst.noise"),
        ("[channel.burst]\nnoise = nan\nevery = 2\nlength = 1\n", "channel.burst.noise"),
        ("[channel.burst]\nnoise = 0.1\nevery = 0\nlength = 1\n", "channel.burst.every"),
        ("[channel.burst]\nnoise = 0.1\nevery = 2\nlength = -1\n", "channel.burst.length"),
        ('[channel.burst]\nnoise = 0.1\nevery = 2\nlength = "1"\n', "channel.burst.length"),
        ("[channel.burst]\nnoise = 0.1\nevery = 2\nlength = 1\nsigma = 1\n",
         "channel.burst.sigma: unknown key"),
    ],
)  # fmt: skip
def test_bad_bursts_are_one_line_naming_file_line_and_key(lines, says):
    test_bad_geometry_is_one_line_naming_file_line_and_key(lines, says)


@pytest.mark.parametrize(
    "burst, length, attention, fails",
    [
        (0.002, 0.2, "confirmed", False),
        (0.2, 0.5, "threshold", True),  # the paper's attention: a missed spike ends the run
        pytest.param(0.2, 0.5, "confirmed", False, marks=pytest.mark.slow),  # misreads, and
        # the gate opens all the same
    ],
)
def test_a_run_with_bursts_is_the_same_on_both_engines_and_verifies(
    burst, length, attention, fails, logged_run
):
    """Short, faint bursts on a calm channel leave the gate open; strong ones end the run
    with the paper's threshold attention (a misread or a missed spike), and make misreads
    with the confirmed one. Either way both engines make the same run and its log, which
    carries the scenario, replays and verifies (the bursts drawn again from the seed)."""
    from rgtbus.units.rerun import verify_log

    from rgtbus.telemetry.read import load_replay

    sc = gate_with(f"[channel.burst]\nnoise = {burst}\nevery = 3.0\nlength = {length}\n")
    sc = parse_scenario(sc.text.replace("[timing]", f'[timing]\nattention = "{attention}"'), "b")
    assert sc.channel.noisy and sc.channel.noise == 0.0
    skip = {"wall_seconds", "engine", "steps", "bus", "sync", "log", "scenario"}  # not results
    summaries = []
    for engine in ("event", "dense"):
        summary, data = logged_run(sc, engine)
        summaries.append({k: v for k, v in summary.items() if k not in skip})
        rp = load_replay(io.BytesIO(data))
        assert rp.scenario.channel.burst == sc.channel.burst
        assert verify_log(rp).ok
    assert summaries[0] == summaries[1]
    assert (summaries[0]["error"] is not None) is fails
    assert bool(summaries[0]["decode_errors"]["misread"]) is (burst > 0.1)


# -- delays and clocks ---------------------------------------------------------------------------


def test_a_pulse_off_its_sample_is_split_between_two_and_keeps_its_size_and_centre():
    from rgtbus.signal.channel import render

    samples, values = np.array([10, 20, 21]), np.array([0.4, -0.2, 0.7])
    same = render(samples, values, 0.0, 1.0)
    assert same[0] is samples and same[1] is values  # on its samples: untouched
    for a, b in [(2.25, 1.0), (-1.6, 1.00003), (0.5, 0.99995), (3.0, 1.0)]:
        rows, vals = render(samples, values, a, b)
        assert (np.diff(rows) >= 0).all() and vals.sum() == pytest.approx(values.sum())
        for j, m in zip(samples, values, strict=True):  # each pulse alone: size and centre
            r, v = render(np.array([j]), np.array([m]), a, b)
            x = a + b * j
            assert v.sum() == pytest.approx(m) and (r * v).sum() / m == pytest.approx(x)
            assert r[0] == np.floor(x) and len(r) <= 2
        if a == 3.0:
            assert list(rows) == [13, 23, 24] and np.allclose(vals, values)  # whole samples


def test_arrivals_follow_distance_speed_offset_and_drift():
    from rgtbus.signal.channel import Channel, Clock

    ch = Channel(
        positions={"a": (0.0, 0.0, 0.0), "b": (3.43, 0.0, 0.0)},
        speed=343.0,
        clocks={"a": Clock(0.002, 0.0), "b": Clock(0.0, 100.0)},
    )
    tau = 0.005
    assert ch.timed and ch.delay("a", "b") == pytest.approx(0.01)
    at_b = ch.arrivals(["a", "b"], "b", tau)
    # a's sample j is sent at 0.002 + j·τ, lands 10 ms later; b samples at k·τ·(1 + 1e-4)
    for j in (0, 1000, 20000):
        true = 0.002 + j * tau + 0.01
        assert at_b[0, 0] + at_b[1, 0] * j == pytest.approx(true / (tau * (1 + 1e-4)))
    assert at_b[0, 1] == 0.0 and at_b[1, 1] == 1.0  # b hears itself on its own samples
    assert not Channel().timed and not Channel(clocks={"a": Clock()}).timed


def test_a_two_sample_read_gets_a_pulse_split_between_the_samples_whole():
    from rgtbus.signal.decoder import ReadoutHistory

    h = ReadoutHistory(1, 100, 1, window=2)
    rows = np.array([10, 11, 30])
    h.store(0, 40, rows, np.array([0.3, 0.1, 0.4]).reshape(3, 1, 1))
    assert h.values([10, 30, 20], 0).tolist() == pytest.approx([0.4, 0.4, 0.0])
    assert np.allclose(h.gather(np.array([[10, 29]]), np.array([0]))[0], [[0.4, 0.4]])
    with pytest.raises(RgtbusError, match="outside"):
        h.values([39], 0)  # its second sample is not heard yet
    with pytest.raises(RgtbusError, match="window"):
        ReadoutHistory(1, 100, 1, window=3)


ROBOTS = (ROOT / "scenarios" / "robots_on_a_plane.toml").read_text()


@pytest.mark.parametrize(
    "old, new, says",
    [
        ("speed = 343.0", "speed = -1", "channel.speed: must be m/s > 0"),
        ("speed = 343.0", 'speed = "fast"', "channel.speed: must be m/s > 0"),
        ("offset = { a = 0.0012,", "offset = { a = 2.0,",
         "channel.clock.offset.a: must be seconds"),
        ("drift = { a = 20,", "drift = { a = 5000,", "channel.clock.drift.a: must be ppm"),
        ("drift = { a = 20,", "drift = { zed = 20,", "zed"),
        ("[channel.clock]", "[channel.clock]\nskew = 1", "channel.clock.skew: unknown key"),
        # the clocks come apart by 0.27 s within the default hour: beyond half the lookahead
        ("drift = { a = 20,", "drift = { a = 40,", "channel.clock.drift: the clocks come"),
        ("search = 6 ", "search = 6\nanchor = \"schedule\" ", "channel.speed: delays and clocks"),
        ("search = 6 ", 'search = 6\nattention = "threshold" ', "need turns that follow"),
        ("search = 6 ", "search = 65 ", "timing.search: must be an integer 0..64"),
        ("[channel.clock]", '[protocol]\nschedule = "concurrent"\n[channel.clock]',
         "channel.speed: delays and clocks need turns that follow what each unit hears"),
    ],
)  # fmt: skip
def test_bad_delays_and_clocks_are_one_line_naming_file_line_and_key(old, new, says):
    assert old in ROBOTS
    with pytest.raises(RgtbusError) as e:
        parse_scenario(ROBOTS.replace(old, new, 1), "robots.toml")
    msg = str(e.value)
    assert says in msg and msg.startswith("robots.toml:") and "\n" not in msg, msg


def test_speed_needs_positions():
    with pytest.raises(RgtbusError, match=r"channel\.speed: needs \[channel\.positions\]"):
        gate_with("speed = 343\n")


def test_robots_on_a_plane_are_the_same_on_both_engines_replay_and_verify(logged_run):
    """Distances, sound delays (fractional), drifting clocks, noise and bursts: both engines
    make the same run, the gate opens, and the log (which carries all of it) verifies."""
    from rgtbus.units.rerun import verify_log

    from rgtbus.telemetry.read import load_replay

    sc = parse_scenario(ROBOTS, "robots.toml")
    assert sc.channel.timed and sc.channel.noisy and sc.channel.burst is not None
    delays = [sc.channel.delay(s, r) / sc.timing.tau for s, r in sc.pairs()]
    assert max(delays) > 2 and any(d % 1 > 0.2 for d in delays)  # off the samples, far
    skip = {"wall_seconds", "engine", "steps", "bus", "sync", "log", "scenario"}
    summaries = []
    for engine in ("event", "dense"):
        summary, data = logged_run(sc, engine)
        summaries.append({k: v for k, v in summary.items() if k not in skip})
        rp = load_replay(io.BytesIO(data))
        assert rp.scenario.channel == sc.channel and rp.has_gains()
        assert verify_log(rp).ok
    assert summaries[0] == summaries[1]
    assert summaries[0]["error"] is None and summaries[0]["outcome"] == "gate: open"


def test_the_timing_search_is_what_follows_the_delays():
    """Without a search wide enough for the delays the robots lose an ID; with it, not."""
    import rgtbus

    narrow = parse_scenario(ROBOTS.replace("search = 6", "search = 1", 1), "robots.toml")
    s = rgtbus.run(narrow, seed=1).summary
    assert s["error"] is not None and "no ID heard" in s["error"]
    assert rgtbus.run(parse_scenario(ROBOTS, "robots.toml"), seed=1).summary["error"] is None


def test_robots_on_a_plane_over_zenoh_equal_the_memory_run():
    """The same run over the zenoh bus (one process, loopback) as over the memory bus."""
    import rgtbus

    sc = parse_scenario(ROBOTS, "robots.toml")
    skip = {"wall_seconds", "engine", "steps", "bus", "sync", "log", "scenario"}
    runs = [
        {k: v for k, v in rgtbus.run(sc, seed=2, bus=bus).summary.items() if k not in skip}
        for bus in ("memory", "zenoh")
    ]
    assert runs[0] == runs[1] and runs[0]["error"] is None


def test_a_scenario_holds_its_channel_so_alike_is_worked_out_once_a_run(monkeypatch):
    """``Scenario.channel`` is the section the loader built, one object (it was rebuilt from
    flat fields at every access, and every unit asked whether the medium is heard alike:
    n² work n times, 2.64 s at 300 units). A variation is a replaced section."""
    from dataclasses import replace
    from functools import cached_property

    from rgtbus.units.group import run_group

    from rgtbus.signal.channel import Channel
    from rgtbus.telemetry import NullRecorder

    calls: list[int] = []
    work = Channel.__dict__["alike"].func

    def counted(self: Channel) -> bool:
        calls.append(1)
        return work(self)

    alike = cached_property(counted)
    alike.__set_name__(Channel, "alike")
    monkeypatch.setattr(Channel, "alike", alike)
    sc = parse_scenario(GATE, "gate.toml")
    noisy = replace(sc, channel=replace(sc.channel, noise=0.02))
    assert noisy.channel is noisy.channel and noisy.channel.noise == 0.02
    assert sc.channel.noise == 0.0 and noisy.units == sc.units
    before = len(calls)
    run_group(noisy, "memory", NullRecorder())
    assert len(calls) == before + 1  # the new channel's, once for all four units


def test_rayleigh_fading_has_unit_mean_power_and_each_receiver_draws_its_own():
    """|h| = sqrt((x² + y²) / 2): E|h|² = 1 over many links, 1 on a unit's own link, the
    same draws for a receiver whatever the others, and apart from its noise's draws."""
    from rgtbus.signal.channel import fading_amplitudes, noise_rng

    rows = np.array([fading_amplitudes("rayleigh", 7, r, 400) for r in range(400)])
    assert np.all(np.diag(rows) == 1.0)
    power = rows[~np.eye(400, dtype=bool)] ** 2
    assert abs(power.mean() - 1.0) < 0.02  # 159,600 links: the mean's sd is 0.0025
    assert abs(np.median(power) - math.log(2)) < 0.02  # exponential power: median ln 2
    assert np.array_equal(fading_amplitudes("rayleigh", 7, 3, 400), rows[3])
    assert not np.array_equal(fading_amplitudes("rayleigh", 8, 3, 400), rows[3])
    assert np.all(fading_amplitudes("none", 7, 3, 5) == 1.0)
    assert noise_rng(7, 3).standard_normal() == np.random.default_rng([7, 3, 1]).standard_normal()
    with pytest.raises(ValueError, match="unknown fading 'rician'"):
        fading_amplitudes("rician", 7, 3, 5)


def test_a_faded_channel_is_not_heard_alike_and_a_bad_fading_is_one_line():
    faded = gate_with('fading = "rayleigh"\n').channel
    assert faded.fading == "rayleigh" and not faded.alike and not faded.unit_gains
    assert gate_with("").channel.alike
    with pytest.raises(RgtbusError, match=r"channel\.fading: unknown fading 'rician' \(none, "):
        gate_with('fading = "rician"\n', "bad.toml")


@pytest.mark.parametrize("engine", ["event", "dense"])
def test_units_hear_and_decode_through_their_faded_links_and_the_log_verifies(engine, logged_run):
    """Each receiver the engine builds hears its links faded (``Reception``) and its unit
    decodes on those gains: the shipped gate_fading opens its gate, both engines alike, and
    its log re-runs to the same records (``replay --verify``)."""
    from dataclasses import replace

    from rgtbus.units.rerun import verify_log

    from rgtbus.engine.listener import OwnHearing, Reception
    from rgtbus.scenario import load_scenario
    from rgtbus.signal.channel import fading_amplitudes
    from rgtbus.telemetry.read import load_replay

    sc = load_scenario(ROOT / "scenarios" / "gate_fading.toml")
    heard = Reception(sc.channel, sc.units, sc.seed, sc.timing.tau)
    for r, u in enumerate(sc.units):
        gains = heard.listener(u, OwnHearing(keep=10)).gains
        assert np.array_equal(gains, fading_amplitudes("rayleigh", sc.seed, r, 4))
        assert len(set(gains.round(6))) == 4  # every link its own
    summary, data = logged_run(sc, engine)
    assert summary["outcome"] == "gate: open" and summary["decode_errors"]["misread"] == 0
    assert verify_log(load_replay(io.BytesIO(data))).ok
    nearest = replace(sc, decoding="nearest")  # it ships with the matched filter
    worse = [logged_run(nearest.with_seed(seed), engine)[0] for seed in (1, 4)]
    assert all(
        s["decode_errors"]["misread"] for s in worse
    )  # a deep fade or a strong link misreads


@pytest.mark.parametrize("engine", ["event", "dense"])
def test_the_matched_filter_rule_reads_faded_links_that_the_nearest_word_misreads(
    engine, logged_run
):
    """``decoding = "matched-filter"`` (a scenario's second rule, rgtbus.signal.rules): over
    faded links and no noise every code is read right, seeds where the nearest word (which
    weighs words by their length too) misreads included; its log re-runs to the same records."""
    from dataclasses import replace

    from rgtbus.units.rerun import verify_log

    from rgtbus.scenario import load_scenario
    from rgtbus.telemetry.read import load_replay

    text = (ROOT / "scenarios" / "gate_fading.toml").read_text()
    matched = load_scenario(ROOT / "scenarios" / "gate_fading.toml")
    assert matched.decoding == "matched-filter"  # as it ships
    nearest = replace(matched, decoding="nearest")
    misread = [
        s for s in (1, 4) if logged_run(nearest.with_seed(s), engine)[0]["decode_errors"]["misread"]
    ]
    assert misread == [1, 4]
    for seed in (1, 4):
        summary, data = logged_run(replace(matched, seed=seed), engine)
        assert summary["decode_errors"]["misread"] == 0 and summary["outcome"] == "gate: open"
        assert verify_log(load_replay(io.BytesIO(data))).ok
    with pytest.raises(RgtbusError, match=r"decoding: unknown decoding rule 'ml' \(nearest, "):
        parse_scenario(text.replace('decoding = "matched-filter"', 'decoding = "ml"'), "x.toml")


FLEET = """name = "fleet"
seed = 9
units = ["rover_A", "b2", "kilo", "Zed", "m_4", "nine", "q"]
actions = ["go", "wait"]
frequencies = "auto"
decoding = "matched-filter"
[timing]
anchor = "schedule"
[protocol]
schedule = "serial"
[channel]
noise = 0.02
fading = "rayleigh"
[relations]
policy = "random"
p = 0.5
[influences]
policy = "random"
"""


def test_over_noisy_faded_links_the_matched_filter_reads_a_group_the_nearest_word_misreads():
    """Seven units of other names, two actions, noise and fading, the serial schedule: the
    matched filter reads payloads (IDs stay with the nearest word, which must read the
    ID-code or the turn fails) with far fewer misreads than the nearest word, and no turn
    fails; under the concurrent schedule the loader refuses it in one line."""
    from dataclasses import replace

    from rgtbus.units.group import run_group

    from rgtbus.telemetry import NullRecorder

    matched = parse_scenario(FLEET, "fleet.toml")
    got = {}
    for sc in (matched, replace(matched, decoding="nearest")):
        summary = run_group(sc, "memory", NullRecorder()).summary
        assert summary["error"] is None
        got[sc.decoding] = summary["decode_errors"]["misread"]
    assert got["matched-filter"] * 4 < got["nearest"], got
    with pytest.raises(RgtbusError, match=r"fleet.toml:6: decoding: 'matched-filter' reads the "):
        concurrent = FLEET.replace('schedule = "serial"', 'schedule = "concurrent"')
        parse_scenario(concurrent, "fleet.toml")
