"""Load transfer (issue 38, item 2): the saturating tyres' axle loads moved by braking and traction.

The acceptance run is made here, by this file's own equations (MODEL.md's eqs 7-11 with tanh tyres whose peak
force is μ_i times the axle load of the body-fixed longitudinal acceleration a_x = dV/dt − V·β·r, integrated by
scipy's DOP853 to 1e-10; not online_id's simulator, which takes the loads of a first pass): a car braking and
accelerating through a slalom at up to 0.7 g lateral and 0.3 g longitudinal, logged at 100 Hz with its
``longitudinal_acceleration``. ``diagnose --validate`` must name ``load_transfer``, and ``estimate --effects-from``
its diagnosis must get the 8 within 3 % and each μ within 5 %, with the verdict consistent.
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from online_id.effects import EFFECTS
from online_id.errors import OnlineIdError
from online_id.io.tracklog import TrackRun, write_track_run
from online_id.model import tyres
from online_id.sim.maneuvers import SpeedProfile
from online_id.sim.with_effects import predict
from online_id.vehicle import load_vehicle
from online_id.vehicle.parameters import MIN_LOAD_SHARE, axle_loads, axle_loads_at

CAR = load_vehicle("haro2008")
K = CAR.known
TRUTH = CAR.truth("track")
MU = (0.8, 0.85)
G = 9.81
#: braking from 100 to 70 km/h and back every 12 s: up to 0.29 g either way
SLALOM_SPEED = "0:100,6:70,12:100,18:70,24:100,30:70,36:100,42:70,48:100,54:70,60:100"
NOISE = {"yaw_rate": 0.004, "roll_angle": 0.0005, "roll_rate": 0.002, "lateral_acceleration": 0.05,
         "longitudinal_acceleration": 0.05, "speed": 0.02}


def braking_slalom(seed: int, *, amplitude_deg: float = 40.0, duration_s: float = 60.0, rate_hz: float = 100.0,
                   top_hz: float = 3.0, combined: bool = False, exponent: float | None = None,
                   downforce: float = 0.0) -> TrackRun:
    """The car of this file's own equations (module docstring) through a 0.2-``top_hz`` Hz steering sweep at
    ``amplitude_deg`` while braking and accelerating (:data:`SLALOM_SPEED`), logged at ``rate_hz`` with noise.
    ``combined``: each axle's braking or driving force (M·a_x, 60 % on the front when braking, all on the rear
    under traction) takes its share of the friction circle, the peak √((μFz)² − Fx²), at least 20 % of μFz.
    ``exponent`` p (``load_sensitivity``'s law): each axle's whole static curve scaled by k·s, k = (Fz/Fz⁰)^p and
    s = √(1 − (Fx/(k·μ·Fz⁰))²) (at least 0.2), the loads with ``downforce`` c·Fz⁰·(V/50 m/s)² added."""
    th = TRUTH
    M, ms, Mxz, h0, h1, h2, l1, l2, e1, e2 = K.M, K.ms, K.Mxz, K.h0, K.h1, K.h2, K.l1, K.l2, K.eps1, K.eps2
    L = l1 + l2
    profile = SpeedProfile.parse(SLALOM_SPEED)
    amp = np.deg2rad(amplitude_deg) / K.steering_ratio
    rate = np.log(top_hz / 0.2) / duration_s  # an exponential sweep: as many cycles of each octave

    def delta(t):
        return amp * np.sin(2 * np.pi * 0.2 * (np.exp(rate * t) - 1) / rate)

    def forces(x, V, dV):
        r, beta, alpha = x[0], x[1], x[4:6]
        ax = dV - V * beta * r  # the body-fixed longitudinal acceleration at the CG
        Fz = np.array([M * (G * l2 - ax * K.hg) / L, M * (G * l1 + ax * K.hg) / L])
        D = np.array([th.D1, th.D2])
        if exponent is not None:
            static = np.array([M * G * l2 / L, M * G * l1 / L])
            Fz = np.maximum(Fz + downforce * static * (V / 50.0) ** 2, 0.05 * static)
            k = (Fz / static) ** exponent
            front = 0.6 if ax < 0 else 0.0
            Fx = np.array([front, 1.0 - front]) * M * ax
            full = np.array(MU) * static
            s = np.maximum(np.sqrt(np.maximum(1.0 - (Fx / (k * full)) ** 2, 0.0)), 0.2)
            return -k * s * full * np.tanh(D * alpha / full), ax
        peak = np.array(MU) * Fz
        if combined:
            front = 0.6 if ax < 0 else 0.0
            Fx = np.array([front, 1.0 - front]) * M * ax
            peak = np.maximum(np.sqrt(np.maximum(peak ** 2 - Fx ** 2, 0.0)), 0.2 * peak)
        return -peak * np.tanh(D * alpha / peak), ax

    def rhs(t, x):
        r, beta, phi, p, a1, a2 = x
        V, dV = float(profile.speed(t)), float(profile.acceleration(t))
        (F1, F2), _ = forces(x, V, dV)
        # [roll; yaw; lateral] in (ṙ, β̇, ṗ), MODEL.md eqs 7-9
        E = np.array([[-Mxz, -ms * h0 * V, th.Mxx + ms * h0 ** 2],
                      [th.Mzz, 0.0, -Mxz],
                      [0.0, M * V, -ms * h0]])
        b = np.array([-th.Kro * phi - th.Aro * p + ms * h0 * V * r,
                      l1 * F1 - l2 * F2,
                      F1 + F2 - M * V * r])
        rd, bd, pd = np.linalg.solve(E, b)
        a1d = (V * beta - V * a1 + h1 * p + l1 * r - V * e1 * phi - V * delta(t)) / th.b1  # eqs 10-11
        a2d = (V * beta - V * a2 + h2 * p - l2 * r - V * e2 * phi) / th.b2
        return np.array([rd, bd, p, pd, a1d, a2d])

    t = np.arange(int(duration_s * rate_hz)) / rate_hz
    sol = solve_ivp(rhs, (0.0, t[-1]), np.zeros(6), method="DOP853", t_eval=t, rtol=1e-10, atol=1e-12)
    assert sol.success, sol.message
    X = sol.y.T
    V, dV = profile.speed(t), profile.acceleration(t)
    ay = np.array([V[k] * (rhs(t[k], X[k])[1] + X[k, 0]) for k in range(len(t))])
    ax = dV - V * X[:, 1] * X[:, 0]
    rng = np.random.default_rng(seed)

    def noisy(v, name):
        return v + NOISE[name] * rng.standard_normal(len(v))

    return TrackRun(time=t, steering_wheel_angle=K.steering_ratio * delta(t), speed=noisy(V, "speed"),
                    yaw_rate=noisy(X[:, 0], "yaw_rate"), lateral_acceleration=noisy(ay, "lateral_acceleration"),
                    roll_angle=noisy(X[:, 2], "roll_angle"), roll_rate=noisy(X[:, 3], "roll_rate"),
                    longitudinal_acceleration=noisy(ax, "longitudinal_acceleration"), source="braking slalom")


def test_axle_loads_move_forward_under_braking_by_m_ax_hg_over_l_and_keep_their_sum():
    ax = np.array([-5.0, 0.0, 3.0, -200.0])
    loads = axle_loads_at(K, ax)
    static = axle_loads(K)
    L = K.l1 + K.l2
    np.testing.assert_allclose(loads[1], static)
    np.testing.assert_allclose(loads[0] - static, [K.M * 5.0 * K.hg / L, -K.M * 5.0 * K.hg / L])
    np.testing.assert_allclose(loads[:3].sum(axis=1), K.M * G * np.ones(3), rtol=1e-3)  # (the package's g: 9.80665)
    assert loads[3, 1] == pytest.approx(MIN_LOAD_SHARE * static[1])  # a 20 g stop: the rear lifts, held at 5 %


def test_without_longitudinal_acceleration_the_effect_is_the_axles_law_bit_for_bit():
    """At a_x = 0 the loads are static: ``load_transfer`` is ``tire_saturation_axles``; a run's loads per sample
    through the compiled kernels give what static loads give (the wrappers tile them)."""
    rng = np.random.default_rng(0)
    n, dt = 3000, 0.01
    steering = np.deg2rad(60) * np.sin(2 * np.pi * 0.7 * np.arange(n) * dt) + 0.01 * rng.standard_normal(n)
    speed = np.full(n, 25.0)
    theta = TRUTH.to_vector()
    moved = predict(theta, [EFFECTS["load_transfer"](mu_front=0.8, mu_rear=0.85)], K, steering, speed, dt,
                    method="rk4", longitudinal_acceleration=np.zeros(n))
    static = predict(theta, [EFFECTS["tire_saturation_axles"](mu_front=0.8, mu_rear=0.85)], K, steering, speed, dt,
                     method="rk4")
    np.testing.assert_array_equal(moved[1], static[1])
    # braking moves the outputs: the front gains grip, the car turns in harder
    braking = predict(theta, [EFFECTS["load_transfer"](mu_front=0.8, mu_rear=0.85)], K, steering, speed, dt,
                      method="rk4", longitudinal_acceleration=np.full(n, -3.0))
    assert np.abs(braking[1] - static[1]).max() > 0.01
    with pytest.raises(ValueError, match="axle loads of shape"):
        tyres.per_sample_loads(np.ones((n - 1, 2)), n)


def test_the_effect_needs_a_longitudinal_acceleration_and_a_cg_height():
    effect = EFFECTS["load_transfer"](mu_front=0.8, mu_rear=0.85)
    with pytest.raises(OnlineIdError, match="longitudinal acceleration"):
        effect.axle_loads(K, None)
    with pytest.raises(OnlineIdError, match="CG height hg"):
        effect.axle_loads(replace(K, hg=0.0), np.zeros(3))


def slalom_logs(folder, seeds, **law):
    """The training and held-out braking slaloms of a car with the tyre ``law`` (:func:`braking_slalom`'s keywords)
    written as ``train.csv`` and ``held.csv`` in ``folder`` (the held-out run steered less and slower); the training
    run."""
    run = braking_slalom(seed=seeds[0], **law)
    write_track_run(run, folder / "train.csv")
    write_track_run(braking_slalom(seed=seeds[1], amplitude_deg=36.0, top_hz=2.5, **law), folder / "held.csv")
    return run


@pytest.fixture(scope="module")
def slalom(tmp_path_factory):
    folder = tmp_path_factory.mktemp("slalom")
    return folder, slalom_logs(folder, (1, 2))


def _cli(*args, timeout=900):
    done = subprocess.run([sys.executable, "-m", "online_id.cli.main", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout)
    assert done.returncode == 0, done.stderr[-3000:]
    return done


def carried(folder, diag, filt: str, effect: str, *args) -> dict:
    """``estimate train.csv --effects-from diag --filter filt`` (more ``args``) in ``folder``: its JSON, checked to be
    consistent, the 8 within 3 % of the truth and ``effect``'s μ within 5 % of :data:`MU`."""
    res = folder / f"{filt}.json"
    _cli("estimate", folder / "train.csv", "--effects-from", diag, "--filter", filt, "--json", res, "--quiet", *args)
    r = json.loads(res.read_text())
    assert r["consistency"]["consistent"] is True, (filt, r["consistency"])
    values = np.array([r["parameters"][n]["value"] for n in ("Mzz", "Mxx", "D1", "D2", "Aro", "Kro", "b1", "b2")])
    np.testing.assert_allclose(values, TRUTH.to_vector(), rtol=0.03, err_msg=filt)
    mu = r["effects"][effect]
    np.testing.assert_allclose([mu["mu_front"]["value"], mu["mu_rear"]["value"]], MU, rtol=0.05, err_msg=filt)
    return r


def test_the_slalom_run_is_what_the_issue_asks(slalom):
    _, run = slalom
    assert 0.65 * G < np.abs(run.lateral_acceleration).max() < 0.85 * G
    assert run.longitudinal_acceleration.min() < -0.25 * G and run.longitudinal_acceleration.max() > 0.25 * G


def test_diagnose_names_load_transfer_and_the_filters_carry_it(slalom):
    """Issue 38's acceptance: the diagnosis names the load transfer on a run it did not fit; the EKF and the UKF
    carrying it from the diagnosis get the 8 within 3 % and μ within 5 %, consistent. (Measured: μ 0.801/0.849
    named, held-out cost −91 % after −52 % for one μ and +0.8 % for a μ per axle; the filters within 0.2 %.)"""
    folder, _ = slalom
    diag = folder / "diag.json"
    out = _cli("diagnose", folder / "train.csv", "--validate", folder / "held.csv", "--json", diag).stdout
    assert "load_transfer" in out
    d = json.loads(diag.read_text())
    assert [c.split(":")[0] for c in d["carry"]["online"]] == ["load_transfer"], d["carry"]
    step = next(st for st in d["refinements"] if st.get("tried") == "load_transfer")
    assert step["significant"] and step["reduction"] > 0.5, step
    np.testing.assert_allclose([step["parameters"]["mu_front"], step["parameters"]["mu_rear"]], MU, rtol=0.05)
    for filt in ("ekf", "ukf"):
        carried(folder, diag, filt, "load_transfer", "--no-polish")


def test_every_source_carries_the_longitudinal_acceleration_to_the_samples(tmp_path, slalom):
    """A table, an MDF file (channels by name, units converted) and the array path give the filters the logged a_x;
    an MDF's lateral velocity comes through too (both were left out of an MDF's units until now: a KeyError)."""
    from asammdf import MDF, Signal
    from online_id.drivers.sources import open_source

    from online_id.stream.samples import SampleArrays

    _, run = slalom
    first = slice(0, 500)
    run = replace(run, time=run.time[first], steering_wheel_angle=run.steering_wheel_angle[first],
                  speed=run.speed[first], yaw_rate=run.yaw_rate[first], roll_angle=None, roll_rate=None,
                  lateral_acceleration=run.lateral_acceleration[first],
                  longitudinal_acceleration=run.longitudinal_acceleration[first])
    arrays = SampleArrays.from_run(run)
    np.testing.assert_array_equal(arrays.longitudinal_acceleration, run.longitudinal_acceleration)
    assert arrays.sample(7).longitudinal_acceleration == run.longitudinal_acceleration[7]
    assert SampleArrays.from_samples(list(arrays)).longitudinal_acceleration.tolist() == \
        run.longitudinal_acceleration.tolist()
    t = run.time
    mdf = MDF()
    mdf.append([Signal(np.rad2deg(run.steering_wheel_angle), t, name="steering_wheel_angle", unit="deg"),
                Signal(run.speed * 3.6, t, name="speed", unit="km/h"),
                Signal(run.yaw_rate, t, name="yaw_rate", unit="rad/s"),
                Signal(run.lateral_acceleration, t, name="lateral_acceleration", unit="m/s^2"),
                Signal(run.longitudinal_acceleration / 9.80665, t, name="longitudinal_acceleration", unit="g"),
                Signal(3.6 * 0.01 * run.speed, t, name="lateral_velocity", unit="km/h")])
    path = tmp_path / "logger.mf4"
    mdf.save(str(path), overwrite=True)
    got = list(open_source(path))
    assert len(got) == len(run)
    np.testing.assert_allclose([s.longitudinal_acceleration for s in got], run.longitudinal_acceleration, rtol=1e-12)
    np.testing.assert_allclose([s.lateral_velocity for s in got], 0.01 * run.speed, rtol=1e-12)


def test_without_the_column_the_loads_take_the_speeds_slope_and_say_so(slalom, tmp_path):
    """A log without ``longitudinal_acceleration``: the filter's loads take dV/dt of the logged speed (smoothed,
    causal), said in the events line; from μ's default start the 8 within 3 % and μ within 5 %, consistent
    (measured: worst parameter 0.44 %, μ 0.800/0.850)."""
    _, run = slalom
    log = tmp_path / "no_ax.csv"
    write_track_run(replace(run, longitudinal_acceleration=None), log)
    res = tmp_path / "no_ax.json"
    out = _cli("estimate", log, "--effect", "load_transfer", "--no-polish", "--json", res).stdout
    assert "longitudinal acceleration from speed: 6000" in out
    r = json.loads(res.read_text())
    assert r["consistency"]["consistent"] is True, r["consistency"]
    values = np.array([r["parameters"][n]["value"] for n in ("Mzz", "Mxx", "D1", "D2", "Aro", "Kro", "b1", "b2")])
    np.testing.assert_allclose(values, TRUTH.to_vector(), rtol=0.03)
    mu = r["effects"]["load_transfer"]
    np.testing.assert_allclose([mu["mu_front"]["value"], mu["mu_rear"]["value"]], MU, rtol=0.05)


@pytest.fixture(scope="module")
def combined(tmp_path_factory):
    folder = tmp_path_factory.mktemp("combined")
    slalom_logs(folder, (3, 4), combined=True)
    return folder


def test_combined_slip_is_named_down_the_chain_and_carried(combined):
    """The same slalom with each axle's braking or driving force on the friction circle (60 % front braking, rear
    drive: the vehicle file's defaults): the diagnosis goes one μ → (a μ per axle, not kept) → load transfer (kept)
    → combined slip (kept), and the filters carrying it get the 8 within 3 % and μ within 5 %, consistent.
    (Measured: held-out cost −40 % for the loads, then −74 % more; μ 0.799/0.850; EKF worst parameter 0.23 %, UKF
    0.15 %.)"""
    diag = combined / "diag.json"
    _cli("diagnose", combined / "train.csv", "--validate", combined / "held.csv", "--json", diag)
    d = json.loads(diag.read_text())
    assert [c.split(":")[0] for c in d["carry"]["online"]] == ["combined_slip"], d["carry"]
    kept = [(st["tried"], st["significant"]) for st in d["refinements"] if "tried" in st]
    assert kept[1:3] == [("load_transfer", True), ("combined_slip", True)], kept
    # the chain goes on to the laws whose whole curve follows the load: not this car's, not kept
    assert kept[3:] == [("load_sensitivity", False), ("downforce", False)], kept
    for filt in ("ekf", "ukf"):
        carried(combined, diag, filt, "combined_slip", "--no-polish")


def test_the_friction_ellipse_takes_the_longitudinal_force_from_the_peak():
    """peak √((μFz)² − Fx²) with its μ-derivative μFz²/peak (the polish's and the EKF's sensitivity), at least 20 %
    of μFz; without a longitudinal force the static law bit for bit (the kernels' loads of 2 or 4 columns)."""
    from online_id.model.tyres import MIN_PEAK_SHARE, _peaks

    mu = np.array([0.9, 1.1])
    peak, dpeak = np.empty(4), np.empty(4)  # (peaks, then each curve's scale: 1 in this law)
    _peaks(mu, np.array([4000.0, 5000.0, -1800.0, 0.0]), peak, dpeak)
    assert list(peak[2:]) == [1.0, 1.0] and list(dpeak[2:]) == [0.0, 0.0]
    peak, dpeak = peak[:2], dpeak[:2]
    assert peak[0] == pytest.approx(np.sqrt((0.9 * 4000) ** 2 - 1800 ** 2)) and peak[1] == 1.1 * 5000
    h = 1e-7
    up = np.empty(4)
    _peaks(mu + h, np.array([4000.0, 5000.0, -1800.0, 0.0]), up, np.empty(4))
    np.testing.assert_allclose((up[:2] - peak) / h, dpeak, rtol=1e-5)
    both = np.empty(4)
    _peaks(mu, np.array([4000.0, 5000.0, 3900.0, 0.0]), both, np.empty(4))
    assert both[0] == pytest.approx(MIN_PEAK_SHARE * 0.9 * 4000)
    effect = EFFECTS["combined_slip"](mu_front=0.9, mu_rear=1.1)
    loads = effect.axle_loads(K, np.array([-3.0, 0.0, 2.0]))
    np.testing.assert_allclose(loads[:, :2], axle_loads_at(K, [-3.0, 0.0, 2.0]))
    np.testing.assert_allclose(loads[:, 2:], [[-0.6 * K.M * 3, -0.4 * K.M * 3], [0, 0], [0, K.M * 2]])


def test_a_can_signal_map_brings_lateral_velocity_and_longitudinal_acceleration(tmp_path):
    """A map naming them (here on online-id's own roll frame's two signals, as a logger's CAN channels would be)
    gives them to the samples: the frame assembler left the lateral velocity out until now."""
    import cantools
    from online_id.drivers.assembler import FrameAssembler
    from online_id.drivers.frames import frames_from_run
    from online_id.drivers.signal_map import builtin_dbc_path, builtin_map_path, load_signal_map

    from online_id.sim.simulator import simulate

    text = builtin_map_path("online_id").read_text()
    text = text.replace("[signals.roll_angle]", "[signals.lateral_velocity]").replace(
        "[signals.roll_rate]", "[signals.longitudinal_acceleration]")
    (tmp_path / "online_id.dbc").write_bytes(builtin_dbc_path().read_bytes())
    (tmp_path / "map.toml").write_text(text)
    run = simulate(CAR, TRUTH, duration_s=0.5, rate_hz=100.0, seed=1).run
    assembler = FrameAssembler(cantools.database.load_file(str(builtin_dbc_path())),
                               load_signal_map(tmp_path / "map.toml"))
    samples = [s for s in (assembler.feed(m) for m in frames_from_run(run)) if s is not None]
    assert len(samples) == len(run)
    np.testing.assert_allclose([s.lateral_velocity for s in samples], run.roll_angle, atol=1e-7)
    np.testing.assert_allclose([s.longitudinal_acceleration for s in samples], run.roll_rate, atol=1e-6)
    assert all(s.roll_angle is None for s in samples)
