"""Figures of data and fit results (the paper's Figs 3, 7-12 and diagnostics).

Every function returns a `matplotlib.figure.Figure` built without `pyplot`: no display, no
global figure registry, no backend switch, so they are safe in scripts, servers and tests, and a
notebook shows a returned figure as usual. `save_png_bytes` renders one into memory (Agg).

Inputs are plain objects: a `mrjax.FitResult` (or anything with the same per-condition
arrays `labels`, `current`, `frequency`, `amplitude`, `rms`, ...) and a `mrjax.data.Batch`.
Conditions whose current, frequency or amplitude is unknown (NaN) fall back to their index.
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from matplotlib import colormaps
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import FuncFormatter

from ..objective import masked_rms

_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*", "<", ">", "h", "p")
MEASURED_COLOR = "0.55"
FITTED_COLOR = "#d62728"
_CMAP = "viridis"


# --------------------------------------------------------------------------------------------
# Helpers


def save_png_bytes(fig: Figure, *, dpi: int = 130) -> bytes:
    """Render `fig` as PNG into memory (Agg) and return the bytes.

    The figure is not shown or registered anywhere, so writing the bytes with
    `mrjax._io.atomic_output` keeps a set of outputs all-or-nothing.
    """
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, facecolor="white")
    return buf.getvalue()


def new_figure(width: float, height: float) -> Figure:
    """A figure of `width` x `height` inches with constrained layout (no pyplot)."""
    return Figure(figsize=(width, height), layout="constrained")


def _arr(obj: Any, name: str, n: int) -> np.ndarray:
    v = getattr(obj, name, None)
    if v is None:
        return np.full(n, np.nan)
    return np.asarray(v, dtype=float).reshape(-1)


def labels_of(obj: Any, n: int) -> list[str]:
    """The `labels` of `obj` as strings, or `#0`, `#1`, ... for its `n` conditions."""
    labels = getattr(obj, "labels", None)
    return [str(s) for s in labels] if labels is not None else [f"#{i}" for i in range(n)]


def _n(obj: Any) -> int:
    for name in ("rms", "current", "labels"):
        v = getattr(obj, name, None)
        if v is not None:
            return len(v)
    raise TypeError(f"cannot tell the number of conditions of {type(obj).__name__}")


def motion_of(f: float, a: float) -> tuple[float, float] | None:
    """`(frequency [Hz], amplitude [m])`, or None when either is unknown (NaN)."""
    return (float(f), float(a)) if math.isfinite(f) and math.isfinite(a) else None


def motion_label(m: tuple[float, float] | None) -> str:
    """A motion as text, `1 Hz, 8 mm` (or `unknown motion`)."""
    return "unknown motion" if m is None else f"{m[0]:g} Hz, {m[1] * 1e3:g} mm"


def distinct_motions(freq: np.ndarray, amp: np.ndarray) -> list[tuple[float, float] | None]:
    """Distinct (frequency, amplitude) pairs, sorted (unknown last)."""
    keys = {motion_of(f, a) for f, a in zip(freq, amp)}
    known = sorted(k for k in keys if k is not None)
    return known + ([None] if None in keys else [])


def _x_current(current: np.ndarray) -> tuple[np.ndarray, str]:
    """Current as the x axis, or the condition index if any current is unknown."""
    if current.size and np.all(np.isfinite(current)):
        return current, "current [A]"
    return np.arange(current.size, dtype=float), "condition index (current unknown)"


def current_colors(current: np.ndarray):
    """A colour per condition from its current, and the ScalarMappable for a colorbar.

    With unknown currents, colours cycle by index and the mappable is None.
    """
    finite = current[np.isfinite(current)]
    if finite.size == current.size and finite.size:
        lo, hi = float(finite.min()), float(finite.max())
        if hi <= lo:
            hi = lo + 1.0
        norm = Normalize(lo, hi)
        cmap = colormaps[_CMAP]
        sm = ScalarMappable(norm=norm, cmap=cmap)
        return [cmap(0.9 * norm(c)) for c in current], sm
    cycle = colormaps["tab10"]
    return [cycle(i % 10) for i in range(current.size)], None


def velocity_scale(v: np.ndarray) -> tuple[float, str]:
    """`(factor, unit)` to show velocities `v` [m/s]: mm/s below 1 m/s, else m/s."""
    vmax = float(np.nanmax(np.abs(v))) if v.size else 0.0
    return (1.0, "m/s") if vmax >= 1.0 else (1e3, "mm/s")


def small_axes(ax, size: float = 6.0) -> None:
    """Ticks of `size` points (about four per axis) and a light grid on a small panel."""
    ax.tick_params(labelsize=size, length=2, pad=1.5)
    ax.locator_params(nbins=4)
    ax.grid(True, lw=0.3, alpha=0.5)


def _as_results(results: Any) -> dict[str, Any]:
    if isinstance(results, Mapping):
        out = dict(results)
    elif isinstance(results, (list, tuple)):
        out = {}
        for r in results:
            name = getattr(getattr(r, "model", None), "name", None) or f"fit {len(out)}"
            out[name if name not in out else f"{name} ({len(out)})"] = r
    else:
        name = getattr(getattr(results, "model", None), "name", None) or "fit"
        out = {name: results}
    if not out:
        raise ValueError("no results to plot")
    return out


def rows_rms(force: np.ndarray, pred: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """RMS error [N] of each row (C, T) over its masked samples: `mrjax.objective.masked_rms`
    per row (inf for a row without samples or with a non-finite prediction)."""
    return np.asarray(jax.vmap(masked_rms)(jnp.asarray(pred), jnp.asarray(force),
                                           jnp.asarray(mask, bool)), float)


def measured_and_model(result: Any, batch: Any, force: np.ndarray | None,
                       rms: Sequence[float] | None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What a measured-vs-model figure draws: `(F, pred, mask, rms)` with the measured force
    (C, T) [N], the model's (`force`, or `result.predict(batch)`), the mask and the RMS per
    condition [N] (`rms`, else `result.rms` when it has one entry per condition, else
    :func:`rows_rms`). Raises `ValueError` when the model force's shape is not the batch's."""
    pred = np.asarray(result.predict(batch) if force is None else force, dtype=float)
    F = np.asarray(batch.force, dtype=float)
    mask = np.asarray(batch.mask, dtype=bool)
    C = F.shape[0]
    if pred.shape != F.shape:
        raise ValueError(f"model force has shape {pred.shape}, the batch {F.shape}")
    if rms is None:
        r = getattr(result, "rms", None)
        rms = (np.asarray(r, float) if r is not None and np.size(r) == C
               else rows_rms(F, pred, mask))
    return F, pred, mask, np.asarray(rms, float)


def _no_data(fig: Figure, ax, text: str) -> Figure:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, fontsize=10,
            color="0.35")
    ax.set_xticks([])
    ax.set_yticks([])
    return fig


# --------------------------------------------------------------------------------------------
# Per-condition scalars vs current


def _dodged(xs: np.ndarray, slot: int, nslot: int, step: float, lo: float, hi: float
            ) -> np.ndarray:
    """`xs` moved to slot `slot` of `nslot` markers `step` apart: centred on each x, but
    inside [lo, hi] (the markers of the lowest current go right of it, those of the highest
    left), so that no marker sits at a current that was not tested (below 0 A)."""
    half = 0.5 * (nslot - 1) * step
    shift = np.where(np.isclose(xs, lo), half, np.where(np.isclose(xs, hi), -half, 0.0))
    return xs + (slot - 0.5 * (nslot - 1)) * step + (shift if hi > lo else 0.0)


def _dodge_step(x: np.ndarray, nslot: int) -> float:
    """Horizontal offset between `nslot` markers sharing one x, so they do not hide each other."""
    u = np.unique(x[np.isfinite(x)])
    if u.size == 0 or nslot <= 1:
        return 0.0
    span = float(u[-1] - u[0]) or 1.0
    gap = float(np.min(np.diff(u))) if u.size > 1 else span
    return min(0.012 * span, 0.6 * gap / nslot)


def _scatter_vs_current(ax, results: dict[str, Any], value: Callable[[Any], np.ndarray],
                        filled: Callable[[Any], np.ndarray] | None = None) -> tuple[str, list]:
    """Draw one marker per condition: colour per result, marker per motion. Returns the x
    label and the legend handles."""
    all_motions: list = []
    for res in results.values():
        n = _n(res)
        for m in distinct_motions(_arr(res, "frequency", n), _arr(res, "amplitude", n)):
            if m not in all_motions:
                all_motions.append(m)
    all_motions = sorted(m for m in all_motions if m is not None) + (
        [None] if None in all_motions else [])
    xlabel = "current [A]"
    nres = len(results)
    currents = np.concatenate([_arr(r, "current", _n(r)) for r in results.values()])
    nslot = len(results) * len(all_motions)
    step = _dodge_step(currents, nslot)
    lo, hi = (float(np.nanmin(currents)), float(np.nanmax(currents))) if np.isfinite(
        currents).any() else (0.0, 0.0)
    handles = []
    for j, (name, res) in enumerate(results.items()):
        n = _n(res)
        xs, xl = _x_current(_arr(res, "current", n))
        if xl != "current [A]":
            xlabel = xl
        y = np.asarray(value(res), float)
        fill = np.ones(n, bool) if filled is None else np.asarray(filled(res), bool)
        freq, amp = _arr(res, "frequency", n), _arr(res, "amplitude", n)
        for k, m in enumerate(all_motions):
            # one result: colour by motion too (easier to read); several: colour by result
            color = f"C{(j if nres > 1 else k) % 10}"
            xd = _dodged(xs, j * len(all_motions) + k, nslot, step, lo, hi)
            sel = np.array([motion_of(f, a) == m for f, a in zip(freq, amp)], bool)
            for mk_fill in (True, False):
                s = sel & (fill == mk_fill)
                if not s.any():
                    continue
                ax.scatter(xd[s], y[s], marker=_MARKERS[k % len(_MARKERS)], s=34,
                           facecolors=color if mk_fill else "none", edgecolors=color,
                           linewidths=1.0, alpha=0.9, zorder=3)
        if nres > 1:
            handles.append(Line2D([], [], ls="", marker="o", color=f"C{j % 10}", label=name))
    if all_motions != [None]:
        for k, m in enumerate(all_motions):
            handles.append(Line2D([], [], ls="", marker=_MARKERS[k % len(_MARKERS)],
                                  color="0.3" if nres > 1 else f"C{k % 10}", mfc="none",
                                  label=motion_label(m)))
    return xlabel, handles


def plot_rms_vs_current(results: Any, *, logy: bool = False) -> Figure:
    """RMS force error vs current (the paper's Fig 9).

    **Arguments:**

    - `results`: one `mrjax.FitResult`, a list of them, or a dict `{name: FitResult}` (e.g.
        one per model). Anything with per-condition `current`, `frequency`, `amplitude` and
        `rms` arrays works. Colour per result, marker per (frequency, amplitude) pair.
    - `logy`: logarithmic RMS axis.

    **Returns:** the figure.
    """
    results = _as_results(results)
    fig = new_figure(7.0, 4.4)
    ax = fig.subplots()
    xlabel, handles = _scatter_vs_current(ax, results, lambda r: _arr(r, "rms", _n(r)))
    ax.set_xlabel(xlabel)
    ax.set_ylabel("RMS force error [N]")
    if logy:
        ax.set_yscale("log")
    else:
        ys = np.concatenate([_arr(r, "rms", _n(r)) for r in results.values()])
        top = float(np.nanmax(ys)) if np.any(np.isfinite(ys)) else 1.0
        ax.set_ylim(0, 1.08 * top if top > 0 else 1.0)
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.set_title("RMS error vs current" + (f" ({', '.join(results)})" if len(results) < 4 else ""))
    fig.legend(handles=handles, fontsize=7.5, loc="outside right upper", frameon=False)
    return fig


def plot_generations_vs_current(results: Any) -> Figure:
    """Swarm generations to termination vs current (the paper's Fig 10).

    Filled markers: stopped by the statistical criterion; open markers: hit the generation cap
    (dashed line). Results fitted without a swarm (`method="lm"`) have no generations and are
    left out.

    **Arguments:** `results` as for :func:`plot_rms_vs_current` (with `generations` and
    `stopped_by_criterion` arrays).

    **Returns:** the figure.
    """
    results = _as_results(results)
    swarm = {k: r for k, r in results.items()
             if np.any(np.asarray(getattr(r, "generations", [-1])) >= 0)}
    fig = new_figure(7.0, 4.4)
    ax = fig.subplots()
    ax.set_title("Generations to termination vs current")
    if not swarm:
        return _no_data(fig, ax, "no swarm generations (fitted with method='lm')")
    gens = lambda r: np.where(np.asarray(r.generations) >= 0, r.generations, np.nan)
    xlabel, handles = _scatter_vs_current(
        ax, swarm, gens, filled=lambda r: np.asarray(r.stopped_by_criterion, bool))
    caps = {np.asarray(r.history).shape[1] - 1 for r in swarm.values()
            if getattr(r, "history", None) is not None and np.asarray(r.history).ndim == 2}
    for cap in sorted(caps):
        ax.axhline(cap, color="0.5", ls="--", lw=0.8, zorder=1)
    handles += [Line2D([], [], ls="", marker="o", color="0.3", label="stopped by criterion"),
                Line2D([], [], ls="", marker="o", color="0.3", mfc="none", label="hit the cap")]
    if caps:
        handles.append(Line2D([], [], ls="--", color="0.5", label="generation cap"))
    ax.set_xlabel(xlabel)
    ax.set_ylabel("generations")
    ax.set_ylim(0, 1.06 * max([*caps, 1, *(np.nanmax(gens(r)) for r in swarm.values())]))
    ax.grid(True, lw=0.4, alpha=0.5)
    fig.legend(handles=handles, fontsize=7.5, loc="outside right upper", frameon=False)
    return fig


def _eval_laws(laws: Any, grid: np.ndarray, P: int) -> np.ndarray:
    """Law values on `grid`, shape (len(grid), P)."""
    if hasattr(laws, "params_at"):
        out = np.asarray(laws.params_at(grid), float)
    elif callable(laws):
        out = np.stack([np.asarray(laws(float(i)), float).reshape(-1) for i in grid])
    else:
        raise TypeError("laws must be a callable current -> (P,) or have .params_at(currents)")
    if out.shape == (P, grid.size) and P != grid.size:
        out = out.T
    if out.shape != (grid.size, P):
        raise ValueError(f"laws gave shape {out.shape} for {grid.size} currents, "
                         f"expected ({grid.size}, {P})")
    return out


def plot_params_vs_current(result: Any, *, laws: Any = None, ncols: int = 3) -> Figure:
    """Each identified parameter vs current, with std-error bars (the paper's Fig 11).

    **Arguments:**

    - `result`: a `mrjax.FitResult`.
    - `laws`: optional current-dependent law to overlay as a line: a callable
        `current [A] -> (P,)` parameters, or an object with `.params_at(currents) -> (N, P)`
        such as a `mrjax.generalize.GeneralizedModel`.
    - `ncols`: subplot columns.

    **Returns:** the figure, one subplot per parameter (markers per motion).
    """
    theta = np.asarray(result.theta, float)
    C, P = theta.shape
    names = list(result.param_names)
    units = list(getattr(result.model, "units", [""] * P))
    stderr = np.asarray(getattr(result, "stderr", np.full((C, P), np.nan)), float)
    cur = _arr(result, "current", C)
    xs, xlabel = _x_current(cur)
    freq, amp = _arr(result, "frequency", C), _arr(result, "amplitude", C)
    motions = distinct_motions(freq, amp)
    law = None
    if laws is not None and xlabel == "current [A]":
        lo, hi = float(np.min(cur)), float(np.max(cur))
        grid = np.linspace(lo, hi if hi > lo else lo + 1.0, 200)
        law = (grid, _eval_laws(laws, grid, P))
    dodge = _dodge_step(xs, len(motions))
    lo, hi = float(np.min(xs)), float(np.max(xs))

    ncols = max(1, min(int(ncols), P))
    nrows = math.ceil(P / ncols)
    fig = new_figure(3.4 * ncols + 1.6, 2.6 * nrows + 0.6)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    for p in range(P):
        ax = axes[p // ncols][p % ncols]
        for k, m in enumerate(motions):
            sel = np.array([motion_of(f, a) == m for f, a in zip(freq, amp)], bool)
            xd = _dodged(xs, k, len(motions), dodge, lo, hi)
            err = np.where(np.isfinite(stderr[sel, p]), stderr[sel, p], 0.0)
            ax.errorbar(xd[sel], theta[sel, p], yerr=err, ls="",
                        marker=_MARKERS[k % len(_MARKERS)], ms=4, mfc="none", color=f"C{k % 10}",
                        elinewidth=0.8, capsize=1.5, label=motion_label(m))
        if law is not None:
            ax.plot(law[0], law[1][:, p], color="k", lw=1.4, label="fitted law", zorder=4)
        unit = (units[p] if p < len(units) else "") or "-"
        ax.set_ylabel(f"{names[p]} [{unit.replace('*', '·')}]")  # [-]: dimensionless
        ax.set_title(names[p], fontsize=10)
        ax.set_xlabel(xlabel, fontsize=8.5)
        ax.tick_params(labelsize=8)
        ax.grid(True, lw=0.4, alpha=0.5)
    for p in range(P, nrows * ncols):
        axes[p // ncols][p % ncols].set_visible(False)
    handles, labs = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labs, loc="outside right upper", fontsize=8, frameon=False)
    model = getattr(getattr(result, "model", None), "name", "")
    fig.suptitle(f"{model} parameters vs current" + (" with fitted laws" if law else "")
                 + "  (bars: ±1 std-error)", fontsize=11)
    if dodge > 0:
        fig.supxlabel("markers of one current are spread sideways, within the tested range, "
                      "so that they do not hide each other", fontsize=8, color="0.35")
    return fig


# --------------------------------------------------------------------------------------------
# Optimizer diagnostics


def plot_convergence(result: Any, *, logy: bool = True) -> Figure:
    """Group-best RMS vs generation for every condition, coloured by current.

    Each line ends where its swarm stopped: a dot when the statistical criterion stopped it, a
    cross when it hit the generation cap.

    **Arguments:** `result` a `mrjax.FitResult` (uses `history`, `generations`,
    `stopped_by_criterion`, `current`); `logy` logarithmic RMS axis.

    **Returns:** the figure.
    """
    hist = np.asarray(result.history, float)
    fig = new_figure(7.5, 4.6)
    ax = fig.subplots()
    ax.set_title("Swarm convergence: group-best RMS per condition")
    if hist.ndim != 2 or hist.shape[1] == 0:
        return _no_data(fig, ax, "no swarm history (fitted with method='lm')")
    C = hist.shape[0]
    cur = _arr(result, "current", C)
    gens = np.asarray(result.generations, int)
    crit = np.asarray(result.stopped_by_criterion, bool)
    colors, sm = current_colors(cur)
    for i in range(C):
        g = int(min(max(gens[i], 0), hist.shape[1] - 1))
        h = hist[i, : g + 1]
        ax.plot(np.arange(g + 1), h, color=colors[i], lw=1.0, alpha=0.85)
        ax.plot([g], [h[-1]], ls="", marker="o" if crit[i] else "x", ms=5 if crit[i] else 6,
                color=colors[i], mew=1.3)
    if logy and np.all(hist[np.isfinite(hist)] > 0):
        ax.set_yscale("log")
        plain = FuncFormatter(lambda v, _: f"{v:g}")
        ax.yaxis.set_major_formatter(plain)
        ax.yaxis.set_minor_formatter(plain)
        ax.tick_params(axis="y", which="minor", labelsize=7)
    ax.set_xlabel("generation")
    ax.set_ylabel("group-best RMS [N]")
    ax.grid(True, which="both", lw=0.4, alpha=0.4)
    handles = [Line2D([], [], ls="", marker="o", color="0.3", label="stopped by criterion"),
               Line2D([], [], ls="", marker="x", color="0.3", mew=1.3, label="hit the cap")]
    ax.legend(handles=handles, fontsize=8, loc="upper right", frameon=False)
    if sm is not None:
        cb = fig.colorbar(sm, ax=ax, pad=0.01)
        cb.set_label("current [A]")
    return fig


def plot_pso_vs_polish(result: Any) -> Figure:
    """Per-condition RMS of the swarm alone vs after the Levenberg-Marquardt polish.

    **Arguments:** `result` a `mrjax.FitResult` (uses `pso_rms`, `rms`, `labels`).

    **Returns:** the figure: one column per condition, open marker = swarm, filled = polished,
    joined by a line (longer line, larger gain).
    """
    rms = np.asarray(result.rms, float)
    pso = np.asarray(result.pso_rms, float)
    C = rms.size
    labels = labels_of(result, C)
    fig = new_figure(max(6.0, min(16.0, 2.5 + 0.24 * C)), 4.4)
    ax = fig.subplots()
    ax.set_title("Swarm alone vs after the Levenberg-Marquardt polish")
    if not np.any(np.isfinite(pso)):
        return _no_data(fig, ax, "no swarm result to compare (fitted with method='lm')")
    i = np.arange(C)
    ax.vlines(i, np.fmin(pso, rms), np.fmax(pso, rms), color="0.6", lw=1.2, zorder=1)
    ax.scatter(i, pso, marker="o", s=30, facecolors="none", edgecolors="C0", label="swarm",
               zorder=3)
    ax.scatter(i, rms, marker="o", s=22, color="C3", label="swarm + polish", zorder=4)
    both = np.concatenate([pso[np.isfinite(pso)], rms[np.isfinite(rms)]])
    if both.size and both.min() > 0 and both.max() / both.min() > 20:
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.set_xticks(i)
    ax.set_xticklabels(labels, rotation=90, fontsize=6 if C > 20 else 8)
    ax.set_xlim(-0.7, C - 0.3)
    ax.set_ylabel("RMS force error [N]")
    ax.grid(True, axis="y", lw=0.4, alpha=0.5)
    gain = np.nanmedian(np.where(pso > 0, 1 - rms / pso, np.nan)) if C else np.nan
    note = f"median reduction {100 * gain:.3g} %" if np.isfinite(gain) else ""
    ax.legend(fontsize=8, loc="upper right", frameon=False, title=note or None,
              title_fontsize=8)
    return fig
