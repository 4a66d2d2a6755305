"""The effect contract, checked the same way for every entry of the registry :data:`EFFECTS`.

Each effect must declare itself (name, stage, syntax, example, summary), give fit parameters that
make sense, parse its own example, and provide its three forms consistently: the block-mean form
the fits use equals the full-rate simulation averaged over blocks, and the filter form (where it
has one) reproduces the simulation to first order; where it has none it says so in a one-line
OnlineIdError. Nothing outside ``online_id/effects`` may name a concrete effect class.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from online_id.effects import EFFECTS, Effect, ExtraState, parse_effect, parse_effect_to_estimate
from online_id.effects.base import STAGES, in_stage_order
from online_id.errors import OnlineIdError
from online_id.filters.augment import Augmentation
from online_id.model.lateral import OUTPUT_NAMES
from online_id.sim.simulator import SensorNoise, propagate, simulate
from online_id.sim.with_effects import BlockPredictor, predict
from online_id.vehicle.loader import load_vehicle
from online_id.vehicle.parameters import axle_loads

VEHICLE = load_vehicle("haro2008")
_VY = OUTPUT_NAMES.index("lateral_velocity")
THETA = VEHICLE.truth("track")
NAMES = list(EFFECTS)
#: Largest difference allowed between filter form and simulation, relative to each channel's spread.
FIRST_ORDER_TOLERANCE = 5e-3


@pytest.fixture(scope="module")
def run():
    return simulate(VEHICLE, THETA, duration_s=6.0, noise=SensorNoise.none()).run


def _example(name) -> Effect:
    return parse_effect(f"{name}={EFFECTS[name].example}")


@pytest.mark.parametrize("name", NAMES)
def test_declares_itself(name):
    cls = EFFECTS[name]
    assert cls.name == name
    assert cls.stage in STAGES
    for attr in ("syntax", "example", "summary"):
        assert isinstance(getattr(cls, attr), str) and getattr(cls, attr).strip(), attr
    assert isinstance(cls.note, str)
    assert isinstance(cls.channels, tuple)
    params = cls.fit_parameters()
    assert params and len({p.name for p in params}) == len(params)
    for p in params:
        assert p.lower <= p.initial <= p.upper and p.scale > 0 and p.unit


@pytest.mark.parametrize("name", NAMES)
def test_parses_its_example_and_round_trips_its_vector(name):
    e = _example(name)
    assert isinstance(e, EFFECTS[name]) and e.stage in STAGES
    assert (e.channel in e.channels) if e.channels else e.channel is None
    assert e.to_dict()["name"] == name and e.label.startswith(name)
    v = e.vector() * 1.5 + 0.01
    assert np.allclose(e.with_vector(v).vector(), v) and e.with_vector(v).channel == e.channel
    for c in e.candidates(("yaw_rate", "roll_angle", "lateral_acceleration")):
        assert isinstance(c, EFFECTS[name]) and ((c.channel in c.channels) if c.channels else c.channel is None)


@pytest.mark.parametrize("name", NAMES)
def test_effect_to_estimate_takes_its_channel_and_refuses_a_wrong_one(name):
    cls = EFFECTS[name]
    if cls.channels:
        e = parse_effect_to_estimate(f"{name}:{cls.channels[0]}")
        assert e.channel == cls.channels[0]
        with pytest.raises(OnlineIdError, match="CHANNEL"):
            parse_effect_to_estimate(name)
        with pytest.raises(OnlineIdError, match="unknown channel 'speed'"):
            parse_effect_to_estimate(f"{name}:speed")
    else:
        assert parse_effect_to_estimate(name).channel is None
    with pytest.raises(OnlineIdError, match="unknown effect 'warp'"):
        parse_effect_to_estimate("warp:yaw_rate")


#: An input effect with memory (a steering delay) cannot invert the first moments of a run, whose steering
#: came from before it: the inversion is checked after these seconds (longer than any delay's upper bound).
LEAD_IN_S = 0.3


@pytest.mark.parametrize("name", NAMES)
def test_simulation_form_changes_the_logged_run_and_inverts_its_steering(name, run):
    e = _example(name)
    dH = run.steering_wheel_angle
    after = int(LEAD_IN_S / 1e-3)
    assert np.allclose(e.car_steering(e.logged_steering(dH, 1e-3), 1e-3)[after:], dH[after:])
    _, with_effect = predict(THETA.to_vector(), [e], VEHICLE.known, dH, run.speed, 1e-3)
    _, base = predict(THETA.to_vector(), [], VEHICLE.known, dH, run.speed, 1e-3)
    assert np.max(np.abs(with_effect - base) / base.std(axis=0)) > 1e-3


@pytest.mark.parametrize("kind", ["hold", "cubic"])
@pytest.mark.parametrize("name", NAMES)
def test_block_mean_form_equals_the_full_simulation_averaged(name, kind, run):
    """For the steering held over each sample and for the cubic between samples (online_id/model/intersample.py):
    the block-mean form (the base model's exact block means, the unit-steering response, a force law solved at
    full rate) against the full-rate simulation with the same steering, averaged."""
    e = _example(name)
    bp = BlockPredictor(VEHICLE.known, run.steering_wheel_angle, run.speed, 1e-3, 10, intersample=kind)
    _, full = predict(THETA.to_vector(), [e], VEHICLE.known, run.steering_wheel_angle, run.speed, 1e-3,
                      intersample=kind)
    full_blocks = full[: bp.sim.n_used].reshape(-1, 10, 5).mean(axis=1)
    fast = bp.outputs(THETA.to_vector(), [e])
    assert np.max(np.abs(fast - full_blocks) / full_blocks.std(axis=0)) < 5e-4


@pytest.mark.parametrize("name", NAMES)
def test_filter_form_reproduces_the_simulation_or_says_why_not(name, run):
    """The extra states at the example's values, put into the base model the way the filters do
    (δ + g·e into the dynamics, C x + D δ + M e + Σ e K x out, a lagged channel read e later), give the
    effect's logged outputs."""
    e = _example(name)
    try:
        states = e.filter_states(VEHICLE.known)
    except OnlineIdError as exc:
        assert name in str(exc) and "\n" not in str(exc)
        return
    # one state a fit parameter, but those the filters carry as constants (the last ones)
    assert [s.parameter for s in states] == [p.name for p in e.fit_parameters()][:len(states)]
    assert len(states) == len(e.fit_parameters()) - len(e.held_online)
    assert all(isinstance(s, ExtraState) and s.prior_std > 0 and s.random_walk >= 0 for s in states)
    aug = Augmentation(states)
    values = e.vector()[:len(states)]
    shift = aug.steering_shift(values)
    i_s = VEHICLE.known.steering_ratio
    dH = run.steering_wheel_angle
    if aug.has_tyres:  # μ acts through the saturating law: the filters' nonlinear model (online_id/model/tyres.py)
        # (a law whose loads move reads each sample's a_x, here dV/dt = 0 as predict takes it, and speed)
        loads = (aug.axle_loads(VEHICLE.known, np.zeros(len(dH)), speed=run.speed) if aug.moves_loads else
                 np.broadcast_to(axle_loads(VEHICLE.known), (len(dH), 2)))
        x, y = _propagate_tyres(aug.axle_mu(values), (dH + shift * i_s) / i_s, run.speed, loads)
    else:
        x, y = propagate(THETA, VEHICLE.known, dH + shift * i_s, run.speed, 1e-3)
    extra = aug.output_offset(values) + x @ aug.output_matrix(values).T
    extra[:, _VY] *= run.speed  # (the filters' lateral velocity is per unit speed, β: its terms in m/s are V times)
    y_filter = y + extra
    lags, _ = aug.channel_lags(values)  # the filter reads channel c at t + lag: it sees the model's y_c(t − lag)
    t = run.time - run.time[0]
    for c in np.flatnonzero(lags):
        y_filter[:, c] = np.interp(t - lags[c], t, y_filter[:, c], left=0.0)
    _, y_effect = predict(THETA.to_vector(), [e], VEHICLE.known, dH, run.speed, 1e-3)
    # first order: a filter form linear in φ (accelerometer_gravity) misses a_y·φ²/2 ≈ 0.2 % of a_y's spread
    # at this run's peak roll; an exact form (offsets) agrees to round-off
    assert np.max(np.abs(y_filter - y_effect) / y_effect.std(axis=0)) < FIRST_ORDER_TOLERANCE


def _propagate_tyres(mu, delta, speed, loads, dt=1e-3):
    """States and outputs of the filters' model with saturating tyres (μ per axle) over a run, each sample's axle
    loads ``loads`` (n, ·) held over the step into the next (as the filters hold them)."""
    from online_id.model import tyres

    kn, th = tyres.known_array(VEHICLE.known), THETA.to_vector()[None]
    loads = np.ascontiguousarray(loads, dtype=float)
    mus = np.asarray(mu, dtype=float)[None]
    X, xs, ys = np.zeros((1, 6)), np.empty((len(delta), 6)), np.empty((len(delta), 5))
    for k in range(len(delta)):
        if k:
            X = tyres.step_points(X, th, mus, loads[k - 1], delta[k - 1:k], speed[k - 1], dt, kn)
        xs[k] = X[0]
        ys[k] = tyres.output_points(X, th, mus, loads[k], delta[k:k + 1], speed[k], kn)[0]
        ys[k, 4] *= speed[k]  # (the filters' lateral velocity is per unit speed: v_y = V β)
    return xs, ys


def test_stage_order_puts_input_before_dynamics_before_sensor():
    effects = [_example(n) for n in NAMES]
    stages = [e.stage for e in in_stage_order(effects)]
    assert stages == sorted(stages, key=STAGES.index)


def test_nothing_outside_effects_names_a_concrete_effect_class():
    """A branch on a concrete class outside the registry means the contract misses a hook."""
    root = Path(__file__).resolve().parents[1]
    classes = [cls.__name__ for cls in EFFECTS.values()]
    offenders = []
    for path in (root / "online_id").rglob("*.py"):
        if "effects" in path.relative_to(root / "online_id").parts[:1]:
            continue
        text = path.read_text(encoding="utf-8")
        offenders += [f"{path.relative_to(root)}: {c}" for c in classes if c in text]
    assert not offenders, offenders
