"""Code synthesis, superposition and the channel model."""

import math

import numpy as np
import pytest

from rgtbus.errors import RgtbusError
from rgtbus.signal.waveform import (
    Transmission,
    code_length,
    code_waveform,
    hear,
    pulse_instants,
    superpose,
)


def test_pulse_instants_round_t_over_tau():
    w = 3 * math.pi / 2  # period 4/3 s
    assert pulse_instants(w, 0.001, 3).tolist() == [0, 267, 534]
    assert pulse_instants(4 * math.pi / 3, 0.5, 3).tolist() == [100, 400, 700]
    assert code_length(w, 3, 0.001) == 535


def test_superpose_and_collisions():
    a = Transmission(3 * math.pi / 2, 0.001, (0.5, 0.2, 0.5))
    c = Transmission(5 * math.pi / 3, 0.001, (0.2, 0.3, 0.7))
    u = superpose([a, c], 600)
    assert u[0] == pytest.approx(0.7)  # first pulses share sample 0
    assert u[267] == 0.2 and u[240] == 0.3 and np.count_nonzero(u) == 5
    np.testing.assert_array_equal(code_waveform(a.word, a.omega, a.start, 600), superpose([a], 600))


def test_hear_gains_and_seeded_noise():
    a = Transmission(3 * math.pi / 2, 0.001, (0.4, 0.4, 0.4), sender=0)
    b = Transmission(4 * math.pi / 3, 0.001, (0.4, 0.4, 0.4), sender=1)
    g = [[1.0, 0.5], [0.0, 2.0]]
    h = hear([a, b], 700, n_receivers=2, gains=g)
    np.testing.assert_allclose(h[:, 0], superpose([a], 700))
    np.testing.assert_allclose(h[:, 1], 0.5 * superpose([a], 700) + 2 * superpose([b], 700))
    n1 = hear([a], 700, sigma=0.1, seed=3)
    n2 = hear([a], 700, sigma=0.1, seed=3)
    assert np.array_equal(n1, n2) and not np.array_equal(n1, hear([a], 700, sigma=0.1, seed=4))
    assert np.std(n1[:, 0] - superpose([a], 700)) == pytest.approx(0.1, rel=0.15)


def test_waveform_refusals():
    w = 3 * math.pi / 2
    with pytest.raises(RgtbusError, match="past the end"):
        superpose([Transmission(w, 0.001, (0.4, 0.4, 0.4))], 500)
    with pytest.raises(RgtbusError, match="omega"):
        pulse_instants(-1.0, 0.0, 3)
    with pytest.raises(RgtbusError, match="start"):
        pulse_instants(w, -0.1, 3)
    with pytest.raises(RgtbusError, match="pulses"):
        pulse_instants(w, 0.0, 0)
    with pytest.raises(RgtbusError, match="finite"):
        code_waveform((0.4, math.nan), w, 0.0, 600)
    with pytest.raises(RgtbusError, match="not a list"):
        code_waveform(("a",), w, 0.0, 600)
    with pytest.raises(RgtbusError, match="n_samples"):
        superpose([], -1)
    with pytest.raises(RgtbusError, match="sigma"):
        hear([], 10, sigma=-1)
    with pytest.raises(RgtbusError, match="gains of shape"):
        hear([Transmission(w, 0.0, (0.4,), sender=1)], 10, gains=[[1.0]])
    with pytest.raises(RgtbusError, match="n_receivers"):
        hear([], 10, n_receivers=0)
    with pytest.raises(RgtbusError, match="finite"):
        hear([Transmission(w, 0.0, (0.4,))], 10, gains=[[math.inf]])
    with pytest.raises(RgtbusError, match="sender"):
        hear([Transmission(w, 0.0, (0.4,), sender=-1)], 10)
