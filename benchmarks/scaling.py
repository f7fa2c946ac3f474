"""Section 4, `scaling`: time per swarm generation against conditions, particles and samples
(log-log fitted slopes), drawn in `scaling.png`."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

import mrjax
from mrjax.data import Condition, make_batch
from mrjax.models import get

from ._common import fmt_s, log
from ._work import SIGMA, per_generation_by_callback


def synthetic_batch(C: int, T: int, seed: int = 0):
    """C tanh-model conditions of T samples each (2 cycles at 1 Hz, any T), made with NumPy."""
    rng = np.random.default_rng(seed)
    cur = np.resize(np.asarray(mrjax.data.PAPER_CURRENTS), C)
    motions = mrjax.data.PAPER_MOTIONS
    conds = []
    for i in range(C):
        f, a = motions[i % len(motions)]
        t = np.arange(T) * (2.0 / f) / T
        x = a * np.sin(2 * np.pi * f * t)
        v = a * 2 * np.pi * f * np.cos(2 * np.pi * f * t)
        c, k, al, b, d, f0 = mrjax.data.paper_parameters(cur[i])
        F = c * v + k * x + al * np.tanh(b * v + d * np.sign(x)) + f0 + rng.normal(0, SIGMA, T)
        conds.append(Condition(f"c{i}", float(cur[i]), f, a, t, x, v, F))
    return make_batch(conds)


def _sweep(model, base: dict, axis: str, values, G: int, dn: str, dt) -> dict:
    """Time per generation along one axis (the others at `base`) and its log-log slopes."""
    pts = []
    for v in values:
        size = dict(base, **{axis: v})
        batch = synthetic_batch(size["C"], size["T"])
        r = per_generation_by_callback(
            model, batch, generations=G, dtype=dt, n_particles=size["N"]
        )
        per_gen = r["per_gen_s"]
        pts.append(
            {
                "value": v,
                "per_gen_s": per_gen,
                "per_gen_all_s": r["per_gen_all_s"],
                "first_s": r["first_s"],
                "evals_per_s": size["C"] * size["N"] * size["T"] / per_gen,
            }
        )
        log(f"scaling {dn} {axis}={v}: {fmt_s(per_gen)} per generation")
    x = np.log([p["value"] for p in pts])
    y = np.log([p["per_gen_s"] for p in pts])
    slope = float(np.polyfit(x, y, 1)[0]) if len(pts) > 1 else float("nan")
    hi = len(pts) // 2
    slope_hi = float(np.polyfit(x[hi:], y[hi:], 1)[0]) if len(pts) - hi > 1 else slope
    return {"axis": axis, "dtype": dn, "points": pts, "slope": slope, "slope_upper_half": slope_hi}


def section_scaling(cfg) -> dict:
    model = get("kwok")
    base = dict(C=36, N=50, T=2000)
    G = cfg.scaling_generations
    out: dict = {"base": base, "generations": G, "mode": "full", "points": {}}
    for dn, dt in cfg.scaling_dtypes.items():
        for axis, values in cfg.sweeps.items():
            out["points"][f"{axis} {dn}"] = _sweep(model, base, axis, values, G, dn, dt)
    _plot_scaling(out, cfg.out / "scaling.png")
    return out


def _plot_scaling(res, path):
    axes_names = list(dict.fromkeys(v["axis"] for v in res["points"].values()))
    label = {"C": "conditions C", "N": "particles N", "T": "samples T"}
    fig, axes = plt.subplots(1, len(axes_names), figsize=(4.6 * len(axes_names), 3.8))
    for ax, a in zip(np.atleast_1d(axes), axes_names):
        for v in res["points"].values():
            if v["axis"] != a:
                continue
            xs = [p["value"] for p in v["points"]]
            ys = [p["per_gen_s"] for p in v["points"]]
            ax.loglog(
                xs,
                ys,
                "o-",
                label=f"{v['dtype']}: slope {v['slope']:.2f} "
                f"(upper half {v['slope_upper_half']:.2f})",
            )
        ax.set_xlabel(label[a])
        ax.set_ylabel("time per generation [s]")
        others = ", ".join(f"{k}={val}" for k, val in res["base"].items() if k != a)
        ax.set_title(f"tanh, full swarm ({others})", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
