"""Does each channel belong to the car? Three low-frequency relations, and the channel that breaks two of them.

The unit and sign checks of :mod:`online_id.trust.plausibility` judge a relation's *slope* once the channels
correlate; a channel that does not correlate at all (a wrong column mapped, a sensor unplugged and logging
noise or a constant, a channel reversed in time) left them saying "not enough excitation". Yet a run that
turns the car has three relations at low frequency (two 2 s moving averages, where the car is nearly in a
steady state), each between two of the three turning channels:

- a_y ≈ V·r (kinematics: a_y = V·(β̇ + r), β̇ small at low frequency);
- r ≈ r_ss(δH), the prior model's steady-state yaw rate from the steering wheel;
- a_y ≈ V·r_ss(δH).

A channel that does not belong breaks both relations it is in and leaves the third: a_y that is noise
correlates with neither V·r nor V·r_ss while r still follows the steering. So a channel is named when its
two relations have a correlation under :data:`BROKEN_CORRELATION` (in size) while the other two channels
agree (at least :data:`AGREE_CORRELATION`) and show turning (their low-passed signals' spread at least
:data:`MIN_TURNING_SPREAD`): the excitation is there, the channel does not follow it. A channel constant
over the whole run is named as dead on less turning (:data:`MIN_DEAD_TURNING_SPREAD`). The roll angle, when
logged, is judged against a_y (once a_y is not the channel named). A failed relation is a refusal (exit
status 2) like a unit slip; ``--allow-implausible ay_follows`` (``yaw_follows``, ``steering_follows``,
``roll_follows``) accepts it.

When no two channels agree, the run cannot say which one is wrong: that is said, not refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from online_id.trust.slopes import (
    MIN_CORRELATION,
    CheckResult,
    fit_slope,
    lowpass,
    steady_yaw_gain,
)
from online_id.units import CHANNEL_UNITS

#: The check (for ``--allow-implausible``) that names each channel.
FOLLOW_CHECKS = {"lateral_acceleration": "ay_follows", "yaw_rate": "yaw_follows",
                 "steering_wheel_angle": "steering_follows", "roll_angle": "roll_follows"}
#: Two channels agree when their low-passed correlation is at least this (in size: a sign slip still
#: agrees, and the sign checks name it). Measured (``python benchmarks/plausibility_margins.py``): 0.98-1.00
#: on every relation of the clean simulated runs, 0.99-1.00 on the race-car log, 0.85-0.89 on the RAV4 log.
AGREE_CORRELATION = 0.9
#: Under this (in size) a relation is broken: the channels do not follow each other. Measured: a_y replaced
#: by noise of its spread -0.66 (20 s chirp: about ten independent 2 s windows, so chance correlations
#: are large) to -0.03 (the race car); a_y reversed in time -0.11, -0.03; a yaw-rate channel of noise or
#: of the roll rate -0.17 to 0.25.
BROKEN_CORRELATION = MIN_CORRELATION
#: Least spread (std) of both low-passed signals of the agreeing pair, as lateral accelerations [m/s²], for
#: the run to count as turning: 0.01 g. A sensor's noise, low-passed, is far under it (a_y noise of
#: 0.05 m/s² at 100 Hz leaves 0.002 m/s² after the 2 s averages); the RAV4 highway log (0.037) and a 3 deg
#: chirp (0.039) turn too little to be judged here, the 20 s built-in chirp turns 0.30, the race car 5.2.
MIN_TURNING_SPREAD = 0.1
#: A channel constant over the whole run is unambiguous (a real sensor has noise, or at least changes a
#: quantisation step as the car turns): it is named as dead once the other two agree (correlation at least
#: MIN_CORRELATION) with this much turning [m/s²], 0.002 g: enough for the RAV4 highway log (0.04, agreeing
#: at 0.89), far above a low-passed sensor noise.
MIN_DEAD_TURNING_SPREAD = 0.02
#: Lateral acceleration [m/s²] above which a sample counts as cornering in the messages (0.05 g).
CORNERING_AY = 0.49


@dataclass(frozen=True)
class Relation:
    """Correlation (low-passed) of ``a`` against ``b``, and the spread of each side [m/s² equivalent]."""

    a: str
    b: str
    correlation: float
    spread_a: float
    spread_b: float

    @property
    def agrees(self) -> bool:
        return abs(self.correlation) >= AGREE_CORRELATION

    @property
    def broken(self) -> bool:
        return abs(self.correlation) < BROKEN_CORRELATION

    @property
    def turning(self) -> bool:
        return min(self.spread_a, self.spread_b) >= MIN_TURNING_SPREAD

    @property
    def shows_a_dead_channel(self) -> bool:
        """Agreeing and turning enough to show that the third channel, constant, is dead."""
        return abs(self.correlation) >= MIN_CORRELATION and min(self.spread_a, self.spread_b) >= MIN_DEAD_TURNING_SPREAD


def _relation(a: str, b: str, x: np.ndarray, y: np.ndarray) -> Relation:
    _, corr, spread_x = fit_slope(x, y)
    ok = np.isfinite(y)
    spread_y = float(np.std(y[ok])) if ok.sum() > 1 else 0.0
    return Relation(a, b, float(corr) if np.isfinite(corr) else 0.0, spread_y, float(spread_x))


def _constant(values: np.ndarray | None) -> float | None:
    """The value of a channel that never changes (a dead sensor, a signal not mapped), else None."""
    if values is None:
        return None
    finite = values[np.isfinite(values)]
    if len(finite) < 2 or np.ptp(finite) > 0:
        return None
    return float(finite[0])


def measure(t, dH, V, r, ay, phi, known, prior) -> dict:
    """The low-frequency relations of a run (arrays (N,), SI): ``ay_vr`` (a_y against V·r), ``yaw_steer``
    (r against r_ss(δH)), ``ay_steer`` (a_y against V·r_ss(δH)), ``roll_ay`` (φ against a_y; None without
    φ), all as :class:`Relation`, spreads in m/s² (V times a yaw rate); and ``cornering_s``."""
    lp = lambda v: lowpass(t, v)  # noqa: E731
    r_ss = dH * steady_yaw_gain(known, prior, V)
    Vr, Vrss, AY = lp(V * r), lp(V * r_ss), lp(ay)
    out = {"ay_vr": _relation("lateral_acceleration", "speed × yaw_rate", Vr, AY),
           "yaw_steer": _relation("yaw_rate", "the steady-state yaw rate from steering_wheel_angle", Vrss, lp(V * r)),
           "ay_steer": _relation("lateral_acceleration", "speed × the steady-state yaw rate from"
                                 " steering_wheel_angle", Vrss, AY),
           "roll_ay": None if phi is None else _relation("roll_angle", "lateral_acceleration", AY, lp(phi))}
    out["cornering_s"] = cornering_seconds(t, V * r)
    return out


def cornering_seconds(t: np.ndarray, lateral: np.ndarray) -> float:
    """Seconds in which ``lateral`` (a lateral acceleration, or V·r [m/s²]) is over :data:`CORNERING_AY` from
    its median (an offset is not a corner)."""
    if len(t) < 2 or not np.isfinite(lateral).any():
        return 0.0
    turning = np.abs(lateral - np.nanmedian(lateral)) >= CORNERING_AY
    dt = np.diff(t)
    return float(np.sum(dt[turning[1:] & np.isfinite(dt)]))


#: The channels each relation links, and the one it leaves out (the third of the triangle).
_TRIANGLE = {"ay_vr": ("lateral_acceleration", "yaw_rate"), "yaw_steer": ("yaw_rate", "steering_wheel_angle"),
             "ay_steer": ("lateral_acceleration", "steering_wheel_angle")}
_WRONG = "wrong column, or a broken sensor?"
_DEAD = "a dead sensor, or a signal not mapped?"


def judge_relations(t, dH, V, r, ay, phi, known, prior) -> list[CheckResult]:
    """The checks of :data:`FOLLOW_CHECKS` over a run (see the module docstring); arrays (N,), SI, NaN where a
    sample lacks a channel. Raises nothing."""
    if r is None or ay is None:
        return [CheckResult(check, "absent", None, channel, f"cannot check that {channel} follows the others:"
                            " yaw rate or lateral acceleration missing")
                for channel, check in FOLLOW_CHECKS.items() if channel != "roll_angle" or phi is not None]
    m = measure(t, dH, V, r, ay, phi, known, prior)
    dead = {c: _constant(v) for c, v in (("steering_wheel_angle", dH), ("yaw_rate", r), ("lateral_acceleration", ay),
                                         ("roll_angle", phi))}
    named: dict[str, str] = {}
    for channel in ("lateral_acceleration", "yaw_rate", "steering_wheel_angle"):
        own = [k for k, pair in _TRIANGLE.items() if channel in pair]
        other = next(k for k in _TRIANGLE if k not in own)
        seen = m[other].shows_a_dead_channel if dead[channel] is not None else m[other].agrees and m[other].turning
        if all(m[k].broken for k in own) and seen:
            named[channel] = _message(channel, m, own, other, dead[channel], t, V, r, ay)
    ay_trusted = "lateral_acceleration" not in named and (m["ay_vr"].agrees or m["ay_steer"].agrees)
    roll = m["roll_ay"]
    roll_seen = MIN_DEAD_TURNING_SPREAD if dead["roll_angle"] is not None else MIN_TURNING_SPREAD
    if roll is not None and ay_trusted and roll.broken and roll.spread_b >= roll_seen:
        corner = cornering_seconds(t, ay)
        if dead["roll_angle"] is not None:
            evidence, cause = f"is constant{_value(dead['roll_angle'], 'roll_angle')}", _DEAD
        else:
            evidence = f"does not follow lateral_acceleration: correlation {roll.correlation:+.2f} at low frequency"
            cause = _WRONG
        named["roll_angle"] = (f"roll_angle {evidence} over {corner:.3g} s of cornering, while lateral_acceleration"
                               f" follows speed × yaw_rate or the steering (correlation"
                               f" {max(m['ay_vr'].correlation, m['ay_steer'].correlation):+.2f}); {cause}")

    turning = any(m[k].turning for k in _TRIANGLE)
    quiet = (f"not enough turning to check that each channel follows the others (low-passed speed × yaw_rate"
             f" spread {m['ay_vr'].spread_b:.2g} m/s², speed × steady-state yaw rate from the steering"
             f" {m['ay_steer'].spread_b:.2g} m/s², lateral_acceleration {m['ay_vr'].spread_a:.2g} m/s²; needs"
             f" {MIN_TURNING_SPREAD:g})")
    nobody = None
    if not named and turning and not any(m[k].agrees for k in _TRIANGLE):
        nobody = ("steering_wheel_angle, yaw_rate and lateral_acceleration do not follow each other at low frequency"
                  " (correlations: " + ", ".join(f"{m[k].a} with {m[k].b} {m[k].correlation:+.2f}" for k in _TRIANGLE)
                  + "): cannot tell which channel is wrong")
    results = []
    for channel, check in FOLLOW_CHECKS.items():
        if channel == "roll_angle" and phi is None:
            continue
        if channel in named:
            results.append(CheckResult(check, "failed", None, channel, named[channel]))
        elif nobody is not None:
            results.append(CheckResult(check, "not judged", None, channel, nobody))
        elif channel == "roll_angle" and not ay_trusted:
            results.append(CheckResult(check, "skipped", None, channel,
                                       "roll_angle not checked against lateral_acceleration: a_y itself is in doubt"))
        elif not turning or (channel == "roll_angle" and roll.spread_b < MIN_TURNING_SPREAD):
            results.append(CheckResult(check, "not judged", None, channel, quiet))
        else:
            corr = ", ".join(f"{m[k].a} with {m[k].b} {m[k].correlation:+.2f}" for k in (
                ["roll_ay"] if channel == "roll_angle" else [k for k, pair in _TRIANGLE.items() if channel in pair]))
            results.append(CheckResult(check, "ok", None, channel, f"{channel} follows the others: {corr}"))
    return results


def _value(value: float | None, channel: str) -> str:
    return "" if value is None else f" ({value:.6g} {CHANNEL_UNITS[channel]})"


def _message(channel: str, m: dict, own: list[str], other: str, dead: float | None, t, V, r, ay) -> str:
    """One line: the channel, what it does not follow with the correlations, the pair that does, the cause."""
    partners = {"lateral_acceleration": "speed × yaw_rate or the steering",
                "yaw_rate": "the steering or lateral_acceleration / speed",
                "steering_wheel_angle": "yaw_rate or lateral_acceleration"}[channel]
    a, b = _TRIANGLE[other]
    corner = cornering_seconds(t, V * r if channel == "lateral_acceleration" else ay)
    if dead is not None:
        what = f"is constant{_value(dead, channel)} over the whole run"
        cause = _DEAD
    else:
        corr = " and ".join(f"{m[k].correlation:+.2f}" for k in own)
        what = f"does not follow {partners}: correlation {corr} at low frequency"
        cause = _WRONG
    return (f"{channel} {what}, while {a} and {b} agree (correlation {m[other].correlation:+.2f}) over"
            f" {corner:.3g} s of cornering; {cause}")
