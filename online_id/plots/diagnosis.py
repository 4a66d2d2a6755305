"""Figures of the gap diagnosis: where the base model misses, before and after the best effect."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from online_id.diagnosis.diagnose import STEERING_FREQUENCY_BANDS, GapDiagnosis  # noqa: E402
from online_id.diagnosis.gap import (  # noqa: E402
    AMPLITUDE_BANDS,
    input_cross_correlation,
    instantaneous_frequency,
    is_contiguous,
    residual_autocorrelation,
)
from online_id.units import CHANNEL_UNITS  # noqa: E402


def write_report(d: GapDiagnosis, folder: Path) -> list[Path]:
    """Write the report figures into ``folder``; returns their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    s = d.series
    model, held = s["held_model"], s["held"]
    before, after = s["base"], s.get("after")
    label = s.get("after_label", "")
    chans = model.channels
    finst = instantaneous_frequency(model.block_time, model.steering_blocks)
    ay = model.measured[:, chans.index("lateral_acceleration")] if "lateral_acceleration" in chans else None
    paths = []

    def save(fig, name):
        p = folder / name
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)

    # 1. over time (held-out data)
    fig, axes = plt.subplots(len(chans), 1, figsize=(11, 2.6 * len(chans)), sharex=True, squeeze=False)
    t = model.block_time
    for i, c in enumerate(chans):
        ax = axes[i, 0]
        b = np.where(held, before[:, i] * model.std[i], np.nan)
        ax.plot(t, b, lw=0.6, color="tab:red", label="base model")
        if after is not None:
            ax.plot(t, np.where(held, after[:, i] * model.std[i], np.nan), lw=0.6, color="tab:blue",
                    label=f"with {label}")
        ax.set_ylabel(f"{c}\nerror [{CHANNEL_UNITS[c]}]")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper left")
    axes[0, 0].set_title(f"Model minus measurement on held-out data ({d.held_out})")
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    save(fig, "gap_over_time.png")

    # 2. error spectra (held-out data in one piece: the validation run)
    if is_contiguous(held):
        from scipy import signal

        fs = 1.0 / (model.q * model.dt)
        nper = int(min(held.sum(), 4 * fs))
        fig, axes = plt.subplots(len(chans), 1, figsize=(11, 2.6 * len(chans)), sharex=True, squeeze=False)
        for i, c in enumerate(chans):
            ax = axes[i, 0]
            for series_, colour, name in ((model.measured[held, i], "0.6", "measured"),
                                          (before[held, i] * model.std[i], "tab:red", "error, base model"),
                                          (None if after is None else after[held, i] * model.std[i], "tab:blue",
                                           f"error with {label}")):
                if series_ is None:
                    continue
                f, p = signal.welch(series_, fs=fs, nperseg=nper)
                ax.semilogy(f, np.sqrt(p), color=colour, lw=0.9, label=name)
            ax.set_xlim(0, 10)
            ax.set_ylabel(f"{c}\n[{CHANNEL_UNITS[c]}/√Hz]")
            ax.grid(alpha=0.3, which="both")
        axes[0, 0].legend(loc="upper right")
        axes[0, 0].set_title(f"Amplitude spectra on held-out data ({d.held_out})")
        axes[-1, 0].set_xlabel("frequency [Hz]")
        fig.tight_layout()
        save(fig, "gap_spectrum.png")

    # 3. by steering frequency and by |a_y|
    fig, axes = plt.subplots(len(chans), 2, figsize=(11, 2.6 * len(chans)), squeeze=False)
    for i, c in enumerate(chans):
        for j, (key, bands, xlabel) in enumerate((
                (finst, STEERING_FREQUENCY_BANDS, "steering frequency [Hz]"),
                (np.abs(ay) if ay is not None else None, AMPLITUDE_BANDS[:-1] + ((4.0, 6.0),), "|a_y| [m/s²]"))):
            ax = axes[i, j]
            if key is None:
                ax.set_visible(False)
                continue
            centres, rb, ra = [], [], []
            for lo, hi in bands:
                sel = held & (np.nan_to_num(key, nan=-1.0) >= lo) & (key < hi)
                if sel.sum() < 5:
                    continue
                centres.append(0.5 * (lo + hi))
                rb.append(np.sqrt(np.mean((before[sel, i] * model.std[i]) ** 2)))
                ra.append(np.sqrt(np.mean((after[sel, i] * model.std[i]) ** 2)) if after is not None else np.nan)
            width = 0.35 * (bands[0][1] - bands[0][0])
            ax.bar(np.array(centres) - width / 2, rb, width, color="tab:red", label="base model")
            ax.bar(np.array(centres) + width / 2, ra, width, color="tab:blue", label=f"with {label}")
            ax.set_xlabel(xlabel)
            ax.set_ylabel(f"{c} RMS error\n[{CHANNEL_UNITS[c]}]")
            ax.grid(alpha=0.3)
    axes[0, 0].legend()
    fig.suptitle("Where the held-out gap lies: by steering frequency and by lateral acceleration")
    fig.tight_layout()
    save(fig, "gap_by_frequency_and_amplitude.png")

    # 4. residual tests on the training run (base model)
    train = s["train_model"]
    mask = np.arange(train.n_blocks) >= train.first_block
    fs = 1.0 / (train.q * train.dt)
    fig, axes = plt.subplots(len(train.channels), 2, figsize=(11, 2.4 * len(train.channels)), squeeze=False)
    for i, c in enumerate(train.channels):
        w = d.gap["training_run"][c]
        wt = w["whiteness"]  # the diagnosis's own test of these residuals (autocorrelation is scale-free)
        axes[i, 0].plot(wt["lags_s"], wt["acf"], color="tab:red", lw=0.8, label="base model")
        axes[i, 0].axhspan(-wt["band"], wt["band"], color="tab:green", alpha=0.25, label="95 % band")
        axes[i, 0].set_ylabel(f"{c}\nautocorrelation")
        cc = w["input_cross_correlation"]
        axes[i, 1].plot(cc["lags_s"], cc["ccf"], color="tab:red", lw=0.8)
        axes[i, 1].axhspan(-cc["band"], cc["band"], color="tab:green", alpha=0.25)
        if "train_after" in s:
            ea = s["train_after"][mask, i]
            axes[i, 0].plot(wt["lags_s"], residual_autocorrelation(ea, fs)["acf"], color="tab:blue", lw=0.8,
                            label=f"with {label}")
            axes[i, 1].plot(cc["lags_s"], input_cross_correlation(ea, train.steering_blocks[mask], fs)["ccf"],
                            color="tab:blue", lw=0.8)
        axes[i, 1].set_ylabel("residual × steering")
        for ax in axes[i]:
            ax.grid(alpha=0.3)
    axes[0, 0].legend()
    axes[0, 0].set_title("Residual whiteness (training run)")
    axes[0, 1].set_title("Residual-steering cross-correlation")
    axes[-1, 0].set_xlabel("lag [s]")
    axes[-1, 1].set_xlabel("lag [s]")
    fig.tight_layout()
    save(fig, "residual_tests.png")

    # 5. candidates
    fig, ax = plt.subplots(figsize=(9, 0.5 * len(d.candidates) + 1.5))
    names = [c.fit.label for c in d.candidates]
    red = [100 * c.reduction for c in d.candidates]
    colors = ["tab:green" if c.significant else "tab:gray" for c in d.candidates]
    ax.barh(names[::-1], red[::-1], color=colors[::-1])
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("held-out gap reduction [%] (green: significant)")
    ax.set_title(f"Candidate effects; verdict: {d.verdict or 'none explains the gap'}")
    ax.grid(alpha=0.3, axis="x")
    fig.tight_layout()
    save(fig, "effects.png")
    return paths
