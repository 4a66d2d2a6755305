"""Counting what a stream lost: frames from COUNTER gaps, samples from sample-time gaps.

online-id's own frames (``data/online_id.dbc``) make every loss visible: each frame of sample k
carries COUNTER = k mod 256 and the trigger frame carries SAMPLE_TIME. A frame of message M whose
counter jumps from c to c + d (mod 256) follows d - 1 lost frames of M; a sample whose time
follows the previous one by n nominal periods follows n - 1 lost samples (the period is the
median step, as the filter's :class:`~online_id.stream.gaps.SampleClock` finds it). Time says
more than the 8-bit counter, which aliases after 256 lost samples; without a time signal the
trigger's counter is used.
"""

from __future__ import annotations

from collections import Counter

from online_id.stream.gaps import SampleClock

#: Range of an 8-bit rolling counter.
COUNTER_MODULUS = 256


class LossCounter:
    """Lost frames per message and lost samples of one stream.

    ``lost_frames`` : Counter by message name; ``lost_samples`` : samples that never arrived (or never
    assembled) between the first and the last sample seen; ``first_loss_time`` : sample time [s]
    of the first loss (None while nothing was lost).
    """

    def __init__(self) -> None:
        self.lost_frames: Counter = Counter()
        self.lost_samples = 0
        self.first_loss_time: float | None = None
        self._last_counter: dict[str, int] = {}
        self._clock = SampleClock()
        self._last_time: float | None = None
        self._last_trigger_counter: int | None = None

    def frame(self, message: str, counter: int | None) -> None:
        """A frame of ``message`` with its counter value (None: the map has no counter)."""
        if counter is None:
            return
        last = self._last_counter.get(message)
        self._last_counter[message] = counter
        if last is not None:
            gap = (counter - last) % COUNTER_MODULUS
            if gap > 1:
                self.lost_frames[message] += gap - 1

    def sample(self, time: float | None, counter: int | None) -> int:
        """A sample assembled at ``time`` [s] (its own time base; None: no time signal) with the
        trigger's counter; returns the samples lost just before it. A trigger whose sample could not
        be assembled is not reported here: the next sample's gap counts it."""
        lost = None
        if time is not None:
            if self._last_time is not None and time > self._last_time:
                dt = time - self._last_time
                if self._clock.period is not None:
                    lost = self._clock.missing(dt)
                self._clock.observe(dt)
            self._last_time = time
        if lost is None:  # no time signal, or its period not known yet: the counter
            lost = 0
            if counter is not None and self._last_trigger_counter is not None:
                lost = max((counter - self._last_trigger_counter) % COUNTER_MODULUS - 1, 0)
        if counter is not None:
            self._last_trigger_counter = counter
        if lost:
            self.lost_samples += lost
            if self.first_loss_time is None:
                self.first_loss_time = time
        return lost
