"""The UKF's and the saturating-tyre filters' steps driven by the input between samples (issue 36).

Each sigma point of the linear UKF steps x ← Ad x + Γ w (filters/sigma_block.py: from its eigen-decomposition
or by the compiled Padé expm of the augmented generator), checked against the references of
online_id/model/intersample.py; the tyre model's RK4 takes δ at each stage's time (model/tyres.py), checked
against a 64 times finer RK4 with the same input and, with μ huge, against the linear model's exact step. The
bounds are the ones the docstrings state.
"""

from __future__ import annotations

import numpy as np
import pytest

from online_id.effects import parse_effect_to_estimate
from online_id.filters.config import FilterConfig
from online_id.filters.sigma_block import sigma_expm_steps, sigma_pass, sigma_steps
from online_id.model import intersample as its
from online_id.model import tyres
from online_id.model.discretise import continuous_derivatives, continuous_speed_derivatives, spectral_form
from online_id.model.lateral import continuous_matrices
from online_id.sim.simulator import simulate
from online_id.vehicle import load_vehicle
from online_id.vehicle.parameters import axle_loads
from tests.test_array_path import _assert_same, _both, _damaged_run

CAR = load_vehicle("haro2008")
TRUTH = CAR.truth("track")
CUBIC = FilterConfig(intersample="cubic")

#: Γ·w against intersample.reference_step (scipy's expm of the augmented generator), relative to ‖Bd‖·|w|, as
#: tests/test_intersample.py's STEP_BOUND (measured over the points below: Padé 1e-14, spectral 2e-13).
STEP_BOUND = 1e-10
#: Each column Γ_j against the mode-by-mode reference (intersample.modal_input_columns, each φ on its own: 1e-15
#: of the column against an extended-precision expm), relative to the column's largest entry (measured: Padé
#: 1.3e-14, spectral 2.8e-13; up to 5e-13 over other seeds, at eigenvector conditions up to 7e3).
COLUMN_BOUND = 1e-11
#: Ad against the reference, relative to ‖Ad − I‖ (as tests/test_filters_discretisation.py's EXACT_BOUND;
#: measured: Padé 2.7e-14, spectral 3.6e-13).
TRANSITION_BOUND = 1e-11
#: The first-order speed term of Γ (the derivative of each column in V) against Van Loan's
#: (intersample.input_column_derivatives), relative to the derivative's column (measured: 1.8e-9 both paths,
#: the reference's: against an extended-precision Van Loan both are within 1e-10).
SPEED_TERM_BOUND = 1e-7


def _points(n, seed=3):
    """Parameter sets around the prior, speeds 3-70 m/s, periods 0.1-80 ms (as tests/test_intersample.py)."""
    rng = np.random.default_rng(seed)
    prior = CAR.prior.to_vector()
    for _ in range(n):
        theta = prior * np.exp(rng.normal(0.0, 0.7, 8))
        yield rng, theta, rng.uniform(3.0, 70.0), np.exp(rng.uniform(np.log(1e-4), np.log(0.08)))


def _smooth_input(rng, dt):
    omega = rng.uniform(0.5, 25.0)
    return rng.normal(0.0, 0.05, 4) * (omega * dt) ** np.arange(4)


def _both_paths(theta, V_ref, dt, c, q=4):
    """(Ad, Γ) of one parameter set at periods ``dt`` (m,) and speed coefficients ``c`` (m,) from the spectral
    form (sigma_steps) and from the Padé expm (sigma_expm_steps): {name: (Ad (m, 6, 6), Γ (m, 6, q))}."""
    Ac, Bc, dAc, dBc = continuous_speed_derivatives(theta[None], V_ref, CAR.known)
    form = spectral_form(Ac, Bc, dAc[:, None], dBc[:, None])
    G, dG = np.zeros((1, 7, 7)), np.zeros((1, 1, 7, 7))
    G[:, :6, :6], G[:, :6, 6], dG[:, 0, :6, :6], dG[:, 0, :6, 6] = Ac, Bc, dAc, dBc
    m = len(dt)
    cc = np.asarray(c, dtype=float).reshape(m, 1)
    out = {}
    for name in ("spectral", "pade"):
        Ad, Gam = np.empty((1, m, 6, 6)), np.empty((1, m, 6, q))
        if name == "spectral":
            sigma_steps(form.eigenvalues, form.vectors, form.inverse, form.directions, dt, cc, 0.0, Ad, Gam)
        else:
            sigma_expm_steps(G, dG, dt, cc, 0.0, Ad, Gam)
        out[name] = (Ad[0], Gam[0])
    return out


def test_each_points_step_is_the_exact_step_of_the_cubic():
    """Both discretisations of a sigma point against intersample.reference_step and the mode-by-mode columns."""
    worst = {"step": 0.0, "column": 0.0, "transition": 0.0}
    for rng, theta, V, dt in _points(150):
        Ac, Bc = continuous_matrices(theta, V, CAR.known)
        Ad_ref, Gam_ref = its.reference_step(Ac, Bc, dt)
        lam, W = np.linalg.eig(Ac)
        modal = its.modal_input_columns(lam, W, np.linalg.inv(W), Bc, dt)
        w = _smooth_input(rng, dt)
        scale = np.linalg.norm(Gam_ref[:, 0]) * np.abs(w).max()
        for Ad, Gam in _both_paths(theta, V, np.array([dt]), [0.0]).values():
            worst["step"] = max(worst["step"], np.abs(Gam[0] @ w - Gam_ref @ w).max() / scale)
            worst["column"] = max(worst["column"], (np.abs(Gam[0] - modal).max(0) / np.abs(modal).max(0)).max())
            worst["transition"] = max(worst["transition"],
                                      np.abs(Ad[0] - Ad_ref).max() / np.abs(Ad_ref - np.eye(6)).max())
    assert worst["step"] < STEP_BOUND, worst
    assert worst["column"] < COLUMN_BOUND, worst
    assert worst["transition"] < TRANSITION_BOUND, worst


def test_the_speed_terms_are_the_columns_derivatives_in_speed():
    """Γ at V_ref + c, first order in c, on both paths: (Γ(c) − Γ(0))/c against Van Loan's derivative."""
    worst = 0.0
    for _, theta, V, dt in _points(60, seed=5):
        Ac, Bc, _, _, dAc_V, dBc_V = continuous_derivatives(theta, V, CAR.known)
        dGam = its.input_column_derivatives(Ac, Bc, dAc_V[None], dBc_V[None], dt)[0]
        paths = _both_paths(theta, V, np.array([dt, dt]), [0.0, 0.5])
        for _, Gam in paths.values():
            got = (Gam[1] - Gam[0]) / 0.5
            worst = max(worst, (np.abs(got - dGam).max(0) / np.abs(dGam).max(0)).max())
    assert worst < SPEED_TERM_BOUND, worst


def test_the_hold_and_the_linear_take_the_cubics_first_columns():
    """q = 1 (the hold) fills Γ_0 = Bd alone, q = 2 (the linear) Γ_0 and Γ_1; with q = 4 they are the same to
    round-off (the spectral path forms Γ_0 the cancellation-free way when q > 1, the Padé path from the larger
    generator), and so is the Padé path's Ad; the spectral path's Ad is the same bit for bit."""
    theta = TRUTH.to_vector()
    dt, c = np.array([1e-3, 1e-3, 4e-3]), [0.0, 0.2, -0.1]
    hold = _both_paths(theta, 22.0, dt, c, q=1)
    cubic = _both_paths(theta, 22.0, dt, c, q=4)
    for name in hold:
        np.testing.assert_allclose(cubic[name][1][..., 0], hold[name][1][..., 0], rtol=1e-11,
                                   atol=1e-12 * np.abs(hold[name][1]).max())
    np.testing.assert_array_equal(cubic["spectral"][0], hold["spectral"][0])
    np.testing.assert_allclose(cubic["pade"][0], hold["pade"][0], rtol=0, atol=1e-13)
    linear = _both_paths(theta, 22.0, dt, c, q=2)  # (the first-order hold's two columns)
    for name in linear:
        np.testing.assert_allclose(linear[name][1], cubic[name][1][..., :2], rtol=1e-11,
                                   atol=1e-12 * np.abs(cubic[name][1]).max())


def test_sigma_pass_steps_with_every_input_column():
    """The compiled pass: x ← Ad x + Γ_0 (w_0 + g·e) + Σ_j Γ_j w_j per point, against numpy."""
    rng = np.random.default_rng(4)
    S, m = 5, 6
    Ad = np.eye(6) + 0.01 * rng.standard_normal((S, m, 6, 6))
    Gam = 0.01 * rng.standard_normal((S, m, 6, 4))
    w = rng.standard_normal((m, 4))
    shift = 0.1 * rng.standard_normal(S)
    X0 = rng.standard_normal((S, 6))
    z = np.zeros
    X = X0.copy()
    sigma_pass(Ad, Gam, np.arange(m), X, w, z(m), np.zeros(m, dtype=bool), z((m, 4)), np.ones((m, 4), dtype=bool),
               z((S, 4, 6)), z((S, 4)), shift, z((S, 4)), z((S, 4)), z((S, 4, 6)), z((S, 4)), np.full(S, 1 / S),
               np.full(S, 1 / S), np.ones(4), 25.0, z((S, 4)), z(4), z(4), z(4, dtype=np.int64))
    ref = X0.copy()
    for k in range(m):
        u = np.tile(w[k], (S, 1))
        u[:, 0] += shift
        ref = np.einsum("sij,sj->si", Ad[:, k], ref) + np.einsum("sij,sj->si", Gam[:, k], u)
    np.testing.assert_allclose(X, ref, rtol=1e-13, atol=1e-15)


def test_the_ukfs_pade_and_spectral_steps_give_the_same_cubic_estimate(monkeypatch):
    """As tests/test_filters_discretisation.py's hold test, with the cubic input: a run at one rate whose speed
    swings ±20 %, through the Padé steps and through the spectral ones."""
    from online_id.estimation import make_estimator
    from online_id.filters import ukf
    from online_id.stream.samples import SampleArrays

    t = np.arange(2000) * 1e-3
    run = simulate(CAR, TRUTH, duration_s=2.0, speed_mps=22 * (1 + 0.2 * np.sin(2 * np.pi * 2 * t)), seed=4).run
    arrays = SampleArrays.from_run(run)
    pade = make_estimator(CAR, "ukf", config=CUBIC)
    pade.update_many(arrays)
    monkeypatch.setattr(ukf, "EXPM_PERIODS_MAX", 0)
    spectral = make_estimator(CAR, "ukf", config=CUBIC)
    spectral.update_many(arrays)
    assert pade.events == spectral.events and pade.events["corrections"] > 90
    np.testing.assert_allclose(pade.x, spectral.x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(pade.P, spectral.P, rtol=1e-8, atol=1e-15)


def test_the_ukfs_exact_fallback_gives_the_spectral_cubic_steps(monkeypatch):
    """Ill-conditioned decompositions: each sample's Padé expm at its own speed, against the spectral steps
    (first order in the speed: within the first-order bound of the speed's ±2 % band)."""
    from online_id.estimation import make_estimator
    from online_id.filters import ukf
    from online_id.model import discretise as disc

    rng = np.random.default_rng(0)
    est = make_estimator(CAR, "ukf", config=CUBIC)
    thetas = TRUTH.to_vector() * np.exp(0.2 * rng.standard_normal((4, 8)))
    dt = np.array([1e-3, 2e-3, 1.5e-3])
    V = np.array([20.0, 20.2, 19.8])
    monkeypatch.setattr(ukf, "EXPM_PERIODS_MAX", 0)
    Ad, Gam, *_ = est._segment_steps(thetas, dt, V, 20.0, lagged=False)
    monkeypatch.setattr(disc, "SPECTRAL_CONDITION_LIMIT", 1.0)
    Ad_x, Gam_x, *_ = est._segment_steps(thetas, dt, V, 20.0, lagged=False)
    assert Gam_x.shape == Gam.shape == (4, 3, 6, 4)
    np.testing.assert_allclose(Ad_x, Ad, atol=2e-4 * np.abs(Ad - np.eye(6)).max())
    for j in range(4):
        assert np.abs(Gam_x[..., j] - Gam[..., j]).max() <= 2e-4 * np.abs(Gam[..., j]).max(), j


# -- the saturating tyres ------------------------------------------------------------------------------
THETA = TRUTH.to_vector()
KN, FZ = tyres.known_array(CAR.known), axle_loads(CAR.known)
NONE_I, NONE_F = np.zeros(0, dtype=np.int64), np.zeros(0)
IDX = np.array(list(range(6, 14)) + [14, 14], dtype=np.int64)
STEER_COLS, STEER_G = np.array([15]), np.array([-1 / CAR.known.steering_ratio])
X0 = np.array([0.3, 0.02, 0.03, 0.1, 0.04, 0.03])  # deep in the tanh: u = Dα/(μFz) about 0.6-1.3 at μ 0.8
#: A cubic step input [rad]: a 4 Hz steering swing's value and derivatives in normalised time at 100 Hz.
W_CUBIC = np.array([0.03, 0.012, -0.004, 0.0015])


def _cubic_at(dt):
    """:data:`W_CUBIC`'s curve over a period ``dt`` [s] (the same derivatives in time: w_j scales as dt^j)."""
    return W_CUBIC * (dt / 1e-2) ** np.arange(4)


def _tyre_step(z, w, dt, V=22.2, n_aug=0):
    """The tyre step and the outputs at the augmented state z = [x, s, μ, e] with input ``w``."""
    x, s, mu, e = z[:6], z[6:14], z[14], z[15]
    th = THETA * np.exp(s)
    S = np.eye(6, 16) if n_aug else np.zeros((6, 0))
    idx = IDX if n_aug else -np.ones(10, dtype=np.int64)
    cols, g = (STEER_COLS, STEER_G) if n_aug else (NONE_I, NONE_F)
    shift = STEER_G[0] * e
    x1, S1 = tyres.step_input(x.copy(), S, th, np.array([mu, mu]), FZ, w, shift, V, dt, KN, idx, np.ones(8), cols, g)
    y, H, _ = tyres.output(x1, S1, th, np.array([mu, mu]), FZ, w[0] + shift, V, KN, idx, np.ones(8), cols, g)
    return x1, S1, y, H


#: The tyre step's error, relative to the state, at 1 kHz and 100 Hz with :func:`_cubic_at`'s input (measured
#: 1.4e-10 and 1.7e-5: RK4's own error at h·V/b ≤ 0.5, the hold's 2.4e-11 and 3.2e-6 from the same state; the
#: hold's step is 6.8e-5 and 5.4e-3 off the cubic's).
TYRE_STEP_BOUNDS = [(1e-3, 1e-9), (1e-2, 3e-5)]


@pytest.mark.parametrize("dt, bound", TYRE_STEP_BOUNDS)
def test_the_tyre_step_with_a_cubic_input_against_a_fine_reference(dt, bound):
    """One sample period against RK4 at 64 times finer steps with the same curve (each sub-step its piece of
    it, intersample.split_step)."""
    z = np.concatenate([X0, np.zeros(8), [0.8, 0.0]])
    w = _cubic_at(dt)
    x1 = _tyre_step(z, w, dt)[0]
    x = X0.copy()
    for part in its.split_step(w, 64):
        x = _tyre_step(np.concatenate([x, z[6:]]), part, dt / 64)[0]
    assert np.abs(x1 - x).max() / np.abs(x).max() < bound
    held = _tyre_step(z, np.array([w[0], 0, 0, 0]), dt)[0]
    assert np.abs(held - x).max() > 100 * np.abs(x1 - x).max()  # the curve matters


def test_the_tyre_steps_jacobian_with_a_cubic_input():
    """F and H the exact derivatives of the step the EKF predicts with, the steering shift's included (central
    differences agree to 1e-6 relative, as for the hold)."""
    z = np.concatenate([X0, np.zeros(8), [0.8, 0.01]])
    _, S, _, H = _tyre_step(z, W_CUBIC, 1e-2, n_aug=16)
    num_S, num_H = np.zeros_like(S), np.zeros_like(H)
    for j in range(16):
        h = 1e-6 * max(1.0, abs(z[j]))
        zp, zm = z.copy(), z.copy()
        zp[j] += h
        zm[j] -= h
        p, m = _tyre_step(zp, W_CUBIC, 1e-2), _tyre_step(zm, W_CUBIC, 1e-2)
        num_S[:, j] = (p[0] - m[0]) / (2 * h)
        num_H[:, j] = (p[2] - m[2]) / (2 * h)
    assert np.abs(num_S - S).max() / np.abs(S).max() < 1e-6
    assert np.abs(num_H - H).max() / np.abs(H).max() < 1e-6
    assert np.abs(S[:, 15]).max() > 1e-6  # the steering shift moves the state


@pytest.mark.parametrize("dt, bound", TYRE_STEP_BOUNDS)
def test_with_mu_huge_the_tyre_step_is_the_linear_models_exact_step(dt, bound):
    """μ = 1e6 (w → 0): RK4 with δ at its stages' times against x(T) = Ad x + Γ w (intersample.reference_step):
    the stage times are the curve's; the RK4's own error only (the bounds above)."""
    Ac, Bc = continuous_matrices(THETA, 22.2, CAR.known)
    Ad, Gam = its.reference_step(Ac, Bc, dt)
    w = _cubic_at(dt)
    exact = Ad @ X0 + Gam @ w
    got = _tyre_step(np.concatenate([X0, np.zeros(8), [1e6, 0.0]]), w, dt)[0]
    assert np.abs(got - exact).max() / np.abs(exact).max() < bound


def test_the_hold_through_the_input_step_is_the_held_step_bit_for_bit():
    """step(δ) is step_input([δ, 0, 0, 0], 0); step_points(δ_s) is step_points_input(0, δ_s): the hold's numbers."""
    z = np.concatenate([X0, np.zeros(8), [0.8, 0.01]])
    th, mu, S = THETA * np.exp(z[6:14]), np.array([0.8, 0.8]), np.eye(6, 16)
    args = (KN, IDX, np.ones(8), STEER_COLS, STEER_G)
    a = tyres.step(X0.copy(), S, th, mu, FZ, 0.031, 22.2, 1e-2, *args)
    b = tyres.step_input(X0.copy(), S, th, mu, FZ, np.array([0.025, 0, 0, 0]), 0.006, 22.2, 1e-2, *args)
    c = tyres.step_input(X0.copy(), S, th, mu, FZ, np.array([0.031, 0, 0, 0]), 0.0, 22.2, 1e-2, *args)
    np.testing.assert_array_equal(a[0], c[0])
    np.testing.assert_array_equal(a[1], c[1])
    np.testing.assert_allclose(b[0], a[0], rtol=1e-14)  # (0.025 + 0.006: one rounding)
    X = np.stack([X0, 0.5 * X0])
    thetas, mus = np.stack([THETA, THETA * 1.1]), np.array([[0.8, 0.8], [0.9, 0.7]])
    deltas = np.array([0.03, -0.01])
    held = tyres.step_points(X, thetas, mus, FZ, deltas, 22.2, 1e-2, KN)
    shifted = tyres.step_points_input(X, thetas, mus, FZ, np.array([0.02, 0, 0, 0]), deltas - 0.02, 22.2, 1e-2, KN)
    np.testing.assert_allclose(shifted, held, rtol=1e-14)
    for s in range(2):
        one, _ = tyres.step_input(X[s].copy(), np.zeros((6, 0)), thetas[s], mus[s], FZ, W_CUBIC, deltas[s], 22.2,
                                  1e-2, KN, -np.ones(10, dtype=np.int64), np.ones(8), NONE_I, NONE_F)
        many = tyres.step_points_input(X, thetas, mus, FZ, W_CUBIC, deltas, 22.2, 1e-2, KN)[s]
        np.testing.assert_allclose(many, one, rtol=1e-14)


# -- the array path with the cubic input (tests/test_array_path.py's checks) ---------------------------
def test_the_ukfs_array_path_gives_the_per_sample_numbers_with_the_cubic():
    one, many = _both("ukf", simulate(CAR, TRUTH, duration_s=6.0, seed=1).run, config=CUBIC)
    _assert_same(one, many)
    assert one.events["corrections"] > 200


def test_the_ukfs_array_path_keeps_every_guard_with_the_cubic():
    one, many = _both("ukf", _damaged_run(), config=CUBIC)
    _assert_same(one, many)
    for event in ("outliers_rejected", "missing_values", "invalid_samples", "missing_samples", "gaps",
                  "frozen_low_speed"):
        assert one.events.get(event, 0) > 0, event


@pytest.mark.parametrize("filt", ["ekf", "ukf"])
def test_the_array_path_with_saturating_tyres_and_the_cubic(filt):
    one, many = _both(filt, _damaged_run(2.5), effects=[parse_effect_to_estimate("tire_saturation")], config=CUBIC)
    _assert_same(one, many)
    assert one.extra_states


@pytest.mark.parametrize("norm", [1e-3, 0.1, 0.5, 1.5, 4.0, 30.0])
@pytest.mark.parametrize("chain", [True, False], ids=["chain", "any"])
def test_the_compiled_expm_of_ten_by_ten_matrices(norm, chain):
    """model/compiled.py's expm and Fréchet derivative at 10 × 10 (the generator with the cubic input's chain:
    its products skip the zero lower-left block; any other 10 × 10: every product whole) against scipy's."""
    from scipy.linalg import expm, expm_frechet

    from online_id.model.compiled import expm_frechet as compiled_expm_frechet

    rng = np.random.default_rng(int(norm * 1000) + chain)
    for _ in range(5):
        X = rng.standard_normal((10, 10))
        E = rng.standard_normal((2, 10, 10))
        if chain:
            X[6:] = 0.0
            X[6, 7] = X[7, 8] = X[8, 9] = 2.0 ** -6
            E[:, 6:] = 0.0
        X *= norm / np.abs(X).sum(axis=0).max()
        F, L = np.empty((10, 10)), np.empty((2, 10, 10))
        compiled_expm_frechet(X, E, F, L)
        scale = np.exp(np.abs(X).sum(axis=0).max())
        np.testing.assert_allclose(F, expm(X), rtol=0, atol=1e-14 * scale)
        for k in range(2):
            np.testing.assert_allclose(L[k], expm_frechet(X, E[k], compute_expm=False), rtol=0, atol=1e-14 * scale)
        if chain:
            assert not F[7:, :7].any() and not L[:, 7:, :7].any()


def test_the_polishs_tyre_pass_takes_the_curve_and_the_hold_as_before():
    """simulate_blocks_input (the polish's tyre model with a curve): with the hold's inputs [δ, 0, 0, 0] it is
    simulate_blocks bit for bit; with a 4 Hz steering's cubic at 25 Hz its block means differ from the held
    ones (the curve reaches the stages) and match a run of the same curve at 8 times finer steps, where the
    held ones lag by half a sample."""
    n, q, dt, V = 400, 4, 1 / 25, np.full(400, 22.2)
    t = np.arange(n) * dt
    delta = 0.04 * np.sin(2 * np.pi * 4.0 * t)
    mu = np.array([0.8, 0.8])
    W = np.zeros((n, 4))
    W[:, 0] = delta
    held = tyres.simulate_blocks(THETA, mu, FZ, delta, V, dt, KN, q, 1)
    same = tyres.simulate_blocks_input(THETA, mu, tyres.per_sample_loads(FZ, n), W, V, dt, KN, q, 1)
    np.testing.assert_array_equal(same[0], held[0])
    np.testing.assert_array_equal(same[1], held[1])
    from online_id.sim.block_means import step_inputs

    W, _ = step_inputs("cubic", delta, V, dt)
    curve = tyres.simulate_blocks_input(THETA, mu, tyres.per_sample_loads(FZ, n), W, V, dt, KN, 1, 1)[0]  # at samples
    fine_W = np.concatenate([its.split_step(w, 8) for w in W])  # the same curve in 8 sub-steps a sample
    fine = tyres.simulate_blocks_input(THETA, mu, tyres.per_sample_loads(FZ, 8 * n), fine_W, np.full(8 * n, 22.2),
                                       dt / 8, KN, 1, 1)[0][::8]
    held = tyres.simulate_blocks(THETA, mu, FZ, delta, V, dt, KN, 1, 1)[0]
    scale = np.abs(fine).max(axis=0)
    err, lag = np.abs(curve - fine).max(axis=0) / scale, np.abs(held - fine).max(axis=0) / scale
    assert err.max() < 0.02 * lag.max() and err.max() < 2e-3, (err, lag)
