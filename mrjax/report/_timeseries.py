"""Signals against time: the records as read (`mrjax inspect`) and measured vs model force of
records that are not periodic (random, earthquake-type), where F-x and F-v "loops" are an
unreadable scribble.

Like every figure of `mrjax.report`, the functions return a `matplotlib.figure.Figure` built
without `pyplot`. Long records are drawn through a min/max envelope of a few thousand points
per line, so a long record draws about as fast as a short one and keeps its peaks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from ._figures import FITTED_COLOR, MEASURED_COLOR, labels_of, measured_and_model, velocity_scale

#: Most points drawn per line: longer signals are reduced to their min/max envelope.
_MAX_POINTS = 4000
_RESIDUAL = "#1f77b4"
_ZOOM_SHADE = "#ffbf00"


def _envelope(t: np.ndarray, y: np.ndarray, n_max: int = _MAX_POINTS) -> tuple[np.ndarray,
                                                                                np.ndarray]:
    """`(t, y)` reduced to at most about `n_max` points: the minimum and the maximum of each
    of `n_max / 2` consecutive buckets, in time order (the drawn line keeps every peak)."""
    n = t.shape[0]
    if n <= n_max:
        return t, y
    k = math.ceil(n / (n_max // 2))
    m = n // k * k
    blocks = y[:m].reshape(-1, k)
    base = np.arange(blocks.shape[0]) * k
    idx = np.sort(np.concatenate([base + blocks.argmin(1), base + blocks.argmax(1)]))
    if m < n:
        tail = m + np.array([np.argmin(y[m:]), np.argmax(y[m:])])
        idx = np.concatenate([idx, np.sort(tail)])
    return t[idx], y[idx]


def chosen_panels(C: int, max_panels: int) -> list[int]:
    """At most `max_panels` condition indices, evenly spread over `C`."""
    max_panels = max(1, int(max_panels))
    if C <= max_panels:
        return list(range(C))
    return sorted(set(np.linspace(0, C - 1, max_panels).round().astype(int).tolist()))


def zoom_span(t: np.ndarray, f: np.ndarray, zoom: float | tuple[float, float] | None,
               ) -> tuple[float, float]:
    """The zoomed time span [s] of one record (see :func:`plot_force_time`)."""
    if isinstance(zoom, (tuple, list)):
        lo, hi = float(zoom[0]), float(zoom[1])
        if not hi > lo:
            raise ValueError(f"zoom span must have t1 > t0, got {zoom!r}")
        return lo, hi
    duration = float(t[-1] - t[0])
    step = duration / max(t.shape[0] - 1, 1)
    length = duration / 8.0 if zoom is None else float(zoom)
    if not (math.isfinite(length) and length > 0):
        raise ValueError(f"zoom length must be positive seconds, got {zoom!r}")
    length = min(max(length, 20 * step), duration)
    centre = float(t[int(np.argmax(np.abs(f - np.median(f))))])
    lo = min(max(centre - length / 2, float(t[0])), float(t[-1]) - length)
    return lo, lo + length


def plot_force_time(
    result: Any,
    batch: Any,
    *,
    force: np.ndarray | None = None,
    rms: Sequence[float] | None = None,
    title: str | None = None,
    max_panels: int = 8,
    zoom: float | tuple[float, float] | None = None,
) -> Figure:
    """Measured vs model force against time, whole record and a zoomed window, with the
    residual: the figure for records that are not periodic.

    One row per condition: on the left the whole record, on the right a zoomed window (shaded
    on the left), each with the force [N] above and the residual measured - model [N] below.

    **Arguments:**

    - `result`: a `mrjax.FitResult`, or any object with `.predict(batch) -> (C, T)` force [N]
        (e.g. a generalized model); not called when `force` is given.
    - `batch`: the `mrjax.data.Batch` (same conditions, same order).
    - `force`: the model force (C, T) [N], instead of `result.predict(batch)`.
    - `rms`: per-condition RMS [N] to print (default `result.rms` when it has one entry per
        condition, else the RMS over the batch mask).
    - `title`: figure title (default names the model).
    - `max_panels`: at most this many conditions are drawn, evenly spread over the batch; the
        title says how many were left out.
    - `zoom`: the zoomed window: a length [s] centred on the largest measured force (clipped
        to the record), or a span `(t0, t1)` [s]. Default: an eighth of each record (at least
        20 samples) centred on its largest force.

    **Returns:** the figure.
    """
    F, pred, mask, rms = measured_and_model(result, batch, force, rms)
    C = F.shape[0]
    t_all = np.asarray(batch.t, dtype=float)
    labels = labels_of(batch, C)
    idx = chosen_panels(C, max_panels)

    W, row_h = 11.0, 2.5
    H = 0.75 + row_h * len(idx)
    fig = Figure(figsize=(W, H))
    gs = fig.add_gridspec(len(idx), 2, width_ratios=(2.3, 1.0), left=0.75 / W,
                          right=1 - 0.15 / W, bottom=0.4 / H, top=1 - 0.6 / H, wspace=0.12,
                          hspace=0.55)
    for row, i in enumerate(idx):
        n = int(mask[i].sum())
        t, f, p = t_all[i, :n], F[i, :n], pred[i, :n]
        res = f - p
        lo, hi = zoom_span(t, f, zoom)
        inside = (t >= lo) & (t <= hi)
        for col, sel in ((0, slice(None)), (1, inside)):
            sg = gs[row, col].subgridspec(2, 1, height_ratios=(3, 1), hspace=0.08)
            ax_f = fig.add_subplot(sg[0])
            ax_r = fig.add_subplot(sg[1], sharex=ax_f)
            ts = t[sel]
            for ax, y, color, lw in ((ax_f, f[sel], MEASURED_COLOR, 0.7), (ax_f, p[sel], FITTED_COLOR, 0.8),
                                     (ax_r, res[sel], _RESIDUAL, 0.6)):
                ax.plot(*_envelope(ts, y), color=color, lw=lw)
            ax_r.axhline(0.0, color="0.3", lw=0.5)
            for ax in (ax_f, ax_r):
                ax.tick_params(labelsize=6.5, length=2, pad=1.5)
                ax.grid(True, lw=0.3, alpha=0.5)
                ax.locator_params(axis="y", nbins=4)
            ax_f.tick_params(labelbottom=False)
            if col == 0:
                ax_f.axvspan(lo, hi, color=_ZOOM_SHADE, alpha=0.18, lw=0)
                ax_r.axvspan(lo, hi, color=_ZOOM_SHADE, alpha=0.18, lw=0)
                ax_f.set_ylabel("F [N]", fontsize=7, labelpad=1)
                ax_r.set_ylabel("resid. [N]", fontsize=6.5, labelpad=1)
                rtxt = f"{rms[i]:.3g} N" if np.isfinite(rms[i]) else "-"
                ax_f.set_title(f"{labels[i]}   RMS {rtxt}   ({t[-1] - t[0]:.4g} s)", fontsize=7.5,
                               loc="left", pad=2)
                ax_f.set_xlim(t[0], t[-1])
            else:
                ax_f.set_title(f"zoom {lo:.4g}-{hi:.4g} s", fontsize=7, loc="left", pad=2)
                ax_f.set_xlim(lo, hi)
            if row == len(idx) - 1:
                ax_r.set_xlabel("time [s]", fontsize=7, labelpad=1)
    name = getattr(getattr(result, "model", None), "name", None)
    head = title or (f"{name}: measured vs fitted force" if name else "measured vs model force")
    if len(idx) < C:
        head += f" ({len(idx)} of {C} conditions shown)"
    fig.suptitle(head, fontsize=10, x=0.75 / W, ha="left", y=1 - 0.12 / H, va="top")
    fig.legend([Line2D([], [], color=MEASURED_COLOR, lw=1.2), Line2D([], [], color=FITTED_COLOR, lw=1.2),
                Line2D([], [], color=_RESIDUAL, lw=1.2)],
               ["measured", "model", "residual (measured - model)"], loc="upper right",
               bbox_to_anchor=(1 - 0.15 / W, 1 - 0.04 / H), fontsize=7.5, ncols=3,
               frameon=False)
    return fig


def plot_records(data: Any, *, max_panels: int = 12, title: str | None = None) -> Figure:
    """The records as read, against time: a quick look to check a data spec before a fit.

    One row per condition: displacement [mm], velocity [mm/s or m/s] (marked when estimated
    from the displacement), force [N] and, when any condition carries one, the per-sample
    command (current [A] or voltage [V]).

    **Arguments:**

    - `data`: a `mrjax.data.Batch` or a sequence of `mrjax.data.Condition` (as
        `mrjax.data.load` returns them).
    - `max_panels`: at most this many conditions are drawn, evenly spread; the title says how
        many were left out.
    - `title`: figure title (default "what was read").

    **Returns:** the figure.
    """
    conds = data.conditions() if hasattr(data, "conditions") else list(data)
    if not conds:
        raise ValueError("no conditions to plot")
    C = len(conds)
    idx = chosen_panels(C, max_panels)
    has_cmd = any(conds[i].command is not None for i in idx)
    vs, vunit = velocity_scale(np.concatenate([conds[i].xdot for i in idx]))
    cols = ["displacement [mm]", f"velocity [{vunit}]", "force [N]"]
    if has_cmd:
        cols.append("command")
    W = 2.9 * len(cols) + 0.6
    row_h = 1.55
    H = 0.75 + row_h * len(idx)
    fig = Figure(figsize=(W, H))
    gs = fig.add_gridspec(len(idx), len(cols), left=0.55 / W, right=1 - 0.12 / W,
                          bottom=0.42 / H, top=1 - 0.55 / H, wspace=0.3, hspace=0.75)
    for row, i in enumerate(idx):
        c = conds[i]
        signals = [(c.x * 1e3, "x [mm]", ""), (c.xdot * vs, f"v [{vunit}]",
                                                " (estimated)" if "xdot" in c.estimated else ""),
                   (c.force, "F [N]", "")]
        if has_cmd:
            signals.append((c.command, f"command [{c.command_unit}]", "") if c.command is not None
                           else (None, "command", " (none)"))
        first = None
        for col, (y, ylabel, note) in enumerate(signals):
            ax = fig.add_subplot(gs[row, col], sharex=first)
            first = first or ax
            if y is not None:
                ax.plot(*_envelope(c.t, np.asarray(y, float)), color="C0" if col < 3 else "C2",
                        lw=0.6)
            else:
                ax.set_yticks([])
            ax.set_ylabel(ylabel, fontsize=6.5, labelpad=1)
            ax.tick_params(labelsize=6, length=2, pad=1.5)
            ax.locator_params(nbins=4)
            ax.grid(True, lw=0.3, alpha=0.5)
            ax.set_xlim(c.t[0], c.t[-1])
            what = cols[col].split(" [")[0]
            ax.set_title((f"{c.label}: {what}" if col == 0 else what) + note, fontsize=7,
                         loc="left", pad=2)
            if row == len(idx) - 1:
                ax.set_xlabel("time [s]", fontsize=6.5, labelpad=1)
    head = title or "What was read"
    if len(idx) < C:
        head += f" ({len(idx)} of {C} conditions shown)"
    fig.suptitle(head, fontsize=10, x=0.55 / W, ha="left", y=1 - 0.12 / H, va="top")
    return fig
