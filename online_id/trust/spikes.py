"""Single-sample glitches in the inputs: found, said, and mended before anything learns from them.

The filters gate each measured channel against its predicted spread, but the steering-wheel angle and the
speed are *inputs*: nothing checks them, and one wrong sample drives the model. The race car's log has three
steering samples of 105°, 116° and 183° between neighbours under 15° (at 57.28, 353.50 and 374.86 s, 100 Hz:
10,000-17,000 deg/s, where the log's fastest real steering is 380 deg/s); 80 % of what the filter learned
about Mxx came from the two seconds around one of them, and three such spikes in a simulated run moved D1 by
1.5 % while ``check`` said every parameter was determined (issue 39).

A spike at sample k: x_k leaves both neighbours, the same way, faster than a car can
(:data:`MAX_RATE`, per channel) and by more than :data:`MIN_JUMP`, while the neighbours agree with each other
(within :data:`RETURN_FRACTION` of the jump). It is mended to the mean of its neighbours (what a linear
interpolation across it gives) and listed: ``check``, ``estimate``, ``fit`` and ``diagnose`` all see the mended
run and say so. A step (the value stays) is not a spike; neither is a fast but real input (a 4 Hz, 22° chirp
at 1 kHz moves 0.55° a sample).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace

import numpy as np

from online_id.units import G

DEG = 180.0 / math.pi
#: The inputs checked, with the fastest change a car's input can make [unit/s]: a hand on the steering wheel
#: reaches about 1,000-1,500 deg/s in an emergency (2,000 allowed); a car's speed changes by at most a few g
#: (3 g allowed).
MAX_RATE: dict[str, float] = {"steering_wheel_angle": math.radians(2000.0), "speed": 3 * G}
#: The least jump [unit] that counts: below it, a fast log's noise or quantisation (0.1° steps, 0.1 m/s).
MIN_JUMP: dict[str, float] = {"steering_wheel_angle": math.radians(5.0), "speed": 2.0}
#: The neighbours of a spike agree within this fraction of its smaller jump (else it is a step or a swing).
RETURN_FRACTION = 0.25
#: How each input is shown.
SHOWN: dict[str, tuple[str, float]] = {"steering_wheel_angle": ("°", DEG), "speed": ("m/s", 1.0)}


@dataclass(frozen=True)
class Spike:
    """One glitch: its ``channel``, sample ``index`` and ``time`` [s], the ``value`` logged and the value it was
    ``mended`` to (SI units)."""

    channel: str
    index: int
    time: float
    value: float
    mended: float

    def to_json_dict(self) -> dict:
        return {"channel": self.channel, "time": self.time, "value": self.value, "mended_to": self.mended}


def find_spikes(time: np.ndarray, values: np.ndarray, channel: str) -> list[Spike]:
    """The single-sample spikes of ``values`` (N,) at ``time`` (N,) [s] on the input ``channel`` (a key of
    :data:`MAX_RATE`)."""
    t, x = np.asarray(time, dtype=float), np.asarray(values, dtype=float)
    if len(x) < 3:
        return []
    up = x[1:-1] - x[:-2]
    down = x[1:-1] - x[2:]
    dt_up, dt_down = np.diff(t)[:-1], np.diff(t)[1:]
    jump = np.minimum(np.abs(up), np.abs(down))
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = np.minimum(np.abs(up) / dt_up, np.abs(down) / dt_down)
    found = ((np.sign(up) == np.sign(down)) & (jump > MIN_JUMP[channel]) & (rate > MAX_RATE[channel])
             & (np.abs(x[2:] - x[:-2]) < RETURN_FRACTION * jump))
    return [Spike(channel, int(k) + 1, float(t[k + 1]), float(x[k + 1]), float(0.5 * (x[k] + x[k + 2])))
            for k in np.flatnonzero(found)]


def mend_run(run):
    """``run`` (a TrackRun) with its input spikes mended (a new run sharing the untouched arrays; ``run`` itself
    when it has none), and the spikes found, in time order."""
    spikes: list[Spike] = []
    changed = {}
    for channel in MAX_RATE:
        found = find_spikes(run.time, getattr(run, channel), channel)
        if found:
            values = np.array(getattr(run, channel), dtype=float)
            for s in found:
                values[s.index] = s.mended
            changed[channel] = values
            spikes += found
    if not spikes:
        return run, []
    return replace(run, **changed), sorted(spikes, key=lambda s: s.time)


def mend_samples(samples: Iterable, found: list[Spike]) -> Iterator:
    """A stream of samples (a CAN log) with the input spikes mended, one sample behind; ``found`` collects them."""
    window: list = []
    index = 0
    for sample in samples:
        window.append(sample)
        if len(window) == 3:
            window[1] = _mended(window, index + 1, found)
            yield window.pop(0)
            index += 1
    yield from window


def _mended(window: list, index: int, found: list[Spike]):
    a, b, c = window
    changes = {}
    for channel in MAX_RATE:
        x = [getattr(s, channel) for s in window]
        if any(v is None for v in x):
            continue
        hit = find_spikes(np.array([a.time, b.time, c.time]), np.array(x, dtype=float), channel)
        if hit:
            found.append(replace(hit[0], index=index))
            changes[channel] = hit[0].mended
    return replace(b, **changes) if changes else b


def spike_lines(spikes: list[Spike], where: str = "") -> list[str]:
    """One line per input channel: how many spikes, their values and times, and what was done."""
    out = []
    for channel in MAX_RATE:
        mine = [s for s in spikes if s.channel == channel]
        if not mine:
            continue
        unit, factor = SHOWN[channel]
        shown = ", ".join(f"{factor * s.value:.4g}{'' if unit == '°' else ' '}{unit} at {s.time:.2f} s"
                          for s in mine[:5]) + (f" and {len(mine) - 5} more" if len(mine) > 5 else "")
        out.append(f"{where}{len(mine)} single-sample spike(s) in {channel} ({shown}): faster than a car's input,"
                   " a sensor glitch; mended to the mean of their neighbours before anything learned from them")
    return out
