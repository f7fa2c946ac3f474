"""The study's figures: the paper's Figs 3 and 7-12 and four diagnostics, each drawn as soon as
the runs it shows are ready."""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace
from typing import Any, NamedTuple

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from ..data import paper_parameters
from ..report import (
    TANH_STEP_NOTE,
    plot_convergence,
    plot_data_loops,
    plot_generations_vs_current,
    plot_loops_grid,
    plot_params_vs_current,
    plot_pso_vs_polish,
    plot_rms_vs_current,
    save_png_bytes,
)
from ._data import figure_motions, motion_index
from ._study import Study, headline_generalized


def _loops_for_motions(result, batch, force, rms, motions, title) -> Figure:
    """Measured vs model loops of the conditions of `motions` (rows) x current (columns)."""
    idx = motion_index(batch, motions)
    if idx.size == 0:
        idx = np.arange(batch.n_conditions)
    sub = batch.subset(idx)
    f = np.asarray(force, float)[idx][:, : sub.length]
    return plot_loops_grid(result, sub, force=f, rms=np.asarray(rms, float)[idx], title=title)


def _motions_text(batch) -> str:
    return " and ".join(f"{f:g} Hz / {a * 1e3:g} mm" for f, a in figure_motions(batch))


def _fig_data(study: Study) -> Figure:
    if study.data_info["truth"]:  # the embedded data: simulated by the tanh model
        return plot_data_loops(
            study.batch, title="Fig 3: simulated force loops by current (tanh model at eq "
            "24-29, 20 N noise)", note=TANH_STEP_NOTE)
    return plot_data_loops(study.batch, title="Fig 3: measured force loops by current")


def _fig_loops(key: str, number: int, name: str) -> Callable[[Study], Figure]:
    def draw(study: Study) -> Figure:
        r = study.runs[key]
        return _loops_for_motions(
            r, study.batch, r.predict(study.batch), r.rms, figure_motions(study.batch),
            f"Fig {number}: {name} model (paper's swarm) vs data at {_motions_text(study.batch)}")
    return draw


def _paper_pair(study: Study) -> dict[str, Any]:
    return {"tanh": study.runs["kwok_paper_swarm"], "Bouc-Wen": study.runs["bouc_wen_paper_swarm"]}


def _fig_rms(study: Study) -> Figure:
    fig = plot_rms_vs_current(_paper_pair(study))
    fig.axes[0].set_title("Fig 9: RMS error vs current, paper's swarm (same seed)")
    return fig


def _fig_generations(study: Study) -> Figure:
    pair = _paper_pair(study)
    fig = plot_generations_vs_current(pair)
    ax = fig.axes[0]
    ax.set_title("Fig 10: generations to the stop, paper's swarm")
    top = max(int(np.max(r.generations)) for r in pair.values())
    cap = min(int(np.asarray(r.history).shape[1] - 1) for r in pair.values())
    if top < 0.6 * cap:  # zoom on the data; the cap is far above and was never reached
        ax.set_ylim(0, 1.12 * top)
        ax.text(0.01, 0.98, f"generation cap {cap}: not reached", transform=ax.transAxes,
                ha="left", va="top", fontsize=8, color="0.35")
        for leg in list(fig.legends):
            keep = [(h, t.get_text()) for h, t in zip(leg.legend_handles, leg.get_texts())
                    if t.get_text() not in ("generation cap", "hit the cap")]
            leg.remove()
            fig.legend([h for h, _ in keep], [t for _, t in keep], fontsize=7.5,
                       loc="outside right upper", frameon=False)
    return fig


def _fig_params(study: Study) -> Figure:
    """Each tanh parameter vs current with its two-step law and, with the embedded data, the
    paper's eq 24-29."""
    res = study.runs["kwok_separable"]
    key = headline_generalized(study)
    gm = study.generalized.get(key) if key else None
    fig = plot_params_vs_current(res, laws=gm)
    cur = np.asarray(study.batch.current, float)
    if study.data_info["truth"] and np.all(np.isfinite(cur)):
        grid = np.linspace(float(cur.min()), float(cur.max()), 200)
        ref = paper_parameters(grid)
        axes = {ax.get_title(): ax for ax in fig.axes}
        # the truth as a wide light band under the fitted law: both stay visible where they
        # coincide (a dashed line on top hid the law, under it the law hid the truth)
        band = dict(color="C3", lw=6, alpha=0.3, solid_capstyle="butt", zorder=1)
        for p, name in enumerate(res.param_names):
            if name in axes:
                axes[name].plot(grid, ref[:, p], **band)
        handles, labels = [], []
        first = axes.get(res.param_names[0])
        if first is not None:
            handles, labels = first.get_legend_handles_labels()
        handles.append(Line2D([], [], **band))
        labels.append("eq 24-29 (truth)")
        for leg in list(fig.legends):
            leg.remove()
        fig.legend(handles, labels, loc="outside right upper", fontsize=8, frameon=False)
    if gm is not None:
        fig.suptitle(f"Fig 11: tanh parameters per test (separable swarm + LM, bars ±1 "
                     f"std-error) and {key} laws", fontsize=11)
    return fig


def _fig_generalized(study: Study) -> Figure:
    key = headline_generalized(study)
    gm = study.generalized[key]
    ev = study.generalized_eval[key]
    return plot_loops_grid(gm, study.batch, force=ev["predicted"], rms=ev["rms"],
                           title=f"Fig 12: generalized tanh model ({key} laws, total RMS "
                                 f"{gm.total_rms:.1f} N) vs data")


def _fig_rms_identified(study: Study) -> Figure:
    ks = study.runs["kwok_separable"]
    swarm_only = SimpleNamespace(current=ks.current, frequency=ks.frequency,
                                 amplitude=ks.amplitude, labels=ks.labels, rms=ks.pso_rms)
    res = {"tanh, separable swarm": swarm_only, "tanh, separable swarm + LM": ks}
    if "bouc_wen_separable" in study.runs:
        res["Bouc-Wen, separable swarm"] = study.runs["bouc_wen_separable"]
    fig = plot_rms_vs_current(res)
    fig.axes[0].set_title("RMS error, accurate identification")
    return fig


def _fig_pso_vs_polish(study: Study) -> Figure:
    fig = plot_pso_vs_polish(study.runs["kwok_paper_swarm_polished"])
    ax = fig.axes[0]
    ax.set_title("tanh, paper's swarm: alone vs after the LM polish")
    if ax.get_legend() is not None:
        ax.get_legend().set_loc("upper left")
    return fig


def _fig_convergence(key: str, name: str) -> Callable[[Study], Figure]:
    def draw(study: Study) -> Figure:
        fig = plot_convergence(study.runs[key])
        fig.axes[0].set_title(f"{name}, paper's swarm: group-best RMS per condition")
        return fig
    return draw


class _Figure(NamedTuple):
    needs: tuple[str, ...]  # runs it shows
    draw: Callable[[Study], Figure]
    caption: str  # its line in summary.md
    needs_generalized: bool = False
    final_only: bool = False  # waits for every run (it shows the Bouc-Wen one if there is one)


#: Figure file -> what it needs, how it is drawn and its caption, in the order of summary.md.
FIGURES: dict[str, _Figure] = {
    "fig03_data_loops.png": _Figure(
        (), _fig_data, "Fig 3: the data, force-displacement and force-velocity loops by current "
        "(simulated by the tanh model for the embedded data: its force steps at x = 0, the "
        "δ·sign(x) term)"),
    "fig07_loops_tanh.png": _Figure(
        ("kwok_paper_swarm",), _fig_loops("kwok_paper_swarm", 7, "tanh"),
        "Fig 7: loops of the tanh model (paper's swarm) against the data (the step at x = 0 "
        "is the model's δ·sign(x) term)"),
    "fig08_loops_bouc_wen.png": _Figure(
        ("bouc_wen_paper_swarm",), _fig_loops("bouc_wen_paper_swarm", 8, "Bouc-Wen"),
        "Fig 8: loops of the Bouc-Wen model (paper's swarm)"),
    "fig09_rms_vs_current.png": _Figure(
        ("kwok_paper_swarm", "bouc_wen_paper_swarm"), _fig_rms,
        "Fig 9: RMS error vs current, both models, paper's swarm"),
    "fig10_generations_vs_current.png": _Figure(
        ("kwok_paper_swarm", "bouc_wen_paper_swarm"), _fig_generations,
        "Fig 10: generations to the statistical stop"),
    "fig11_params_vs_current.png": _Figure(
        ("kwok_separable",), _fig_params, "Fig 11: tanh parameters vs current with their laws"),
    "fig12_generalized_loops.png": _Figure(
        ("kwok_separable",), _fig_generalized, "Fig 12: loops of the generalized tanh model",
        needs_generalized=True),
    "rms_identified.png": _Figure(
        ("kwok_separable",), _fig_rms_identified,
        "RMS of the accurate identifications (separable swarms)", final_only=True),
    "pso_vs_polish.png": _Figure(
        ("kwok_paper_swarm_polished",), _fig_pso_vs_polish,
        "The paper's swarm alone vs after the Levenberg-Marquardt polish"),
    "convergence_tanh.png": _Figure(
        ("kwok_paper_swarm",), _fig_convergence("kwok_paper_swarm", "tanh"),
        "Convergence histories, tanh, paper's swarm"),
    "convergence_bouc_wen.png": _Figure(
        ("bouc_wen_paper_swarm",), _fig_convergence("bouc_wen_paper_swarm", "Bouc-Wen"),
        "Convergence histories, Bouc-Wen, paper's swarm"),
}


def draw_figures(study: Study, files: dict[str, bytes], *, final: bool = True) -> list[str]:
    """Render into `files` (name -> PNG bytes) every figure of the study whose inputs are
    ready and that is not there yet. `rms_identified.png` waits for `final` (it shows the
    Bouc-Wen separable swarm when there is one).

    **Returns:** the names drawn.
    """
    drawn = []
    for name, spec in FIGURES.items():
        if name in files or not all(k in study.runs for k in spec.needs):
            continue
        if spec.needs_generalized and headline_generalized(study) is None:
            continue
        if spec.final_only and not final:
            continue
        files[name] = save_png_bytes(spec.draw(study))
        drawn.append(name)
    return drawn
