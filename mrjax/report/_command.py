"""Figures of records with a time-varying command (the Spencer 1997 workflow): force against
time (measured, identified, a reference model), the command and the filtered command the laws
see, and the laws against the command."""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure

from ..data import as_batch
from ..generalize import GeneralizedModel, lag_current
from ._figures import FITTED_COLOR, MEASURED_COLOR, labels_of, new_figure, rows_rms, save_png_bytes
from ._timeseries import chosen_panels, zoom_span

_REFERENCE = "#1f77b4"
_COMMAND = "0.35"


def _commands(batch) -> np.ndarray:
    """(C, T) command of every condition: its per-sample command, else its constant current."""
    kind = np.asarray(batch.command_kind)
    cur = np.asarray(batch.current, float)
    cmd = np.asarray(batch.command, float) if batch.command is not None else \
        np.full(np.asarray(batch.force).shape, np.nan)
    return np.where(kind[:, None] > 0, cmd, cur[:, None])


def plot_command_record(
    gm: GeneralizedModel,
    data: Any,
    *,
    predicted: np.ndarray | None = None,
    reference: GeneralizedModel | None = None,
    max_panels: int = 4,
    zoom: float | tuple[float, float] | None = None,
) -> Figure:
    """Force against time of records with a time-varying command, in a zoomed window: the
    measured force, the identified model's (`gm`) and, where given, a `reference` model's [N]
    above; the command v and the filtered command u the laws see ($\\dot u = -\\eta(u - v)$,
    `gm.lag`) below, in `gm.command_unit`.

    **Arguments:** `gm` the identified laws; `data` a `mrjax.data.Batch` or condition(s);
    `predicted` (C, T) [N] instead of `gm.predict`; `reference` e.g.
    `mrjax.generalize.spencer_1997()`; `max_panels` at most this many records; `zoom` a
    window length [s] or span `(t0, t1)` (default 2 s, clipped to the record, centred on its
    largest force). **Returns:** the figure.
    """
    batch = as_batch(data)
    F = np.asarray(batch.force, float)
    pred = np.asarray(gm.predict(batch) if predicted is None else predicted, float)
    ref = None if reference is None else np.asarray(reference.predict(batch), float)
    t_all, mask = np.asarray(batch.t, float), np.asarray(batch.mask, bool)
    dt_all = np.asarray(batch.dt, float)
    cmd_all = _commands(batch)
    C = F.shape[0]
    idx = chosen_panels(C, max_panels)
    labels = labels_of(batch, C)
    rms = rows_rms(F, pred, mask)
    unit = gm.command_unit
    fig = new_figure(9.0, 3.4 * len(idx))
    axes = fig.subplots(2 * len(idx), 1, squeeze=False,
                        gridspec_kw={"height_ratios": [2, 1] * len(idx)})[:, 0]
    for r, i in enumerate(idx):
        m = mask[i]
        t, f = t_all[i, m], F[i, m]
        lo, hi = zoom_span(t, f, 2.0 if zoom is None else zoom)
        w = (t >= lo) & (t <= hi)
        ax, axc = axes[2 * r], axes[2 * r + 1]
        ax.plot(t[w], f[w], color=MEASURED_COLOR, lw=0.8, label="measured")
        ax.plot(t[w], pred[i, m][w], color=FITTED_COLOR, lw=1.0,
                label=f"identified (RMS {rms[i]:.3g} N)")
        if ref is not None:
            rr = float(np.sqrt(np.mean((ref[i, m] - f) ** 2)))
            ax.plot(t[w], ref[i, m][w], color=_REFERENCE, lw=0.9, ls="--",
                    label=f"reference (RMS {rr:.3g} N)")
        ax.set_ylabel("force [N]")
        ax.set_title(labels[i], fontsize=9)
        ax.legend(fontsize=7, loc="upper right")
        v = cmd_all[i, m]
        axc.step(t[w], v[w], where="post", color=_COMMAND, lw=0.8, label=f"command v [{unit}]")
        if gm.lag is not None and np.all(np.isfinite(v)):
            u = np.asarray(lag_current(v, dt_all[i, m], gm.lag))
            axc.plot(t[w], u[w], color=FITTED_COLOR, lw=1.0,
                     label=f"filtered u (eta = {gm.lag:.4g} 1/s)")
        axc.set_ylabel(f"[{unit}]")
        axc.set_xlabel("time [s]")
        axc.legend(fontsize=7, loc="upper right")
    return fig


def plot_laws_vs_command(
    gm: GeneralizedModel,
    *,
    reference: GeneralizedModel | None = None,
    n: int = 101,
) -> Figure:
    """Every parameter's law against the command over `gm.command_range` (in
    `gm.command_unit`), with +-2 std-errors where `gm.uncertainty` gives them (propagated by
    the coefficients' std-errors, independent), and a `reference` model's laws dashed (both on
    the |z|max = 1 scale of :meth:`GeneralizedModel.with_canonical_z`). **Returns:** the
    figure."""
    lo, hi = gm.command_range
    u = np.linspace(lo, hi, int(n))
    names, units = gm.param_names, gm.model.units
    P = len(names)
    vals = np.asarray(gm.params_at(u), float)
    refv = None
    if reference is not None:
        refv = np.asarray(reference.with_canonical_z().params_at(u), float)
    cols = min(P, 4)
    rows = -(-P // cols)
    fig = new_figure(2.6 * cols, 2.1 * rows)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    unc = gm.uncertainty
    for p, (name, un) in enumerate(zip(names, units)):
        ax = axes[p]
        ax.plot(u, vals[:, p], color=FITTED_COLOR, lw=1.2, label="identified")
        se = None if unc is None else unc.stderr.get(name)
        if se is not None and np.all(np.isfinite(se)) and gm.laws[name].kind == "poly":
            s = np.sqrt(sum((np.asarray(se[k]) * u ** k) ** 2 for k in range(len(se))))
            ax.fill_between(u, vals[:, p] - 2 * s, vals[:, p] + 2 * s, color=FITTED_COLOR,
                            alpha=0.2, lw=0)
        if refv is not None:
            ax.plot(u, refv[:, p], color=_REFERENCE, lw=1.0, ls="--", label="reference")
        ax.set_title(f"{name} [{un}]", fontsize=9)
        ax.set_xlabel(f"command [{gm.command_unit}]", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes[P:]:
        ax.set_visible(False)
    axes[0].legend(fontsize=7)
    return fig


def command_figures(gm: GeneralizedModel, batch: Any,
                    predicted: np.ndarray | None = None) -> dict[str, bytes]:
    """The PNG figures of laws identified from time-varying commands, name -> bytes:
    `force_time.png` (:func:`plot_command_record`) and `laws_vs_command.png`
    (:func:`plot_laws_vs_command`)."""
    return {"force_time.png": save_png_bytes(plot_command_record(gm, batch,
                                                                 predicted=predicted)),
            "laws_vs_command.png": save_png_bytes(plot_laws_vs_command(gm))}
