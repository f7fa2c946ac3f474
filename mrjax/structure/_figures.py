"""The figure of a structure's measured against simulated response."""

from __future__ import annotations

from typing import Any

from ._result import Prediction

#: Records drawn at most, and the samples of each one's zoomed window.
MAX_ROWS, WINDOW = 6, 600


def response_figure(pred: Prediction, *, title: str = "", unit: str = "m") -> Any:
    """A matplotlib `Figure` (no pyplot): per record (at most `MAX_ROWS`), the measured and
    the simulated response over a window of `WINDOW` samples in the record's middle, and the
    error (simulated - measured) over the whole record, in `unit` (`"m"` drawn in mm)."""
    from matplotlib.figure import Figure  # imported here: only a drawing needs matplotlib

    rows = min(len(pred.labels), MAX_ROWS)
    fig = Figure(figsize=(11, 2.6 * rows), layout="constrained")
    axes = fig.subplots(rows, 2, squeeze=False)
    scale, shown = (1e3, "mm") if unit == "m" else (1.0, unit)
    for i in range(rows):
        n = int(pred.n[i])
        t = pred.t[i, :n]
        a = max(0, n // 2 - WINDOW // 2)
        w = slice(a, min(n, a + WINDOW))
        ax, ex = axes[i]
        if pred.mask[i].any():
            ax.plot(t[w], scale * pred.measured[i, w], color="0.3", lw=1.6, label="measured")
        ax.plot(t[w], scale * pred.predicted[i, w], color="C3", lw=0.9, ls="--",
                label="simulated")
        ax.set_ylabel(f"{pred.labels[i]} [{shown}]")
        ax.legend(loc="upper right", fontsize=8)
        if pred.mask[i].any():
            err = scale * (pred.predicted[i, :n] - pred.measured[i, :n])
            ex.plot(t, err, color="C0", lw=0.6)
            ex.set_title(f"error, RMS {pred.rms[i]:.3g} ({100 * pred.nrmse[i]:.3g} %)",
                         fontsize=9)
        ex.set_ylabel(f"simulated - measured [{shown}]")
    axes[-1, 0].set_xlabel("time [s]")
    axes[-1, 1].set_xlabel("time [s]")
    if title:
        fig.suptitle(title)
    return fig
