"""Convergence of the online estimate: one panel per parameter (after Macchi et al., Figs 1-5)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from online_id.vehicle.parameters import PARAMETER_NAMES, PARAMETER_UNITS

#: A prior further than this many times the settled range from the estimates is written, not drawn
#: (drawing it would squash the trajectories into a line).
PRIOR_OFF_SCALE_SPANS = 3.0


def plot_convergence(runs, path: str | Path, truth=None, title: str = "") -> Path:
    """Draw each run's trajectory with a ±1σ band, its prior as a dotted line, and the truth where known.

    ``runs`` is a list of ``(label, EstimationResult)``; ``truth`` a
    :class:`~online_id.vehicle.parameters.Parameters` or None. Time is counted from the start of the
    run (a real log's bus time, e.g. 46,410 s, is not). A parameter a run did not inform is marked
    on its panel ("not informed", shaded), a fixed one "fixed". Writes a PNG to ``path``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = draw_convergence(runs, truth, title)
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def draw_convergence(runs, truth=None, title: str = ""):
    """The figure of :func:`plot_convergence` (a matplotlib Figure, not yet saved)."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 2, figsize=(12, 11), sharex=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    truth_v = None if truth is None else truth.to_vector()
    t_start = min((res.trace.time[0] for _, res in runs if len(res.trace.time)), default=0.0)
    priors = _distinct_priors(runs)
    for i, (ax, name) in enumerate(zip(axes.flat, PARAMETER_NAMES)):
        lo_all, hi_all = [], []
        for j, (label, res) in enumerate(runs):
            tr = res.trace
            c = colours[j % len(colours)]
            v, s = tr.values[:, i], tr.std[:, i]
            ax.plot(tr.time - t_start, v, color=c, lw=1.2, label=label)
            ax.fill_between(tr.time - t_start, v - s, v + s, color=c, alpha=0.2, lw=0)
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
        off_scale = []
        for label, value, colour in priors:
            p = value.to_vector()[i]
            if lo - PRIOR_OFF_SCALE_SPANS * (hi - lo + pad) <= p <= hi + PRIOR_OFF_SCALE_SPANS * (hi - lo + pad):
                ax.axhline(p, color=colour, ls=":", lw=1.2, label=label)
                lo, hi = min(lo, p), max(hi, p)
            else:
                off_scale.append(f"{label} {p:.4g}")
        pad = 0.5 * (hi - lo) + 0.02 * abs(hi)
        ax.set_ylim(lo - pad, hi + pad)
        if off_scale:
            ax.text(0.99, 0.03, "off scale: " + ", ".join(off_scale), transform=ax.transAxes, ha="right",
                    va="bottom", fontsize=8, color="0.3")
        status = _status(runs, name)
        if status:
            ax.set_facecolor("#f6e8e8" if status == "not informed" else "#eeeeee")
            ax.text(0.01, 0.97, status, transform=ax.transAxes, ha="left", va="top", fontsize=9,
                    color="#a02020" if status == "not informed" else "0.3", fontweight="bold")
        ax.set_ylabel(f"{name} [{PARAMETER_UNITS[name]}]")
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time from the start of the run [s]")
    handles, labels = [], []
    for ax in axes.flat:  # every label once, whichever panel drew it
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.suptitle(title or "online estimate with ±1σ", y=0.99)
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.965), ncol=min(len(labels), 6),
               frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    return fig


def _distinct_priors(runs) -> list[tuple[str, object, str]]:
    """(legend label, prior Parameters, colour) for each distinct prior among the runs: grey when they
    share one, else in the colour of the first run that started from it."""
    out: list[tuple[str, object, str]] = []
    for j, (label, res) in enumerate(runs):
        prior = getattr(res, "prior", None)
        if prior is None or any(np.array_equal(prior.to_vector(), p.to_vector()) for _, p, _ in out):
            continue
        out.append((f"prior of {label}", prior, f"C{j % 10}"))
    if len(out) == 1:
        return [("prior", out[0][1], "0.35")]
    return out


def _status(runs, name: str) -> str:
    """"fixed" when every run held the parameter, "not informed" when any run did not inform it, else ""."""
    if runs and all(name in getattr(res, "fixed", {}) for _, res in runs):
        return "fixed"
    if any(name not in getattr(res, "fixed", {}) and not res.informed.get(name, True) for _, res in runs):
        return "not informed"
    return ""


def final_errors(runs, truth) -> list[tuple[str, np.ndarray]]:
    """Relative error of each run's final estimate against ``truth``: list of (label, (8,) array)."""
    t = truth.to_vector()
    return [(label, res.parameters.to_vector() / t - 1) for label, res in runs]
