"""What the plausibility checks (:mod:`online_id.trust.plausibility`) and the channel relations
(:mod:`online_id.trust.relations`) both judge with: the two-pass low-pass, the slope and correlation of two
low-passed channels, the prior model's steady-state yaw gain, and one check's result.

Both modules import these from here; neither imports the other's internals (plausibility runs the relations
after its own checks, so it imports relations, and relations imports nothing of plausibility).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Low-pass window [s]: two passes of a moving average this long (response sinc², first null at
#: 1/window Hz).  Below 0.5 Hz the car is close to a steady state, so a_y ≈ V·r and r ≈ r_ss.
LOWPASS_WINDOW_S = 2.0
#: A relation is judged only when the low-passed channels correlate at least this much: below it the
#: slope is mostly noise (a highway log, a steering wheel held still).
MIN_CORRELATION = 0.7
#: Least samples a judgement uses.
MIN_SAMPLES = 50
#: Denominator floor of the steady-state gain 1 + K·V² (an oversteering prior near its critical speed).
MIN_STABILITY_FACTOR = 0.2


@dataclass(frozen=True)
class CheckResult:
    """One check's verdict.

    ``status`` is ``"ok"``, ``"failed"``, ``"not judged"`` (not enough excitation yet), ``"absent"``
    (a channel it needs is not logged) or ``"skipped"`` (another check's failure makes it moot);
    ``value`` is the slope measured (None when not measured); ``channel`` the channel blamed;
    ``message`` one line with the evidence and the likely cause.
    """

    check: str
    status: str
    value: float | None
    channel: str
    message: str
    correlation: float | None = None

    @property
    def failed(self) -> bool:
        return self.status == "failed"

    def to_dict(self) -> dict:
        return {"check": self.check, "status": self.status, "value": self.value, "channel": self.channel,
                "correlation": self.correlation, "message": self.message}


def lowpass(time: np.ndarray, values: np.ndarray, window_s: float = LOWPASS_WINDOW_S) -> np.ndarray:
    """Two passes of a centred moving average ``window_s`` long (in samples at the median period).

    ``values`` of shape (N,) → (N,); near the ends the window is cut short.
    """
    dt = float(np.median(np.diff(time))) if len(time) > 1 else 1.0
    width = max(1, int(round(window_s / dt)))
    out = np.asarray(values, dtype=float)
    for _ in range(2):
        out = _moving_average(out, width)
    return out


def _moving_average(x: np.ndarray, width: int) -> np.ndarray:
    """Centred mean of the finite values over ``width`` samples, the window clipped at the ends.

    NaN where under half a window of finite values is available.
    """
    n_x = len(x)
    finite = np.isfinite(x)
    c = np.concatenate(([0.0], np.cumsum(np.where(finite, x, 0.0))))
    n = np.concatenate(([0], np.cumsum(finite)))
    half = width // 2
    k = np.arange(n_x)
    lo, hi = np.maximum(k - half, 0), np.minimum(k + half + 1, n_x)
    total, count = c[hi] - c[lo], n[hi] - n[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count >= max(1, half), total / count, np.nan)


def fit_slope(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Least-squares slope of y on x with an intercept, the correlation, and std(x), over finite pairs.

    The classification of a failed slope uses slope/|corr| (the geometric mean of the two regressions).
    """
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < MIN_SAMPLES:
        return float("nan"), 0.0, 0.0
    x, y = x[ok] - x[ok].mean(), y[ok] - y[ok].mean()
    sxx, syy = float(x @ x), float(y @ y)
    if sxx <= 0 or syy <= 0:
        return float("nan"), 0.0, math.sqrt(sxx / len(x))
    sxy = float(x @ y)
    return sxy / sxx, sxy / math.sqrt(sxx * syy), math.sqrt(sxx / len(x))


def steady_yaw_gain(known, theta, speed) -> np.ndarray:
    """Steady-state yaw rate per steering-wheel angle [1/s] of the linear model at ``speed`` [m/s].

    r/δH = V / (L·(1 + K·V²)) / i_s,  K = M·(l2/D1 − l1/D2)/L²  (understeer gradient [s²/m²]).
    """
    L = known.l1 + known.l2
    K = known.M * (known.l2 / theta.D1 - known.l1 / theta.D2) / L**2
    V = np.asarray(speed, dtype=float)
    return V / (L * np.maximum(1.0 + K * V**2, MIN_STABILITY_FACTOR)) / known.steering_ratio
