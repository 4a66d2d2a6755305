"""Where the model misses: the residual (model minus measurement) located by frequency, amplitude
and time, and tested for whiteness and for correlation with the steering input.

All functions take block-mean series (see :mod:`online_id.diagnosis.fitting`): a 1 kHz run with
blocks of 10 gives 100 Hz series, ample for the 0-10 Hz of lateral dynamics.
"""

from __future__ import annotations

import numpy as np
from scipy import signal, stats

#: Frequency bands [Hz] for the error spectrum and the residual-steering coherence.
FREQUENCY_BANDS = ((0.0, 1.0), (1.0, 2.0), (2.0, 3.0), (3.0, 4.0), (4.0, 6.0), (6.0, 10.0))
#: Bands of |a_y| [m/s²].
AMPLITUDE_BANDS = ((0.0, 1.0), (1.0, 2.0), (2.0, 3.0), (3.0, 4.0), (4.0, np.inf))
#: Window for the gap over time [s].
TIME_WINDOW_S = 5.0
MAX_LAG_S = 0.5


def instantaneous_frequency(time, steering) -> np.ndarray:
    """Steering frequency [Hz] at each time, from the spacing of its zero crossings (NaN where unknown)."""
    s = np.asarray(steering, dtype=float) - np.median(steering)
    idx = np.nonzero(np.signbit(s[1:]) != np.signbit(s[:-1]))[0]
    if len(idx) < 3:
        return np.full(len(s), np.nan)
    tc = time[idx]
    f = 0.5 / np.diff(tc)
    mid = 0.5 * (tc[1:] + tc[:-1])
    return np.interp(time, mid, f, left=np.nan, right=np.nan)


def is_contiguous(mask: np.ndarray) -> bool:
    """Is the selection one unbroken stretch of blocks? (Spectra are meaningless across joins.)"""
    if not mask.any():
        return False
    first = int(np.argmax(mask))
    return bool(np.all(mask[first:first + int(mask.sum())]))


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def banded_rms(residual, key, bands) -> list[dict]:
    """RMS of ``residual`` over the samples whose ``key`` falls in each band."""
    out = []
    for lo, hi in bands:
        sel = (key >= lo) & (key < hi)
        out.append({"band": [lo, hi if np.isfinite(hi) else None], "n": int(sel.sum()),
                    "rms": _rms(residual[sel]) if sel.any() else None})
    return out


def spectrum_by_band(residual, steering, fs: float) -> list[dict]:
    """Error RMS per frequency band (Welch spectrum) and the mean residual-steering coherence there."""
    nper = int(min(len(residual), 4 * fs))
    f, p = signal.welch(residual, fs=fs, nperseg=nper)
    _, coh = signal.coherence(steering, residual, fs=fs, nperseg=nper)
    df = f[1] - f[0]
    out = []
    for lo, hi in FREQUENCY_BANDS:
        sel = (f >= lo) & (f < hi)
        out.append({"band_hz": [lo, hi], "rms": float(np.sqrt(np.sum(p[sel]) * df)),
                    "coherence": float(np.mean(coh[sel])) if sel.any() else None})
    return out


def residual_autocorrelation(residual, fs: float) -> dict:
    """Autocorrelation of the residual at lags up to MAX_LAG_S with the 95 % band ±1.96/√N, and
    the Ljung-Box test over those lags."""
    e = residual - residual.mean()
    n = len(e)
    lags = int(min(MAX_LAG_S * fs, n // 4))
    acf = np.array([np.dot(e[:-k], e[k:]) / np.dot(e, e) for k in range(1, lags + 1)])
    band = 1.96 / np.sqrt(n)
    q = n * (n + 2) * np.sum(acf ** 2 / (n - np.arange(1, lags + 1)))
    return {"lags_s": (np.arange(1, lags + 1) / fs).tolist(), "acf": acf.tolist(), "band": band,
            "fraction_outside_band": float(np.mean(np.abs(acf) > band)),
            "ljung_box_q": float(q), "ljung_box_p": float(stats.chi2.sf(q, lags)), "white": bool(
                stats.chi2.sf(q, lags) > 0.05)}


def input_cross_correlation(residual, steering, fs: float) -> dict:
    """Cross-correlation of the residual with the steering input at lags ±MAX_LAG_S, with the 95 %
    band ±1.96/√N (valid for a white residual)."""
    e = (residual - residual.mean()) / residual.std()
    u = (steering - steering.mean()) / steering.std()
    n = len(e)
    lags = int(min(MAX_LAG_S * fs, n // 4))
    ks = np.arange(-lags, lags + 1)
    cc = np.array([np.mean(e[max(k, 0):n + min(k, 0)] * u[max(-k, 0):n - max(k, 0)]) for k in ks])
    band = 1.96 / np.sqrt(n)
    worst = int(np.argmax(np.abs(cc)))
    return {"lags_s": (ks / fs).tolist(), "ccf": cc.tolist(), "band": band,
            "fraction_outside_band": float(np.mean(np.abs(cc) > band)), "max_abs": float(abs(cc[worst])),
            "lag_of_max_s": float(ks[worst] / fs), "correlated": bool(np.mean(np.abs(cc) > band) > 0.05)}


def locate(time, residuals: dict[str, np.ndarray], measured: dict[str, np.ndarray], steering,
           lateral_acceleration) -> dict:
    """The "where" section of the diagnosis for one run: per channel, the error by frequency
    (spectrum and coherence with steering, and by instantaneous steering frequency), by |a_y| and
    over time, and the whiteness and input-correlation tests."""
    fs = 1.0 / float(np.median(np.diff(time)))
    finst = instantaneous_frequency(time, steering)
    windows = np.floor((time - time[0]) / TIME_WINDOW_S)
    out = {}
    for ch, e in residuals.items():
        y = measured[ch]
        inst_bands = tuple((lo, lo + 0.5) for lo in np.arange(0.0, 5.0, 0.5))
        out[ch] = {
            "rms": _rms(e),
            "relative_rms": _rms(e) / float(np.std(y)),
            "by_frequency": spectrum_by_band(e, steering, fs),
            "by_steering_frequency": banded_rms(e, np.nan_to_num(finst, nan=-1.0), inst_bands),
            "by_lateral_acceleration": banded_rms(e, np.abs(lateral_acceleration), AMPLITUDE_BANDS),
            "over_time": [{"start_s": float(time[0] + w * TIME_WINDOW_S), "rms": _rms(e[windows == w])}
                          for w in np.unique(windows)],
            "whiteness": residual_autocorrelation(e, fs),
            "input_cross_correlation": input_cross_correlation(e, steering, fs),
        }
    return out
