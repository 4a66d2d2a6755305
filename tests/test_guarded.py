"""Least squares that guard their numbers (online_id/batchfit/guarded.py): a non-finite cost or Jacobian stops
with a reason instead of reaching LAPACK; a finite problem is solved exactly as scipy solves it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from online_id.batchfit.guarded import NonFiniteStep, guarded_least_squares
from online_id.errors import OnlineIdError


def _rosenbrock(x):
    return np.array([10 * (x[1] - x[0] ** 2), 1 - x[0], 0.5 * (x[2] - 0.3)])


@pytest.mark.parametrize("diff_step", [None, 1e-6])
def test_a_finite_problem_takes_exactly_the_steps_scipy_takes(diff_step):
    """The forward differences are scipy's '2-point' ones, bounds included: same iterates, same answer."""
    bounds = (np.array([-2.0, -1.0, 0.0]), np.array([0.9, 2.0, 1.0]))
    x0 = np.array([-1.2, 1.0, 0.99])
    ours = guarded_least_squares(_rosenbrock, x0, what="test", bounds=bounds, diff_step=diff_step, method="trf",
                                 x_scale=1.0, xtol=1e-12, ftol=1e-12)
    theirs = least_squares(_rosenbrock, x0, bounds=bounds, diff_step=diff_step, method="trf", x_scale=1.0,
                           xtol=1e-12, ftol=1e-12)
    assert np.array_equal(ours.x, theirs.x) and ours.nfev == theirs.nfev
    assert ours.x[0] == pytest.approx(0.9)  # at its bound


def test_a_cost_that_overflows_at_the_start_stops_with_a_reason():
    with pytest.raises(NonFiniteStep, match=r"the polish stopped: the cost at its start is not finite \(residuals"
                                            r" up to 1e\+300\)") as info:
        guarded_least_squares(lambda x: np.full(3, 1e300) * (1 + x[0]), np.zeros(2), what="the polish")
    assert isinstance(info.value, OnlineIdError)  # one line, exit 2, in the CLI
    with pytest.raises(NonFiniteStep, match="2 of 3 residuals at its start are not finite"):
        guarded_least_squares(lambda x: np.array([np.nan, np.inf, 1.0]), np.zeros(2), what="the polish")


def test_a_jacobian_that_is_not_finite_names_the_unknown():
    def fun(x):  # finite at the start, overflowing one step away in b only
        return np.array([x[0] - 1, 1e150 * (1 + 1e170 * x[1]), x[1]])

    with pytest.raises(NonFiniteStep, match=r"the fit stopped: its Jacobian is not finite in b "):
        guarded_least_squares(fun, np.zeros(2), what="the fit", names=["a", "b"])

    def jac(x):  # an analytic Jacobian with a NaN column
        return np.array([[1.0, np.nan], [0.0, 1.0], [0.0, 0.0]])

    with pytest.raises(NonFiniteStep, match="not finite in #1"):
        guarded_least_squares(lambda x: np.array([x[0], x[1], 0.0]), np.ones(2), jac=jac, what="the fit")


def test_the_polish_from_an_unstable_estimate_names_it_and_keeps_the_filter_estimate(tmp_path):
    """The first row of issue 29: the filter, fed a reversed a_y, ended at a model that is unstable at 22 m/s;
    the polish then met a cost of 1e307 and scipy's SVD raised. Now the polish stops with a reason."""
    from online_id.batchfit.polish import polish_estimate
    from online_id.cli.main import main
    from online_id.estimation import make_estimator, run_estimator
    from online_id.io.tracklog import read_track_run
    from online_id.stream.samples import samples_from_run
    from online_id.vehicle.loader import load_vehicle
    from online_id.vehicle.parameters import Parameters

    path = tmp_path / "run.csv"
    assert main(["simulate", "--out", str(path), "--duration", "20", "--rate", "100", "--seed", "2"]) == 0
    run, vehicle = read_track_run(path), load_vehicle("haro2008")
    result = run_estimator(make_estimator(vehicle, "ekf"), samples_from_run(run, ("yaw_rate",)), channels=["yaw_rate"])
    # where the filter ended on the reversed a_y of issue 29 (20 s at 1 kHz): a mode growing at +467 /s
    result.parameters = Parameters(Mzz=49.98, Mxx=11.41, D1=12954.0, D2=68962.5, Aro=7235.7, Kro=6027.1, b1=1.472,
                                   b2=68.43)
    before = result.parameters
    problem = polish_estimate(result, vehicle, run, {"yaw_rate": 0.004}, burn_in_s=1.0)
    assert problem is not None and problem == result.polish["error"]
    assert "the polish stopped: the cost at its start (the filter's estimate) is not finite" in problem
    assert "the model is unstable there at 22.2 m/s (a mode growing at +4" in problem
    assert problem.endswith("kept the filter's estimate")
    assert result.parameters == before and result.online is None
