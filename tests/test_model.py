"""The lateral model: exact discretisation against RK4, physics checks, Jacobians against finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from online_id.model import lateral as L
from online_id.model.discretise import discretise, discretise_with_sensitivity
from online_id.sim import maneuvers
from online_id.sim.simulator import SensorNoise, propagate, simulate
from online_id.units import G
from online_id.vehicle import load_vehicle


@pytest.fixture(scope="module")
def car():
    return load_vehicle("haro2008")


def _rk4_reference_derivative(known, th, V):
    """ẋ = f(x, δ) written out from MODEL.md eqs 1-5 with plain floats, independently of online_id.model.

    The three coupled accelerations (ṙ, β̇, ṗ) come from solving the 3×3 mass matrix of
    the roll, yaw and lateral equations by Cramer's rule.
    """
    M, ms, Mxz, h0, h1, h2 = known.M, known.ms, known.Mxz, known.h0, known.h1, known.h2
    l1, l2, e1, e2 = known.l1, known.l2, known.eps1, known.eps2
    Mzz, Mxx, D1, D2, Aro, Kro, b1, b2 = th.to_vector()
    # unknowns q = (ṙ, β̇, ṗ); rows: roll, yaw, lateral
    m = [[-Mxz, -ms * h0 * V, Mxx + ms * h0 * h0],
         [Mzz, 0.0, -Mxz],
         [0.0, M * V, -ms * h0]]

    def det3(a):
        return (a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
                - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
                + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]))

    det = det3(m)

    def f(x, delta):
        r, beta, phi, p, a1, a2 = x
        rhs = (-Kro * phi - Aro * p + ms * h0 * V * r,
               -l1 * D1 * a1 + l2 * D2 * a2,
               -M * V * r - D1 * a1 - D2 * a2)
        q = []
        for col in range(3):
            mc = [list(row) for row in m]
            for i in range(3):
                mc[i][col] = rhs[i]
            q.append(det3(mc) / det)
        rdot, betadot, pdot = q
        a1dot = (V * beta - V * a1 + h1 * p + l1 * r - V * e1 * phi - V * delta) / b1
        a2dot = (V * beta - V * a2 + h2 * p - l2 * r - V * e2 * phi) / b2
        return (rdot, betadot, p, pdot, a1dot, a2dot), V * (betadot + r)

    return f


def test_discretisation_matches_fine_step_rk4_over_the_60s_chirp(car):
    """Exact ZOH against RK4 with 5 substeps per 1 ms sample, input held over each sample."""
    th, V, rate = car.truth("track"), 80 / 3.6, 1000.0
    dt = 1 / rate
    t = np.arange(int(60 * rate)) * dt
    dH = maneuvers.chirp(t, np.deg2rad(22.0), duration_s=60.0)
    _, y_zoh = propagate(th, car.known, dH, V, dt)

    f = _rk4_reference_derivative(car.known, th, V)
    sub = 5
    h = dt / sub
    x = (0.0,) * 6
    y_rk = np.empty((len(t), 4))
    delta = dH / car.known.steering_ratio
    for k in range(len(t)):
        d, ay = f(x, delta[k])
        y_rk[k] = (x[0], x[2], x[3], ay)
        for _ in range(sub):
            k1, _ = f(x, delta[k])
            k2, _ = f(tuple(xi + h / 2 * ki for xi, ki in zip(x, k1)), delta[k])
            k3, _ = f(tuple(xi + h / 2 * ki for xi, ki in zip(x, k2)), delta[k])
            k4, _ = f(tuple(xi + h * ki for xi, ki in zip(x, k3)), delta[k])
            x = tuple(xi + h / 6 * (a + 2 * b + 2 * c + e) for xi, a, b, c, e in zip(x, k1, k2, k3, k4))
    rel = np.abs(y_zoh[:, :4] - y_rk).max(axis=0) / np.abs(y_rk).max(axis=0)
    for name, e in zip(L.OUTPUT_NAMES, rel):
        assert e < 1e-6, f"{name}: relative error {e:.2e}"


def test_steady_turn_roll_angle_is_ms_h0_ay_over_kro(car):
    th = car.truth("track")
    sim = simulate(car, th, duration_s=15.0, rate_hz=200.0, maneuver="step",
                   amplitude_rad=np.deg2rad(30.0), noise=SensorNoise.none())
    ay, phi = sim.outputs[-1, 3], sim.outputs[-1, 1]
    expected = car.known.ms * car.known.h0 * ay / th.Kro
    assert phi == pytest.approx(expected, rel=0.01)
    assert phi > 0 and ay > 0, "left steer: positive a_y and positive roll (ISO 8855)"


@pytest.mark.parametrize("truth,kmh", [("track", 80.0), ("track60", 60.0), ("constructor", 100.0)])
def test_steady_state_yaw_rate_gain_matches_closed_form(car, truth, kmh):
    """r/δ = 1 / (L/V + M V (l2/D1 − l1/D2)/L − (ε1 − ε2) ms h0 V / Kro), from eqs 1-5 with all rates zero."""
    th, k, V = car.truth(truth), car.known, kmh / 3.6
    Lwb = k.l1 + k.l2
    gain = 1.0 / (Lwb / V + k.M * V * (k.l2 / th.D1 - k.l1 / th.D2) / Lwb
                  - (k.eps1 - k.eps2) * k.ms * k.h0 * V / th.Kro)
    amp = np.deg2rad(20.0)
    sim = simulate(car, th, duration_s=15.0, rate_hz=200.0, speed_mps=V, maneuver="step",
                   amplitude_rad=amp, noise=SensorNoise.none())
    measured = sim.outputs[-1, 0] / (amp / k.steering_ratio)
    assert measured == pytest.approx(gain, rel=0.01)


def test_chirp_at_80kmh_with_22deg_stays_at_0p4g(car):
    """Haro kept |a_y| under 0.4 g. With the Table 6 car the 2.44 Hz resonance gives 0.4005 g at 22°:
    the run must not exceed 0.4 g by more than that rounding, and a smaller amplitude must stay under it."""
    th = car.truth("track")
    peak = np.abs(simulate(car, th, noise=SensorNoise.none()).outputs[:, 3]).max() / G
    assert 0.35 < peak < 0.401
    peak_21 = np.abs(simulate(car, th, amplitude_rad=np.deg2rad(21.9), noise=SensorNoise.none())
                     .outputs[:, 3]).max() / G
    assert peak_21 < 0.4


def _fd(fun, x0, rel=1e-6):
    x0 = np.asarray(x0, dtype=float)
    cols = []
    for i in range(len(x0)):
        h = rel * max(abs(x0[i]), 1e-3)
        xp, xm = x0.copy(), x0.copy()
        xp[i] += h
        xm[i] -= h
        cols.append((np.asarray(fun(xp)) - np.asarray(fun(xm))) / (2 * h))
    return np.stack(cols, axis=-1)


def _assert_close(analytic, numeric, rtol=1e-5):
    scale = np.abs(numeric).max()
    err = np.abs(analytic - numeric).max() / scale
    assert err < rtol, f"relative error {err:.2e}"


@pytest.fixture
def point(car):
    rng = np.random.default_rng(1)
    x = rng.normal(size=6) * np.array([0.2, 0.02, 0.02, 0.1, 0.02, 0.02])
    return x, 0.01, car.truth("track"), 80 / 3.6


def test_state_jacobian_matches_finite_differences(car, point):
    x, u, th, V = point
    J = L.state_jacobian(x, u, th, V, car.known)
    _assert_close(J, _fd(lambda xx: L.state_derivative(xx, u, th, V, car.known), x))


def test_parameter_jacobian_matches_finite_differences(car, point):
    x, u, th, V = point
    J = L.parameter_jacobian(x, u, th, V, car.known)
    num = _fd(lambda t: L.state_derivative(x, u, t, V, car.known), th.to_vector())
    # column by column: each parameter's derivative must be right, not just the largest
    for i in range(8):
        _assert_close(J[:, i], num[:, i])


def test_output_parameter_jacobian_matches_finite_differences(car, point):
    x, u, th, V = point
    J = L.output_parameter_jacobian(x, u, th, V, car.known)
    num = _fd(lambda t: L.outputs(x, u, t, V, car.known), th.to_vector())
    _assert_close(J[3], num[3])
    assert np.all(J[:3] == 0) and np.allclose(num[:3], 0)


def test_discrete_sensitivity_matches_finite_differences(car):
    th, V, dt = car.truth("track"), 80 / 3.6, 1e-3
    Ad, Bd, dAd, dBd = discretise_with_sensitivity(th, V, car.known, dt)
    Ad0, Bd0 = discretise(th, V, car.known, dt)
    assert np.allclose(Ad, Ad0, atol=1e-14) and np.allclose(Bd, Bd0, atol=1e-16)
    # Ad is close to I: a larger central step keeps round-off below the 1e-5 tolerance
    num_A = _fd(lambda t: discretise(t, V, car.known, dt)[0], th.to_vector(), rel=1e-4)
    num_B = _fd(lambda t: discretise(t, V, car.known, dt)[1], th.to_vector(), rel=1e-4)
    for i in range(8):
        _assert_close(dAd[i], num_A[..., i])
        _assert_close(dBd[i], num_B[..., i])


def test_batched_matrices_equal_one_at_a_time(car):
    thetas = np.stack([car.truth("track").to_vector(), car.prior.to_vector()])
    speeds = np.array([10.0, 30.0])
    Ad, Bd = discretise(thetas, speeds, car.known, 1e-3)
    for j in range(2):
        A1, B1 = discretise(thetas[j], speeds[j], car.known, 1e-3)
        assert np.allclose(Ad[j], A1) and np.allclose(Bd[j], B1)


def test_the_spectral_radius_bound_is_above_rho_and_within_a_per_cent():
    """The tyre RK4's stability bound (model/tyres.py ``spectral_radius_bound``): never below the spectral radius
    (an explicit step would blow up), within 1 % above it; on random matrices of every scale and on the race
    car's linear part at parameters a fit without a roll channel reaches (roll damping ×100, Mxx ÷100); and the
    sub-step count it gives is the exact ρ's or one more."""
    from online_id.model import tyres
    from online_id.vehicle import load_vehicle

    rng = np.random.default_rng(5)
    for trial in range(200):
        EA = rng.standard_normal((6, 6)) * 10.0 ** rng.uniform(-3, 8)
        if trial % 3 == 0:  # non-normal: a Jordan-like coupling
            EA = np.triu(EA) + np.diag(rng.uniform(-1, 1, 6)) * np.abs(EA).max()
        rho = np.abs(np.linalg.eigvals(EA)).max()
        bound = tyres.spectral_radius_bound(EA, np.abs(EA).sum(axis=1).max())
        assert rho * (1 - 1e-12) <= bound <= rho * 1.01, (trial, rho, bound)
    car = load_vehicle("revs_250lm")
    kn = tyres.known_array(car.known)
    theta = car.truth("constructor").to_vector()
    for scale in (np.ones(8), np.array([1, 0.01, 1, 1, 1, 1, 1, 1.0]), np.array([1, 1, 1, 1, 100, 1, 1, 1.0]),
                  np.array([1, 1, 1, 1, 1, 100, 1, 1.0])):
        th = tyres.floored(theta * scale)
        for V in (5.0, 30.0, 75.0):
            E, A = tyres._linear_parts(th, V, kn)
            EA = np.linalg.solve(E, A)
            rho = np.abs(np.linalg.eigvals(EA)).max()
            exact = max(1, int(np.ceil(max(0.01 * V / th[6:8].min() / tyres.MAX_STIFF_STEP,
                                           0.01 * rho / tyres.MAX_STABLE_STEP))))
            assert exact <= tyres.substeps(0.01, V, th, kn) <= exact + 1


@pytest.mark.parametrize("vehicle", ["haro2008", "revs_250lm"])
def test_the_tyre_passes_inverse_of_e_is_lapacks(vehicle):
    """E⁻¹ and E⁻¹A of the tyre passes (model/tyres.py ``_inverse_parts``: E's 3 × 3 coupled block by cofactors, the
    rest of its diagonal by reciprocals, no LAPACK call a sample): LAPACK's within rounding, at speeds from walking
    pace to 75 m/s and at parameter sets a fit or a sigma point reaches (each parameter × or ÷ 100); and at V = 0,
    where E is singular, the same error as LAPACK's inverse, not numbers."""
    from online_id.model import tyres
    from online_id.vehicle import load_vehicle

    car = load_vehicle(vehicle)
    kn = tyres.known_array(car.known)
    theta = car.truth("constructor" if vehicle == "revs_250lm" else "track").to_vector()
    rng = np.random.default_rng(3)
    for trial in range(60):
        th = tyres.floored(theta * (1.0 if trial == 0 else 10.0 ** rng.uniform(-2, 2, 8)))
        for V in (0.5, 12.0, 33.3, 75.0):
            E, A = tyres._linear_parts(th, V, kn)
            Einv, EA = tyres._inverse_parts(th, V, kn)
            np.testing.assert_allclose(Einv @ E, np.eye(6), atol=1e-9)
            np.testing.assert_allclose(EA, np.linalg.solve(E, A), rtol=1e-9,
                                       atol=1e-12 * np.abs(np.linalg.solve(E, A)).max())
            assert tyres.substeps_from(0.01, V, th, EA) == tyres.substeps_from(0.01, V, th, np.linalg.solve(E, A))
    with pytest.raises(np.linalg.LinAlgError):
        tyres._inverse_parts(tyres.floored(theta), 0.0, kn)


@pytest.mark.parametrize("vehicle", ["haro2008", "revs_250lm"])
def test_the_tyre_filters_output_is_its_rhs(vehicle):
    """The tyre EKF's outputs at a sample (model/tyres.py ``output``: E⁻¹ by cofactors and β̇ with its sensitivity by
    the passes' loops, no LAPACK call or matrix product a sample) are the definition's: y, H = C·S + ∂y/∂(constants)
    and C = ∂y/∂x from ``_rhs`` (LAPACK's E⁻¹, numpy's products), within rounding: a μ for both axles or one each,
    static or moving loads (the six-column row), a parameter column dropped, a steering shift's column, parameter
    sets × or ÷ 10 and speeds from 1 to 70 m/s."""
    from online_id.model import tyres

    car = load_vehicle(vehicle)
    kn = tyres.known_array(car.known)
    theta0 = car.prior.to_vector()
    rng = np.random.default_rng(11)
    for trial in range(120):
        th = tyres.floored(theta0 * 10.0 ** rng.uniform(-1, 1, 8))
        x = rng.normal(0, [0.3, 0.05, 0.05, 0.2, 0.05, 0.05])
        S = rng.normal(0, 1, (6, 17))
        mu = rng.uniform(0.3, 1.5, 2)
        Fz = np.array([4000.0, 5000.0]) if trial % 3 else np.array([4000.0, 5000.0, -1800.0, 2500.0, 1.2, 0.85])
        idx = np.arange(6, 16, dtype=np.int64)
        if trial % 2:
            idx[9] = idx[8]
        if trial % 5 == 0:
            idx[3] = -1
        steer_cols = np.array([16] if trial % 4 == 0 else [], dtype=np.int64)
        steer_g = np.full(len(steer_cols), 0.3)
        V, delta, scale = rng.uniform(1, 70), rng.normal(0, 0.05), np.ones(8)
        y, H, C = tyres.output(x, S, th, mu, Fz, delta, V, kn, idx, scale, steer_cols, steer_g)
        f, J, Dz = tyres._rhs(x, th, mu, Fz, delta, V, kn, idx, scale, steer_cols, steer_g, S.shape[1])
        C_ref = np.zeros((5, 6))
        C_ref[[0, 1, 2, 4], [L.R, L.PHI, L.P, L.BETA]] = 1.0
        C_ref[3] = V * J[L.BETA]
        C_ref[3, L.R] += V
        H_ref = C_ref @ S
        H_ref[3] += V * Dz[L.BETA]
        y_ref = np.array([x[L.R], x[L.PHI], x[L.P], V * (f[L.BETA] + x[L.R]), x[L.BETA]])
        for got, want, name in ((y, y_ref, "y"), (H, H_ref, "H"), (C, C_ref, "C")):
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max(), err_msg=f"{name} {trial}")


def _blocks_step_by_step(tyres, theta, mu, Fz, W, speeds, dt, kn, q, mu_columns):
    """simulate_blocks_input's definition: the filters' own output() and step_input() sample by sample; ``Fz``
    (n, 2) each sample's axle loads (its output's; the step into the next sample takes the two samples' mean, as the
    filters do)."""
    theta = tyres.floored(theta)
    n_aug = L.N_STATES + L.N_PARAMS + mu_columns
    idx = np.empty(L.N_PARAMS + 2, dtype=np.int64)
    idx[:L.N_PARAMS] = L.N_STATES + np.arange(L.N_PARAMS)
    idx[L.N_PARAMS] = L.N_STATES + L.N_PARAMS
    idx[L.N_PARAMS + 1] = L.N_STATES + L.N_PARAMS + (1 if mu_columns == 2 else 0)
    scale, none_i, none_f = np.ones(L.N_PARAMS), np.zeros(0, dtype=np.int64), np.zeros(0)
    x, S = np.zeros(L.N_STATES), np.zeros((L.N_STATES, n_aug))
    n_blocks = len(W) // q
    Y, dY = np.zeros((n_blocks, 5)), np.zeros((n_blocks, 5, n_aug - L.N_STATES))
    for k in range(n_blocks * q):
        y, H, _ = tyres.output(x, S, theta, mu, Fz[k], W[k, 0], speeds[k], kn, idx, scale, none_i, none_f)
        y[4] *= speeds[k]
        H[4] *= speeds[k]
        Y[k // q] += y / q
        dY[k // q] += H[:, L.N_STATES:] / q
        step = 0.5 * (Fz[k] + Fz[k + 1]) if k + 1 < len(W) else Fz[k]
        x, S = _rk4_by_rhs(tyres, x, S, theta, mu, step, W[k], speeds[k], dt, kn, idx, scale, none_i, none_f)
    return Y, dY


def _rk4_by_rhs(tyres, x, S, th, mu, Fz, w, V, dt, kn, idx, scale, steer_cols, steer_g, shift=0.0):
    """One step as the module docstring defines it, each stage by _rhs (E⁻¹ formed there): the reference of
    step_input and of the polish's pass."""
    n = tyres.substeps(dt, V, th, kn)
    h = dt / n
    want = S.shape[1]
    for i in range(n):
        d0, dm, d1 = (tyres.input_at(w, (i + c) / n, shift) for c in (0.0, 0.5, 1.0))
        f1, J1, Z1 = tyres._rhs(x, th, mu, Fz, d0, V, kn, idx, scale, steer_cols, steer_g, want)
        k1 = J1 @ S + Z1
        f2, J2, Z2 = tyres._rhs(x + 0.5 * h * f1, th, mu, Fz, dm, V, kn, idx, scale, steer_cols, steer_g, want)
        k2 = J2 @ (S + 0.5 * h * k1) + Z2
        f3, J3, Z3 = tyres._rhs(x + 0.5 * h * f2, th, mu, Fz, dm, V, kn, idx, scale, steer_cols, steer_g, want)
        k3 = J3 @ (S + 0.5 * h * k2) + Z3
        f4, J4, Z4 = tyres._rhs(x + h * f3, th, mu, Fz, d1, V, kn, idx, scale, steer_cols, steer_g, want)
        k4 = J4 @ (S + h * k3) + Z4
        x = x + h / 6.0 * (f1 + 2.0 * f2 + 2.0 * f3 + f4)
        S = S + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x, S


def test_a_tyre_filters_step_is_its_stages_by_rhs():
    """step_input (E⁻¹ once a step, the stages by loops into buffers) against the stages by _rhs: a filter's
    augmented state (model states, the 8, an extra state steering the wheels and a μ per axle in their columns,
    one parameter left out), a state deep in the tyres' saturation, the cubic input and a steering shift."""
    from online_id.model import tyres

    car = load_vehicle("revs_250lm")
    kn = tyres.known_array(car.known)
    from online_id.vehicle.parameters import axle_loads

    Fz, theta, mu = axle_loads(car.known), car.prior.to_vector() * 1.3, np.array([1.1, 1.25])
    n_aug = L.N_STATES + L.N_PARAMS + 3
    idx = np.array([L.N_STATES + p for p in range(L.N_PARAMS)] + [n_aug - 2, n_aug - 1], dtype=np.int64)
    idx[1] = -1  # a fixed parameter: no column
    scale = np.linspace(0.5, 1.5, L.N_PARAMS)
    steer_cols, steer_g = np.array([n_aug - 3], dtype=np.int64), np.array([0.7])
    rng = np.random.default_rng(3)
    x = np.array([0.4, -0.05, 0.03, 0.2, 0.12, 0.09])  # yaw rate, sideslip, roll, roll rate, slip angles [rad]
    S = rng.normal(size=(L.N_STATES, n_aug))
    w = np.array([0.05, 0.02, -0.01, 0.004])
    for V, dt in ((45.0, 0.01), (12.0, 0.04)):
        args = (theta, mu, Fz, w, 0.01, V, dt, kn, idx, scale, steer_cols, steer_g)
        got = tyres.step_input(x, S, *args)
        want = _rk4_by_rhs(tyres, x, S, tyres.floored(theta), mu, Fz, w, V, dt, kn, idx, scale, steer_cols, steer_g,
                           shift=0.01)
        for a, b in zip(got, want):
            assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max(), np.abs(a - b).max() / np.abs(b).max()


@pytest.mark.parametrize("vehicle, mu, mu_columns, amplitude", [("haro2008", (0.7, 0.7), 1, 1.2),
                                                                  ("revs_250lm", (1.06, 1.27), 2, 2.5)])
def test_the_tyre_polishs_pass_is_the_filters_steps_sample_by_sample(vehicle, mu, mu_columns, amplitude):
    """simulate_blocks_input (the tyre polish's pass, its stages by loops into buffers, E⁻¹ once a sample) gives
    the block means and sensitivities of output() and step_input() taken sample by sample, to round-off: on the
    Table 6 car and on the race car (1.1 g, μ per axle, a speed that changes at every sample, the cubic input, the
    axle loads moved by braking and traction at every sample: load_transfer's)."""
    from online_id.model import tyres
    from online_id.sim.block_means import step_inputs
    from online_id.vehicle.parameters import axle_loads_at

    car = load_vehicle(vehicle)
    n, dt = 600, 0.01
    t = np.arange(n) * dt
    kn, Fz = tyres.known_array(car.known), axle_loads_at(car.known, 6.0 * np.sin(1.3 * t))
    theta = car.prior.to_vector()
    delta = amplitude * np.deg2rad(3) * np.sin(2 * np.pi * (0.3 + 0.5 * t) * t)
    W, V = step_inputs("cubic", delta, 30 + 10 * np.sin(0.3 * t), dt)
    W, V = np.ascontiguousarray(W[:n]), np.ascontiguousarray(V[:n])
    want = _blocks_step_by_step(tyres, theta, np.array(mu), Fz, W, V, dt, kn, 5, mu_columns)
    got = tyres.simulate_blocks_input(theta, np.array(mu), Fz, W, V, dt, kn, 5, mu_columns)
    assert np.abs(want[0][:, 3]).max() > (10.0 if vehicle == "revs_250lm" else 5.0)  # into the tyres' saturation
    for a, b in zip(want, got):
        assert a.shape == b.shape
        assert np.abs(a - b).max() <= 1e-12 * np.abs(a).max(), np.abs(a - b).max() / np.abs(a).max()


def test_the_ukfs_sigma_point_steps_are_their_stages_by_rhs():
    """step_points_input (the UKF's sigma points through the tyre model: E⁻¹A once a point, the stages by
    _rhs_into) against each point's stages by _rhs, the mean alone: spread parameters and μ, a steering shift per
    point, states deep in the tyres' saturation."""
    from online_id.model import tyres
    from online_id.vehicle.parameters import axle_loads

    car = load_vehicle("revs_250lm")
    kn, Fz = tyres.known_array(car.known), axle_loads(car.known)
    rng = np.random.default_rng(5)
    n = 9
    thetas = car.prior.to_vector() * np.exp(rng.normal(0.0, 0.3, size=(n, 8)))
    mus = rng.uniform(0.9, 1.4, size=(n, 2))
    X = rng.normal(0.0, 0.1, size=(n, L.N_STATES))
    shifts = rng.normal(0.0, 0.01, size=n)
    w = np.array([0.05, 0.02, -0.01, 0.004])
    idx, scale = -np.ones(L.N_PARAMS + 2, dtype=np.int64), np.ones(L.N_PARAMS)
    none_i, none_f = np.zeros(0, dtype=np.int64), np.zeros(0)
    for V, dt in ((45.0, 0.01), (12.0, 0.04)):
        got = tyres.step_points_input(X, thetas, mus, Fz, w, shifts, V, dt, kn)
        for s in range(n):
            th = tyres.floored(thetas[s])
            want, _ = _rk4_by_rhs(tyres, X[s], np.zeros((L.N_STATES, 0)), th, mus[s], Fz, w, V, dt, kn, idx, scale,
                                  none_i, none_f, shift=shifts[s])
            assert np.abs(got[s] - want).max() <= 1e-12 * np.abs(want).max()
