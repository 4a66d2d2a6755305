"""A final batch polish of an estimate: the output-error maximum-likelihood fit started from the filter.

The online filter carries the parameters as slowly drifting states and leaves part of the
information in a run unused at its end. With white sensor noise of standard deviation σ_c on each
channel c, the maximum-likelihood estimate of θ from the whole run minimises

    Σ_c Σ_k (ȳ_c,k(θ) − z̄_c,k)² / (σ_c² / q)

plus, when a prior is given, Σ_i (ln θ_i − ln θ_prior,i)² / σ_prior,i² (a maximum a posteriori
estimate, the target of the filter too: a parameter the run barely informs stays near its prior
instead of wandering; with the filter's widened prior, σ ≥ 1 in log scale, the term is negligible
for a parameter the run determines), over block means of q samples (ȳ from the exact block simulator,
:class:`~online_id.sim.block_means.BlockSimulator`, starting at rest; the first ``burn_in_s`` left out
when the run may not start at rest). :func:`polish` solves it by Gauss-Newton with a trust region
(:func:`scipy.optimize.least_squares`, its numbers guarded: :mod:`online_id.batchfit.guarded`) on
log-scale factors around the start, with a Jacobian whose 8 finite-difference columns are simulated
together in one batch. Started from the filter's estimate, it is a few iterations from the minimum.

Failing fast: every evaluation of the cost is watched (:class:`_Watch`). A polish whose best point still misses
a channel by half its spread and more than 5 noise σ after :data:`FAR_ITERATIONS` evaluations, its cost no longer
falling, or whose best point holds a parameter on its bound while the cost stalls, stops at once with
:class:`PolishFailsFast` naming the channel or the parameter; the filter's estimate stays.

Covariance, honestly:

1. Gauss-Newton: (JᵀJ)⁻¹ with J the Jacobian of the weighted residuals at the minimum;
2. each channel's weight uses the noise its residuals show (σ̂_c, the RMS residual), not the
   assumed σ_c, where they differ: a model that misses the data has wider errors than the sensor;
3. inflated by each channel's integrated autocorrelation time of the residuals,
   τ_c = 1 + 2 Σ_{k≥1} ρ_c(k) (summed until ρ first drops below zero, at most
   :data:`MAX_LAG_BLOCKS` lags): correlated residuals carry fewer independent errors than
   samples. White residuals give τ = 1; the largest τ over channels multiplies the covariance.

When the residuals are about white and about σ_c, this is the Cramér-Rao bound at the estimate.

With ``effects`` (``estimate --effect``) their parameters are polished with the 8 (in units of each
parameter's typical size, :class:`~online_id.effects.base.FitParameter`). The saturating tyre law alone: the
filters' own nonlinear model (:func:`online_id.model.tyres.simulate_blocks_input`, RK4 with exact sensitivities,
so the Jacobian is exact and one evaluation costs one pass over the run). Effects without a force law:
their block-mean form (:class:`~online_id.sim.with_effects.BlockPredictor`), the Jacobian by differences.

``intersample`` is the steering between the log's samples the simulations take (:mod:`online_id.model.intersample`:
the hold, the behaviour before issue 36, or the linear or cubic curve through the samples, exact through each
step's Γ; by default :data:`online_id.sim.BATCH_INTERSAMPLE`). The tyre model's RK4 takes the curve at its
stages (:func:`online_id.model.tyres.simulate_blocks_input`), as the filters' tyre model does.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from online_id.batchfit.guarded import NonFiniteStep, check_jacobian, check_residuals, guarded_least_squares
from online_id.effects.base import loads_with_speed
from online_id.errors import OnlineIdError
from online_id.io.tracklog import TrackRun, longitudinal_acceleration_of
from online_id.model.intersample import check_kind
from online_id.model.lateral import OUTPUT_NAMES, OUTPUT_UNITS
from online_id.sim import BATCH_INTERSAMPLE
from online_id.sim.block_means import BlockSimulator
from online_id.trust.consistency import correlation_time
from online_id.util.interrupts import interrupt_inside
from online_id.util.stages import absorb, stage
from online_id.util.threads import single_blas_thread
from online_id.vehicle.loader import Vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES

#: Block length [s] of the polish's block means: 5 ms keeps nearly all of the information of signals
#: under 5 Hz (the chirp reaches 4 Hz) and makes the 1 kHz built-in run 5x cheaper; at 100 Hz it is 1 sample.
BLOCK_S = 0.005
#: Log-scale bound of the polish around its start: ×/÷ e³ ≈ 20 (a wrong start shows as a bound hit).
LOG_BOUND = 3.0
#: Relative finite-difference step on the log-scale factors (simulation is exact to ~1e-13).
DIFF_STEP = 1e-6
#: The weights are re-estimated from the residuals (and the fit repeated) when a channel's residual
#: RMS is outside this factor of its assumed σ.
REWEIGHT_FACTOR = 1.5
#: Most lags summed in the integrated autocorrelation time.
MAX_LAG_BLOCKS = 200
#: Seconds left out at the start of a log by ``estimate``'s polish: the simulation starts at rest, a real car
#: may be turning (the model's slowest mode, roll, settles within about a second).
POLISH_BURN_IN_S = 1.0
#: Tolerances of the least squares (relative change of cost and of the parameters).
TOLERANCE = 1e-10
#: Wall time [s] after which the polish gives up and the filter's estimate stays: the polish with tyres costs
#: one RK4 pass per point, and a pass with short relaxation lengths at high speed takes many sub-steps.
MAX_WALL_S = 60.0
#: With tyres the budget is at least this many passes of the model over the run (the first one timed), so that a
#: long log is not refused for its length alone: the race car's 300-400 s at up to 61 m/s cost 2-5 s a pass on a
#: shared machine (4.5 s measured at load 7 for 400 s), and its Gauss-Newton took 19.
MAX_PASSES = 40


#: The stage name a failure inside the polish is reported under (online_id/util/stages.py).
POLISH_STAGE = "polish"

#: Failing fast (issue 26): after this many evaluations of the cost, a polish whose best point so far still misses
#: a channel (its residual RMS above FAR_FRACTION of the channel's own spread and above FAR_SIGMA of its noise σ:
#: the model explains under 75 % of a signal that stands well above the noise) and no longer gets closer
#: (below) stops: Gauss-Newton would only spend passes confirming it (an a_y column reversed in time: 26 + 11
#: evaluations to a "converged" fit 1.2× the channel's spread from the data, with σ of about 1 %).
FAR_ITERATIONS = 5
FAR_FRACTION = 0.5
FAR_SIGMA = 5.0
#: ... while its best cost fell by less than FAR_PROGRESS (relative) over the last FAR_STALL evaluations (a far start
#: still on its way down is left to go on).
FAR_STALL = 3
FAR_PROGRESS = 0.1
#: ... and a polish whose best point has had a parameter on its bound for BOUND_ITERATIONS evaluations while
#: the cost fell by less than BOUND_PROGRESS (relative) stops with the bound named (the race car's linear
#: polish reached the bound in Mxx and Kro at its 11th evaluation, then spent 21 more, 13 s, to end there).
#: (A rule on a parameter heading for its bound, far from the filter's estimate for little cost, was tried and
#: dropped: on the race car with a μ per axle the filter ends at b1 = 1.6 cm and the polish moves it ×8.7 towards a
#: car's value for 0.003 % of cost; that is a poorly informed parameter going where it belongs, not a runaway.)
BOUND_ITERATIONS = 3
BOUND_PROGRESS = 1e-3
#: Converged within the noise: a polish whose χ² (the weighted cost, in units of its reduced χ² when that is above
#: 1) fell by less than CONVERGED_CHI2 × τ over its last CONVERGED_EVALUATIONS evaluations, its last step that lowered
#: it too (a run of rejected trial steps after a large gain is not convergence), stops at its best point,
#: τ the residuals' correlation time there (the factor its covariance is inflated by). What is left to gain then
#: moves the parameters by about √0.01 = a tenth of the σ the polish reports (the usual rule of a Levenberg-Marquardt
#: fit: a χ² change far below 1 is not significant). The race car's polish with a μ per axle, its box widened to
#: take in the prior (a trial, not the polish's box), whose cost is flat in b2 and moves by 1e-6 relative from one
#: sub-step count to the next, ran 30 evaluations (30 s) at a cost flat to 6 digits before scipy's tolerances (1e-10)
#: let it go (17 with a first version of this rule, which counted evaluations alone).
CONVERGED_CHI2 = 0.01
CONVERGED_EVALUATIONS = 3
#: How close (log scale) to its bound a parameter counts as on it.
BOUND_EPS = 1e-3

#: Seconds per RK4 sub-step of the tyre model with its sensitivities (measured: 1.0 s for 60k single steps).
SUBSTEP_S = 1.7e-5


class _OutOfTime(OnlineIdError):
    """The polish's time is up: the filter's estimate stays (polish_estimate reports why)."""


class _Converged(Exception):
    """The polish's χ² no longer moves by what its σ could tell (:data:`CONVERGED_CHI2`): its best point stands."""

    def __init__(self, x: np.ndarray, evaluations: int, tau: float):
        super().__init__("converged within the noise")
        self.x, self.evaluations, self.tau = x, evaluations, tau


class PolishFailsFast(OnlineIdError):
    """The polish saw within a few evaluations that it will not end at a trustworthy minimum (a channel the model
    misses, a parameter held on its bound): the filter's estimate stays (polish_estimate reports why)."""


class _Watch:
    """Watches the cost's evaluations for the signs that a polish will not converge to a trustworthy minimum
    (:data:`FAR_ITERATIONS`, :data:`BOUND_ITERATIONS`) and raises :class:`PolishFailsFast` naming them."""

    def __init__(self, source: str, use, measured: np.ndarray, assumed: np.ndarray, free: np.ndarray,
                 unknowns: list[str], t0: float, units: dict[str, str]):
        self.source, self.use, self.free, self.unknowns, self.t0, self.units = source, use, free, unknowns, t0, units
        self.spread = measured.std(axis=0)
        self.assumed = assumed
        self.evaluations = 0
        self.best = np.inf
        self.best_rms = None
        self.best_x = None  # the unknowns at the best cost so far
        self.history: list[float] = []  # the best cost after each evaluation
        self.on_bound: list[float] = []  # the best cost at each evaluation since a parameter went onto its bound
        self.new_pass()

    def new_pass(self) -> None:
        """A least-squares pass with new weights starts: its χ² is on a scale of its own."""
        self.chi2: list[float] = []  # this pass's best weighted cost (χ²) after each evaluation
        self.best_chi2, self.best_chi2_x, self.tau, self.reduced = np.inf, None, 1.0, 1.0
        self.last_gain = np.inf  # what its last step that lowered χ² took off

    def __call__(self, x: np.ndarray, residuals: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                 weighted: np.ndarray | None = None) -> None:
        """After one evaluation at x (all unknowns) with unweighted block residuals (blocks, channels) and the
        least-squares residual vector (``weighted``: the data's weighted residuals, then the prior's)."""
        self.evaluations += 1
        if not np.all(np.isfinite(residuals)):
            return  # the guard names a non-finite cost (guarded_least_squares)
        rms = np.sqrt(np.mean(residuals ** 2, axis=0))
        cost = float(np.sum((rms / self.assumed) ** 2))
        if cost < self.best:
            self.best, self.best_rms, self.best_x = cost, rms, x.copy()
        self.history.append(self.best)
        far = (self.best_rms > FAR_FRACTION * self.spread) & (self.best_rms > FAR_SIGMA * self.assumed)
        stalled = len(self.history) > FAR_STALL and \
            self.history[-1 - FAR_STALL] - self.best < FAR_PROGRESS * self.history[-1 - FAR_STALL]
        if self.evaluations >= FAR_ITERATIONS and np.any(far) and stalled:
            missed = "; ".join(
                f"{c}: residual RMS {r:.3g} {self.units.get(c, '')} is {100 * r / s:.0f} % of the channel's own spread"
                f" {s:.3g} and {r / a:.0f}× its noise σ" for c, r, s, a, f in
                zip(self.use, self.best_rms, self.spread, self.assumed, far) if f)
            raise PolishFailsFast(
                f"{self.source}: the polish stopped after {self.evaluations} evaluations ({self._spent()}): the model"
                f" misses {', '.join(c for c, f in zip(self.use, far) if f)} and no longer gets closer ({missed}):"
                " a wrong or broken channel, or a car the model does not describe (run 'online-id diagnose');"
                " kept the filter's estimate")
        bound = self.free & _on_bound(self.best_x, lower, upper)
        if not np.any(bound):
            self.on_bound = []
        else:
            self.on_bound.append(self.best)
            if len(self.on_bound) > BOUND_ITERATIONS and \
                    self.on_bound[-1 - BOUND_ITERATIONS] - self.best < BOUND_PROGRESS * self.best:
                names = ", ".join(n for n, b in zip(self.unknowns, bound) if b)
                raise PolishFailsFast(
                    f"the polish ran to its bound in {names} (×/÷ {np.exp(LOG_BOUND):.0f} of the filter's estimate;"
                    f" stopped after {self.evaluations} evaluations, {self._spent()}, the cost no longer falling):"
                    " kept the filter's estimate")
        if weighted is not None:  # (after the rules that fail fast: they name why, this one only ends early)
            self._converged(x, residuals, weighted)

    def _converged(self, x: np.ndarray, residuals: np.ndarray, weighted: np.ndarray) -> None:
        """Raise :class:`_Converged` when this pass's χ² no longer falls by what its σ could tell: over its last
        evaluations, and at its last step that lowered it (a run of trial steps the solver rejects right after a
        large gain says nothing of how far the minimum is)."""
        chi2 = float(weighted @ weighted)
        if chi2 < self.best_chi2:
            if np.isfinite(self.best_chi2):
                self.last_gain = self.best_chi2 - chi2
            data = weighted[:residuals.size]
            self.best_chi2, self.best_chi2_x = chi2, x.copy()
            self.reduced = max(1.0, float(data @ data) / data.size)
            self.tau = max(1.0, max(correlation_time(residuals[:, i], MAX_LAG_BLOCKS)
                                    for i in range(residuals.shape[1])))
        self.chi2.append(self.best_chi2)
        enough = CONVERGED_CHI2 * self.tau * self.reduced
        if len(self.chi2) > CONVERGED_EVALUATIONS and self.last_gain < enough and \
                self.chi2[-1 - CONVERGED_EVALUATIONS] - self.best_chi2 < enough:
            raise _Converged(self.best_chi2_x, self.evaluations, self.tau)

    def _spent(self) -> str:
        return f"{time.perf_counter() - self.t0:.2g} s"


@dataclass
class _ConvergedResult:
    """What :func:`scipy.optimize.least_squares` returns, for a pass stopped by :class:`_Converged`."""

    x: np.ndarray
    nfev: int
    tau: float
    success: bool = True

    @property
    def message(self) -> str:
        return (f"converged within the noise: χ² fell by less than {CONVERGED_CHI2:g} × τ ({self.tau:.3g}) over the"
                f" last {CONVERGED_EVALUATIONS} evaluations and at its last step")


def _on_bound(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Which unknowns of x are on their bound: the 8 within :data:`BOUND_EPS` (log scale) of ±LOG_BOUND, an
    effect's parameter within 1e-3 of its range (what the watch stops on, and what PolishResult.at_bound names)."""
    eps = np.where(np.arange(len(x)) < 8, BOUND_EPS, 1e-3 * (upper - lower))
    return np.minimum(x - lower, upper - x) < eps


@dataclass
class PolishResult:
    """The polished estimate with its covariance (SI units) and what was seen of the residuals."""

    theta: np.ndarray  # (8,) SI
    start: np.ndarray  # (8,) the estimate it started from
    covariance: np.ndarray  # (8, 8) SI
    relative_std: np.ndarray  # (8,) log-scale σ ≈ relative σ
    residual_std: dict[str, float]  # RMS residual per channel [SI]
    assumed_std: dict[str, float]  # the σ_c the weights started from [SI]
    correlation_time: dict[str, float]  # τ_c per channel (1 = white)
    inflation: float  # the factor applied to the Gauss-Newton covariance
    iterations: int
    success: bool
    message: str
    wall_s: float
    block: int
    channels: tuple[str, ...]
    at_bound: list[str] = field(default_factory=list)
    #: polished effect parameters {label: {parameter: {"value", "std", "unit"}}} (with ``effects``)
    effects: dict = field(default_factory=dict)
    intersample: str = "hold"  # the steering between samples the model took
    #: parameters that started at the prior, not at the filter's estimate, which did not inform them
    #: (:func:`polish_start`)
    started_at_prior: list[str] = field(default_factory=list)

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0, None))

    def to_json_dict(self) -> dict:
        def num(x):
            return float(x) if np.isfinite(x) else None

        return {
            "parameters": {n: {"value": float(v), "std": num(s)}
                           for n, v, s in zip(PARAMETER_NAMES, self.theta, self.std)},
            "relative_std": {n: num(s) for n, s in zip(PARAMETER_NAMES, self.relative_std)},
            "start": {n: float(v) for n, v in zip(PARAMETER_NAMES, self.start)},
            "covariance": [[num(c) for c in row] for row in self.covariance],
            "residual_std": self.residual_std,
            "assumed_std": self.assumed_std,
            "correlation_time": self.correlation_time,
            "covariance_inflation": self.inflation,
            "iterations": self.iterations,
            "success": self.success,
            "message": self.message,
            "wall_s": round(self.wall_s, 4),
            "block_samples": self.block,
            "channels": list(self.channels),
            "at_bound": self.at_bound,
            "intersample": self.intersample,
            "started_at_prior": list(self.started_at_prior),
            **({"effects": self.effects} if self.effects else {}),
        }


class TyreOutputs:
    """Block means of the model with the saturating tyre law (an effect with :meth:`~online_id.effects.base.Effect.
    tyre_mu`: one μ for both axles, or one per axle) and their exact derivatives, one pass per point (the filters'
    model; the last point's pass is kept, as least squares asks for the residuals and then the Jacobian at the
    same point). The polish's model with tyres, and the diagnosis's Jacobian of a tyre law's fit
    (:func:`online_id.diagnosis.fitting.fit_family`). The law's parameters beyond its μ's (a load exponent, a
    downforce share: :attr:`~online_id.effects.base.Effect.held_online`) get no column here (zero): the polish holds
    them, the diagnosis differences them; when they move, the axle loads are formed anew. Sensor effects beside the
    tyres (an offset, a misaligned velocity sensor: :func:`senses_with_tyres`) act on the block means through their
    block-mean form, their derivatives chained through it (differences of that cheap map, no pass of the model)."""

    def __init__(self, vehicle: Vehicle, run: TrackRun, dt: float, q: int, n_blocks: int, deadline: float,
                 budget: float, effects, intersample: str = "hold"):
        from online_id.effects.base import BlockContext
        from online_id.model import pieces, tyres
        from online_id.sim.block_means import step_inputs

        effects = list(effects)
        effect = next(e for e in effects if e.tyre_mu() is not None)
        ends = np.cumsum([0] + [len(e.fit_parameters()) for e in effects])
        parts = [slice(int(a), int(b)) for a, b in zip(ends[:-1], ends[1:])]
        self.tyre_part = parts[effects.index(effect)]
        # a steering offset beside the tyres (an input effect that only shifts the road-wheel angle): the tyre model
        # takes the shift, its derivative one more sensitivity column (:func:`steering_gains`)
        others = [(e, part, steering_gains(e, vehicle.known)) for e, part in zip(effects, parts) if e is not effect]
        self.steers = [(e, part, g) for e, part, g in others if g is not None]
        self.sensors = [(e, part) for e, part, g in others if g is None]
        self.n_values = int(ends[-1])
        self.tyres, self.deadline, self.effect = tyres, deadline, effect
        self.pieces = pieces  # (a long run in two pieces, one on each core: online_id/model/pieces.py)
        # its fit parameters are its μ's (Effect.tyre_mu), then any the filters carry as constants (Effect.held_online:
        # load_sensitivity's exponent), which the polish holds too
        self.mu_columns = len(effect.fit_parameters()) - len(effect.held_online)
        self.held = [self.tyre_part.start + i for i in range(self.mu_columns, len(effect.fit_parameters()))]
        self.source, self.budget = run.source, budget
        n = n_blocks * q
        # each step driven by its input polynomial (the hold's: [δ, 0, 0, 0] at the sample's own speed)
        w, V = step_inputs(intersample, run.steering_wheel_angle / vehicle.known.steering_ratio,
                           np.asarray(run.speed, dtype=float), dt)
        self.args = (np.ascontiguousarray(w[:n]), np.ascontiguousarray(V[:n]), float(dt))
        self.known, self.n = vehicle.known, n
        self.longitudinal_acceleration = longitudinal_acceleration_of(run)[0] if effect.moves_loads else None
        self.speed = np.asarray(run.speed, dtype=float)
        self.Fz = self._loads(effect)  # (static, or each sample's), formed anew when a held parameter moves (below)
        self._held_values = effect.vector()[self.mu_columns:].tobytes()
        self.kn, self.q = tyres.known_array(vehicle.known), q
        speed = self.speed[:n].reshape(n_blocks, q).mean(axis=1)
        self.context = BlockContext(time=(np.arange(n_blocks) + 0.5) * q * dt, block_dt=q * dt,
                                    unit_steering_response=_no_unit_response, speed=speed)
        self._last = (None, None)

    def __call__(self, theta: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Block means (n_blocks, 5) and their derivatives (n_blocks, 5, 8 + k) at θ (8,) and the effects' k
        parameters (in the effects' order: the tyre's μ's, one or front and rear, and any sensor effect's)."""
        values = np.asarray(values, dtype=float)
        key = (theta.tobytes(), values.tobytes())
        if self._last[0] != key:
            d, V, dt = self.args
            if np.isfinite(self.deadline):  # (the diagnosis's Jacobian has none)
                self._check_cost(theta, V, dt)
            tyre = self.effect.with_vector(values[self.tyre_part])
            held = values[self.tyre_part][self.mu_columns:].tobytes()
            if held != self._held_values:  # a load exponent or a downforce share moved (a diagnosis's fit of them)
                self.Fz, self._held_values = self._loads(tyre), held
            mu_axles = np.maximum(tyre.tyre_mu(), self.tyres.MU_FLOOR)
            shift = float(sum(g @ values[part] for _, part, g in self.steers))
            Y, dY = self.pieces.blocks(theta, mu_axles, self.Fz, d, V, dt, self.kn, self.q, self.mu_columns, shift,
                                       bool(self.steers))
            # every column in the effects' order: θ, then each effect's parameters (the held ones and the sensors'
            # zero here; the sensors' through their map below)
            full = np.zeros(dY.shape[:2] + (8 + self.n_values,))
            full[..., :8] = dY[..., :8]
            mus = slice(8 + self.tyre_part.start, 8 + self.tyre_part.start + self.mu_columns)
            full[..., mus] = dY[..., 8:8 + self.mu_columns]
            for _, part, g in self.steers:  # ∂/∂e = ∂/∂shift · g
                full[..., 8 + part.start:8 + part.stop] = dY[..., -1:] * g
            dY = full
            if self.sensors:
                Y, dY = self._sensed(Y, dY, values)
            self._last = (key, (Y, dY))
        return self._last[1]

    def _loads(self, tyre) -> np.ndarray:
        """The axle loads each sample (n, ·) [N] under the tyre law ``tyre`` (its held parameters' values)."""
        loads = loads_with_speed(tyre.axle_loads)(self.known, self.longitudinal_acceleration, self.speed)
        return self.tyres.per_sample_loads(loads[:self.n] if loads.ndim == 2 else loads, self.n)

    def _sensed(self, Y, dY, values):
        """The tyre model's block means and derivatives (columns θ, then every effect's parameters in order, the
        sensors' zero) through the sensor effects at ``values``: the logged channels' block means and their
        derivatives (the same columns, the sensors' filled)."""
        def sensed(Z, at=values):
            for e, part in self.sensors:
                Z = e.with_vector(at[part]).block_means(Z, self.context)
            return Z

        out = sensed(Y)
        dOut = np.zeros(Y.shape + (8 + len(values),))
        scale = max(float(np.max(np.abs(Y))), 1.0)
        sensor_columns = {8 + i for _, part in self.sensors for i in range(part.start, part.stop)}
        model_columns = [c for c in range(8 + len(values)) if c not in sensor_columns]
        for column in model_columns:  # through the sensors' map, by a difference along the column
            size = float(np.max(np.abs(dY[..., column])))
            if size == 0.0:
                continue
            h = 1e-6 * scale / size
            dOut[..., column] = (sensed(Y + h * dY[..., column]) - out) / h
        for _, part in self.sensors:  # the sensors' own parameters: differences of the map alone
            for i in range(part.start, part.stop):
                h = 1e-6 * max(1.0, abs(values[i]))
                moved = values.copy()
                moved[i] += h
                dOut[..., 8 + i] = (sensed(Y, moved) - out) / h
        return out, dOut

    def _check_cost(self, theta, V, dt) -> None:
        """Refuse a pass that cannot end before the deadline: short relaxation lengths at speed and stiff
        parameter sets take many RK4 sub-steps (:func:`online_id.model.tyres.substeps`)."""
        b = max(min(theta[PARAMETER_NAMES.index("b1")], theta[PARAMETER_NAMES.index("b2")]), self.tyres.B_FLOOR)
        steps = self.tyres.total_substeps(theta, V, dt, self.kn)
        left = self.deadline - time.perf_counter()
        if steps * SUBSTEP_S > left:
            raise _OutOfTime(f"{self.source}: the polish would run past its {self.budget:.2g} s: one pass of the tyre"
                             f" model takes about {steps * SUBSTEP_S:.2g} s ({steps / len(V):.0f} RK4 sub-steps a"
                             f" sample; shortest relaxation length {1e3 * b:.3g} mm, speed up to"
                             f" {np.max(np.abs(V)):.0f}"
                             f" m/s, {max(left, 0):.0f} s left); kept the filter's estimate")


def steering_gains(effect, known):
    """The road-wheel angle's shift per unit of each of ``effect``'s parameters (k,) when it is an input effect that
    only shifts the steering (a steering-wheel offset: its filter form's ``steering`` gains, nothing else), else
    None: the polish's tyre model takes it beside the tyres."""
    if effect.stage != "input" or effect.tyre_mu() is not None:
        return None
    try:
        states = effect.filter_states(known)
    except OnlineIdError:
        return None
    if len(states) != len(effect.fit_parameters()) or any(
            st.lags or st.tyre_axles or st.output_state is not None or any(st.output) or st.steering == 0.0
            for st in states):
        return None
    return np.array([st.steering for st in states], dtype=float)


def senses_with_tyres(effect) -> bool:
    """Whether the polish's tyre model takes ``effect`` beside it: a sensor effect whose block-mean form holds on
    the polish's blocks (not a delay, which needs every sample's outputs) and needs no unit-steering response."""
    return effect.stage == "sensor" and not effect.short_blocks_only and effect.tyre_mu() is None


def _not_beside_tyres(effects, known) -> list:
    """The effects :class:`TyreOutputs` cannot take beside the first saturating tyre law of ``effects``: all but
    sensor effects it takes (:func:`senses_with_tyres`) and steering offsets (:func:`steering_gains`)."""
    tyre = next((e for e in effects if e.tyre_mu() is not None), None)
    return [e for e in effects if e is not tyre and not senses_with_tyres(e) and steering_gains(e, known) is None]


def beside_tyres(effects, known) -> bool:
    """Whether :class:`TyreOutputs` models ``effects``: one saturating tyre law, every other effect a sensor effect
    it takes (:func:`senses_with_tyres`) or a steering offset (:func:`steering_gains`)."""
    return any(e.tyre_mu() is not None for e in effects) and not _not_beside_tyres(effects, known)


def _no_unit_response():
    raise OnlineIdError("no unit-steering response beside the saturating tyres (an input effect)")


def _effect_model(effects, vehicle: Vehicle, run: TrackRun, dt: float, q: int, n_blocks: int, deadline: float,
                  budget: float, intersample: str = "hold"):
    """How the polish simulates the model with ``effects``: ("tyres", TyreOutputs) for the saturating tyre
    law (tire_saturation, tire_saturation_axles, ...) alone or with sensor effects (:func:`senses_with_tyres`),
    ("blocks", BlockPredictor) for effects without a force law; an OnlineIdError otherwise."""
    from online_id.sim.with_effects import BlockPredictor

    tyre = [e for e in effects if e.tyre_mu() is not None]
    if tyre:
        others = _not_beside_tyres(effects, vehicle.known)
        if others:
            raise OnlineIdError(f"the polish models {tyre[0].label} with sensor effects and steering offsets only,"
                                " not with " + ", ".join(e.label for e in others))
        return "tyres", TyreOutputs(vehicle, run, dt, q, n_blocks, deadline, budget, effects, intersample)
    theta = vehicle.prior.to_vector()
    if any(e.force_law(theta, vehicle.known) is not None for e in effects):
        raise OnlineIdError("the polish has no fast form for " + ", ".join(e.label for e in effects))
    return "blocks", BlockPredictor(vehicle.known, run.steering_wheel_angle, run.speed, dt, q, intersample=intersample,
                                    longitudinal_acceleration=longitudinal_acceleration_of(run)[0])


@single_blas_thread
def polish(vehicle: Vehicle, run: TrackRun, start, noise_std: dict[str, float],
           channels: tuple[str, ...] | None = None, burn_in_s: float = 0.0,
           max_iterations: int = 50, prior=None, prior_log_std=None, effects=(),
           max_wall_s: float | None = None, fixed: dict[str, float] | None = None,
           progress: bool = False, intersample: str = BATCH_INTERSAMPLE) -> PolishResult:
    """The output-error ML estimate of the 8 parameters on ``run``, from ``start`` (8,) SI.

    ``noise_std`` gives each channel's assumed sensor σ [SI] (a filter's measurement σ); the channels
    used are those in ``channels`` (default: all of :data:`OUTPUT_NAMES` the run has and
    ``noise_std`` names). ``burn_in_s`` leaves out the start (the simulation starts at rest).
    ``effects`` (instances, starting at their values) are polished with the 8 (module docstring).
    ``fixed`` names parameters held at their ``start`` values (σ 0), as the filter held them.
    Past ``max_wall_s`` of work (default :data:`MAX_WALL_S`, with tyres at least :data:`MAX_PASSES` passes as long as
    the first) it stops with an OnlineIdError saying so.
    ``progress`` shows a tqdm bar on stderr (passes of the model over the run), as the filter does.
    ``intersample``: the steering between samples (module docstring).
    """
    t0 = time.perf_counter()
    check_kind(intersample)
    bar = _progress_bar(progress, MAX_WALL_S if max_wall_s is None else max_wall_s)
    try:
        return _polish(vehicle, run, start, noise_std, channels, burn_in_s, max_iterations, prior, prior_log_std,
                       effects, max_wall_s, fixed, t0, bar, intersample)
    finally:
        if bar is not None:
            bar.close()


def _progress_bar(progress: bool, max_wall_s: float):
    """A tqdm bar for the polish (None without ``progress``): one tick per pass of the model over the run."""
    if not progress:
        return None
    from tqdm import tqdm

    return tqdm(unit="pass", desc=f"polish (at most {max_wall_s:g} s)", mininterval=0.5, leave=False)


def _polish(vehicle, run, start, noise_std, channels, burn_in_s, max_iterations, prior, prior_log_std, effects,
            max_wall_s, fixed, t0, bar, intersample="hold") -> PolishResult:
    """:func:`polish`'s work (``bar``: a progress bar or None)."""
    start = np.asarray(start, dtype=float)
    use = tuple(c for c in OUTPUT_NAMES if getattr(run, c, None) is not None and c in noise_std
                and (channels is None or c in channels))
    if not use:
        raise OnlineIdError(f"{run.source}: no measured channel with a known noise to polish against")
    dts = np.diff(run.time)
    dt = float(np.median(dts))
    if np.any(np.abs(dts - dt) > 0.01 * dt):
        raise OnlineIdError(f"{run.source}: the polish needs evenly sampled data (steps from {dts.min() * 1e3:.3g}"
                            f" to {dts.max() * 1e3:.3g} ms)")
    if np.any(np.abs(run.speed) < 1.0):
        raise OnlineIdError(f"{run.source}: the polish needs the car moving (speed under 1 m/s found)")
    q = max(1, int(round(BLOCK_S / dt)))
    if len(run.time) // q - int(np.ceil(burn_in_s / (dt * q))) < 10 * len(PARAMETER_NAMES):
        raise OnlineIdError(f"{run.source}: too short for the polish ({len(run.time)} samples)")
    sim = BlockSimulator(vehicle.known, run.steering_wheel_angle, run.speed, dt, block=q, intersample=intersample)
    cols = [OUTPUT_NAMES.index(c) for c in use]
    first = int(np.ceil(burn_in_s / (dt * q)))
    measured = np.column_stack([getattr(run, c)[: sim.n_used] for c in use]).reshape(-1, q, len(use)).mean(axis=1)
    measured = measured[first:]
    assumed = np.array([noise_std[c] for c in use], dtype=float)
    if np.any(assumed <= 0) or len(measured) < 10 * len(PARAMETER_NAMES):
        raise OnlineIdError(f"{run.source}: too short for the polish, or a channel's noise σ is not positive")

    effects = list(effects)
    params = [(e, p) for e in effects for p in e.fit_parameters()]
    k = len(params)
    scales = np.array([p.scale for _, p in params])
    start_e = np.array([e.values[p.name] / p.scale for e, p in params])
    budget = MAX_WALL_S if max_wall_s is None else max_wall_s
    kind, model = (_effect_model(effects, vehicle, run, dt, q, sim.n_blocks, t0 + budget, budget, intersample)
                   if effects else ("linear", None))
    deadline = t0 + budget

    def effects_at(x) -> list:
        out, i = [], 0
        for e in effects:
            m = len(e.fit_parameters())
            out.append(e.with_vector(np.asarray(x[8 + i:8 + i + m]) * scales[i:i + m]))
            i += m
        return out

    def outputs(S):
        """Block means of the used channels for rows S (P, 8 + k) (log-scale factors, then the effects'
        parameters in units of their scale) → (P, blocks, channels)."""
        S = np.atleast_2d(S)
        if bar is not None:
            bar.update(len(S))
        with np.errstate(all="ignore"):
            if kind == "linear":
                return sim.block_means(start * np.exp(S[:, :8]))[:, first:, :][..., cols]
            if kind == "tyres":
                return np.stack([model(start * np.exp(x[:8]), x[8:] * scales)[0][first:, cols] for x in S])
            return np.stack([model.outputs(start * np.exp(x[:8]), effects_at(x))[first:, cols] for x in S])

    def derivative(x) -> np.ndarray:
        """∂(block means)/∂x (blocks, channels, 8 + k): exact with tyres, else forward differences."""
        if kind == "tyres":
            dY = model(start * np.exp(x[:8]), x[8:] * scales)[1][first:][:, cols, :]
            return np.concatenate([dY[..., :8], dY[..., 8:] * scales], axis=-1)
        h = DIFF_STEP * np.maximum(1.0, np.abs(x))
        h = np.where(x + h > upper, -h, h)
        Y = outputs(np.vstack([x, x + np.diag(h)]))
        return np.moveaxis((Y[1:] - Y[0]) / h[:, None, None], 0, -1)

    if prior is not None:  # on the 8 only: the effects' parameters start where the filter left them
        prior_s = np.concatenate([np.log(np.asarray(prior, dtype=float) / start), start_e])
        with np.errstate(divide="ignore"):  # a fixed parameter's σ 0: no penalty (below), it does not move
            prior_w = np.concatenate([1.0 / np.asarray(prior_log_std, dtype=float), np.zeros(k)])
    else:
        prior_s, prior_w = np.concatenate([np.zeros(8), start_e]), np.zeros(8 + k)
    sigma = assumed.copy()
    unknowns = [*PARAMETER_NAMES, *(f"{e.label} {p.name}" for e, p in params)]
    what = f"{run.source}: the polish"
    lower = np.concatenate([np.full(8, -LOG_BOUND), [p.lower / p.scale for _, p in params]])
    upper = np.concatenate([np.full(8, LOG_BOUND), [p.upper / p.scale for _, p in params]])
    s = np.concatenate([np.zeros(8), np.clip(start_e, lower[8:] + 1e-9, upper[8:] - 1e-9)])
    free = np.concatenate([[n not in (fixed or {}) for n in PARAMETER_NAMES], np.ones(k, bool)])
    if kind == "tyres":  # a tyre law's parameters beyond its μ's (load_sensitivity's exponent) stay where they are
        free[[8 + i for i in model.held]] = False
    prior_w = np.where(free, prior_w, 0.0)

    def with_free(xr):
        x = s.copy()
        x[free] = xr
        return x

    if kind == "tyres" and max_wall_s is None:  # the budget: at least MAX_PASSES passes like the first (kept)
        pass_start = time.perf_counter()
        model(start * np.exp(s[:8]), s[8:] * scales)
        budget = max(budget, pass_start - t0 + MAX_PASSES * (time.perf_counter() - pass_start))
        deadline = model.deadline = t0 + budget
        model.budget = budget
    iterations = 0
    res = None
    watch = _Watch(run.source, use, measured, assumed, free, unknowns, t0, dict(zip(OUTPUT_NAMES, OUTPUT_UNITS)))
    for _ in range(2):  # the second pass only when the residuals disagree with the assumed noise
        weight = np.sqrt(q) / sigma
        watch.new_pass()
        before = watch.evaluations

        def fun(x, weight=weight):
            if time.perf_counter() > deadline:
                raise _OutOfTime(f"{run.source}: the polish ran past {budget:.3g} s without converging;"
                                 " kept the filter's estimate")
            with np.errstate(over="ignore", invalid="ignore"):  # an overflow is caught by the guard, with a reason
                e = outputs(x)[0] - measured
                r = (e * weight).ravel()
            out = np.concatenate([np.where(np.isfinite(r), r, 1e6), (x - prior_s) * prior_w])
            watch(x, e, lower, upper, out)
            return out

        def jac(x, weight=weight):
            if kind == "linear":
                h = DIFF_STEP * np.maximum(1.0, np.abs(x))
                h = np.where(x + h > upper, -h, h)
                Y = outputs(np.vstack([x, x + np.diag(h)]))
                J = ((Y[1:] - Y[0]) * weight).reshape(8, -1).T / h
            else:
                J = (derivative(x) * weight[:, None]).reshape(-1, 8 + k)
            return np.vstack([np.where(np.isfinite(J), J, 0.0), np.diag(prior_w)])

        try:
            res = guarded_least_squares(lambda xr, f=fun: f(with_free(xr)), s[free],
                                        jac=lambda xr, j=jac: j(with_free(xr))[:, free],
                                        bounds=(lower[free], upper[free]), method="trf", x_scale="jac",
                                        xtol=TOLERANCE, ftol=TOLERANCE, gtol=TOLERANCE, max_nfev=max_iterations,
                                        what=what, names=[u for u, f in zip(unknowns, free) if f],
                                        start="at its start (the filter's estimate)" if iterations == 0 else
                                        "after its first pass")
        except NonFiniteStep as exc:
            unstable = _unstable_mode(start * np.exp(s[:8]), run.speed, vehicle.known)
            raise NonFiniteStep(f"{exc}{unstable}; kept the filter's estimate") from None
        except _Converged as done:
            res = _ConvergedResult(done.x[free], done.evaluations - before, done.tau)
        s = with_free(res.x)
        iterations += int(res.nfev)
        if isinstance(res, _ConvergedResult) and np.any(free & _on_bound(s, lower, upper)):
            break  # converged on a bound: a pass with new weights would not take it off (PolishResult.at_bound)
        rms = np.sqrt(np.mean(((outputs(s)[0] - measured) * np.sqrt(q)) ** 2, axis=0))  # per-sample σ̂
        if np.all((rms < REWEIGHT_FACTOR * sigma) & (rms > sigma / REWEIGHT_FACTOR)):
            break
        sigma = np.where(rms > 0, rms, sigma)

    e = outputs(s)[0] - measured
    try:  # the covariance's numbers, guarded as the steps' were
        check_residuals(e.ravel(), what, "at its end")
        rms = np.sqrt(np.mean(e ** 2, axis=0) * q)
        weight = np.sqrt(q) / np.maximum(sigma, rms)  # the larger of assumed and seen noise
        J = jac(s, weight=weight)[:, free]
        check_jacobian(J, what, [u for u, f in zip(unknowns, free) if f])
        with np.errstate(over="ignore", invalid="ignore"):
            info = J.T @ J
        if not np.all(np.isfinite(info)):
            raise NonFiniteStep(f"{what} stopped: the information matrix JᵀJ at its end overflows")
    except NonFiniteStep as exc:
        raise NonFiniteStep(f"{exc}; kept the filter's estimate") from None
    tau = np.array([correlation_time(e[:, i], MAX_LAG_BLOCKS) for i in range(len(use))])
    inflation = float(max(1.0, tau.max()))
    cov_s = np.zeros((8 + k, 8 + k))
    cov_s[np.ix_(free, free)] = _inverse(info) * inflation
    theta = start * np.exp(s[:8])
    at_bound = [n for n, b in zip(unknowns, free & _on_bound(s, lower, upper)) if b]
    std_s = np.sqrt(np.clip(np.diag(cov_s), 0, None))
    polished_effects: dict = {}
    for (e, p), v, sd, sc in zip(params, s[8:], std_s[8:], scales):
        polished_effects.setdefault(e.label, {})[p.name] = {"value": float(v * sc), "std": float(sd * sc),
                                                            "unit": p.unit}
    return PolishResult(
        theta=theta, start=start, covariance=cov_s[:8, :8] * np.outer(theta, theta),
        relative_std=std_s[:8], effects=polished_effects,
        residual_std={c: float(v) for c, v in zip(use, rms)}, assumed_std={c: float(v) for c, v in zip(use, assumed)},
        correlation_time={c: float(v) for c, v in zip(use, tau)}, inflation=inflation, iterations=iterations,
        success=bool(res.success), message=str(res.message), wall_s=time.perf_counter() - t0, block=q,
        channels=use, at_bound=at_bound, intersample=intersample)


def _unstable_mode(theta: np.ndarray, speed: np.ndarray, known) -> str:
    """": the model is unstable there at V m/s (a mode growing at +λ /s)" when the model at theta is unstable
    at the run's highest speed (where a linear car loses stability first), else ""."""
    from online_id.model.lateral import continuous_matrices

    V = float(np.max(np.abs(speed)))
    try:
        growth = float(np.max(np.linalg.eigvals(continuous_matrices(theta, V, known)[0]).real))
    except (np.linalg.LinAlgError, ValueError):
        return ""
    return f": the model is unstable there at {V:.3g} m/s (a mode growing at {growth:+.3g} /s)" \
        if growth > 0 else ""



def _inverse(info: np.ndarray) -> np.ndarray:
    from online_id.trust.identifiability import (
        information_covariance,  # infinite σ along directions the data do not inform
    )

    return information_covariance(info)


def polish_estimate(result, vehicle: Vehicle, run: TrackRun, noise_std: dict[str, float],
                    burn_in_s: float = 0.0, prior_log_std_floor: float = 0.0, effects=(),
                    progress: bool = False, intersample: str = BATCH_INTERSAMPLE) -> str | None:
    """Polish an :class:`~online_id.estimation.EstimationResult` of ``run`` in place (see
    :func:`_polish_estimate`); ``result.wall_s`` becomes the filter's and the polish's wall time together
    (the filter's alone stays in ``result.wall_s_filter``), whether the polish succeeds or not.
    ``progress``: a bar on stderr while it works; ``intersample``: the steering between samples (the filter's,
    :attr:`~online_id.filters.FilterConfig.intersample`)."""
    t0 = time.perf_counter()
    if result.wall_s_filter is None:
        result.wall_s_filter = result.wall_s
    try:
        return _polish_estimate(result, vehicle, run, noise_std, burn_in_s, prior_log_std_floor, effects, progress,
                                intersample)
    finally:
        spent = time.perf_counter() - t0
        result.wall_s = result.wall_s_filter + spent
        if isinstance(result.polish, dict):
            result.polish.setdefault("wall_s", spent)


def polish_start(result) -> tuple[np.ndarray, list[str]]:
    """Where the polish of a filter's ``result`` starts: the filter's estimate, but the prior's value for each
    parameter the filter did not inform (:attr:`~online_id.estimation.EstimationResult.informed`, not fixed), and
    the names of those. A parameter the run does not inform wanders in the filter's random walk: its value there
    carries no information, and it may have wandered where the model is stiff and the polish slow, or outside the
    polish's box (×/÷ 20 of its start, :data:`LOG_BOUND`) around the answer. On the race log the filter's b1 was 4.3 mm
    against a car's 0.3-0.6 m: from it the polish ran to its bound and was discarded after 8.6 s; from the prior
    it converged in 13 evaluations (b1 0.51 m, and the 8 and μ per axle of the diagnosis's batch fit)."""
    start = result.parameters.to_vector().copy()
    prior = result.prior.to_vector()
    informed = result.informed
    from_prior = [n for n in PARAMETER_NAMES if not informed.get(n, True) and n not in result.fixed]
    for n in from_prior:
        start[PARAMETER_NAMES.index(n)] = prior[PARAMETER_NAMES.index(n)]
    return start, from_prior


def _polish_estimate(result, vehicle: Vehicle, run: TrackRun, noise_std: dict[str, float],
                     burn_in_s: float = 0.0, prior_log_std_floor: float = 0.0, effects=(),
                     progress: bool = False, intersample: str = "hold") -> str | None:
    """Polish an :class:`~online_id.estimation.EstimationResult` of ``run`` in place.

    On success ``result.parameters``, ``std``, ``relative_std`` and ``covariance`` become the polished
    estimate's, the filter's own go to ``result.online`` and the polish's details to ``result.polish``.
    When the polish cannot run or cannot be trusted (uneven samples, a bound hit, no convergence) the
    filter's estimate stays and the reason is returned (and kept in ``result.polish["error"]``). So does any
    other failure inside the polish: its reason names it, ``result.polish["internal_error"]`` holds it, and
    it is recorded for the crash report (:func:`online_id.util.stages.absorb`).
    The filter's prior enters as in the filter, its log-scale σ widened to ``prior_log_std_floor``; the
    parameters it held fixed (``result.fixed``) stay fixed.
    ``effects`` (those the filter estimated) are polished from the filter's values of them; their polished
    values replace the filter's in ``result.extra_states`` (the filter's stay in ``result.online``).
    """
    prior_log_std = np.maximum(np.asarray(result.prior_relative_std, dtype=float), prior_log_std_floor)
    from online_id.vehicle.parameters import Parameters

    online = {"parameters": {n: {"value": float(v), "std": float(s)} for n, v, s in
                             zip(PARAMETER_NAMES, result.parameters.to_vector(), result.std)},
              "relative_std": {n: float(s) for n, s in zip(PARAMETER_NAMES, result.relative_std)}}
    # each effect parameter where the filter reports it: (group, key, parameter) of its extra state
    where = {e.label: [(st.group, st.key, st.parameter) for st in e.filter_states(vehicle.known)] for e in effects}
    extra = result.extra_states

    def filtered(e, i, default):
        if i >= len(where[e.label]):  # a parameter the filters carry as a constant (load_sensitivity's exponent)
            return default
        group, key, name = where[e.label][i]
        entry = extra.get(group, {}).get(key, {})
        return (entry if group == "offsets" else entry.get(name, {})).get("value", default)

    effects = [e.with_vector([filtered(e, i, e.values[p.name]) for i, p in enumerate(e.fit_parameters())])
               for e in effects]
    online.update({g: extra[g] for g in ("offsets", "effects") if g in extra})
    try:
        with stage(POLISH_STAGE):
            start, from_prior = polish_start(result)
            p = polish(vehicle, run, start, noise_std,
                       channels=tuple(result.channels) or None, burn_in_s=burn_in_s, prior=result.prior.to_vector(),
                       prior_log_std=prior_log_std, effects=effects, fixed=result.fixed, progress=progress,
                       intersample=intersample)
            p.started_at_prior = from_prior
    except OnlineIdError as exc:
        result.polish = {"error": str(exc)}
        return str(exc)
    except (KeyboardInterrupt, Exception) as exc:  # the filter's estimate is kept whatever happens in the polish
        if interrupt_inside(exc) is not None:  # the run reports the interrupt
            result.interrupted = True
            result.polish = {"error": "interrupted"}
            return "the polish was interrupted: kept the filter's estimate"
        line = absorb(exc, POLISH_STAGE)  # not an input the polish knows: a bug, reported with a crash file
        reason = f"the polish failed ({line}): kept the filter's estimate"
        result.polish = {"error": reason, "internal_error": line}
        return reason
    reason = None
    if p.at_bound:
        of = ("the filter's estimate" if not from_prior else
              f"its start: the prior for {', '.join(from_prior)}, else the filter's estimate")
        reason = (f"the polish ran to its bound in {', '.join(p.at_bound)} (×/÷ {np.exp(LOG_BOUND):.0f} of {of};"
                  f" ended there after {p.iterations} evaluations, {p.wall_s:.2g} s): kept the filter's estimate")
    elif not p.success:
        reason = f"the polish did not converge ({p.message}): kept the filter's estimate"
    if reason:
        result.polish = dict(p.to_json_dict(), error=reason)
        return reason
    result.online = online
    result.polish = p.to_json_dict()
    result.parameters = Parameters.from_vector(p.theta)
    result.std = p.std
    result.relative_std = p.relative_std
    result.covariance = p.covariance
    if p.effects:  # the polished values where the filter's were
        new = {g: {k: dict(v) for k, v in extra[g].items()} for g in extra}
        for e in effects:
            for (group, key, name), fp in zip(where[e.label], e.fit_parameters()):
                value = {k: v for k, v in p.effects[e.label][fp.name].items() if k != "unit"}  # the filter's unit stays
                if group == "offsets":
                    new.setdefault(group, {})[key] = {"unit": fp.unit, **new.get(group, {}).get(key, {}), **value}
                else:
                    slot = new.setdefault(group, {}).setdefault(key, {})
                    slot[name] = {"unit": fp.unit, **slot.get(name, {}), **value}
        result.extra_states = new
    return None
