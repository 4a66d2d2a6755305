"""A long run's tyre pass in two pieces, one on each core (online_id/model/pieces.py, issue 40): the same block means,
outputs and sensitivities as the whole pass, whatever the number of threads; where the pieces do not meet, the whole
pass's numbers bit for bit."""

from types import SimpleNamespace

import numpy as np
import pytest

from online_id.model import pieces, tyres
from online_id.util.threads import THREADS_ENV
from online_id.vehicle.loader import load_vehicle
from online_id.vehicle.parameters import axle_loads_at

VEHICLE = load_vehicle("revs_250lm")
KN = tyres.known_array(VEHICLE.known)
#: the race car's load_sensitivity fit (diagnose, README step 4): relaxation lengths at the floor, tyres saturating
THETA = np.array([1268.6, 200.0, 62833.2, 114540.4, 3500.0, 120000.0, 0.05, 0.05])
MU = np.array([1.15, 1.22])


def _run(seconds, rate=100.0, seed=0, steer=(0.01, 0.02)):
    """A lapping car's inputs: steering up to 0.06 rad at 0.2-1.5 Hz, speed 18-38 m/s, loads moved by ±8 m/s² of a_x."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / rate)
    delta = sum(a * np.sin(2 * np.pi * f * t + p) for a, f, p in zip(rng.uniform(*steer, 4),
                                                                     (0.2, 0.5, 0.9, 1.5), rng.uniform(*steer, 4)))
    speed = 28.0 + 10.0 * np.sin(2 * np.pi * 0.03 * t)
    ax = np.gradient(speed, t) * 4.0
    W = np.zeros((len(t), 4))
    W[:, 0] = delta
    W[:-1, 1] = np.diff(delta)  # (a linear input between samples: the stages take δ where the line is)
    return W, speed, np.ascontiguousarray(axle_loads_at(VEHICLE.known, ax)), 1.0 / rate


class _Calls(list):
    rows: list


def _spied(monkeypatch) -> _Calls:
    """The pieces' passes, as called (pieces.py's ``tyres`` seen through a spy); ``rows``: each call's samples."""
    calls = _Calls()
    rows = calls.rows = []
    spy = SimpleNamespace(**{k: getattr(tyres, k) for k in dir(tyres) if not k.startswith("__")})
    spy.states_and_outputs_from = lambda *a: calls.append("states") or rows.append(len(a[3])) or \
        tyres.states_and_outputs_from(*a)
    spy.blocks_from = lambda *a: calls.append("blocks") or rows.append(len(a[3])) or tyres.blocks_from(*a)
    monkeypatch.setattr(pieces, "tyres", spy)
    return calls


@pytest.mark.parametrize("rate, q, seconds", [(100.0, 10, 90.0), (25.0, 3, 90.5), (10.0, 1, 90.0)])
def test_a_long_run_in_two_pieces_is_the_whole_pass(rate, q, seconds, monkeypatch):
    """At 100, 25 and 10 Hz, in blocks of 10, 3 and 1 samples (a 10 Hz log's: the piece's last step takes the loads of
    the sample after it, which is in no block of the piece), a run that is not a whole number of blocks too."""
    W, V, Fz, dt = _run(seconds, rate)
    assert pieces.split_points(len(W), dt) is not None
    states, Y = tyres.rk4_states_and_outputs_input(THETA, MU, Fz, W, V, dt, KN)
    Yb, dYb = tyres.simulate_blocks_input(THETA, MU, Fz, W, V, dt, KN, q, 2, 0.002, True)
    assert np.abs(Y[:, 3]).max() > 6.0  # (0.7 g: the tyres at 60 % of their peak)
    answers = {}
    calls = _spied(monkeypatch)
    for threads in ("1", "2"):
        monkeypatch.setenv(THREADS_ENV, threads)
        answers[threads] = (*pieces.states_and_outputs(THETA, MU, Fz, W, V, dt, KN),
                            *pieces.blocks(THETA, MU, Fz, W, V, dt, KN, q, 2, 0.002, True))
    assert calls == ["states", "states", "blocks", "blocks"] * 2  # the pieces met: two passes each, not three
    for a, b in zip(answers["1"], answers["2"]):  # the split is the run's, not the machine's: bit for bit
        assert np.array_equal(a, b)
    got_states, got_Y, got_Yb, got_dYb = answers["2"]
    for got, whole in ((got_states, states), (got_Y, Y), (got_Yb, Yb), (got_dYb, dYb)):
        assert got.shape == whole.shape
        assert np.abs(got - whole).max() <= 1e-12 * np.abs(whole).max()


def test_pieces_that_do_not_meet_where_they_should_are_joined_where_they_do(monkeypatch):
    """Started from rest 3 s before the half, the second piece has not quite forgotten its start where the pieces meet
    (2e-9 of the scale): the run is simulated again from the first piece's state, 5 s at a time, until the second
    piece meets it."""
    monkeypatch.setattr(pieces, "OVERLAP_S", 3.0)
    W, V, Fz, dt = _run(70.0)
    calls = _spied(monkeypatch)
    states, Y = pieces.states_and_outputs(THETA, MU, Fz, W, V, dt, KN)
    Yb, dYb = pieces.blocks(THETA, MU, Fz, W, V, dt, KN, 10, 2)
    again = calls.count("states") - 2
    assert 1 <= again <= 3 and calls.count("blocks") - 2 == again  # (not the whole second half: 7 stretches)
    stretches = [r for c, r in zip(calls, calls.rows) if c == "states"][2:]
    assert stretches == [round(pieces.CHUNK_S / dt) + 1] * again  # 5 s and the sample after, not the rest at once
    whole = (*tyres.rk4_states_and_outputs_input(THETA, MU, Fz, W, V, dt, KN),
             *tyres.simulate_blocks_input(THETA, MU, Fz, W, V, dt, KN, 10, 2))
    for got, want in zip((states, Y, Yb, dYb), whole):
        assert np.abs(got - want).max() <= 1e-12 * np.abs(want).max()


def test_a_car_that_spins_is_the_whole_pass_bit_for_bit(monkeypatch):
    """Steered beyond its grip, the race car spins (states in the thousands): the pieces never meet, and the run is
    the whole pass's continuation to its end in one go (the pieces differ by far more than stretches could mend),
    the same numbers bit for bit. So is a second piece started from rest 20 ms before the half."""
    W, V, Fz, dt = _run(70.0, steer=(0.015, 0.03))
    calls = _spied(monkeypatch)
    states, Y = pieces.states_and_outputs(THETA, MU, Fz, W, V, dt, KN)
    Yb, dYb = pieces.blocks(THETA, MU, Fz, W, V, dt, KN, 10, 2)
    assert calls.count("states") == calls.count("blocks") == 3
    whole = (*tyres.rk4_states_and_outputs_input(THETA, MU, Fz, W, V, dt, KN),
             *tyres.simulate_blocks_input(THETA, MU, Fz, W, V, dt, KN, 10, 2))
    assert np.abs(whole[0]).max() > 100.0
    for got, want in zip((states, Y, Yb, dYb), whole):
        assert np.array_equal(got, want)
    monkeypatch.setattr(pieces, "OVERLAP_S", 0.02)
    W, V, Fz, dt = _run(70.0)
    calls.clear()
    got = (*pieces.states_and_outputs(THETA, MU, Fz, W, V, dt, KN), *pieces.blocks(THETA, MU, Fz, W, V, dt, KN, 10, 2))
    assert calls.count("states") == calls.count("blocks") == 3
    whole = (*tyres.rk4_states_and_outputs_input(THETA, MU, Fz, W, V, dt, KN),
             *tyres.simulate_blocks_input(THETA, MU, Fz, W, V, dt, KN, 10, 2))
    assert all(np.array_equal(a, b) for a, b in zip(got, whole))


def test_a_short_run_is_one_piece():
    W, V, Fz, dt = _run(30.0)
    assert pieces.split_points(len(W), dt) is None
    assert all(np.array_equal(a, b) for a, b in zip(pieces.states_and_outputs(THETA, MU, Fz, W, V, dt, KN),
                                                    tyres.rk4_states_and_outputs_input(THETA, MU, Fz, W, V, dt, KN)))
