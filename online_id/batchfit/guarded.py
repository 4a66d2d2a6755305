"""Least squares that guard their numbers: a non-finite cost or Jacobian stops the step with a reason.

:func:`scipy.optimize.least_squares` hands its Jacobian to LAPACK's SVD, which refuses a NaN or an infinity
with ``ValueError: array must not contain infs or NaNs`` and a traceback, and a cost that overflowed
(a model simulated at parameters where it is unstable: outputs of 1e307) passes as a number until then.
:func:`guarded_least_squares` checks before scipy sees them:

- the residuals at the start: every one finite, and their sum of squares too (no overflow);
- every Jacobian: every entry finite, and every column's norm (what the trust region scales by);

and stops with :class:`NonFiniteStep` (an :class:`~online_id.errors.OnlineIdError`) naming what was not
finite, where, and the likely cause. Trial points with a non-finite cost are left to scipy, which rejects
them and shrinks its trust region. Without a callable Jacobian the forward differences are taken here
(scipy's ``'2-point'`` scheme, the same steps and the same bound handling), so that they are checked too.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.optimize import least_squares

from online_id.errors import OnlineIdError

#: scipy's default relative step of its '2-point' differences: √(machine ε).
DEFAULT_DIFF_STEP = float(np.sqrt(np.finfo(float).eps))


class NonFiniteStep(OnlineIdError):
    """A least-squares step met a non-finite cost or Jacobian (see the module docstring)."""


def _largest(values: np.ndarray) -> str:
    finite = np.abs(values[np.isfinite(values)])
    return f"{finite.max():.3g}" if finite.size else "none finite"


def check_residuals(r: np.ndarray, what: str, where: str) -> None:
    """Raise :class:`NonFiniteStep` unless ``r`` and its sum of squares are finite."""
    bad = ~np.isfinite(r)
    if bad.any():
        raise NonFiniteStep(f"{what} stopped: {int(bad.sum())} of {r.size} residuals {where} are not finite"
                            " (NaN or inf): the model's simulated outputs overflow at these parameters")
    with np.errstate(over="ignore"):
        cost = float(r @ r)
    if not np.isfinite(cost):
        raise NonFiniteStep(f"{what} stopped: the cost {where} is not finite (residuals up to {_largest(r)}):"
                            " the model's simulated outputs diverge at these parameters")


def check_jacobian(J: np.ndarray, what: str, names: Sequence[str] = ()) -> None:
    """Raise :class:`NonFiniteStep` unless every entry of ``J`` (residuals × unknowns) and every column norm
    is finite; the message names the unknowns (``names``, else their indices) whose columns are not."""
    J = np.asarray(J, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        column_ok = np.all(np.isfinite(J), axis=0) & np.isfinite(np.linalg.norm(J, axis=0))
    if column_ok.all():
        return
    columns = [names[i] if i < len(names) else f"#{i}" for i in np.flatnonzero(~column_ok)]
    raise NonFiniteStep(f"{what} stopped: its Jacobian is not finite in {', '.join(columns)} (entries up to"
                        f" {_largest(J)}): the model's outputs overflow near these parameters")


def forward_differences(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray, f0: np.ndarray,
                        lower: np.ndarray, upper: np.ndarray, rel_step: float | None = None) -> np.ndarray:
    """Forward-difference Jacobian (len(f0), len(x)) of ``fun`` at ``x`` with scipy's '2-point' steps:
    √ε·sign(x)·max(1, |x|), or ``rel_step``·sign(x)·|x| when given (√ε·sign(x)·max(1, |x|) where that is
    no step at all); reversed where it would leave the bounds and fits the other way, else cut to the room."""
    x = np.asarray(x, dtype=float)
    sign = np.where(x >= 0, 1.0, -1.0)
    default = DEFAULT_DIFF_STEP * sign * np.maximum(1.0, np.abs(x))
    h = default if rel_step is None else rel_step * sign * np.abs(x)
    h = np.where((x + h) - x == 0, default, h)
    lower_room, upper_room = x - lower, upper - x
    outside = (x + h < lower) | (x + h > upper)
    fits = np.abs(h) <= np.maximum(lower_room, upper_room)
    h = np.where(outside & fits, -h, h)
    h = np.where(~fits & (upper_room >= lower_room), upper_room, np.where(~fits, -lower_room, h))
    J = np.empty((len(f0), len(x)))
    for i in range(len(x)):
        xi = x.copy()
        xi[i] += h[i]
        J[:, i] = (np.asarray(fun(xi), dtype=float) - f0) / (xi[i] - x[i])  # the step the arithmetic took
    return J


def guarded_least_squares(fun: Callable[[np.ndarray], np.ndarray], x0, *, what: str,
                          names: Sequence[str] = (), start: str = "at its start", jac: Callable | None = None,
                          bounds=(-np.inf, np.inf), diff_step: float | None = None, **options):
    """:func:`scipy.optimize.least_squares` (``method``, tolerances, ``max_nfev`` ... in ``options``) with the
    checks of the module docstring; ``what`` ("the polish"), ``names`` (of the unknowns) and ``start`` ("at the
    filter's estimate") word the reason. Raises :class:`NonFiniteStep` instead of reaching LAPACK with
    non-finite numbers."""
    x0 = np.asarray(x0, dtype=float)
    lower, upper = (np.broadcast_to(np.asarray(b, dtype=float), x0.shape) for b in bounds)
    last: dict = {}

    def residuals(x):
        r = np.asarray(fun(x), dtype=float)
        if not last:
            check_residuals(r, what, start)
        last.update(key=np.asarray(x, dtype=float).tobytes(), r=r)
        return r

    def jacobian(x):
        x = np.asarray(x, dtype=float)
        if jac is not None:
            J = jac(x)
        else:
            f0 = last["r"] if last.get("key") == x.tobytes() else np.asarray(fun(x), dtype=float)
            J = forward_differences(fun, x, f0, lower, upper, diff_step)
        check_jacobian(J, what, names)
        return J

    try:
        return least_squares(residuals, x0, jac=jacobian, bounds=(lower, upper), **options)
    except np.linalg.LinAlgError as exc:  # the checks above make this rare: an SVD that did not converge
        raise NonFiniteStep(f"{what} stopped: the linear algebra failed ({exc})") from None
    except ValueError as exc:
        if "finite" in str(exc) or "infs or NaNs" in str(exc):
            raise NonFiniteStep(f"{what} stopped: non-finite numbers reached the solver ({exc})") from None
        raise
