"""The four figures of a comparison, as `matplotlib.figure.Figure` objects without pyplot.

Reached through `CompareResult.figures()` (which imports this module only when figures are
drawn, so that a comparison never loads matplotlib otherwise); render one with
`mrjax.report.save_png_bytes`. The functions take the `CompareResult` they are given and read
its public fields; this module imports nothing of the comparison (no import circle).
"""

from __future__ import annotations

import math
import textwrap
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

#: A `mrjax.CompareResult` (duck-typed: its public fields are read).
CompareResult = Any

_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")
_MEASURED = "0.45"


def _figure(width: float, height: float) -> Figure:
    return Figure(figsize=(width, height), layout="constrained")


def _style(models) -> dict[str, tuple]:
    """A fixed colour and marker per model (by position in the comparison)."""
    cmap = colormaps["tab10"]
    return {m: (cmap(i % 10), _MARKERS[i % len(_MARKERS)]) for i, m in enumerate(models)}


def _grid(n: int) -> tuple[int, int]:
    cols = min(n, 3)
    return math.ceil(n / cols), cols


def _motion_groups(freq: np.ndarray, amp: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """(title, test indices) per distinct (frequency, amplitude), sorted; unknown last."""
    known = np.isfinite(freq) & np.isfinite(amp)
    keys = sorted({(float(f), float(a)) for f, a, k in zip(freq, amp, known) if k})
    out = [(f"{f:g} Hz, {1e3 * a:g} mm",
            np.flatnonzero(known & (freq == f) & (amp == a))) for f, a in keys]
    if (~known).any():
        out.append(("motion unknown", np.flatnonzero(~known)))
    return out


def plot_nrmse_per_test(result: CompareResult) -> Figure:
    """NRMSE [%] of every model's per-test fit: one panel per motion (frequency, amplitude),
    the tests of a panel along the current (or their index where the current is unknown)."""
    groups = _motion_groups(result.frequency, result.amplitude)
    rows, cols = _grid(len(groups))
    fig = _figure(3.4 * cols, 2.6 * rows + 0.5)
    axes = fig.subplots(rows, cols, squeeze=False, sharey=True)
    style = _style(result.models)
    cur = result.current
    for ax, (title, idx) in zip(axes.ravel(), groups):
        x = cur[idx]
        known = np.all(np.isfinite(x))
        if not known:
            x = np.arange(idx.size, dtype=float)
        order = np.argsort(x, kind="stable")
        for i, m in enumerate(result.models):
            color, marker = style[m]
            ax.plot(x[order], 100 * result.nrmse[i, idx][order], marker=marker, ms=4, lw=1,
                    color=color, label=m)
        if idx.size == 1:
            ax.set_xlim(x[0] - 0.5, x[0] + 0.5)
        ax.set_title(title, fontsize=8)
        ax.set_xlabel("current [A]" if known else "test (current unknown)", fontsize=7)
        ax.tick_params(labelsize=7)
        ax.grid(True, lw=0.3, alpha=0.5)
    for ax in axes[:, 0]:
        ax.set_ylabel("NRMSE [%]", fontsize=7)
    for ax in axes.ravel()[len(groups):]:
        ax.set_visible(False)
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="outside lower center",
               ncols=min(len(result.models), 5), fontsize=7, frameon=False)
    fig.suptitle("Per-test fit error by motion and current", fontsize=9)
    return fig


def plot_delta_aic(result: CompareResult) -> Figure:
    """AIC against the best model: the summed ΔAIC per model (left, symlog) and the per-test
    ΔAIC to the test's best model (right, symlog), models in ranking order."""
    fig = _figure(8.0, 3.2)
    left, right = fig.subplots(1, 2)
    ranked = list(result.ranking)
    style = _style(result.models)
    summ = {s["model"]: s for s in result.summary()}
    d = np.array([summ[m]["delta_aic"] for m in ranked], float)
    y = np.arange(len(ranked))
    left.barh(y, np.where(np.isfinite(d), d, 0.0), color=[style[m][0] for m in ranked])
    for yi, v in zip(y, d):
        left.text(max(v, 0.0) if np.isfinite(v) else 0.0, yi,
                  f" {v:.1f}" if np.isfinite(v) else " diverged", va="center", fontsize=7)
    left.set_yticks(y, ranked, fontsize=7)
    left.invert_yaxis()
    left.set_xscale("symlog", linthresh=10.0)
    left.set_xlabel("summed AIC − lowest summed AIC", fontsize=7)
    left.set_title(f"ΔAIC over {result.n_tests} tests (ranked by summed BIC)", fontsize=8)
    best = np.min(np.where(np.isnan(result.aic), np.inf, result.aic), axis=0)
    rng = np.random.default_rng(0)  # fixed jitter: the same figure every time
    for j, m in enumerate(ranked):
        i = result.models.index(m)
        with np.errstate(invalid="ignore"):
            v = result.aic[i] - best
        v = v[np.isfinite(v)]
        right.scatter(j + rng.uniform(-0.2, 0.2, v.size), v, s=10, color=style[m][0],
                      marker=style[m][1], alpha=0.8)
    right.set_xticks(range(len(ranked)), ranked, fontsize=7, rotation=20)
    right.set_yscale("symlog", linthresh=10.0)
    right.set_ylim(bottom=-1.0)
    right.set_ylabel("AIC − best AIC of the test", fontsize=7)
    right.set_title("per test", fontsize=8)
    for ax in (left, right):
        ax.tick_params(labelsize=7)
        ax.grid(True, lw=0.3, alpha=0.5)
    return fig


def plot_holdout_nrmse(result: CompareResult) -> Figure:
    """NRMSE [%] of each model's current-dependent laws on the held-out tests: one point per
    held-out test, a bar at the median, side by side per generalization method."""
    fig = _figure(max(4.5, 1.3 * len(result.models) + 1.5), 3.2)
    ax = fig.subplots()
    G = len(result.methods)
    width = 0.8 / max(G, 1)
    hatches = ("", "//", "..")
    rng = np.random.default_rng(0)
    style = _style(result.models)
    for g, method in enumerate(result.methods):
        for i, m in enumerate(result.models):
            v = 100 * result.holdout_nrmse[g, i]
            v = v[np.isfinite(v)]
            x0 = i - 0.4 + width * (g + 0.5)
            if v.size:
                ax.bar(x0, np.median(v), width * 0.9, color=style[m][0], alpha=0.35,
                       hatch=hatches[g % len(hatches)], edgecolor=style[m][0],
                       label=method if i == 0 else None)
                ax.scatter(x0 + rng.uniform(-0.25, 0.25, v.size) * width, v, s=9,
                           color=style[m][0], marker=style[m][1], zorder=3)
    ax.set_xticks(range(len(result.models)), result.models, fontsize=7)
    ax.set_ylabel("held-out NRMSE [%]", fontsize=7)
    ax.set_title("Current-dependent laws on held-out tests\n"
                 + textwrap.fill(result.description, 70), fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, axis="y", lw=0.3, alpha=0.5)
    if G:
        ax.legend(fontsize=7, title="bar: median", title_fontsize=7, frameon=False)
    return fig


def worst_test(result: CompareResult) -> int:
    """The compared test on which the best-ranked model has its largest NRMSE."""
    i = result.models.index(result.ranking[0])
    nr = result.nrmse[i]
    return int(np.argmax(np.where(np.isnan(nr), -np.inf, nr)))


def plot_worst_test(result: CompareResult) -> Figure:
    """Measured force and every model's fitted force against time on the worst test (see
    :func:`worst_test`), in one panel."""
    j = worst_test(result)
    cond = result.batch.condition(j)
    pred = result.predict(j)
    style = _style(result.models)
    fig = _figure(7.0, 3.4)
    ax = fig.subplots()
    ax.plot(cond.t, cond.force, ".", ms=2.5, color=_MEASURED, label="measured")
    for i, m in enumerate(result.models):
        ax.plot(cond.t, pred[m], lw=1.1, color=style[m][0],
                label=f"{m} ({100 * result.nrmse[i, j]:.1f} %)")
    ax.set_xlabel("time [s]", fontsize=7)
    ax.set_ylabel("force [N]", fontsize=7)
    ax.set_title(f"Worst test of {result.ranking[0]}: {cond.label}", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, lw=0.3, alpha=0.5)
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", fontsize=7,
               frameon=False, ncols=min(len(result.models) + 1, 6))
    return fig
