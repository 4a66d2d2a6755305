"""What a run can tell before any estimate: its excitation, its sampling, and the Cramér-Rao bound
per parameter, with the manoeuvre that would inform what it cannot.

:func:`check_run` takes a :class:`~online_id.io.tracklog.TrackRun` (from any source) and returns a
:class:`CheckReport` of named figures:

- sampling (rate, jitter, gaps), channels present and missing;
- speed range, and the share of samples under the filter's minimum speed;
- steering-wheel amplitude and its Welch spectrum summarised by band (share of the steering
  variance and RMS amplitude per band, the frequency under which 95 % of it lies);
- |a_y| range and the share above :data:`LINEAR_LIMIT_MPS2` (0.4 g: Haro kept under it; the
  linear tyre model does not hold far beyond);
- the Cramér-Rao bound on each parameter's relative σ (:mod:`online_id.trust.identifiability`) at the
  prior (the linearisation point) with the configured sensor noise, and again with each
  channel's noise floor measured from the log (for a real car usually much larger);
- candidates: the bound if this run were supplemented by a roll channel, by a 0.2-4 Hz chirp
  at the run's median speed (amplitude for 0.4 g at the prior), or by both. Information adds,
  I = I_run + I_candidate, so each candidate says what it would gain. The advice names, per
  parameter the run cannot determine, the first candidate (simplest first) that would.

The sensitivities take the steering between the run's samples as ``intersample`` says
(:mod:`online_id.model.intersample`). The bound assumes the model is right and the noise white: it is a floor,
and on a real car the model error dominates. A parameter not determined by the bound cannot be learned from the run by
any estimator.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from online_id.io.tracklog import OPTIONAL_COLUMNS, TrackRun
from online_id.model.lateral import OUTPUT_NAMES
from online_id.sim import BATCH_INTERSAMPLE, maneuvers
from online_id.trust.identifiability import (
    FisherReport,
    channel_information,
    output_sensitivities,
    report_from_information,
)
from online_id.trust.over_time import Excitation, fisher_by_window
from online_id.units import G
from online_id.util.stages import stage
from online_id.vehicle.loader import Vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES, Parameters

#: Haro kept |a_y| under 0.4 g: the linear tyre model (F = -D·α) holds there, not at the limit.
LINEAR_LIMIT_MPS2 = 0.4 * G
#: A parameter whose Cramér-Rao bound on the relative σ is above this is "not determined" by the run
#: (the same limit as :meth:`FisherReport.undetermined`).
DETERMINED_RELATIVE_STD = 0.1
#: Edges of the steering-spectrum bands [Hz]; the last band runs to the Nyquist frequency. 0.2-4 Hz
#: is Haro's sweep; b1/b2 and Mzz show mainly above 1 Hz.
BAND_EDGES_HZ: tuple[float, ...] = (0.0, 0.2, 0.5, 1.0, 2.0, 4.0)
#: Welch segment length [s]: resolves 0.1 Hz, and a 60 s run still averages over ~11 segments.
WELCH_SEGMENT_S = 10.0
#: Speeds are rounded to this [m/s] for the sensitivity simulation: one discretisation per distinct
#: speed, and a real log has thousands; 0.05 m/s changes the model's matrices by under 0.3 % at 16 m/s.
SPEED_QUANTUM_MPS = 0.05
#: The candidate chirp: Haro's protocol (0.2-4 Hz, 60 s), amplitude for this peak |a_y| at the prior.
CHIRP_BAND_HZ = (0.2, 4.0)
CHIRP_DURATION_S = 60.0
CHIRP_PEAK_MPS2 = LINEAR_LIMIT_MPS2
#: The candidate chirp stays under this fraction of the log's Nyquist frequency (4 Hz needs 10 Hz or more).
CHIRP_NYQUIST_FRACTION = 0.8
ROLL_CHANNELS = ("roll_angle", "roll_rate")


#: What a null in ``check --json`` stands for (strict JSON has no Infinity): a bound or a condition number
#: that is infinite, because the run does not inform that parameter, or some combination of them, at all
#: (a straight line informs none).
NULL_MEANS = ("infinite: the run does not inform that parameter (a relative_std) or some combination of the"
              " parameters (the condition_number) at all")


@dataclass(frozen=True)
class Band:
    low_hz: float
    high_hz: float
    power_fraction: float  # share of the steering variance in the band
    rms_rad: float  # RMS steering-wheel amplitude in the band


@dataclass(frozen=True)
class Supplement:
    """The bound if the run were supplemented by a manoeuvre or a channel."""

    label: str
    description: str
    crlb_relative_std: np.ndarray  # (8,)
    newly_determined: list[str]
    short: str = ""  # a few words for the advice, e.g. "a 0.2-4 Hz chirp at 17.9 m/s"


@dataclass
class CheckReport:
    """What :func:`check_run` found. Arrays are per parameter in :data:`PARAMETER_NAMES` order."""

    source: str
    samples: int
    duration_s: float
    rate_hz: float
    jitter_s: float
    gaps: tuple[tuple[float, float], ...]
    channels_present: list[str]
    channels_missing: list[str]
    speed: dict[str, float]
    steering: dict[str, float]
    bands: list[Band]
    lateral_acceleration: dict[str, float]
    noise_std: dict[str, float]
    noise_floor: dict[str, float]
    linearised_at: str
    crlb: FisherReport
    crlb_at_noise_floor: FisherReport | None
    candidates: list[Supplement] = field(default_factory=list)
    advice: list[str] = field(default_factory=list)
    #: where the run informs each parameter, window by window (:func:`online_id.trust.over_time.fisher_by_window`)
    excitation: Excitation | None = None
    #: single-sample input glitches mended before the bound was computed (:mod:`online_id.trust.spikes`),
    #: ``{"channel", "time", "value", "mended_to"}`` each (the check workflow fills it)
    input_spikes: list[dict] = field(default_factory=list)
    #: the steering between samples the sensitivities took (online_id/model/intersample.py)
    intersample: str = "hold"

    @property
    def decisive(self) -> FisherReport:
        """The bound that decides what is determined: at the log's noise where it exceeds the configured."""
        return self.crlb if self.crlb_at_noise_floor is None else self.crlb_at_noise_floor

    @property
    def not_determined(self) -> list[str]:
        """Parameters whose decisive bound is over :data:`DETERMINED_RELATIVE_STD`."""
        return self.decisive.undetermined(DETERMINED_RELATIVE_STD)

    def to_json_dict(self) -> dict:
        def rel(values):
            return {n: (float(v) if np.isfinite(v) else None) for n, v in zip(PARAMETER_NAMES, values)}

        out = {
            "source": self.source,
            "samples": self.samples,
            "duration_s": self.duration_s,
            "sampling": {"rate_hz": self.rate_hz, "jitter_s": self.jitter_s, "gaps": len(self.gaps),
                         "longest_gap_s": max((g[1] for g in self.gaps), default=0.0),
                         "longest_gap_at_s": max(self.gaps, key=lambda g: g[1])[0] if self.gaps else None},
            "channels": {"present": self.channels_present, "missing": self.channels_missing},
            "speed_mps": self.speed,
            "steering": {**self.steering, "bands": [vars(b) for b in self.bands]},
            "lateral_acceleration": self.lateral_acceleration,
            "null_means": NULL_MEANS,
            "crlb": {"linearised_at": self.linearised_at, "noise_std": self.noise_std,
                     "channels": list(self.crlb.channels), "relative_std": rel(self.crlb.crlb_relative_std),
                     "condition_number": (self.crlb.condition_number if np.isfinite(self.crlb.condition_number)
                                          else None),
                     "determined_below": DETERMINED_RELATIVE_STD,
                     "not_determined": self.crlb.undetermined(DETERMINED_RELATIVE_STD),
                     "intersample": self.intersample},
            "not_determined": self.not_determined,
            "candidates": [{"label": c.label, "description": c.description,
                            "relative_std": rel(c.crlb_relative_std), "newly_determined": c.newly_determined}
                           for c in self.candidates],
            "advice": self.advice,
            "input_spikes": list(self.input_spikes),
        }
        if self.crlb_at_noise_floor is not None:
            out["crlb_at_noise_floor"] = {"noise_floor": self.noise_floor,
                                          "relative_std": rel(self.crlb_at_noise_floor.crlb_relative_std),
                                          "not_determined": self.crlb_at_noise_floor.undetermined(
                                              DETERMINED_RELATIVE_STD)}
        return out

    def text(self) -> str:
        """The report for a terminal."""
        s, st, ay = self.speed, self.steering, self.lateral_acceleration
        lines = [
            f"{self.source}: {self.samples} samples, {self.duration_s:.1f} s at {self.rate_hz:.4g} Hz"
            f" (jitter {self.jitter_s * 1e3:.2g} ms, {len(self.gaps)} gap(s)"
            + (f", longest {max(g[1] for g in self.gaps):.3g} s" if self.gaps else "") + ")",
            f"channels: {', '.join(self.channels_present)}"
            + (f"; missing: {', '.join(self.channels_missing)}" if self.channels_missing else ""),
            f"speed: {s['min']:.1f}-{s['max']:.1f} m/s (median {s['median']:.1f});"
            f" {100 * s['below_min_speed_fraction']:.1f} % under {s['min_speed']:g} m/s (no update there)",
            f"steering wheel: RMS {np.degrees(st['rms_rad']):.2f} deg, max {np.degrees(st['max_abs_rad']):.1f} deg;"
            f" 95 % of its variance under {st['f95_hz']:.2f} Hz; {100 * st['above_1hz_fraction']:.1f} % above 1 Hz",
            "  band [Hz]    share   RMS [deg]",
        ]
        for b in self.bands:
            lines.append(f"  {b.low_hz:4.1f}-{b.high_hz:<5.1f} {100 * b.power_fraction:6.1f} %"
                         f" {np.degrees(b.rms_rad):9.3f}")
        lines.append(f"|a_y|: max {ay['max_abs']:.2f} m/s² ({ay['max_abs'] / G:.2f} g), 95th percentile"
                     f" {ay['p95_abs']:.2f} m/s²; {100 * ay['above_linear_fraction']:.1f} % of samples above 0.4 g"
                     " (the linear tyre model's range)")
        lines.append("noise floor measured from the log (second differences, or what the steering does not explain)"
                     " vs configured: " + ", ".join(f"{c} {self.noise_floor[c]:.3g} vs {self.noise_std[c]:.3g}"
                                                     for c in self.noise_floor))
        head = f"{'param':<5} {'CRLB σ %':>10}"
        if self.crlb_at_noise_floor is not None:
            head += f" {'at log noise':>13}"
        for c in self.candidates:
            head += f" {c.label:>13}"
        lines += [f"Cramér-Rao bound (relative σ) at {self.linearised_at}, channels {', '.join(self.crlb.channels)}"
                  f" (condition number {self.crlb.condition_number:.3g}), at the configured noise and at the log's"
                  " where larger; candidates add to this run (at the log's noise):",
                  "  " + head]
        for i, n in enumerate(PARAMETER_NAMES):
            row = f"{n:<5} {_pct(self.crlb.crlb_relative_std[i]):>10}"
            if self.crlb_at_noise_floor is not None:
                row += f" {_pct(self.crlb_at_noise_floor.crlb_relative_std[i]):>13}"
            for c in self.candidates:
                row += f" {_pct(c.crlb_relative_std[i]):>13}"
            if n in self.not_determined:
                row += "  NOT DETERMINED"
            lines.append("  " + row)
        for c in self.candidates:
            lines.append(f"  {c.label}: {c.description}")
        if self.input_spikes:
            shown = ", ".join(f"{s['channel']} {s['value']:.4g} at {s['time']:.2f} s" for s in self.input_spikes[:6])
            lines.append(f"input spikes: {len(self.input_spikes)} single-sample glitch(es) mended before the bound"
                         f" was computed ({shown}{', ...' if len(self.input_spikes) > 6 else ''}; SI units): a"
                         " glitch excites every parameter and is no manoeuvre")
        lines += [f"advice: {a}" for a in self.advice]
        return "\n".join(lines)


def _pct(v: float) -> str:
    return f"{100 * v:.3g}" if np.isfinite(v) else "inf"


@stage("check")
def check_run(run: TrackRun, vehicle: Vehicle, theta: Parameters | None = None,
              noise_std: dict[str, float] | None = None, min_speed_mps: float = 3.0,
              linearised_at: str = "the vehicle's prior", intersample: str = BATCH_INTERSAMPLE) -> CheckReport:
    """Analyse ``run`` (see the module docstring). ``theta`` is the linearisation point (default the
    vehicle's prior); ``noise_std`` the sensor σ per channel [SI] (default the filter's); ``intersample`` the
    steering between samples."""
    from online_id.filters.config import FilterConfig

    theta = theta or vehicle.prior
    noise_std = dict(noise_std or FilterConfig().measurement_std)
    sampling = run.sampling
    present = [c for c in run.channels if c in OUTPUT_NAMES or c in OPTIONAL_COLUMNS]
    measured = [c for c in OUTPUT_NAMES if getattr(run, c) is not None and c in noise_std]
    missing = [c for c in OUTPUT_NAMES if getattr(run, c) is None]  # (measured channels; a_x is an input)
    rate = sampling.rate_hz
    bands, steering = steering_spectrum(run.steering_wheel_angle, rate)
    floor = {c: noise_floor(getattr(run, c), run.steering_wheel_angle, run.speed, run.time) for c in measured}

    sens_run = output_sensitivities(vehicle, theta, _quantised(run), intersample=intersample)
    info_run = channel_information(sens_run)
    crlb = _bound(info_run, measured, noise_std)
    # what decides: the configured noise, or the log's where it is larger (a real car's vibration)
    decisive_noise = {**noise_std, **{c: max(floor[c], noise_std[c]) for c in measured}}
    at_floor = _bound(info_run, measured, decisive_noise)

    candidates = _candidates(run, vehicle, theta, info_run, measured, decisive_noise, at_floor, rate, intersample)
    report = CheckReport(
        source=run.source, samples=len(run), duration_s=float(run.time[-1] - run.time[0]),
        rate_hz=rate, jitter_s=sampling.jitter_s, gaps=sampling.gaps, channels_present=present,
        channels_missing=missing, speed=_speed_summary(run.speed, min_speed_mps), steering=steering,
        bands=bands, lateral_acceleration=_lateral_summary(run.lateral_acceleration), noise_std=noise_std,
        noise_floor=floor, linearised_at=linearised_at, crlb=crlb, crlb_at_noise_floor=at_floor,
        candidates=candidates, intersample=intersample,
    )
    report.advice = _advice(report)
    report.excitation = fisher_by_window(run.time, sens_run, np.array([decisive_noise[c] if c in measured else np.inf
                                                                       for c in OUTPUT_NAMES]))
    return report


def steering_spectrum(steering: np.ndarray, rate_hz: float) -> tuple[list[Band], dict[str, float]]:
    """Welch spectrum of the steering-wheel angle [rad] summarised by :data:`BAND_EDGES_HZ`."""
    from scipy.signal import welch

    x = np.asarray(steering, dtype=float)
    nperseg = int(min(len(x), max(16, round(WELCH_SEGMENT_S * rate_hz))))
    f, pxx = welch(x, fs=rate_hz, nperseg=nperseg)
    df = f[1] - f[0] if len(f) > 1 else 1.0
    power = pxx * df
    power[0] = 0.0  # the mean (a steering offset) is not excitation
    total = float(power.sum())
    nyquist = rate_hz / 2
    edges = [e for e in BAND_EDGES_HZ if e < nyquist] + [nyquist]
    bands = []
    for lo, hi in zip(edges, edges[1:]):
        sel = (f >= lo) & (f < hi) if hi < nyquist else (f >= lo)
        p = float(power[sel].sum())
        bands.append(Band(low_hz=lo, high_hz=hi, power_fraction=p / total if total > 0 else 0.0,
                          rms_rad=float(np.sqrt(p))))
    cum = np.cumsum(power) / total if total > 0 else np.zeros_like(power)
    f95 = float(f[np.searchsorted(cum, 0.95)]) if total > 0 else 0.0
    above_1 = float(power[f >= 1.0].sum() / total) if total > 0 else 0.0
    return bands, {"rms_rad": float(np.std(x)), "max_abs_rad": float(np.max(np.abs(x))), "f95_hz": f95,
                   "above_1hz_fraction": above_1}


def noise_floor(y: np.ndarray, steering: np.ndarray | None = None, speed: np.ndarray | None = None,
                time: np.ndarray | None = None) -> float:
    """σ of white noise on ``y``: the smaller of two upper bounds.

    - Its second difference: var(y[k+1] - 2y[k] + y[k-1]) = 6σ² for white noise, while a signal contributes
      (2πf·dt)² of its amplitude: close for a channel sampled well above its content, useless below
      (at 10 Hz a 3 Hz chirp's second difference is 3.5× the signal: 1.8 m/s² of "noise" on a_y instead
      of 0.05).
    - With ``steering``, ``speed`` and ``time``: the residual of ``y`` regressed on what the steering input
      explains whatever the parameters (:func:`input_residual_std`), valid at any rate.
    """
    d2 = np.diff(np.asarray(y, dtype=float), n=2)
    floor = float(np.sqrt(np.mean(d2 * d2) / 6)) if len(d2) else float("nan")
    if steering is not None and speed is not None and time is not None:
        floor = float(np.nanmin([floor, input_residual_std(y, steering, speed, time)]))
    return floor


#: Time constants [s] of the Laguerre filter banks :func:`input_residual_std` regresses on: from the
#: relaxation lengths' and yaw's tenths of a second to the roll mode's decay (about 0.6 s on Haro's car).
LAGUERRE_TAUS_S = (0.05, 0.2, 0.8)
#: Filters per bank: 8 orthonormal Laguerre functions span an impulse response of a few time constants.
LAGUERRE_ORDER = 8


def input_residual_std(y: np.ndarray, steering: np.ndarray, speed: np.ndarray, time: np.ndarray) -> float:
    """σ of what the steering input does not explain in ``y`` [its unit]: least squares on a constant and
    the steering through banks of discrete Laguerre filters (:data:`LAGUERRE_TAUS_S`, orthonormal impulse
    responses that span any stable linear response of that time scale), each also times V and 1/V (the
    model's gains vary with speed). Model-free, so an upper bound on the white sensor noise (it keeps what
    the regressors miss), and unlike the second difference it holds at any sample rate. NaN when the run is
    shorter than twice the regressors."""
    from scipy.signal import lfilter

    y, u, v = (np.asarray(a, dtype=float) for a in (y, steering, speed))
    dt = float(np.median(np.diff(time))) if len(time) > 1 else float("nan")
    if not dt > 0:
        return float("nan")
    columns = [np.ones_like(u)]
    for tau in LAGUERRE_TAUS_S:
        a = float(np.exp(-dt / tau))
        x = lfilter([np.sqrt(1 - a * a)], [1, -a], u)
        bank = [u, x]
        for _ in range(LAGUERRE_ORDER - 1):
            x = lfilter([-a, 1], [1, -a], x)
            bank.append(x)
        for b in bank:
            columns += [b, b * v, b / np.maximum(np.abs(v), 1.0)]
    A = np.column_stack(columns)
    n, m = A.shape
    if n < 2 * m:
        return float("nan")
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ coef
    return float(np.sqrt(r @ r / (n - m)))


def _speed_summary(v: np.ndarray, min_speed: float) -> dict[str, float]:
    p5, med, p95 = np.percentile(v, [5, 50, 95])
    return {"min": float(v.min()), "p5": float(p5), "median": float(med), "p95": float(p95), "max": float(v.max()),
            "min_speed": min_speed, "below_min_speed_fraction": float(np.mean(np.abs(v) < min_speed))}


def _lateral_summary(ay: np.ndarray) -> dict[str, float]:
    a = np.abs(ay)
    return {"max_abs": float(a.max()), "p95_abs": float(np.percentile(a, 95)),
            "above_linear_fraction": float(np.mean(a > LINEAR_LIMIT_MPS2))}


def _quantised(run: TrackRun) -> TrackRun:
    """The run with its speed rounded to :data:`SPEED_QUANTUM_MPS` (for the sensitivity simulation)."""
    speed = np.maximum(np.round(run.speed / SPEED_QUANTUM_MPS) * SPEED_QUANTUM_MPS, SPEED_QUANTUM_MPS)
    return TrackRun(time=run.time, steering_wheel_angle=run.steering_wheel_angle, speed=speed,
                    yaw_rate=run.yaw_rate, lateral_acceleration=run.lateral_acceleration, source=run.source)


def _bound(info: dict[str, np.ndarray], channels, noise_std) -> FisherReport:
    total = sum(info[c] / noise_std[c] ** 2 for c in channels)
    return report_from_information(total, tuple(channels))


def _chirp_run(run: TrackRun, vehicle: Vehicle, theta: Parameters, rate_hz: float,
               intersample: str = "hold") -> tuple[TrackRun, float, float]:
    """Haro's chirp at the run's median speed and rate, scaled to CHIRP_PEAK_MPS2 at ``theta``."""
    from online_id.sim.simulator import propagate

    # as _quantised: at least one quantum (the model is singular at standstill)
    speed = float(max(np.round(np.median(run.speed) / SPEED_QUANTUM_MPS) * SPEED_QUANTUM_MPS, SPEED_QUANTUM_MPS))
    t = np.arange(int(round(CHIRP_DURATION_S * rate_hz))) / rate_hz
    unit = maneuvers.chirp(t, 1.0, *chirp_band(rate_hz), duration_s=CHIRP_DURATION_S)
    _, y = propagate(theta, vehicle.known, unit, speed, 1.0 / rate_hz, intersample=intersample)
    amplitude = CHIRP_PEAK_MPS2 / float(np.abs(y[:, OUTPUT_NAMES.index("lateral_acceleration")]).max())
    zeros = np.zeros_like(t)
    chirp_run = TrackRun(time=t, steering_wheel_angle=amplitude * unit, speed=np.full_like(t, speed),
                         yaw_rate=zeros, lateral_acceleration=zeros, source="candidate chirp")
    return chirp_run, speed, amplitude


def chirp_band(rate_hz: float) -> tuple[float, float]:
    """The candidate chirp's band [Hz]: Haro's 0.2-4 Hz, its top kept under CHIRP_NYQUIST_FRACTION of the
    log's Nyquist frequency (a slower log cannot carry 4 Hz: the samples would alias it)."""
    low, high = CHIRP_BAND_HZ
    return low, min(high, CHIRP_NYQUIST_FRACTION * rate_hz / 2)


def _candidates(run, vehicle, theta, info_run, measured, noise_std, crlb, rate_hz,
                intersample: str = "hold") -> list[Supplement]:
    base_missing = set(crlb.undetermined(DETERMINED_RELATIVE_STD))
    roll_missing = [c for c in ROLL_CHANNELS if c not in measured and c in noise_std]
    chirp, speed, amplitude = _chirp_run(run, vehicle, theta, rate_hz, intersample)
    info_chirp = channel_information(output_sensitivities(vehicle, theta, chirp, intersample=intersample))
    band = chirp_band(rate_hz)
    chirp_text = (f"{band[0]:g}-{band[1]:.3g} Hz steering chirp, {CHIRP_DURATION_S:g} s at"
                  f" {speed:.1f} m/s, ±{np.degrees(amplitude):.1f} deg at the wheel ({CHIRP_PEAK_MPS2 / G:.1f} g"
                  f" peak at the prior), at {rate_hz:.4g} Hz")
    roll = " and ".join(roll_missing)
    chirp_short = f"a {band[0]:g}-{band[1]:.3g} Hz chirp at {speed:.1f} m/s"
    specs = []
    if roll_missing:
        specs.append(("+roll", f"log {roll} on this run", f"logging {roll}", measured + roll_missing, False))
    specs.append(("+chirp", f"add a {chirp_text}, channels as logged", f"adding {chirp_short}", measured, True))
    if roll_missing:
        specs.append(("+chirp+roll", f"add the chirp and log {roll}", f"adding {chirp_short} and logging {roll}",
                      measured + roll_missing, True))
    # the lateral velocity (an INS's or an optical sideslip sensor's, issue 38): what it adds, or would add
    if "lateral_velocity" in measured:
        specs.append(("-v_y", "this run without its lateral_velocity (what that channel adds)",
                      "dropping lateral_velocity", [c for c in measured if c != "lateral_velocity"], False))
    elif "lateral_velocity" in noise_std:
        specs.append(("+v_y", "log lateral_velocity on this run (an INS's or an optical sideslip sensor's, at"
                      f" {noise_std['lateral_velocity']:g} m/s noise)", "logging lateral_velocity",
                      measured + ["lateral_velocity"], False))
    out = []
    for label, text, short, channels, with_chirp in specs:
        channels = [c for c in OUTPUT_NAMES if c in channels]
        total = sum(info_run[c] / noise_std[c] ** 2 for c in channels)
        if with_chirp:
            total = total + sum(info_chirp[c] / noise_std[c] ** 2 for c in channels)
        rep = report_from_information(total, tuple(channels))
        now = set(rep.undetermined(DETERMINED_RELATIVE_STD))
        out.append(Supplement(label=label, description=text, crlb_relative_std=rep.crlb_relative_std,
                             newly_determined=[n for n in PARAMETER_NAMES if n in base_missing and n not in now],
                             short=short))
    return out


def _advice(report: CheckReport) -> list[str]:
    out = []
    missing = report.not_determined
    if not missing:
        out.append(f"every parameter is determined (Cramér-Rao bound under {100 * DETERMINED_RELATIVE_STD:g} %);"
                   " the bound assumes the model is right: it is a floor, not a promise")
    crlb = dict(zip(PARAMETER_NAMES, report.decisive.crlb_relative_std))
    for n in missing:
        fix = next((c for c in report.candidates if n in c.newly_determined), None)
        if fix is None:
            out.append(f"{n}: bound {_pct(crlb[n])} % on this run; none of the candidates determines it"
                       " (hold it fixed with --fix if it is known)")
        else:
            i = PARAMETER_NAMES.index(n)
            out.append(f"{n}: bound {_pct(crlb[n])} % on this run; {fix.short} ({fix.label}) would bring it to"
                       f" {_pct(fix.crlb_relative_std[i])} %")
    st, ay = report.steering, report.lateral_acceleration
    if st["above_1hz_fraction"] < 0.05:
        out.append(f"only {100 * st['above_1hz_fraction']:.1f} % of the steering variance is above 1 Hz, where the"
                   " relaxation lengths b1/b2 and the yaw inertia Mzz show")
    if ay["above_linear_fraction"] > 0.05:
        out.append(f"{100 * ay['above_linear_fraction']:.0f} % of samples are above 0.4 g, beyond the linear tyre"
                   " model: expect the estimates to be effective values (run 'online-id diagnose')")
    if report.crlb_at_noise_floor is not None:
        worse = [c for c in report.noise_floor if report.noise_floor[c] > 2 * report.noise_std[c]]
        if worse:
            out.append("the log is noisier than the filter assumes on " + ", ".join(
                f"{c} ({report.noise_floor[c] / report.noise_std[c]:.1f}x)" for c in worse)
                + "; see the bound 'at log noise'")
    return out
