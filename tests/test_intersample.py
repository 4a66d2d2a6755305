"""The input between samples (online_id/model/intersample.py): the exact step it drives, its streaming and
whole-run forms, and what it is for: a logger-rate run whose outputs the model reproduces."""

from __future__ import annotations

import numpy as np
import pytest

from online_id.model import intersample as its
from online_id.model.discretise import continuous_derivatives, discretise
from online_id.model.lateral import continuous_matrices
from online_id.vehicle import load_vehicle

#: Γ·w against expm of the augmented generator, relative to ‖Bd‖·|w| (measured 1e-14 to 3e-12 over the
#: points below: periods 0.1 ms-80 ms, speeds 3-70 m/s, inputs with a bandwidth up to 25 rad/s).
STEP_BOUND = 1e-10
#: Γ's derivatives against central differences of Γ (step 1e-6 relative: truncation ~1e-12, round-off 1e-10).
DERIVATIVE_BOUND = 1e-6


@pytest.fixture(scope="module")
def car():
    return load_vehicle("haro2008")


def _points(car, n, seed=3):
    rng = np.random.default_rng(seed)
    prior = car.prior.to_vector()
    for _ in range(n):
        theta = prior * np.exp(rng.normal(0.0, 0.7, 8))
        yield rng, theta, rng.uniform(3.0, 70.0), np.exp(rng.uniform(np.log(1e-4), np.log(0.08)))


def _smooth_input(rng, dt):
    """w of a step of an input with bandwidth ω ≤ 25 rad/s (4 Hz): w_j ~ (ω T)^j."""
    omega = rng.uniform(0.5, 25.0)
    return rng.normal(0.0, 0.05, 4) * (omega * dt) ** np.arange(4)


def test_columns_make_the_exact_step(car):
    """Γ·w from the augmented generator's expm against a fine integration of the same cubic input."""
    for rng, theta, V, dt in _points(car, 5):
        Ac, Bc = continuous_matrices(theta, V, car.known)
        w = _smooth_input(rng, dt)
        Ad, Bd = discretise(theta, V, car.known, dt)
        Gamma = its.input_columns(Ac, Bc, dt)
        assert np.allclose(Gamma[:, 0], Bd, rtol=1e-12, atol=1e-14 * np.abs(Bd).max())
        n = 400  # midpoint sub-steps of the hold: second order, 400 of them: ~1e-6 of the step
        h = dt / n
        Ah, Bh = discretise(theta, V, car.known, h)
        x = np.zeros(6)
        for i in range(n):
            x = Ah @ x + Bh * its.value_at(w, (i + 0.5) / n)
        assert np.abs(Gamma @ w - x).max() <= 1e-5 * np.abs(x).max()


def test_modal_columns_match_the_exponential(car):
    """Each mode's φ on its own: right where the recurrence through (Ac T)⁻¹ loses digits (a slow mode)."""
    worst = 0.0
    for rng, theta, V, dt in _points(car, 200):
        Ac, Bc = continuous_matrices(theta, V, car.known)
        lam, W = np.linalg.eig(Ac)
        modal = its.modal_input_columns(lam, W, np.linalg.inv(W), Bc, dt)
        exact = its.input_columns(Ac, Bc, dt)
        w = _smooth_input(rng, dt)
        _, Bd = discretise(theta, V, car.known, dt)
        worst = max(worst, np.abs(modal @ w - exact @ w).max() / (np.linalg.norm(Bd) * np.abs(w).max()))
    assert worst < STEP_BOUND, worst


def test_phi_functions_against_exact_sums():
    """φ_j(μ) = (e^μ − Σ_{k<j} μ^k/k!)/μ^j summed with exact rationals for real μ (Fraction: no round-off but
    e^μ's), and against the closed form for complex μ away from zero."""
    from fractions import Fraction
    from math import factorial

    real = [-30.0, -2.5, -1.0, -0.999, -0.3, -1e-6, 0.0, 0.4, 1.5]
    phi = its.phi_functions(np.array(real), 4)
    for j in range(5):
        for i, m in enumerate(real):
            q = Fraction(m)
            exact = sum(q ** n / factorial(n + j) for n in range(120)) if abs(m) < 3 else None
            closed = (np.exp(m) - sum(m ** k / factorial(k) for k in range(j))) / m ** j if m else np.nan
            ref = float(exact) if exact is not None else closed
            assert phi[j][i] == pytest.approx(ref, rel=1e-13, abs=1e-300), (j, m)
    cplx = np.array([-5 + 8j, 0.2 - 0.9j, 3j])
    phi = its.phi_functions(cplx, 4)
    for j in range(5):
        ref = (np.exp(cplx) - sum(cplx ** k / factorial(k) for k in range(j))) / cplx ** j
        assert np.allclose(phi[j], ref, rtol=1e-12)


def test_hold_is_the_zero_order_hold(car):
    theta = car.prior.to_vector()
    Ac, Bc = continuous_matrices(theta, 22.0, car.known)
    _, Bd = discretise(theta, 22.0, car.known, 0.01)
    w = its.step_input("hold", 0.3, 0.7, 0.01)
    assert np.array_equal(w, [0.3, 0.0, 0.0, 0.0])
    assert np.allclose(its.input_columns(Ac, Bc, 0.01) @ w, Bd * 0.3, rtol=1e-12, atol=0)


def test_column_derivatives_match_differences(car):
    for _, theta, V, dt in _points(car, 10, seed=5):
        Ac, Bc, dAc, dBc, dAc_dV, dBc_dV = continuous_derivatives(theta, V, car.known)
        dG = its.input_column_derivatives(Ac, Bc, np.concatenate([dAc, dAc_dV[None]]),
                                          np.concatenate([dBc, dBc_dV[None]]), dt)
        for k in range(9):
            h = 1e-6 * (theta[k] if k < 8 else V)
            th_p, th_m, V_p, V_m = theta.copy(), theta.copy(), V, V
            if k < 8:
                th_p[k] += h
                th_m[k] -= h
            else:
                V_p, V_m = V + h, V - h
            numeric = (its.input_columns(*continuous_matrices(th_p, V_p, car.known), dt)
                       - its.input_columns(*continuous_matrices(th_m, V_m, car.known), dt)) / (2 * h)
            # the differences' round-off: ~1e-16 |Γ| / h
            floor = 1e-9 * np.abs(its.input_columns(Ac, Bc, dt)).max() / (theta[k] if k < 8 else V)
            assert np.abs(dG[k] - numeric).max() <= DERIVATIVE_BOUND * np.abs(numeric).max() + floor, k


def test_sub_steps_make_the_whole_step(car):
    theta = car.truth("track").to_vector()
    Ac, Bc = continuous_matrices(theta, 25.0, car.known)
    dt = 0.04
    w = np.array([0.02, 0.01, -0.03, 0.05])
    Ad, Gamma = its.reference_step(Ac, Bc, dt)
    x0 = np.array([0.1, 0.01, 0.02, -0.1, 0.003, 0.001])
    whole = Ad @ x0 + Gamma @ w
    parts = its.split_step(w, 5)
    Ad5, Gamma5 = its.reference_step(Ac, Bc, dt / 5)
    x = x0
    for p in parts:
        x = Ad5 @ x + Gamma5 @ p
    assert np.allclose(x, whole, rtol=1e-12, atol=1e-15)
    s = np.linspace(0, 1, 11)
    assert np.allclose(its.value_at(parts[2], (s + 0) ), its.value_at(w, (2 + s) / 5), atol=1e-15)


@pytest.mark.parametrize("cubic_term", [0.0, 0.8])
def test_cubic_is_exact_for_a_cubic_input(cubic_term):
    """The four-point slopes are exact for a cubic (the three-point ones only for a quadratic): every inner
    step reproduces the input on a jittering log."""
    t = np.cumsum(np.random.default_rng(0).uniform(0.005, 0.02, 40))  # a jittering log

    def curve(x):
        return 0.3 - 2.0 * x + 1.5 * x ** 2 + cubic_term * x ** 3

    W, _ = its.run_inputs("cubic", t, curve(t), np.full_like(t, 20.0))
    for k in range(3, len(t) - 2):  # inner steps: both end slopes with two samples before and one after
        s = np.linspace(0, 1, 7)
        tt = t[k - 1] + s * (t[k] - t[k - 1])
        assert np.allclose(its.value_at(W[k], s), curve(tt), rtol=0, atol=1e-12)


def test_four_point_slopes_on_an_even_grid_are_the_batch_jobs():
    """The filters' slopes (non-uniform formula) and the batch jobs' even-grid ones (sim/block_means.even_slopes) are
    the same numbers, and at a 4 Hz sine sampled at 25 Hz (ωT ≈ 1) the cubic loses under 0.4 % of the
    amplitude where the central three-point slope lost 1.1 % (the loss a filter reads as tyre lag)."""
    from online_id.sim.block_means import even_slopes

    T = 1 / 25
    t = np.arange(200) * T
    u = np.sin(2 * np.pi * 4.0 * t)
    _, _, M = its.run_inputs("cubic", t, u, np.full_like(t, 20.0), slopes=True)
    np.testing.assert_allclose(M * T, even_slopes(u), rtol=0, atol=1e-12)
    W, _ = its.run_inputs("cubic", t, u, np.full_like(t, 20.0))
    s = np.linspace(0, 1, 401)
    curve = np.concatenate([its.value_at(W[k], s[:-1]) for k in range(10, 190)])
    fine = np.sin(2 * np.pi * 4.0 * (t[9] + np.concatenate([(k + s[:-1]) * T for k in range(180)])))
    gain = np.dot(curve, fine) / np.dot(fine, fine)
    assert abs(gain - 1) < 0.004, gain


@pytest.mark.parametrize("kind", its.INTERSAMPLE)
def test_stream_and_run_give_the_same_numbers(kind):
    rng = np.random.default_rng(1)
    n = 300
    t = np.cumsum(rng.uniform(0.001, 0.03, n))
    u = np.sin(7 * t) * 0.2 + rng.normal(0, 1e-3, n)
    V = 20 + np.cumsum(rng.normal(0, 0.05, n))
    valid = rng.random(n) > 0.1
    W, S = its.run_inputs(kind, t, u, V, valid)
    stream = its.InputStream(kind)
    got = []
    for k in np.flatnonzero(valid):
        got += stream.push(t[k], u[k], V[k])
    got += stream.drain()
    assert [g[0] for g in got] == list(range(int(valid.sum())))
    rows = np.flatnonzero(valid)
    assert got[0][1] is None and np.isnan(W[rows[0]]).all()
    for (_, w, speed), row in zip(got[1:], rows[1:]):
        assert np.array_equal(w, W[row]) and speed == S[row]  # bit for bit
    assert np.isnan(W[~valid]).all()


def test_stream_waits_one_sample_for_the_cubic():
    stream = its.InputStream("cubic")
    assert stream.push(0.0, 0.0, 20.0) == []
    assert [r[0] for r in stream.push(0.01, 0.1, 20.0)] == [0]
    assert [r[0] for r in stream.push(0.02, 0.3, 20.0)] == [1]
    assert [r[0] for r in stream.drain()] == [2]
    assert stream.drain() == []
    assert [r[0] for r in its.InputStream("linear").push(0.0, 0.0, 20.0)] == [0]


def test_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="choose from hold, linear, cubic"):
        its.InputStream("spline")


def _logger_error(car, rate, kind):
    """RMS error [noise σ] of the outputs of the built-in chirp simulated finely (10 kHz, the cubic: exact to
    round-off there) and sampled at ``rate``, against the model driven through ``kind`` at the logger's rate."""
    from online_id.model.lateral import outputs_from_continuous
    from online_id.sim import maneuvers

    theta = car.truth("track").to_vector()
    V = 80 / 3.6
    Ac, Bc = continuous_matrices(theta, V, car.known)
    C, _ = outputs_from_continuous(Ac, Bc, np.asarray(V))

    def run(rate_hz, kind_):
        t = np.arange(int(20 * rate_hz)) / rate_hz
        u = maneuvers.chirp(t, np.deg2rad(22.0), duration_s=20.0) / car.known.steering_ratio
        W, _ = its.run_inputs(kind_, t, u, np.full_like(t, V))
        dt = 1 / rate_hz
        Ad, Gamma = its.reference_step(Ac, Bc, dt)
        x = np.zeros(6)
        Y = np.empty((len(t), 5))
        Y[0] = C @ x
        for k in range(1, len(t)):
            x = Ad @ x + Gamma @ W[k]
            Y[k] = C @ x
        return Y

    fine = run(10_000, "cubic")[:: int(10_000 / rate)]
    coarse = run(rate, kind)
    noise = np.array([0.004, 0.0005, 0.004, 0.05, 0.02])
    return np.sqrt((((coarse - fine) / noise) ** 2).mean(axis=0)).max()


def test_the_cubic_follows_a_logger_where_the_hold_lags(car):
    hold, cubic = _logger_error(car, 100, "hold"), _logger_error(car, 100, "cubic")
    assert hold > 1.0  # the half-sample lag: about 2.5 noise σ at 100 Hz
    assert cubic < 0.01, cubic
