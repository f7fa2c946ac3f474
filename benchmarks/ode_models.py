"""Section 2, `ode`: Bouc-Wen and modified Bouc-Wen, one swarm generation.

mrjax's generation (host callbacks: the swarm integrates with the L-stable SDIRK2 scheme, one
step per sample), the bare `lax.scan` fitness kernel on the same work (one call; several in one
loop), the same kernel with the earlier swarm policy (RK4 with the sub-steps its stability
needs on the box, capped at 8) and a NumPy RK4 with those sub-steps, the way a user writes it.
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
    """NumPy RK4 with `model.substeps` sub-steps on one condition per record length (time
    scaled to all conditions), and its largest relative difference from `kernel_values` (the
    mrjax kernel of the same RK4 model on the same particles)."""
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
    ratios["kernel RK4 (earlier policy) / kernel SDIRK float64"] = (
        T["kernel RK4 float64"]["median_s"] / T["kernel float64"]["median_s"]
    )
    return ratios


def _one_model(cfg, name: str) -> dict:
    batch = ode_grid(name)
    base = get(name)
    lo, hi = base.bounds
    model = models.resolve_model(
        base, models.box_corners(base, lo, hi), batch.xdot, batch.dt, batch.mask, swarm=True
    )
    # the earlier swarm policy and the NumPy user's: RK4, sub-steps for stability on the box
    corners = models.box_corners(base, lo, hi)
    v, h = np.where(batch.mask, batch.xdot, 0.0), np.where(batch.mask, batch.dt, 0.0)
    n_rk4 = int(min(models.SWARM_MAX_SUBSTEPS, base.resolve_substeps(corners, v, h)))
    rk4 = base.with_substeps(n_rk4, "rk4")
    C, D = batch.n_conditions, base.n_params
    data = objective.condition_data(batch)
    res: dict = {
        "substeps": model.substeps,
        "scheme": model.scheme,
        "rk4_substeps": n_rk4,
        "work": f"{C} conditions x {N_PARTICLES} particles x {batch.length} samples, "
        f"{model.scheme} with {model.substeps} step(s) per sample (RK4 baseline: {n_rk4})",
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
    rk4_one, _, _ = bare_kernel(
        objective.FullObjective(rk4), C, N_PARTICLES, D, lo, hi, data, DTYPES["float64"]
    )
    fns["kernel RK4 float64"] = rk4_one
    t = interleaved(fns, repeats=max(1, cfg.repeats - 2))
    res["timings"] = {k: v.as_dict() for k, v in t.items()}
    for dn, dt in DTYPES.items():
        res["timings"][f"mrjax generation {dn}"] = per_generation_by_callback(
            base, batch, generations=cfg.ode_generations, dtype=dt
        )
    kv = np.asarray(fns["kernel float64"]())
    kv_rk4 = np.asarray(rk4_one())
    res["timings"]["numpy RK4"], res["numpy_vs_mrjax_max_rel_diff"] = _numpy_rk4(
        cfg, name, rk4, batch, pos["float64"], kv_rk4
    )
    both = np.isfinite(kv) & np.isfinite(kv_rk4)
    res["sdirk_vs_rk4_median_rel_diff"] = float(
        np.median(np.abs(kv[both] - kv_rk4[both]) / kv_rk4[both])
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
