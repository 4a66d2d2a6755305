"""The batch fit: hybrid GA for the global search, least-squares polish of each minimum it found.

Steps, in log-scale space s = ln(θ/θ_prior) within bounds (default 0.2× to 5× the prior):

1. the hybrid GA (:mod:`online_id.batchfit.ga`) on Haro's cost (:mod:`online_id.batchfit.cost`);
2. the final population is clustered (two points closer than ``cluster_radius`` in every
   log-parameter belong together) and the best point of each cluster is polished by a
   trust-region least-squares on the same residuals (:func:`scipy.optimize.least_squares`),
   giving the distinct local minima;
3. among the minima whose cost is within ``equivalent_cost`` (relative) of the lowest, the one
   closest to the prior (Mahalanobis distance with the prior's σ) is chosen, as Haro kept the
   minimum consistent with prior knowledge;
4. the covariance comes from the curvature of the cost at the chosen minimum (Gauss-Newton:
   (JᵀJ)⁻¹ with residuals scaled by each channel's residual spread); a parameter whose relative
   σ exceeds ``undetermined_relative_std`` is named as not determined by the data.

A fixed parameter (``fixed={"Mzz": 1600.0}``) is left out of the search vector: the GA, the polish
and the curvature work on the others (:class:`_FreeCost`), and its σ is 0.

With ``effects`` (``fit --effect``) the GA searches the 8 with the effects at their starting values,
and the polish and the covariance take the effects' parameters with the 8 (see
:class:`~online_id.batchfit.cost.FitCost`).

``FitConfig.intersample`` is the steering between the log's samples every simulation of the fit takes
(:mod:`online_id.model.intersample`; by default :data:`online_id.sim.BATCH_INTERSAMPLE`, the hold as before issue 36).
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from online_id.batchfit.cost import FitCost
from online_id.batchfit.ga import GAConfig, GAResult, hybrid_ga
from online_id.batchfit.guarded import NonFiniteStep, check_jacobian, guarded_least_squares
from online_id.errors import OnlineIdError
from online_id.filters.config import LINEAR_RANGE_AY
from online_id.filters.prior import centre_with_fixed, check_fixed, fixed_mask
from online_id.io.tracklog import TrackRun
from online_id.model.intersample import check_kind
from online_id.sim import BATCH_INTERSAMPLE
from online_id.trust.consistency import judge_fit
from online_id.trust.identifiability import information_covariance
from online_id.util.interrupts import interrupt_inside
from online_id.util.stages import absorb, stage
from online_id.util.threads import single_blas_thread
from online_id.vehicle.loader import Vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES, PARAMETER_UNITS, Parameters

#: The stage name a failure in the least-squares polish of the GA's minima is reported under.
FIT_POLISH_STAGE = "polish of the GA's minima"


@dataclass(frozen=True)
class FitConfig:
    """Settings of the batch fit (see the module docstring)."""

    lower_factor: float = 0.2
    upper_factor: float = 5.0
    ga: GAConfig = GAConfig()
    block: int = 10
    burn_in_s: float = 1.0
    cluster_radius: float = 0.05
    max_minima: int = 4
    equivalent_cost: float = 0.01
    undetermined_relative_std: float = 0.3
    #: blocks beyond the model's linear range are left out of the cost (see FilterConfig.linear_range_ay)
    linear_range_ay: float = LINEAR_RANGE_AY
    #: and the blocks this long after them [s]: the simulation carries an excursion's error for a few
    #: of the model's yaw and sideslip time constants (about 0.1 s on Haro's car)
    linear_range_settle_s: float = 0.5
    #: the steering between samples (online_id/model/intersample.py): "hold", "linear" or "cubic"
    intersample: str = BATCH_INTERSAMPLE

    def __post_init__(self):
        check_kind(self.intersample)


@dataclass
class Minimum:
    """A polished local minimum."""

    s: np.ndarray
    cost: float
    prior_distance: float
    chosen: bool = False
    polished: bool = True  # False: the GA's best as it was (its polish failed, or an interrupt came first)


@dataclass
class FitResult:
    parameters: Parameters
    std: np.ndarray  # (8,) SI
    relative_std: np.ndarray
    covariance: np.ndarray  # (8, 8) SI
    cost: float  # eq 12 at every sample
    rms_errors: dict[str, float]  # per channel, SI
    minima: list[Minimum]
    choice_reason: str
    evaluations: int
    wall_s: float
    undetermined: list[str]
    warnings: list[str]
    prior: Parameters
    channels: tuple[str, ...]
    ga: GAResult
    simulated: np.ndarray  # (N, 4) outputs of the chosen parameters
    run: TrackRun = field(repr=False, default=None)
    truth: Parameters | None = None
    interrupted: bool = False  # stopped early: the best candidate so far (see choice_reason)
    fixed: dict[str, float] = field(default_factory=dict)  # parameters held fixed [SI]
    prior_simulated: np.ndarray | None = field(repr=False, default=None)  # (N, 4) outputs of the prior
    consistency: dict | None = None  # online_id.trust.consistency.judge_fit
    outside_linear_range: float = 0.0  # fraction of the blocks left out of the cost
    #: fitted effect parameters: {label: {parameter: {"value", "std", "unit"}}} (``fit --effect``)
    effects: dict = field(default_factory=dict)
    intersample: str = "hold"  # the steering between samples the fit's model took (FitConfig.intersample)

    def to_json_dict(self) -> dict:
        """``parameters``, ``cost``, ``candidates``, ``evaluations``, ``wall_s`` are stable keys."""
        v = self.parameters.to_vector()
        theta0 = centre_with_fixed(self.prior.to_vector(), self.fixed)  # the centre the minima's s refer to
        out = {
            # an undetermined parameter has no finite σ: null
            "parameters": {n: {"value": float(x), "std": float(s) if np.isfinite(s) else None}
                           for n, x, s in zip(PARAMETER_NAMES, v, self.std)},
            "cost": self.cost,
            "candidates": [
                {"parameters": {n: float(x) for n, x in zip(PARAMETER_NAMES, theta0 * np.exp(m.s[:8]))},
                 "cost": m.cost, "prior_distance": m.prior_distance, "chosen": m.chosen, "polished": m.polished}
                for m in self.minima
            ],
            "evaluations": int(self.evaluations),
            "wall_s": round(self.wall_s, 3),
            "choice": self.choice_reason,
            "rms_errors": self.rms_errors,
            "units": dict(PARAMETER_UNITS),
            "relative_std": {n: float(s) if np.isfinite(s) else None for n, s in zip(PARAMETER_NAMES,
                                                                                      self.relative_std)},
            "covariance": [[float(c) if np.isfinite(c) else None for c in row] for row in self.covariance],
            "undetermined": self.undetermined,
            "warnings": self.warnings,
            "channels": list(self.channels),
            "generations": self.ga.generations,
            "interrupted": self.interrupted,
            "fixed": dict(self.fixed),
            "outside_linear_range": {"fraction": self.outside_linear_range},
            "intersample": self.intersample,
        }
        if self.consistency is not None:
            out["consistency"] = self.consistency
        if self.effects:
            out["effects"] = self.effects
        if self.truth is not None:
            t = self.truth.to_vector()
            out["truth"] = {n: float(x) for n, x in zip(PARAMETER_NAMES, t)}
            out["relative_error"] = {n: float(e) for n, e in zip(PARAMETER_NAMES, v / t - 1)}
        return out

    def write_json(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_json_dict(), indent=2) + "\n", encoding="utf-8")

    def table(self) -> str:
        head = f"{'param':<5} {'unit':<10} {'prior':>11} {'fit':>11} {'1σ':>9} {'1σ %':>7}"
        if self.truth is not None:
            head += f" {'truth':>11} {'error %':>8}"
        lines = [head, "-" * len(head)]
        v, p = self.parameters.to_vector(), self.prior.to_vector()
        for i, n in enumerate(PARAMETER_NAMES):
            row = (f"{n:<5} {PARAMETER_UNITS[n]:<10} {p[i]:>11.5g} {v[i]:>11.5g} {self.std[i]:>9.3g}"
                   f" {100 * self.relative_std[i]:>7.3f}")
            if self.truth is not None:
                t = self.truth.to_vector()[i]
                row += f" {t:>11.5g} {100 * (v[i] / t - 1):>8.3f}"
            if n in self.fixed:
                row += "  FIXED"
            elif n in self.undetermined:
                row += "  NOT DETERMINED"
            lines.append(row)
        return "\n".join(lines)


@single_blas_thread
@stage("fit")
def fit_run(vehicle: Vehicle, run: TrackRun, config: FitConfig = FitConfig(), seed: int = 0,
            prior: Parameters | None = None, prior_relative_std=None, truth: Parameters | None = None,
            channels: tuple[str, ...] | None = None, progress: bool = False,
            fixed: dict[str, float] | None = None, effects=()) -> FitResult:
    """Fit the 8 parameters (and those of ``effects``) to ``run`` (see the module docstring); ``fixed``
    {name: value [SI]} are held."""
    t0 = time.perf_counter()
    prior = prior or vehicle.prior
    fixed = check_fixed(fixed)
    free = ~fixed_mask(fixed)
    theta0 = centre_with_fixed(prior.to_vector(), fixed)
    prior_sd = np.asarray(prior_relative_std if prior_relative_std is not None
                          else vehicle.prior_relative_std.to_vector(), dtype=float)[free]
    full_cost = FitCost(vehicle, run, theta0, block=config.block, burn_in_s=config.burn_in_s, channels=channels,
                        linear_range_ay=config.linear_range_ay, settle_s=config.linear_range_settle_s,
                        effects=effects, intersample=config.intersample)
    cost = _FreeCost(full_cost, free)
    n_free = cost.n_parameters
    lower = np.full(n_free, np.log(config.lower_factor))
    upper = np.full(n_free, np.log(config.upper_factor))
    effect_lower, effect_upper = full_cost.effect_bounds()

    bar = None
    callback = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=config.ga.generations, unit="gen", desc="hybrid GA", leave=False, mininterval=0.5)

        def callback(gen, best):
            bar.update(gen - bar.n)
            bar.set_postfix_str(f"cost {best:.4g}", refresh=False)
    try:
        with stage("GA"):
            ga = hybrid_ga(cost.batch, lower, upper, config.ga, seed=seed, initial=np.zeros((1, n_free)),
                           progress=callback)
    finally:
        if bar is not None:
            bar.close()

    interrupted = ga.interrupted
    polish_failures: list[str] = []
    if interrupted:  # the GA's best so far, as it is: polishing would take the time the user did not give
        minima = [Minimum(s=ga.best.copy(), cost=float(ga.costs.min()), prior_distance=0.0, polished=False)]
    else:
        minima, interrupted, polish_failures = _polish_minima(cost, ga, np.concatenate([lower, effect_lower]),
                                                              np.concatenate([upper, effect_upper]), config)
    for m in minima:
        m.prior_distance = float(np.sqrt(np.sum((m.s[:n_free] / prior_sd) ** 2)))
    best_cost = min(m.cost for m in minima)
    equivalent = [m for m in minima if m.cost <= best_cost * (1 + config.equivalent_cost)]
    chosen = min(equivalent, key=lambda m: m.prior_distance)
    chosen.chosen = True
    if len(equivalent) > 1:
        reason = (f"{len(equivalent)} minima fit within {100 * config.equivalent_cost:g} % of the lowest cost;"
                  f" chose the one closest to the prior (Mahalanobis distance {chosen.prior_distance:.2f})")
    elif len(minima) > 1:
        reason = (f"lowest cost of {len(minima)} distinct minima; the others cost"
                  f" {', '.join(f'{m.cost / best_cost - 1:+.1%}' for m in minima if m is not chosen)} more")
    else:
        reason = "the GA's population converged to one minimum"
    if ga.interrupted:
        reason = f"interrupted in GA generation {ga.generations}: its best candidate so far, not polished"
    elif interrupted:
        reason = f"interrupted while polishing: the best of the {len(minima)} minima polished so far"
    elif not chosen.polished:
        reason = f"the polish of the GA's minima failed ({polish_failures[0]}): the GA's best, not polished"

    theta = cost.theta(chosen.s)
    notes = []
    chosen_free = chosen.s.copy()
    try:
        cov_free = _curvature_covariance(cost, chosen_free)
    except NonFiniteStep as exc:  # no curvature: every free parameter undetermined, and why
        cov_free = np.full((len(chosen_free), len(chosen_free)), np.inf)
        notes.append(f"{exc}: no covariance")
    cov_all = cost.embed_covariance(cov_free)
    cov_s = cov_all[:8, :8]
    rel_sd = np.sqrt(np.clip(np.diag(cov_s), 0, None))
    for mini in minima:
        mini.s = cost.full(mini.s)
    effects_out = {}
    for (e, p), v, sd in zip(full_cost.effect_parameters, chosen.s[8:],
                             np.sqrt(np.clip(np.diag(cov_all)[8:], 0, None))):
        effects_out.setdefault(e.label, {})[p.name] = {"value": float(v * p.scale), "std": float(sd * p.scale),
                                                       "unit": p.unit}
    if polish_failures:
        notes.append(f"the polish failed from {len(polish_failures)} of the GA's minima: {polish_failures[0]}")
    if np.std(run.steering_wheel_angle) < 1e-4:
        notes.append("no steering excitation in this run (steering-wheel angle constant):"
                     " the fit cannot inform any parameter")
    undetermined = [n for n, s in zip(PARAMETER_NAMES, rel_sd)
                    if not s < config.undetermined_relative_std and n not in fixed]
    if undetermined:
        notes.append(f"the data cannot determine {', '.join(undetermined)} (relative σ over"
                     f" {100 * config.undetermined_relative_std:g} %): their values are not to be trusted")
        warnings.warn(notes[-1], RuntimeWarning, stacklevel=2)
    at_bound = [n for n, s in zip(PARAMETER_NAMES, chosen.s)
                if n not in fixed and (s <= lower[0] + 1e-3 or s >= upper[0] - 1e-3)]
    if at_bound:
        notes.append(f"{', '.join(at_bound)} ended at a bound ({config.lower_factor:g}× or {config.upper_factor:g}×"
                     " the prior): widen the bounds or check the data")
    if full_cost.blocks_outside:
        notes.append(f"{100 * full_cost.outside_fraction:.1f} % of the run beyond the model's linear range"
                     f" (|a_y| > {config.linear_range_ay:.3g} m/s², and {config.linear_range_settle_s:g} s after):"
                     " left out of the cost")
    rate_cost, rms, simulated = full_cost.full_rate(theta, full_cost.effects_at(chosen.s))
    prior_simulated = full_cost.full_rate(prior.to_vector())[2]
    consistency = judge_fit(cost.residuals(chosen_free).reshape(-1, len(cost.channels)), cost.channels, theta,
                            vehicle.known, at_bound, full_cost.outside_fraction, not_determined=undetermined)
    return FitResult(
        parameters=Parameters.from_vector(theta), std=theta * rel_sd, relative_std=rel_sd,
        covariance=cov_s * np.outer(theta, theta), cost=rate_cost, rms_errors=rms, minima=minima,
        choice_reason=reason, evaluations=cost.evaluations, wall_s=time.perf_counter() - t0,
        undetermined=undetermined, warnings=notes, prior=prior, channels=cost.channels, ga=ga,
        simulated=simulated, run=run, truth=truth, interrupted=interrupted, fixed=fixed,
        prior_simulated=prior_simulated, consistency=consistency, outside_linear_range=full_cost.outside_fraction,
        effects=effects_out, intersample=config.intersample,
    )


class _FreeCost:
    """A :class:`FitCost` seen through the free unknowns only.

    The cost's unknowns are the 8 log-scale parameters, then the effects' parameters (``fit --effect``).
    Here the fixed parameters are left out (held at s = 0: their centre is their fixed value). A vector
    shorter than the free unknowns (the GA's, which searches the free parameters alone) takes the
    effects at their starting values.
    """

    def __init__(self, cost: FitCost, free_parameters: np.ndarray):
        self._cost = cost
        k = len(cost.start) - len(free_parameters)
        self._free = np.concatenate([free_parameters, np.ones(k, dtype=bool)])
        self._index = np.flatnonzero(self._free)
        self.start = cost.start[self._free]
        self.channels = cost.channels
        #: free physical parameters: the first entries of a free vector, and the GA's search space
        self.n_parameters = int(np.count_nonzero(free_parameters))

    @property
    def evaluations(self) -> int:
        return self._cost.evaluations

    @property
    def names(self) -> list[str]:
        """The free unknowns' names: parameters, then "<effect label> <parameter>"."""
        every = [*PARAMETER_NAMES, *(f"{e.label} {p.name}" for e, p in self._cost.effect_parameters)]
        return [every[i] for i in self._index]

    def full(self, s) -> np.ndarray:
        """All the cost's unknowns: ``s`` in the first free places, the rest at their start (0 for
        a fixed parameter, the starting value for an effect's)."""
        s = np.asarray(s, dtype=float)
        out = self._cost.start.copy()
        out[self._index[:len(s)]] = s
        return out

    def theta(self, s) -> np.ndarray:
        return self._cost.theta(self.full(s))

    def residuals(self, s) -> np.ndarray:
        return self._cost.residuals(self.full(s))

    def __call__(self, s) -> float:
        return self._cost(self.full(s))

    def batch(self, S) -> np.ndarray:
        return self._cost.batch(np.array([self.full(s) for s in np.atleast_2d(S)]))

    def embed_covariance(self, cov: np.ndarray) -> np.ndarray:
        """(m, m) of the first m free unknowns → (n, n) of all, zero variance where fixed or not fitted."""
        n = len(self._free)
        idx = self._index[:len(cov)]
        out = np.zeros((n, n))
        out[np.ix_(idx, idx)] = cov
        return out


def _polish_minima(cost: _FreeCost, ga: GAResult, lower, upper, config: FitConfig) \
        -> tuple[list[Minimum], bool, list[str]]:
    """The distinct minima, polished; whether a KeyboardInterrupt cut the polishing short (the minima
    polished so far are kept, or the GA's best when none was); and one line per start whose polish failed
    (the GA's best, not polished, stands in when every one failed)."""
    order = np.argsort(ga.costs)
    reps: list[np.ndarray] = []
    m = ga.population.shape[1]
    for i in order:
        if not np.isfinite(ga.costs[i]):
            continue
        if all(np.abs(ga.population[i] - r[:m]).max() > config.cluster_radius for r in reps):
            reps.append(np.concatenate([ga.population[i], cost.start[m:]]))  # the effects from their start
        if len(reps) >= config.max_minima:
            break
    minima: list[Minimum] = []
    failures: list[str] = []
    for r in reps:
        try:
            with stage(FIT_POLISH_STAGE):
                sol = guarded_least_squares(cost.residuals, r, bounds=(lower, upper), method="trf", x_scale=1.0,
                                            diff_step=1e-6, xtol=1e-10, ftol=1e-12, max_nfev=200,
                                            what="the polish of a GA minimum", names=cost.names)
                c = cost(sol.x)
        except (KeyboardInterrupt, Exception) as exc:
            if interrupt_inside(exc) is not None:  # the minima polished so far are kept, or the GA's best
                if not minima:
                    minima.append(Minimum(s=ga.best.copy(), cost=float(ga.costs.min()), prior_distance=0.0,
                                          polished=False))
                return minima, True, failures
            # this start is lost, the others are polished; the GA's best stays when none could be
            failures.append(str(exc) if isinstance(exc, OnlineIdError) else absorb(exc, FIT_POLISH_STAGE))
            continue
        if all(np.abs(sol.x - m.s).max() > config.cluster_radius / 5 for m in minima):
            minima.append(Minimum(s=sol.x, cost=c, prior_distance=0.0))
    if not minima:
        best = np.concatenate([ga.best, cost.start[len(ga.best):]])  # the effects at their start
        minima.append(Minimum(s=best, cost=float(ga.costs.min()), prior_distance=0.0, polished=False))
    return minima, False, failures


def _curvature_covariance(cost: FitCost, s: np.ndarray) -> np.ndarray:
    """Gauss-Newton covariance of s: residuals scaled to unit spread per channel, (JᵀJ)⁻¹."""
    r0 = cost.residuals(s)
    m = len(cost.channels)
    spread = np.sqrt(np.mean(r0.reshape(-1, m) ** 2, axis=0))
    spread = np.where(spread > 0, spread, 1.0)
    scale = np.tile(1.0 / spread, len(r0) // m)
    J = np.empty((len(r0), len(s)))
    h = 1e-5
    for i in range(len(s)):
        sp, sm = s.copy(), s.copy()
        sp[i] += h
        sm[i] -= h
        J[:, i] = (cost.residuals(sp) - cost.residuals(sm)) / (2 * h) * scale
    check_jacobian(J, "the covariance of the fit", cost.names)
    with np.errstate(over="ignore", invalid="ignore"):
        info = J.T @ J
    if not np.all(np.isfinite(info)):
        raise NonFiniteStep("the covariance of the fit stopped: the information matrix JᵀJ overflows")
    return information_covariance(info)
