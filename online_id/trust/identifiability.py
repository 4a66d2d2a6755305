"""What a run can tell about the parameters: Fisher information and the Cramér-Rao bound.

For outputs y_k(θ) simulated from the run's inputs and white measurement noise
of standard deviation σ_c on channel c, the Fisher information of the
log-scale parameters s (θ = θ0 e^s) is

    I = Σ_k Σ_c (∂y_c,k/∂s)ᵀ (∂y_c,k/∂s) / σ_c²,

and the Cramér-Rao bound on the relative standard deviation of θ_i is
sqrt((I⁻¹)_ii). The sensitivities come from central differences of the
exact simulation (relative step 1e-5 in θ), driven by the run's steering between its samples as
``intersample`` says (:mod:`online_id.model.intersample`; by default :data:`online_id.sim.BATCH_INTERSAMPLE`, the hold
as before issue 36).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from online_id.io.tracklog import TrackRun
from online_id.model.lateral import OUTPUT_NAMES
from online_id.sim import BATCH_INTERSAMPLE
from online_id.sim.simulator import propagate
from online_id.vehicle.loader import Vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES, Parameters


@dataclass(frozen=True)
class FisherReport:
    """Fisher information (8, 8) of the log-scale parameters, with derived figures.

    crlb_relative_std : (8,) Cramér-Rao bound on each parameter's relative σ
    condition_number : of the information matrix scaled to unit diagonal
    """

    information: np.ndarray
    crlb_relative_std: np.ndarray
    condition_number: float
    channels: tuple[str, ...]

    def undetermined(self, relative_std_limit: float = 0.1) -> list[str]:
        """Parameters whose bound is worse than ``relative_std_limit`` (the run cannot pin them)."""
        return [n for n, s in zip(PARAMETER_NAMES, self.crlb_relative_std) if not s < relative_std_limit]


def output_sensitivities(vehicle: Vehicle, theta: Parameters, run: TrackRun, rel_step: float = 1e-5,
                         intersample: str = BATCH_INTERSAMPLE) -> np.ndarray:
    """∂y/∂s of every output at every sample, shape (N, 4, 8) in :data:`OUTPUT_NAMES` order (SI units
    per unit log-scale change), by central differences of the exact simulation from the run's inputs."""
    dt = float(np.median(np.diff(run.time)))
    base = theta.to_vector()
    sens = np.empty((len(run), len(OUTPUT_NAMES), len(PARAMETER_NAMES)))
    for i in range(len(PARAMETER_NAMES)):
        up, down = base.copy(), base.copy()
        up[i] *= np.exp(rel_step)
        down[i] *= np.exp(-rel_step)
        _, y_up = propagate(up, vehicle.known, run.steering_wheel_angle, run.speed, dt, intersample=intersample)
        _, y_down = propagate(down, vehicle.known, run.steering_wheel_angle, run.speed, dt, intersample=intersample)
        sens[:, :, i] = (y_up - y_down) / (2 * rel_step)
    return sens


def channel_information(sensitivities: np.ndarray) -> dict[str, np.ndarray]:
    """Fisher information (8, 8) of each output channel at unit noise σ: I = Σ_c I_c / σ_c² for any noise."""
    return {c: sensitivities[:, k, :].T @ sensitivities[:, k, :] for k, c in enumerate(OUTPUT_NAMES)}


def report_from_information(info: np.ndarray, channels: tuple[str, ...]) -> FisherReport:
    """Cramér-Rao bound and condition number of an information matrix (8, 8) of the log-scale parameters."""

    cov = information_covariance(info)
    if not np.all(np.isfinite(info)):  # sensitivities that overflowed: no bound, and no condition number
        return FisherReport(information=info, crlb_relative_std=np.sqrt(np.diag(cov)),
                            condition_number=float("inf"), channels=tuple(channels))
    d = np.sqrt(np.diag(info))
    scaled = info / np.outer(d, d) if np.all(d > 0) else info
    return FisherReport(information=info, crlb_relative_std=np.sqrt(np.clip(np.diag(cov), 0, None)),
                        condition_number=float(np.linalg.cond(scaled)), channels=tuple(channels))


def fisher_information(vehicle: Vehicle, theta: Parameters, run: TrackRun,
                       noise_std: dict[str, float], channels: tuple[str, ...] | None = None,
                       rel_step: float = 1e-5, intersample: str = BATCH_INTERSAMPLE) -> FisherReport:
    """Fisher information of ``run``'s inputs at ``theta`` for the given channels and noise (SI units)."""
    use = [c for c in OUTPUT_NAMES if (channels is None or c in channels) and c in noise_std]
    cols = [OUTPUT_NAMES.index(c) for c in use]
    sd = np.array([noise_std[c] for c in use])
    dt = float(np.median(np.diff(run.time)))
    base = theta.to_vector()
    sens = []
    for i in range(len(PARAMETER_NAMES)):
        up, down = base.copy(), base.copy()
        up[i] *= np.exp(rel_step)
        down[i] *= np.exp(-rel_step)
        _, y_up = propagate(up, vehicle.known, run.steering_wheel_angle, run.speed, dt, intersample=intersample)
        _, y_down = propagate(down, vehicle.known, run.steering_wheel_angle, run.speed, dt, intersample=intersample)
        sens.append(((y_up - y_down)[:, cols] / (2 * rel_step)) / sd)
    S = np.stack([s.reshape(-1) for s in sens], axis=1)  # (N·channels, 8)
    with np.errstate(over="ignore", invalid="ignore"):
        info = S.T @ S
    if not np.all(np.isfinite(info)):  # sensitivities that overflowed (an unstable model at theta): no bound
        return FisherReport(information=info, crlb_relative_std=np.full(len(PARAMETER_NAMES), np.inf),
                            condition_number=float("inf"), channels=tuple(use))
    cov = np.linalg.pinv(info)
    d = np.sqrt(np.diag(info))
    scaled = info / np.outer(d, d) if np.all(d > 0) else info
    return FisherReport(
        information=info,
        crlb_relative_std=np.sqrt(np.clip(np.diag(cov), 0, None)),
        condition_number=float(np.linalg.cond(scaled)),
        channels=tuple(use),
    )


def information_covariance(info: np.ndarray, rcond: float = 1e-12) -> np.ndarray:
    """Inverse of an information matrix, with infinite variance along directions it does not inform.

    (A pseudo-inverse would give those directions zero variance: a confident answer from no data.)
    A matrix with a non-finite entry informs nothing: every variance is infinite.
    """
    if not np.all(np.isfinite(info)):
        return np.full(np.shape(info), np.inf)
    e, V = np.linalg.eigh(0.5 * (info + info.T))
    floor = rcond * max(float(e.max()), 0.0)
    with np.errstate(divide="ignore"):
        inv_e = np.where(e > floor, 1.0 / np.where(e > floor, e, 1.0), np.inf)
    informed = np.isfinite(inv_e)
    cov = (V[:, informed] * inv_e[informed]) @ V[:, informed].T
    if not informed.all():
        # a parameter with any weight on an uninformed direction has unbounded variance
        leak = (V[:, ~informed] ** 2).sum(axis=1) > 1e-12
        cov[leak, :] = np.where(np.eye(len(e), dtype=bool)[leak], np.inf, cov[leak, :])
    return cov


@dataclass(frozen=True)
class EffectInformation:
    """Fisher information of the 8 log-scale parameters and an effect's own (in their units), from one run.

    names : the 8 parameter names, then the effect's parameter names
    information : (8 + k, 8 + k)
    crlb : (8 + k,) Cramér-Rao bound: relative σ for the 8, σ in the effect's unit for its own
    crlb_without : (8,) the bound on the 8 with the effect known (its parameters not estimated)
    correlation : (8 + k, 8 + k) the correlations of the bound's covariance
    """

    names: tuple[str, ...]
    information: np.ndarray
    crlb: np.ndarray
    crlb_without: np.ndarray
    correlation: np.ndarray

    def inflation(self) -> dict[str, float]:
        """How much estimating the effect widens each of the 8's bound (1: the data separate them)."""
        return {n: float(a / b) for n, a, b in zip(PARAMETER_NAMES, self.crlb, self.crlb_without)}

    def correlation_with_effect(self, parameter: str | None = None) -> dict[str, float]:
        """The bound's correlation of each of the 8 with the effect's (first) parameter."""
        k = len(PARAMETER_NAMES) + (0 if parameter is None else self.names.index(parameter) - len(PARAMETER_NAMES))
        return {n: float(self.correlation[i, k]) for i, n in enumerate(PARAMETER_NAMES)}


def effect_information(vehicle: Vehicle, theta: Parameters, run: TrackRun, noise_std: dict[str, float], effect,
                       rel_step: float = 1e-5, intersample: str = BATCH_INTERSAMPLE) -> EffectInformation:
    """Fisher information of ``run``'s inputs for the 8 and ``effect``'s parameters at their values (the model
    with the effect, :func:`online_id.sim.with_effects.predict`; central differences: relative step
    ``rel_step`` on the 8, the parameter's ``scale`` × ``rel_step`` on the effect's), white noise ``noise_std``
    [SI] on the channels given there. What it says: whether the data can tell the effect from the dynamics
    (a yaw-rate delay from Mzz, a steering delay from b1) — the correlations and the widening of the 8's bound."""
    from online_id.sim.with_effects import predict

    use = [c for c in OUTPUT_NAMES if c in noise_std]
    cols = [OUTPUT_NAMES.index(c) for c in use]
    sd = np.array([noise_std[c] for c in use])
    dt = float(np.median(np.diff(run.time)))
    base = theta.to_vector()
    params = effect.fit_parameters()

    def outputs(th, e):
        return predict(th, [e], vehicle.known, run.steering_wheel_angle, run.speed, dt, method="loop",
                       intersample=intersample)[1][:, cols]

    columns = []
    for i in range(len(PARAMETER_NAMES)):
        up, down = base.copy(), base.copy()
        up[i] *= np.exp(rel_step)
        down[i] *= np.exp(-rel_step)
        columns.append((outputs(up, effect) - outputs(down, effect)) / (2 * rel_step))
    v = effect.vector()
    for j, p in enumerate(params):
        h = p.scale * rel_step * 100  # the effect's parameters act less smoothly (an interpolated delay)
        up, down = v.copy(), v.copy()
        up[j] += h
        down[j] -= h
        columns.append((outputs(base, effect.with_vector(up)) - outputs(base, effect.with_vector(down))) / (2 * h))
    S = np.stack([(c / sd).reshape(-1) for c in columns], axis=1)
    info = S.T @ S
    cov = information_covariance(info)
    d = np.sqrt(np.clip(np.diag(cov), 0, None))
    corr = cov / np.outer(d, d)
    n = len(PARAMETER_NAMES)
    without = np.sqrt(np.clip(np.diag(information_covariance(info[:n, :n])), 0, None))
    return EffectInformation(names=tuple(PARAMETER_NAMES) + tuple(p.name for p in params), information=info,
                             crlb=d, crlb_without=without, correlation=corr)
