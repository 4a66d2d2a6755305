"""Haro's cost criterion (eq 12) over a run, evaluated fast for many parameter sets.

    j(θ) = (1/N) · sqrt( Σ e_r²/var(r) + Σ e_φ²/var(φ) + Σ e_ay²/var(a_y) [+ Σ e_vy²/var(v_y)] )

e is the simulation error (model output from the run's inputs, starting at rest,
minus measurement) and var() the variance of the measured signal; the sums run
over the channels present. For speed the errors are taken on block means of q
samples (:class:`~online_id.sim.block_means.BlockSimulator`, exact) rather than on
every sample: the criterion's minimiser is unchanged in expectation and nearly
all the information kept. :meth:`FitCost.full_rate` gives eq 12 on every sample.

With ``effects`` (``fit --effect``) the model is the base model with those effects (their
block-mean form, :class:`~online_id.sim.with_effects.BlockPredictor`), and the vector of unknowns
is s = [8 log-scale factors, each effect parameter divided by its typical size (``scale``)].

The model is driven by the logged steering between its samples as ``intersample`` says (held, or the linear or
cubic curve through the samples, :mod:`online_id.model.intersample`): every simulation here takes it.
"""

from __future__ import annotations

import numpy as np

from online_id.effects.base import in_stage_order
from online_id.errors import OnlineIdError
from online_id.io.tracklog import TrackRun, longitudinal_acceleration_of
from online_id.model.lateral import OUTPUT_NAMES
from online_id.sim import BATCH_INTERSAMPLE
from online_id.sim.block_means import BlockSimulator, simulate_outputs
from online_id.sim.with_effects import BlockPredictor, predict
from online_id.stream.samples import block_samples
from online_id.vehicle.loader import Vehicle

#: The channels of Haro's criterion, in model output order, and the lateral velocity where the log has it (an INS's
#: or an optical sensor's, issue 38; weighted like the others by its variance over the run).
COST_CHANNELS: tuple[str, ...] = ("yaw_rate", "roll_angle", "lateral_acceleration", "lateral_velocity")


class FitCost:
    """Cost of parameter sets on one run. Parameters are log-scale factors s around ``theta0``.

    Parameters
    ----------
    vehicle : the car (known constants)
    run : the track run (inputs and measured channels)
    theta0 : centre of the log scale, shape (8,) (usually the prior)
    block : samples per block for the fast cost (default 10; fewer on a slow log, see
        :func:`online_id.stream.samples.block_samples`)
    burn_in_s : seconds at the start left out of the sums: the simulation starts at rest,
        a real run may not
    channels : which of :data:`COST_CHANNELS` to use (default: those present)
    linear_range_ay : blocks with a sample whose measured |a_y| exceeds this [m/s²] are left out of
        the sums (the model's tyres are linear), and so are the blocks of ``settle_s`` seconds after
        them (the simulation's states carry the excursion's error for a few of the model's time
        constants); counted in :attr:`blocks_outside`. inf (the default here): every block counts.
    effects : effects (:mod:`online_id.effects`) whose parameters are fitted with the 8, from their values
    intersample : the steering between samples (``"hold"``, ``"linear"``, ``"cubic"``)
    """

    def __init__(self, vehicle: Vehicle, run: TrackRun, theta0, block: int = 10, burn_in_s: float = 1.0,
                 channels: tuple[str, ...] | None = None, linear_range_ay: float = np.inf,
                 settle_s: float = 0.0, effects=(), intersample: str = BATCH_INTERSAMPLE):
        self.vehicle, self.run, self.intersample = vehicle, run, intersample
        self.theta0 = np.asarray(theta0, dtype=float)
        present = [c for c in COST_CHANNELS if getattr(run, c) is not None and (channels is None or c in channels)]
        if not present:
            raise OnlineIdError(f"{run.source}: none of {', '.join(COST_CHANNELS)} to fit against")
        self.channels = tuple(present)
        self._cols = [OUTPUT_NAMES.index(c) for c in present]
        dts = np.diff(run.time)
        self.dt = float(np.median(dts))
        if np.any(np.abs(dts - self.dt) > 0.01 * self.dt):
            raise OnlineIdError(
                f"{run.source}: the batch fit needs evenly sampled data (period {self.dt * 1e3:.3g} ms,"
                f" but steps range {dts.min() * 1e3:.3g}-{dts.max() * 1e3:.3g} ms); resample it or use the"
                " online estimator, which takes uneven samples")
        if np.any(np.abs(run.speed) < 1.0):
            raise OnlineIdError(f"{run.source}: the batch fit needs the car moving (speed under 1 m/s found)")
        if int(np.ceil(burn_in_s / (self.dt * block))) >= len(run.time) // block - 10:
            raise OnlineIdError(f"{run.source}: too short for the fit after a {burn_in_s:g} s burn-in"
                                f" ({len(run.time)} samples; it needs 10 blocks of {block} after it)")
        self.effects = list(effects)
        self.effect_parameters = [(e, p) for e in self.effects for p in e.fit_parameters()]
        block = block_samples(self.dt, block)  # never more than MAX_BATCH_BLOCK_S: a slow log keeps its content
        if self.effects:
            self.predictor = BlockPredictor(vehicle.known, run.steering_wheel_angle, run.speed, self.dt, block,
                                            intersample=intersample,
                                            longitudinal_acceleration=longitudinal_acceleration_of(run)[0])
            self.sim = self.predictor.sim
        else:
            self.sim = BlockSimulator(vehicle.known, run.steering_wheel_angle, run.speed, self.dt, block=block,
                                      intersample=intersample)
        #: the starting unknowns: the prior, and each effect's values in units of its scale
        self.start = np.concatenate([np.zeros(8), [e.values[p.name] / p.scale for e, p in self.effect_parameters]])
        q, n = self.sim.q, self.sim.n_used
        measured = np.column_stack([getattr(run, c)[:n] for c in present])
        self.var = np.array([np.var(getattr(run, c)) for c in present])
        if np.any(self.var <= 0):
            raise OnlineIdError(f"{run.source}: a measured channel is constant; nothing to fit")
        self.measured_blocks = measured.reshape(-1, q, len(present)).mean(axis=1)
        self.first_block = int(np.ceil(burn_in_s / (self.dt * q)))
        if self.first_block >= self.sim.n_blocks - 10:
            raise OnlineIdError(f"{run.source}: too short for the fit after a {burn_in_s:g} s burn-in")
        self.used = np.arange(self.sim.n_blocks) >= self.first_block  # blocks in the sums
        outside = np.zeros(self.sim.n_blocks, dtype=bool)
        if run.lateral_acceleration is not None and np.isfinite(linear_range_ay):
            ay = run.lateral_acceleration
            if run.yaw_rate is not None:  # the car's a_y: sensor effects on the channel undone at their start values
                for e in reversed(in_stage_order(self.effects)):  # (an accelerometer ahead of the CG reads x_a·ṙ more)
                    ay = e.car_lateral_acceleration(ay, run.yaw_rate, self.dt)
            beyond = np.abs(ay[:n]).reshape(-1, q).max(axis=1) > linear_range_ay
            settle = int(np.ceil(settle_s / (self.dt * q)))
            outside = np.convolve(beyond, np.ones(settle + 1), mode="full")[:len(beyond)] > 0
        self.blocks_outside = int(np.count_nonzero(outside & self.used))
        self.outside_fraction = self.blocks_outside / max(int(np.count_nonzero(self.used)), 1)
        self.used &= ~outside
        self.n_blocks_used = int(np.count_nonzero(self.used))
        if self.n_blocks_used < 10:
            raise OnlineIdError(f"{run.source}: {100 * self.outside_fraction:.0f} % of the run is beyond the"
                                f" model's linear range (|a_y| > {linear_range_ay:.3g} m/s²): too little left to fit")
        self.evaluations = 0

    def theta(self, s) -> np.ndarray:
        return self.theta0 * np.exp(np.asarray(s, dtype=float)[..., :8])

    def effects_at(self, s) -> list:
        """The effects with their parameters from the unknowns ``s`` (their entries after the 8)."""
        out, k = [], 8
        for e in self.effects:
            scales = np.array([p.scale for p in e.fit_parameters()])
            out.append(e.with_vector(np.asarray(s[k:k + len(scales)]) * scales))
            k += len(scales)
        return out

    def effect_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of the effects' unknowns (in units of their scale)."""
        return (np.array([p.lower / p.scale for _, p in self.effect_parameters]),
                np.array([p.upper / p.scale for _, p in self.effect_parameters]))

    def residuals(self, s) -> np.ndarray:
        """Block errors divided by each channel's measured standard deviation, flattened."""
        self.evaluations += 1
        with np.errstate(over="ignore", invalid="ignore"):  # unstable candidates: inf, not a warning
            if self.effects:
                y = self.predictor.outputs(self.theta(s), self.effects_at(s))[:, self._cols]
            else:
                y = self.sim.block_means(self.theta(s))[:, self._cols]
            e = (y - self.measured_blocks)[self.used]
            return (e / np.sqrt(self.var)).ravel()

    def __call__(self, s) -> float:
        """Eq 12 on block means for one log-scale parameter vector s (8,)."""
        r = self.residuals(s)
        with np.errstate(over="ignore", invalid="ignore"):
            total = np.sum(r * r)
        if not np.isfinite(total):
            return np.inf
        return float(np.sqrt(total) / self.n_blocks_used)

    def batch(self, S) -> np.ndarray:
        """Costs of the rows of S, shape (P, 8) → (P,), simulated together (one batched decomposition
        per speed, one recursion carrying every row: a GA generation costs little more than one row).
        With effects, rows of (P, 8) take the effects at their starting values, or give them (P, 8 + k),
        and are evaluated one by one."""
        S = np.atleast_2d(np.asarray(S, dtype=float))
        if self.effects:
            if S.shape[1] < len(self.start):
                S = np.hstack([S, np.broadcast_to(self.start[S.shape[1]:], (len(S), len(self.start) - S.shape[1]))])
            return np.array([self(s) for s in S])
        self.evaluations += len(S)
        with np.errstate(over="ignore", invalid="ignore"):
            y = self.sim.block_means(self.theta(S))[:, self.used][:, :, self._cols]
            e = (y - self.measured_blocks[self.used]) / np.sqrt(self.var)
            total = np.sum(e * e, axis=(1, 2))
        return np.where(np.isfinite(total), np.sqrt(total) / self.n_blocks_used, np.inf)

    def full_rate(self, theta, effects=()) -> tuple[float, dict[str, float], np.ndarray]:
        """Eq 12 on every sample of the blocks in the sums, the RMS error per channel [SI units],
        and the simulated outputs (N, 4) (of the model with ``effects``)."""
        run = self.run
        if effects:
            _, y = predict(theta, effects, self.vehicle.known, run.steering_wheel_angle, run.speed, self.dt,
                           method="rk4", intersample=self.intersample,
                           longitudinal_acceleration=longitudinal_acceleration_of(run)[0])
        else:
            y = simulate_outputs(theta, self.vehicle.known, run.steering_wheel_angle, run.speed, self.dt,
                                 intersample=self.intersample)
        used = np.zeros(len(run), dtype=bool)
        used[:self.sim.n_used] = np.repeat(self.used, self.sim.q)
        if self.used[-1]:
            used[self.sim.n_used:] = True  # the samples after the last whole block, as before
        total, rms = 0.0, {}
        for c, col, var in zip(self.channels, self._cols, self.var):
            e = y[used, col] - getattr(run, c)[used]
            total += np.sum(e * e) / var
            rms[c] = float(np.sqrt(np.mean(e * e)))
        return float(np.sqrt(total) / np.count_nonzero(used)), rms, y
