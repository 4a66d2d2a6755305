"""Handling metrics of the identified car, with σ propagated from the parameters' covariance.

The numbers vehicle engineers compare cars by, computed from the full linear model (MODEL.md eqs 1-5,
:mod:`online_id.model.lateral`) at the estimated parameters θ̂ — not from a simplified one:

* **understeer gradient** K [deg/g of road-wheel angle]: from the steady state at speed V,
  δ = (L/V² + K)·a_y, so K = δ/a_y − L/V² (a_y = V·r in a steady turn). On the linear model it does not
  depend on V and equals the bicycle model's (M/L)(l2/D1 − l1/D2) plus the roll steer's
  −(ε1 − ε2)·ms·h0/Kro (``tests/test_handling.py`` checks both closed forms);
* **characteristic speed** √(L/K) for an understeering car (where the steady yaw-rate gain peaks), or
  the **critical speed** √(−L/K) for an oversteering one (where it diverges);
* **steady-state yaw-rate gain** r/δH [1/s = (deg/s)/deg of steering-wheel angle] at the run's median
  speed, and over speed (:data:`GAIN_SPEEDS_MPS`): its speed dependence;
* **yaw natural frequency** ωn/2π [Hz] and **damping ratio** ζ at the run's median speed, of the
  two-degree-of-freedom model (:func:`yaw_mode`: D1, D2, Mzz with M, l1, l2; the classical definition);
* the **frequency response** r/δH(j2πf) = [(j2πf·I − Ac)⁻¹ Bc]_r / i_s over :data:`FREQUENCIES_HZ`,
  magnitude [1/s] and phase [deg].

σ: first order, from the covariance Σ of θ (8×8, SI): each metric m is differentiated in log θ by central
differences (step :data:`LOG_STEP`; every perturbed θ is evaluated in one broadcast call), and
σ_m² = J Σ_s Jᵀ with Σ_s = Σ / θθᵀ. A parameter whose σ is not finite (a fit that could not determine it)
leaves every metric that depends on it without σ (None), never a small one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from online_id.handling.measured import finite_list  # noqa: F401 (this module's name for it, as before)
from online_id.model.lateral import R, continuous_matrices, steady_state
from online_id.units import G
from online_id.vehicle.parameters import PARAMETER_NAMES, KnownParameters

DEG = 180.0 / math.pi
#: Central-difference step in log θ: truncation error ~1e-8 relative, round-off far below it.
LOG_STEP = 1e-4
#: The speeds the steady yaw-rate gain is given over [m/s]: 18-216 km/h.
GAIN_SPEEDS_MPS = np.linspace(5.0, 60.0, 56)
#: The frequencies of the model's frequency response [Hz]: the 0.2-4 Hz of Haro's chirp and a decade around.
FREQUENCIES_HZ = np.geomspace(0.05, 10.0, 90)
#: Below this speed [m/s] the model (which divides by V) has no meaningful yaw mode: no metrics at speed.
MIN_SPEED_MPS = 3.0
#: The most significant digits a metric is printed with (its σ decides how many are worth showing).
MAX_DIGITS = 7
#: |dm/ds| below this (relative to |m|, or absolute for m = 0) counts as "does not depend on that parameter"
#: when that parameter's σ is not finite.
NEGLIGIBLE_SENSITIVITY = 1e-9


@dataclass(frozen=True)
class Metric:
    """One handling number: value and 1σ (None: not determined) in ``unit``."""

    value: float
    std: float | None
    unit: str

    def to_json_dict(self) -> dict:
        return {"value": _finite(self.value), "std": _finite(self.std), "unit": self.unit}

    def text(self, digits: int = 3) -> str:
        """``value ± σ unit``, the value to the σ's second significant digit (at least ``digits``)."""
        if not np.isfinite(self.value):
            return f"— {self.unit}".strip()
        if self.std is None or not np.isfinite(self.std):
            return f"{self.value:.{digits}g} {self.unit} (σ not determined)".replace("  ", " ")
        if self.std > 0 and self.value != 0:
            digits = min(MAX_DIGITS, max(digits, math.ceil(math.log10(abs(self.value) / self.std)) + 2))
        return f"{self.value:.{digits}g} ± {self.std:.2g} {self.unit}".strip()


@dataclass
class FrequencyResponse:
    """Yaw rate over steering-wheel angle: ``frequency_hz`` (F,), ``magnitude`` [1/s] and ``phase_deg``
    (F,), with their 1σ (F,) (NaN: not determined)."""

    frequency_hz: np.ndarray
    magnitude: np.ndarray
    magnitude_std: np.ndarray
    phase_deg: np.ndarray
    phase_deg_std: np.ndarray

    def to_json_dict(self) -> dict:
        return {"frequency_hz": finite_list(self.frequency_hz), "magnitude": finite_list(self.magnitude),
                "magnitude_std": finite_list(self.magnitude_std), "phase_deg": finite_list(self.phase_deg),
                "phase_deg_std": finite_list(self.phase_deg_std), "unit": "1/s"}


@dataclass
class Handling:
    """The handling metrics of one parameter set (see the module docstring), at ``speed_mps``.

    ``kind`` of the characteristic speed: ``"characteristic"`` (understeer), ``"critical"`` (oversteer) or
    ``"neutral"``; ``measured`` the run's own response (:class:`~online_id.handling.measured.MeasuredResponse`)
    when a run was given."""

    speed_mps: float
    understeer_gradient: Metric
    characteristic_speed: Metric
    speed_kind: str
    yaw_rate_gain: Metric
    gain_speeds_mps: np.ndarray
    gain_by_speed: np.ndarray
    gain_by_speed_std: np.ndarray
    yaw_frequency: Metric
    yaw_damping: Metric
    response: FrequencyResponse
    measured: object | None = None
    notes: list[str] = field(default_factory=list)

    def to_json_dict(self) -> dict:
        """The ``handling`` key of ``estimate --json`` and ``fit --json``."""
        return {
            "speed_mps": _finite(self.speed_mps),
            "understeer_gradient": dict(self.understeer_gradient.to_json_dict(), of="road-wheel angle"),
            "characteristic_speed": dict(self.characteristic_speed.to_json_dict(), kind=self.speed_kind),
            "yaw_rate_gain": dict(self.yaw_rate_gain.to_json_dict(), of="steering-wheel angle",
                                  speed_mps=_finite(self.speed_mps)),
            "yaw_rate_gain_by_speed": {"speed_mps": finite_list(self.gain_speeds_mps),
                                       "value": finite_list(self.gain_by_speed),
                                       "std": finite_list(self.gain_by_speed_std), "unit": "1/s"},
            "yaw_natural_frequency": dict(self.yaw_frequency.to_json_dict(), speed_mps=_finite(self.speed_mps)),
            "yaw_damping": dict(self.yaw_damping.to_json_dict(), speed_mps=_finite(self.speed_mps)),
            "frequency_response": self.response.to_json_dict(),
            "measured_response": None if self.measured is None else self.measured.to_json_dict(),
            "notes": list(self.notes),
        }

    def lines(self, of: str = "the estimate") -> list[str]:
        """What the terminal prints under the parameter table (``of``: whose parameters these are)."""
        v = self.speed_mps
        ch = self.characteristic_speed
        speed = ("neutral steer: no characteristic speed" if self.speed_kind == "neutral" else
                 f"{self.speed_kind} speed {_kmh(ch)}")
        out = [f"handling (the linear model at {of}, ±1σ; speed-dependent ones at the run's median"
               f" speed, {3.6 * v:.0f} km/h):",
               f"  understeer gradient  {self.understeer_gradient.text()} (road wheel;"
               f" {'understeer' if self.understeer_gradient.value > 0 else 'oversteer'}); {speed}",
               f"  yaw-rate gain        {self.yaw_rate_gain.text()} (steady state, per steering-wheel angle)",
               f"  yaw mode             {self.yaw_frequency.text()}, damping {self.yaw_damping.text()}"
               " (two-degree-of-freedom model)"]
        if self.measured is not None:
            out.append(f"  measured response    {self.measured.summary()}")
        out += [f"  note: {n}" for n in self.notes]
        return out


def _finite(x):
    return float(x) if x is not None and np.isfinite(x) else None


def _kmh(m: Metric) -> str:
    return Metric(3.6 * m.value, None if m.std is None else 3.6 * m.std, "km/h").text()


# -- the model's numbers at a population of parameter sets -------------------------------------------------

def understeer_gradient(theta, speed, known: KnownParameters) -> np.ndarray:
    """K [rad of road-wheel angle per m/s²] of each parameter set (..., 8) at ``speed`` [m/s], from the
    full model's steady state: δ/a_y − L/V², a_y = V·r."""
    r = steady_state(1.0, theta, speed, known)[..., R]
    V = np.asarray(speed, dtype=float)
    return 1.0 / (V * r) - (known.l1 + known.l2) / V ** 2


def yaw_rate_gain(theta, speed, known: KnownParameters) -> np.ndarray:
    """Steady-state r/δH [1/s] per steering-wheel angle at ``speed`` [m/s] (broadcast with θ's leading axes)."""
    return steady_state(1.0, theta, speed, known)[..., R] / known.steering_ratio


def yaw_mode(theta, speed, known: KnownParameters) -> tuple[np.ndarray, np.ndarray]:
    """(ωn [rad/s], ζ) of the yaw-sideslip mode of the two-degree-of-freedom (bicycle) model at ``speed``
    [m/s], for θ (..., 8):

        ωn² = D1·D2·L² / (M·Mzz·V²) + (D2·l2 − D1·l1) / Mzz
        2ζωn = (D1 + D2) / (M·V) + (D1·l1² + D2·l2²) / (Mzz·V)

    the classical definition cars are compared by (the 6-state model reduces to it with short relaxation
    lengths and no roll coupling: ``tests/test_handling.py``). With the estimated relaxation lengths the yaw
    motion couples with the slip lags into two lightly damped pairs of similar weight in r and β (Haro's track
    car at 80 km/h: 3.6 and 4.4 Hz), so no single pair of the full model is "the" yaw mode; the frequency
    response beside these numbers is the full model's. NaN past an oversteering car's critical speed (ωn² < 0:
    unstable)."""
    t = np.asarray(theta, dtype=float)
    V = np.asarray(speed, dtype=float)
    Mzz, D1, D2 = t[..., 0], t[..., 2], t[..., 3]
    M, l1, l2 = known.M, known.l1, known.l2
    wn2 = D1 * D2 * (l1 + l2) ** 2 / (M * Mzz * V * V) + (D2 * l2 - D1 * l1) / Mzz
    two_zeta_wn = (D1 + D2) / (M * V) + (D1 * l1 ** 2 + D2 * l2 ** 2) / (Mzz * V)
    with np.errstate(invalid="ignore"):
        wn = np.where(wn2 > 0, np.sqrt(np.abs(wn2)), np.nan)
        return wn, two_zeta_wn / (2 * wn)


def frequency_response(theta, speed, known: KnownParameters, frequency_hz=FREQUENCIES_HZ) -> np.ndarray:
    """r/δH(j2πf) (..., F), complex [1/s], of each parameter set at ``speed``."""
    Ac, Bc = continuous_matrices(theta, speed, known)
    s = 2j * math.pi * np.asarray(frequency_hz, dtype=float)
    eye = np.eye(6)
    M = s[:, None, None] * eye - Ac[..., None, :, :]  # (..., F, 6, 6)
    x = np.linalg.solve(M, np.broadcast_to(Bc[..., None, :, None], M.shape[:-1] + (1,)))[..., 0]
    return x[..., R] / known.steering_ratio


# -- the metrics with σ ------------------------------------------------------------------------------------

def handling(theta, covariance, known: KnownParameters, speed: float, run=None,
             frequency_hz=FREQUENCIES_HZ) -> Handling:
    """The handling metrics of ``theta`` (8,) [SI] with σ from ``covariance`` (8, 8) [SI] (None: no σ), the
    speed-dependent ones at ``speed`` [m/s] (the run's median); with ``run`` (a TrackRun) the run's own
    yaw-rate/steering response too (:func:`online_id.handling.measured.measured_response`)."""
    theta = np.asarray(theta, dtype=float)
    notes = []
    speed = float(speed)
    if not speed >= MIN_SPEED_MPS:
        notes.append(f"median speed {speed:.3g} m/s is under {MIN_SPEED_MPS:g} m/s: the metrics are given at"
                     f" {MIN_SPEED_MPS:g} m/s")
        speed = MIN_SPEED_MPS
    thetas = _perturbed(theta)  # (17, 8): θ̂, then ±h on each log θ_i
    cov_s, undetermined = _log_covariance(theta, covariance)

    def with_std(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """values (17, ...) -> (value (...), σ (...)) by the central differences and Σ_s."""
        J = (values[1::2] - values[2::2]) / (2 * LOG_STEP)  # (8, ...)
        centre = values[0]
        if cov_s is None:
            return centre, np.full(centre.shape, np.nan)
        J2 = J.reshape(len(PARAMETER_NAMES), -1)
        var = np.einsum("ip,ij,jp->p", J2, cov_s, J2)
        std = np.sqrt(np.maximum(var, 0.0)).reshape(centre.shape)
        if undetermined.any():
            scale = np.maximum(np.abs(centre.reshape(-1)), 1e-300)
            depends = (np.abs(J2[undetermined]) > NEGLIGIBLE_SENSITIVITY * scale).any(axis=0)
            std = np.where(depends.reshape(centre.shape), np.nan, std)
        return centre, std

    K, K_sd = with_std(understeer_gradient(thetas, speed, known))
    K, K_sd = float(K), float(K_sd)
    L = known.l1 + known.l2
    k_deg_g = G * DEG
    if K > 0:
        kind, v_ch = "characteristic", math.sqrt(L / K)
    elif K < 0:
        kind, v_ch = "critical", math.sqrt(-L / K)
    else:
        kind, v_ch = "neutral", math.inf
    v_sd = v_ch / (2 * abs(K)) * K_sd if K != 0 else math.nan
    if np.isfinite(K_sd) and K_sd > abs(K):
        notes.append(f"the understeer gradient is within 1σ of zero: understeer or oversteer is not determined,"
                     f" and the {kind} speed is a lower bound")
    gain, gain_sd = with_std(yaw_rate_gain(thetas, speed, known))
    speeds = np.asarray(GAIN_SPEEDS_MPS, dtype=float)
    curve, curve_sd = with_std(yaw_rate_gain(thetas[:, None, :], speeds, known))
    wn, zeta = yaw_mode(thetas, speed, known)
    wn, wn_sd = with_std(wn / (2 * math.pi))
    zeta, zeta_sd = with_std(zeta)
    H = frequency_response(thetas, speed, known, frequency_hz)
    mag, mag_sd = with_std(np.abs(H))
    phase, phase_sd = with_std(np.degrees(np.unwrap(np.angle(H), axis=-1)))
    measured = None
    if run is not None:
        from online_id.handling.measured import measured_response

        measured = measured_response(run)
    return Handling(
        speed_mps=speed,
        understeer_gradient=Metric(K * k_deg_g, _std(K_sd * k_deg_g), "deg/g"),
        characteristic_speed=Metric(v_ch, _std(v_sd), "m/s"), speed_kind=kind,
        yaw_rate_gain=Metric(float(gain), _std(gain_sd), "1/s"),
        gain_speeds_mps=speeds, gain_by_speed=curve, gain_by_speed_std=curve_sd,
        yaw_frequency=Metric(float(wn), _std(wn_sd), "Hz"), yaw_damping=Metric(float(zeta), _std(zeta_sd), ""),
        response=FrequencyResponse(np.asarray(frequency_hz, dtype=float), mag, mag_sd, phase, phase_sd),
        measured=measured, notes=notes)


def _std(x) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


def _perturbed(theta: np.ndarray) -> np.ndarray:
    """θ̂ and θ̂·e^{±h} on each parameter in turn: (1 + 2·8, 8)."""
    out = np.repeat(theta[None, :], 1 + 2 * len(theta), axis=0)
    for i in range(len(theta)):
        out[1 + 2 * i, i] *= math.exp(LOG_STEP)
        out[2 + 2 * i, i] *= math.exp(-LOG_STEP)
    return out


def _log_covariance(theta: np.ndarray, covariance) -> tuple[np.ndarray | None, np.ndarray]:
    """Σ / θθᵀ (the covariance of log θ) and which parameters have no finite σ."""
    if covariance is None:
        return None, np.zeros(len(theta), dtype=bool)
    cov = np.asarray(covariance, dtype=float)
    undetermined = ~np.isfinite(np.diag(cov))
    cov_s = cov / np.outer(theta, theta)
    cov_s[undetermined, :] = 0.0
    cov_s[:, undetermined] = 0.0
    return cov_s, undetermined
