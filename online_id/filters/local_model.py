"""The model around one linearisation point, as the EKF uses it: per-sample steps and outputs.

At θ_lin = θ0 e^(s_lin) and speed V_lin one eigen-decomposition of G = [[Ac, Bc], [0, 0]]
(:class:`~online_id.model.discretise.SpectralForm`) gives, for a group of samples of any periods dt_j
and speeds V_j near V_lin,

    [Ad_j, Bd_j] = expm((G + Σ_i Δs_i θ_i ∂G/∂θ_i + ΔV_j ∂G/∂V) dt_j)   to first order in Δs, ΔV_j,
    ∂(Ad_j x + Bd_j δ)/∂s_i = L(G dt_j, θ_i ∂G/∂θ_i dt_j) [x; δ]           (at θ_lin, V_lin),

exact in dt_j (no tolerance on the sample period: a CAN log's jitter costs nothing). With an input
polynomial between samples (``order`` 4, the cubic of :mod:`online_id.model.intersample`: w = [δ(0), δ'(0),
δ''(0), δ'''(0)] in normalised time) the step is x ← Ad_j x + Γ_j w_j with the input columns

    Γ_j,k = [φ_k((G + Σ_i Δs_i θ_i ∂G/∂θ_i + ΔV_j ∂G/∂V) dt_j)]_{0:6, 6}   (Γ_j,0 = Bd_j), first order likewise,
    ∂(Ad_j x + Γ_j w)/∂s_i = L(G dt_j, θ_i ∂G/∂θ_i dt_j) [x; w_0] + Σ_k≥1 L_φk(G dt_j, θ_i ∂G/∂θ_i dt_j)[:, 6] w_k,

φ_k of each of G's eigenvalues on its own and their divided differences for the Fréchet derivatives L_φk
(:meth:`SpectralForm.input_table <online_id.model.discretise.SpectralForm.input_table>`): no recurrence through
(Ac dt)⁻¹, which loses digits on a slow mode. The hold (``order`` 1) works Γ_0 = Bd alone, as before. A group of one
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
* the input columns Γ_1..Γ_3 alike: at the point each column within 1e-12 × the eigenvectors' condition
  number of its largest entry (round-off, as Bd's; measured ≤ 2.2e-13 ×, beside a slow mode too), near it
  ≤ 2e-4 of Γ's largest entry (measured 1.4e-4), their parameter columns ≤ 1e-10 (measured 4e-12).

The outputs y = C x + D δ do not depend on V (a_y = V(β̇ + r) is the lateral force balance divided by
M, free of V), so :meth:`LocalModel.outputs` is first order in Δs only.

Where the eigenvectors are too ill-conditioned (within ~1e-12 of a coalescing eigenvalue pair, or a slow
mode beside the input's eigenvalue 0: a car at its critical speed) :class:`ExactModel` takes over: scipy's
expm (Van Loan) at each sample's own θ, V and dt, slower but exact (with an input polynomial, expm of the
augmented generator of :mod:`online_id.model.intersample` and its Van Loan derivatives).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from online_id.filters import block_close
from online_id.filters.augment import Augmentation
from online_id.filters.groups import recurse_group
from online_id.filters.spectral_group import propagate_group
from online_id.model.discretise import derivative_blocks, linearise, single_spectral_form
from online_id.model.intersample import input_column_derivatives, input_columns
from online_id.model.lateral import BETA, N_STATES, outputs_from_continuous
from online_id.vehicle.parameters import KnownParameters

#: Sample periods of a group within this relative spread are one period (time stamps k·dt parsed
#: from text differ in the last bits); the step's error is then under 1e-9 of Φ − I.
SAMPLE_PERIOD_TOLERANCE = 1e-9
def one_period(dt) -> bool:
    """Whether the sample periods ``dt`` (m,) [s] (an array or a list: a group's few periods, where Python's min
    and max cost less than numpy's ptp) are one period, within ``SAMPLE_PERIOD_TOLERANCE``."""
    return bool(max(dt) - min(dt) <= SAMPLE_PERIOD_TOLERANCE * dt[0])


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
        if self.extra is None:  # (one compiled call: a 100 Hz block's close makes a few of these; issue 36)
            return block_close.output_sensitivity(self.C, self.dC, self.dD, F_x, x, float(delta))
        H = self.C @ F_x
        n_out, P = self.dD.shape
        H[:, N_STATES:N_STATES + P] += (self.dC @ x).reshape(n_out, P) + self.dD * delta
        if self.extra is not None:
            rate = None if self.rate_C is None else self.rate_C @ x + self.rate_D * delta
            H[:, N_STATES + P:] += self.extra.sensitivity(self.D, x, count, rate)
        return H

    def at(self, ds):
        """The same outputs at s_lin + ``ds``, first order in ``ds`` (without extra states)."""
        C, D = block_close.outputs_at(self.C, self.D, self.dC, self.dD, ds)  # (one compiled call; issue 36)
        return LinearOutputs(C, D, self.dC, self.dD)

    def with_extra_states(self, augment: Augmentation, e, rates=None) -> LinearOutputs:
        """The outputs at extra-state values ``e`` (n,): C + Σ e_i K_i, offset M e; with a lag, the outputs'
        rates ``(rate_C, rate_D)`` (:meth:`LocalModel.output_rates`)."""
        rate_C, rate_D = rates if rates is not None else (None, None)
        return replace(self, C=self.C + augment.output_matrix(e), offset=augment.output_offset(e), extra=augment,
                       rate_C=rate_C, rate_D=rate_D)


def _outputs(Ac, Bc, dAc_s, dBc_s, speed) -> LinearOutputs:
    """Outputs at (θ, V): only a_y (row 3) depends on θ, a_y = V (Ac[β] + e_r) x + V Bc[β] δ."""
    C, D = outputs_from_continuous(Ac, Bc, np.asarray(speed, dtype=float), per_unit_speed=True)
    P = dAc_s.shape[0]
    dC = np.zeros((C.shape[0], P, N_STATES))
    dC[3] = speed * dAc_s[:, BETA, :]
    dD = np.zeros((C.shape[0], P))
    dD[3] = speed * dBc_s[:, BETA]
    return LinearOutputs(C, D, dC.reshape(-1, N_STATES), dD)


class GroupSteps:
    """The steps of one group of samples: ``Ad`` (m, 6, 6), ``Gamma`` (m, 6, K) (the input columns Γ_0 = Bd, …,
    Γ_K−1 of the step's input w (m, K), model/intersample.py; K = 1: the hold), and their parameter columns.
    ``input_terms`` (m, P, 6, K − 1): ∂Γ_j/∂s_i, j ≥ 1, of each sample (None for K = 1)."""

    def __init__(self, form, weights, Ad, Gamma, n_params, input_terms=None):
        self._form, self._weights = form, weights
        self.Ad, self.Gamma = Ad, Gamma
        self._params = slice(0, n_params)
        self._input_terms = input_terms

    @property
    def Bd(self):
        """Γ_0 (m, 6): the column of the input's value (the hold's whole input column)."""
        return self.Gamma[:, :, 0]

    def parameter_columns(self, x_before, w):
        """J_j = ∂(Ad_j x_j-1 + Γ_j w_j)/∂s, (m, 6, P), from the states before each step (m, 6) and the steps'
        inputs ``w`` (m, K) (or the held δ (m,))."""
        w = _input_rows(w)
        z = np.concatenate([x_before, w[:, :1]], axis=1)
        cols = self._form.directional_weighted(self._weights, z, self._params)  # (m, P, 7)
        cols = cols[:, :, :N_STATES].transpose(0, 2, 1)
        if self._input_terms is not None and w.shape[1] > 1:
            cols = cols + np.einsum("mpaj,mj->map", self._input_terms, w[:, 1:])
        return cols


def _input_rows(w):
    """The steps' inputs as rows (m, K): a held δ (m,) is the hold's w (m, 1)."""
    w = np.asarray(w, dtype=float)
    return w[:, None] if w.ndim == 1 else w


class _TableGroupSteps:
    """:class:`GroupSteps` of a group with one sample period, from :class:`LocalModel`'s tables for that
    period: the same numbers (round-off apart) in real products of a few rows."""

    def __init__(self, Ad, Gamma, columns_table):
        self.Ad, self.Gamma = Ad, Gamma
        # (6 + K, P · 6): [x; w] ↦ the parameters' columns, parameter-major
        self.columns_table = self._columns = columns_table

    @property
    def Bd(self):
        return self.Gamma[:, :, 0]

    def parameter_columns(self, x_before, w):
        w = _input_rows(w)
        m, K = w.shape
        z = np.empty((m, N_STATES + K))
        z[:, :N_STATES] = x_before
        z[:, N_STATES:] = w
        return (z @ self._columns[:N_STATES + K]).reshape(m, -1, N_STATES).transpose(0, 2, 1)


class LocalModel:
    """The model linearised at log-scale parameters ``s`` and ``speed`` (see the module docstring).

    ``covers(s, speed)`` says whether a state is close enough for the first-order steps. ``order``: the length
    K of the steps' inputs w (model/intersample.py): 1 for the hold (Γ = Bd alone), 4 for an input polynomial
    (Γ_0 … Γ_3).
    """

    def __init__(self, theta0, s, speed: float, known: KnownParameters, log_step: float, speed_step: float,
                 order: int = 1):
        self.s = np.array(s, dtype=float)
        self.speed = float(speed)
        self.order = int(order)
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
        period and linearisation point: Φ_j = Φ_lin + Σ_i Δs_i L_i + ΔV_j L_V and likewise the input columns
        Γ_j, the same first-order terms as the general path, without its complex products.
        """
        dt = np.asarray(dt, dtype=float)
        ds = s - self.s
        dV = np.asarray(speed, dtype=float) - self.speed
        P = self.n_params
        if one_period(dt):
            Phi0, L, columns, inputs = self._tables(float(dt[0]))
            base = Phi0 + ds @ L[:P]  # (49,): the step at s, V_lin
            Phi = (base + np.multiply.outer(dV, L[P])).reshape(len(dt), N_STATES + 1, N_STATES + 1)
            return _TableGroupSteps(Phi[:, :N_STATES, :N_STATES], self._input_columns(Phi, inputs, ds, dV), columns)
        coefficients = np.empty((len(dt), P + 1))
        coefficients[:, :-1] = ds
        coefficients[:, -1] = dV
        weights = self.form.weights(dt)
        Phi = self.form.transitions_weighted(weights, coefficients)
        Gamma, terms = Phi[:, :N_STATES, N_STATES:], None
        if self.order > 1:  # (a mixed group: with an exact fallback's run; each sample's own input table)
            tables = [self.form.input_table(float(h), self.order - 1) for h in dt]
            G0 = np.array([t[0] for t in tables])  # (m, 6, K − 1)
            LG = np.array([t[1] for t in tables])  # (m, P + 1, 6, K − 1)
            extra = G0 + np.einsum("p,mpaj->maj", ds, LG[:, :P]) + dV[:, None, None] * LG[:, P]
            Gamma, terms = np.concatenate([Gamma, extra], axis=2), LG[:, :P]
        return GroupSteps(self.form, weights, Phi[:, :N_STATES, :N_STATES], Gamma, P, terms)

    def step(self, s, dt: float, speed: float) -> _TableGroupSteps:
        """:meth:`steps` of one step (``dt`` [s], ``speed`` [m/s]: a group of one period and one speed, its
        step repeated), with the same numbers and without the group's array checks."""
        Phi0, L, columns, inputs = self._tables(dt)
        ds, dV = s - self.s, speed - self.speed
        # (Φ0 + Σ ds_i L_i + dV L_V in one compiled call; likewise the input columns: issue 36's 100 Hz cost)
        Phi = block_close.first_order(Phi0, L, ds, dV).reshape(1, N_STATES + 1, N_STATES + 1)
        return _TableGroupSteps(Phi[:, :N_STATES, :N_STATES], self._input_columns(Phi, inputs, ds, dV), columns)

    def _input_columns(self, Phi, inputs, ds, dV):
        """Γ (m, 6, K) of steps Φ (m, 7, 7) at ``ds`` and speed offsets ``dV`` (m,) or a number: Γ_0 = Bd (Φ's
        last column), then Γ_1 … Γ_K−1 from the period's input table, first order in ds and dV."""
        if inputs is None:
            return Phi[:, :N_STATES, N_STATES:]
        G0, LG = inputs
        P = self.n_params
        Gamma = np.empty((len(Phi), N_STATES, self.order))
        Gamma[:, :, 0] = Phi[:, :N_STATES, N_STATES]
        if np.ndim(dV) == 0:  # one step (:meth:`step`): G0 + Σ ds_i LG_i + dV LG_V in one compiled call
            Gamma[:, :, 1:] = block_close.first_order(G0, LG, ds, dV).reshape(N_STATES, -1)
        else:
            Gamma[:, :, 1:] = ((G0 + ds @ LG[:P]) + np.multiply.outer(dV, LG[P])).reshape(len(Phi), N_STATES, -1)
        return Gamma

    def _tables(self, dt: float) -> tuple:
        """For one sample period: Φ at the linearisation point (49,), the first-order terms L_k
        (K, 49) of each direction (the parameters', then the speed's), the parameters' columns
        table (6 + order, P · 6) (:class:`_TableGroupSteps`), and with an input polynomial (order > 1) its
        columns Γ_1 … at the point (6 · (order − 1),) and their first-order terms (K, 6 · (order − 1))
        (:meth:`SpectralForm.input_table <online_id.model.discretise.SpectralForm.input_table>`; None for the
        hold). Cached per period (a log has one or a few)."""
        key = float(f"{dt:.12g}")  # relative 5e-13: the last bits of parsed time stamps share one table
        tables = self._period_tables.get(key)
        if tables is None:
            if len(self._period_tables) >= MAX_PERIOD_TABLES:
                self._period_tables.clear()
            # Q diag(e^(λ dt)) Q⁻¹ and Q (D ∘ W_k) Q⁻¹ flat, the columns table (rows 7..: w_j ↦ ∂Γ_j/∂s_i,
            # parameter-major like the rest) and the input polynomial's columns, in one compiled call
            Phi0, L, columns, G0, LG = self.form.local_tables(key, self.n_params, self.order - 1)
            inputs = (G0, LG) if self.order > 1 else None
            tables = self._period_tables[key] = (Phi0, L, columns, inputs)
        return tables

    def output_rates(self) -> tuple[np.ndarray, np.ndarray]:
        """ẏ = rate_C x + rate_D δ at the point: (C·Ac (n_out, 6), C·Bc (n_out,)) (a delay's sensitivity,
        filters/lagged.py; it shapes only the gain, so the point's own speed and parameters serve)."""
        Ac, Bc = self._continuous[0], self._continuous[1]
        C, _ = outputs_from_continuous(Ac, Bc, np.asarray(self.speed, dtype=float), per_unit_speed=True)
        return C @ Ac, C @ Bc

    def outputs(self, s) -> LinearOutputs:
        """Outputs at parameters ``s`` (first order in s − s_lin; independent of V)."""
        if self._outputs is None:  # (a linearisation point for a new speed only never needs them)
            self._outputs = _outputs(*self._continuous, self.speed)
        return self._outputs.at(s - self.s)


class _ExactGroupSteps:
    """Each sample's step at its own θ, V and dt by scipy's expm (Van Loan for the derivatives); with an input
    polynomial (``order`` > 1) its columns Γ_1 … and their derivatives from the augmented generator
    (:func:`~online_id.model.intersample.input_columns`,
    :func:`~online_id.model.intersample.input_column_derivatives`)."""

    def __init__(self, lins, theta, order=1):
        self._lins, self._theta = lins, theta
        self.Ad = np.array([lin.Ad for lin in lins])
        Bd = np.array([lin.Bd for lin in lins])
        self._input_terms = None
        if order > 1:
            Gamma = np.array([input_columns(lin.Ac, lin.Bc, lin.dt) for lin in lins])
            self._input_terms = np.array([input_column_derivatives(
                lin.Ac, lin.Bc, lin.dAc * theta[:, None, None], lin.dBc * theta[:, None], lin.dt)[:, :, 1:order]
                for lin in lins])  # (m, P, 6, order − 1): log scale
            self.Gamma = np.concatenate([Bd[:, :, None], Gamma[:, :, 1:order]], axis=2)
        else:
            self.Gamma = Bd[:, :, None]

    @property
    def Bd(self):
        return self.Gamma[:, :, 0]

    def parameter_columns(self, x_before, w):
        th = self._theta
        w = _input_rows(w)
        cols = np.array([np.einsum("pij,j->ip", lin.dAd * th[:, None, None], x) + (lin.dBd * th[:, None]).T * d
                         for lin, x, d in zip(self._lins, x_before, w[:, 0])])
        if self._input_terms is not None and w.shape[1] > 1:
            cols = cols + np.einsum("mpaj,mj->map", self._input_terms, w[:, 1:])
        return cols


class ExactModel(LocalModel):
    """The fallback where :class:`LocalModel`'s eigenvectors are ill-conditioned: each sample's step
    from scipy's expm at its own θ, V and dt (Van Loan for the derivatives). About 30x slower."""

    def __init__(self, theta0, s, speed, known, log_step, speed_step, order: int = 1):
        super().__init__(theta0, s, speed, known, log_step, speed_step, order)
        self._theta0, self._known = theta0, known

    @property
    def usable(self) -> bool:
        return True

    def steps(self, s, dt, speed):
        theta = self._theta0 * np.exp(s)
        return _ExactGroupSteps([linearise(theta, v, self._known, d) for d, v in zip(dt, speed)], theta, self.order)


def local_model(theta0, s, speed: float, known: KnownParameters, log_step: float, speed_step: float,
                order: int = 1) -> LocalModel:
    """A :class:`LocalModel` at (s, speed), or the :class:`ExactModel` where its decomposition is unusable;
    ``order``: the length of the steps' inputs w (1: the hold)."""
    model = LocalModel(theta0, s, speed, known, log_step, speed_step, order)
    if model.usable:
        return model
    return ExactModel(theta0, s, speed, known, log_step, speed_step, order)


#: The speed of :func:`compile_now`'s point [m/s] (any speed the model is defined at).
_COMPILE_SPEED = 20.0


def compile_now(theta0, known: KnownParameters, order: int = 1) -> None:
    """Compile (or load from numba's disk cache) the compiled loops of a point (model/compiled.py) and of a
    jittering group (filters/spectral_group.py) now, with the types the filter will use: a live run must
    not stall a few seconds at its first sample or its first jittering group. One point at ``theta0``;
    ``order``: the length of the steps' inputs (1: the hold; more: an input polynomial's φ-functions too)."""
    model = LocalModel(theta0, np.zeros(len(theta0)), _COMPILE_SPEED, known, 0.0, 0.0, order)
    X, F = np.zeros((2, N_STATES)), np.zeros((2, N_STATES, N_STATES + len(theta0)))
    w = np.zeros((1, order))
    propagate_group(model.form, np.array([1e-3]), np.zeros(len(theta0)), np.zeros(1), w, X, F)
    steps = model.step(np.zeros(len(theta0)), 1e-3, _COMPILE_SPEED)  # a one-period group's recursion (groups.py)
    recurse_group(np.ascontiguousarray(steps.Ad), np.ascontiguousarray(steps.Gamma), steps.columns_table[None],
                  np.zeros(1, dtype=np.int64), np.zeros(0), w, X, F)
