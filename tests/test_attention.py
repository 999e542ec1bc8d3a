"""Confirmed attention ([timing] attention, the spike anchor's default; docs/protocol.md,
"Attention"): the same logs as the paper's threshold attention on a clean channel, and turns
timed by attention spikes that survive noise where the threshold's do not."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest
from same_run import plain

from rgtbus.errors import RgtbusError
from rgtbus.scenario import parse_scenario
from rgtbus.signal.resonator import clean_first_spike

ROOT = Path(__file__).resolve().parent.parent


def _text(name: str, attention: str | None = None, noise: float | None = None) -> str:
    text = (ROOT / "scenarios" / f"{name}.toml").read_text()
    if attention is not None:
        text = text.replace("[timing]", f'[timing]\nattention = "{attention}"', 1)
    if noise is not None:
        assert "[channel]\nnoise = 0.0" in text
        text = text.replace("[channel]\nnoise = 0.0", f"[channel]\nnoise = {noise}", 1)
    return text


def _messages(run, text: str, engine: str) -> tuple[dict, list]:
    """The run's summary and its log's messages (``run``: the ``logged_run`` fixture): the
    same messages at the same times, simultaneous ones in any order; /run holds wall time."""
    from rgtbus.telemetry import read_log

    summary, data = run(parse_scenario(text, "s.toml"), engine)
    messages, _ = read_log(io.BytesIO(data))
    return summary, sorted(
        (ns, topic, json.dumps(m, sort_keys=True, default=plain))
        for topic, ns, m in messages
        if topic != "/run"
    )


@pytest.mark.parametrize(
    "name, engine",
    [
        ("gate", "event"),
        ("tug_of_war", "event"),
        pytest.param("gate", "dense", marks=pytest.mark.slow),
        pytest.param("example2", "event", marks=pytest.mark.slow),
        pytest.param("example2", "dense", marks=pytest.mark.slow),
        pytest.param("tug_of_war", "dense", marks=pytest.mark.slow),
    ],
)
def test_on_a_clean_channel_confirmed_attention_logs_what_the_paper_s_threshold_logs(
    name, engine, logged_run
):
    """Every spike, decode, pulse, table and decision: the same message at the same time
    (the reaction is where the clean attention spike is, ``clean_first_spike``)."""
    confirmed, a = _messages(logged_run, _text(name), engine)
    _, b = _messages(logged_run, _text(name, "threshold"), engine)
    assert confirmed["error"] is None and a == b
    assert parse_scenario(_text(name), "s.toml").timing.attention == "confirmed"


def test_the_spike_timed_gate_opens_at_a_noise_that_stops_the_threshold_s():
    """σ = 0.02: the paper's threshold attention comes early, late or not at all and the gate
    never opens; confirmed by the ID decode it opens in every seed, on both engines alike."""
    import rgtbus

    noisy = parse_scenario(_text("gate", noise=0.02), "g.toml")
    paper = parse_scenario(_text("gate", "threshold", 0.02), "g.toml")
    assert noisy.timing.anchor == "spike"
    for seed in range(8):
        got = rgtbus.run(noisy, seed=seed).summary
        assert got["error"] is None and got["outcome"] == "gate: open", (seed, got["error"])
        assert rgtbus.run(paper, seed=seed).summary["error"] is not None
    dense = rgtbus.run(noisy, seed=3, engine="dense").summary
    event = rgtbus.run(noisy, seed=3).summary
    skip = {"wall_seconds", "engine", "steps", "bus", "sync", "log"}
    assert {k: v for k, v in dense.items() if k not in skip} == {
        k: v for k, v in event.items() if k not in skip
    }


def test_clean_first_spike_is_when_a_resonator_at_rest_fires_on_the_id():
    """The paper's ID {.4, .4, .4} on 3π/2 fires exactly at its last pulse; too faint (a far
    link) it never fires; the result does not depend on where the pulses sit in time."""
    import math

    from rgtbus.signal.resonator import ResonatorBank

    omega, tau = 3 * math.pi / 2, 0.005
    offsets = (0, 267, 533)
    word = (0.4, 0.4, 0.4)
    k = clean_first_spike(omega, "paper", tau, word, offsets, 1.0, 800)
    assert k == offsets[-1]
    assert clean_first_spike(omega, "paper", tau, word, offsets, 0.5, 800) is None
    u = [0.0] * 1500
    for o, m in zip(offsets, word, strict=True):
        u[700 + o] = m
    spikes = ResonatorBank([omega], mode="paper", tau=tau).feed(u).spikes
    assert int(spikes[0, 0]) == 700 + k


def test_an_unknown_attention_is_one_line_naming_file_line_and_key():
    with pytest.raises(RgtbusError) as e:
        parse_scenario(_text("gate", "sometimes"), "bad.toml")
    msg = str(e.value)
    assert msg.startswith("bad.toml:") and "timing.attention: unknown attention 'sometimes'" in msg
