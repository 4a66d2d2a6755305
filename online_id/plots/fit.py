"""Batch-fit figures after Haro (2008) Figs 9-11: measured against simulated per channel, and the
normalised squared residuals (eq 13) with their polynomial regression over time."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from online_id.model.lateral import OUTPUT_NAMES, OUTPUT_UNITS
from online_id.vehicle.parameters import PARAMETER_NAMES


def normalised_squared_residuals(measured: np.ndarray, simulated: np.ndarray) -> np.ndarray:
    """Haro's eq 13: e²/var(e), shape (N,)."""
    e = simulated - measured
    v = np.var(e)
    return e * e / v if v > 0 else np.zeros_like(e)


def plot_fit(result, path: str | Path, degree: int = 6) -> Path:
    """Two rows per fitted channel: measured vs simulated (and simulated at the prior, dotted), and eq 13
    residuals with a polynomial trend. Time from the start of the run; the fitted values head the
    figure, with the parameters the data could not determine (and the fixed ones) marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run = result.run
    chans = list(result.channels)
    fig, axes = plt.subplots(2 * len(chans), 1, figsize=(12, 3.2 * 2 * len(chans)), sharex=True)
    t = run.time - run.time[0]  # from the start of the run, not the logger's clock
    prior_sim = getattr(result, "prior_simulated", None)
    for k, c in enumerate(chans):
        col = OUTPUT_NAMES.index(c)
        meas, sim = getattr(run, c), result.simulated[:, col]
        ax = axes[2 * k]
        ax.plot(t, meas, lw=0.5, color="0.5", label="measured")
        if prior_sim is not None:
            ax.plot(t, prior_sim[:, col], lw=0.8, color="C1", ls=":", label="simulated (prior)")
        ax.plot(t, sim, lw=0.9, color="C0", label="simulated (fit)")
        ax.set_ylabel(f"{c}\n[{OUTPUT_UNITS[col]}]")
        ax.legend(loc="upper left", frameon=False)
        ax.grid(alpha=0.3)
        ax2 = axes[2 * k + 1]
        res = normalised_squared_residuals(meas, sim)
        ax2.plot(t, res, lw=0.4, color="0.6", label="normalised squared residual (eq 13)")
        coef = np.polynomial.polynomial.polyfit(t, res, degree)
        ax2.plot(t, np.polynomial.polynomial.polyval(t, coef), color="C3", lw=1.5,
                 label=f"polynomial regression (degree {degree})")
        ax2.set_ylim(0, np.percentile(res, 99.5) * 1.1)
        ax2.set_ylabel(f"{c}\nresidual² / var")
        ax2.legend(loc="upper left", frameon=False)
        ax2.grid(alpha=0.3)
    axes[-1].set_xlabel("time from the start of the run [s]")
    fig.suptitle(f"batch fit over {run.source}: cost {result.cost:.4g}\n{parameter_summary(result)}", y=0.998,
                 fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def parameter_summary(result) -> str:
    """One line: each parameter's fitted value, "(fixed)" or "NOT DETERMINED" where so."""
    parts = []
    for n, v in zip(PARAMETER_NAMES, result.parameters.to_vector()):
        fixed = n in getattr(result, "fixed", {})
        mark = " (fixed)" if fixed else " NOT DETERMINED" if n in result.undetermined else ""
        parts.append(f"{n} {v:.4g}{mark}")
    return ", ".join(parts)
