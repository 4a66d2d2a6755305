"""What an unmodelled effect is: a documented extension of the base model with its own parameters.

An effect acts at one stage of the path from the driver's hands to the logged channels
(:attr:`Effect.stage`, which also orders the effects wherever several act together):

- ``input``: between the logged steering-wheel angle and the angle the car really sees
  (:meth:`Effect.car_steering`, and its inverse :meth:`Effect.logged_steering` for simulation);
- ``dynamics``: inside the model, either as an exact re-parametrisation
  (:meth:`Effect.transform_theta`) or as an extra force law of the slip angles
  (:meth:`Effect.force_law`, see :mod:`online_id.sim.forces`);
- ``sensor``: between the true outputs and the logged channels (:meth:`Effect.measure`).

Every effect provides the same three forms of itself, each a hook of :class:`Effect`:

1. **simulation** (full rate): the stage hooks above, run by :func:`online_id.sim.with_effects.predict`;
2. **block means** (the batch fits and the diagnosis): :meth:`Effect.block_means` turns the base
   model's block-mean outputs into the logged channels' block means
   (:class:`online_id.sim.with_effects.BlockPredictor`);
3. **filter form** (the online filters): :meth:`Effect.filter_states` describes the effect's
   parameters as extra states of the augmented filter (:class:`ExtraState`, consumed by
   :mod:`online_id.filters.augment`), or raises :class:`~online_id.errors.OnlineIdError` saying why
   the effect has none.

A new effect is a module in this folder with one :class:`Effect` subclass and one line in
:data:`online_id.effects.EFFECTS`. It needs a ``name``, ``stage``, ``syntax``, ``example`` and
``summary``, its fit parameters (:meth:`Effect.fit_parameters`), :meth:`Effect.parse`, the hooks of
its stage, and the block-mean and filter forms; ``tests/test_effects_contract.py`` checks all of it
for every registered effect. Nothing outside this folder branches on a concrete effect class.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from online_id.errors import OnlineIdError
from online_id.model.lateral import OUTPUT_NAMES
from online_id.vehicle.parameters import KnownParameters

#: Channels a sensor effect can sit on (the model outputs, in order).
SENSOR_CHANNELS: tuple[str, ...] = OUTPUT_NAMES
STEERING = "steering_wheel_angle"
#: The stages in the order they act (logged steering → car → sensors).
STAGES: tuple[str, ...] = ("input", "dynamics", "sensor")


@dataclass(frozen=True)
class FitParameter:
    """One extra parameter: name, unit, start of the fit, bounds and typical size (for scaling)."""

    name: str
    unit: str
    initial: float
    lower: float
    upper: float
    scale: float


@dataclass(frozen=True)
class ExtraState:
    """One effect parameter as an extra state of the online filters (see :mod:`online_id.filters.augment`).

    The state e is additive, in SI units (not log-scale), and follows a random walk. It enters the
    model linearly (to first order where the effect is not linear), or, for a tyre's μ (``tyre_axles``),
    through the saturating force law, or, for a time lag (``lags``), through the time at which the
    filter reads the lagged channels:

        δ = δH / i_s + steering · e                          (the road-wheel angle)
        y_logged = C x + D δ + e · (output + output_state · x)  (the outputs [r, φ, p, a_y, v_y], the filters'
        v_y per unit speed)
        y_c,logged(t + e) = y_c(t)                           (a channel c in ``lags``: e seconds late)

    Attributes
    ----------
    group, key : where the state is reported: ``"offsets"`` (by channel) or ``"effects"`` (by the
        effect's label); ``parameter`` is the effect's fit-parameter name
    unit : the state's unit
    prior_std : 1σ before any data [unit]
    random_walk : 1σ growth per √s [unit/√s]
    initial : the state's starting value [unit]
    output : (5,) direct sensitivity of the outputs to e
    output_state : (5, 6) or None: sensitivity of the outputs to e times the model state x
    steering : sensitivity of the road-wheel angle to e [rad per unit]
    tyre_axles : the axles (0 front, 1 rear) whose friction coefficient μ this state is: the state then
        enters the dynamics through the saturating tyre law (:mod:`online_id.model.tyres`), not linearly,
        and the filters switch to that model's form (:mod:`online_id.filters.tyre_filters`)
    lags : the channels (measured channels, and ``"speed"``) this state, a time lag [s], delays against the
        logged steering: the filters read them e later (the lagged-output form,
        :mod:`online_id.filters.lagged`), and their sensitivity to e is −ẏ (none for the speed)
    axle_loads : for a tyre μ (``tyre_axles``) whose axle loads follow the longitudinal acceleration, the effect's
        :meth:`Effect.axle_loads` (known, a_x (n,)) → (n, 2) loads, or (n, 4) with the axles' longitudinal forces;
        the filters then read each sample's ``longitudinal_acceleration``. None: static loads
    bounds : (lower, upper) the values the state can physically have (a delay is not negative), or None: an
        estimate beyond them by more than a few σ is a reason in the consistency verdict
        (:func:`online_id.trust.consistency.judge_estimator`): the state is taking up model error
    """

    group: str
    key: str
    parameter: str
    unit: str
    prior_std: float
    random_walk: float
    initial: float = 0.0
    output: tuple[float, ...] = (0.0,) * len(OUTPUT_NAMES)
    output_state: tuple[tuple[float, ...], ...] | None = None
    steering: float = 0.0
    tyre_axles: tuple[int, ...] = ()
    lags: tuple[str, ...] = ()
    bounds: tuple[float, float] | None = None
    axle_loads: Callable | None = None


@dataclass(frozen=True)
class BlockContext:
    """What :meth:`Effect.block_means` may use besides the block means themselves.

    Attributes
    ----------
    time : (n_blocks,) centre of each block from the start of the run [s]
    block_dt : the length of a block [s]
    unit_steering_response : () → (n_blocks, 4) block means of the base model's outputs for a
        constant steering-wheel angle of 1 rad (at the parameters being evaluated)
    speed : (n_blocks,) each block's mean speed [m/s] (for an effect that :attr:`Effect.reads_speed`), or None
    """

    time: np.ndarray
    block_dt: float
    unit_steering_response: Callable[[], np.ndarray]
    speed: np.ndarray | None = None


class Effect:
    """Base class. An instance holds the effect's parameter values (and channel, where it has one).

    Class attributes a subclass sets: ``name`` (the registry key), ``stage`` (one of :data:`STAGES`;
    an instance may refine it, as a steering offset is an input effect), ``syntax`` (the value of
    ``simulate --effect NAME=VALUE``), ``example`` (a valid value, used by the contract test),
    ``summary`` (one line for help texts and reports), ``channels`` (the channels it can sit on,
    empty for none), ``note`` (a caveat the diagnosis reports with the effect, or "") and ``refines``.
    """

    name: ClassVar[str]
    stage: ClassVar[str]
    syntax: ClassVar[str]
    example: ClassVar[str]
    summary: ClassVar[str]
    channels: ClassVar[tuple[str, ...]] = ()
    note: ClassVar[str] = ""
    #: the registry name of the effect this one refines with more parameters (the same law), or "": the diagnosis
    #: tries a refinement only when asked (``diagnose --effects``), as both would claim the same gap
    refines: ClassVar[str] = ""
    #: True for an effect whose block-mean form holds on short blocks only (a delay shifts the outputs in time): on
    #: longer blocks the fits apply it to every sample's outputs, then average
    #: (:data:`online_id.sim.with_effects.SHIFT_BLOCK_S`)
    short_blocks_only: ClassVar[bool] = False

    def __init__(self, channel: str | None = None, **values: float):
        self.channel = channel
        names = [p.name for p in self.fit_parameters()]
        unknown = set(values) - set(names)
        if unknown:
            raise ValueError(f"{self.name}: unknown parameter(s) {', '.join(sorted(unknown))}")
        self.values = {p.name: float(values.get(p.name, p.initial)) for p in self.fit_parameters()}

    # --- description -------------------------------------------------------------------------
    @classmethod
    def fit_parameters(cls) -> list[FitParameter]:
        raise NotImplementedError

    @classmethod
    def parse(cls, text: str) -> Effect:
        """The effect from the value part of ``NAME=VALUE`` (see :attr:`syntax`)."""
        raise NotImplementedError

    #: the measured channel an effect without a channel of its own acts on (its candidates need it in the run), or ""
    acts_on: ClassVar[str] = ""
    #: fit parameters the online filters carry as constants of the law, at their given values (not extra states;
    #: the last ones of :meth:`fit_parameters`): ``load_sensitivity``'s load exponent. The polish holds them too.
    held_online: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def candidates(cls, channels: tuple[str, ...]) -> list[Effect]:
        """Starting instances for a fit on a run with the given measured channels: none when the run lacks the
        channel the effect :attr:`acts_on`."""
        return [cls()] if not cls.acts_on or cls.acts_on in channels else []

    @classmethod
    def to_estimate(cls, text: str = "") -> Effect:
        """An instance to estimate, from the part after the name in ``--effect NAME[:CHANNEL[:VALUE]]``
        (or ``NAME=CHANNEL...``): the channel where the effect has one, an optional starting value."""
        parts = [t.strip() for t in text.split(":")] if text else []
        channel = None
        if cls.channels:
            if not parts or parts[0] not in cls.channels:
                got = f"unknown channel {parts[0]!r}" if parts else "no channel given"
                raise OnlineIdError(f"--effect {cls.name}: {got}; write {cls.name}:CHANNEL with CHANNEL one of"
                                    f" {', '.join(cls.channels)}")
            channel = parts.pop(0)
        values = {}
        if parts:
            params = cls.fit_parameters()
            if len(parts) != len(params):
                raise OnlineIdError(f"--effect {cls.name}: expected at most {len(params)} starting value(s)"
                                    f" ({', '.join(p.name for p in params)}), got {':'.join(parts)!r}")
            values = {p.name: parse_number(cls.name, v, p.name) for p, v in zip(params, parts)}
        return cls(channel=channel, **values)

    @property
    def label(self) -> str:
        return f"{self.name}({self.channel})" if self.channel else self.name

    def with_vector(self, vector) -> Effect:
        """A copy with the fit parameters set from ``vector`` (in :meth:`fit_parameters` order)."""
        values = dict(zip([p.name for p in self.fit_parameters()], np.asarray(vector, dtype=float)))
        return type(self)(channel=self.channel, **values)

    @classmethod
    def fit_bounds(cls, parameter: str) -> tuple[float, float]:
        """(lower, upper) of a fit parameter: the values it can physically have."""
        p = next(p for p in cls.fit_parameters() if p.name == parameter)
        return (p.lower, p.upper)

    def vector(self) -> np.ndarray:
        return np.array([self.values[p.name] for p in self.fit_parameters()])

    def estimate_spec(self) -> str:
        """The ``--effect`` value that estimates this effect from its current values:
        ``NAME[:CHANNEL]:VALUE...`` (what ``diagnose`` prints and ``--effects-from`` reads)."""
        parts = [self.name, *([self.channel] if self.channel else []),
                 *(f"{self.values[p.name]:.6g}" for p in self.fit_parameters())]
        return ":".join(parts)

    def has_filter_form(self, known: KnownParameters) -> bool:
        """Whether the online filters can carry this effect (:meth:`filter_states` does not refuse)."""
        try:
            self.filter_states(known)
        except OnlineIdError:
            return False
        return True

    def to_dict(self) -> dict:
        d = {"name": self.name, **self.values}
        if self.channel:
            d["channel"] = self.channel
        return d

    # --- hooks (identity by default) ---------------------------------------------------------
    def car_steering(self, logged: np.ndarray, dt: float) -> np.ndarray:
        """Steering-wheel angle the car sees, from the logged one [rad], sampled every ``dt`` [s]."""
        return logged

    def logged_steering(self, true: np.ndarray, dt: float) -> np.ndarray:
        """Inverse of :meth:`car_steering` (used by the simulator; an effect with memory, a delay, cannot
        invert the first moments of a run, whose steering came from before it)."""
        return true

    def transform_theta(self, theta: np.ndarray, known: KnownParameters) -> np.ndarray:
        """Base-model parameters that reproduce the effect exactly, where it is a re-parametrisation."""
        return theta

    def force_law(self, theta: np.ndarray, known: KnownParameters):
        """A correction to the linear tyre forces (see :mod:`online_id.sim.forces`), or None."""
        return None

    #: True for a tyre law whose axle loads follow the run's longitudinal acceleration (braking, traction): every form
    #: of it reads ``longitudinal_acceleration`` (:meth:`axle_loads`), and the force-law solver's static law does not
    #: serve it (the compiled tyre model does, :mod:`online_id.model.tyres`)
    moves_loads: ClassVar[bool] = False

    def axle_loads(self, known: KnownParameters, longitudinal_acceleration=None, speed=None) -> np.ndarray:
        """The axle loads [N] under this effect's tyre law (:meth:`tyre_mu`): static (2,) (the default), or per
        sample (n, 2) from the longitudinal acceleration (n,) [m/s²] for an effect that :attr:`moves_loads` ((n, 4)
        with each axle's longitudinal force beside its load, on the friction ellipse, or (n, 6) with each axle's
        curve scale: :func:`online_id.model.tyres._peaks`), and the speed (n,) [m/s] for one whose loads follow it
        too (``downforce``; :func:`loads_with_speed` calls a law written before the speed was passed without it)."""
        from online_id.vehicle.parameters import axle_loads

        return axle_loads(known)

    def tyre_mu(self) -> np.ndarray | None:
        """μ of each axle (2,) when this effect is the saturating tyre law of :mod:`online_id.model.tyres` (the
        online filters' and the fast fits' model), else None. Such an effect's fit parameters are its μ's."""
        return None

    def measure(self, outputs: np.ndarray, dt: float) -> np.ndarray:
        """Logged outputs (N, 4) from the true ones."""
        return outputs

    def car_lateral_acceleration(self, logged, yaw_rate, dt: float) -> np.ndarray:
        """The car's lateral acceleration at its centre of gravity (N,) [m/s²] from the ``logged`` channel, undoing
        this effect at its current values where it acts on that channel (the logged yaw rate (N,) at hand): what
        the fits judge the model's linear range by (the default: the channel as logged)."""
        return logged

    #: True for a sensor effect whose reading depends on the speed (a misaligned velocity sensor): its simulation form
    #: is :meth:`measure_at`, and its block-mean form reads :attr:`BlockContext.speed`
    reads_speed: ClassVar[bool] = False

    def measure_at(self, outputs: np.ndarray, dt: float, speed) -> np.ndarray:
        """:meth:`measure` with each sample's ``speed`` (N,) [m/s] (or one speed) at hand: what the simulation runs (the
        default ignores it)."""
        return self.measure(outputs, dt)

    def block_means(self, outputs: np.ndarray, context: BlockContext) -> np.ndarray:
        """Block means of the logged outputs (n_blocks, 4) from the model's block means (after any
        ``transform_theta`` and ``force_law``), for the batch fits. The default serves an effect
        whose input and sensor hooks are the identity; any other must override it."""
        if type(self).measure is not Effect.measure or type(self).car_steering is not Effect.car_steering:
            raise OnlineIdError(f"{self.name}: no block-mean form for this effect")
        return outputs

    def filter_states(self, known: KnownParameters) -> list[ExtraState]:
        """The effect's parameters as extra states of the online filters, in :meth:`fit_parameters`
        order. An effect without a filter form raises :class:`OnlineIdError` saying why."""
        raise OnlineIdError(f"{self.label}: this effect has no filter form; it cannot be estimated online")


def loads_with_speed(axle_loads: Callable) -> Callable:
    """``axle_loads`` (an :meth:`Effect.axle_loads`, or an :class:`ExtraState`'s) as a function of (known, a_x, speed)
    whatever its signature: an effect written before the speed was passed (a plug-in's ``axle_loads(known,
    longitudinal_acceleration=None)``) is called without it."""
    import inspect

    try:
        params = inspect.signature(axle_loads).parameters
    except (TypeError, ValueError):
        return lambda known, ax, speed=None: axle_loads(known, ax)
    if "speed" in params or any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return lambda known, ax, speed=None: axle_loads(known, ax, speed=speed)
    return lambda known, ax, speed=None: axle_loads(known, ax)


def parse_number(effect: str, text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise OnlineIdError(f"--effect {effect}: {what} must be a number, got {text!r}") from None
    if not np.isfinite(value):
        raise OnlineIdError(f"--effect {effect}: {what} must be finite, got {text!r}")
    return value


def in_stage_order(effects) -> list[Effect]:
    """The effects sorted by :attr:`Effect.stage` (input, dynamics, sensor), in their given order within a stage."""
    return sorted(effects, key=lambda e: STAGES.index(e.stage))


def parse_channel_value(effect: str, text: str, allowed: tuple[str, ...]) -> tuple[str, float]:
    channel, sep, value = text.partition(":")
    if not sep:
        raise OnlineIdError(f"--effect {effect}={text}: expected CHANNEL:VALUE with CHANNEL one of"
                            f" {', '.join(allowed)}")
    if channel not in allowed:
        raise OnlineIdError(f"--effect {effect}: unknown channel {channel!r}; choose from {', '.join(allowed)}")
    return channel, parse_number(effect, value, "the value")
