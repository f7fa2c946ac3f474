"""Section 3, `polish`: swarm alone vs swarm + Levenberg-Marquardt polish vs polish alone,
RMS/sigma against wall time (tanh and Bouc-Wen), drawn in `polish.png`."""

from __future__ import annotations

import time

import matplotlib.pyplot as plt
import numpy as np

import mrjax
from mrjax.data import paper_grid

from ._common import log
from ._work import SIGMA, ode_grid

#: The settings of each method (`FitResult.method`): the swarm alone, swarm then polish, the
#: polish alone.
METHODS = {"pso": dict(polish=None), "pso+lm": dict(polish=mrjax.Polish(uncertainty=False)),
           "lm": dict(swarm=None, polish=mrjax.Polish(uncertainty=False))}


def _one_method(cfg, name: str, batch, method: str) -> dict:
    """`mrjax.fit(name, batch, **METHODS[method])`: first (compiling) call, warm repeats,
    quality and, with a swarm, its median convergence curve against time."""
    kw = dict(METHODS[method], key=0)
    t0 = time.perf_counter()
    mrjax.fit(name, batch, **kw)
    first = time.perf_counter() - t0
    times, r = [], None
    for _ in range(max(1, cfg.repeats_slow - 1)):
        t0 = time.perf_counter()
        r = mrjax.fit(name, batch, **kw)
        times.append(time.perf_counter() - t0)
    e = {
        "first_s": first,
        "median_s": float(np.median(times)),
        "times_s": times,
        "median_rms_over_sigma": float(np.median(r.rms) / SIGMA),
        "max_rms_over_sigma": float(np.max(r.rms) / SIGMA),
        "stage_timings": r.timings,
    }
    if method != "lm":
        e["generations_median"] = float(np.median(r.generations))
        swarm_t = r.timings.get("swarm", np.nan)
        G = r.history.shape[1] - 1
        e["curve_t_s"] = (np.arange(G + 1) * swarm_t / max(G, 1)).tolist()
        e["curve_rms_over_sigma"] = (np.median(r.history, axis=0) / SIGMA).tolist()
    return e


def section_polish(cfg) -> dict:
    out: dict = {}
    grids = {"kwok": paper_grid(), "bouc_wen": ode_grid("bouc_wen")}
    for name, batch in grids.items():
        res = {}
        for method in ("pso", "pso+lm", "lm"):
            log(f"polish: {name} {method}")
            res[method] = _one_method(cfg, name, batch, method)
        out[name] = res
    _plot_polish(out, cfg.out / "polish.png")
    return out


def _plot_polish(res, path):
    fig, axes = plt.subplots(1, len(res), figsize=(5.2 * len(res), 4.0))
    for ax, (name, r) in zip(np.atleast_1d(axes), res.items()):
        p = r["pso"]
        ax.plot(
            np.maximum(p["curve_t_s"], 1e-3),
            p["curve_rms_over_sigma"],
            "-",
            color="C0",
            label="swarm, best RMS per generation",
        )
        for m, mk, c in (("pso", "o", "C0"), ("pso+lm", "s", "C1"), ("lm", "^", "C2")):
            ax.plot(
                [r[m]["median_s"]],
                [r[m]["median_rms_over_sigma"]],
                mk,
                color=c,
                ms=8,
                label=f"{m}: {r[m]['median_s']:.2f} s, "
                f"RMS/sigma {r[m]['median_rms_over_sigma']:.3f}",
            )
        ax.axhline(1.0, color="0.5", lw=0.8, ls=":")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time, warm [s]")
        ax.set_ylabel("median RMS / sigma (sigma = 20 N)")
        ax.set_title(f"{name}: 36 conditions")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
