"""Force loops: measured vs model F-x and F-v loops of every condition (the paper's Figs 7, 8
and 12) and the measured loops by current (Fig 3)."""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from ._figures import (
    FITTED_COLOR,
    MEASURED_COLOR,
    current_colors,
    distinct_motions,
    labels_of,
    measured_and_model,
    motion_label,
    motion_of,
    new_figure,
    small_axes,
    velocity_scale,
)

#: The note under loops of the tanh model: its force steps where x changes sign.
TANH_STEP_NOTE = ("The tanh model's δ·sign(x) term steps its force where the displacement "
                  "changes sign: the vertical jumps of the F–x loops at x = 0 (and, on a real "
                  "record, a spike in its first cycle) are the model, not the data.")
#: Cell of one condition in a loop grid [in]: F-x above F-v.
_CELL_W, _CELL_H = 1.95, 3.3


def condition_title(label: str, frequency: float, amplitude: float, current: float) -> str:
    """A condition as an engineer names it, `25 mm, 0.1 Hz, 0.25 A` (amplitude [m],
    frequency [Hz], current [A]); what is unknown (NaN) is left out, and the label is used when
    all are."""
    parts = []
    if math.isfinite(amplitude):
        parts.append(f"{amplitude * 1e3:.3g} mm")
    if math.isfinite(frequency):
        parts.append(f"{frequency:.3g} Hz")
    if math.isfinite(current):
        parts.append(f"{current:.3g} A")
    return ", ".join(parts) if parts else label


def _layout_cells(cur: np.ndarray, freq: np.ndarray, amp: np.ndarray, idx: Sequence[int]):
    """(row, col) of each selected condition: motions by rows and currents by columns when the
    conditions form such a grid (one condition per cell), else row-major in a near-square grid.

    Returns `(cells, nrows, ncols, grid)`: `grid` tells whether rows are motions."""
    idx = list(idx)
    keys = [(motion_of(freq[i], amp[i]), cur[i]) for i in idx]
    if all(m is not None and math.isfinite(c) for m, c in keys) and len(set(keys)) == len(keys):
        motions = sorted({m for m, _ in keys})
        currents = sorted({c for _, c in keys})
        full = len(keys) >= 0.75 * len(motions) * len(currents)
        if len(motions) > 1 and len(currents) > 1 and len(currents) <= 8 and full:
            cells = [(motions.index(m), currents.index(c)) for m, c in keys]
            return cells, len(motions), len(currents), True
    n = len(idx)
    ncols = max(1, min(6, math.ceil(math.sqrt(n))))
    nrows = math.ceil(n / ncols)
    return [(k // ncols, k % ncols) for k in range(n)], nrows, ncols, False


def _model_name(result: Any) -> str | None:
    """The model's name of a fit result or a generalized model (`.model.name`)."""
    return getattr(getattr(result, "model", None), "name", None)


def plot_loops_grid(
    result: Any,
    batch: Any,
    *,
    max_panels: int = 36,
    force: np.ndarray | None = None,
    rms: Sequence[float] | None = None,
    title: str | None = None,
) -> Figure:
    """Measured vs fitted force-displacement and force-velocity loops of every condition.

    Each condition gets a cell: its F-x loop [mm] above its F-v loop [mm/s], each with its
    axis labels, under a title naming the test (`25 mm, 0.1 Hz, 0.25 A`, else its label) and
    its RMS error. When the conditions form a motion x current grid, rows are motions and
    columns currents (as the paper's Figs 7, 8 and 12); otherwise they fill a near-square grid
    in batch order. Loops of the tanh model carry a note on its force step at x = 0
    (`TANH_STEP_NOTE`).

    **Arguments:**

    - `result`: a `mrjax.FitResult`, or any object with `.predict(batch) -> (C, T)` force [N]
        (e.g. a generalized model); not called when `force` is given.
    - `batch`: the `mrjax.data.Batch` it was fitted on (same conditions, same order).
    - `max_panels`: at most this many conditions are drawn, evenly spread over the batch; the
        title says how many were left out.
    - `force`: the model force (C, T) [N], instead of `result.predict(batch)`.
    - `rms`: per-condition RMS [N] to print (default `result.rms` when it has one entry per
        condition, else the RMS over the batch mask).
    - `title`: figure title (default names the model).

    **Returns:** the figure.
    """
    F, pred, mask, rms = measured_and_model(result, batch, force, rms)
    C = F.shape[0]
    x = np.asarray(batch.x, dtype=float) * 1e3
    vs, vunit = velocity_scale(np.asarray(batch.xdot)[mask])
    v = np.asarray(batch.xdot, dtype=float) * vs
    labels = labels_of(batch, C)
    cur, freq, amp = (np.asarray(getattr(batch, k), float) for k in
                      ("current", "frequency", "amplitude"))

    max_panels = max(1, int(max_panels))
    idx = (list(range(C)) if C <= max_panels
           else sorted(set(np.linspace(0, C - 1, max_panels).round().astype(int).tolist())))
    cells, nrows, ncols, grid = _layout_cells(cur, freq, amp, idx)
    name = _model_name(result)
    note = TANH_STEP_NOTE if name == "kwok" else None

    # manual grid (constrained layout is slow with dozens of axes); margins fixed in inches
    left, right, top = 0.62, 0.12, 0.78
    W = max(6.0, left + right + _CELL_W * ncols)
    if note:  # about 15 characters per inch at 7.5 pt
        note = textwrap.fill(note, width=int(15 * (W - left - right)))
    bottom = 0.42 + (0.15 + 0.14 * note.count("\n") if note else 0.0)
    H = top + bottom + _CELL_H * nrows
    fig = Figure(figsize=(W, H))
    gs = fig.add_gridspec(nrows, ncols, left=left / W, right=1 - right / W, bottom=bottom / H,
                          top=1 - top / H, wspace=0.42, hspace=0.3)
    first_col = {r: min(c for rr, c in cells if rr == r) for r, _ in cells}
    for i, (r, c) in zip(idx, cells):
        sg = gs[r, c].subgridspec(2, 1, hspace=0.5)
        ax_x, ax_v = fig.add_subplot(sg[0, 0]), fig.add_subplot(sg[1, 0])
        m = np.flatnonzero(mask[i])
        m = m[:: max(1, m.size // 2000)]  # a few thousand points are plenty at this size
        for ax, xx, xl in ((ax_x, x[i, m], "x [mm]"), (ax_v, v[i, m], f"v [{vunit}]")):
            ax.plot(xx, F[i, m], color=MEASURED_COLOR, lw=0.7)
            ax.plot(xx, pred[i, m], color=FITTED_COLOR, lw=0.9)
            small_axes(ax, 7)
            ax.locator_params(nbins=3)
            ax.set_xlabel(xl, fontsize=7.5, labelpad=1)
            if c == first_col[r]:
                ax.set_ylabel("F [N]", fontsize=7.5, labelpad=1)
        rtxt = f"{rms[i]:.3g} N" if np.isfinite(rms[i]) else "-"
        ax_x.set_title(f"{condition_title(labels[i], freq[i], amp[i], cur[i])}\nRMS {rtxt}",
                       fontsize=8, pad=3, linespacing=1.15)
    head = title or (f"{name}: measured vs fitted loops" if name else "measured vs model loops")
    if len(idx) < C:
        head += f" ({len(idx)} of {C} conditions shown)"
    if grid:
        head += "   (rows: motion, columns: current)"
    fig.suptitle(head, fontsize=10, x=left / W, ha="left", y=1 - 0.1 / H, va="top")
    fig.legend([Line2D([], [], color=MEASURED_COLOR, lw=1.2),
                Line2D([], [], color=FITTED_COLOR, lw=1.2)],
               ["measured", "model"], loc="upper right",
               bbox_to_anchor=(1 - right / W, 1 - 0.02 / H), fontsize=8, ncols=2, frameon=False)
    if note:
        fig.text(left / W, 0.1 / H, note, fontsize=7.5, color="0.3", ha="left", va="bottom")
    return fig


def plot_data_loops(batch: Any, *, motion: tuple[float, float] | None = None,
                    title: str = "Measured force loops by current",
                    note: str | None = None) -> Figure:
    """Force-displacement and force-velocity loops of the data coloured by current (Fig 3).

    One panel pair (F-x, F-v) per (frequency, amplitude) motion, or only `motion`.

    **Arguments:**

    - `batch`: a `mrjax.data.Batch`.
    - `motion`: `(frequency [Hz], amplitude [m])` to draw only that motion (default: all).
    - `title`: the figure's title (e.g. "Simulated force loops ..." for synthetic data).
    - `note`: a line of text under the panels (e.g. `TANH_STEP_NOTE` for data simulated by
        the tanh model), or None.

    **Returns:** the figure. Raises `ValueError` if `motion` is not in the batch.
    """
    F = np.asarray(batch.force, float)
    x = np.asarray(batch.x, float) * 1e3
    mask = np.asarray(batch.mask, bool)
    vs, vunit = velocity_scale(np.asarray(batch.xdot)[mask])
    v = np.asarray(batch.xdot, float) * vs
    cur, freq, amp = (np.asarray(getattr(batch, k), float) for k in
                      ("current", "frequency", "amplitude"))
    labels = labels_of(batch, F.shape[0])
    motions = distinct_motions(freq, amp)
    if motion is not None:
        want = (float(motion[0]), float(motion[1]))
        hit = [m for m in motions if m is not None and np.allclose(m, want, rtol=1e-6)]
        if not hit:
            raise ValueError(f"motion {motion_label(want)} not in the batch; it has "
                             f"{', '.join(motion_label(m) for m in motions)}")
        motions = hit
    colors, sm = current_colors(cur)

    nblk = min(3, len(motions))
    nrows = math.ceil(len(motions) / nblk)
    fig = new_figure(max(7.0, 5.6 * nblk) + 0.6, 0.8 + 2.9 * nrows + (0.3 if note else 0.0))
    axes = fig.subplots(nrows, 2 * nblk, squeeze=False)
    for k, m in enumerate(motions):
        r, c = divmod(k, nblk)
        ax_x, ax_v = axes[r][2 * c], axes[r][2 * c + 1]
        sel = [i for i in range(F.shape[0]) if motion_of(freq[i], amp[i]) == m]
        sel.sort(key=lambda i: (cur[i] if np.isfinite(cur[i]) else np.inf, i))
        for i in sel:
            mi = mask[i]
            lab = labels[i] if sm is None else None
            ax_x.plot(x[i, mi], F[i, mi], color=colors[i], lw=0.9, label=lab)
            ax_v.plot(v[i, mi], F[i, mi], color=colors[i], lw=0.9)
        for ax, xl in ((ax_x, "displacement x [mm]"), (ax_v, f"velocity v [{vunit}]")):
            small_axes(ax, 7)
            ax.set_xlabel(xl, fontsize=8)
            ax.set_ylabel("force F [N]", fontsize=8)
            ax.set_title(f"{motion_label(m)}: F-{'x' if ax is ax_x else 'v'}", fontsize=8.5)
        if sm is None:
            ax_x.legend(fontsize=6, frameon=False)
    for k in range(len(motions), nrows * nblk):
        r, c = divmod(k, nblk)
        axes[r][2 * c].set_visible(False)
        axes[r][2 * c + 1].set_visible(False)
    if sm is not None:
        cb = fig.colorbar(sm, ax=axes, shrink=0.9, pad=0.01, aspect=40)
        cb.set_label("current [A]", fontsize=8)
        cb.ax.tick_params(labelsize=7)
    fig.suptitle(title, fontsize=11)
    if note:
        fig.supxlabel(note, fontsize=8, color="0.3")
    return fig
