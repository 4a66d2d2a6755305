"""The model around one linearisation point, as the EKF uses it: per-sample steps and outputs.

At θ_lin = θ0 e^(s_lin) and speed V_lin one eigen-decomposition of G = [[Ac, Bc], [0, 0]]
(:class:`~online_id.model.discretise.SpectralForm`) gives, for a group of samples of any periods dt_j
and speeds V_j near V_lin,

    [Ad_j, Bd_j] = expm((G + Σ_i Δs_i θ_i ∂G/∂θ_i + ΔV_j ∂G/∂V) dt_j)   to first order in Δs, ΔV_j,
    ∂(Ad_j x + Bd_j δ)/∂s_i = L(G dt_j, θ_i ∂G/∂θ_i dt_j) [x; δ]           (at θ_lin, V_lin),

exact in dt_j (no tolerance on the sample period: a CAN log's jitter costs nothing). A group of one
period (a 100 Hz log, the built-in 1 kHz run) takes the same first-order terms from tables built once
per period and point (:meth:`LocalModel.steps`), in real products; the EKF works a group whose period
changes at every sample with the same formulas in one compiled loop (filters/spectral_group.py). Error against
scipy's expm at the exact (θ, V_j, dt_j), measured over random θ (prior · e^N(0, 0.7)), V in 5-70 m/s
and dt in 0.2-50 ms (tests/test_filters_discretisation.py asserts these):

* Δs = 0, ΔV = 0: ≤ 1e-12 of ‖Φ − I‖ (round-off, the eigenvectors' condition number times 1e-16);
* |Δs_i| ≤ 3e-3 (``relinearise_log_step``) and |ΔV| ≤ 2 % of V (``speed_tolerance``): ≤ 2e-4 of
  ‖Φ − I‖, the neglected second-order term; the speed sensor's own error (0.1-0.5 %) moves Φ more.
* the parameter columns are those at θ_lin, V_lin: first order in Δs, ΔV, like the old per-speed
  Jacobian (they only shape the covariance, never the mean).

The outputs y = C x + D δ do not depend on V (a_y = V(β̇ + r) is the lateral force balance divided by
M, free of V), so :meth:`LocalModel.outputs` is first order in Δs only.

Where the eigenvectors are too ill-conditioned (within ~1e-12 of a coalescing eigenvalue pair)
:class:`ExactModel` takes over: scipy's expm (Van Loan) at each sample's own θ, V and dt, slower but
exact.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from online_id.filters.augment import Augmentation
from online_id.filters.groups import recurse_group
from online_id.filters.spectral_group import propagate_group
from online_id.model.discretise import derivative_blocks, linearise, single_spectral_form
from online_id.model.lateral import BETA, N_STATES, outputs_from_continuous
from online_id.vehicle.parameters import KnownParameters

#: Sample periods of a group within this relative spread are one period (time stamps k·dt parsed
#: from text differ in the last bits); the step's error is then under 1e-9 of Φ − I.
SAMPLE_PERIOD_TOLERANCE = 1e-9
def one_period(dt) -> bool:
    """Whether the sample periods ``dt`` (m,) [s] are one period, within ``SAMPLE_PERIOD_TOLERANCE``."""
    return bool(np.ptp(dt) <= SAMPLE_PERIOD_TOLERANCE * dt[0])


#: Periods whose tables a linearisation point keeps (a jittering log has many; they are rebuilt).
MAX_PERIOD_TABLES = 8


@dataclass(frozen=True)
class LinearOutputs:
    """y = C x + D δ with its sensitivity to the log-scale parameters, ∂y/∂s = dC x + dD δ.

    C (n_out, 6), D (n_out,), dC (n_out · P, 6) (rows: output-major, parameter-minor), dD (n_out, P).

    With extra states e (:meth:`with_extra_states`, filters/augment.py) y = C' x + D δ + M e, where
    C' = C + Σ e_i K_i and δ already includes g·e: ``offset`` is M e (n_out,) and ``extra`` the
    :class:`~online_id.filters.augment.Augmentation`, whose direct sensitivity D gᵀ + M + [K_i x] fills
    the last n columns of H. The parameters' P columns follow the 6 model states. With a delay among them
    (a lag, filters/lagged.py) the outputs' rates ẏ = rate_C x + rate_D δ (C·A and C·B at the point) give
    its columns, −ẏ on the channels it lags.
    """

    C: np.ndarray
    D: np.ndarray
    dC: np.ndarray
    dD: np.ndarray
    offset: np.ndarray | None = None
    extra: Augmentation | None = None
    rate_C: np.ndarray | None = None
    rate_D: np.ndarray | None = None

    def predict(self, x, delta):
        """Outputs for states ``x`` (m, 6) and inputs ``delta`` (m,): (m, n_out)."""
        y = x @ self.C.T + np.multiply.outer(delta, self.D)
        if self.offset is not None:
            y += self.offset
        return y

    def summed(self, sum_x, sum_delta, count):
        """Σ y over ``count`` samples whose states sum to ``sum_x`` (6,) and inputs to ``sum_delta``."""
        y = self.C @ sum_x + self.D * sum_delta
        if self.offset is not None:
            y += count * self.offset
        return y

    def sensitivity(self, F_x, x, delta, count=1):
        """H (n_out, N) of an output y = C x + D δ to the augmented state the chained Jacobian ``F_x``
        (6, N) refers to: C F_x, plus ∂y/∂s in the P parameter columns (and ∂y/∂e directly in the extra
        states' columns). Linear in (F_x, x, δ, count), so sums of them over ``count`` samples give the
        sum of the H."""
        H = self.C @ F_x
        n_out, P = self.dD.shape
        H[:, N_STATES:N_STATES + P] += (self.dC @ x).reshape(n_out, P) + self.dD * delta
        if self.extra is not None:
            rate = None if self.rate_C is None else self.rate_C @ x + self.rate_D * delta
            H[:, N_STATES + P:] += self.extra.sensitivity(self.D, x, count, rate)
        return H

    def at(self, ds):
        """The same outputs at s_lin + ``ds``, first order in ``ds`` (without extra states)."""
        n_out, P = self.dD.shape
        C = self.C + (self.dC.reshape(n_out, P, -1) * ds[:, None]).sum(axis=1)
        return LinearOutputs(C, self.D + self.dD @ ds, self.dC, self.dD)

    def with_extra_states(self, augment: Augmentation, e, rates=None) -> LinearOutputs:
        """The outputs at extra-state values ``e`` (n,): C + Σ e_i K_i, offset M e; with a lag, the outputs'
        rates ``(rate_C, rate_D)`` (:meth:`LocalModel.output_rates`)."""
        rate_C, rate_D = rates if rates is not None else (None, None)
        return replace(self, C=self.C + augment.output_matrix(e), offset=augment.output_offset(e), extra=augment,
                       rate_C=rate_C, rate_D=rate_D)


def _outputs(Ac, Bc, dAc_s, dBc_s, speed) -> LinearOutputs:
    """Outputs at (θ, V): only a_y (row 3) depends on θ, a_y = V (Ac[β] + e_r) x + V Bc[β] δ."""
    C, D = outputs_from_continuous(Ac, Bc, np.asarray(speed, dtype=float))
    P = dAc_s.shape[0]
    dC = np.zeros((C.shape[0], P, N_STATES))
    dC[3] = speed * dAc_s[:, BETA, :]
    dD = np.zeros((C.shape[0], P))
    dD[3] = speed * dBc_s[:, BETA]
    return LinearOutputs(C, D, dC.reshape(-1, N_STATES), dD)


class GroupSteps:
    """The steps of one group of samples: ``Ad`` (m, 6, 6), ``Bd`` (m, 6), and their parameter columns."""

    def __init__(self, form, weights, Ad, Bd, n_params):
        self._form, self._weights = form, weights
        self.Ad, self.Bd = Ad, Bd
        self._params = slice(0, n_params)

    def parameter_columns(self, x_before, delta):
        """J_j = ∂(Ad_j x_j-1 + Bd_j δ_j)/∂s, (m, 6, P), from the states before each step (m, 6)."""
        z = np.concatenate([x_before, delta[:, None]], axis=1)
        cols = self._form.directional_weighted(self._weights, z, self._params)  # (m, P, 7)
        return cols[:, :, :N_STATES].transpose(0, 2, 1)


class _TableGroupSteps:
    """:class:`GroupSteps` of a group with one sample period, from :class:`LocalModel`'s tables for that
    period: the same numbers (round-off apart) in real products of a few rows."""

    def __init__(self, Ad, Bd, columns_table):
        self.Ad, self.Bd = Ad, Bd
        self.columns_table = self._columns = columns_table  # (7, P · 6): z ↦ the parameters' columns, parameter-major

    def parameter_columns(self, x_before, delta):
        m = len(delta)
        z = np.empty((m, N_STATES + 1))
        z[:, :N_STATES] = x_before
        z[:, N_STATES] = delta
        return (z @ self._columns).reshape(m, -1, N_STATES).transpose(0, 2, 1)


class LocalModel:
    """The model linearised at log-scale parameters ``s`` and ``speed`` (see the module docstring).

    ``covers(s, speed)`` says whether a state is close enough for the first-order steps.
    """

    def __init__(self, theta0, s, speed: float, known: KnownParameters, log_step: float, speed_step: float):
        self.s = np.array(s, dtype=float)
        self.speed = float(speed)
        self._log_step, self._speed_step = log_step, speed_step
        theta = theta0 * np.exp(self.s)
        self.n_params = P = len(theta)
        AB, d = derivative_blocks(theta, speed, known)  # [Ac, Bc] (6, 7); their θ- then V-derivatives (P + 1, 6, 7)
        d[:P] *= theta[:, None, None]  # chain rule to log-scale: ∂/∂s_i = θ_i ∂/∂θ_i
        G = np.zeros((N_STATES + 1, N_STATES + 1))
        G[:N_STATES] = AB
        dG = np.zeros((P + 1, N_STATES + 1, N_STATES + 1))
        dG[:, :N_STATES] = d
        self.form = single_spectral_form(G, dG)
        # for the outputs, built when first asked for: Ac, Bc, ∂Ac/∂s, ∂Bc/∂s
        self._continuous = (AB[:, :N_STATES], AB[:, N_STATES], d[:P, :, :N_STATES], d[:P, :, N_STATES])
        self._outputs = None
        self._period_tables: dict[float, tuple] = {}

    @property
    def usable(self) -> bool:
        return self.form.usable

    def covers(self, s, speed: float) -> bool:
        return (abs(speed - self.speed) <= self._speed_step * self.speed
                and float(np.abs(s - self.s).max()) <= self._log_step)

    def steps(self, s, dt, speed) -> GroupSteps:
        """The group's transitions at parameters ``s``, periods ``dt`` (m,) [s] and speeds ``speed`` (m,).

        A group of one period (within ``SAMPLE_PERIOD_TOLERANCE``: a 100 Hz log's time stamps differ in the
        last bits) takes its steps from the tables of that period (:meth:`_tables`), built once per
        period and linearisation point: Φ_j = Φ_lin + Σ_i Δs_i L_i + ΔV_j L_V, the same first-order
        terms as the general path, without its complex products.
        """
        dt = np.asarray(dt, dtype=float)
        ds = s - self.s
        dV = np.asarray(speed, dtype=float) - self.speed
        if one_period(dt):
            Phi0, L, columns = self._tables(float(dt[0]))
            P = self.n_params
            base = Phi0 + ds @ L[:P]  # (49,): the step at s, V_lin
            Phi = (base + np.multiply.outer(dV, L[P])).reshape(len(dt), N_STATES + 1, N_STATES + 1)
            return _TableGroupSteps(Phi[:, :N_STATES, :N_STATES], Phi[:, :N_STATES, N_STATES], columns)
        coefficients = np.empty((len(dt), self.n_params + 1))
        coefficients[:, :-1] = ds
        coefficients[:, -1] = dV
        weights = self.form.weights(dt)
        Phi = self.form.transitions_weighted(weights, coefficients)
        return GroupSteps(self.form, weights, Phi[:, :N_STATES, :N_STATES], Phi[:, :N_STATES, N_STATES],
                          self.n_params)

    def step(self, s, dt: float, speed: float) -> _TableGroupSteps:
        """:meth:`steps` of one step (``dt`` [s], ``speed`` [m/s]: a group of one period and one speed, its
        step repeated), with the same numbers and without the group's array checks."""
        Phi0, L, columns = self._tables(dt)
        P = self.n_params
        Phi = ((Phi0 + (s - self.s) @ L[:P]) + (speed - self.speed) * L[P]).reshape(1, N_STATES + 1, N_STATES + 1)
        return _TableGroupSteps(Phi[:, :N_STATES, :N_STATES], Phi[:, :N_STATES, N_STATES], columns)

    def _tables(self, dt: float) -> tuple:
        """For one sample period: Φ at the linearisation point (49,), the first-order terms L_k
        (K, 49) of each direction (the parameters', then the speed's), and the parameters' columns
        table (7, P · 6) (:class:`_TableGroupSteps`). Cached per period (a log has one or a few)."""
        key = float(f"{dt:.12g}")  # relative 5e-13: the last bits of parsed time stamps share one table
        tables = self._period_tables.get(key)
        if tables is None:
            if len(self._period_tables) >= MAX_PERIOD_TABLES:
                self._period_tables.clear()
            Phi0, L = self.form.period_table(key)  # Q diag(e^(λ dt)) Q⁻¹, Q (D ∘ W_k) Q⁻¹
            Phi0, L = Phi0.reshape(-1), L.reshape(len(L), -1)
            P, n = self.n_params, N_STATES + 1
            columns = L[:P].reshape(P, n, n)[:, :N_STATES, :].reshape(P * N_STATES, n).T.copy()
            tables = self._period_tables[key] = (Phi0, L, columns)
        return tables

    def output_rates(self) -> tuple[np.ndarray, np.ndarray]:
        """ẏ = rate_C x + rate_D δ at the point: (C·Ac (n_out, 6), C·Bc (n_out,)) (a delay's sensitivity,
        filters/lagged.py; it shapes only the gain, so the point's own speed and parameters serve)."""
        Ac, Bc = self._continuous[0], self._continuous[1]
        C, _ = outputs_from_continuous(Ac, Bc, np.asarray(self.speed, dtype=float))
        return C @ Ac, C @ Bc

    def outputs(self, s) -> LinearOutputs:
        """Outputs at parameters ``s`` (first order in s − s_lin; independent of V)."""
        if self._outputs is None:  # (a linearisation point for a new speed only never needs them)
            self._outputs = _outputs(*self._continuous, self.speed)
        return self._outputs.at(s - self.s)


class _ExactGroupSteps:
    def __init__(self, lins, theta):
        self._lins, self._theta = lins, theta
        self.Ad = np.array([lin.Ad for lin in lins])
        self.Bd = np.array([lin.Bd for lin in lins])

    def parameter_columns(self, x_before, delta):
        th = self._theta
        return np.array([np.einsum("pij,j->ip", lin.dAd * th[:, None, None], x) + (lin.dBd * th[:, None]).T * d
                         for lin, x, d in zip(self._lins, x_before, delta)])


class ExactModel(LocalModel):
    """The fallback where :class:`LocalModel`'s eigenvectors are ill-conditioned: each sample's step
    from scipy's expm at its own θ, V and dt (Van Loan for the derivatives). About 30x slower."""

    def __init__(self, theta0, s, speed, known, log_step, speed_step):
        super().__init__(theta0, s, speed, known, log_step, speed_step)
        self._theta0, self._known = theta0, known

    @property
    def usable(self) -> bool:
        return True

    def steps(self, s, dt, speed):
        theta = self._theta0 * np.exp(s)
        return _ExactGroupSteps([linearise(theta, v, self._known, d) for d, v in zip(dt, speed)], theta)


def local_model(theta0, s, speed: float, known: KnownParameters, log_step: float, speed_step: float) -> LocalModel:
    """A :class:`LocalModel` at (s, speed), or the :class:`ExactModel` where its decomposition is unusable."""
    model = LocalModel(theta0, s, speed, known, log_step, speed_step)
    if model.usable:
        return model
    return ExactModel(theta0, s, speed, known, log_step, speed_step)


#: The speed of :func:`compile_now`'s point [m/s] (any speed the model is defined at).
_COMPILE_SPEED = 20.0


def compile_now(theta0, known: KnownParameters) -> None:
    """Compile (or load from numba's disk cache) the compiled loops of a point (model/compiled.py) and of a
    jittering group (filters/spectral_group.py) now, with the types the filter will use: a live run must
    not stall a few seconds at its first sample or its first jittering group. One point at ``theta0``."""
    model = LocalModel(theta0, np.zeros(len(theta0)), _COMPILE_SPEED, known, 0.0, 0.0)
    X, F = np.zeros((2, N_STATES)), np.zeros((2, N_STATES, N_STATES + len(theta0)))
    propagate_group(model.form, np.array([1e-3]), np.zeros(len(theta0)), np.zeros(1), np.zeros(1), X, F)
    Phi0, _, columns = model._tables(1e-3)  # a one-period group's recursion (filters/groups.py)
    Ad = np.ascontiguousarray(Phi0.reshape(N_STATES + 1, N_STATES + 1)[None, :N_STATES, :N_STATES])
    recurse_group(Ad, np.zeros((1, N_STATES)), columns[None], np.zeros(1, dtype=np.int64), np.zeros(0), np.zeros(1),
                  X, F)
