"""The base model with effects over a whole run: logged steering in, logged channels out.

:func:`predict` runs the simulation form of the effects at full rate (the reference, used by the
simulator); :class:`BlockPredictor` gives block means through each effect's block-mean form (the
batch fit and the diagnosis). Both apply the effects in stage order (input, dynamics, sensor).
It lives with the simulators it drives (``sim/``): the effects package describes effects and imports
no simulator (nor scipy).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

import numpy as np

from online_id.effects.base import BlockContext, Effect, in_stage_order, loads_with_speed
from online_id.errors import OnlineIdError
from online_id.io.tracklog import speed_slope
from online_id.model import intersample as its
from online_id.sim.block_means import BlockSimulator, step_inputs
from online_id.sim.forces import simulate_with_forces
from online_id.vehicle.parameters import KnownParameters, axle_loads

#: Convergence of the tyre-force fixed point in the fits. The least-squares steps take finite differences
#: with a relative step of 1e-6: a looser tolerance makes the cost noisy at that scale and stalls the
#: optimiser short of the minimum (seen with two effects fitted together at 1e-7).
PICARD_TOL = 1e-10


def predict(theta, effects: Sequence[Effect], known: KnownParameters, logged_steering, speed, dt: float,
            method: str = "picard", intersample: str = "hold", longitudinal_acceleration=None,
            **options) -> tuple[np.ndarray, np.ndarray]:
    """States (N, 6) and logged outputs (N, 4) [r, φ, p, a_y] of the model with ``effects``.

    The stages run in order: input effects turn the logged steering into what the car sees, dynamics
    effects change the model, sensor effects turn true outputs into logged ones. ``method`` is how a
    force law is solved (:func:`online_id.sim.forces.simulate_with_forces`, which also takes
    ``options`` such as ``tol`` and ``warm``); ``"rk4"``: the saturating tyre law (``tire_saturation``,
    ``tire_saturation_axles``) through the online filters' compiled model
    (:func:`online_id.model.tyres.rk4_states_and_outputs`, 16× faster than the fixed point and the same to 1e-4 rad/s
    at 0.9 g; the batch fits use it), other force laws as ``"picard"``.

    ``intersample``: the car's steering between its samples (after the input effects;
    :mod:`online_id.model.intersample`), exact through the linear part's Γ in
    :mod:`online_id.sim.forces`; ``"rk4"`` with another ``intersample`` than the hold takes the step's input
    polynomial at the RK4's stages (:func:`online_id.model.tyres.rk4_states_and_outputs_input`; the fixed point it
    replaced until 2026-11-27 fell back to a per-sample Python loop at the race car's 1.7 g). ``"midpoint"``: the
    RK4 holding each step's own input at its midpoint, δ(t_k + T/2), at the step's speed (the mean of its two samples',
    :func:`midpoint_inputs`): second order, for a simulation at a fine rate
    (:func:`online_id.sim.simulator.simulate`: at 10 kHz the same as at 20 kHz to 1e-4 of the sensor noise).

    ``longitudinal_acceleration`` (N,) [m/s²]: what a tyre law whose axle loads move with it reads
    (:attr:`Effect.moves_loads <online_id.effects.base.Effect.moves_loads>`, ``load_transfer``; None: dV/dt of
    ``speed``); such a law is solved by the compiled RK4 whatever ``method`` says (the force-law solver's law has
    static loads).
    """
    effects = in_stage_order(effects)
    steering, theta = car_inputs(effects, logged_steering, theta, known, dt)
    law = _force_law(effects, theta, known)
    tyre = next((e for e in effects if e.tyre_mu() is not None), None)
    if tyre is not None and tyre.moves_loads and longitudinal_acceleration is None:  # dV/dt of the speed, then
        longitudinal_acceleration = speed_slope(np.broadcast_to(np.asarray(speed, dtype=float), np.shape(steering)), dt)
    Fz = None if tyre is None else loads_with_speed(tyre.axle_loads)(
        known, longitudinal_acceleration, np.broadcast_to(np.asarray(speed, dtype=float), np.shape(steering)))
    if tyre is not None and tyre.moves_loads and method not in ("rk4", "midpoint"):
        if not law_is_tyres(effects, theta, known):
            raise OnlineIdError(f"{tyre.name}: no other force law can act with it")
        method = "rk4"
    if tyre is not None and method == "rk4" and intersample != "hold" and law_is_tyres(effects, theta, known):
        # the same RK4 with each step's input polynomial at its stages (compiled, online_id/model/tyres.py)
        states, outputs = _tyre_rk4_input(theta, tyre.tyre_mu(), known, steering, speed, dt, intersample, Fz)
    elif tyre is not None and (method == "midpoint" or (method == "rk4" and intersample == "hold")):
        # the online filters' model, compiled (online_id/model/tyres.py)
        states, outputs = _tyre_rk4(theta, tyre.tyre_mu(), known, steering, speed, dt,
                                    "hold" if method == "rk4" else intersample, Fz)
    else:
        states, outputs = simulate_with_forces(theta, known, steering, speed, dt, law,
                                               method="picard" if method in ("rk4", "midpoint") else method,
                                               intersample=intersample, **options)
    return states, logged_outputs(effects, outputs, dt, speed)


def car_inputs(effects: Sequence[Effect], logged_steering, theta, known: KnownParameters,
               dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The steering-wheel angle the car sees (N,) [rad] and the base model's parameters (8,) that make it the
    car with ``effects`` (in stage order): their input and re-parametrising stages, as :func:`predict` runs them."""
    steering = np.asarray(logged_steering, dtype=float)
    theta = np.asarray(theta, dtype=float)
    for e in effects:
        steering = e.car_steering(steering, dt)
        theta = e.transform_theta(theta, known)
    return steering, theta


def logged_outputs(effects: Sequence[Effect], outputs: np.ndarray, dt: float, speed=None) -> np.ndarray:
    """The logged channels (N, 4) from the car's outputs: the sensor stages of ``effects`` (in stage order), with each
    sample's ``speed`` [m/s] for an effect that reads it (:meth:`Effect.measure_at`)."""
    for e in effects:
        outputs = e.measure(outputs, dt) if speed is None or not e.reads_speed else e.measure_at(outputs, dt, speed)
    return outputs


def has_force_law(effects: Sequence[Effect], theta, known: KnownParameters) -> bool:
    """Whether one of ``effects`` adds a force law to the model (it then needs a force-law solver)."""
    return _force_law(effects, np.asarray(theta, dtype=float), known) is not None


def _tyre_rk4(theta, mu, known: KnownParameters, steering, speed, dt: float, intersample: str, Fz=None):
    """States (N, 6) and outputs (N, 4) of the saturating tyre law by the filters' RK4 (:func:`predict`): δ held
    over each step, at the sample's value (the hold) or at the step's midpoint (another ``intersample``)."""
    from online_id.model import pieces, tyres

    delta, V = midpoint_inputs(intersample, steering / known.steering_ratio,
                               np.broadcast_to(np.asarray(speed, dtype=float), steering.shape), dt)
    W = np.zeros((len(delta), 4))
    W[:, 0] = delta
    loads = tyres.per_sample_loads(axle_loads(known) if Fz is None else Fz, len(delta))
    return pieces.states_and_outputs(theta, np.ascontiguousarray(mu, dtype=float), loads, W, np.ascontiguousarray(V),
                                     float(dt), tyres.known_array(known))


def law_is_tyres(effects, theta, known) -> bool:
    """Whether the saturating tyre is the only force law among ``effects`` (the compiled RK4 has no other)."""
    return sum(1 for e in effects if e.force_law(theta, known) is not None) == 1


def _tyre_rk4_input(theta, mu, known: KnownParameters, steering, speed, dt: float, intersample: str, Fz=None):
    """States (N, 6) and outputs (N, 5) of the saturating tyre law by RK4 with each step's input polynomial
    (:func:`online_id.model.tyres.rk4_states_and_outputs_input`), the step speeds as the polish takes them."""
    from online_id.model import pieces, tyres
    from online_id.sim.block_means import step_inputs

    W, V = step_inputs(intersample, steering / known.steering_ratio,
                       np.broadcast_to(np.asarray(speed, dtype=float), steering.shape), dt)
    loads = tyres.per_sample_loads(axle_loads(known) if Fz is None else Fz, len(W))
    return pieces.states_and_outputs(theta, np.ascontiguousarray(mu, dtype=float), loads, np.ascontiguousarray(W),
                                     np.ascontiguousarray(V), float(dt), tyres.known_array(known))


def midpoint_inputs(intersample: str, delta, speed, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The road-wheel angle (n,) [rad] and speed (n,) [m/s] a model that holds its input over each step from a
    sample takes (the RK4 tyre model, :mod:`online_id.model.tyres`): the samples' own with the hold; else each
    step's input at its midpoint, δ(t_k + T/2) (:func:`online_id.model.intersample.value_at`), and the step's
    speed. Second order: off the exact step by about T³·(A·B·δ'/12 + B·δ''/24) a step (Ac = A, Bc = B), against
    the hold's T²·B·δ'/2. The
    outputs do not take δ directly (D = 0, :func:`online_id.model.lateral.output_matrices`), so nothing else moves."""
    if intersample == "hold":
        return np.asarray(delta, dtype=float), np.asarray(speed, dtype=float)
    w, step_speed = step_inputs(intersample, delta, speed, dt)
    return its.value_at(w, 0.5), step_speed


def _force_law(effects, theta, known):
    laws = [law for e in effects if (law := e.force_law(theta, known)) is not None]
    if len(laws) > 1:
        raise OnlineIdError("only one force-law effect at a time")
    return laws[0] if laws else None


#: Force-law simulations whose car outputs a :class:`BlockPredictor` keeps (a fit's point and, on threads, the
#: Jacobian's columns in flight).
CAR_OUTPUTS_KEPT = 4


#: Longest block [s] over which a time shift (a delay) is applied to the block means themselves; on longer blocks
#: (a 100 Hz log's 0.1 s) the shift is applied to every sample's outputs, then averaged: a 3 Hz steering is
#: 0.3 cycles of a 0.1 s block, and the shifted block means of a 4 Hz chirp's last seconds cannot be had from the
#: block means alone (measured: a 40 ms steering delay at 100 Hz fitted as 56-58 ms, 12 noise σ left).
SHIFT_BLOCK_S = 0.02


class BlockPredictor:
    """Block means of the logged outputs of the model with effects over one run's inputs.

    Parameters
    ----------
    known : vehicle constants
    steering_wheel_angle, speed : the run's inputs, shape (N,) [rad, m/s]
    dt : sample period [s]
    block : samples per block q
    intersample : the steering between samples (:mod:`online_id.model.intersample`), for the base model's
        block means, the unit-steering response and the force law's full-rate simulation alike
    """

    def __init__(self, known: KnownParameters, steering_wheel_angle, speed, dt: float, block: int,
                 intersample: str = "hold", longitudinal_acceleration=None):
        self.known, self.dt, self.intersample = known, float(dt), intersample
        #: (N,) [m/s²] or None: what a tyre law with moving axle loads reads (:func:`predict`)
        self.longitudinal_acceleration = (None if longitudinal_acceleration is None else
                                          np.asarray(longitudinal_acceleration, dtype=float))
        self.steering = np.asarray(steering_wheel_angle, dtype=float)
        self.speed = np.broadcast_to(np.asarray(speed, dtype=float), self.steering.shape)
        self.sim = BlockSimulator(known, self.steering, self.speed, self.dt, block=block, intersample=intersample)
        self.q, self.n_blocks = self.sim.q, self.sim.n_blocks
        #: block centres from the start of the run [s]
        self.time = (np.arange(self.n_blocks) + 0.5) * self.q * self.dt
        self._unit_sim: BlockSimulator | None = None
        self._sample_sim: BlockSimulator | None = None  # every sample's outputs, for a shift on long blocks
        self._unit_sample_sim: BlockSimulator | None = None
        self._warm: dict = {}  # the force-law solver's warm start between calls
        #: the car's outputs (before the sensor effects) of the last few force-law simulations, by parameters and
        #: the input and dynamics effects' values: a fit that moves a sensor effect alone (a screen beside the
        #: tyres, its Jacobian column) needs no pass of the model (:meth:`outputs`); shared by threads, so locked
        self._car_outputs: dict = {}
        self._car_lock = threading.Lock()
        self._speeds_by_block: dict[int, np.ndarray] = {}  # (_block_speeds)

    def prefetch(self, thetas) -> None:
        """Simulate the base-model parameter sets ``thetas`` (P, 8) together (a fit's Jacobian points),
        and their unit-steering responses once an effect has asked for them."""
        self.sim.prefetch(thetas)
        if self._unit_sim is not None:
            self._unit_sim.prefetch(thetas)
        for sim in (self._sample_sim, self._unit_sample_sim):
            if sim is not None:
                sim.prefetch(thetas)

    def outputs(self, theta, effects: Sequence[Effect] = ()) -> np.ndarray:
        """Block means of all four logged outputs (n_blocks, 4) with ``effects``."""
        effects = in_stage_order(effects)
        th = np.asarray(theta, dtype=float)
        if _force_law(effects, th, self.known) is not None:  # solved at full rate, then averaged
            n = self.sim.n_used
            # (not held: the whole run, so that the last used sample's slope sees its successor, as the blocks do)
            m = n if self.intersample == "hold" else len(self.steering)
            ax = None if self.longitudinal_acceleration is None else self.longitudinal_acceleration[:m]
            car = [e for e in effects if e.stage != "sensor"]
            key = (th.tobytes(), tuple((e.name, e.channel, e.vector().tobytes()) for e in car))
            with self._car_lock:
                y = self._car_outputs.get(key)
            if y is None:  # (predict with the sensor effects is this, then logged_outputs: the same numbers)
                _, y = predict(th, car, self.known, self.steering[:m], self.speed[:m], self.dt, method="rk4",
                               intersample=self.intersample, tol=PICARD_TOL, warm=self._warm, hold=self.q,
                               longitudinal_acceleration=ax)
                with self._car_lock:
                    self._car_outputs[key] = y
                    while len(self._car_outputs) > CAR_OUTPUTS_KEPT:
                        self._car_outputs.pop(next(iter(self._car_outputs)))
            y = logged_outputs([e for e in effects if e.stage == "sensor"], y, self.dt, self.speed[:m])
            return y[:n].reshape(self.n_blocks, self.q, -1).mean(axis=1)
        for e in effects:
            th = e.transform_theta(th, self.known)
        if self.q > 1 and self.dt * self.q > SHIFT_BLOCK_S and any(e.short_blocks_only for e in effects):
            return self._through_samples(th, effects)
        context = BlockContext(time=self.time, block_dt=self.dt * self.q,
                               unit_steering_response=lambda: self._unit_response(th),
                               speed=self._block_speeds(self.q))
        with np.errstate(over="ignore", invalid="ignore"):  # unstable candidates: inf, not a warning
            y = self.sim.block_means(th)
            for e in effects:
                y = e.block_means(y, context)
        return y

    def _through_samples(self, th, effects) -> np.ndarray:
        """The block means with ``effects`` that shift in time, on blocks longer than :data:`SHIFT_BLOCK_S`: each
        effect's block form applied to every sample's outputs (blocks of one sample), then averaged over the q
        samples of each block."""
        if self._sample_sim is None:
            self._sample_sim = BlockSimulator(self.known, self.steering, self.speed, self.dt, block=1,
                                              intersample=self.intersample)
        n = self.sim.n_used
        time = (np.arange(self._sample_sim.n_blocks) + 0.5) * self.dt
        context = BlockContext(time=time, block_dt=self.dt,
                               unit_steering_response=lambda: self._unit_response(th, per_sample=True),
                               speed=self._block_speeds(1))
        with np.errstate(over="ignore", invalid="ignore"):  # unstable candidates: inf, not a warning
            y = self._sample_sim.block_means(th)
            for e in effects:
                y = e.block_means(y, context)
        return y[:n].reshape(self.n_blocks, self.q, -1).mean(axis=1)

    def _block_speeds(self, q: int) -> np.ndarray:
        """The logged speed's mean over each block of ``q`` samples (n_blocks,) [m/s] (a sensor that reads the speed
        at its samples: the block mean of V·c is c times it), worked out once per block length."""
        speeds = self._speeds_by_block.get(q)
        if speeds is None:
            n = len(self.speed) // q
            speeds = self._speeds_by_block[q] = self.speed[:n * q].reshape(n, q).mean(axis=1)
        return speeds

    def _unit_response(self, theta, per_sample: bool = False) -> np.ndarray:
        if per_sample:
            if self._unit_sample_sim is None:
                self._unit_sample_sim = BlockSimulator(self.known, np.ones(len(self.steering)), self.speed, self.dt,
                                                       block=1, intersample=self.intersample)
            return self._unit_sample_sim.block_means(theta)
        if self._unit_sim is None:
            self._unit_sim = BlockSimulator(self.known, np.ones(len(self.steering)), self.speed, self.dt,
                                            block=self.q, intersample=self.intersample)
        return self._unit_sim.block_means(theta)
