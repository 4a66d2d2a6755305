"""Running an online estimator over a stream of samples, and what comes out of it.

:func:`run_estimator` is the loop every front end uses (a CSV log, a CAN log, a
live bus): it feeds samples one at a time, records a trace of the estimate,
and returns an :class:`EstimationResult` with named arrays. It stops cleanly
on Ctrl-C, keeping what was computed (``result.interrupted``).
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from online_id.filters import FilterConfig, OnlineEstimator, filter_class
from online_id.filters.prior import informed_flags
from online_id.stream.samples import MEASURED_CHANNELS, Sample, SampleArrays
from online_id.tracing import TraceRows, columns, csv_header, write_csv_rows
from online_id.trust.consistency import judge_estimator, moved_prior_sigma
from online_id.util.interrupts import interrupt_inside
from online_id.util.stages import stage
from online_id.util.threads import single_blas_thread
from online_id.vehicle.loader import Vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES, PARAMETER_UNITS, Parameters


@dataclass
class EstimateTrace:
    """How the estimate evolved: time (M,) [s], values (M, 8) [SI], std (M, 8) [SI]; the speed [m/s] and
    lateral acceleration [m/s², NaN where not measured] (M,) at those instants (not in the CSV)."""

    time: np.ndarray
    values: np.ndarray
    std: np.ndarray
    speed: np.ndarray | None = None
    lateral_acceleration: np.ndarray | None = None

    def write_csv(self, path: str | Path) -> None:
        """Columns: time, then <name>, <name>_std for each of the 8 parameters (SI units)."""
        with Path(path).open("w", encoding="utf-8") as fh:
            fh.write(csv_header())
            write_csv_rows(fh, self.time, self.values, self.std)


@dataclass
class EstimationResult:
    """Final estimate, its uncertainty, the events met on the way, and the trace.

    ``std`` is 1σ in SI units; ``relative_std`` is the log-scale σ (≈ relative σ), after every widening
    (correlated innovations, a polish's covariance). :attr:`informed` is read from that σ, whoever set it;
    whether a parameter *moved* is a separate fact, :attr:`moved_prior_sigma` (distance from the prior in
    prior σ). ``consistency`` is the verdict of :func:`online_id.trust.consistency.judge_estimator`.
    """

    filter: str
    samples: int
    wall_s: float
    parameters: Parameters
    std: np.ndarray
    relative_std: np.ndarray
    prior: Parameters
    prior_relative_std: np.ndarray
    events: dict[str, int]
    gated: dict[str, int]
    trace: EstimateTrace
    source: str = ""
    truth: Parameters | None = None
    interrupted: bool = False
    channels: list[str] = field(default_factory=list)
    covariance: np.ndarray | None = None
    cross_check: dict | None = None
    source_report: dict | None = None
    fixed: dict[str, float] = field(default_factory=dict)  # parameters held fixed [SI]
    prior_widened: dict | None = None  # PriorSpread.to_json_dict(): which prior σ were widened, and why
    consistency: dict | None = None
    #: the filter's own wall time [s] once ``wall_s`` covers more (the polish after it); None until then
    wall_s_filter: float | None = None
    #: σ / prior σ below which a parameter counts as informed (``FilterConfig.uninformed_ratio``)
    uninformed_ratio: float = 0.5
    #: the handling metrics with σ (:class:`online_id.handling.Handling`), set by the estimate workflow
    handling: object | None = None
    #: single-sample input glitches mended before the filter saw them (online_id.trust.spikes), as JSON dicts
    input_spikes: list = field(default_factory=list)
    #: the car the run was estimated as: ``{"name", "given"}`` (given: False when no vehicle was named and the
    #: default was used); set by the estimate workflow
    vehicle: dict | None = None
    #: the steering between samples the filter took (:mod:`online_id.model.intersample`)
    intersample: str | None = None

    @property
    def informed(self) -> dict[str, bool]:
        """Per parameter: did this run inform it? Its σ as reported (:attr:`relative_std`, after every
        widening) below ``uninformed_ratio`` of its prior σ; a parameter held at its prior (fixed, held for a
        missing roll channel, or every parameter once the filter diverged: σ = the prior's) never is
        (:func:`online_id.filters.prior.informed_flags`). The terminal, the JSON, ``batch``'s summary and
        the pages all read this one property."""
        return informed_flags(self.relative_std, self.prior_relative_std, self.fixed, self.uninformed_ratio)

    @property
    def moved_prior_sigma(self) -> np.ndarray:
        """|ln(θ/θ_prior)| / prior log-scale σ per parameter, (8,): how far the estimate moved."""
        return moved_prior_sigma(np.log(self.parameters.to_vector() / self.prior.to_vector()),
                                 self.prior_relative_std)
    #: extra states (offsets, effect parameters): {"offsets": {...}, "effects": {...}}, empty without
    extra_states: dict = field(default_factory=dict)
    #: RMS block innovation per channel [SI] (see OnlineEstimator.innovation_rms)
    innovation_rms: dict = field(default_factory=dict)
    #: the filter's own estimate when a batch polish replaced it (online_id.batchfit.polish), and the polish's details
    online: dict | None = None
    polish: dict | None = None
    #: the normalised block innovations, rows of online_id.filters.innovations.InnovationLog (not in the JSON)
    innovations: np.ndarray | None = None
    #: the plausibility checks of the inputs (PlausibilityReport.to_dict()): failures allowed by
    #: --allow-implausible are listed under "allowed"
    plausibility: dict | None = None
    #: τ: the filter's σ (std, relative_std, the extra states') widened by √τ, its covariance by τ, for innovations
    #: that are not white (online_id.trust.consistency); 1 when they are
    std_inflation: float = 1.0

    @property
    def sim_seconds(self) -> float:
        return float(self.trace.time[-1] - self.trace.time[0]) if len(self.trace.time) > 1 else 0.0

    def to_json_dict(self) -> dict:
        """The ``--json`` output; ``filter``, ``samples``, ``wall_s`` and ``parameters`` are stable keys."""
        values = self.parameters.to_vector()
        out = {
            "filter": self.filter,
            "samples": int(self.samples),
            "wall_s": round(float(self.wall_s), 4),  # the whole estimate: the filter and the polish after it
            "wall_s_filter": round(float(self.wall_s if self.wall_s_filter is None else self.wall_s_filter), 4),
            "parameters": {n: {"value": float(v), "std": float(s)}
                           for n, v, s in zip(PARAMETER_NAMES, values, self.std)},
            "intersample": self.intersample,
            "units": dict(PARAMETER_UNITS),
            "relative_std": {n: float(s) for n, s in zip(PARAMETER_NAMES, self.relative_std)},
            "prior": {n: {"value": float(v), "relative_std": float(s)}
                      for n, v, s in zip(PARAMETER_NAMES, self.prior.to_vector(), self.prior_relative_std)},
            "informed": dict(self.informed),
            "not_informed": [n for n, ok in self.informed.items() if not ok and n not in self.fixed],
            "fixed": dict(self.fixed),
            "prior_widened": self.prior_widened,
            "moved_prior_sigma": {n: float(m) for n, m in zip(PARAMETER_NAMES, self.moved_prior_sigma)},
            "events": {k: int(v) for k, v in sorted(self.events.items())},
            "outliers_by_channel": {k: int(v) for k, v in sorted(self.gated.items())},
            "channels": list(self.channels),
            "source": self.source,
            "interrupted": self.interrupted,
        }
        if self.covariance is not None:
            out["covariance"] = self.covariance.tolist()
        if self.cross_check is not None:
            out["cross_check"] = self.cross_check
        if self.source_report is not None:
            out["source_report"] = self.source_report
        if self.consistency is not None:
            out["consistency"] = self.consistency
        out.update(self.extra_states)  # "offsets": {channel: {value, std, unit}}, "effects": {label: {...}}
        out["innovation_rms"] = dict(self.innovation_rms)
        out["std_inflation"] = float(self.std_inflation)
        if self.online is not None:
            out["online"] = self.online
        if self.polish is not None:
            out["polish"] = self.polish
        if self.plausibility is not None:
            out["plausibility"] = self.plausibility
        if self.handling is not None:
            out["handling"] = self.handling.to_json_dict()
        if self.vehicle is not None:
            out["vehicle"] = dict(self.vehicle)
        if self.input_spikes:
            out["input_spikes"] = list(self.input_spikes)
        if self.truth is not None:
            t = self.truth.to_vector()
            out["truth"] = {n: float(v) for n, v in zip(PARAMETER_NAMES, t)}
            out["relative_error"] = {n: float(e) for n, e in zip(PARAMETER_NAMES, values / t - 1)}
        return out

    def write_json(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_json_dict(), indent=2) + "\n", encoding="utf-8")

    def table(self) -> str:
        """Parameter, unit, prior, estimate, 1σ, and truth with the error when known."""
        head = f"{'param':<5} {'unit':<10} {'prior':>11} {'estimate':>11} {'1σ':>9} {'1σ %':>7}"
        if self.truth is not None:
            head += f" {'truth':>11} {'error %':>8} {'err/σ':>6}"
        head += "  informed  moved [prior σ]"
        lines = [head, "-" * len(head)]
        truth = None if self.truth is None else self.truth.to_vector()
        for i, n in enumerate(PARAMETER_NAMES):
            v = self.parameters.to_vector()[i]
            row = (f"{n:<5} {PARAMETER_UNITS[n]:<10} {self.prior.to_vector()[i]:>11.5g} {v:>11.5g}"
                   f" {self.std[i]:>9.3g} {100 * self.relative_std[i]:>7.3f}")
            if truth is not None:
                err = v / truth[i] - 1
                ratio = f"{err / self.relative_std[i]:>6.2f}" if n not in self.fixed else f"{'-':>6}"
                row += f" {truth[i]:>11.5g} {100 * err:>8.3f} {ratio}"
            # two facts: did the data shrink σ (informed), and how far from the prior did it go (moved)
            informed = "FIXED" if n in self.fixed else "yes" if self.informed[n] else "no"
            row += f"  {informed:<8}  {self.moved_prior_sigma[i]:>5.1f}"
            lines.append(row)
        return "\n".join(lines)

    def events_summary(self) -> str:
        ev = dict(self.events)
        parts = [f"{ev.pop('samples', 0)} samples", f"{ev.pop('corrections', 0)} corrections"]
        samples = max(int(self.events.get("samples", 0)), 1)
        parts += [f"{k.replace('_', ' ')}: {v}" + (f" ({100 * v / samples:.1f} % of samples, not learned from)"
                                                   if k in ("outside_linear_range", "outside_model_range") else "")
                  for k, v in sorted(ev.items()) if v]
        if self.gated:
            parts.append("outliers by channel: " + ", ".join(f"{k} {v}" for k, v in sorted(self.gated.items())))
        return "; ".join(parts)


def make_estimator(vehicle: Vehicle, filter_name: str = "ekf", prior: Parameters | None = None,
                   prior_relative_std=None, initial: Parameters | None = None,
                   config: FilterConfig | None = None, fixed: dict[str, float] | None = None, effects=(),
                   offsets=False, channels=None) -> OnlineEstimator:
    """An estimator by name (a key of :data:`online_id.filters.FILTERS`: ``"ekf"``, ``"ukf"``); ``fixed``
    {name: value [SI]} holds parameters fixed.

    ``effects`` (:class:`~online_id.effects.base.Effect` instances) are estimated with the 8 as extra
    states (their filter form); ``offsets`` adds the sensor offsets of
    :data:`~online_id.effects.OFFSET_CHANNELS` (True) or of the channels listed. ``channels``: the measured
    channels the run has; with saturating tyres and no roll channel among them the roll parameters are held at
    the prior (:func:`online_id.filters.prior.hold_unobserved_roll`, in ``estimator.prior_spread.notes()``).
    """
    from online_id.effects import OFFSET_CHANNELS, sensor_offsets
    from online_id.filters.augment import Augmentation

    effects = list(effects)
    if offsets:
        labels = {e.label for e in effects}
        effects += [e for e in sensor_offsets(OFFSET_CHANNELS if offsets is True else offsets)
                    if e.label not in labels]
    augment = Augmentation.from_effects(effects, vehicle.known)
    held = ""
    # saturating tyres: the nonlinear model's form of the filter (filters/registry.py)
    cls = filter_class(filter_name, tyres=augment.has_tyres)
    if augment.has_tyres:
        from online_id.filters.prior import hold_unobserved_roll

        fixed, held = hold_unobserved_roll(channels, (prior or vehicle.prior).to_vector(), fixed)
    estimator = cls(vehicle, prior=prior, prior_log_std=prior_relative_std, initial=initial, config=config,
                    fixed=fixed, augment=augment)
    if held:
        estimator.prior_spread = replace(estimator.prior_spread, held_note=held)
    return estimator


@single_blas_thread
@stage("filter")
def run_estimator(estimator: OnlineEstimator, samples: Iterable[Sample] | SampleArrays, *, total: int | None = None,
                  progress: bool = False, trace_interval_s: float = 0.01, source: str = "",
                  truth: Parameters | None = None, channels: list[str] | None = None,
                  on_sample=None, trace_rows=None) -> EstimationResult:
    """Feed ``samples`` to ``estimator``; record the estimate every ``trace_interval_s`` seconds.

    ``progress`` shows a tqdm bar on stderr (``total`` samples expected). ``on_sample(estimator,
    sample)`` is called after each sample (for live tables). Ctrl-C ends the loop early and the
    result says ``interrupted``. ``trace_rows`` takes the trace's rows (:mod:`online_id.tracing`): None keeps
    every row in memory; a :class:`~online_id.tracing.StreamedTrace` writes them to its file as they come and
    keeps an evenly thinned copy, which ``result.trace`` then is (a live run of hours).
    """
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, unit="sample", unit_scale=True, desc=f"{estimator.name}", mininterval=0.5,
                   leave=False)
    rows = trace_rows if trace_rows is not None else TraceRows()  # one call per row: columns never unequal
    next_trace = -np.inf
    interrupted = False
    t0 = time.perf_counter()
    n = 0
    arrays = (samples if isinstance(samples, SampleArrays) and on_sample is None and estimator.takes_arrays(samples)
              else None)
    try:
        if arrays is not None:  # the array path (OnlineEstimator.update_many): the same numbers, compiled runs
            n = _run_arrays(estimator, arrays, rows, trace_interval_s, bar)
        recorded = None  # the last sample recorded: a row is the estimate after a sample was worked, at its time
        for sample in (() if arrays is not None else samples):
            estimator.update(sample)
            n += 1
            worked = estimator.last_worked  # (with the cubic input, the sample before this one: lookahead)
            if worked is not recorded and worked is not None and worked.time >= next_trace:
                theta, std = estimator.trace_values()  # = parameters, without the dataclass
                ay = worked.lateral_acceleration
                rows.add(worked.time, theta, std, worked.speed, np.nan if ay is None else ay)
                next_trace = worked.time + trace_interval_s
                recorded = worked
            if on_sample is not None:
                on_sample(estimator, sample)
            if bar is not None and n % 1000 == 0:
                bar.update(1000)
    except KeyboardInterrupt:
        interrupted = True
    except SystemError as exc:  # a signal while a compiled step was dispatched (online_id/util/interrupts.py)
        if interrupt_inside(exc) is None:
            raise
        interrupted = True
    finally:
        if arrays is not None:
            n = getattr(estimator, "array_position", 0)
        if bar is not None:
            bar.close()
    estimator.finish()  # the samples a delay's lagged reading or the cubic input's lookahead still hold
    worked = estimator.last_worked
    if arrays is None and worked is not None and worked is not recorded and worked.time >= next_trace:
        ay = worked.lateral_acceleration
        theta, std = estimator.trace_values()
        rows.add(worked.time, theta, std, worked.speed, np.nan if ay is None else ay)
    wall = time.perf_counter() - t0
    last = rows.last
    if estimator._last_time is not None and (last is None or last[0] != estimator._last_time):
        rows.add(estimator._last_time, estimator.parameters.to_vector(), estimator.parameter_std,
                 np.nan if last is None else last[-2], np.nan if last is None else last[-1])
    rows.flush()
    times, values, stds, speeds, lateral = columns(rows.rows())
    consistency = judge_estimator(estimator)
    # correlated innovations carry fewer independent errors than corrections: σ widened by √τ (trust/consistency.py)
    inflation = float(consistency.get("innovations", {}).get("std_inflation", 1.0))
    widen = np.sqrt(inflation)
    return EstimationResult(
        filter=estimator.name,
        samples=n,
        wall_s=wall,
        parameters=estimator.parameters,
        std=estimator.parameter_std * widen,
        relative_std=estimator.log_scale_std * widen,
        prior=estimator.prior,
        prior_relative_std=estimator.prior_log_std,
        uninformed_ratio=estimator.config.uninformed_ratio,
        intersample=estimator.config.intersample,
        events=dict(estimator.events),
        gated=dict(estimator.gated),
        trace=EstimateTrace(times, values, stds, speeds, lateral),
        source=source,
        truth=truth,
        interrupted=interrupted,
        channels=channels or [],
        covariance=estimator.parameter_covariance * inflation,
        fixed=dict(estimator.fixed),
        prior_widened=estimator.prior_spread.to_json_dict(),
        consistency=consistency,
        extra_states=_widened(estimator.extra_states, widen),
        std_inflation=inflation,
        innovation_rms=estimator.innovation_rms,
        innovations=estimator.innovations.rows().copy(),  # (the log's own rows are a view)
    )


def _run_arrays(estimator: OnlineEstimator, arrays: SampleArrays, rows, interval: float, bar) -> int:
    """The loop of :func:`run_estimator` over arrays: the same trace rows (the estimate after each sample
    ``interval`` after the last row's), the samples fed by :meth:`OnlineEstimator.update_many`."""
    times = arrays.time.tolist()
    record = np.zeros(len(times), dtype=bool)
    next_trace = -np.inf
    worked = estimator.valid_rows(arrays).tolist()  # a row is the estimate after a sample was worked
    for k, t in enumerate(times):
        if worked[k] and t >= next_trace:
            record[k] = True
            next_trace = t + interval
    ay_index = MEASURED_CHANNELS.index("lateral_acceleration")
    ay = np.where(arrays.absent[:, ay_index], np.nan, arrays.values[:, ay_index])
    done = [0]

    def on_record(k):
        theta, std = estimator.trace_values()
        rows.add(times[k], theta, std, float(arrays.speed[k]), float(ay[k]))
        if bar is not None and k + 1 - done[0] >= 1000:
            bar.update(k + 1 - done[0])
            done[0] = k + 1

    speed = arrays.speed

    def on_records(ks):  # rows with one estimate (between two corrections): its values read once
        theta, std = estimator.trace_values()
        last = ks[-1]
        taken = slice(ks[0], last + 1) if last - ks[0] + 1 == len(ks) else ks  # (consecutive rows: views)
        rows.add_many(arrays.time[taken], theta, std, speed[taken], ay[taken])
        if bar is not None and last + 1 - done[0] >= 1000:
            bar.update(last + 1 - done[0])
            done[0] = last + 1

    estimator.update_many(arrays, record=record, on_record=on_record, on_records=on_records)
    return len(times)


def _widened(extra_states: dict, factor: float) -> dict:
    """The extra states' report with every σ × ``factor``."""
    if factor == 1.0:
        return extra_states
    return {group: {key: ({**entry, "std": entry["std"] * factor} if "std" in entry else
                          {name: {**e, "std": e["std"] * factor} for name, e in entry.items()})
                    for key, entry in items.items()} for group, items in extra_states.items()}
