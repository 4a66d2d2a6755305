"""The base model with effects over a whole run: logged steering in, logged channels out.

:func:`predict` runs the simulation form of the effects at full rate (the reference, used by the
simulator); :class:`BlockPredictor` gives block means through each effect's block-mean form (the
batch fit and the diagnosis). Both apply the effects in stage order (input, dynamics, sensor).
It lives with the simulators it drives (``sim/``): the effects package describes effects and imports
no simulator (nor scipy).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from online_id.effects.base import BlockContext, Effect, in_stage_order
from online_id.errors import OnlineIdError
from online_id.sim.fast import BlockSimulator
from online_id.sim.forces import simulate_with_forces
from online_id.vehicle.parameters import KnownParameters

#: Convergence of the tyre-force fixed point in the fits. The least-squares steps take finite differences
#: with a relative step of 1e-6: a looser tolerance makes the cost noisy at that scale and stalls the
#: optimiser short of the minimum (seen with two effects fitted together at 1e-7).
PICARD_TOL = 1e-10


def predict(theta, effects: Sequence[Effect], known: KnownParameters, logged_steering, speed, dt: float,
            method: str = "picard", **options) -> tuple[np.ndarray, np.ndarray]:
    """States (N, 6) and logged outputs (N, 4) [r, φ, p, a_y] of the model with ``effects``.

    The stages run in order: input effects turn the logged steering into what the car sees, dynamics
    effects change the model, sensor effects turn true outputs into logged ones. ``method`` is how a
    force law is solved (:func:`online_id.sim.forces.simulate_with_forces`, which also takes
    ``options`` such as ``tol`` and ``warm``); ``"rk4"``: the saturating tyre law (``tire_saturation``,
    ``tire_saturation_axles``) through the online filters' compiled model
    (:func:`online_id.model.tyres.simulate_outputs`, 16× faster than the fixed point and the same to 1e-4 rad/s
    at 0.9 g; the batch fits use it), other force laws as ``"picard"``.
    """
    effects = in_stage_order(effects)
    steering = np.asarray(logged_steering, dtype=float)
    theta = np.asarray(theta, dtype=float)
    for e in effects:
        steering = e.car_steering(steering, dt)
        theta = e.transform_theta(theta, known)
    law = _force_law(effects, theta, known)
    tyre = next((e for e in effects if e.tyre_mu() is not None), None)
    if method == "rk4" and tyre is not None:  # the online filters' model, compiled (online_id/model/tyres.py)
        from online_id.model import tyres

        mu = np.ascontiguousarray(tyre.tyre_mu(), dtype=float)
        states, outputs = tyres.simulate_outputs(
            theta, mu, tyres.axle_loads(known), np.ascontiguousarray(steering / known.steering_ratio),
            np.ascontiguousarray(np.broadcast_to(np.asarray(speed, dtype=float), steering.shape)), float(dt),
            tyres.known_array(known))
    else:
        states, outputs = simulate_with_forces(theta, known, steering, speed, dt, law,
                                               method="picard" if method == "rk4" else method, **options)
    for e in effects:
        outputs = e.measure(outputs, dt)
    return states, outputs


def _force_law(effects, theta, known):
    laws = [law for e in effects if (law := e.force_law(theta, known)) is not None]
    if len(laws) > 1:
        raise OnlineIdError("only one force-law effect at a time")
    return laws[0] if laws else None


class BlockPredictor:
    """Block means of the logged outputs of the model with effects over one run's inputs.

    Parameters
    ----------
    known : vehicle constants
    steering_wheel_angle, speed : the run's inputs, shape (N,) [rad, m/s]
    dt : sample period [s]
    block : samples per block q
    """

    def __init__(self, known: KnownParameters, steering_wheel_angle, speed, dt: float, block: int):
        self.known, self.dt = known, float(dt)
        self.steering = np.asarray(steering_wheel_angle, dtype=float)
        self.speed = np.broadcast_to(np.asarray(speed, dtype=float), self.steering.shape)
        self.sim = BlockSimulator(known, self.steering, self.speed, self.dt, block=block)
        self.q, self.n_blocks = self.sim.q, self.sim.n_blocks
        #: block centres from the start of the run [s]
        self.time = (np.arange(self.n_blocks) + 0.5) * self.q * self.dt
        self._unit_sim: BlockSimulator | None = None
        self._warm: dict = {}  # the force-law solver's warm start between calls

    def prefetch(self, thetas) -> None:
        """Simulate the base-model parameter sets ``thetas`` (P, 8) together (a fit's Jacobian points),
        and their unit-steering responses once an effect has asked for them."""
        self.sim.prefetch(thetas)
        if self._unit_sim is not None:
            self._unit_sim.prefetch(thetas)

    def outputs(self, theta, effects: Sequence[Effect] = ()) -> np.ndarray:
        """Block means of all four logged outputs (n_blocks, 4) with ``effects``."""
        effects = in_stage_order(effects)
        th = np.asarray(theta, dtype=float)
        if _force_law(effects, th, self.known) is not None:  # solved at full rate, then averaged
            n = self.sim.n_used
            _, y = predict(th, effects, self.known, self.steering[:n], self.speed[:n], self.dt, method="rk4",
                           tol=PICARD_TOL, warm=self._warm, hold=self.q)
            return y.reshape(self.n_blocks, self.q, 4).mean(axis=1)
        for e in effects:
            th = e.transform_theta(th, self.known)
        context = BlockContext(time=self.time, block_dt=self.dt * self.q,
                               unit_steering_response=lambda: self._unit_response(th))
        with np.errstate(over="ignore", invalid="ignore"):  # unstable candidates: inf, not a warning
            y = self.sim.block_means(th)
            for e in effects:
                y = e.block_means(y, context)
        return y

    def _unit_response(self, theta) -> np.ndarray:
        if self._unit_sim is None:
            self._unit_sim = BlockSimulator(self.known, np.ones(len(self.steering)), self.speed, self.dt,
                                            block=self.q)
        return self._unit_sim.block_means(theta)
