"""How samples reach an online filter's hooks: time bookkeeping and the guards on each sample.

:class:`SampleFeeding` is the part of :class:`~online_id.filters.base.OnlineEstimator` that takes samples, one
by one (:meth:`~SampleFeeding.update`, river's ``learn_one``) or as arrays (:meth:`~SampleFeeding.update_many`,
the same numbers, runs of ordinary samples at once): it accepts or counts a sample (invalid, out of order), steps
the filter over the time since the last one (gaps bridged or restarted, low speed frozen), hands the measurements
to the filter's ``_observe`` and closes a block every ``correct_every`` samples with the estimator's
:class:`~online_id.filters.health.FilterHealth`. It is the estimator's own loop over its hooks, not a role of its
own (it reads and writes the estimator's time bookkeeping at every sample, set up in ``OnlineEstimator.__init__``),
so it is a base class written apart rather than a collaborator.
"""

from __future__ import annotations

import math

import numpy as np

from online_id.filters.config import RESTART_PERIODS
from online_id.model.intersample import LOOKAHEAD, run_inputs, split_step
from online_id.stream.gaps import GAP_FACTOR, bridge_inputs
from online_id.stream.samples import MEASURED_CHANNELS, Sample, SampleArrays

_YAW, _AY = MEASURED_CHANNELS.index("yaw_rate"), MEASURED_CHANNELS.index("lateral_acceleration")
#: The lateral velocity: worked per unit speed, as the sideslip angle v_y / V (model/lateral.py VY), its noise
#: variance R [(m/s)²] divided by V² (``OnlineEstimator._R_now``).
_VY = MEASURED_CHANNELS.index("lateral_velocity")


class SampleFeeding:
    """Streaming and array feeding of an :class:`~online_id.filters.base.OnlineEstimator` (see the module
    docstring); not used alone."""

    def update(self, sample: Sample) -> None:
        """Feed one sample. Never raises on bad data: problems are counted in :attr:`events`.

        With a delay among the extra states the sample is held until its lagged channels have arrived
        (filters/lagged.py), and worked then; :meth:`finish` works those still held at the end of a stream."""
        retimer = self._retimer
        if retimer is None:
            self._update(sample)
            return
        t = sample.time
        last = retimer.last_time
        if not _finite(t) or (last is not None and t <= last):  # the reading needs increasing times
            self._events["samples"] += 1
            self._events["invalid_samples"] += 1
            return
        self._read_lags()
        for s in retimer.push(sample):
            self._update(s)

    def finish(self) -> None:
        """The stream has ended: work the samples still held for a delay's lagged reading (their readings
        beyond the end are absent), and the one a cubic input waits with for its successor (its end slope
        one-sided). Without a delay or that sample, nothing to do."""
        if self._retimer is not None:
            self._read_lags()
            for s in self._retimer.drain():
                self._update(s)
        for _, w, v in self._inputs.drain():
            sample, self._waiting = self._waiting, None
            self._work(sample, w, v)

    @property
    def lookahead(self) -> int:
        """Samples a streaming ``update`` waits for before it works a sample (1 with the cubic input: the
        estimate after ``update(sample)`` is that of the samples before it; :meth:`finish` works the last)."""
        return LOOKAHEAD[self.config.intersample]

    def _read_lags(self) -> None:
        """Give the reading the current lags (they move only at corrections)."""
        e = self._extra_mean().tolist()
        if e != self._lags_read:
            self._lags_read = e
            self._retimer.set_lags(*self.augment.channel_lags(np.array(e)))

    def _accept(self, sample: Sample) -> bool:
        """Count the sample; whether it can be worked (finite time and inputs, time after the last valid one)."""
        self._events["samples"] += 1
        t, dH, V = sample.time, sample.steering_wheel_angle, sample.speed
        if not (_finite(t) and _finite(dH) and _finite(V)):
            self._events["invalid_samples"] += 1
            return False
        if self._accepted_time is not None and t <= self._accepted_time:
            self._events["invalid_samples"] += 1
            return False
        self._accepted_time = t
        return True

    def _update(self, sample: Sample) -> None:
        if not self._accept(sample):
            return
        ready = self._inputs.push(sample.time, sample.steering_wheel_angle / self.known.steering_ratio, sample.speed)
        if not self.lookahead:
            for _, w, v in ready:
                self._work(sample, w, v)
            return
        previous, self._waiting = self._waiting, sample  # (the cubic: the sample before is ready now, if any)
        for _, w, v in ready:
            self._work(previous, w, v)

    def _work(self, sample: Sample, w, v_step) -> None:
        """One valid sample: the step into it (input ``w``, speed ``v_step``: None for the first), its guards,
        its measurements, the correction when it closes a block."""
        self.last_worked = sample
        if self.augment.moves_loads:  # (the tyre law's axle loads, from this sample's a_x)
            self._read_loads(sample)
        t, dH, V = sample.time, sample.steering_wheel_angle, sample.speed
        delta = dH / self.known.steering_ratio
        moving = abs(V) >= self.config.min_speed_mps
        observed = False
        if self._last_time is not None:
            dt = t - self._last_time
            prev_delta, prev_V = self._last_input
            missing = self._clock.missing(dt)
            self._clock.observe(dt)
            if self._clock.rough_period != self._period:
                self._scale_to_period(self._clock.rough_period)
            if missing:
                self._events["missing_samples"] += missing
            if dt > self._max_gap and self._period is not None:  # no period yet (3 steps): no step is a gap
                self._events["gaps"] += 1
                self._restart_states()
            elif not moving or abs(prev_V) < self.config.min_speed_mps:
                self._events["frozen_low_speed"] += 1
                self._restart_states()
            elif self._states_valid:
                if missing:  # see online_id/stream/gaps.py: hold δ across a gap and the fit is biased
                    if self.config.intersample == "hold":
                        h, deltas = bridge_inputs(dt, missing, prev_delta, delta)
                        parts = [(d, 0.0, 0.0, 0.0) for d in deltas.tolist()]
                    else:  # the step's own curve, cut into sub-steps of the period (one table)
                        h, parts = dt / (missing + 1), split_step(w, missing + 1)
                    for part in parts:
                        self._propagate(h, np.asarray(part, dtype=float), v_step)
                    if missing > self.config.max_bridged_samples:
                        self._gap_state_variance = self._gap_state_variance + self._initial_state_variance * min(
                            1.0, dt / self._max_gap)
                else:
                    self._propagate(dt, w, v_step)
                self._since_correction += 1
                values, mask = self._measurement_vector(sample)
                if mask[_VY]:  # the lateral velocity per unit speed: the sideslip angle (model/lateral.py VY)
                    values = _per_unit_speed(values, V)
                ay = sample.lateral_acceleration
                if _finite(ay) and _finite(sample.yaw_rate):
                    self.kinematics.add(dt, V, sample.yaw_rate, ay)
                if ay is not None and abs(ay) > self._ay_limit:
                    self._events[self._ay_limit_event] += 1  # propagated, not learned from
                elif self._any_configured if mask is self._configured else mask.any():
                    self.health.seen |= mask
                    self._observe(values, mask, delta, V)
                observed = True
        elif not moving:
            self._events["frozen_low_speed"] += 1
        self._last_time, self._last_input = t, (delta, V)
        if moving and not self._states_valid:
            self._states_valid = True  # the states restart here; the next samples inform them
            return
        if observed and self._since_correction >= self._correct_every:
            self.health.correct()

    def _read_loads(self, sample: Sample) -> None:
        """A variant whose tyre law's axle loads follow the longitudinal acceleration reads ``sample``'s here (the
        saturating tyre filters, :mod:`online_id.filters.tyre_filters`)."""

    def _scale_to_period(self, period: float | None) -> None:
        """The thresholds in time that a slow log's period would defeat (FilterConfig.max_gap_s, max_block_s), and
        the tempering, scaled to the log's rate (:data:`~online_id.filters.config.TEMPER_REFERENCE_RATE_HZ`)."""
        self._period = period
        if period is None or not period > 0:
            return
        self._max_gap = max(self.config.max_gap_s, RESTART_PERIODS * period)
        # the 1e-6: a period of exactly max_block_s / k in floating point still gives k
        span = self.max_block_s if self.config.max_block_s is None else self.config.max_block_s
        self._correct_every = max(1, min(self.config.correct_every, int(span / period + 1e-6)))
        self.health.scale_tempering(period)

    def update_many(self, samples, *, start: int = 0, stop: int | None = None, record=None,
                    on_record=None, on_records=None) -> None:
        """Feed several samples: a :class:`~online_id.stream.samples.SampleArrays` (the array path, below), or
        any iterable of :class:`Sample` (fed one by one to :meth:`update`).

        The array path gives the numbers :meth:`update` gives for the same samples one by one (the test
        ``tests/test_array_path.py``): runs of ordinary samples (valid, moving, no gap, the same channels,
        every value finite, the period not being refreshed) go to the variant's
        :meth:`_propagate_observe_many` up to the sample that closes a block, whose correction follows as it
        would; any other sample (the first, a gap, a stop, a NaN, a spike of a_y, ...) goes through
        :meth:`update`, with every guard and warning. With a delay's lagged reading every sample does.

        ``start``, ``stop``: the rows to feed. ``record`` (n,) bool and ``on_record(k)``: called after row k
        where ``record[k]`` (the trace of online_id.estimation.run_estimator). ``on_records(rows)``, if given,
        takes several such rows at once (a list, increasing) where the estimate is the same after each (the
        rows between two corrections of the array path: a 100 Hz trace has a row at every sample), with the
        numbers ``on_record`` would be called with; ``on_record`` still takes the rows worked one by one."""
        if not isinstance(samples, SampleArrays):
            for s in samples:
                self.update(s)
            self.finish()
            return
        arrays = samples
        n = len(arrays) if stop is None else stop
        self.array_position = start  # the next row to feed (what was fed, should the run be interrupted)
        inputs = None if self._retimer is not None or self.augment.moves_loads else self._array_inputs(arrays)
        if inputs is None or n <= start:
            for k in range(start, n):
                self.update(arrays.sample(k))
                self.array_position = k + 1
                if record is not None and record[k]:
                    on_record(k)
            self.finish()
            return
        W, S, slopes = inputs
        t, V = arrays.time, arrays.speed
        delta = arrays.steering_wheel_angle / self.known.steering_ratio
        values, absent = arrays.values, arrays.absent
        min_speed = self.config.min_speed_mps
        with np.errstate(invalid="ignore"):
            # a sample the fast path may take, judged alone: finite inputs and values, moving
            alone = (np.isfinite(t) & np.isfinite(delta) & np.isfinite(V) & (np.abs(V) >= min_speed)
                     & (np.isfinite(values) | absent).all(axis=1))
            # and with the sample before it: times increasing, the one before also such a sample
            step = np.empty(len(t))
            step[0] = np.nan
            step[1:] = t[1:] - t[:-1]
            plain = alone & (step > 0)
            plain[1:] &= alone[:-1] & (absent[1:] == absent[:-1]).all(axis=1)  # (and the same channels)
        # the rows as Python lists: a run is a few samples, read a few at a time (numpy's calls cost more there)
        rows = _Rows(t, delta, V, values, absent, step, W, S)
        alone_l, plain_l, step_l, t_l = alone.tolist(), plain.tolist(), rows.step, rows.t
        record_l = None if record is None else record.tolist()

        held: list[int] = []  # rows to record whose estimate is the one now (on_records: recorded at once)

        def flush_held() -> None:
            if held:
                on_records(held.copy())
                held.clear()

        def one(k: int) -> None:
            """Sample k through the streaming path's checks and work (a guard, a gap, a change of channels: what
            update decides), with its step's input from the arrays."""
            flush_held()
            sample = arrays.sample(k)
            if self._accept(sample):
                self._work(sample, None if np.isnan(W[k, 0]) else W[k], float(S[k]))
            self.array_position = k + 1
            if record is not None and record[k]:
                on_record(k)

        recorded = [] if record is None else np.flatnonzero(record).tolist()  # (the rows to record, in order)
        next_recorded = 0  # the first of them not yet passed
        k = start
        try:
            while k < n:
                last = self._last_time
                if not (alone_l[k] and self._states_valid and last is not None and t_l[k] > last
                        and abs(self._last_input[1]) >= min_speed):
                    one(k)
                    k += 1
                    continue
                # the longest run of plain samples from k that ends at the latest at the sample closing the block,
                # before a refresh that moves the period and at the first sample to record
                block_end = k + max(1, self._correct_every - self._since_correction)
                quiet = self._clock.quiet_steps()
                limit = min(n, block_end, k + quiet)
                if limit == k + quiet < min(n, block_end) and self._clock.period is not None:
                    # the step that refreshes the period joins the run where it leaves the period as it is (a
                    # steady clock: no threshold moves), as update would find
                    r = k + quiet
                    if self._clock.period_after(float(t[r] - (t[r - 1] if r > k else last))) == self._period:
                        limit = r + 1
                h = self._clock.period
                # the longest step that is neither a gap (a restart) nor skips samples (bridged)
                longest = min(self._max_gap if self._period is not None else np.inf,
                              np.inf if h is None else GAP_FACTOR * h)
                first = t_l[k] - last  # (the sample before may have been left out: the step from the last one taken)
                j = k
                if limit > k and first <= longest:
                    j = k + 1
                    cut = record_l is not None and not self._reading_moves_at_corrections  # (at a row to record)
                    while j < limit and plain_l[j] and step_l[j] <= longest and not (cut and record_l[j - 1]):
                        j += 1
                if j == k:  # (a step that is a gap or skips samples, a change of channels, a period refresh)
                    one(k)
                    k += 1
                    continue
                if record is not None and j - 1 > k:  # rows inside the run read the estimate as it is before it
                    i = next_recorded
                    while i < len(recorded) and recorded[i] < k:
                        i += 1
                    first_inside = i
                    while i < len(recorded) and recorded[i] < j - 1:
                        i += 1
                    inside, next_recorded = recorded[first_inside:i], i
                    if on_records is None:
                        for i in inside:
                            on_record(i)
                    else:
                        held.extend(inside)
                flush_held()
                self._plain_run(k, j, first, rows)
                self.array_position = j
                if record is not None and record[j - 1]:
                    if on_records is None:
                        on_record(j - 1)
                    else:  # (recorded with the next run's first rows: the estimate is the same until its correction)
                        held.append(j - 1)
                k = j
        finally:  # (an interruption keeps the rows whose estimate was reached)
            flush_held()
        worked = np.flatnonzero(self._valid_of[:n]) if self._last_time is not None else ()
        if len(worked):  # a stream that goes on after these rows starts from the last
            r = int(worked[-1])
            r2 = int(worked[-2]) if len(worked) > 1 else None
            self._inputs.seed((float(t[r]), float(delta[r]), float(V[r])), float(slopes[r]),
                              None if r2 is None else (float(t[r2]), float(delta[r2]), float(V[r2])))

    def takes_arrays(self, arrays: SampleArrays) -> bool:
        """Whether :meth:`update_many` takes ``arrays`` on the array path (else it streams them row by row: a
        delay's lagged reading, or an estimator fed before)."""
        return (self._retimer is None and not self.augment.moves_loads  # (loads read sample by sample)
                and self._array_inputs(arrays) is not None)

    def valid_rows(self, arrays: SampleArrays, after: float | None = None) -> np.ndarray:
        """Which rows of ``arrays`` this estimator works (n,) bool: finite time, steering and speed, and a time
        after every earlier such row's (and after ``after``): what :meth:`_accept` decides row by row."""
        t = arrays.time
        with np.errstate(invalid="ignore"):
            finite = np.isfinite(t) & np.isfinite(arrays.steering_wheel_angle) & np.isfinite(arrays.speed)
        latest = np.maximum.accumulate(np.where(finite, t, -np.inf))
        before = np.empty(len(t))
        if len(t):
            before[0] = -np.inf if after is None else after
            before[1:] = np.maximum(latest[:-1], before[0])
        return finite & (t > before)

    def _array_inputs(self, arrays: SampleArrays):
        """The step inputs of every row of ``arrays`` (model/intersample.py ``run_inputs``: W (n, 4), step speeds
        (n,), slopes (n,)), for an estimator that has not been fed before (else None: the rows are streamed);
        kept for further calls with the same arrays (``start``/``stop``)."""
        cached = getattr(self, "_inputs_of", None)
        if cached is not None and cached[0] is arrays:
            return cached[1]
        if self._accepted_time is not None or self._waiting is not None:
            return None
        valid = self.valid_rows(arrays)
        self._valid_of = valid
        delta = arrays.steering_wheel_angle / self.known.steering_ratio
        inputs = run_inputs(self.config.intersample, arrays.time, delta, arrays.speed, valid, slopes=True)
        self._inputs_of = (arrays, inputs)
        return inputs

    def _plain_run(self, a, b, first, rows) -> None:
        """Samples a..b-1 of the array path (:meth:`update_many`), each what :meth:`_update` would do with it
        (the same branches: moving, no gap, every value finite, one set of channels); ``first``: the step
        from the last sample taken to sample a; ``rows``: the arrays' :class:`_Rows`."""
        count = b - a
        self._events["samples"] += count
        self._accepted_time = rows.t[b - 1]
        dts = [first] + rows.step[a + 1:b]
        self._clock.observe_many(dts)
        pattern = rows.absent[a]
        mask = self._configured if not rows.any_absent[a] else self._absent_mask(tuple(pattern))
        vals = rows.values[a:b]
        V = rows.V[a:b]
        if not pattern[_VY]:  # the lateral velocity per unit speed: the sideslip angle (model/lateral.py VY)
            vals = vals.copy()
            vals[:, _VY] /= rows.speed[a:b]
        if not pattern[_AY] and not pattern[_YAW]:
            self.kinematics.add_many(dts, rows.speed[a:b], vals[:, _YAW], vals[:, _AY])
        usable = self._any_configured if mask is self._configured else bool(mask.any())
        if not pattern[_AY]:
            limit = self._ay_limit
            observe = [not v > limit for v in rows.ay_abs[a:b]]
            n_over = count - sum(observe)
            if n_over:
                self._events[self._ay_limit_event] += n_over
            if not usable:
                observe = [False] * count
        else:
            observe = [usable] * count
        if usable and any(observe):
            self.health.seen |= mask
        delta = rows.delta[a:b]
        args = (dts, rows.W[a:b], rows.S[a:b], vals, mask, delta, V, observe)
        if not (self._since_correction + count >= self._correct_every and self._stage_block(*args)):
            self._propagate_observe_many(*args)
        self._since_correction += count
        self._last_time, self._last_input = rows.t[b - 1], (delta[-1], V[-1])
        if self._since_correction >= self._correct_every:
            self.array_position = b - 1  # (the last sample counts as worked once its correction is done)
            self.health.correct()
        self.array_position = b

    def _propagate_observe_many(self, dt, w, speed_step, values, mask, delta, speed, observe) -> None:
        """``_propagate`` then, where ``observe``, ``_observe`` for each of several samples (lists; ``w`` (m, 4)
        the steps' inputs, ``values`` (m, 4)); a variant may do them at once, with the same numbers."""
        for k in range(len(dt)):
            self._propagate(dt[k], w[k], speed_step[k])
            if observe[k]:
                self._observe(values[k], mask, delta[k], speed[k])

    def _stage_block(self, dt, w, speed_step, values, mask, delta, speed, observe) -> bool:
        """A variant may take a run that is a whole block, closed by the correction that follows, as one: True
        if it did (the samples are then its, to be worked by that correction with the numbers
        :meth:`_propagate_observe_many` and the correction give); False (the default): the samples go to
        :meth:`_propagate_observe_many`."""
        return False

    def _absent_mask(self, absent: tuple) -> np.ndarray:
        """The shared read-only mask of the configured channels less those ``absent`` (one per pattern)."""
        mask = self._masks_absent.get(absent)
        if mask is None:
            mask = self._masks_absent[absent] = self._configured & ~np.array(absent)
            mask.flags.writeable = False
        return mask

    def _measurement_vector(self, sample: Sample) -> tuple:
        """Measured values (4,) with 0.0 where unusable, and the mask of usable channels.

        The common case, every channel present and finite, returns the values as they came (a
        tuple) and the shared mask of configured channels, which must not be modified; likewise
        when some channels are absent (None) and the rest finite, with one shared mask per pattern.
        """
        m = sample.measurements()
        if None not in m and _all_finite(m):
            return m, self._configured
        if _all_finite([v for v in m if v is not None]):  # some channels absent (a log without roll)
            # one shared read-only mask per pattern, as for complete samples
            mask = self._absent_mask(tuple(v is None for v in m))
            return tuple(0.0 if v is None else v for v in m), mask
        present = self._configured & np.array([v is not None for v in m])
        values = np.array([np.nan if v is None else v for v in m], dtype=float)
        mask = present & np.isfinite(values)
        mask.flags.writeable = False  # (every mask the compiled calls take is read-only: block_close._masks)
        missing = int(np.count_nonzero(present & ~mask))
        if missing:
            self._events["missing_values"] += missing
        return np.where(mask, values, 0.0), mask


class _Rows:
    """The array path's rows (:meth:`SampleFeeding.update_many`) as a run of samples reads them: times, road-wheel
    angles, speeds, step speeds, steps [s], |a_y| and the absent channels as Python lists (a run is a few samples:
    numpy's calls on a few values cost more than the values), the measured values, speeds and step inputs as
    arrays (what the filter's compiled calls take)."""

    def __init__(self, t, delta, V, values, absent, step, W, S):
        self.t, self.delta, self.V, self.S = t.tolist(), delta.tolist(), V.tolist(), S.tolist()
        self.step = step.tolist()
        self.ay_abs = np.abs(values[:, _AY]).tolist()
        self.absent, self.any_absent = absent.tolist(), absent.any(axis=1).tolist()
        self.values, self.speed, self.W = values, V, W


def _per_unit_speed(values, speed: float):
    """``values`` (a tuple or an array of the measured channels) with the lateral velocity divided by ``speed``."""
    values = list(values) if isinstance(values, tuple) else values.copy()
    values[_VY] = values[_VY] / speed
    return values if not isinstance(values, list) else tuple(values)


def _finite(v) -> bool:
    return v is not None and math.isfinite(v)


def _all_finite(values) -> bool:
    isfinite = math.isfinite
    for v in values:
        if not isfinite(v):
            return False
    return True
