"""Steering-wheel inputs of the test protocols (Haro 2008, section 5).

Each function returns the steering-wheel angle δH [rad] at the given times [s]
(array of shape (N,)).
"""

from __future__ import annotations

import numpy as np


def chirp(time, amplitude_rad: float, f_start_hz: float = 0.2, f_end_hz: float = 4.0,
          duration_s: float | None = None) -> np.ndarray:
    """Sine sweep with frequency rising linearly from ``f_start_hz`` to ``f_end_hz``.

    δH(t) = A sin(2π (f0 t + (f1 − f0) t² / (2T))), starting at zero, as
    Haro's hand-driven 0.2-4 Hz sweep; T defaults to the last time stamp.
    """
    t = np.asarray(time, dtype=float)
    T = float(duration_s if duration_s is not None else max(t[-1], 1e-9))
    phase = 2 * np.pi * (f_start_hz * t + (f_end_hz - f_start_hz) * t**2 / (2 * T))
    return amplitude_rad * np.sin(phase)


def chirp_frequency(time, f_start_hz: float = 0.2, f_end_hz: float = 4.0, duration_s: float | None = None):
    """Instantaneous frequency [Hz] of :func:`chirp` at ``time``."""
    t = np.asarray(time, dtype=float)
    T = float(duration_s if duration_s is not None else max(t[-1], 1e-9))
    return f_start_hz + (f_end_hz - f_start_hz) * t / T


def step(time, amplitude_rad: float, start_s: float = 1.0, ramp_s: float = 0.1) -> np.ndarray:
    """Step steer: zero, then a linear ramp of ``ramp_s`` seconds from ``start_s`` to the amplitude."""
    t = np.asarray(time, dtype=float)
    if ramp_s <= 0:
        return np.where(t >= start_s, amplitude_rad, 0.0)
    return amplitude_rad * np.clip((t - start_s) / ramp_s, 0.0, 1.0)


def sine(time, amplitude_rad: float, frequency_hz: float) -> np.ndarray:
    """A plain sine of one frequency (a run with little excitation when slow and small)."""
    return amplitude_rad * np.sin(2 * np.pi * frequency_hz * np.asarray(time, dtype=float))


MANEUVERS = ("chirp", "step", "sine")


class SpeedProfile:
    """A speed that changes along the run: braking and traction between given speeds (issue 38).

    ``breakpoints`` are (time [s], speed [m/s]) pairs, times strictly increasing; between them the speed is the
    shape-preserving cubic through them (:class:`scipy.interpolate.PchipInterpolator`: no overshoot, the
    acceleration continuous and zero where the speed turns), held at the last speed after the last breakpoint and
    at the first before the first. ``speed(t)`` [m/s] and ``acceleration(t)`` [m/s²], its exact derivative, at
    any times: a simulation integrated finer than it is logged evaluates both at its fine times.
    """

    def __init__(self, breakpoints):
        from scipy.interpolate import PchipInterpolator

        pts = np.asarray(breakpoints, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 1:
            raise ValueError("a speed profile is a list of (time [s], speed [m/s]) pairs")
        if not np.all(np.isfinite(pts)):
            raise ValueError("a speed profile's times and speeds must be finite")
        if np.any(np.diff(pts[:, 0]) <= 0):
            raise ValueError(f"a speed profile's times must increase strictly, got {pts[:, 0].tolist()}")
        if np.any(pts[:, 1] <= 0):
            raise ValueError(f"a speed profile's speeds must be positive, got {pts[:, 1].tolist()} m/s")
        self.breakpoints = pts
        self._curve = PchipInterpolator(pts[:, 0], pts[:, 1]) if len(pts) > 1 else None
        self._slope = None if self._curve is None else self._curve.derivative()

    def speed(self, time) -> np.ndarray:
        """The speed [m/s] at ``time`` [s]."""
        t = np.asarray(time, dtype=float)
        if self._curve is None:
            return np.full(t.shape, self.breakpoints[0, 1])
        return self._curve(np.clip(t, self.breakpoints[0, 0], self.breakpoints[-1, 0]))

    def acceleration(self, time) -> np.ndarray:
        """dV/dt [m/s²] at ``time`` [s] (zero outside the breakpoints, where the speed is held)."""
        t = np.asarray(time, dtype=float)
        if self._slope is None:
            return np.zeros(t.shape)
        inside = (t >= self.breakpoints[0, 0]) & (t <= self.breakpoints[-1, 0])
        return np.where(inside, self._slope(np.clip(t, self.breakpoints[0, 0], self.breakpoints[-1, 0])), 0.0)

    @classmethod
    def parse(cls, text: str) -> SpeedProfile:
        """``"0:100,4:60,8:100"``: time [s] : speed [km/h] pairs (the command line's ``--speed-profile``)."""
        pairs = []
        for part in text.split(","):
            t, sep, v = part.strip().partition(":")
            try:
                if not sep:
                    raise ValueError
                pairs.append((float(t), float(v) / 3.6))
            except ValueError:
                raise ValueError(f"speed profile {text!r}: {part.strip()!r} is not TIME_S:SPEED_KMH"
                                 " (e.g. 0:100,4:60,8:100)") from None
        return cls(pairs)

    def to_dict(self) -> dict:
        return {"time_s": self.breakpoints[:, 0].tolist(), "speed_mps": self.breakpoints[:, 1].tolist()}
