"""The run's own yaw-rate/steering frequency response, to lay over the model's (:mod:`online_id.handling.metrics`).

Welch's H1 estimate: H(f) = P_δr(f) / P_δδ(f), the cross-spectrum of steering-wheel angle δH and yaw rate r over
the steering's auto-spectrum (averaged over half-overlapping Hann segments of :func:`segment_samples`), with
the coherence γ² = |P_δr|² / (P_δδ·P_rr). Only frequencies where γ² ≥ :data:`MIN_COHERENCE` and the steering
has power (:data:`MIN_INPUT_POWER` of its peak) are kept: there the steering explains most of the yaw rate and
H is a measurement, elsewhere it is noise (a straight line has none). A log with jittered samples is put on an
even grid at its median period first (linear interpolation). The speed of a real log varies; the response
measured is the average over the run, the model's is at the median speed: the caption says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Frequencies where the steering explains less of the yaw rate's power than this are left out.
MIN_COHERENCE = 0.5
#: The longest segment [s]: 0.1 Hz resolution, the lower end of a driver's steering.
SEGMENT_S = 10.0
#: The fewest segments averaged (a shorter run gets shorter segments): the coherence of two unrelated signals
#: averages about 1/segments, and with 3 it passed 0.5 above the end of a 0.2-4 Hz chirp.
MIN_SEGMENTS = 8
#: Frequencies where the steering's power is under this fraction of its peak carry no input to measure a
#: response from (above the end of a chirp), whatever the coherence says.
MIN_INPUT_POWER = 1e-3
#: The fewest samples of a segment (and of a run) for a spectrum at all.
MIN_SEGMENT_SAMPLES = 64
#: Points drawn at most: the kept frequencies are averaged in this many log-spaced bins.
MAX_POINTS = 120
#: The measured range [Hz] (the model's curve spans the same).
BAND_HZ = (0.05, 10.0)


@dataclass
class MeasuredResponse:
    """``frequency_hz`` (F,), ``magnitude`` [1/s], ``phase_deg``, ``coherence`` (F,) where γ² ≥ MIN_COHERENCE;
    ``speed_mps`` (min, median, max) of the run; ``segment_s`` the Welch segment length."""

    frequency_hz: np.ndarray
    magnitude: np.ndarray
    phase_deg: np.ndarray
    coherence: np.ndarray
    speed_mps: tuple[float, float, float]
    segment_s: float

    def to_json_dict(self) -> dict:
        return {"frequency_hz": finite_list(self.frequency_hz), "magnitude": finite_list(self.magnitude),
                "phase_deg": finite_list(self.phase_deg), "coherence": finite_list(self.coherence), "unit": "1/s",
                "speed_mps": {"min": self.speed_mps[0], "median": self.speed_mps[1], "max": self.speed_mps[2]},
                "segment_s": self.segment_s, "min_coherence": MIN_COHERENCE}

    def summary(self) -> str:
        if not len(self.frequency_hz):
            return (f"no frequency where the steering explains the yaw rate (coherence ≥ {MIN_COHERENCE:g}):"
                    " the run did not excite the yaw response")
        lo, med, hi = self.speed_mps
        return (f"{len(self.frequency_hz)} frequencies from {self.frequency_hz[0]:.2g} to {self.frequency_hz[-1]:.2g}"
                f" Hz with coherence ≥ {MIN_COHERENCE:g} (speed {3.6 * lo:.0f}-{3.6 * hi:.0f} km/h, median"
                f" {3.6 * med:.0f})")


def segment_samples(n: int, rate_hz: float) -> int:
    """Welch segment length [samples]: a power of two near :data:`SEGMENT_S`, at most n / MIN_SEGMENTS."""
    want = min(SEGMENT_S * rate_hz, n / MIN_SEGMENTS)
    return max(MIN_SEGMENT_SAMPLES, 2 ** int(math.floor(math.log2(max(want, 1.0)))))


def spectra(x: np.ndarray, y: np.ndarray, rate_hz: float, nper: int):
    """Welch's averaged spectra of two even series over half-overlapping Hann segments of ``nper`` samples,
    each segment's mean removed: (f (F,), P_xx, P_yy, P_xy (F,)), one-sided (the scale cancels in H and γ²).
    numpy's FFT: scipy.signal's import alone costs seconds on a busy machine, every estimate."""
    step = nper // 2
    starts = np.arange(0, len(x) - nper + 1, step)
    window = np.hanning(nper + 1)[:-1]  # periodic Hann, as Welch's
    idx = starts[:, None] + np.arange(nper)
    segs_x, segs_y = x[idx], y[idx]
    fx = np.fft.rfft((segs_x - segs_x.mean(axis=1, keepdims=True)) * window, axis=1)
    fy = np.fft.rfft((segs_y - segs_y.mean(axis=1, keepdims=True)) * window, axis=1)
    f = np.fft.rfftfreq(nper, 1.0 / rate_hz)
    return (f, (np.abs(fx) ** 2).mean(axis=0), (np.abs(fy) ** 2).mean(axis=0), (np.conj(fx) * fy).mean(axis=0))


def measured_response(run) -> MeasuredResponse | None:
    """The yaw-rate/steering response of ``run`` (a TrackRun), or None when it is too short for a spectrum."""
    t = np.asarray(run.time, dtype=float)
    if len(t) < MIN_SEGMENT_SAMPLES * 2:
        return None
    dt = float(np.median(np.diff(t)))
    grid = t[0] + dt * np.arange(int((t[-1] - t[0]) / dt) + 1)
    delta = np.interp(grid, t, run.steering_wheel_angle)
    r = np.interp(grid, t, run.yaw_rate)
    rate = 1.0 / dt
    nper = segment_samples(len(grid), rate)
    if nper > len(grid):
        return None
    f, p_dd, p_rr, p_dr = spectra(delta, r, rate, nper)
    with np.errstate(invalid="ignore", divide="ignore"):
        H = p_dr / p_dd
        coh = np.abs(p_dr) ** 2 / (p_dd * p_rr)
    keep = ((f >= BAND_HZ[0]) & (f <= BAND_HZ[1]) & np.isfinite(coh) & (coh >= MIN_COHERENCE) & np.isfinite(H)
            & (p_dd >= MIN_INPUT_POWER * p_dd[1:].max(initial=0.0)))
    f, H, coh = f[keep], H[keep], coh[keep]
    if len(f) > MAX_POINTS:  # average in log-spaced bins: a long log has thousands of lines
        edges = np.geomspace(f[0], f[-1] * (1 + 1e-9), MAX_POINTS + 1)
        which = np.digitize(f, edges) - 1
        used = np.unique(which)
        f = np.array([np.exp(np.mean(np.log(f[which == k]))) for k in used])
        H = np.array([np.mean(H[which == k]) for k in used])
        coh = np.array([np.mean(coh[which == k]) for k in used])
    speed = np.asarray(run.speed, dtype=float)
    return MeasuredResponse(frequency_hz=f, magnitude=np.abs(H), phase_deg=np.degrees(np.unwrap(np.angle(H))),
                            coherence=coh, speed_mps=(float(speed.min()), float(np.median(speed)), float(speed.max())),
                            segment_s=nper * dt)


def finite_list(values) -> list:
    """An array as a JSON list, NaN and ±inf as None (a σ not determined): strict JSON by any writer."""
    return [float(v) if math.isfinite(v) else None for v in np.asarray(values, dtype=float).ravel().tolist()]
