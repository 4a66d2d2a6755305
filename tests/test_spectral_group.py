"""The compiled group of jittering samples (filters/spectral_group.py) against the numpy path it replaces:
LocalModel.steps (SpectralForm's weights, transitions and directional derivatives), the transition
table, the mean and the chained Jacobians (filters/groups.py)."""

from __future__ import annotations

import numpy as np
import pytest

from online_id.effects.base import ExtraState
from online_id.filters import FilterConfig, ekf
from online_id.filters.augment import Augmentation
from online_id.filters.groups import chain_jacobians, propagate_mean, transition_table
from online_id.filters.local_model import LocalModel
from online_id.filters.spectral_group import propagate_group
from online_id.model.discretise import spectral_form
from online_id.sim.simulator import simulate
from online_id.stream.samples import samples_from_run
from online_id.util.jit import cached_njit
from online_id.vehicle import load_vehicle

LOG_STEP, SPEED_STEP = 3e-3, 0.02
#: Relative to the largest entry: the two paths sum the same products in different orders.
ROUND_OFF = 1e-11


def _numpy_group(steps, x0, w, F0, steering):
    """X, F the way the EKF's table path works them (filters/ekf.py ``_tabled``); ``w`` (m, K) the steps'
    inputs (K = 1: the held δ)."""
    A, T = transition_table(steps.Ad)
    X = propagate_mean(A, T, x0, np.einsum("mak,mk->ma", steps.Gamma, w))
    columns = steps.parameter_columns(X[:-1], w)
    if steering.size:
        columns = np.concatenate([columns, steps.Bd[:, :, None] * steering], axis=2)
    return X, chain_jacobians(A, T, F0, columns)


def _compiled_group(form, dt, ds, dV, x0, w, F0, steering):
    X, F = np.empty((len(dt) + 1, 6)), np.empty((len(dt) + 1,) + F0.shape)
    X[0], F[0] = x0, F0
    propagate_group(form, dt, ds, dV, w, X, F, steering)
    return X, F


def _inputs(rng, m, K, dt):
    """Steps' inputs (m, K) of a steering angle with a bandwidth up to 25 rad/s: w_j ~ 0.02 (ω dt)^j."""
    omega = rng.uniform(0.5, 25.0)
    return rng.normal(0.0, 0.02, (m, K)) * (omega * dt[:, None]) ** np.arange(K)


def _assert_close(a, b):
    np.testing.assert_allclose(a, b, rtol=0, atol=ROUND_OFF * np.abs(b).max())


@pytest.mark.parametrize("K", [1, 4])
@pytest.mark.parametrize("n_extra", [0, 3])
def test_a_jittering_group_equals_the_numpy_path_at_random_points(n_extra, K):
    """40 random points (θ = prior · e^N(0, 0.7), V 5-70 m/s), periods jittering 0.1-29 ms (the RAV4 log's
    range), parameters and speed moved within a point's range, with and without extra states; the steps'
    inputs the hold's δ (K = 1) or a cubic's (K = 4: Γ_1..Γ_3 from φ-functions of each sample's period)."""
    car = load_vehicle("haro2008")
    theta0 = car.prior.to_vector()
    rng = np.random.default_rng(7)
    for _ in range(40):
        s, V = rng.normal(0.0, 0.7, 8), rng.uniform(5.0, 70.0)
        model = LocalModel(theta0, s, V, car.known, LOG_STEP, SPEED_STEP, K)
        m = int(rng.integers(1, 41))
        dt = rng.uniform(1e-4, 29e-3, m)
        s1 = s + rng.uniform(-LOG_STEP, LOG_STEP, 8)
        V1 = V * (1 + rng.uniform(-SPEED_STEP, SPEED_STEP, m))
        x0, w = rng.normal(0.0, 0.05, 6), _inputs(rng, m, K, dt)
        F0 = rng.normal(size=(6, 6 + 8 + n_extra))
        steering = rng.normal(size=n_extra)
        X_ref, F_ref = _numpy_group(model.steps(s1, dt, V1), x0, w, F0, steering)
        X, F = _compiled_group(model.form, dt, s1 - model.s, V1 - model.speed, x0, w, F0, steering)
        _assert_close(X, X_ref)
        _assert_close(F, F_ref)
        assert np.abs(F[1:, :, 6:14]).max() > 0  # the parameter columns are really exercised


def test_nearly_equal_eigenvalues_take_the_series_like_the_numpy_path():
    """Two eigenvalues 1e-7 apart (the φ1 series branch of the divided differences) and a complex pair."""
    rng = np.random.default_rng(3)
    lam = np.diag([-5.0, -5.0 + 1e-7, -30.0, -2.0, -7.0, -1.0])
    lam[4, 5], lam[5, 4] = 9.0, -9.0
    S = np.eye(6) + 0.3 * rng.normal(size=(6, 6))
    Ac = S @ lam @ np.linalg.inv(S)
    form = spectral_form(Ac, rng.normal(size=6), rng.normal(size=(3, 6, 6)), rng.normal(size=(3, 6)))
    m = 6
    dt, ds, dV = rng.uniform(1e-3, 3e-2, m), np.array([2e-3, -1e-3]), rng.uniform(-0.3, 0.3, m)
    x0, delta, F0 = rng.normal(size=6), rng.normal(size=m), rng.normal(size=(6, 8))
    coefficients = np.column_stack([np.tile(ds, (m, 1)), dV])
    weights = form.weights(dt)
    Phi = form.transitions_weighted(weights, coefficients)
    A, T = transition_table(Phi[:, :6, :6])
    X_ref = propagate_mean(A, T, x0, Phi[:, :6, 6] * delta[:, None])
    z = np.column_stack([X_ref[:-1], delta])
    columns = form.directional_weighted(weights, z, slice(0, 2))[:, :, :6].transpose(0, 2, 1)
    F_ref = chain_jacobians(A, T, F0, columns)
    X, F = _compiled_group(form, dt, ds, dV, x0, delta, F0, np.zeros(0))
    _assert_close(X, X_ref)
    _assert_close(F, F_ref)
    # with a cubic's inputs: Γ_1..Γ_3 and their first-order terms from each period's input table
    w = _inputs(rng, m, 4, dt)
    w[:, 0] = delta
    tables = [form.input_table(h) for h in dt]
    Gamma = np.concatenate([Phi[:, :6, 6:], np.array([G0 + np.einsum("k,krj->rj", c, LG)
                                                      for (G0, LG), c in zip(tables, coefficients)])], axis=2)
    X_ref = propagate_mean(A, T, x0, np.einsum("mak,mk->ma", Gamma, w))
    z = np.column_stack([X_ref[:-1], delta])
    columns = form.directional_weighted(weights, z, slice(0, 2))[:, :, :6].transpose(0, 2, 1)
    columns += np.array([np.einsum("krj,j->rk", LG[:2], wj[1:]) for (_, LG), wj in zip(tables, w)])
    F_ref = chain_jacobians(A, T, F0, columns)
    X, F = _compiled_group(form, dt, ds, dV, x0, w, F0, np.zeros(0))
    _assert_close(X, X_ref)
    _assert_close(F, F_ref)


def test_arrays_that_do_not_fit_the_group_are_refused():
    """The compiled loop has no bounds checks: every size is checked before it runs."""
    car = load_vehicle("haro2008")
    model = LocalModel(car.prior.to_vector(), np.zeros(8), 20.0, car.known, LOG_STEP, SPEED_STEP)
    dt, ds, dV, delta = np.full(5, 0.01), np.zeros(8), np.zeros(5), np.zeros(5)
    X, F = np.zeros((6, 6)), np.zeros((6, 6, 14))
    with pytest.raises(ValueError, match="do not fit 4 samples"):
        propagate_group(model.form, dt[:4], ds, dV[:4], delta[:4], X, F)
    with pytest.raises(ValueError, match="8 parameters and 3 extra states"):  # no columns for the extra states
        propagate_group(model.form, dt, ds, dV, delta, X, F, steering=np.ones(3))
    for bad in ({"ds": ds[:7]}, {"dV": dV[:4]}, {"delta": delta[:4]}, {"delta": np.zeros((5, 5))}):
        args = {"ds": ds, "dV": dV, "delta": delta} | bad
        with pytest.raises(ValueError, match="do not fit 8 parameters and 5 samples"):
            propagate_group(model.form, dt, args["ds"], args["dV"], args["delta"], X, F)


@pytest.mark.parametrize("kind", ["hold", "cubic"])
def test_the_ekf_on_a_jittering_run_with_extra_states_equals_its_table_path(monkeypatch, kind):
    """The EKF end to end: a jittering run (1-4 ms) whose speed swings ±20 % in 1 s (groups that cross
    linearisation points: several runs per compiled group) with two extra states, against the same filter
    with every group on the numpy table path (``_catch_up``'s other branch), with the hold's and the cubic's
    input between samples."""
    car = load_vehicle("haro2008")
    t = np.arange(3000) * 1e-3
    speed = 80 / 3.6 * (1 + 0.2 * np.sin(2 * np.pi * t / 1.0))
    samples = list(samples_from_run(simulate(car, car.truth("track"), duration_s=3.0, speed_mps=speed, seed=12).run))
    keep = np.cumsum(np.random.default_rng(5).integers(1, 5, size=len(samples)))
    samples = [samples[i] for i in keep[keep < len(samples)]]

    def augment():
        return Augmentation([ExtraState("offsets", "steer", "o", "rad", 0.01, 0.0, steering=1.0),
                             ExtraState("offsets", "ay", "o2", "m/s2", 0.2, 0.0, output=(0, 0, 0, 1.0, 0))])

    compiled_runs = []
    jittered = ekf.EKFEstimator._jittered
    monkeypatch.setattr(ekf.EKFEstimator, "_jittered", lambda self, runs, *a: compiled_runs.append(len(runs))
                        or jittered(self, runs, *a))
    results = []
    for table_path in (False, True):
        if table_path:  # no model counts as a LocalModel: every group takes the table path
            monkeypatch.setattr(ekf, "LocalModel", type("NotALocalModel", (), {}))
        est = ekf.EKFEstimator(car, augment=augment(), config=FilterConfig(intersample=kind))
        for sample in samples:
            est.update(sample)
        est.finish()
        results.append((est.x.copy(), est.P.copy(), dict(est.events)))
    assert len(compiled_runs) > 20 and max(compiled_runs) > 1  # the compiled path ran, with several runs a group
    (x, P, events), (x_ref, P_ref, events_ref) = results
    assert events == events_ref
    sd = np.sqrt(np.diag(P_ref))
    assert np.abs(x - x_ref).max() / sd.min() < 1e-9
    np.testing.assert_allclose(np.diag(P), np.diag(P_ref), rtol=1e-10)


def test_without_a_writable_cache_the_loops_are_compiled_without_one(monkeypatch):
    """Where numba finds no writable cache directory (it raises RuntimeError when the function is defined,
    i.e. at import), the package still imports and runs: compiled without the cache."""
    import online_id.util.jit as jit

    def njit_without_cache_dir(cache=False, **options):
        if cache:
            raise RuntimeError("cannot cache function 'f': no locator available for file 'f.py'")
        return lambda func: ("compiled", func, options)

    monkeypatch.setattr(jit, "njit", njit_without_cache_dir)
    compiled, func, options = cached_njit(fastmath=True)(abs)
    assert (compiled, func, options) == ("compiled", abs, {"fastmath": True})
