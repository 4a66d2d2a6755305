"""Is a run consistent with the model? A verdict from what the filter (or the fit) already has.

A filter whose model describes the data has block innovations ν = (z - ẑ)/√S that are white and of
unit variance. The verdict checks, each against a named bound with its reason:

- **size**: per channel, the normalised innovation squared against the nominal sensor noise,
  averaged over sliding windows of ``WINDOW_S`` seconds (longer on a slow log, to hold
  ``WINDOW_MIN_INNOVATIONS``); the mean of k NIS values of a consistent
  filter is χ²_k/k, and a window above its χ² quantile at ``WINDOW_ALPHA`` counts. The channel is
  flagged when more windows exceed than a consistent filter would give at the false-alarm budget
  (binomial count), or the whole segment's mean is far below 1 (the filter claims a spread it does
  not see);
- **bias**: per channel, a mean of the innovations both significant and material (``MAX_MEAN_FRACTION``
  of their spread): an offset, which the whiteness test (mean removed) cannot see;
- **whiteness**: Ljung-Box over ``LJUNG_BOX_LAGS`` lags per channel; flagged when the statistic is
  beyond its χ² quantile *and* the autocorrelations are material (Σρ² over the lags above
  ``WHITENESS_MIN_RHO2``): a filter's own approximations leave a small, significant correlation on a
  long clean run that is no reason to distrust it. A flagged channel's innovations carry fewer independent
  errors than corrections: the filter's σ, computed as if they were white, is widened by √τ, τ the largest
  integrated autocorrelation time (:func:`correlation_time`) of a flagged channel (``"std_inflation"``: τ;
  the batch polish does the same with its residuals);
- **guards**: the rates of resets, gated samples and gated blocks;
- **the linear range**: most samples beyond it (the model was not meant for that run);
- **parameters**: at the filter's range limit, moved over 3 combined σ from the prior, or implausible
  for a car (judged on the informed parameters; :func:`plausibility`, MODEL.md "Plausible values").

The innovations are judged after the filter converged (tempering and forgetting off), or, for a run
that never converged, over its second half.

:class:`~online_id.filters.innovations.InnovationLog` is the filter's bounded record of its block
innovations (one row per correction, filled in ``FilterHealth.correct``). :func:`judge_estimator`
gives the verdict of a filter, :func:`judge_fit` that of a batch fit; both return the dict that goes under the JSON key
``"consistency"``: ``{"consistent": true|false|null, "reasons": [str, ...], "judged": bool, ...details}``;
``consistent`` is null when nothing failed but the run was too short to test (``"not_judged_because"``
says why): a run nobody judged never reads as consistent.
"""

from __future__ import annotations

import math

import numpy as np

from online_id.stream.samples import MEASURED_CHANNELS
from online_id.units import G
from online_id.util.stages import stage
from online_id.vehicle.parameters import PARAMETER_NAMES

N_CHANNELS = len(MEASURED_CHANNELS)

#: The false-alarm budget of the whole verdict on a clean run (the issue's acceptance: ≤ 5 %).
#: Each statistical test below gets a share of it (Bonferroni over tests and channels).
FALSE_ALARM_BUDGET = 0.05
#: Statistical tests per channel (size in windows, whiteness, mean): the budget's shares, over the channels judged
#: and at least the four of Haro's protocol (yaw rate, roll angle and rate, a_y; :func:`significance`).
TESTS_PER_CHANNEL = 3
#: The fewest channels the budget is shared over (a log with fewer keeps the four's share: as before issue 38).
BUDGET_CHANNELS = 4


def significance(n_channels: int = BUDGET_CHANNELS) -> float:
    """Each test's significance when ``n_channels`` channels are judged (Bonferroni over tests and channels)."""
    return FALSE_ALARM_BUDGET / (TESTS_PER_CHANNEL * max(BUDGET_CHANNELS, n_channels))


TEST_ALPHA = significance()

#: Window of the sliding innovation-size test [s]: 100 corrections at the default 50/s, enough for
#: χ²_k/k to be near Gaussian and short enough to see a misfit that comes and goes.
WINDOW_S = 2.0
#: Fewest innovations a window holds: on a log slower still than those the defaults were tuned on the
#: window widens to hold them (8: the fewest those give, the RAV4 CAN log's 8.3 per 2 s; the race car and a
#: 10 Hz log give 10, 1 kHz 100).
WINDOW_MIN_INNOVATIONS = 8
#: A window counts as too large beyond this upper χ² quantile of its mean NIS.
WINDOW_ALPHA = 1e-3
#: A segment mean NIS below this is a filter claiming over 3x the spread it sees (S too large).
MIN_MEAN_NIS = 0.1
#: Ljung-Box lags: 20 corrections are 0.4 s at the default rate, beyond the chirp's slowest period's
#: quarter (0.2 Hz ⇒ 1.25 s) only in part, but enough to see misfit correlated with the input.
LJUNG_BOX_LAGS = 20
#: Material correlation: Σρ² over the lags. Measured on clean built-in runs: 0.02-0.05 (the
#: filter's first-order relinearisation and block approximations); model or unit errors: 1-5.
WHITENESS_MIN_RHO2 = 0.2
#: A mean of innovations or fit residuals beyond this fraction of their spread is material (with
#: significance at TEST_ALPHA): the model has no output mean of its own under a zero-mean steering
#: input, so a sensor offset stays in the residuals whole (0.3 m/s² on a_y with 0.05 m/s² noise: 6
#: spreads), while a whiteness test, which removes the mean, cannot see it.
MAX_MEAN_FRACTION = 0.2
#: Fewest block innovations (or fit residuals) per channel worth judging.
MIN_INNOVATIONS = 100

#: Resets per minute of run beyond which the filter's breakdowns are a reason (a clean run has none;
#: one bad stretch of a long real log may break one block).
MAX_RESETS_PER_MIN = 1.0
#: Gated fractions beyond which the gate is doing the model's work: a consistent filter's 5σ gate
#: rejects 6e-7 of the samples; a few spikes in a real log stay far under 1 %.
MAX_GATED_SAMPLE_FRACTION = 0.01
MAX_GATED_BLOCK_FRACTION = 0.01
#: A run with more than this fraction of its samples beyond the linear range is mostly outside what
#: the model describes: the values rest on the rest.
MAX_OUTSIDE_LINEAR_FRACTION = 0.5
#: Parameters within this of the filter's log-scale limit (MAX_LOG_SCALE = 5: 150x) count as at
#: the limit: ln 2, a factor 2 from where the filter resets.
LIMIT_MARGIN = math.log(2.0)
#: Moved from the prior by more than this many combined σ (prior and estimate, log scale): 0.3 % of a
#: Gaussian prior; the same 3 as the cross-check of `estimate --prior`.
MOVED_PRIOR_SIGMA = 3.0

# -- plausible values of a car (MODEL.md "Plausible values"); loose on purpose --------------------------
#: Dynamic index Mzz/(M l1 l2): road cars 0.8-1.2 (Milliken & Milliken, Race Car Vehicle Dynamics).
#: Haro's own track fit is 0.29 (an effective value of the simple model), so the lower bound sits
#: below it; the upper bound allows a car with much mass beyond its axles.
DYNAMIC_INDEX_RANGE = (0.2, 2.5)
#: Cornering stiffness per unit static axle load [1/rad]: typical 5-30 (MODEL.md), Haro's fit 11-25;
#: halved and doubled, since D is an effective stiffness that absorbs compliance.
AXLE_STIFFNESS_RANGE = (2.5, 60.0)
#: Steady roll gradient ms h0 g / Kro [deg/g]: race cars about 1, road cars a few, Haro's fit 5.4;
#: from a quarter of a race car's to twice a soft road car's.
ROLL_GRADIENT_RANGE_DEG_PER_G = (0.25, 12.0)
#: Tyre relaxation lengths [m]: a few tenths of a metre to about a metre (MODEL.md); loosened.
RELAXATION_LENGTH_RANGE = (0.05, 3.0)



# -- statistics ----------------------------------------------------------------------------------------
def chi2_upper(k, alpha: float):
    """The χ²_k quantile exceeded with probability ``alpha`` (k a number or an array)."""
    from scipy.special import chdtri

    return chdtri(k, alpha)


def ljung_box(x: np.ndarray, lags: int = LJUNG_BOX_LAGS) -> tuple[float, float]:
    """Ljung-Box Q = n(n+2) Σ ρ_l²/(n-l) over lags 1..``lags`` of the finite values of ``x``, and Σρ_l²."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    n = len(x)
    if n <= lags + 1:
        return 0.0, 0.0
    x = x - x.mean()
    c0 = x @ x
    if c0 <= 0:
        return 0.0, 0.0
    rho = np.array([x[:-k] @ x[k:] for k in range(1, lags + 1)]) / c0
    q = n * (n + 2) * float(np.sum(rho ** 2 / (n - np.arange(1, lags + 1))))
    return q, float(np.sum(rho ** 2))


def biased(x: np.ndarray, alpha: float = TEST_ALPHA) -> bool:
    """Is the mean of ``x`` both significant (two-sided at ``alpha``) and material (MAX_MEAN_FRACTION)?"""
    from scipy.special import ndtri

    x = x[np.isfinite(x)]
    if len(x) < 2:
        return False
    mean, spread = float(np.mean(x)), float(np.std(x))
    if spread <= 0:
        return mean != 0
    z_bound = float(-ndtri(alpha / 2))
    return abs(mean) > MAX_MEAN_FRACTION * spread and abs(mean) / spread * math.sqrt(len(x)) > z_bound


def binomial_upper(n: int, p: float, alpha: float) -> int:
    """Smallest c with P(Binomial(n, p) > c) ≤ alpha."""
    total, term = 0.0, (1 - p) ** n
    for c in range(n + 1):
        total += term
        if 1 - total <= alpha:
            return c
        term *= (n - c) / (c + 1) * p / (1 - p)
    return n


def whiteness(x: np.ndarray, alpha: float = TEST_ALPHA) -> tuple[bool, dict]:
    """Is ``x`` materially and significantly correlated (Ljung-Box at ``alpha``, see the module docstring)? And
    the details."""
    q, rho2 = ljung_box(x)
    bound = float(chi2_upper(LJUNG_BOX_LAGS, alpha))
    detail = {"ljung_box_q": round(q, 1), "ljung_box_bound": round(bound, 1), "sum_rho2": round(rho2, 3)}
    return bool(q > bound and rho2 > WHITENESS_MIN_RHO2), detail


def whiteness_reason(flagged: dict[str, dict], what: str = "innovations", inflation: float = 1.0) -> str | None:
    """One reason naming the channels whose ``what`` are not white ({channel: details}); with the σ widening
    ``inflation`` (τ) when above 1."""
    if not flagged:
        return None
    widened = (f"; σ widened ×{math.sqrt(inflation):.2g} (correlation time {inflation:.3g} corrections)"
               if inflation > 1 else "")
    return (f"{what} not white (Ljung-Box over {LJUNG_BOX_LAGS} lags: "
            + ", ".join(f"{c} Σρ² {d['sum_rho2']:.2g}" for c, d in flagged.items())
            + f"): the model misses structure in the data{widened}")


#: Most lags summed in :func:`correlation_time`.
MAX_CORRELATION_LAGS = 200


def correlation_time(e: np.ndarray, max_lag: int = MAX_CORRELATION_LAGS) -> float:
    """Integrated autocorrelation time 1 + 2 Σ ρ(k) of a series (finite values), summed while ρ(k) > 0: how many
    consecutive values carry one independent error (1 for white)."""
    e = np.asarray(e, dtype=float)
    e = e[np.isfinite(e)]
    e = e - np.mean(e) if len(e) else e
    n = len(e)
    var = float(e @ e) / n if n else 0.0
    if n < 3 or var <= 0:
        return 1.0
    spectrum = np.fft.rfft(e, 2 * n)
    acov = np.fft.irfft(spectrum * np.conj(spectrum))[: min(max_lag, n - 1) + 1] / n
    rho = acov[1:] / var
    stop = np.flatnonzero(rho <= 0)
    rho = rho[: stop[0]] if len(stop) else rho
    return float(1.0 + 2.0 * rho.sum())


def innovation_size(t: np.ndarray, nis: np.ndarray, alpha: float = TEST_ALPHA) -> tuple[str | None, dict]:
    """Sliding-window χ² test of a channel's NIS against the nominal sensor noise (module docstring).

    Returns "large", "small" or None, and the details (``rms_ratio`` = √mean NIS: the innovations'
    size in their expected σ).
    """
    ok = np.isfinite(nis)
    t, nis = t[ok], nis[ok]
    mean = float(np.mean(nis))
    spacing = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    window = max(WINDOW_S, WINDOW_MIN_INNOVATIONS * spacing)
    edges = np.arange(t[0], t[-1] + window, window)
    idx = np.searchsorted(edges, t, side="right") - 1
    counts = np.bincount(idx)
    sums = np.bincount(idx, weights=nis)
    full = counts >= max(counts.max() // 2, 1)
    win_mean = sums[full] / counts[full]
    bounds = chi2_upper(counts[full], WINDOW_ALPHA) / counts[full]
    over = int(np.count_nonzero(win_mean > bounds))
    allowed = binomial_upper(len(win_mean), WINDOW_ALPHA, alpha)
    detail = {"rms_ratio": round(math.sqrt(mean), 4), "windows": len(win_mean), "windows_over": over,
              "windows_allowed": allowed, "window_s": round(window, 3)}
    if over > allowed:
        return "large", detail
    if mean < MIN_MEAN_NIS:
        return "small", detail
    return None, detail


# -- parameters -----------------------------------------------------------------------------------------
def plausibility(theta: np.ndarray, known, informed: dict[str, bool] | None = None) -> tuple[list[str], dict]:
    """Reasons a parameter set (8,) [SI] is not a car's, and the derived quantities (MODEL.md).

    With ``informed``, a quantity whose parameter the data did not inform is not judged (it is the
    prior's, reported as not learned); it is still in the details.
    """
    p = dict(zip(PARAMETER_NAMES, np.asarray(theta, dtype=float)))
    L = known.l1 + known.l2
    derived = {
        "dynamic_index": p["Mzz"] / (known.M * known.l1 * known.l2),
        "front_stiffness_per_load": p["D1"] / (known.M * G * known.l2 / L),
        "rear_stiffness_per_load": p["D2"] / (known.M * G * known.l1 / L),
        "roll_gradient_deg_per_g": math.degrees(known.ms * known.h0 * G / p["Kro"]),
        "b1": p["b1"],
        "b2": p["b2"],
    }
    checks = [
        ("dynamic_index", "Mzz", DYNAMIC_INDEX_RANGE, "dynamic index Mzz/(M·l1·l2)", ""),
        ("front_stiffness_per_load", "D1", AXLE_STIFFNESS_RANGE, "D1 per unit front axle load", " /rad"),
        ("rear_stiffness_per_load", "D2", AXLE_STIFFNESS_RANGE, "D2 per unit rear axle load", " /rad"),
        ("roll_gradient_deg_per_g", "Kro", ROLL_GRADIENT_RANGE_DEG_PER_G, "roll gradient ms·h0·g/Kro", " °/g"),
        ("b1", "b1", RELAXATION_LENGTH_RANGE, "front relaxation length b1", " m"),
        ("b2", "b2", RELAXATION_LENGTH_RANGE, "rear relaxation length b2", " m"),
    ]
    reasons = []
    for key, param, (lo, hi), label, unit in checks:
        if informed is not None and not informed.get(param, True):
            continue
        v = derived[key]
        if not lo <= v <= hi:
            reasons.append(f"implausible {label} {v:.3g}{unit} (a car has {lo:g}-{hi:g}{unit})")
    return reasons, {k: round(float(v), 4) for k, v in derived.items()}


def moved_prior_sigma(log_scale: np.ndarray, prior_log_std: np.ndarray) -> np.ndarray:
    """How far each parameter moved from the prior, in prior σ (log scale), (8,); 0 for a fixed
    parameter (prior σ 0: it cannot move)."""
    return _over(np.abs(np.asarray(log_scale, dtype=float)), np.asarray(prior_log_std, dtype=float))


def _over(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a / b, and 0 where b is 0 (a fixed parameter, whose a is 0 too)."""
    return np.divide(a, b, out=np.zeros_like(a), where=b > 0)


def parameter_reasons(log_scale: np.ndarray, prior_log_std: np.ndarray, limit: float,
                      log_std: np.ndarray | None = None) -> tuple[list[str], dict]:
    """Reasons from where the log-scale parameters (8,) ended: within ``LIMIT_MARGIN`` of the filter's
    ``limit``, or further from the prior than ``MOVED_PRIOR_SIGMA`` combined σ (prior σ and the
    estimate's own ``log_std``, so that a tight prior from a fit is not an alarm by itself)."""
    s = np.asarray(log_scale, dtype=float)
    moved = moved_prior_sigma(s, prior_log_std)
    own = np.zeros_like(s) if log_std is None else np.asarray(log_std, dtype=float)
    z = _over(np.abs(s), np.hypot(np.asarray(prior_log_std, dtype=float), own))
    reasons = []
    at_limit = [n for n, v in zip(PARAMETER_NAMES, s) if abs(v) >= limit - LIMIT_MARGIN]
    if at_limit:
        reasons.append(f"{', '.join(at_limit)} at the filter's range limit ({math.exp(limit - LIMIT_MARGIN):.0f}x"
                       " or more from the prior)")
    far = [f"{n} {m:.1f}σ ({math.exp(v):.3g}x)" for n, m, zz, v in zip(PARAMETER_NAMES, moved, z, s)
           if zz > MOVED_PRIOR_SIGMA and n not in at_limit]
    if far:
        reasons.append(f"moved more than {MOVED_PRIOR_SIGMA:g} prior σ: {', '.join(far)}")
    return reasons, {"at_limit": at_limit, "moved_prior_sigma": {n: round(float(m), 2)
                                                                  for n, m in zip(PARAMETER_NAMES, moved)}}


# -- verdicts -------------------------------------------------------------------------------------------
def judge_innovations(rows: np.ndarray) -> tuple[list[str], dict]:
    """Size and whiteness of each channel's block innovations (rows of
    :class:`~online_id.filters.innovations.InnovationLog`)."""
    if len(rows) == 0:
        return [], {"segment": "none", "channels": {}}
    t, converged = rows[:, 0], rows[:, 1] > 0
    if np.count_nonzero(converged) >= MIN_INNOVATIONS:
        seg, segment = converged, f"after convergence at {t[converged][0]:.1f} s"
    else:
        seg, segment = t >= t[0] + 0.5 * (t[-1] - t[0]), "second half (the filter did not converge)"
    t = t[seg]
    nu = rows[seg, 2:2 + N_CHANNELS] * np.sqrt(rows[seg, 2 + N_CHANNELS:])  # against the nominal R
    details, large, small, correlated, offsets = {}, [], [], {}, []
    judged = [c for c in range(N_CHANNELS) if np.count_nonzero(np.isfinite(nu[:, c])) >= MIN_INNOVATIONS]
    alpha = significance(len(judged))
    for c, name in enumerate(MEASURED_CHANNELS):
        x = nu[:, c]
        if c not in judged:
            continue
        size, d_size = innovation_size(t, x ** 2, alpha)
        white_fail, d_white = whiteness(x, alpha)
        details[name] = {**d_size, **d_white}
        flags = details[name]["flags"] = []  # what failed, by kind (next_steps reads them)
        if size == "large":
            large.append(f"{name} {d_size['rms_ratio']:.3g}×")
            flags.append("large")
        elif size == "small":
            small.append(f"{name} {d_size['rms_ratio']:.2g}×")
            flags.append("small")
        if white_fail:
            correlated[name] = d_white
            flags.append("not_white")
            details[name]["correlation_time"] = round(correlation_time(x), 3)
        mean = float(np.nanmean(x))
        details[name]["mean"] = round(mean, 4)
        if biased(x, alpha):
            offsets.append(f"{name} {mean:+.3g}σ")
            flags.append("biased")
    reasons = []
    if large:
        white = [c.split()[0] for c in large if c.split()[0] not in correlated
                 and not any(o.startswith(c.split()[0] + " ") for o in offsets)]
        hint = (f"; {', '.join(white)} white: its sensor noise may be larger than measurement_std says"
                if white else "")
        window = max((d.get("window_s", WINDOW_S) for d in details.values()), default=WINDOW_S)
        reasons.append(f"innovations beyond their expected size ({', '.join(large)}; χ² over {window:.3g}-s"
                       f" windows{hint})")
    if small:
        reasons.append(f"innovations far under their expected size ({', '.join(small)}): the filter's predicted"
                       " spread is not credible")
    if offsets:
        reasons.append(f"innovations biased (mean {', '.join(offsets)}): a sensor offset, or a unit or sign slip?")
    inflation = max([1.0] + [details[c]["correlation_time"] for c in correlated])
    reasons += [r for r in [whiteness_reason(correlated, inflation=inflation)] if r]
    return reasons, {"segment": segment, "channels": details, "std_inflation": inflation}


#: An extra state beyond what it can physically be (ExtraState.bounds) by more than this many of its σ is a reason.
BOUND_SIGMAS = 3.0


def extra_state_reasons(est) -> list[str]:
    """Extra states estimated beyond their physical range (a negative delay): the state takes up model error."""
    augment = est.augment
    if not any(s.bounds for s in augment.states):
        return []
    from online_id.filters.base import N_AUG

    values, std = est.x[N_AUG:], np.sqrt(np.clip(np.diag(est.P)[N_AUG:], 0.0, None))
    out = []
    for s, v, sd in zip(augment.states, values, std):
        if s.bounds and not s.bounds[0] - BOUND_SIGMAS * sd <= v <= s.bounds[1] + BOUND_SIGMAS * sd:
            out.append(f"{s.key} {s.parameter} {v:.3g} {s.unit} is not what it stands for ({s.bounds[0]:g} to"
                       f" {s.bounds[1]:g} {s.unit}): the state takes up model error")
    return out


@stage("consistency verdict")
def judge_estimator(est) -> dict:
    """The verdict on an online filter's run so far (an :class:`~online_id.filters.base.OnlineEstimator`)."""
    from online_id.filters.health import MAX_LOG_SCALE  # (the filters import filterpy: not at CLI start-up)

    events = dict(est.events)
    rows = est.innovations.rows()
    reasons, out = judge_innovations(rows)
    details = {"innovations": out}
    failed = _channel_flags(out["channels"])
    samples = max(events.get("samples", 0), 1)
    # the run's length in minutes (at least one: a short run's first reset is not a rate)
    minutes = max(rows[-1, 0] - rows[0, 0], 60.0) / 60 if len(rows) > 1 else 1.0
    resets = events.get("resets", 0)
    if resets / minutes > MAX_RESETS_PER_MIN:
        failed.setdefault("resets", [])
        reasons.append(f"{resets:,} filter resets ({resets / minutes / 60:.2g} per s): the filter repeatedly broke"
                       " down (" + ", ".join(f"{why} ×{k}" for why, k in est.reset_reasons.most_common(2)) + ")")
    excess = est.kinematic_offset()
    details["kinematics"] = est.kinematics.to_dict()
    if excess is not None:
        failed["kinematic"] = ["lateral_acceleration", "yaw_rate"]
        k = est.kinematics
        reasons.append(f"a_y − V·r averages {excess:+.3g} m/s² over {k.duration:.0f} s beyond the ±{k.bound:.2g} m/s²"
                       f" any car's sideslip allows: an offset on lateral_acceleration ({excess:+.3g} m/s²) or on"
                       f" yaw_rate ({-excess / k.mean_speed:+.3g} rad/s at the mean {k.mean_speed:.1f} m/s)")
    if est.diverged_at is not None and getattr(est, "held_because", None):
        reasons.append(f"the parameters were held at the prior from t = {est.diverged_at:.1f} s ({est.held_because}):"
                       " not learned (reported at the prior, with the prior's σ)")
    elif est.diverged_at is not None:
        failed.setdefault("resets", [])
        reasons.append(f"the filter diverged at t = {est.diverged_at:.1f} s ({est.config.diverged_resets:g} resets"
                       f" within {est.config.diverged_window_s:g} s): its parameters were not learned (reported at"
                       " the prior, with the prior's σ)")
    n_channels = max(int(np.count_nonzero(est._configured)), 1)
    gated = events.get("outliers_rejected", 0) / (samples * n_channels)
    if gated > MAX_GATED_SAMPLE_FRACTION:
        failed.setdefault("gated", [])
        reasons.append(f"{100 * gated:.2g} % of the measurements gated as outliers")
    corrections = max(events.get("corrections", 0) + events.get("blocks_rejected", 0), 1)
    blocks = events.get("blocks_rejected", 0) / corrections
    if blocks > MAX_GATED_BLOCK_FRACTION:
        failed.setdefault("gated", [])
        reasons.append(f"{100 * blocks:.2g} % of the block corrections rejected by the gate")
    outside = events.get("outside_linear_range", 0) / samples
    if outside > MAX_OUTSIDE_LINEAR_FRACTION:
        failed.setdefault("linear_range", [])
        reasons.append(f"{100 * outside:.0f} % of the samples beyond the model's linear range"
                       f" (|a_y| > {est.config.linear_range_ay / G:.2g} g): not learned from; the values rest on"
                       " the rest")
    beyond_model = events.get("outside_model_range", 0) / samples
    if beyond_model > MAX_OUTSIDE_LINEAR_FRACTION:
        failed.setdefault("structure", [])
        reasons.append(f"{100 * beyond_model:.0f} % of the samples beyond what the tyre law can make (|a_y| >"
                       f" {est._ay_limit / G:.2g} g = {est.config.tyre_range:g}·μ̂·g): not learned from; the values"
                       " rest on the rest")
    details.update(resets_per_min=round(resets / minutes, 3), gated_sample_fraction=round(gated, 5),
                   gated_block_fraction=round(blocks, 5), outside_linear_range_fraction=round(outside, 4),
                   converged_at=est.converged_at)
    if "outside_model_range" in events:
        details["outside_model_range_fraction"] = round(beyond_model, 4)
    reasons += extra_state_reasons(est)
    p_reasons, p_details = parameter_reasons(est.log_scale, est.prior_log_std, MAX_LOG_SCALE,
                                             est.log_scale_std)
    pl_reasons, derived = plausibility(est.parameters.to_vector(), est.known, est.informed)
    reasons += p_reasons + pl_reasons
    if p_reasons or pl_reasons:
        failed.setdefault("parameters", [])
    details.update(p_details, plausibility=derived)
    judged = bool(out["channels"])  # some channel had enough innovations to test
    offsets_on = {s.key for s in est.augment.states if s.group == "offsets"}
    not_informed = [n for n, ok in est.informed.items() if not ok and n not in est.fixed]
    details["next_steps"] = next_steps(failed if reasons else {}, tool="filter", offsets_on=offsets_on,
                                       not_informed=not_informed)
    return _verdict(reasons, judged, None if judged else innovations_not_judged(rows), details)


@stage("consistency verdict")
def judge_fit(residuals: np.ndarray, channels, theta: np.ndarray, known, at_bound: list[str],
              outside_fraction: float = 0.0, not_determined=()) -> dict:
    """The verdict on a batch fit: whiteness of its block residuals (n_blocks, m), parameters at the
    search bounds, plausibility, and the share of the run outside the linear range. ``not_determined``:
    the parameters the fit could not determine (for the next steps)."""
    details, correlated, offsets, failed = {}, {}, [], {}
    alpha = significance(len(channels))
    for c, name in enumerate(channels):
        x = residuals[:, c][np.isfinite(residuals[:, c])]
        fail, details[name] = whiteness(x, alpha)
        details[name]["n"] = int(len(x))
        if fail:
            correlated[name] = details[name]
            failed.setdefault("not_white", []).append(name)
        mean, spread = float(np.mean(x)), float(np.std(x))
        details[name]["mean_over_spread"] = round(mean / spread, 4) if spread > 0 else 0.0
        if biased(x, alpha):
            offsets.append(f"{name} {mean / spread:+.2g}")
            failed.setdefault("biased", []).append(name)
    reasons = [r for r in [whiteness_reason(correlated, what="residuals")] if r]
    if offsets:
        reasons.append(f"residual means far from zero ({', '.join(offsets)} of their spread): an offset the model"
                       " cannot produce (a sensor bias?)")
    if at_bound:
        reasons.append(f"{', '.join(at_bound)} at the search bounds")
        failed["parameters"] = list(at_bound)
    if outside_fraction > MAX_OUTSIDE_LINEAR_FRACTION:
        reasons.append(f"{100 * outside_fraction:.0f} % of the run beyond the model's linear range: left out"
                       " of the cost; the values rest on the rest")
        failed["linear_range"] = []
    pl_reasons, derived = plausibility(theta, known)
    reasons += pl_reasons
    if pl_reasons:
        failed.setdefault("parameters", [])
    judged = any(d.get("n", 0) >= MIN_INNOVATIONS for d in details.values())
    why = None if judged else (f"fewer than {MIN_INNOVATIONS} block residuals per channel"
                               f" ({max((d.get('n', 0) for d in details.values()), default=0)}): too short to"
                               " test their whiteness and mean")
    return _verdict(reasons, judged, why, {"residuals": details, "at_bound": list(at_bound),
                                           "outside_linear_range_fraction": round(float(outside_fraction), 4),
                                           "plausibility": derived,
                                           "next_steps": next_steps(failed if reasons else {}, tool="fit",
                                                                    not_informed=list(not_determined))})


def _verdict(reasons: list[str], judged: bool, why_not: str | None, details: dict) -> dict:
    """The verdict dict: ``consistent`` is True (judged, nothing failed), False (some check failed, judged
    or not) or None (nothing failed, but the statistical tests could not be run: nobody judged the run,
    and a script reading ``consistent`` must not take that for consistent); ``not_judged_because`` says why."""
    consistent = False if reasons else (True if judged else None)
    out = {"consistent": consistent, "reasons": reasons, "judged": judged}
    if not judged:
        out["not_judged_because"] = why_not
    return {**out, **details}


#: Why a run that informed none of its free parameters is not judged (issue 39: a straight line read
#: "verdict: consistent" and was the fleet page's only green row).
NOTHING_LEARNED = ("the run informed none of the {n} free parameters (each σ above half its prior σ): its values"
                   " are the prior's, not the car's, and there is nothing to judge (a straight line, or too little"
                   " steering); check says which manoeuvre or channel would inform them")


def with_informed(consistency: dict | None, informed: dict[str, bool], fixed=(), corrections: int = 1) -> dict | None:
    """The verdict once the result's σ are final (after the polish): when the run ``informed`` none of the
    parameters not in ``fixed``, a verdict that no check failed becomes ``consistent: None`` with
    ``nothing_learned: True`` and :data:`NOTHING_LEARNED` as ``not_judged_because`` (a straight line's
    innovations are white: it agrees with any car; too short to test, it still informed nothing), and the
    excitation step is added to the next steps. An inconsistent verdict stays so, and so does one of a run that
    made no ``corrections`` at all (its own reason says more). ``informed_count`` is added either way, and the
    excitation step (which :func:`judge_estimator` filled from the filter's σ before any widening) names the
    parameters the final σ did not inform, so the next steps say what the table says."""
    if consistency is None:
        return None
    free = [n for n in informed if n not in fixed]
    learned = [n for n in free if informed[n]]
    missing = [n for n in free if not informed[n]]
    out = dict(consistency, informed_count=len(learned))
    # the excitation step names what the final σ say was not informed (judge_estimator saw the filter's own σ)
    steps = [s for s in out.get("next_steps", ()) if s.get("lever") != "excitation"]
    if missing and (out.get("consistent") is False or len(steps) < len(out.get("next_steps", ()))):
        steps.append(_fill(NEXT_STEPS["excitation"], "excitation", parameters=", ".join(missing)))
    if "next_steps" in out or steps:
        out["next_steps"] = steps
    if learned or not free or out.get("consistent") is False or corrections == 0:
        out.pop("nothing_learned", None)
        return out
    out.update(consistent=None, nothing_learned=True, not_judged_because=NOTHING_LEARNED.format(n=len(free)))
    if not any(s.get("lever") == "excitation" for s in steps):
        out["next_steps"] = steps + [_fill(NEXT_STEPS["excitation"], "excitation", parameters=", ".join(missing))]
    return out


def innovations_not_judged(rows: np.ndarray) -> str:
    """Why a filter's innovations could not be judged (no channel had MIN_INNOVATIONS of them in the
    segment judged), with the count it had."""
    if len(rows) == 0:
        return "the filter made no correction (no sample reached its measurement update)"
    t, converged = rows[:, 0], rows[:, 1] > 0
    seg = converged if np.count_nonzero(converged) >= MIN_INNOVATIONS else t >= t[0] + 0.5 * (t[-1] - t[0])
    most = int(np.max(np.count_nonzero(np.isfinite(rows[seg, 2:2 + N_CHANNELS]), axis=0), initial=0))
    return (f"{most} block innovation(s) per channel in the segment judged, fewer than the {MIN_INNOVATIONS}"
            " needed to test their size and whiteness: run longer (or the filter did not converge and the"
            " second half of the run is short)")


# -- what to try next ------------------------------------------------------------------------------------
#: The channels ``--offsets`` gives an offset state (online_id.effects.sensor_bias.OFFSET_CHANNELS, less the
#: steering, which has no innovation of its own); a bias elsewhere takes ``--effect sensor_bias:CHANNEL``.
OFFSET_FLAG_CHANNELS = ("yaw_rate", "lateral_acceleration")

#: What to try next for each kind of failed check (issue 30), the likely lever first: data, so that every
#: front end (estimate, listen, fit, batch's JSON, the API) says the same. ``add``: arguments for the same
#: command; ``run``: another command, ``LOG`` standing for the run's log. ``{channels}`` and ``{parameters}``
#: are filled from what failed. The filters take --offsets; the fit takes a sensor_bias effect per channel.
NEXT_STEPS: dict[str, dict] = {
    "offsets": {"add": ["--offsets"],
                "because": "biased innovations or a_y − V·r off zero ({channels}): the likely cause is a sensor"
                           " offset, which --offsets estimates with the 8 (yaw rate, lateral acceleration,"
                           " steering)"},
    "sensor_bias": {"add": ["--effect", "sensor_bias:{channel}"],
                    "because": "{what} biased on {channels}: a sensor offset the model cannot produce;"
                               " --effect sensor_bias:CHANNEL estimates it with the 8"},
    "sideslip_sensor": {"run": ["online-id", "check", "LOG"],
                        "because": "{what} biased on lateral_velocity: a sensor that reads a sideslip the model cannot"
                                   " make (mounted away from the centre of gravity: the vehicle file's [sensors]"
                                   " lateral_velocity_x_m moves it there; or misaligned in yaw: it reads ε·V); check"
                                   " shows what the other channels determine without it (its -v_y column), and"
                                   " --channels without lateral_velocity estimates without it"},
    "structure": {"run": ["online-id", "diagnose", "LOG", "--json", "DIAG.json"],
                  "because": "{what}: the model misses structure in the data; diagnose names the effect that"
                             " closes the gap on held-out data, then add --effects-from DIAG.json (or"
                             " --effect NAME) to this command"},
    "linear_range": {"add": ["--effect", "tire_saturation"],
                     "because": "most of the run is beyond the linear tyres: the saturating tyre model learns"
                                " from the whole envelope"},
    "noise": {"run": ["online-id", "check", "LOG"],
              "because": "innovations far under their expected size on {channels}: the sensors are quieter"
                         " than measurement_std says; check measures each channel's noise floor"},
    "excitation": {"run": ["online-id", "check", "LOG"],
                   "because": "{parameters} not informed by this run: check says which manoeuvre or channel"
                              " would determine them (more excitation)"},
}


def _channel_flags(channels: dict) -> dict[str, list[str]]:
    """{kind: [channel, ...]} from the per-channel ``flags`` of :func:`judge_innovations`."""
    out: dict[str, list[str]] = {}
    for name, d in channels.items():
        for flag in d.get("flags", ()):
            out.setdefault(flag, []).append(name)
    return out


def _fill(template: dict, key: str, **values) -> dict:
    step = {"lever": key, "because": template["because"].format(**values)}
    for k in ("add", "run"):
        if k in template:
            step[k] = [a.format(**values) for a in template[k]]
    return step


def next_steps(failed: dict[str, list[str]], tool: str = "filter", offsets_on=(), not_informed=()) -> list[dict]:
    """What to try next, the likely lever first (``[{"lever", "because", "add"|"run"}, ...]``; see
    :data:`NEXT_STEPS`), from what failed: ``failed`` maps a kind (``biased``, ``kinematic`` (a_y − V·r off
    zero), ``large``, ``not_white``, ``small``, ``resets``, ``gated``, ``linear_range``, ``structure``,
    ``parameters``) to its channels or parameters. ``tool``: ``filter`` (estimate, listen) or ``fit``;
    ``offsets_on``: the channels whose offsets the filter already estimated; ``not_informed``: parameters the
    run did not inform."""
    steps: list[dict] = []
    kinematic = failed.get("kinematic", [])
    biased = list(dict.fromkeys(failed.get("biased", []) + kinematic))
    flag_offsets = [c for c in biased if tool == "filter" and c in OFFSET_FLAG_CHANNELS and c not in offsets_on]
    offset_steps = [_fill(NEXT_STEPS["offsets"], "offsets", channels=", ".join(flag_offsets))] if flag_offsets else []
    what = "innovations" if tool == "filter" else "residuals"
    offset_steps += [_fill(NEXT_STEPS["sensor_bias"], "sensor_bias", channel=c, channels=c, what=what)
                     for c in biased if c not in flag_offsets and c not in offsets_on and c != "lateral_velocity"]
    if "lateral_velocity" in biased:
        offset_steps.append(_fill(NEXT_STEPS["sideslip_sensor"], "sideslip_sensor", what=what))
    # An offset is the likely lever first when the parameter-free balance a_y − V·r shows it, or when the biased
    # channels are otherwise the right size and white; a bias on innovations that are also far too large or
    # correlated is more often the model's structure (the race car), so diagnose (whose candidates include
    # sensor_bias) comes first there.
    misfit = set(failed.get("large", [])) | set(failed.get("not_white", []))
    offsets_first = bool(kinematic) or not (set(failed.get("biased", [])) & misfit)
    if offsets_first:
        steps += offset_steps
    structure = []
    what = "innovations" if tool == "filter" else "residuals"
    if failed.get("large"):
        structure.append(f"{what} beyond their expected size on {', '.join(failed['large'])}")
    if failed.get("not_white"):
        structure.append(f"{what} not white on {', '.join(failed['not_white'])}")
    still = [c for c in biased if c in offsets_on]
    if still:
        structure.append(f"innovations still biased with their offsets estimated ({', '.join(still)})")
    for kind, text in (("resets", "the filter broke down"), ("gated", "the gate rejected much of the data"),
                       ("structure", "much of the run beyond what the model can make"),
                       ("parameters", "parameters at a limit, far from the prior or not a car's")):
        if kind in failed:
            structure.append(text)
    if "linear_range" in failed:
        steps.append(_fill(NEXT_STEPS["linear_range"], "linear_range"))
    if structure:
        steps.append(_fill(NEXT_STEPS["structure"], "structure", what="; ".join(structure)))
    if not offsets_first:
        steps += offset_steps
    if failed.get("small"):
        steps.append(_fill(NEXT_STEPS["noise"], "noise", channels=", ".join(failed["small"])))
    if not_informed and failed:
        steps.append(_fill(NEXT_STEPS["excitation"], "excitation", parameters=", ".join(not_informed)))
    return steps


#: Flags (with one value each) that say how to read the log and which car it is: a ``run`` step carries them
#: from the command as typed, so that ``online-id diagnose LOG`` reads a CAN log through the same DBC.
READING_FLAGS = ("--vehicle", "--dbc", "--signals", "--can-channel", "--resample")


def _reading_flags(argv: list[str] | None) -> list[str]:
    """The :data:`READING_FLAGS` of ``argv`` with their values (``--flag VALUE`` or ``--flag=VALUE``)."""
    out, args = [], list(argv or [])
    for i, a in enumerate(args):
        name = a.split("=", 1)[0]
        if name in READING_FLAGS:
            out += [a] if "=" in a else args[i:i + 2]
    return out


def next_step_lines(consistency: dict | None, argv: list[str] | None = None, log=None) -> list[str]:
    """The next steps of a verdict as lines for a terminal: ``next: <why>: try <command>``. With ``argv``
    (the command as typed, without the program name) an ``add`` step is that command with the arguments
    added; a ``run`` step names ``log`` (or runs without LOG, on the built-in run, when None) and carries
    how the log is read and which car it is (:data:`READING_FLAGS` of ``argv``)."""
    import shlex

    lines = []
    for step in (consistency or {}).get("next_steps", ()):
        if "add" in step:
            command = (f"online-id {shlex.join([*argv, *step['add']])}" if argv
                       else f"add {shlex.join(step['add'])} to the command")
        else:
            run = [str(log) if a == "LOG" else a for a in step["run"] if a != "LOG" or log is not None]
            if log is not None and str(log) in run:  # the flags go right after the log
                at = run.index(str(log)) + 1
                run[at:at] = _reading_flags(argv)
            command = shlex.join(run)
        lines.append(f"next: {step['because']}; try: {command}")
    return lines


def verdict_lines(consistency: dict | None, argv: list[str] | None = None, log=None) -> list[str]:
    """:func:`verdict_line` and, after it, :func:`next_step_lines`."""
    return [verdict_line(consistency), *next_step_lines(consistency, argv, log)]


def verdict_line(consistency: dict | None) -> str:
    """One line for a terminal: ``verdict: consistent`` or ``verdict: INCONSISTENT — reason; reason``."""
    if consistency is None:
        return "verdict: not judged"
    if consistency.get("nothing_learned"):
        return f"verdict: nothing learned — {consistency['not_judged_because']}"
    if consistency["consistent"] is None or (consistency["consistent"] and not consistency.get("judged", True)):
        why = consistency.get("not_judged_because") or (f"fewer than {MIN_INNOVATIONS} corrections with each"
                                                         " channel after convergence or in the second half of the run")
        return f"verdict: not judged yet — {why}"
    if consistency["consistent"]:
        return "verdict: consistent (no check of the model against the data failed)"
    line = "verdict: INCONSISTENT — " + "; ".join(consistency["reasons"])
    if not consistency.get("judged", True):
        line += f" (the statistical tests were not run: {consistency.get('not_judged_because')})"
    return line
