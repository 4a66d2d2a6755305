"""What a run told, window by window: where it informs each parameter (an excitation meter), and how
large the filter's innovations were against their expected spread.

Three views, each an object of named arrays (drawn by :mod:`online_id.report`):

- :func:`fisher_by_window`: each window's share of the run's Fisher information on each log-scale
  parameter, I_w,ii / Σ_w I_w,ii, from the output sensitivities of
  :func:`~online_id.trust.identifiability.output_sensitivities` (the same as ``check``'s Cramér-Rao bound),
  and the bound the run would give had it ended after each window, √((Σ_{v≤w} I_v)⁻¹)_ii. The share
  is the diagonal alone: a parameter correlated with another can have a large share and still a wide
  bound; the cumulative bound accounts for that.
- :func:`learned_by_window`: what the filter itself learned in each window, the fall of ln σ_rel on each
  parameter (a rise, from its process noise or a reopened covariance, counts as nothing), as a share of
  the run's total fall: each halving of σ counts the same, early (100 % to 50 %) or late (0.2 % to 0.1 %),
  where a share of 1/σ² would put everything at the end. Needs only the estimate's trace, so a live view
  has it.
- :func:`innovation_windows`: per channel, the RMS of the normalised block innovations against the
  nominal sensor noise over windows of :data:`~online_id.trust.consistency.WINDOW_S`, and the χ² bound
  the verdict's size test holds each window to (:func:`~online_id.trust.consistency.innovation_size`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from online_id.vehicle.parameters import PARAMETER_NAMES

#: Window lengths to choose from [s]: the shortest that gives at most :data:`MAX_WINDOWS` windows.
WINDOW_CHOICES_S: tuple[float, ...] = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 60.0, 120.0, 300.0)
#: Most windows a meter is cut into: 200 columns read at a glance on a page and keep it small.
MAX_WINDOWS = 200


def window_length(duration_s: float) -> float:
    """The shortest of :data:`WINDOW_CHOICES_S` that cuts ``duration_s`` into at most :data:`MAX_WINDOWS`."""
    for w in WINDOW_CHOICES_S:
        if duration_s / w <= MAX_WINDOWS:
            return w
    return float(np.ceil(duration_s / MAX_WINDOWS))


def _windows(time: np.ndarray, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Window index of each time (from the first) and the windows' start times."""
    t0 = float(time[0])
    idx = np.floor((time - t0) / window_s).astype(int)
    return idx, t0 + window_s * np.arange(int(idx.max()) + 1)


@dataclass(frozen=True)
class Excitation:
    """Per window (W,) and parameter (8): ``share`` (W, 8) of the run's information on the parameter,
    columns summing to 1 (0 where the run gave none); ``bound`` (W, 8) the relative σ after the windows so
    far (NaN where not computed: the filter's meter has none); ``what`` says what the share is of."""

    start: np.ndarray
    window_s: float
    share: np.ndarray
    bound: np.ndarray
    what: str

    @property
    def middle(self) -> np.ndarray:
        return self.start + 0.5 * self.window_s

    def to_json_dict(self) -> dict:
        return {"what": self.what, "window_s": self.window_s, "start_s": self.start.tolist(),
                "share": {n: self.share[:, i].tolist() for i, n in enumerate(PARAMETER_NAMES)},
                "bound_relative_std": {n: [None if not np.isfinite(v) else float(v) for v in self.bound[:, i]]
                                       for i, n in enumerate(PARAMETER_NAMES)}}


def _shares(gain: np.ndarray) -> np.ndarray:
    total = gain.sum(axis=0)
    return np.divide(gain, total, out=np.zeros_like(gain), where=total > 0)


def fisher_by_window(time: np.ndarray, sensitivities: np.ndarray, noise_std: np.ndarray,
                     window_s: float | None = None) -> Excitation:
    """Each window's share of the Fisher information and the cumulative Cramér-Rao bound.

    time (N,) [s]; sensitivities (N, C, 8): ∂y/∂log θ per sample and channel; noise_std (C,): the channels'
    σ [SI] (a channel not measured: ``inf``). Windows of ``window_s`` (default :func:`window_length`).
    """
    from online_id.trust.identifiability import information_covariance

    time = np.asarray(time, dtype=float)
    window_s = window_length(float(time[-1] - time[0])) if window_s is None else float(window_s)
    weighted = sensitivities / np.asarray(noise_std, dtype=float)[None, :, None]
    weighted = np.where(np.isfinite(weighted), weighted, 0.0)
    idx, start = _windows(time, window_s)
    edges = np.searchsorted(idx, np.arange(len(start) + 1))  # idx rises with time: each window is a slice
    k = weighted.shape[2]
    info = np.zeros((len(start), k, k))
    for w in range(len(start)):
        s = weighted[edges[w]:edges[w + 1]].reshape(-1, k)
        info[w] = s.T @ s
    diag = np.einsum("wii->wi", info)
    cumulative = np.cumsum(info, axis=0)
    bound = np.array([np.sqrt(np.clip(np.diag(information_covariance(c)), 0, None)) for c in cumulative])
    return Excitation(start, window_s, _shares(diag), bound,
                      "share of the run's Fisher information on each parameter (the diagonal, at the prior,"
                      " with the sensor noise check judges by)")


def learned_by_window(time: np.ndarray, values: np.ndarray, std: np.ndarray,
                      window_s: float | None = None) -> Excitation:
    """What the filter learned per window: the fall of ln σ_rel (σ_rel = std/value) over each step of the
    trace, clipped at 0, summed over the window, as a share of the run's total.

    time (M,) [s], values and std (M, 8) [SI]: an estimate's trace.
    """
    time = np.asarray(time, dtype=float)
    if len(time) < 2:
        return Excitation(time[:1], window_s or 1.0, np.zeros((len(time[:1]), len(PARAMETER_NAMES))),
                          np.full((len(time[:1]), len(PARAMETER_NAMES)), np.nan), "nothing learned yet")
    window_s = window_length(float(time[-1] - time[0])) if window_s is None else float(window_s)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_sigma = np.log(np.asarray(std) / np.asarray(values))
    log_sigma = np.where(np.isfinite(log_sigma), log_sigma, np.nan)
    rise = np.clip(-np.diff(log_sigma, axis=0), 0, None)  # a step's fall of ln σ, in the window of its end
    rise = np.where(np.isfinite(rise), rise, 0.0)
    idx, start = _windows(time, window_s)
    gain = np.zeros((len(start), len(PARAMETER_NAMES)))
    np.add.at(gain, idx[1:], rise)
    return Excitation(start, window_s, _shares(gain), np.full_like(gain, np.nan),
                      "share of what the filter learned on each parameter (fall of ln σ)")


@dataclass(frozen=True)
class InnovationWindows:
    """One channel's innovations over time: ``middle`` (W,) [s] window centres, ``rms`` (W,) the RMS of the
    normalised innovations against the nominal noise (1 when the model and noise are right), ``bound``
    (W,) the size test's limit for the window's count; ``time``/``nu`` the innovations themselves."""

    channel: str
    middle: np.ndarray
    rms: np.ndarray
    bound: np.ndarray
    time: np.ndarray
    nu: np.ndarray


def innovation_windows(rows: np.ndarray, window_s: float | None = None) -> list[InnovationWindows]:
    """Per measured channel with innovations: windowed RMS and the χ² bound (see the module docstring).

    rows: the filter's :class:`~online_id.filters.innovations.InnovationLog` rows (M, 10).
    """
    from online_id.stream.samples import MEASURED_CHANNELS
    from online_id.trust.consistency import WINDOW_ALPHA, WINDOW_S, chi2_upper

    if rows is None or len(rows) == 0:
        return []
    window_s = WINDOW_S if window_s is None else window_s
    n = len(MEASURED_CHANNELS)
    t = rows[:, 0]
    nu = rows[:, 2:2 + n] * np.sqrt(rows[:, 2 + n:2 + 2 * n])  # against the nominal R, as the verdict judges
    out = []
    for c, name in enumerate(MEASURED_CHANNELS):
        ok = np.isfinite(nu[:, c])
        if not ok.any():
            continue
        tc, x = t[ok], nu[ok, c]
        idx, start = _windows(tc, window_s)
        counts = np.bincount(idx, minlength=len(start))
        sums = np.bincount(idx, weights=x * x, minlength=len(start))
        has = counts > 0
        rms = np.full(len(start), np.nan)
        rms[has] = np.sqrt(sums[has] / counts[has])
        bound = np.full(len(start), np.nan)
        bound[has] = np.sqrt(chi2_upper(counts[has], WINDOW_ALPHA) / counts[has])
        out.append(InnovationWindows(name, start + 0.5 * window_s, rms, bound, tc, x))
    return out
