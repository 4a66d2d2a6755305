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
