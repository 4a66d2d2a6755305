"""The sim-to-real gap: where the base model misses, which candidate effect explains it, how far
the gap shrinks with that effect, all judged on data the fit did not see.

1. The base model is fitted to the training data by least squares on the training blocks, from
   the vehicle's prior (or a given start, such as a batch fit's result).
2. Each candidate effect (:data:`online_id.effects.DIAGNOSIS_CANDIDATES`: the registry without the refinements of
   another, which are tried when named) is fitted from the base fit: 8
   parameters plus its own. For an effect on one channel, every channel is first screened with the
   8 parameters held at the base fit, and the channel that fits the training data best is fitted.
2b. A candidate the training data support (BIC down by more than ``MIN_BIC_DROP``) but the held-out data not
   (below ``MIN_REDUCTION``) may be the wrong form of the right law: its refinements are tried as in step 6, from
   its fit, and what they come to is a candidate of its own, judged against the base model as the others.
3. Every fit is scored on held-out data: the ``validate`` run, or else every
   ``HOLD_OUT_EVERY``-th ``SEGMENT_S`` segment of the run, left out of all least-squares fits.
   The held-out cost is the RMS over held-out blocks of the channel errors divided by each
   channel's measured standard deviation (Haro's eq 12 terms, normalised per block).
4. An effect is significant when it lowers the training BIC by more than ``MIN_BIC_DROP`` and
   the held-out cost by at least ``MIN_REDUCTION``; the verdict is the significant effect with the
   lowest held-out cost, or None.
5. Forward selection adds the other significant effects while each addition is itself significant.
6. Each named effect with a refinement in the registry (:attr:`~online_id.effects.base.Effect.refines`: a μ per
   axle for one μ; the axle loads moved by the longitudinal acceleration for a μ per axle) is refitted as that
   refinement, from the named values, with the rest of the named model; the refinement replaces it when it
   passes the same test against the named model, and the refinements of the refinement are tried next, kept or
   not (a μ per axle may add nothing on a run where loads moved by braking do); the other named effects
   are checked again with it (one a refinement makes redundant is dropped). One μ makes both axles
   saturate together, a car that spins at its limit; on the race car a μ per axle closed most of the
   remaining gap, and the one μ carried online ended at an implausible car.
7. The diagnosis goes on (issue 38): with the named effects in the model, every other candidate (not one the named
   effects refine or are refined by; a channel effect on the channels it is not named on) is screened with the 8
   parameters held (each channel of a channel effect), the best screened is fitted in full with the named
   effects, and it is named when that addition passes the same test (an addition with refinements, kept or a near
   miss as in step 2b, is refined as in step 6 and judged refined); again, until nothing is significant. An
   effect too small to show beside the largest gap alone (the base model's misfit hides it) is found once that
   gap is explained.
8. What is left: the named model's held-out block residuals per channel in units of a block mean's noise σ
   (σ/√q, σ the filters' ``measurement_std``, q samples a block: a model that misses nothing reads about 1 on
   white sensor noise, and 10 is a misfit ten times the noise), overall and by where they lie: by |a_y|, by the
   longitudinal acceleration (braking, coasting, traction: the logged ``longitudinal_acceleration``, or dV/dt
   from the speed, said which) and by speed.

Every model takes the steering between the log's samples as ``intersample`` says (:mod:`online_id.model.intersample`;
by default :data:`online_id.sim.BATCH_INTERSAMPLE`, the hold as before issue 36).
"""

from __future__ import annotations

import time as _time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from online_id.diagnosis import MIN_BIC_DROP, MIN_REDUCTION
from online_id.diagnosis.carry import carry_flags
from online_id.diagnosis.fitting import BlockModel, FamilyFit, boxed_in, fit_family, fit_threads
from online_id.diagnosis.gap import AMPLITUDE_BANDS, banded_rms, instantaneous_frequency, is_contiguous, locate
from online_id.diagnosis.kinematics import kinematics_of
from online_id.effects import DIAGNOSIS_CANDIDATES, EFFECTS
from online_id.errors import OnlineIdError
from online_id.io.tracklog import TrackRun
from online_id.model.lateral import PARAMETER_NAMES
from online_id.sim import BATCH_INTERSAMPLE
from online_id.sim.with_effects import has_force_law
from online_id.util.interrupts import interrupt_inside
from online_id.util.stages import absorb, stage, stage_of
from online_id.util.threads import single_blas_thread
from online_id.vehicle.loader import Vehicle

SEGMENT_S = 5.0
HOLD_OUT_EVERY = 4
STEERING_FREQUENCY_BANDS = ((0.0, 1.0), (1.0, 2.0), (2.0, 3.0), (3.0, 4.0), (4.0, 6.0))


def _is_significant(delta_bic: float, reduction: float) -> bool:
    """The test every addition of an effect must pass (see the module docstring)."""
    return bool(delta_bic < -MIN_BIC_DROP and reduction >= MIN_REDUCTION)


def _at_bound(effects) -> list[str]:
    """The effects' parameters fitted onto an edge of their fit range, as ``"label name=value"``: there the effect is
    absent (a delay of 0, a μ so high the tyres never saturate) or unphysical (a gravity share of −3), and what the
    fit explains is not the effect but the refitted 8 or some other error; such a fit is never significant."""
    out = []
    for e in effects:
        for p in e.fit_parameters():
            v, margin = e.values[p.name], 1e-6 * (p.upper - p.lower)
            if v <= p.lower + margin or v >= p.upper - margin:
                out.append(f"{e.label} {p.name}={v:.4g}")
    return out


def _effect_parameters(e) -> dict:
    """An effect's fitted values, with its channel for a channel effect."""
    return dict(e.values, **({"channel": e.channel} if e.channel else {}))


@dataclass
class EffectCandidate:
    name: str
    fit: FamilyFit
    held_out_cost: float
    delta_bic: float
    reduction: float
    significant: bool
    note: str = ""
    tried: list[str] = field(default_factory=list)
    #: its parameters fitted onto an edge of their range (:func:`_at_bound`): then never significant
    at_bound: list[str] = field(default_factory=list)

    def to_dict(self, base_cost: float) -> dict:
        params = {}
        for e in self.fit.effects:
            params.update(_effect_parameters(e))
        return {"name": self.name, "label": self.fit.label, "held_out_cost_before": base_cost,
                "held_out_cost_after": self.held_out_cost, "reduction": self.reduction,
                "significant": self.significant, "parameters": params, "delta_bic": self.delta_bic,
                "vehicle_parameters": dict(zip(PARAMETER_NAMES, self.fit.theta.tolist())),
                "evaluations": self.fit.evaluations, "note": self.note, "at_bound": self.at_bound}


@dataclass
class GapDiagnosis:
    gap: dict
    base: FamilyFit
    base_held_out_cost: float
    candidates: list[EffectCandidate]  # best first
    verdict: str | None
    how_far: dict | None
    held_out: str
    wall_s: float
    series: dict  # block series for the report figures
    #: forward selection from the verdict: the effects that together explain the gap (None without a verdict)
    combination: dict | None = None
    #: stopped early (Ctrl-C, or SIGTERM/SIGHUP in the CLI): the candidates fitted until then
    interrupted: bool = False
    #: the named effects as flags of ``estimate``/``fit``/``listen``/``batch`` (:mod:`online_id.diagnosis.carry`);
    #: None without a verdict
    carry: dict | None = None
    #: candidates (or the combination) whose fit failed: [{"name", "stage", "error"}]; the others stand
    failed: list[dict] = field(default_factory=list)
    #: the refinements tried: of a near miss (step 2b, ``"near_miss": True``, judged against it) and of the named
    #: effects (step 6): [{"of", "tried", "label", "held_out_cost_before", "held_out_cost_after", "reduction",
    #: "delta_bic", "significant", "parameters"}]
    refinements: list[dict] = field(default_factory=list)
    #: the steering between samples every model took (online_id/model/intersample.py)
    intersample: str = "hold"
    #: step 7: the effects added beside the named ones ({"effects", "label", "held_out_cost", "reduction", "steps"}),
    #: None when nothing was named or nothing else was left to try
    continued: dict | None = None
    #: step 8: what the named model (or the base model) still misses on the held-out data, in noise σ units
    remaining: dict | None = None
    #: step 2b: the candidates the training data support but the held-out data do not, each refined ({"of",
    #: "label" (what its refinements came to), "held_out_cost", "reduction", "delta_bic" (against the base model),
    #: "significant": then a candidate of its own)
    near_misses: list[dict] = field(default_factory=list)

    def to_json_dict(self) -> dict:
        return {"gap": self.gap,
                "effects": [c.to_dict(self.base_held_out_cost) for c in self.candidates],
                "verdict": self.verdict,
                "combination": self.combination,
                "how_far": self.how_far,
                "held_out": self.held_out,
                "base_model": {"parameters": dict(zip(PARAMETER_NAMES, self.base.theta.tolist())),
                               "held_out_cost": self.base_held_out_cost, "held": list(self.base.held)},
                "criteria": {"min_bic_drop": MIN_BIC_DROP, "min_reduction": MIN_REDUCTION},
                "wall_s": self.wall_s,
                "interrupted": self.interrupted,
                "carry": self.carry,
                "failed_candidates": self.failed,
                "refinements": self.refinements,
                "intersample": self.intersample,
                "continued": self.continued,
                "remaining_gap": self.remaining,
                "near_misses": self.near_misses}


def _held_out_cost(model: BlockModel, mask: np.ndarray, fit: FamilyFit) -> tuple[float, np.ndarray]:
    r = model.residuals(fit.theta, fit.effects)
    return float(np.sqrt(np.mean(np.sum(r[mask] ** 2, axis=1)))), r


@single_blas_thread
@stage("diagnosis")
def diagnose_gap(vehicle: Vehicle, run: TrackRun, validate: TrackRun | None = None,
             progress: Callable[[str, int, int], None] | None = None, effects: list[str] | None = None,
             start=None, intersample: str = BATCH_INTERSAMPLE) -> GapDiagnosis:
    """Diagnose the gap between the base model and ``run`` (see the module docstring)."""
    t0 = _time.perf_counter()
    names = effects or list(DIAGNOSIS_CANDIDATES)
    train_model = BlockModel(vehicle, run, intersample=intersample)
    blocks = np.arange(train_model.n_blocks)
    after_burn = blocks >= train_model.first_block
    if validate is not None:
        held_model = BlockModel(vehicle, validate, intersample=intersample)
        train = after_burn
        held = np.arange(held_model.n_blocks) >= held_model.first_block
        held_out = f"validation run {validate.source}"
    else:
        held_model = train_model
        segment = np.floor((train_model.block_time - run.time[0]) / SEGMENT_S).astype(int)
        held = after_burn & (segment % HOLD_OUT_EVERY == HOLD_OUT_EVERY - 1)
        train = after_burn & ~held
        held_out = f"every {HOLD_OUT_EVERY}th {SEGMENT_S:g} s segment of {run.source}"
    # an effect with nothing to act on in this run (a lateral-velocity sensor's misalignment without that channel, an
    # accelerometer's lever arm without a_y) is not a candidate; one asked for by name is said to be left out
    unfit = [n for n in names if not EFFECTS[n].candidates(train_model.channels)]
    names = [n for n in names if n not in unfit]
    total, step = len(names) + 1, 0

    def tick(what):
        nonlocal step
        step += 1
        if progress:
            progress(what, step, total)

    tick("base model")
    start = vehicle.prior.to_vector() if start is None else np.asarray(start, dtype=float)
    with stage("diagnosis base model fit"):
        base = fit_family(train_model, train, start)
    base_cost, base_r = _held_out_cost(held_model, held, base)
    candidates = []
    interrupted = False
    failed: list[dict] = [{"name": n, "stage": "diagnosis",
                           "error": f"not a candidate on this run's channels ({', '.join(train_model.channels)})"}
                          for n in (unfit if effects else ())]
    for name in names:  # an interruption keeps the base fit and the candidates fitted so far
        options = EFFECTS[name].candidates(train_model.channels)
        tick(f"candidate {name}" + (f" (screening {len(options)} channels)" if len(options) > 1 else ""))
        where = f"diagnosis candidate {name}"
        try:
            with stage(where):
                candidates.append(_fit_candidate(name, options, train_model, train, held_model, held, base,
                                                 base_cost, start))
        except (KeyboardInterrupt, Exception) as exc:
            if interrupt_inside(exc) is not None:
                interrupted = True
                break
            # this candidate is lost, the others stand: the failure is recorded on it
            line = str(exc) if isinstance(exc, OnlineIdError) else absorb(exc, where)
            failed.append({"name": name, "stage": stage_of(exc, where), "error": line})
    def guarded(name: str, where: str, step):
        """Run one step after the candidates; a failure is recorded and what was named stands (None returned),
        an interruption stops the diagnosis there."""
        nonlocal interrupted
        try:
            with stage(where):
                return step()
        except (KeyboardInterrupt, Exception) as exc:
            if interrupt_inside(exc) is not None:
                interrupted = True
            else:
                line = str(exc) if isinstance(exc, OnlineIdError) else absorb(exc, where)
                failed.append({"name": name, "stage": stage_of(exc, where), "error": line})
            return None

    # (filled as they go: an interruption or a failure keeps the refinements already found, and what they named)
    refinements: list[dict] = []
    near_misses: list[dict] = []
    refined: list[EffectCandidate] = []
    tried = {c.name for c in candidates}
    if not interrupted and _near_misses(candidates, tried):
        total += 1
        tick("refinements of the candidates the training data support")
        guarded("refinement", "diagnosis refinements of near misses", lambda: _refine_near_misses(
            candidates, tried, base, base_cost, train_model, train, held_model, held, refinements, near_misses,
            refined))
        candidates += refined
    candidates.sort(key=lambda c: c.held_out_cost)
    significant = [c for c in candidates if c.significant]
    verdict = significant[0].name if significant else None
    combination = None
    named = list(significant[0].fit.effects) if significant else []
    named_fit, named_cost = (significant[0].fit, significant[0].held_out_cost) if significant else (None, None)
    if len(significant) > 1 and not interrupted:
        total += 1
        tick("combinations of the significant effects")
        done = guarded("combination", "diagnosis combinations", lambda: _forward_selection(
            significant, train_model, train, held_model, held, base_cost))
        if done is not None:  # (else the single best effect stands as the verdict)
            combination, named_fit, named_cost = done
            named = list(named_fit.effects)

    # a near miss's refinements were judged against it alone: against another named model (forward selection
    # added an effect) they are tried again
    if any(named_fit is c.fit for c in refined):
        tried |= {st["tried"] for st in refinements if "tried" in st}
    if named_fit is not None and not interrupted and any(
            cls.refines in {e.name for e in named} and n not in tried for n, cls in EFFECTS.items()):
        total += 1
        tick("refinements of the named effects")
        done = guarded("refinement", "diagnosis refinements", lambda: _refine(
            named_fit, named_cost, tried, train_model, train, held_model, held))
        if done is not None:
            steps, named_fit, named_cost = done
            refinements = refinements + steps
            named = list(named_fit.effects)

    continued = None
    rest = [n for n in names if not _overlaps(n, named)]
    if named_fit is not None and not interrupted and rest:
        total += 1
        tick("going on: what else is significant beside the named effects")
        done = guarded("going on", "diagnosis going on", lambda: _go_on(
            rest, named_fit, named_cost, train_model, train, held_model, held, base_cost))
        if done is not None:
            continued, named_fit, named_cost = done
            named = list(named_fit.effects)

    # where: the base model's residuals on the training run (all blocks after the burn-in)
    series = {"base": base_r, "held": held, "held_model": held_model, "train_model": train_model,
              "train_residuals": train_model.residuals(base.theta)}
    gap = {"training_run": _locate(train_model, series["train_residuals"], after_burn),
           "held_out": _locate(held_model, base_r, held)}
    how_far = None
    if candidates:
        best = significant[0] if significant else candidates[0]
        _, after_r = _held_out_cost(held_model, held, best.fit)
        series["after"] = after_r
        series["after_label"] = best.fit.label
        series["train_after"] = train_model.residuals(best.fit.theta, best.fit.effects)
        how_far = {"effect": best.name, "significant": best.significant,
                   "channels": _how_far(held_model, base_r, after_r, held)}
    final = named_fit if named_fit is not None else base
    remaining = remaining_gap(held_model, held_model.residuals(final.theta, final.effects), held, final.label)
    remaining["lateral_kinematics"] = kinematics_of(run, validate)
    return GapDiagnosis(gap=gap, base=base, base_held_out_cost=base_cost, candidates=candidates, verdict=verdict,
                     how_far=how_far, held_out=held_out, wall_s=_time.perf_counter() - t0, series=series,
                     combination=combination, interrupted=interrupted,
                     carry=carry_flags(named, vehicle.known) if named else None, failed=failed,
                     refinements=refinements, intersample=intersample, continued=continued,
                     remaining=remaining,
                     near_misses=near_misses)


def _overlaps(name: str, named) -> bool:
    """Whether candidate ``name`` has nothing left to add beside the ``named`` effects: it is one of them (a channel
    effect on every channel it can sit on), or one a named effect refines or is refined by."""
    for e in named:
        if name != e.name and name in _refinement_family(e.name):
            return True
    if not EFFECTS[name].channels:
        return any(e.name == name for e in named)
    return not _free_options(name, named, EFFECTS[name].channels)


def _free_options(name: str, named, channels) -> list:
    """The starting instances of candidate ``name`` on the ``channels`` the named effects do not already give it
    (a sensor bias on a_y beside a named one on the yaw rate)."""
    taken = {e.channel for e in named if e.name == name}
    return [o for o in EFFECTS[name].candidates(channels) if o.channel not in taken]


def _tyre_law_named(fit: FamilyFit, known) -> bool:
    """Whether the named model's force law is the saturating tyres' (the compiled passes, which release the GIL)."""
    return has_force_law(fit.effects, fit.theta, known) and all(
        e.tyre_mu() is not None or e.force_law(fit.theta, known) is None for e in fit.effects)


def _go_on(rest: list[str], fit: FamilyFit, cost: float, train_model: BlockModel, train: np.ndarray,
           held_model: BlockModel, held: np.ndarray, base_cost: float) -> tuple[dict, FamilyFit, float]:
    """Step 7 of the module docstring. Returns what was tried (``steps``: each round's screen, ranked by training
    RSS, and the full fit of its best), the effects added, and the named fit and its held-out cost after them."""
    rest, steps, added = list(rest), [], []
    while rest:
        options = [(name, option) for name in rest for option in _free_options(name, fit.effects, train_model.channels)]

        def screen(item, fit=fit):
            # (the named model held: beside the saturating tyres a sensor effect's screen then costs no tyre pass)
            return fit_family(train_model, train, fit.theta, [*fit.effects, item[1]], free_theta=False, only_last=True)

        threads = fit_threads()
        if threads > 1 and _tyre_law_named(fit, train_model.vehicle.known):
            # the screens beside the saturating tyres (a steering effect's takes a pass of the compiled tyre model an
            # evaluation, with one or two columns: one core) side by side, each as it would run alone (the same list,
            # in order; another force law's solver keeps a warm start, shared: one by one). An interruption waits for
            # the screens running (a few seconds each), as a fit's threaded Jacobian columns do.
            with ThreadPoolExecutor(max_workers=threads) as pool:
                fits = list(pool.map(screen, options))
        else:
            fits = [screen(item) for item in options]
        screens = [(s.train_rss, name, option, s) for (name, option), s in zip(options, fits)]
        if not screens:  # (a channel effect free only on channels this run does not have)
            break
        screens.sort(key=lambda t: t[0])
        _, name, option, screen = screens[0]
        trial = fit_family(train_model, train, fit.theta, [*fit.effects, screen.effects[-1]])
        trial_cost, _ = _held_out_cost(held_model, held, trial)
        dbic = float(trial.bic() - fit.bic())
        reduction = float(1.0 - trial_cost / cost)
        bound = _at_bound(trial.effects[-1:])
        ok = _is_significant(dbic, reduction) and not bound
        step = {"added": name, "label": trial.label, "held_out_cost_before": cost, "held_out_cost_after": trial_cost,
                "reduction": reduction, "delta_bic": dbic, "significant": ok, "at_bound": bound,
                "parameters": _effect_parameters(trial.effects[-1]),
                "screened": [{"label": s.effects[-1].label, "train_rss": rss} for rss, _, _, s in screens]}
        steps.append(step)
        if not bound and (ok or (dbic < -MIN_BIC_DROP and reduction > 0)) and any(
                cls.refines == name for cls in EFFECTS.values()):
            # what is added (or nearly: a near miss, step 2b) is refined as a named effect is (step 6): one μ
            # added beside a sensor bias is the wrong form on a car whose axles differ
            found: list[dict] = []
            best = {"fit": trial, "cost": trial_cost}
            try:
                _refine(trial, trial_cost, set(), train_model, train, held_model, held, found, best,
                        only=len(trial.effects) - 1)
            finally:
                step["refinements"] = found
                kept, r_dbic, r_reduction, r_ok = _refined_against(found, best, fit, cost)
                if r_ok:
                    name, trial, trial_cost, ok = kept[-1], best["fit"], best["cost"], True
                    step.update(added=name, refined_from=step["added"], label=trial.label,
                                held_out_cost_after=trial_cost, reduction=r_reduction, delta_bic=r_dbic,
                                significant=True, parameters=_effect_parameters(trial.effects[-1]))
        if not ok:
            break
        added.append(name)
        fit, cost = trial, trial_cost
        rest = [n for n in rest if not _overlaps(n, fit.effects)]
    return {"effects": added, "label": fit.label, "held_out_cost": cost, "reduction": float(1.0 - cost / base_cost),
            "steps": steps}, fit, cost


#: Bands of the longitudinal acceleration [m/s²]: braking, coasting, traction.
LONGITUDINAL_BANDS = (("braking", -np.inf, -1.0), ("coasting", -1.0, 1.0), ("traction", 1.0, np.inf))
#: Bands of speed [m/s] (0-36, 36-72, 72-108, 108-144, over 144 km/h).
SPEED_BANDS = ((0.0, 10.0), (10.0, 20.0), (20.0, 30.0), (30.0, 40.0), (40.0, np.inf))


def remaining_gap(model: BlockModel, r: np.ndarray, mask: np.ndarray, label: str) -> dict:
    """Step 8 of the module docstring: the held-out residuals ``r`` (n_blocks, channels; divided by each channel's
    std, as :meth:`BlockModel.residuals`) of the model ``label``, per channel in noise σ units, overall and banded."""
    from online_id.filters.config import FilterConfig

    sigma = FilterConfig().measurement_std
    ay = (model.measured[:, model.channels.index("lateral_acceleration")]
          if "lateral_acceleration" in model.channels else np.zeros(model.n_blocks))
    keys = {"by_lateral_acceleration": (np.abs(ay[mask]), [(f"{lo:g}-{hi:g}" if np.isfinite(hi) else f"over {lo:g}",
                                                             lo, hi) for lo, hi in AMPLITUDE_BANDS]),
            "by_longitudinal_acceleration": (model.ax_blocks[mask], LONGITUDINAL_BANDS),
            "by_speed": (model.speed_blocks[mask], [(f"{lo:g}-{hi:g}" if np.isfinite(hi) else f"over {lo:g}", lo, hi)
                                                    for lo, hi in SPEED_BANDS])}
    channels = {}
    for i, c in enumerate(model.channels):
        e = r[mask, i] * model.std[i] / (sigma[c] / np.sqrt(model.q))
        entry = {"noise_std": sigma[c], "sigma": float(np.sqrt(np.mean(e ** 2))), "mean_sigma": float(np.mean(e))}
        for key, (values, bands) in keys.items():
            entry[key] = [{"band": name, "n": int(sel.sum()),
                           "sigma": float(np.sqrt(np.mean(e[sel] ** 2))) if sel.any() else None}
                          for name, lo, hi in bands for sel in [(values >= lo) & (values < hi)]]
        channels[c] = entry
    return {"model": label, "longitudinal_acceleration": model.ax_source, "channels": channels,
            "block_samples": model.q, "sigma_unit": "a block mean's sensor noise σ/√q (σ: noise_std)",
            "units": {"by_lateral_acceleration": "m/s²", "by_longitudinal_acceleration": "m/s²", "by_speed": "m/s"}}


def _refinement_family(name: str) -> set[str]:
    """``name`` and every effect it refines or is refined by, along the chain both ways (``tire_saturation`` →
    ``tire_saturation_axles`` → ``load_transfer``): one law, of which the diagnosis names one at a time."""
    family, grown = {name}, True
    while grown:
        more = {n for n, cls in EFFECTS.items() if cls.refines in family or n in
                {EFFECTS[f].refines for f in family if f in EFFECTS}} - family
        family |= more
        grown = bool(more)
    return family


def _near_misses(candidates: list[EffectCandidate], tried: set[str]) -> list[EffectCandidate]:
    """The candidates the training data support (BIC down by more than ``MIN_BIC_DROP``, no parameter at an edge of
    its range) though the held-out data do not yet (the held-out cost down, by less than ``MIN_REDUCTION``), with
    refinements not tried, best held-out cost first."""
    return [c for c in sorted(candidates, key=lambda c: c.held_out_cost)
            if not c.significant and not c.at_bound and c.delta_bic < -MIN_BIC_DROP and c.reduction > 0
            and any(cls.refines == c.name and n not in tried for n, cls in EFFECTS.items())]


def _refine_near_misses(candidates: list[EffectCandidate], tried: set[str], base: FamilyFit, base_cost: float,
                        train_model: BlockModel, train: np.ndarray, held_model: BlockModel, held: np.ndarray,
                        steps: list[dict], summaries: list[dict], refined: list[EffectCandidate]) -> None:
    """Step 2b of the module docstring: a candidate the training data support (BIC down by more than
    ``MIN_BIC_DROP``) that the held-out data do not may be the wrong form of the right law: one μ on a car whose
    axles differ (on the race car's later laps one μ lowers the held-out cost by 1 %, a μ per axle by 20 %). Each
    such candidate's refinements are tried as step 6 tries a named effect's, from its fit; what they come to is
    a candidate of its own, named after the last refinement kept, when it passes the test against the base model.
    Fills ``steps`` (each marked ``near_miss``), ``summaries`` (one per near miss) and ``refined`` (the new
    candidates) as it goes: an interruption or a failure keeps what was found (a refinement kept is judged
    against the base model before the exception goes on)."""
    tried = set(tried)
    for c in _near_misses(candidates, tried):
        found: list[dict] = []
        best = {"fit": c.fit, "cost": c.held_out_cost}
        try:
            _refine(c.fit, c.held_out_cost, tried, train_model, train, held_model, held, found, best)
        finally:
            steps += [{**st, "near_miss": True} for st in found]
            tried |= {st["tried"] for st in found if "tried" in st}
            fit, cost = best["fit"], best["cost"]
            kept, dbic, reduction, ok = _refined_against(found, best, base, base_cost)
            summaries.append({"of": c.name, "label": fit.label if kept else None, "held_out_cost": cost,
                              "reduction": reduction, "delta_bic": dbic, "significant": ok})
            if ok:
                refined.append(EffectCandidate(kept[-1], fit, cost, dbic, reduction, True, EFFECTS[kept[-1]].note,
                                               [c.fit.label, *(st["label"] for st in found if "tried" in st)]))


def _refined_against(found: list[dict], best: dict, fit: FamilyFit, cost: float) -> tuple:
    """What a chain of refinements (``found``, :func:`_refine`'s steps; ``best``, its fit and held-out cost) came to
    against ``fit`` and its held-out ``cost`` (the base model for a near miss, the named model for going on's
    addition): the refinements kept, ΔBIC, the held-out reduction, and whether the refined model passes the test
    (a refinement kept, its last effect off its range's edges)."""
    kept = [st["tried"] for st in found if st.get("significant") and "tried" in st]
    dbic, reduction = float(best["fit"].bic() - fit.bic()), float(1.0 - best["cost"] / cost)
    ok = bool(kept) and _is_significant(dbic, reduction) and not _at_bound(best["fit"].effects[-1:])
    return kept, dbic, reduction, ok


#: A refinement's start is taken as it is unless its training cost is more than this many times the named fit's.
BROKEN_START_FACTOR = 4.0
#: Where in its range each new parameter of a refinement is tried when its own start breaks the model.
START_GRID = (0.25, 0.5, 0.75)


def _refined_starts(effect, refinement_cls, channels) -> list:
    """The refinement of ``effect`` starting where it ended: each of its parameters at the value of the named
    effect's parameter of that name or of the name it extends (``mu_front`` and ``mu_rear`` from ``mu``); then the
    same with each parameter the named effect does not give at :data:`START_GRID`'s points of its range (all
    combinations), for :func:`_good_start`."""
    start = refinement_cls.candidates(channels)[0]
    values, new = [], []
    for i, p in enumerate(start.fit_parameters()):
        match = [v for k, v in effect.values.items() if p.name == k or p.name.startswith(k + "_")]
        values.append(float(match[0]) if match else float(start.values[p.name]))
        if not match:  # its own start, and points across its range (a range without ends: its start only)
            new.append((i, [values[-1], *(p.lower + f * (p.upper - p.lower) for f in START_GRID)]))
    out = [start.with_vector(values)]
    grids = np.array(np.meshgrid(*[g for _, g in new], indexing="ij")).reshape(len(new), -1).T if new else []
    for point in grids:
        v = list(values)
        for (i, _), x in zip(new, point):
            v[i] = float(x)
        if v != values and np.all(np.isfinite(v)):
            out.append(start.with_vector(v))
    return out


def _good_start(fit: FamilyFit, i: int, starts: list, train_model: BlockModel, train: np.ndarray) -> list:
    """The named effects with effect ``i`` replaced by the first of ``starts`` (:func:`_refined_starts`), unless
    its training cost is more than :data:`BROKEN_START_FACTOR` times the named fit's: a law whose parameter's
    default breaks the model (``load_sensitivity`` from a μ per axle starts at p = 1, where the race car's rear
    keeps 27 % of its curve under 1 g of braking and the open-loop car spins: v_y of 5,000 m/s, and at 25 Hz
    the fit never left it). Then the start with the lowest training cost of them all (a pass each)."""
    def with_start(e):
        return [*fit.effects[:i], e, *fit.effects[i + 1:]]

    def cost(effects):  # (as the fit counts it: a refused or non-finite pass is a residual of 1e3)
        try:
            r = train_model.residuals(fit.theta, effects)[train].ravel()
        except OnlineIdError:
            return np.inf
        return float(np.sum(np.where(np.isfinite(r), r, 1e3) ** 2))

    first = with_start(starts[0])
    first_cost = cost(first) if len(starts) > 1 else 0.0
    if first_cost <= BROKEN_START_FACTOR * fit.train_rss:
        return first
    costs = [first_cost, *(cost(with_start(e)) for e in starts[1:])]
    return with_start(starts[int(np.argmin(costs))])


def _refine(fit: FamilyFit, cost: float, tried: set[str], train_model: BlockModel, train: np.ndarray,
            held_model: BlockModel, held: np.ndarray, steps: list[dict] | None = None,
            best: dict | None = None, only: int | None = None) -> tuple[list[dict], FamilyFit, float]:
    """Step 6 of the module docstring: each named effect's refinements (not already among the candidates),
    refitted with the rest of the named model from its values; kept when significant against the named
    model. Once a refinement is kept, each other named effect is checked again (removed and refitted): one that
    no longer passes the test, judged as its addition was, is dropped (``"without"`` steps). Returns what was
    tried, and the named fit and its held-out cost after the refinements kept; ``steps`` and ``best`` (``{"fit",
    "cost"}``), when given, are filled as it goes (what an interruption leaves); ``only``: the index of the one
    effect to refine (going on's addition), the others not checked again."""
    steps = [] if steps is None else steps
    best = {} if best is None else best
    tried = set(tried)
    for i, effect in enumerate(list(fit.effects)):
        if only is not None and i != only:
            continue
        # along the chain (one μ → a μ per axle → loads moved by a_x), each tried against the model named so far
        # and from its values; one not kept still leads to its own refinements (a μ per axle may add nothing on a
        # run where the loads moving with a_x does)
        queue = [n for n, cls in EFFECTS.items() if cls.refines == effect.name and n not in tried]
        while queue:
            name = queue.pop(0)
            tried.add(name)
            effects = _good_start(fit, i, _refined_starts(fit.effects[i], EFFECTS[name], train_model.channels),
                                  train_model, train)
            trial = fit_family(train_model, train, fit.theta, effects)
            trial_cost, _ = _held_out_cost(held_model, held, trial)
            dbic = float(trial.bic() - fit.bic())
            reduction = float(1.0 - trial_cost / cost)
            bound = _at_bound(trial.effects[i:i + 1])
            ok = _is_significant(dbic, reduction) and not bound
            steps.append({"of": fit.effects[i].name, "tried": name, "label": trial.label,
                          "held_out_cost_before": cost, "held_out_cost_after": trial_cost, "reduction": reduction,
                          "delta_bic": dbic, "significant": ok, "at_bound": bound,
                          "parameters": _effect_parameters(trial.effects[i])})
            if ok:
                fit, cost = trial, trial_cost
                best.update(fit=fit, cost=cost)
            queue += [n for n, cls in EFFECTS.items() if cls.refines == name and n not in tried]
    refined = {st["tried"] for st in steps if st["significant"]}
    # what a refinement explains, another may no longer add
    for other in list(fit.effects) if refined and only is None else ():
        if other.name in refined or len(fit.effects) < 2:
            continue
        trial = fit_family(train_model, train, fit.theta, [e for e in fit.effects if e is not other])
        trial_cost, _ = _held_out_cost(held_model, held, trial)
        dbic = float(fit.bic() - trial.bic())  # what keeping ``other`` is worth, judged as its addition was
        reduction = float(1.0 - cost / trial_cost)
        keep = _is_significant(dbic, reduction)
        steps.append({"of": other.name, "without": other.label, "label": trial.label,
                      "held_out_cost_before": cost, "held_out_cost_after": trial_cost, "reduction": reduction,
                      "delta_bic": dbic, "significant": keep, "dropped": not keep,
                      "parameters": _effect_parameters(other)})
        if not keep:
            fit, cost = trial, trial_cost
            best.update(fit=fit, cost=cost)
    return steps, fit, cost


def _fit_candidate(name: str, options: list, train_model: BlockModel, train: np.ndarray, held_model: BlockModel,
                   held: np.ndarray, base: FamilyFit, base_cost: float, start=None) -> EffectCandidate:
    """One candidate effect fitted from the base fit and scored on the held-out data. A channel effect
    (several ``options``): every channel is screened with the base parameters held, on the training data,
    then the best channel is fitted in full. A candidate whose fit the base fit's range boxed in
    (:func:`~online_id.diagnosis.fitting.boxed_in`: the base fit of a run with an effect it lacks can put a parameter
    far off, a lever-arm accelerometer's b2 at 0.025 m, true 1.04 m, and the candidate stopped at its range's edge,
    held-out −60 % where the effect gives −97 %; issue 38) is fitted again from ``start`` (the base fit's own start),
    the effect from where its first fit ended; the lower training cost wins, the evaluations of both counted."""
    if len(options) > 1:
        screens = [fit_family(train_model, train, base.theta, [e], free_theta=False) for e in options]
        options = [min(zip(screens, options), key=lambda se: se[0].train_rss)[1]]
        tried = [sc.label for sc in screens]
    else:
        tried = [options[0].label]
    fit = fit_family(train_model, train, base.theta, options)
    if start is not None and boxed_in(fit, base.theta, start):
        again = fit_family(train_model, train, start, fit.effects)
        again.evaluations += fit.evaluations
        fit = again if again.train_rss < fit.train_rss else replace(fit, evaluations=again.evaluations)
    cost, _ = _held_out_cost(held_model, held, fit)
    dbic = fit.bic() - base.bic()
    reduction = 1.0 - cost / base_cost
    bound = _at_bound(fit.effects)
    return EffectCandidate(name, fit, cost, float(dbic), float(reduction),
                           _is_significant(dbic, reduction) and not bound, EFFECTS[name].note, tried, bound)


def _forward_selection(significant: list[EffectCandidate], train_model: BlockModel, train: np.ndarray,
                       held_model: BlockModel, held: np.ndarray, base_cost: float) -> tuple[dict, list]:
    """Start from the best effect; add, one at a time, the other significant effect that lowers the
    held-out cost most, refitting everything together, while the addition is itself significant (training
    BIC down by more than MIN_BIC_DROP, held-out cost down by at least MIN_REDUCTION). One effect fitted
    alone also takes up part of another's gap, so a candidate that is significant alone may add nothing
    once the real causes are in. Returns the combination's summary, its fit and that fit's held-out cost."""
    current = significant[0].fit
    cost = significant[0].held_out_cost
    chosen, steps = [significant[0]], []
    remaining = significant[1:]  # one candidate per effect name
    while remaining:
        trials = []
        for c in remaining:
            fit = fit_family(train_model, train, current.theta, [*current.effects, *c.fit.effects])
            trial_cost, _ = _held_out_cost(held_model, held, fit)
            trials.append((trial_cost, c, fit))
        trial_cost, c, fit = min(trials, key=lambda t: t[0])
        dbic = fit.bic() - current.bic()
        reduction = 1.0 - trial_cost / cost
        ok = _is_significant(dbic, reduction)
        steps.append({"added": c.name, "label": c.fit.label, "held_out_cost_before": cost,
                      "held_out_cost_after": trial_cost, "reduction": float(reduction), "delta_bic": float(dbic),
                      "significant": ok})
        if not ok:
            break
        chosen.append(c)
        current, cost = fit, trial_cost
        remaining.remove(c)
    params = {e.label: _effect_parameters(e) for e in current.effects}
    return {"effects": [c.name for c in chosen], "label": current.label, "held_out_cost": cost,
            "reduction": float(1.0 - cost / base_cost), "parameters": params,
            "vehicle_parameters": dict(zip(PARAMETER_NAMES, current.theta.tolist())), "steps": steps}, \
        current, cost


def _locate(model: BlockModel, r: np.ndarray, mask: np.ndarray) -> dict:
    t = model.block_time[mask]
    residuals = {c: r[mask, i] * model.std[i] for i, c in enumerate(model.channels)}
    measured = {c: model.measured[mask, i] for i, c in enumerate(model.channels)}
    ay = model.measured[:, model.channels.index("lateral_acceleration")][mask] \
        if "lateral_acceleration" in model.channels else np.zeros(mask.sum())
    if is_contiguous(mask):  # one stretch: spectra are meaningful
        return locate(t, residuals, measured, model.steering_blocks[mask], ay)
    # held-out segments: no spectrum across the joins; bands by steering frequency and amplitude only
    finst = instantaneous_frequency(model.block_time, model.steering_blocks)[mask]
    out = {}
    for c, e in residuals.items():
        out[c] = {"rms": float(np.sqrt(np.mean(e ** 2))), "relative_rms": float(np.sqrt(np.mean(e ** 2)) /
                                                                                np.std(measured[c])),
                  "by_steering_frequency": banded_rms(e, np.nan_to_num(finst, nan=-1.0), STEERING_FREQUENCY_BANDS),
                  "by_lateral_acceleration": banded_rms(e, np.abs(ay), AMPLITUDE_BANDS)}
    return out


def _how_far(model: BlockModel, before: np.ndarray, after: np.ndarray, mask: np.ndarray) -> dict:
    """Held-out RMS error per channel [SI], overall and per steering-frequency band, before and after."""
    finst = np.nan_to_num(instantaneous_frequency(model.block_time, model.steering_blocks), nan=-1.0)[mask]
    out = {}
    for i, c in enumerate(model.channels):
        b, a = before[mask, i] * model.std[i], after[mask, i] * model.std[i]
        rb, ra = float(np.sqrt(np.mean(b ** 2))), float(np.sqrt(np.mean(a ** 2)))
        bands = []
        for (lo, hi), xb, xa in zip(STEERING_FREQUENCY_BANDS, banded_rms(b, finst, STEERING_FREQUENCY_BANDS),
                                    banded_rms(a, finst, STEERING_FREQUENCY_BANDS)):
            ratio = xa["rms"] / xb["rms"] if xb["rms"] else None
            bands.append({"band_hz": [lo, hi], "before": xb["rms"], "after": xa["rms"], "ratio": ratio})
        out[c] = {"before": rb, "after": ra, "ratio": ra / rb if rb else None, "by_steering_frequency": bands}
    return out
