"""The lagged-output form of a delay: the filters read a channel logged τ late at t + τ̂.

A channel c logged τ_c after the steering (a sensor's delay, ``sensor_delay``; every channel and the speed
under a steering delay, ``steering_delay``) is, in the model's time (the steering's), y_c,logged(t + τ_c) =
y_c(t). The filters keep their model in the steering's time and, for the sample at t, read channel c at
t + τ̂_c from the samples that have arrived since: exactly the model's output at t when τ̂ = τ, and to first
order around it,

    y_c,logged(t + τ̂_c) = y_c(t + τ̂_c − τ_c) ≈ y_c(t) − (τ_c − τ̂_c)·ẏ_c(t),

so the prediction is the model's own and the sensitivity to τ is −ẏ_c (online_id/filters/augment.py; the EKF
and UKF take ẏ = C(A x + B δ) from the model they propagate). No extra dynamic state, no history of the
state: the price is latency (a sample waits until t + max τ̂ has arrived) and the reading between samples.

:class:`Retimer` does the reading. It holds the samples as they come, and releases the sample at t once
two samples beyond t + max τ̂ have arrived, with each lagged channel read at t + τ̂_c by cubic Hermite
interpolation (tangents from the neighbours: Catmull-Rom on an even grid); linear where a neighbour is
missing; absent (``None``) across a gap longer than ``max_gap_s``, where a neighbour has no value, or beyond
the end of the stream (:meth:`Retimer.drain`). The reading's error on a sine of frequency f sampled every h
is at most about (2πfh)³/60 of its amplitude (Catmull-Rom tangents are second order; measured in
tests/test_lagged.py: 4 Hz read at 100 Hz 2.6e-4, at 250 Hz 1.6e-5, at 1 kHz 2.5e-7 of the amplitude,
under the sensors' noise in every case). The lags are clamped to [``MIN_LAG_S``, ``MAX_LAG_S``].
"""

from __future__ import annotations

import math
from bisect import bisect_right

from online_id.stream.samples import MEASURED_CHANNELS, Sample

#: The longest lag the filters read ahead [s] (the fits bound a delay at 0.25 s); beyond it the reading stops.
MAX_LAG_S = 0.5
#: A lag estimate may wander below zero where the true delay is none: the reading looks back this far [s].
MIN_LAG_S = -0.05
#: Samples kept after the one released, for the look-back and the interpolation's lower neighbour.
_HISTORY_MARGIN = 2


class Retimer:
    """Reads lagged channels ahead of the steering (module docstring).

    Parameters
    ----------
    max_gap_s : a step between two samples longer than this is a gap: no reading across it
    """

    def __init__(self, max_gap_s: float):
        self.max_gap_s = float(max_gap_s)
        self._times: list[float] = []
        self._samples: list[Sample] = []
        self._next = 0  # index of the next sample to release
        self.set_lags((0.0,) * len(MEASURED_CHANNELS), 0.0)

    @property
    def last_time(self) -> float | None:
        """The newest sample's time, or None."""
        return self._times[-1] if self._times else None

    def set_lags(self, lags, speed_lag: float) -> None:
        """Read the measured channels ``lags`` (5,) [s] and the speed ``speed_lag`` [s] late from now on."""
        self._lags = [min(max(float(v), MIN_LAG_S), MAX_LAG_S) for v in lags]
        self._speed_lag = min(max(float(speed_lag), MIN_LAG_S), MAX_LAG_S)
        self._horizon = max(max(self._lags), self._speed_lag, 0.0)
        self._lagged = [(c, lag) for c, lag in zip(MEASURED_CHANNELS, self._lags) if lag]

    def push(self, sample: Sample) -> list[Sample]:
        """Hold ``sample`` (times must increase) and release those whose lagged readings have arrived."""
        times = self._times
        times.append(sample.time)
        self._samples.append(sample)
        out = []
        horizon = self._horizon
        while self._next < len(times) - 2 and times[-2] > times[self._next] + horizon:
            out.append(self._release())
        self._trim()
        return out

    def drain(self) -> list[Sample]:
        """Release every held sample (the stream has ended): readings beyond its end are absent."""
        out = [self._release() for _ in range(self._next, len(self._times))]
        self._trim()
        return out

    def _release(self) -> Sample:
        k = self._next
        self._next += 1
        s = self._samples[k]
        t = s.time
        values = {c: getattr(s, c) for c in MEASURED_CHANNELS}
        for c, lag in self._lagged:
            values[c] = self.read(c, t + lag)
        speed = s.speed
        if self._speed_lag:
            v = self.read("speed", t + self._speed_lag)
            speed = speed if v is None else v  # the speed held where it cannot be read
        return Sample(t, s.steering_wheel_angle, speed, **values, longitudinal_acceleration=s.longitudinal_acceleration)

    def read(self, channel: str, t: float) -> float | None:
        """Channel ``channel`` at time ``t`` from the held samples (module docstring), or None."""
        times = self._times
        j = bisect_right(times, t) - 1
        if j < 0 or j >= len(times) - 1:
            return None if not (0 <= j < len(times) and times[j] == t) else _value(self._samples[j], channel)
        t0, t1 = times[j], times[j + 1]
        if t1 - t0 > self.max_gap_s:
            return None
        y0, y1 = _value(self._samples[j], channel), _value(self._samples[j + 1], channel)
        if y0 is None or y1 is None:
            return None
        h = t1 - t0
        u = (t - t0) / h
        # tangents from the neighbours (one-sided where there is none, or across a gap)
        ym = _value(self._samples[j - 1], channel) if j >= 1 and t0 - times[j - 1] <= self.max_gap_s else None
        yp = (_value(self._samples[j + 2], channel)
              if j + 2 < len(times) and times[j + 2] - t1 <= self.max_gap_s else None)
        if ym is None and yp is None:
            return y0 + u * (y1 - y0)
        m0 = (y1 - ym) / (t1 - times[j - 1]) * h if ym is not None else y1 - y0
        m1 = (yp - y0) / (times[j + 2] - t0) * h if yp is not None else y1 - y0
        u2, u3 = u * u, u * u * u
        return ((2 * u3 - 3 * u2 + 1) * y0 + (u3 - 2 * u2 + u) * m0 + (-2 * u3 + 3 * u2) * y1
                + (u3 - u2) * m1)

    def _trim(self) -> None:
        """Forget the samples no future reading needs (before the look-back of the next sample to release)."""
        times = self._times
        start = times[self._next] if self._next < len(times) else times[-1]
        keep_from = start + min(min(self._lags), self._speed_lag, 0.0, MIN_LAG_S)
        cut = bisect_right(times, keep_from) - _HISTORY_MARGIN
        if cut > 256:  # in chunks: a list's head is cheap to cut rarely
            del times[:cut], self._samples[:cut]
            self._next -= cut


def _value(sample: Sample, channel: str) -> float | None:
    v = getattr(sample, channel)
    return v if v is not None and math.isfinite(v) else None
