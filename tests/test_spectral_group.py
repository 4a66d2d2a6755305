"""The compiled group of jittering samples (filters/spectral_group.py) against the numpy path it replaces:
LocalModel.steps (SpectralForm's weights, transitions and directional derivatives), the transition
table, the mean and the chained Jacobians (filters/groups.py)."""

from __future__ import annotations

import numpy as np
import pytest

from online_id.filters.groups import chain_jacobians, propagate_mean, transition_table
from online_id.filters.local_model import LocalModel
from online_id.filters.spectral_group import propagate_group
from online_id.model.discretise import spectral_form
from online_id.vehicle import load_vehicle

LOG_STEP, SPEED_STEP = 3e-3, 0.02
#: Relative to the largest entry: the two paths sum the same products in different orders.
ROUND_OFF = 1e-11


def _numpy_group(steps, x0, delta, F0, steering):
    """X, F the way the EKF's table path works them (filters/ekf.py ``_tabled``)."""
    A, T = transition_table(steps.Ad)
    X = propagate_mean(A, T, x0, steps.Bd * delta[:, None])
    columns = steps.parameter_columns(X[:-1], delta)
    if steering.size:
        columns = np.concatenate([columns, steps.Bd[:, :, None] * steering], axis=2)
    return X, chain_jacobians(A, T, F0, columns)


def _compiled_group(form, dt, ds, dV, x0, delta, F0, steering):
    X, F = np.empty((len(dt) + 1, 6)), np.empty((len(dt) + 1,) + F0.shape)
    X[0], F[0] = x0, F0
    propagate_group(form, dt, ds, dV, delta, X, F, steering)
    return X, F


def _assert_close(a, b):
    np.testing.assert_allclose(a, b, rtol=0, atol=ROUND_OFF * np.abs(b).max())


@pytest.mark.parametrize("n_extra", [0, 3])
def test_a_jittering_group_equals_the_numpy_path_at_random_points(n_extra):
    """40 random points (θ = prior · e^N(0, 0.7), V 5-70 m/s), periods jittering 0.1-29 ms (the RAV4 log's
    range), parameters and speed moved within a point's range, with and without extra states."""
    car = load_vehicle("haro2008")
    theta0 = car.prior.to_vector()
    rng = np.random.default_rng(7)
    for _ in range(40):
        s, V = rng.normal(0.0, 0.7, 8), rng.uniform(5.0, 70.0)
        model = LocalModel(theta0, s, V, car.known, LOG_STEP, SPEED_STEP)
        m = int(rng.integers(1, 41))
        dt = rng.uniform(1e-4, 29e-3, m)
        s1 = s + rng.uniform(-LOG_STEP, LOG_STEP, 8)
        V1 = V * (1 + rng.uniform(-SPEED_STEP, SPEED_STEP, m))
        x0, delta = rng.normal(0.0, 0.05, 6), rng.normal(0.0, 0.02, m)
        F0 = rng.normal(size=(6, 6 + 8 + n_extra))
        steering = rng.normal(size=n_extra)
        X_ref, F_ref = _numpy_group(model.steps(s1, dt, V1), x0, delta, F0, steering)
        X, F = _compiled_group(model.form, dt, s1 - model.s, V1 - model.speed, x0, delta, F0, steering)
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


def test_arrays_that_do_not_fit_the_group_are_refused():
    car = load_vehicle("haro2008")
    model = LocalModel(car.prior.to_vector(), np.zeros(8), 20.0, car.known, LOG_STEP, SPEED_STEP)
    X, F = np.zeros((4, 6)), np.zeros((4, 6, 14))
    with pytest.raises(ValueError, match="do not fit 5 samples"):
        propagate_group(model.form, np.full(5, 0.01), np.zeros(8), np.zeros(5), np.zeros(5), X, F)
