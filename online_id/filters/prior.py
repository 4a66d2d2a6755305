"""The filter's starting uncertainty on the parameters: the prior's σ, how much it is widened and
why, and parameters held fixed.

A vehicle file's ``prior_relative_std`` is the constructor's stated error. The filter widens it
to at least ``FilterConfig.prior_log_std_floor`` (log-scale σ, ≈ relative σ) because a real car
can lie several of those σ from the constructor's figures (Haro's track Kro is 4 σ away, MODEL.md):
a filter that trusts them too much does not get there. The widening is reported, never silent
(:class:`PriorSpread`); ``prior_log_std_floor = 0`` keeps the file's σ as written.

A fixed parameter (``fixed = {"Mzz": 1600.0}``, SI units) has zero initial variance and no random
walk, so the filter never moves it: its log-scale centre is the fixed value and its σ is 0.

Without a roll channel the roll parameters (Mxx, Aro, Kro) are not observable: the roll mode still shapes
a_y through ms·h0·φ̈, but no run tells its inertia, damping and stiffness apart from the tyres'. The
filters with saturating tyres hold them at the prior (:func:`hold_unobserved_roll`, said in a note): left
free, the race car's EKF drove Kro to 1e7 N·m/rad and the UKF spread its sigma points over 150× of it, each
such point a stiff roll mode the RK4 model must sub-step (online_id/model/tyres.py).

What a run *informed* (:func:`informed_flags`) is judged against the same prior σ, once every widening of the
result's σ is done (issue 39): a flag decided on the filter's σ before the run widens it for correlated
innovations (×3-×14 on real logs) said "informed" beside a σ of 1,258 %.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from online_id.errors import OnlineIdError
from online_id.vehicle.parameters import PARAMETER_NAMES

WIDENING_REASON = (
    "FilterConfig.prior_log_std_floor: a car can lie several constructor σ from the constructor's values"
    " (Haro's track Kro is 4σ away), and a filter that trusts a narrow prior does not get there;"
    " --keep-prior-std keeps the file's σ"
)


@dataclass(frozen=True)
class PriorSpread:
    """The initial log-scale σ of each parameter, (8,), and what was changed on the way.

    widened : {name: (σ given, σ used)} for each parameter whose given σ was raised to the floor
    fixed : {name: value [SI]} of the parameters held fixed (σ 0)
    """

    log_std: np.ndarray
    widened: dict[str, tuple[float, float]]
    fixed: dict[str, float]
    #: why some were fixed without being asked (:func:`hold_unobserved_roll`), or ""
    held_note: str = ""

    def to_json_dict(self) -> dict | None:
        """``{"reason": str, "parameters": {name: {"given": σ, "used": σ}}}``, or None when nothing was widened."""
        if not self.widened:
            return None
        return {"reason": WIDENING_REASON,
                "parameters": {n: {"given": g, "used": u} for n, (g, u) in self.widened.items()}}

    def notes(self) -> list[str]:
        """One line per change, for stderr."""
        out = []
        if self.widened:
            parts = ", ".join(f"{n} {100 * g:.3g} %" for n, (g, _) in self.widened.items())
            used = {round(u, 6) for _, u in self.widened.values()}
            to = f"{100 * used.pop():.3g} %" if len(used) == 1 else "the floor"
            out.append(f"prior σ widened to {to} (log-scale) for {parts}; why: {WIDENING_REASON}")
        if self.fixed:
            out.append("held fixed (no update, no random walk): "
                       + ", ".join(f"{n} = {v:.6g}" for n, v in self.fixed.items()))
        if self.held_note:
            out.append(self.held_note)
        return out


def informed_flags(log_std, prior_log_std, fixed=(), ratio: float = 0.5) -> dict[str, bool]:
    """Per parameter: did the data inform it? True when its log-scale σ (8,), *after every widening* (the
    correlated-innovation widening, a polish's covariance), is below ``ratio`` of its prior log-scale σ (8,)
    (``FilterConfig.uninformed_ratio``, one half). A parameter held at its prior (``fixed``: names, or a
    {name: value}; a σ that is not finite or a prior σ of 0) is never informed."""
    sd, prior = np.asarray(log_std, dtype=float), np.asarray(prior_log_std, dtype=float)
    ok = np.isfinite(sd) & np.isfinite(prior) & (prior > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        below = ok & (sd < ratio * prior)
    return {n: bool(b) and n not in fixed for n, b in zip(PARAMETER_NAMES, below)}


def prior_spread(vehicle_relative_std: np.ndarray, given_log_std, floor: float,
                 fixed: dict[str, float] | None = None) -> PriorSpread:
    """Initial log-scale σ (8,): ``given_log_std`` where finite (a fit's or an estimate's σ, taken as
    they are), else the vehicle's relative σ widened to ``floor``; 0 for fixed parameters."""
    fixed = check_fixed(fixed)
    vehicle_sd = np.asarray(vehicle_relative_std, dtype=float)
    given = np.full(len(PARAMETER_NAMES), np.nan) if given_log_std is None else np.asarray(given_log_std, float)
    from_vehicle = ~np.isfinite(given)  # NaN: no σ given for that parameter (e.g. a fit could not determine it)
    sd = np.where(from_vehicle, np.maximum(vehicle_sd, floor), given)
    is_fixed = np.array([n in fixed for n in PARAMETER_NAMES])
    widened = {n: (float(vehicle_sd[i]), float(sd[i])) for i, n in enumerate(PARAMETER_NAMES)
               if from_vehicle[i] and not is_fixed[i] and sd[i] > vehicle_sd[i]}
    return PriorSpread(log_std=np.where(is_fixed, 0.0, sd), widened=widened, fixed=fixed)


def check_fixed(fixed: dict[str, float] | None) -> dict[str, float]:
    """``fixed`` in parameter order, checked: known names, positive finite values (SI units)."""
    fixed = dict(fixed or {})
    for n, v in fixed.items():
        if n not in PARAMETER_NAMES:
            raise OnlineIdError(f"fixed parameter {n!r} is not one of {', '.join(PARAMETER_NAMES)}")
        if not (np.isfinite(v) and v > 0):
            raise OnlineIdError(f"fixed parameter {n} = {v!r} must be a positive number (SI units)")
    if len(fixed) == len(PARAMETER_NAMES):
        raise OnlineIdError("every parameter is fixed: nothing left to estimate")
    return {n: float(fixed[n]) for n in PARAMETER_NAMES if n in fixed}


def fixed_mask(fixed: dict[str, float]) -> np.ndarray:
    """(8,) bool: True where the parameter is fixed."""
    return np.array([n in fixed for n in PARAMETER_NAMES])


def centre_with_fixed(theta0: np.ndarray, fixed: dict[str, float]) -> np.ndarray:
    """The log-scale centre (8,) with each fixed parameter's value in its place (so its s is 0 and
    θ = centre · e⁰ is exactly the fixed value)."""
    return np.array([fixed.get(n, float(v)) for n, v in zip(PARAMETER_NAMES, theta0)])


#: The roll parameters, and the measured channels that observe them.
ROLL_PARAMETERS: tuple[str, ...] = ("Mxx", "Aro", "Kro")
ROLL_CHANNELS: tuple[str, ...] = ("roll_angle", "roll_rate")


def unobserved_roll(channels) -> tuple[str, ...]:
    """The roll parameters a run on ``channels`` cannot inform, held where they are by the tyre filters
    (:func:`hold_unobserved_roll`) and the diagnosis's fits: all three when no roll channel is among them (the data
    barely inform them, through a_y's ms·h0·φ̈ alone, and left free the fits wander to stiff roll modes whose RK4
    passes take many sub-steps: the race car's two-channel diagnosis ran past 50 min, 3 min held, the same
    held-out cost once its tyres are in), else none; none for ``channels`` None (not known)."""
    if channels is None or any(c in ROLL_CHANNELS for c in channels):
        return ()
    return ROLL_PARAMETERS


def hold_unobserved_roll(channels, centre: np.ndarray, fixed: dict[str, float] | None) -> tuple[dict[str, float], str]:
    """``fixed`` with the roll parameters held at ``centre``'s values (8,) [SI] when ``channels`` has no roll channel,
    and a note saying so ("" when nothing was added; a roll parameter fixed by the caller stays as given)."""
    fixed = dict(fixed or {})
    added = {n: float(centre[PARAMETER_NAMES.index(n)]) for n in unobserved_roll(channels) if n not in fixed}
    if not added:
        return fixed, ""
    note = (f"no roll channel: {', '.join(added)} held at the prior ({', '.join(f'{v:.6g}' for v in added.values())})"
            " — the data cannot inform them (the roll mode still shapes a_y through ms·h0·φ̈); with the tyre model"
            " a free, unobserved roll stiffness drifts to values whose stiff roll mode the model must sub-step;"
            " --fix NAME=VALUE sets other values")
    return {**fixed, **added}, note
