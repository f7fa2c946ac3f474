"""Figures of a posterior (`mrjax.posterior`): the pair plot of the least-determined test, the
marginal intervals against current, and the predictive band on the worst test.

Inputs are duck-typed: a `mrjax.bayes.TestPosterior` (its `posterior` draws and its `fit`) and
a `mrjax.bayes.PredictiveBand`; this module does not import `mrjax.bayes`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure

from ._figures import FITTED_COLOR, MEASURED_COLOR, new_figure, save_png_bytes

#: At most this many draws are drawn per scatter panel of the pair plot (evenly thinned).
PAIR_DRAWS = 1000


def spread(post: Any) -> np.ndarray:
    """(U,) how much of its box each unit's 95 % intervals span: the mean over the sampled
    parameters of (97.5 % - 2.5 % quantile) / (upper - lower) (dimensionless)."""
    free = np.flatnonzero(np.asarray(post.free))
    U = len(post.labels)
    draws = np.asarray(post.theta, float).reshape(U, -1, len(post.names))[:, :, free]
    lo, hi = np.percentile(draws, (2.5, 97.5), axis=1)
    width = (np.asarray(post.upper, float) - np.asarray(post.lower, float))[:, free]
    return np.mean((hi - lo) / np.where(width > 0, width, 1.0), axis=1)


def plot_posterior_pair(post: Any, index: int | None = None) -> Figure:
    """Pair plot of one unit's posterior: histograms of every sampled parameter (not those held,
    named in the title) on the diagonal, draws of each pair below it (divergent transitions in
    red), the optimum the chains started from as a cross.

    **Arguments:** `post` a `mrjax.bayes.Posterior`; `index` the unit (default the
    least-determined one, largest :func:`spread`).

    **Returns:** the figure.
    """
    i = int(np.argmax(spread(post))) if index is None else int(index)
    held = np.asarray(getattr(post, "held", np.zeros((len(post.labels), len(post.names)),
                                                      bool)))[i]
    free = np.flatnonzero(np.asarray(post.free) & ~held)
    names = [post.names[j] for j in free]
    d = np.asarray(post.theta, float)[i].reshape(-1, len(post.names))[:, free]
    div = np.asarray(post.diverging, bool)[i].reshape(-1)
    keep = np.unique(np.linspace(0, d.shape[0] - 1, min(PAIR_DRAWS, d.shape[0])).astype(int))
    t0 = np.asarray(post.theta0, float)[i, free]
    K = len(free)
    fig = new_figure(1.55 * K + 1.0, 1.55 * K + 0.6)
    axes = fig.subplots(K, K, squeeze=False)
    for a in range(K):
        for b in range(K):
            ax = axes[a][b]
            if b > a:
                ax.set_visible(False)
                continue
            if a == b:
                ax.hist(d[:, a], bins=30, color="C0", alpha=0.8)
                ax.axvline(t0[a], color=FITTED_COLOR, lw=1.0)
                ax.set_yticks([])
            else:
                ax.plot(d[keep, b], d[keep, a], ".", ms=1.5, color="C0", alpha=0.4)
                if div.any():
                    ax.plot(d[div, b], d[div, a], ".", ms=3, color="red")
                ax.plot(t0[b], t0[a], "+", ms=8, mew=1.5, color=FITTED_COLOR)
            ax.tick_params(labelsize=6)
            if a == K - 1:
                ax.set_xlabel(names[b], fontsize=8)
            else:
                ax.set_xticklabels([])
            if b == 0 and a > 0:
                ax.set_ylabel(names[a], fontsize=8)
            elif b > 0:
                ax.set_yticklabels([])
    fixed = "".join(f"; {post.names[j]} held" for j in np.flatnonzero(held))
    fig.suptitle(f"posterior of {post.labels[i]!r} (least determined; {int(div.sum())} "
                 f"divergent; + the polished optimum{fixed})", fontsize=10)
    return fig


def plot_posterior_intervals(tp: Any, *, level: float = 0.95, ncols: int = 3) -> Figure:
    """Each parameter's posterior median and central `level` interval against current, beside
    the fit's Jacobian 95 % interval (shifted right), one subplot per parameter.

    **Arguments:** `tp` a `mrjax.bayes.TestPosterior` (its `posterior` and `fit`); `level`;
    `ncols` subplot columns.

    **Returns:** the figure.
    """
    post, fit = tp.posterior, tp.fit
    free = np.flatnonzero(np.asarray(post.free))
    cur = np.asarray(fit.current, float)
    xs = cur if np.all(np.isfinite(cur)) else np.arange(cur.size, dtype=float)
    xlabel = "current [A]" if np.all(np.isfinite(cur)) else "condition"
    span = np.ptp(xs) if xs.size > 1 and np.ptp(xs) > 0 else 1.0
    off = 0.012 * span
    units = list(getattr(fit.model, "units", [""] * len(post.names)))
    ci = np.asarray(fit.ci95, float)
    ncols = max(1, min(ncols, free.size))
    nrows = -(-free.size // ncols)
    fig = new_figure(3.4 * ncols + 0.6, 2.6 * nrows + 0.6)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    for k, j in enumerate(free):
        ax = axes[k // ncols][k % ncols]
        name = post.names[j]
        iv = post.interval(name, level)
        med = np.median(post.draws(name), axis=1)
        ax.errorbar(xs - off, med, yerr=[med - iv[:, 0], iv[:, 1] - med], ls="", marker="o",
                    ms=3.5, color="C0", elinewidth=0.9, capsize=1.5,
                    label=f"posterior {100 * level:g} %")
        th = np.asarray(fit.theta, float)[:, j]
        lo, hi = ci[:, j, 0], ci[:, j, 1]
        ok = np.isfinite(lo) & np.isfinite(hi)
        ax.errorbar(xs[ok] + off, th[ok], yerr=[th[ok] - lo[ok], hi[ok] - th[ok]], ls="",
                    marker="s", ms=3, mfc="none", color=FITTED_COLOR, elinewidth=0.9,
                    capsize=1.5, label="Jacobian 95 %")
        unit = units[j].replace("*", "·") if j < len(units) else ""
        ax.set_ylabel(f"{name} [{unit}]" if unit and unit != "-" else name, fontsize=8.5)
        ax.set_xlabel(xlabel, fontsize=8.5)
        ax.tick_params(labelsize=7.5)
        ax.grid(True, lw=0.4, alpha=0.5)
    for k in range(free.size, nrows * ncols):
        axes[k // ncols][k % ncols].set_visible(False)
    handles, labs = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labs, loc="outside upper center", ncols=2, fontsize=8, frameon=False)
    fig.suptitle(f"{fit.model.name}: marginal posterior intervals ({post.noise} noise) and "
                 "Jacobian intervals vs current", fontsize=10)
    return fig


def plot_predictive_band(band: Any, index: int | None = None, *, zoom: float = 0.125) -> Figure:
    """The posterior predictive band of one record against time, whole record and a zoomed
    window around its largest force: measured force, the band of a new measurement (light),
    the band of the model force (dark) and its median.

    **Arguments:** `band` a `mrjax.bayes.PredictiveBand`; `index` the record (default the
    worst: largest NRMSE of the median force); `zoom` the zoomed window's share of the record.

    **Returns:** the figure.
    """
    i = int(np.nanargmax(np.where(np.isfinite(band.nrmse), band.nrmse, -np.inf))) \
        if index is None else int(index)
    m = np.asarray(band.mask, bool)[i]
    t = np.asarray(band.t, float)[i][m]
    y = np.asarray(band.measured, float)[i][m]
    pieces = {k: np.asarray(getattr(band, k), float)[i][m]
              for k in ("median", "lower", "upper", "force_lower", "force_upper")}
    fig = new_figure(11.0, 3.6)
    axes = fig.subplots(1, 2, width_ratios=(2, 1))
    n = t.size
    c = int(np.argmax(np.abs(y))) if n else 0
    half = max(10, int(zoom * n / 2))
    sl = slice(max(0, c - half), min(n, c + half))
    for ax, s in ((axes[0], slice(None)), (axes[1], sl)):
        ax.fill_between(t[s], pieces["lower"][s], pieces["upper"][s], color="C0", alpha=0.25,
                        lw=0, label=f"{100 * band.level:g} % predictive")
        ax.fill_between(t[s], pieces["force_lower"][s], pieces["force_upper"][s], color="C0",
                        alpha=0.6, lw=0, label="model force")
        ax.plot(t[s], y[s], color=MEASURED_COLOR, lw=0.6, label="measured")
        ax.plot(t[s], pieces["median"][s], color=FITTED_COLOR, lw=0.7, label="median")
        ax.set_xlabel("t [s]", fontsize=8.5)
        ax.set_ylabel("force [N]", fontsize=8.5)
        ax.tick_params(labelsize=7.5)
        ax.grid(True, lw=0.4, alpha=0.5)
    if n:
        axes[0].axvspan(t[sl][0], t[sl][-1], color="0.9", zorder=0)
    axes[1].legend(fontsize=7.5, frameon=False)
    fig.suptitle(f"{band.labels[i]!r}: predictive band covers {100 * band.coverage[i]:.1f} % of "
                 f"the measured force (model force band {100 * band.force_coverage[i]:.1f} %; "
                 f"NRMSE {100 * band.nrmse[i]:.2f} %)", fontsize=10)
    return fig


def posterior_figures(tp: Any, band: Any | None = None) -> dict[str, bytes]:
    """The PNG figures of a per-test posterior, name -> bytes: `posterior_pair.png`,
    `posterior_intervals.png` and (with a `band`) `posterior_band.png`."""
    out = {"posterior_pair.png": save_png_bytes(plot_posterior_pair(tp.posterior)),
           "posterior_intervals.png": save_png_bytes(plot_posterior_intervals(tp))}
    if band is not None:
        out["posterior_band.png"] = save_png_bytes(plot_predictive_band(band))
    return out


def plot_law_intervals(lp: Any, *, level: float = 0.95, n: int = 61, ncols: int = 3) -> Figure:
    """Each law's posterior median and central `level` band against current, with the
    currents of the records it was sampled on marked, one subplot per parameter.

    **Arguments:** `lp` a `mrjax.bayes.LawPosterior` (its `law_values`, `model`, `currents`);
    `level`; `n` currents on the laws' range; `ncols` subplot columns.

    **Returns:** the figure.
    """
    gm = lp.model
    lo, hi = gm.current_range
    grid = np.linspace(lo, hi, int(n))
    vals = np.asarray(lp.law_values(grid), float)  # (S, n, P)
    q = np.percentile(vals, (50.0 * (1.0 - level), 50.0, 50.0 * (1.0 + level)), axis=0)
    names, units = gm.param_names, list(gm.model.units)
    P = len(names)
    ncols = max(1, min(ncols, P))
    nrows = -(-P // ncols)
    fig = new_figure(3.4 * ncols + 0.6, 2.6 * nrows + 0.6)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    for p, name in enumerate(names):
        ax = axes[p // ncols][p % ncols]
        ax.fill_between(grid, q[0][:, p], q[2][:, p], color="C0", alpha=0.3, lw=0,
                        label=f"posterior {100 * level:g} %")
        ax.plot(grid, q[1][:, p], color="C0", lw=1.0, label="median")
        for c in np.unique(np.asarray(lp.currents, float)):
            ax.axvline(c, color="0.7", lw=0.6, zorder=0)
        unit = units[p].replace("*", "·")
        ax.set_ylabel(f"{name} [{unit}]" if unit and unit != "-" else name, fontsize=8.5)
        ax.set_xlabel(f"current [{gm.command_unit}]", fontsize=8.5)
        ax.tick_params(labelsize=7.5)
        ax.grid(True, lw=0.4, alpha=0.5)
    for k in range(P, nrows * ncols):
        axes[k // ncols][k % ncols].set_visible(False)
    axes[0][0].legend(fontsize=7.5, frameon=False)
    fig.suptitle(f"{gm.model.name}: posterior of the laws ({lp.posterior.noise} noise; grey: "
                 "the records' currents)", fontsize=10)
    return fig


def law_posterior_figures(lp: Any, band: Any | None = None) -> dict[str, bytes]:
    """The PNG figures of a laws' posterior, name -> bytes: `posterior_pair.png` (the node
    values), `posterior_laws.png` and (with a `band`) `posterior_band.png`."""
    out = {"posterior_pair.png": save_png_bytes(plot_posterior_pair(lp.nodes)),
           "posterior_laws.png": save_png_bytes(plot_law_intervals(lp))}
    if band is not None:
        out["posterior_band.png"] = save_png_bytes(plot_predictive_band(band))
    return out
