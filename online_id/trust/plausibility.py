"""Are the inputs physically plausible?  Unit and sign slips caught before they become parameters.

A log with the speed in km/h, the yaw rate with the SAE sign, the lateral acceleration in g or the
steering-wheel angle in degrees passes every format check and still gives precise, wrong parameters.
These checks compare the channels with each other and with the prior model, at low frequency where
the car is nearly in a steady state and the relations are simple:

``ay_slope`` and ``speed_unit``
    In a steady turn a_y = V·(β̇ + r) ≈ V·r.  The slope s of a_y regressed on V·r (both low-passed,
    with an intercept that absorbs an accelerometer offset) is about 1.  s ≈ −1: a_y or r has the
    other sign (SAE: positive to the right); s ≈ 1/9.81: a_y in g; s ≈ 1/3.6 (1/2.237): speed in km/h
    (mph), reported as ``speed_unit``; s ≈ 1/57.3: yaw rate in deg/s.
``yaw_sign`` and ``steering_gain``
    The yaw rate against the steady-state yaw rate the prior model predicts from the steering wheel,
    r_ss = δH/i_s · V / (L·(1 + K·V²)) with K = M·(l2/D1 − l1/D2)/L² (understeer gradient, s²/m²).
    The slope g of r on r_ss is about 1 (within a factor :data:`STEERING_GAIN_FACTOR`: the prior is
    rough).  g < 0: yaw rate or steering-wheel angle has the other sign (``yaw_sign``); g ≈ 1/57.3:
    steering in degrees; g ≈ i_s: the road-wheel angle logged as the steering-wheel angle; g ≈ 57.3:
    yaw rate in deg/s (``steering_gain``).
``roll``
    When a roll angle is logged: in ISO 8855 a left turn (a_y > 0) rolls the body to positive φ, so
    φ against V·r has a positive slope of a few degrees per g; negative means the other sign, over
    :data:`ROLL_GRADIENT_MAX` means degrees.
``magnitude``
    Per sample, the size limits of the track-run reader (:data:`online_id.io.tracklog.UNIT_LIMITS`):
    the CSV reader applies them to a file, :func:`check_sample_magnitude` to a CAN stream.

``ay_follows``, ``yaw_follows``, ``steering_follows`` and ``roll_follows``
    A channel that does not belong to the car at all (a wrong column mapped, a sensor unplugged logging
    noise or a constant, a channel reversed in time): it follows none of the others while they agree and
    the car turns (:mod:`online_id.trust.relations`). The unit and sign checks on it are then skipped.

A check is judged only when the run excites it (low-passed signal spread and correlation over the
thresholds below); otherwise it says "not enough excitation to check ...", never a refusal.  A failed
check raises :class:`ImplausibleInputError` (exit status 2) unless it is in ``allow`` (the CLI's
``--allow-implausible``), in which case it is a warning.

Pure functions over arrays (:func:`judge`), and :class:`StreamChecker` for a stream of samples
(a CAN log or a live bus): it holds the first samples back until the run has excited every check it
can (or until ``max_window_s``), judges, then lets them through.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from online_id.errors import OnlineIdError
from online_id.io.tracklog import UNIT_LIMITS
from online_id.trust.relations import judge_relations
from online_id.trust.slopes import (
    LOWPASS_WINDOW_S,
    MIN_CORRELATION,
    CheckResult,
    fit_slope,
    lowpass,
    steady_yaw_gain,
)
from online_id.units import CHANNEL_UNITS, G
from online_id.util.stages import stage

#: Names accepted by ``--allow-implausible`` (plus ``all``).
CHECKS: tuple[str, ...] = ("ay_slope", "speed_unit", "yaw_sign", "steering_gain", "roll", "magnitude",
                           "ay_follows", "yaw_follows", "steering_follows", "roll_follows")
#: The checks that each channel follows the others (online_id/trust/relations.py).
FOLLOW_CHECK_NAMES = ("ay_follows", "yaw_follows", "steering_follows", "roll_follows")
#: The channels each relation check compares (a check on a channel named as not belonging is moot).
CHECK_CHANNELS = {"ay_slope": ("lateral_acceleration", "yaw_rate"), "speed_unit": ("lateral_acceleration", "yaw_rate"),
                  "yaw_sign": ("yaw_rate", "steering_wheel_angle"),
                  "steering_gain": ("yaw_rate", "steering_wheel_angle"), "roll": ("roll_angle", "yaw_rate")}

#: Least spread (std) of low-passed V·r [m/s²] to judge ``ay_slope`` and ``roll``: 0.0005 g of turning.
#: Low on purpose: the correlation decides whether the relation is seen (the RAV4 highway log has a
#: spread of 0.038 m/s² and a correlation of 0.86).
MIN_TURN_ACCEL_STD = 0.005
#: Least spread of the low-passed yaw rate [rad/s] to judge the steering checks (0.017 deg/s).
MIN_YAW_RATE_STD = 0.0003
MIN_ROLL_TURN_STD = MIN_TURN_ACCEL_STD
#: Least run length [s] a judgement uses: five low-pass windows.  Shorter, a correlation of 1.0 can
#: come from two or three independent points (the RAV4 log's first 5 s give an a_y slope of 1.9).
MIN_WINDOW_S = 5 * LOWPASS_WINDOW_S
#: A stream is judged from this many seconds on (then every :data:`STREAM_RETRY_S` until complete).
STREAM_MIN_WINDOW_S = 15.0
STREAM_RETRY_S = 2.0

#: a_y against V·r: accepted slope range (real cars: the race-car log 0.99, the RAV4 log about 0.8).
AY_SLOPE_RANGE = (0.7, 1.4)
#: Yaw rate against the prior's steady-state prediction: accepted within this factor either way
#: (the prior's understeer gradient is a guess; a race car at the limit understeers more).
STEERING_GAIN_FACTOR = 4.0
#: A measured slope is explained by a known slip when within this factor of its signature.
SIGNATURE_TOLERANCE = 1.35
#: Steady roll gradient φ/a_y above this [rad per m/s²] (29 deg/g) is no car's: degrees logged.
ROLL_GRADIENT_MAX = 0.05

KMH = 3.6  # km/h per m/s
MPH = 2.2369362920544  # mph per m/s
DEG = 180.0 / math.pi  # degrees per rad


class ImplausibleInputError(OnlineIdError, ValueError):
    """The channels contradict each other or the prior model: a unit or sign slip (exit status 2)."""


@dataclass
class PlausibilityReport:
    """The verdicts of every check over one run."""

    results: list[CheckResult] = field(default_factory=list)
    source: str = ""
    window_s: float = 0.0

    def by_check(self, check: str) -> CheckResult | None:
        return next((r for r in self.results if r.check == check), None)

    @property
    def failures(self) -> list[CheckResult]:
        return [r for r in self.results if r.failed]

    @property
    def complete(self) -> bool:
        """True when every check that applies was judged (none waits for more excitation). The checks that
        each channel follows the others need more turning than the unit checks (a highway log never has
        it): a stream is not held back for them."""
        return all(r.status != "not judged" or r.check in FOLLOW_CHECK_NAMES for r in self.results)

    def to_dict(self) -> dict:
        """``allowed``: the failed checks (a run that goes on had them allowed by ``--allow-implausible``)."""
        return {"window_s": self.window_s, "allowed": [r.check for r in self.failures],
                "checks": [r.to_dict() for r in self.results]}

    def enforce(self, allow: Iterable[str] = ()) -> list[str]:
        """Raise :class:`ImplausibleInputError` on a failed check not in ``allow``; else warning lines.

        The warnings are for the failed-but-allowed checks and the checks not judged.
        """
        allow = set(allow)
        refused = [r for r in self.failures if r.check not in allow and "all" not in allow]
        where = f"{self.source}: " if self.source else ""
        if refused:
            checks = ",".join(dict.fromkeys(r.check for r in refused))
            raise ImplausibleInputError(
                where + "implausible input: " + "; ".join(r.message for r in refused)
                + f" (if the car really is like that: --allow-implausible {checks})")
        notes = [f"{where}implausible input allowed by --allow-implausible: {r.message}" for r in self.failures]
        notes += list(dict.fromkeys(f"{where}{r.message}" for r in self.results if r.status == "not judged"))
        return notes


def parse_allow(text: str | None) -> tuple[str, ...]:
    """``--allow-implausible`` value (``CHECK[,CHECK...]`` or ``all``) as a tuple of check names."""
    if not text:
        return ()
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in (*CHECKS, "all")]
    if unknown:
        raise OnlineIdError(f"--allow-implausible: unknown check {unknown[0]!r}; choose from"
                            f" {', '.join(CHECKS)} or all")
    return names


# --------------------------------------------------------------------------------------------- arrays

def _brackets_meet(slope: float, corr: float, low: float, high: float) -> bool:
    """True when the true slope may lie in [low, high].

    Noise in x biases the regression of y on x towards zero, noise in y biases the inverse regression
    away from it: the true slope lies between ``slope`` and ``slope / corr²`` (noise in both).
    """
    ends = sorted((slope, slope / corr**2))
    return ends[0] <= high and ends[1] >= low


def _signature(slope: float, signatures: list[tuple[float, str, str, str]]):
    """The known slip whose signature (factor, check, channel, cause) lies within tolerance of ``slope``."""
    best = None
    for factor, check, channel, cause in signatures:
        if np.sign(factor) != np.sign(slope):
            continue
        ratio = abs(math.log(abs(slope / factor)))
        if ratio <= math.log(SIGNATURE_TOLERANCE) and (best is None or ratio < best[0]):
            best = (ratio, check, channel, cause)
    return None if best is None else best[1:]


def judge(time, steering_wheel_angle, speed, yaw_rate, lateral_acceleration, roll_angle=None, *,
          known, prior, source: str = "") -> PlausibilityReport:
    """Judge a run's channels (arrays of shape (N,), SI units, ISO 8855 signs as the log claims).

    ``known`` (:class:`~online_id.vehicle.parameters.KnownParameters`) and ``prior`` (its D1, D2) give
    the steady-state yaw gain the steering checks compare with.  NaN entries (a channel absent from a
    sample) are left out.  Returns every check's verdict; raises nothing.
    """
    t = np.asarray(time, dtype=float)
    V = np.asarray(speed, dtype=float)
    dH = np.asarray(steering_wheel_angle, dtype=float)
    r = None if yaw_rate is None else np.asarray(yaw_rate, dtype=float)
    ay = None if lateral_acceleration is None else np.asarray(lateral_acceleration, dtype=float)
    phi = None if roll_angle is None else np.asarray(roll_angle, dtype=float)
    report = PlausibilityReport(source=source, window_s=float(t[-1] - t[0]) if len(t) > 1 else 0.0)
    if report.window_s < MIN_WINDOW_S:
        msg = (f"not enough data to check the units and signs: {report.window_s:.3g} s, the checks need"
               f" {MIN_WINDOW_S:g} s")
        report.results = [CheckResult(c, "not judged", None, "time", msg) for c in CHECKS if c != "magnitude"]
        return report
    lp = lambda v: lowpass(t, v)  # noqa: E731
    Vr = None if r is None else lp(V * r)
    speed_range = f"logged speed {np.nanmin(V):.3g}-{np.nanmax(V):.3g}" if len(V) else ""

    # a_y against V·r
    if ay is None or r is None:
        for check in ("ay_slope", "speed_unit"):
            report.results.append(CheckResult(check, "absent", None, "lateral_acceleration",
                                              f"cannot check {check}: yaw rate or lateral acceleration missing"))
    else:
        s, corr, spread = fit_slope(Vr, lp(ay))
        evidence = f"lateral_acceleration against speed × yaw_rate has slope {s:+.3g} (correlation {corr:+.2f})"
        if spread < MIN_TURN_ACCEL_STD or abs(corr) < MIN_CORRELATION:
            msg = (f"not enough excitation to check the a_y slope and the speed unit (low-passed V·r spread"
                   f" {spread:.2g} m/s², needs {MIN_TURN_ACCEL_STD:g}; correlation {corr:+.2f}, needs"
                   f" {MIN_CORRELATION:g})")
            report.results += [CheckResult(c, "not judged", s if np.isfinite(s) else None, "lateral_acceleration",
                                           msg, corr) for c in ("ay_slope", "speed_unit")]
        elif _brackets_meet(s, corr, *AY_SLOPE_RANGE):
            report.results += [CheckResult(c, "ok", s, "lateral_acceleration", evidence, corr)
                               for c in ("ay_slope", "speed_unit")]
        else:
            yaw_bad = _steering_slope_negative(t, dH, V, r, known, prior)
            sign_channel = "yaw_rate" if yaw_bad else "lateral_acceleration"
            sign_cause = ("yaw_rate has the opposite sign (SAE: positive to the right?)" if yaw_bad else
                          "lateral_acceleration has the opposite sign (SAE: positive to the right?)")
            signatures = [
                (-1.0, "ay_slope", sign_channel, sign_cause),
                (1 / G, "ay_slope", "lateral_acceleration", "lateral_acceleration in g instead of m/s²?"),
                (-1 / G, "ay_slope", "lateral_acceleration",
                 "lateral_acceleration in g and with the opposite sign (SAE)?"),
                (1 / KMH, "speed_unit", "speed", f"speed in km/h instead of m/s ({speed_range})?"),
                (1 / MPH, "speed_unit", "speed", f"speed in mph instead of m/s ({speed_range})?"),
                (1 / DEG, "ay_slope", "yaw_rate", "yaw_rate in deg/s instead of rad/s?"),
            ]
            found = _signature(s / abs(corr), signatures)
            check, channel, cause = found or ("ay_slope", "lateral_acceleration",
                                              f"expected {AY_SLOPE_RANGE[0]:g}-{AY_SLOPE_RANGE[1]:g}; no known"
                                              " unit or sign slip explains it")
            msg = f"{channel}: {evidence}: {cause}"
            for c in ("ay_slope", "speed_unit"):
                report.results.append(CheckResult(c, "failed" if c == check else "ok", s, channel,
                                                  msg if c == check else evidence, corr))

    # yaw rate against the prior's steady-state prediction from the steering wheel
    if r is None:
        for check in ("yaw_sign", "steering_gain"):
            report.results.append(CheckResult(check, "absent", None, "yaw_rate",
                                              f"cannot check {check}: yaw rate missing"))
    else:
        r_lp = lp(r)
        g, corr, _ = fit_slope(lp(dH * steady_yaw_gain(known, prior, V)), r_lp)
        spread = float(np.nanstd(r_lp)) if np.isfinite(r_lp).any() else 0.0
        evidence = (f"yaw_rate against the prior model's steady-state yaw rate from steering_wheel_angle has"
                    f" slope {g:+.3g} (correlation {corr:+.2f})")
        if spread < MIN_YAW_RATE_STD or abs(corr) < MIN_CORRELATION or not np.isfinite(g):
            msg = (f"not enough excitation to check the yaw-rate sign and the steering gain (low-passed yaw-rate"
                   f" spread {spread:.2g} rad/s, needs {MIN_YAW_RATE_STD:g}; correlation {corr:+.2f}, needs"
                   f" {MIN_CORRELATION:g})")
            report.results += [CheckResult(c, "not judged", g if np.isfinite(g) else None, "yaw_rate", msg, corr)
                               for c in ("yaw_sign", "steering_gain")]
        elif g < 0:
            ay_res = report.by_check("ay_slope")
            yaw_flipped = ay_res is not None and ay_res.failed and ay_res.channel == "yaw_rate"
            channel = "yaw_rate" if yaw_flipped else "steering_wheel_angle"
            cause = f"{channel} has the opposite sign (SAE: positive to the right?)"
            if _signature(-g, [(1 / DEG, "", "", "")]):
                cause += ", and steering_wheel_angle looks like degrees"
            report.results.append(CheckResult("yaw_sign", "failed", g, channel, f"{channel}: {evidence}: {cause}",
                                              corr))
            report.results.append(CheckResult("steering_gain", "skipped", g, "steering_wheel_angle",
                                              "steering gain not judged: the yaw-rate sign is wrong", corr))
        elif _brackets_meet(g, corr, 1 / STEERING_GAIN_FACTOR, STEERING_GAIN_FACTOR):
            report.results += [CheckResult(c, "ok", g, "steering_wheel_angle", evidence, corr)
                               for c in ("yaw_sign", "steering_gain")]
        else:
            i_s = known.steering_ratio
            signatures = [
                (1 / DEG, "steering_gain", "steering_wheel_angle", "steering_wheel_angle in degrees instead of rad?"),
                (i_s, "steering_gain", "steering_wheel_angle",
                 f"steering_wheel_angle is the road-wheel angle (gain ≈ the steering ratio {i_s:g})?"),
                (DEG, "steering_gain", "yaw_rate", "yaw_rate in deg/s instead of rad/s?"),
            ]
            found = _signature(g / abs(corr), signatures)
            _, channel, cause = found or ("steering_gain", "steering_wheel_angle",
                                          f"expected within a factor {STEERING_GAIN_FACTOR:g} of 1; no known unit"
                                          " slip explains it (steering ratio or prior far off?)")
            report.results.append(CheckResult("yaw_sign", "ok", g, "yaw_rate", evidence, corr))
            report.results.append(CheckResult("steering_gain", "failed", g, channel,
                                              f"{channel}: {evidence}: {cause}", corr))

    # roll angle against V·r
    reference_bad = [res.check for res in report.failures if res.check in ("ay_slope", "yaw_sign")]
    if phi is None or r is None:
        report.results.append(CheckResult("roll", "absent", None, "roll_angle",
                                          "no roll check: roll angle or yaw rate missing"))
    elif reference_bad:
        report.results.append(CheckResult("roll", "skipped", None, "roll_angle",
                                          f"roll not checked: its reference V·r failed {reference_bad[0]}"))
    else:
        k, corr, spread = fit_slope(Vr, lp(phi))
        evidence = (f"roll_angle against speed × yaw_rate has slope {k:+.3g} rad per m/s²"
                    f" ({k * G * DEG:+.3g} deg/g, correlation {corr:+.2f})")
        if spread < MIN_ROLL_TURN_STD or abs(corr) < MIN_CORRELATION:
            report.results.append(CheckResult(
                "roll", "not judged", k if np.isfinite(k) else None, "roll_angle",
                f"not enough excitation to check the roll sign (low-passed V·r spread {spread:.2g} m/s², needs"
                f" {MIN_ROLL_TURN_STD:g}; correlation {corr:+.2f}, needs {MIN_CORRELATION:g})", corr))
        elif k < 0:
            report.results.append(CheckResult(
                "roll", "failed", k, "roll_angle", f"roll_angle: {evidence}: roll_angle has the opposite sign"
                " (ISO 8855: a left turn rolls the body to positive roll)?", corr))
        elif k > ROLL_GRADIENT_MAX:
            report.results.append(CheckResult(
                "roll", "failed", k, "roll_angle", f"roll_angle: {evidence}: roll_angle in degrees instead of rad"
                f" (no car rolls over {ROLL_GRADIENT_MAX * G * DEG:.0f} deg/g)?", corr))
        else:
            report.results.append(CheckResult("roll", "ok", k, "roll_angle", evidence, corr))
    return _with_relations(report, t, dH, V, r, ay, phi, known, prior)


def _with_relations(report: PlausibilityReport, t, dH, V, r, ay, phi, known, prior) -> PlausibilityReport:
    """The report with the checks that each channel follows the others (:mod:`online_id.trust.relations`); a
    check comparing a channel those name as not belonging is skipped (its slope, or its lack of excitation,
    would name the wrong cause)."""
    follows = judge_relations(t, dH, V, r, ay, phi, known, prior)
    named = {res.channel: res.check for res in follows if res.failed}
    for i, res in enumerate(report.results):
        moot = [c for c in CHECK_CHANNELS.get(res.check, ()) if c in named]
        if moot and res.status != "absent":
            why = f"{res.check} not judged: {moot[0]} does not belong (check {named[moot[0]]})"
            report.results[i] = CheckResult(res.check, "skipped", res.value, moot[0], why, res.correlation)
    report.results += follows
    return report


def _steering_slope_negative(t, dH, V, r, known, prior) -> bool:
    """True when the yaw rate clearly runs against the steering (for naming the channel of a sign slip)."""
    g, corr, _ = fit_slope(lowpass(t, dH * steady_yaw_gain(known, prior, V)), lowpass(t, r))
    return bool(np.isfinite(g) and g < 0 and abs(corr) >= MIN_CORRELATION)


@stage("plausibility checks")
def judge_run(run, vehicle) -> PlausibilityReport:
    """:func:`judge` over a :class:`~online_id.io.tracklog.TrackRun` with a vehicle's known values and prior."""
    return judge(run.time, run.steering_wheel_angle, run.speed, run.yaw_rate, run.lateral_acceleration,
                 run.roll_angle, known=vehicle.known, prior=vehicle.prior, source=run.source)


# -------------------------------------------------------------------------------------------- streams

def check_sample_magnitude(sample, where: str = "") -> None:
    """Raise :class:`ImplausibleInputError` when a channel of ``sample`` exceeds its plausible size."""
    for channel, (limit, hint) in UNIT_LIMITS.items():
        value = getattr(sample, channel, None)
        if value is not None and abs(value) > limit:
            raise ImplausibleInputError(
                f"{where}{channel} = {value:.6g} {CHANNEL_UNITS[channel]} at t = {sample.time:.3f} s exceeds the"
                f" plausible {limit:.3g} {CHANNEL_UNITS[channel]} ({hint}) (check magnitude; if the car really"
                " is like that: --allow-implausible magnitude)")


_STREAM_CHANNELS = ("time", "steering_wheel_angle", "speed", "yaw_rate", "lateral_acceleration", "roll_angle")


class StreamChecker:
    """Judge a stream of samples after its first seconds, then let it through.

    ``check(samples)`` yields the samples of ``samples`` (any iterable of
    :class:`~online_id.stream.samples.Sample`): the first ones are held back until the run has excited every
    check that applies (tried every :data:`STREAM_RETRY_S` from :data:`STREAM_MIN_WINDOW_S` on) or has
    lasted ``max_window_s`` (None: the whole stream), then judged with :func:`judge`; a failure not in
    ``allow`` raises :class:`ImplausibleInputError` before any held sample is released. Every sample is
    also checked for magnitude (unless ``magnitude`` is allowed). ``on_notes(lines)`` receives the
    warnings (allowed failures, checks without enough excitation); ``report`` keeps the verdicts.

    ``hold=False`` (a live bus) passes every sample on at once and judges alongside: the estimator keeps
    pace with the bus, and a failure still raises before anything is reported.
    """

    def __init__(self, known, prior, *, allow: Iterable[str] = (), max_window_s: float | None = 30.0,
                 source: str = "", on_notes: Callable[[list[str]], None] | None = None, hold: bool = True):
        self.known, self.prior = known, prior
        self.allow = tuple(allow)
        self.max_window_s = max_window_s
        self.source = source
        self.on_notes = on_notes
        self.hold = hold
        self.report: PlausibilityReport | None = None

    def check(self, samples: Iterable) -> Iterator:
        check_magnitude = not ({"magnitude", "all"} & set(self.allow))
        where = f"{self.source}: " if self.source else ""
        held: list = []
        columns: dict[str, list[float]] = {c: [] for c in _STREAM_CHANNELS}
        next_try = STREAM_MIN_WINDOW_S
        for sample in samples:
            if check_magnitude:
                check_sample_magnitude(sample, where)
            if self.report is not None:
                yield sample
                continue
            if self.hold:
                held.append(sample)
            else:
                yield sample
            t0 = sample.time if not columns["time"] else columns["time"][0]
            for c in _STREAM_CHANNELS:
                v = getattr(sample, c)
                columns[c].append(np.nan if v is None else v)
            span = sample.time - t0
            if span < next_try:
                continue
            next_try = span + STREAM_RETRY_S
            report = self._judge(columns)
            if report.complete or (self.max_window_s is not None and span >= self.max_window_s):
                self._decide(report)
                yield from held
                held = []
        if self.report is None and columns["time"]:
            self._decide(self._judge(columns))
            yield from held

    def _judge(self, columns: dict[str, list[float]]) -> PlausibilityReport:
        arrays = {c: np.asarray(v, dtype=float) for c, v in columns.items()}
        roll = arrays["roll_angle"] if np.isfinite(arrays["roll_angle"]).any() else None
        return judge(arrays["time"], arrays["steering_wheel_angle"], arrays["speed"], arrays["yaw_rate"],
                     arrays["lateral_acceleration"], roll, known=self.known, prior=self.prior, source=self.source)

    def _decide(self, report: PlausibilityReport) -> None:
        self.report = report
        notes = report.enforce(self.allow)
        if notes and self.on_notes is not None:
            self.on_notes(notes)
