"""Convergence of the online estimate: one panel per parameter (after Macchi et al., Figs 1-5)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from online_id.vehicle.parameters import PARAMETER_NAMES, PARAMETER_UNITS


def plot_convergence(runs, path: str | Path, truth=None, title: str = "") -> Path:
    """Draw each run's trajectory with a ±1σ band, and the truth where known.

    ``runs`` is a list of ``(label, EstimationResult)``; ``truth`` a
    :class:`~online_id.vehicle.parameters.Parameters` or None. Writes a PNG to ``path``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 2, figsize=(12, 11), sharex=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    truth_v = None if truth is None else truth.to_vector()
    for i, (ax, name) in enumerate(zip(axes.flat, PARAMETER_NAMES)):
        lo_all, hi_all = [], []
        for j, (label, res) in enumerate(runs):
            tr = res.trace
            c = colours[j % len(colours)]
            v, s = tr.values[:, i], tr.std[:, i]
            ax.plot(tr.time, v, color=c, lw=1.2, label=label)
            ax.fill_between(tr.time, v - s, v + s, color=c, alpha=0.2, lw=0)
            settled = v[len(v) // 3:] if len(v) > 3 else v
            lo_all.append(settled.min())
            hi_all.append(settled.max())
        if truth_v is not None:
            ax.axhline(truth_v[i], color="k", ls="--", lw=1, label="truth")
            lo_all.append(truth_v[i])
            hi_all.append(truth_v[i])
        # zoom on where the runs settle, so the last two thirds are readable
        lo, hi = min(lo_all), max(hi_all)
        pad = 0.5 * (hi - lo) + 0.02 * abs(hi)
        ax.set_ylim(lo - pad, hi + pad)
        ax.set_ylabel(f"{name} [{PARAMETER_UNITS[name]}]")
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.suptitle(title or "online estimate with ±1σ", y=0.99)
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.965), ncol=min(len(labels), 6),
               frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def final_errors(runs, truth) -> list[tuple[str, np.ndarray]]:
    """Relative error of each run's final estimate against ``truth``: list of (label, (8,) array)."""
    t = truth.to_vector()
    return [(label, res.parameters.to_vector() / t - 1) for label, res in runs]
