"""Section 2, `ode`: Bouc-Wen and modified Bouc-Wen, one swarm generation.

mrjax's generation (host callbacks), the bare `lax.scan` fitness kernel (one call; several in
one loop) and a NumPy RK4 with the same sub-steps and interpolation.
"""

from __future__ import annotations

import numpy as np

from mrjax import models, objective
from mrjax.models import get

from . import baselines
from ._common import interleaved, log, timeit
from ._work import DTYPES, bare_kernel, ode_grid, per_generation_by_callback

N_PARTICLES = 50


def _numpy_rk4(cfg, name, model, batch, positions, kernel_values) -> tuple[dict, float]:
    """NumPy RK4 on one condition per record length (time scaled to all conditions), and its
    largest relative difference from the mrjax kernel on the same particles."""
    conds = baselines.conditions_numpy(batch)
    lengths = [c["x"].size for c in conds]
    sub = sorted({lengths.index(n) for n in set(lengths)})
    scale = sum(lengths) / sum(lengths[i] for i in sub)
    fit_np = [baselines.NUMPY_FITNESS[name](conds[i], model.substeps) for i in sub]
    P = np.asarray(positions)
    np_vals = {}

    def run_np():
        for j, i in enumerate(sub):
            np_vals[i] = fit_np[j](P[i])

    tn = timeit("numpy RK4", run_np, repeats=max(1, cfg.repeats_slow - 2), warmup=False)
    d = tn.as_dict()
    d.update(scaled_to_36_s=tn.median_s * scale, subset=sub, scale=scale)
    kv = kernel_values
    rel = [
        np.max(
            np.abs(np_vals[i][np.isfinite(kv[i])] - kv[i][np.isfinite(kv[i])])
            / kv[i][np.isfinite(kv[i])]
        )
        for i in sub
    ]
    return d, float(max(rel))


def _ratios(T, K: int) -> dict:
    ratios = {}
    for dn in DTYPES:
        g = T[f"mrjax generation {dn}"]["per_gen_s"]
        ratios[f"numpy RK4 / mrjax generation {dn}"] = T["numpy RK4"]["scaled_to_36_s"] / g
        k = T[f"kernel {dn} x{K} (in one loop)"]["median_s"] / K
        ratios[f"mrjax generation / kernel (in loop) {dn}"] = g / k
        ratios[f"mrjax generation / kernel (one call) {dn}"] = g / T[f"kernel {dn}"]["median_s"]
    return ratios


def _one_model(cfg, name: str) -> dict:
    batch = ode_grid(name)
    base = get(name)
    lo, hi = base.bounds
    model = models.resolve_model(
        base, models.box_corners(base, lo, hi), batch.xdot, batch.dt, batch.mask, swarm=True
    )
    C, D = batch.n_conditions, base.n_params
    data = objective.condition_data(batch)
    res: dict = {
        "substeps": model.substeps,
        "work": f"{C} conditions x {N_PARTICLES} particles x {batch.length} samples, "
        f"RK4 with {model.substeps} sub-steps per sample",
    }
    fns = {}
    pos = {}
    K = cfg.ode_generations
    for dn, dt in DTYPES.items():
        one, loop, pos[dn] = bare_kernel(
            objective.FullObjective(model), C, N_PARTICLES, D, lo, hi, data, dt, loops=K
        )
        fns[f"kernel {dn}"] = one
        fns[f"kernel {dn} x{K} (in one loop)"] = loop
    t = interleaved(fns, repeats=max(1, cfg.repeats - 2))
    res["timings"] = {k: v.as_dict() for k, v in t.items()}
    for dn, dt in DTYPES.items():
        res["timings"][f"mrjax generation {dn}"] = per_generation_by_callback(
            base, batch, generations=cfg.ode_generations, dtype=dt
        )
    kv = np.asarray(fns["kernel float64"]())
    res["timings"]["numpy RK4"], res["numpy_vs_mrjax_max_rel_diff"] = _numpy_rk4(
        cfg, name, model, batch, pos["float64"], kv
    )
    res["finite_fraction"] = float(np.mean(np.isfinite(kv)))
    res["ratios"] = _ratios(res["timings"], K)
    return res


def section_ode(cfg) -> dict:
    out: dict = {}
    for name in ("bouc_wen", "modified_bouc_wen"):
        log(f"ode: {name}")
        out[name] = _one_model(cfg, name)
    return out
