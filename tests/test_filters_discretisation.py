"""The EKF's and UKF's steps from one eigen-decomposition against scipy's expm (filters/local_model.py).

The bounds asserted here are the ones the docstrings state: exact in the sample period (round-off),
first order in the parameters' and the speed's distance from the linearisation point.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm, expm_frechet

from online_id.filters.local_model import ExactModel, LocalModel, local_model
from online_id.model import discretise as disc
from online_id.model import intersample as its
from online_id.model.discretise import (
    continuous_derivatives,
    continuous_speed_derivatives,
    discretise,
    linearise,
    spectral_form,
)
from online_id.model.lateral import continuous_parameter_derivatives, output_matrices
from online_id.vehicle import load_vehicle

EXACT_BOUND = 1e-11  # of ‖Φ − I‖, Δs = ΔV = 0 (measured 1e-13)
DERIVATIVE_BOUND = 1e-10  # of ‖∂Φ/∂s z‖ (measured 2e-12)
FIRST_ORDER_BOUND = 2e-4  # of ‖Φ − I‖ at |Δs| ≤ 3e-3, |ΔV| ≤ 2 % (measured 1e-4)
#: An input polynomial's columns Γ_0 = Bd, Γ_1..Γ_3 (model/intersample.py) against expm of the augmented
#: generator at the point: each column within this times the eigenvectors' condition number of its own largest
#: entry (round-off; measured 9e-14 · condition over random points, whose condition is 10-300: at most 7e-12,
#: Bd's column alike; 2.2e-13 · condition beside a slow mode). Near the point first order as Φ (of Γ's largest
#: entry, measured 1.4e-4 against FIRST_ORDER_BOUND); their parameter columns ∂(Ad x + Γ w)/∂s against Van
#: Loan's within DERIVATIVE_BOUND (measured 4e-12).
CONDITION_ROUND_OFF = 1e-12
#: φ_1..φ_3 of an eigenbasis and their divided differences (model/compiled.py ``phi_weights``) against sums
#: in exact rational arithmetic (measured 1.6e-15 relative).
PHI_WEIGHTS_BOUND = 1e-14
LOG_STEP, SPEED_STEP = 3e-3, 0.02


@pytest.fixture(scope="module")
def car():
    return load_vehicle("haro2008")


def _random_points(car, n, seed=1):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        s = rng.normal(0.0, 0.7, 8)
        yield rng, s, rng.uniform(5.0, 70.0), np.exp(rng.uniform(np.log(2e-4), np.log(0.05)))


def _phi(Ad, Bd):
    out = np.eye(7)
    out[:6, :6], out[:6, 6] = Ad, Bd
    return out


def test_steps_match_scipy_expm_within_the_stated_bounds(car):
    theta0 = car.prior.to_vector()
    worst = {"exact": 0.0, "derivative": 0.0, "first order": 0.0}
    for rng, s, V, dt in _random_points(car, 150):
        model = LocalModel(theta0, s, V, car.known, LOG_STEP, SPEED_STEP)
        assert model.usable
        theta = theta0 * np.exp(s)
        lin = linearise(theta, V, car.known, dt)
        exact = _phi(lin.Ad, lin.Bd)
        steps = model.steps(s, np.array([dt]), np.array([V]))
        scale = np.abs(exact - np.eye(7)).max()
        worst["exact"] = max(worst["exact"], np.abs(_phi(steps.Ad[0], steps.Bd[0]) - exact).max() / scale)
        x, d = rng.normal(size=(1, 6)), rng.normal(size=1)
        J = steps.parameter_columns(x, d)[0]
        J_ref = (np.einsum("kij,j->ik", lin.dAd, x[0]) + lin.dBd.T * d[0]) * theta
        worst["derivative"] = max(worst["derivative"], np.abs(J - J_ref).max() / np.abs(J_ref).max())
        # a state near the linearisation point: parameters and speed moved by up to the steps
        s1 = s + rng.uniform(-LOG_STEP, LOG_STEP, 8)
        V1 = V * (1 + rng.uniform(-SPEED_STEP, SPEED_STEP))
        assert model.covers(s1, V1)
        near = model.steps(s1, np.array([dt]), np.array([V1]))
        ref = _phi(*discretise(theta0 * np.exp(s1), V1, car.known, dt))
        worst["first order"] = max(worst["first order"],
                                   np.abs(_phi(near.Ad[0], near.Bd[0]) - ref).max() / np.abs(ref - np.eye(7)).max())
    assert worst["exact"] < EXACT_BOUND, worst
    assert worst["derivative"] < DERIVATIVE_BOUND, worst
    assert worst["first order"] < FIRST_ORDER_BOUND, worst
    assert worst["first order"] > EXACT_BOUND  # the first-order term is really exercised


def _input(rng, dt):
    """w (4,) of a step of a steering angle with a bandwidth up to 25 rad/s: w_j ~ 0.02 (ω dt)^j."""
    return rng.normal(0.0, 0.02, 4) * (rng.uniform(0.5, 25.0) * dt) ** np.arange(4)


def test_input_columns_match_the_augmented_generator_within_the_stated_bounds(car):
    """The one-period tables' input columns Γ (filters/local_model.py with order 4: Γ_0 = Bd, then Γ_1..Γ_3 from
    φ-functions of the eigenvalues) against expm of the augmented generator (model/intersample.py), at the point
    and near it, and the parameters' columns ∂(Ad x + Γ w)/∂s against Van Loan's."""
    theta0 = car.prior.to_vector()
    worst = {"exact": 0.0, "derivative": 0.0, "first order": 0.0}
    for rng, s, V, dt in _random_points(car, 100, seed=6):
        model = LocalModel(theta0, s, V, car.known, LOG_STEP, SPEED_STEP, order=4)
        theta = theta0 * np.exp(s)
        Ac, Bc, dAc, dBc, _, _ = continuous_derivatives(theta, V, car.known)
        exact = its.input_columns(Ac, Bc, dt)
        steps = model.steps(s, np.array([dt]), np.array([V]))
        Gamma = steps.Gamma[0]
        error = (np.abs(Gamma - exact).max(axis=0) / np.abs(exact).max(axis=0)).max()
        worst["exact"] = max(worst["exact"], error / float(model.form.condition))
        x, w = rng.normal(size=(1, 6)), _input(rng, dt)[None]
        lin = linearise(theta, V, car.known, dt)
        dGamma = its.input_column_derivatives(Ac, Bc, dAc, dBc, dt)
        J_ref = (np.einsum("kij,j->ik", lin.dAd, x[0]) + np.einsum("kij,j->ik", dGamma, w[0])) * theta
        J = steps.parameter_columns(x, w)[0]
        worst["derivative"] = max(worst["derivative"], np.abs(J - J_ref).max() / np.abs(J_ref).max())
        s1 = s + rng.uniform(-LOG_STEP, LOG_STEP, 8)
        V1 = V * (1 + rng.uniform(-SPEED_STEP, SPEED_STEP))
        near = model.steps(s1, np.array([dt]), np.array([V1])).Gamma[0]
        ref = its.input_columns(*continuous_derivatives(theta0 * np.exp(s1), V1, car.known)[:2], dt)
        worst["first order"] = max(worst["first order"], np.abs(near - ref).max() / np.abs(ref).max())
        assert np.array_equal(Gamma[:, 0], steps.Bd[0])  # Γ_0 is the hold's column
    assert worst["exact"] < CONDITION_ROUND_OFF, worst
    assert worst["derivative"] < DERIVATIVE_BOUND, worst
    assert EXACT_BOUND < worst["first order"] < FIRST_ORDER_BOUND, worst


def test_input_columns_of_a_slow_mode_and_of_nearly_equal_eigenvalues():
    """Where the recurrence Γ_j = (Ac T)⁻¹ (Γ_j−1 − T Bc / j!) loses (|λ| T)^-j of the digits (a mode near
    zero: a car near its critical speed) and where divided differences cancel (two eigenvalues 1e-7 apart, a
    complex pair): SpectralForm.input_table against expm of the augmented generator and Van Loan. A slow mode
    beside the input's own eigenvalue 0 of G makes G's eigenvectors ill-conditioned: Γ's round-off then grows
    with the condition number, as Bd's does (measured: 2.2e-13 · condition of each column, Bd's 6e-14 ·
    condition; 2.7e-8 at |λ| = 3e-5 /s, condition 1.2e5), far below the steps' first-order error (2e-4), and
    the exact fallback takes over above SPECTRAL_CONDITION_LIMIT (1e6)."""
    rng = np.random.default_rng(4)
    for slow in (-3e-5, 2e-6, -0.5):
        lam = np.diag([-5.0, -5.0 + 1e-7, -30.0, slow, -7.0, -1.0])
        lam[4, 5], lam[5, 4] = 9.0, -9.0
        S = np.eye(6) + 0.3 * rng.normal(size=(6, 6))
        Ac = S @ lam @ np.linalg.inv(S)
        Bc, dAc, dBc = rng.normal(size=6), rng.normal(size=(2, 6, 6)), rng.normal(size=(2, 6))
        form = spectral_form(Ac, Bc, dAc, dBc)
        bound = CONDITION_ROUND_OFF * float(form.condition)
        for dt in (1e-3, 0.01, 0.04):
            Gamma, LG = form.input_table(dt)
            exact = its.input_columns(Ac, Bc, dt)[:, 1:]
            assert (np.abs(Gamma - exact).max(axis=0) <= bound * np.abs(exact).max(axis=0)).all(), (slow, dt)
            dexact = its.input_column_derivatives(Ac, Bc, dAc, dBc, dt)[:, :, 1:]
            assert np.abs(LG - dexact).max() <= bound * np.abs(dexact).max(), (slow, dt)


def _exact_divided_differences(a: complex, b: complex, terms: int = 120) -> list[complex]:
    """φ_j[a, b] = Σ_k≥1 h_k−1(a, b)/(k + j)!, j = 1, 2, 3, in exact rationals (a, b as the floats they are)."""
    from fractions import Fraction
    from math import factorial

    ar, ai, br, bi = (Fraction(v) for v in (a.real, a.imag, b.real, b.imag))
    hr, hi, pr, pi = Fraction(1), Fraction(0), Fraction(1), Fraction(0)
    sums = [[Fraction(1, factorial(j + 1)), Fraction(0)] for j in (1, 2, 3)]
    for k in range(1, terms):
        pr, pi = pr * br - pi * bi, pr * bi + pi * br  # b^k
        hr, hi = ar * hr - ai * hi + pr, ar * hi + ai * hr + pi  # h_k = a h_k−1 + b^k
        for j, acc in zip((1, 2, 3), sums):
            f = Fraction(1, factorial(k + j + 1))
            acc[0] += hr * f
            acc[1] += hi * f
    return [complex(float(re), float(im)) for re, im in sums]


def test_phi_weights_against_exact_sums():
    """φ_1..φ_3 at each μ and their divided differences over every pair (model/compiled.py ``phi_weights``):
    pairs far apart, 1e-9 apart, both under the series radius, across it, a conjugate pair, zero (the input's
    eigenvalue), a fast mode (μ = −25), and the diagonal (φ_j')."""
    mu = np.array([-25.0, -24.9, -3.2 + 0.5j, -3.2 - 0.5j, -3.2 + 0.5j + 1e-9, -0.9, -1.1, -0.5 + 0.3j, 0.2,
                   3e-6, 0.0])
    n = len(mu)
    phi, dd = np.empty((4, n), dtype=complex), np.empty((3, n, n), dtype=complex)
    from online_id.model.compiled import phi_weights

    phi_weights(mu, disc.DIVIDED_DIFFERENCE_CLOSE, disc.PHI1_SERIES, phi, dd)
    np.testing.assert_allclose(phi, its.phi_functions(mu, 3), rtol=1e-14, atol=0)
    worst = 0.0
    for a in range(n):
        for b in range(a, n):
            for j, exact in zip((1, 2, 3), _exact_divided_differences(mu[a], mu[b])):
                assert dd[j - 1, a, b] == dd[j - 1, b, a]
                worst = max(worst, abs(dd[j - 1, a, b] - exact) / abs(exact))
    assert worst < PHI_WEIGHTS_BOUND, worst


@pytest.mark.parametrize("order", [1, 4])
def test_one_group_of_varying_periods_and_speeds_equals_each_step_alone(car, order):
    theta0 = car.prior.to_vector()
    s = np.full(8, 0.2)
    model = LocalModel(theta0, s, 20.0, car.known, LOG_STEP, SPEED_STEP, order)
    dt = np.array([1e-3, 4e-3, 23e-3, 11e-3, 11e-3])
    V = np.array([20.0, 20.3, 19.7, 20.1, 20.1])
    rng = np.random.default_rng(0)
    x, w = rng.normal(size=(5, 6)), np.array([_input(rng, h)[:order] for h in dt])
    group = model.steps(s, dt, V)
    cols = group.parameter_columns(x, w)
    for j in range(5):
        one = model.steps(s, dt[j:j + 1], V[j:j + 1])
        np.testing.assert_allclose(group.Ad[j], one.Ad[0], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(group.Gamma[j], one.Gamma[0], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(cols[j], one.parameter_columns(x[j:j + 1], w[j:j + 1])[0], rtol=1e-10, atol=1e-14)


def test_divided_differences_of_nearly_equal_eigenvalues_match_the_frechet_derivative():
    """Two eigenvalues 1e-7 apart (the series branch) and a conjugate pair: against scipy's expm_frechet."""
    rng = np.random.default_rng(3)
    lam = np.diag([-5.0, -5.0 + 1e-7, -30.0, -2.0, -7.0, -1.0])
    lam[4, 5], lam[5, 4] = 9.0, -9.0  # a complex pair -7 ± 9i... as a real block
    S = np.eye(6) + 0.3 * rng.normal(size=(6, 6))
    Ac = S @ lam @ np.linalg.inv(S)
    Bc = rng.normal(size=6)
    dAc, dBc = rng.normal(size=(2, 6, 6)), rng.normal(size=(2, 6))
    form = spectral_form(Ac, Bc, dAc, dBc)
    dt = 0.02
    G, dG = np.zeros((7, 7)), np.zeros((7, 7))
    G[:6, :6], G[:6, 6] = Ac, Bc
    dG[:6, :6], dG[:6, 6] = dAc[1], dBc[1]
    ref_phi, ref_L = expm_frechet(G * dt, dG * dt)
    z = rng.normal(size=7)
    z[6] = 0.0
    np.testing.assert_allclose(form.transitions(np.array([dt]))[0], ref_phi, atol=1e-10 * np.abs(ref_phi).max())
    L = form.directional(np.array([dt]), z[None])[0, 1]
    np.testing.assert_allclose(L, ref_L @ z, atol=1e-8 * np.abs(ref_L @ z).max())
    np.testing.assert_allclose(expm(G * dt), ref_phi, atol=1e-12)


@pytest.mark.parametrize("order", [1, 4])
def test_ill_conditioned_decompositions_fall_back_to_scipys_expm(car, monkeypatch, order):
    theta0 = car.prior.to_vector()
    s = np.zeros(8)
    spectral = local_model(theta0, s, 25.0, car.known, LOG_STEP, SPEED_STEP, order)
    monkeypatch.setattr(disc, "SPECTRAL_CONDITION_LIMIT", 1.0)  # every decomposition now counts as unusable
    fallback = local_model(theta0, s, 25.0, car.known, LOG_STEP, SPEED_STEP, order)
    assert isinstance(fallback, ExactModel) and not isinstance(spectral, ExactModel)
    dt, V = np.array([2e-3, 9e-3]), np.array([25.0, 25.2])
    x, w = np.ones((2, 6)) * 0.01, np.array([[0.01, 2e-4, -1e-5, 1e-6], [-0.01, 1e-3, 1e-4, -1e-5]])[:, :order]
    a, b = spectral.steps(s, dt, V), fallback.steps(s, dt, V)
    np.testing.assert_allclose(a.Ad, b.Ad, atol=FIRST_ORDER_BOUND)
    np.testing.assert_allclose(a.Gamma, b.Gamma, rtol=0, atol=FIRST_ORDER_BOUND * np.abs(b.Gamma).max())
    ca, cb = a.parameter_columns(x, w), b.parameter_columns(x, w)  # first order in ΔV/V = 0.8 %: within 2 %
    assert np.abs(ca - cb).max() < 0.02 * np.abs(cb).max()


def test_continuous_derivatives_equal_the_model_functions(car):
    rng = np.random.default_rng(2)
    thetas = car.prior.to_vector() * np.exp(rng.normal(0, 0.5, (4, 8)))
    V = 17.0
    batched = continuous_speed_derivatives(thetas, V, car.known)
    h = 1e-4
    for j, th in enumerate(thetas):
        Ac, Bc, dAc, dBc, dAc_V, dBc_V = continuous_derivatives(th, V, car.known)
        for got, want in zip((Ac, Bc, dAc, dBc), continuous_parameter_derivatives(th, V, car.known)):
            np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-9)
        num = (continuous_parameter_derivatives(th, V + h, car.known)[0]
               - continuous_parameter_derivatives(th, V - h, car.known)[0]) / (2 * h)
        np.testing.assert_allclose(dAc_V, num, rtol=1e-6, atol=1e-6 * np.abs(num).max())
        for got, want in zip(batched, (Ac, Bc, dAc_V, dBc_V)):
            np.testing.assert_allclose(got[j], want, rtol=1e-12, atol=1e-12)


def test_outputs_do_not_depend_on_speed(car):
    """a_y = V(β̇ + r) is the lateral force balance over M, and the filters take the lateral velocity per unit
    speed (v_y / V = β): the EKF keeps one output matrix per θ. The batch form's v_y row is V e_β."""
    from online_id.model.lateral import BETA, VY, continuous_matrices, outputs_from_continuous

    th = car.truth("track")
    (C1, D1), (C2, D2) = (outputs_from_continuous(*continuous_matrices(th, V, car.known), V, per_unit_speed=True)
                          for V in (12.0, 55.0))
    np.testing.assert_allclose(C1, C2, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(D1, D2, atol=1e-12)
    C, _ = output_matrices(th, 55.0, car.known)
    np.testing.assert_allclose(np.delete(C, VY, axis=0), np.delete(C2, VY, axis=0), rtol=1e-10, atol=1e-10)
    assert C[VY, BETA] == 55.0 and C2[VY, BETA] == 1.0


def _swinging_run(car, duration_s: float):
    """The track chirp at 1 kHz whose speed swings ±20 % around 22 m/s at 2 Hz (seed 4)."""
    from online_id.sim.simulator import simulate

    t = np.arange(int(round(duration_s * 1000))) * 1e-3
    swing = 22 * (1 + 0.2 * np.sin(2 * np.pi * 2 * t))
    return simulate(car, car.truth("track"), duration_s=duration_s, speed_mps=swing, seed=4).run


def test_ukf_fallback_steps_give_the_spectral_result(car, monkeypatch):
    """The UKF's per-sample expm fallback (ill-conditioned decompositions) against its spectral steps, on a
    run whose speed swings ±20 % and whose period jitters."""
    from online_id.filters import UKFEstimator
    from online_id.stream.samples import samples_from_run

    run = _swinging_run(car, 0.4)
    samples = [s for k, s in enumerate(list(samples_from_run(run))) if k % 3 != 1]  # periods of 1 and 2 ms
    spectral = UKFEstimator(car)
    spectral.update_many(samples)
    monkeypatch.setattr(disc, "SPECTRAL_CONDITION_LIMIT", 1.0)
    fallback = UKFEstimator(car)
    fallback.update_many(samples)
    assert spectral.events == fallback.events
    np.testing.assert_allclose(spectral.log_scale, fallback.log_scale, atol=0.02 * spectral.log_scale_std.min())


@pytest.mark.parametrize("norm", [1e-3, 0.1, 0.5, 1.5, 4.0, 30.0, 500.0])
def test_compiled_expm_and_frechet_derivatives_match_scipys(norm):
    """The compiled Padé expm (model/compiled.py, every degree 3-13 and the squarings) and its Fréchet
    derivatives against scipy's expm and expm_frechet, on augmented generators [[A, b], [0, 0]] scaled to a
    1-norm of ``norm``."""
    from online_id.model.compiled import expm_frechet as compiled_expm_frechet

    rng = np.random.default_rng(int(norm * 1000))
    for _ in range(5):
        X = rng.standard_normal((7, 7))
        X[6] = 0.0
        X *= norm / np.abs(X).sum(axis=0).max()
        E = rng.standard_normal((2, 7, 7))
        E[:, 6] = 0.0
        F, L = np.empty((7, 7)), np.empty((2, 7, 7))
        compiled_expm_frechet(X, E, F, L)
        scale = np.exp(np.abs(X).sum(axis=0).max())  # (the squarings' round-off grows with it)
        np.testing.assert_allclose(F, expm(X), rtol=0, atol=1e-14 * scale)
        for k in range(2):
            np.testing.assert_allclose(L[k], expm_frechet(X, E[k], compute_expm=False), rtol=0, atol=1e-14 * scale)
        F0 = np.empty((7, 7))
        compiled_expm_frechet(X, np.empty((0, 7, 7)), F0, np.empty((0, 7, 7)))  # without directions: the same F
        np.testing.assert_array_equal(F0, F)


def test_ukf_expm_steps_give_the_spectral_result(car, monkeypatch):
    """The UKF's Padé steps (runs of one period) against its spectral steps (many periods), both exact to
    round-off, on a run at one rate whose speed swings ±20 %: the same estimate."""
    from online_id.filters import UKFEstimator, ukf
    from online_id.stream.samples import SampleArrays

    arrays = SampleArrays.from_run(_swinging_run(car, 2.0))
    pade = UKFEstimator(car)
    pade.update_many(arrays)
    monkeypatch.setattr(ukf, "EXPM_PERIODS_MAX", 0)
    spectral = UKFEstimator(car)
    spectral.update_many(arrays)
    assert pade.events == spectral.events
    np.testing.assert_allclose(pade.x, spectral.x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(pade.P, spectral.P, rtol=1e-8, atol=1e-15)


@pytest.mark.parametrize("shape", ["model", "full"])
def test_lapack_decomposition_equals_the_batched_numpy_one(shape):
    """single_spectral_form (LAPACK's dgeev, its complex pairs assembled by hand, getri for Q⁻¹) against the
    batched numpy path of spectral_form: G rebuilt from Q diag(λ) Q⁻¹, the same eigenvalues, and the same
    transitions and directional derivatives. "full": random 7 × 7, so complex pairs also land in the last
    columns; "model": G = [[Ac, Bc], [0, 0]] as the filters use it."""
    rng = np.random.default_rng(7)
    for _ in range(20):
        G = rng.standard_normal((7, 7))
        if shape == "model":
            G[6] = 0.0
        dG = rng.standard_normal((3, 7, 7))
        dG[:, 6] = 0.0
        one = disc.single_spectral_form(G, dG)
        batched = spectral_form(G[None, :6, :6], G[None, :6, 6], dG[None, :, :6, :6], dG[None, :, :6, 6]) \
            if shape == "model" else None
        scale = np.abs(G).max() * float(one.condition)
        assert np.abs(((one.vectors * one.eigenvalues) @ one.inverse) - G).max() <= 1e-13 * scale
        assert np.allclose(np.sort_complex(one.eigenvalues), np.sort_complex(np.linalg.eigvals(G)), atol=1e-12 * scale)
        dt = np.array([1e-3, 0.013, 0.2])
        c = rng.standard_normal((3, 3)) * 1e-3
        z = rng.standard_normal((3, 7))
        if batched is not None:
            assert np.allclose(one.transitions(dt, c), batched.transitions(dt, c)[0], rtol=0, atol=1e-12)
            assert np.allclose(one.directional(dt, z), batched.directional(dt, z)[0], rtol=0, atol=1e-12)
        exact = expm(G * 0.013)
        assert np.abs(one.transitions(np.array([0.013]))[0] - exact).max() <= 1e-12 * max(1.0, float(one.condition))


def test_the_condition_is_the_eigenvectors_1_norm_condition_number(car):
    """``condition`` decides where the exact fallback takes over: ‖Q‖₁ ‖Q⁻¹‖₁ of the decomposition."""
    theta0 = car.prior.to_vector()
    for _, s, V, _ in _random_points(car, 30, seed=4):
        form = LocalModel(theta0, s, V, car.known, LOG_STEP, SPEED_STEP).form
        assert np.isclose(float(form.condition), np.linalg.cond(form.vectors, 1), rtol=1e-9)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_non_finite_generator_is_refused(bad):
    G = np.eye(7)
    G[2, 3] = bad
    with pytest.raises(np.linalg.LinAlgError):
        disc.single_spectral_form(G, np.zeros((1, 7, 7)))


def test_a_singular_descriptor_matrix_is_refused(car, monkeypatch):
    coefficients = list(disc._affine_coefficients(car.known))
    coefficients[0] = np.zeros_like(coefficients[0])  # E0 = 0: E = θ-terms + V E_V only
    coefficients[2] = np.zeros_like(coefficients[2])
    coefficients[5] = np.zeros_like(coefficients[5])
    monkeypatch.setattr(disc, "_affine_coefficients", lambda known: tuple(coefficients))
    with pytest.raises(np.linalg.LinAlgError):
        disc.derivative_blocks(car.prior.to_vector(), 20.0, car.known)
    with pytest.raises(np.linalg.LinAlgError):
        disc.speed_generators(car.prior.to_vector()[None], 20.0, car.known)


def test_speed_generators_are_the_continuous_speed_derivatives(car):
    """The UKF's compiled generators G, ∂G/∂V (model/compiled.py) against continuous_speed_derivatives (numpy)."""
    thetas = car.truth("track").to_vector() * np.exp(0.5 * np.random.default_rng(3).standard_normal((9, 8)))
    for V in (3.0, 22.2, 70.0):
        G, dG = disc.speed_generators(thetas, V, car.known)
        Ac, Bc, dAc, dBc = disc.continuous_speed_derivatives(thetas, V, car.known)
        for got, want in ((G[:, :6, :6], Ac), (G[:, :6, 6], Bc), (dG[:, :6, :6], dAc), (dG[:, :6, 6], dBc)):
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
        assert not G[:, 6].any() and not dG[:, 6].any()


@pytest.mark.parametrize("kind", ["hold", "cubic"])
def test_the_ekf_runs_on_the_exact_fallback_where_every_point_is_ill_conditioned(car, monkeypatch, kind):
    """Every linearisation point the fallback (a 1 kHz run at constant speed: one step repeated per group,
    the EKF's commonest group): the filter learns as on the spectral points, with the hold's input and with
    the cubic's (the fallback's Γ from expm of the augmented generator). It stopped with an AttributeError
    (the one-step group took the tables' path, which the fallback's steps have not)."""
    import warnings

    from online_id.estimation import make_estimator, run_estimator
    from online_id.filters import FilterConfig
    from online_id.sim.simulator import simulate
    from online_id.stream.samples import SampleArrays

    run = simulate(car, car.truth("track"), seed=0, duration_s=2.0).run
    config = FilterConfig(intersample=kind)
    spectral = run_estimator(make_estimator(car, "ekf", config=config), SampleArrays.from_run(run))
    monkeypatch.setattr(disc, "SPECTRAL_CONDITION_LIMIT", 1.0)  # every decomposition now counts as unusable
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no reset either
        exact = run_estimator(make_estimator(car, "ekf", config=config), SampleArrays.from_run(run))
    assert exact.events["corrections"] == spectral.events["corrections"] > 90
    # the two differ by the first-order terms of the spectral steps only (bound above: 2e-4 of ‖Φ − I‖)
    np.testing.assert_allclose(exact.parameters.to_vector(), spectral.parameters.to_vector(), rtol=0.02)
