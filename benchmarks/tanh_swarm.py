"""Section 1, `tanh`: the tanh model, 100 fixed generations on the paper grid.

mrjax (full and separable swarm, float64 and float32) against the bare fitness kernel, pyswarms,
SciPy differential evolution and evosax: time, and the quality each reaches.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mrjax import fitting, objective, pso
from mrjax.data import paper_grid, paper_truth
from mrjax.models import get
from mrjax.objective import rms_per_condition

from . import baselines
from ._common import interleaved, log, timeit
from ._work import DTYPES, GENERATIONS, SIGMA, bare_kernel

N_PARTICLES = 50


def separable_objective(model):
    """The separable swarm's objective of `model` and its search box (log-scaled where the swarm
    searches a parameter's logarithm)."""
    lo, hi = model.bounds
    nl = model.nonlinear_index
    logs = objective.log_search_flags(model, lo)[nl]
    obj = objective.SeparableObjective(
        model, jnp.asarray(lo), jnp.asarray(hi), tuple(bool(v) for v in logs)
    )
    s_lo = np.where(logs, np.log(np.where(logs, lo[nl], 1.0)), lo[nl])
    s_hi = np.where(logs, np.log(np.where(logs, hi[nl], 1.0)), hi[nl])
    return obj, s_lo, s_hi


def _quality(rms, truth_rms) -> dict:
    return {
        "median_rms_over_sigma": float(np.median(rms) / SIGMA),
        "median_rms_over_truth": float(np.median(rms / truth_rms)),
    }


def _swarm(model, batch, params, mode, dtype):
    return fitting.fit_swarm(
        model,
        batch,
        key=jax.random.key(0),
        mode=mode,
        params=params,
        max_generations=GENERATIONS,
        dtype=dtype,
    )


def _time_mrjax_and_kernels(cfg, model, batch, params, data) -> dict:
    """mrjax's two swarms and the bare kernels (one call; x100 in one loop), interleaved."""
    lo, hi = model.bounds
    C, D, G = batch.n_conditions, model.n_params, GENERATIONS
    fns, notes = {}, {}
    for dn, dt in DTYPES.items():
        for mode in ("full", "separable"):
            fns[f"mrjax {mode} {dn}"] = lambda mode=mode, dt=dt: _swarm(
                model, batch, params, mode, dt
            ).rms
        k_full, k_full_loop, _ = bare_kernel(
            objective.FullObjective(model), C, N_PARTICLES, D, lo, hi, data, dt, loops=G
        )
        sobj, s_lo, s_hi = separable_objective(model)
        k_sep, k_sep_loop, _ = bare_kernel(
            sobj, C, N_PARTICLES, len(s_lo), s_lo, s_hi, data, dt, loops=G
        )
        for mode, one, loop in (("full", k_full, k_full_loop), ("separable", k_sep, k_sep_loop)):
            fns[f"kernel {mode} {dn} x{G} (in one loop)"] = loop
            fns[f"kernel {mode} {dn} (one call)"] = one
            notes[f"kernel {mode} {dn} x{G} (in one loop)"] = (
                f"{G} generations of fitness evaluations in one fori_loop: the limit"
            )
            notes[f"kernel {mode} {dn} (one call)"] = (
                "one jitted call = one generation (allocates its buffers every call)"
            )
    log("tanh: mrjax swarms and bare kernels")
    t = interleaved(fns, repeats=cfg.repeats, notes=notes)
    return {k: v.as_dict() for k, v in t.items()}


def _mrjax_quality(model, batch, params, truth_rms) -> dict:
    """The RMS each mrjax swarm reaches after 100 generations."""
    quality = {}
    for dn, dt in DTYPES.items():
        for mode in ("full", "separable"):
            r = _swarm(model, batch, params, mode, dt)
            rms = rms_per_condition(model, np.asarray(r.theta), batch)
            quality[f"mrjax {mode} {dn}"] = _quality(rms, truth_rms)
    return quality


def _pyswarms(cfg, conds, lo, hi, truth_rms):
    """pyswarms' GlobalBestPSO on the conditions one after another: (timing, quality)."""
    log("tanh: pyswarms (sequential over conditions)")
    ps_out = {}

    def run_ps():
        ps_out["cost"], ps_out["pos"] = baselines.pyswarms_fit(conds, lo, hi, iters=GENERATIONS)
        return ps_out["cost"]

    t_ps = timeit(
        "pyswarms",
        run_ps,
        repeats=max(1, cfg.repeats_slow - 1),
        note="GlobalBestPSO, 36 conditions one after another",
    )
    return t_ps.as_dict(), _quality(ps_out["cost"], truth_rms)


def _scipy_de(cfg, conds, lo, hi, truth_rms):
    """SciPy differential evolution on a subset of the conditions, time scaled to all of them
    (vectorized and per point): (timings, quality, whether `vectorized=True` is faster)."""
    C = len(conds)
    sub = list(range(0, C, C // cfg.de_conditions))[: cfg.de_conditions]
    scale = sum(c["x"].size for c in conds) / sum(conds[i]["x"].size for i in sub)
    log(f"tanh: scipy differential_evolution on {len(sub)} conditions (scaled x{scale:.2f})")
    de_out, timings = {}, {}
    for vec in (True, False):

        def run_de(vec=vec):
            de_out[vec] = baselines.de_fit(
                [conds[i] for i in sub], lo, hi, maxiter=GENERATIONS, vectorized=vec
            )
            return de_out[vec][0]

        td = timeit(
            f"scipy DE ({'vectorized' if vec else 'per-point'})", run_de, repeats=1, warmup=False
        )
        d = td.as_dict()
        d.update(
            scaled_to_36_s=td.median_s * scale,
            subset=sub,
            scale=scale,
            nfev_per_condition=int(np.median(de_out[vec][1])),
        )
        timings[td.name] = d
    quality = _quality(de_out[True][0], truth_rms[sub])
    helps = (
        timings["scipy DE (vectorized)"]["median_s"] < timings["scipy DE (per-point)"]["median_s"]
    )
    return timings, quality, helps


def _evosax(cfg, model, data, C, truth_rms):
    """evosax's PSO vmapped over the conditions: (timings, quality or None, status text)."""
    log("tanh: evosax PSO")
    lo, hi = model.bounds
    try:
        ev = {}
        for dn, dt in DTYPES.items():
            obj = objective.FullObjective(model)
            d_ = data
            lo_, hi_ = lo, hi
            if dt is not None:
                obj, d_ = pso.cast_floats((obj, data), jnp.dtype(dt))
                lo_, hi_ = lo.astype(dt), hi.astype(dt)
            run = baselines.evosax_runner(
                obj, lo_, hi_, n_particles=N_PARTICLES, generations=GENERATIONS
            )
            keys = jax.random.split(jax.random.key(0), C)
            ev[f"evosax {dn}"] = lambda run=run, keys=keys, d_=d_: run(keys, d_)
        te = interleaved(ev, repeats=cfg.repeats)
        best = np.asarray(ev["evosax float64"]())
        return {k: v.as_dict() for k, v in te.items()}, _quality(best, truth_rms), "ok"
    except Exception as e:  # record why, do not fail the suite
        status = f"failed: {type(e).__name__}: {e}"
        log(status)
        return {}, None, status


def _ratios(T) -> dict:
    G = GENERATIONS
    ps = T["pyswarms"]["median_s"]
    ratios = {}
    for dn in DTYPES:
        for mode in ("full", "separable"):
            k = f"mrjax {mode} {dn}"
            kernel = T[f"kernel {mode} {dn} x{G} (in one loop)"]
            ratios[f"pyswarms / {k}"] = ps / T[k]["median_s"]
            ratios[f"{k} / kernel x{G} {mode} {dn}"] = T[k]["median_s"] / kernel["median_s"]
            ratios[f"(fastest runs) {k} / kernel x{G} {mode} {dn}"] = (
                T[k]["min_s"] / kernel["min_s"]
            )
            ratios[f"(fastest runs) pyswarms / {k}"] = T["pyswarms"]["min_s"] / T[k]["min_s"]
    ratios["scipy DE (vectorized, scaled) / mrjax full float64"] = (
        T["scipy DE (vectorized)"]["scaled_to_36_s"] / T["mrjax full float64"]["median_s"]
    )
    for dn in DTYPES:
        if f"evosax {dn}" in T:
            ratios[f"evosax {dn} / mrjax full {dn}"] = (
                T[f"evosax {dn}"]["median_s"] / T[f"mrjax full {dn}"]["median_s"]
            )
    return ratios


def section_tanh(cfg) -> dict:
    batch = paper_grid()
    model = get("kwok")
    lo, hi = model.bounds
    params = pso.PSOParams(criterion=False)
    data = objective.condition_data(batch)
    truth_rms = rms_per_condition(model, paper_truth(batch), batch)
    out: dict = {
        "work": f"{batch.n_conditions} conditions x {N_PARTICLES} particles x {batch.length} "
        f"samples, {GENERATIONS} generations (criterion off)"
    }
    timings = out["timings"] = _time_mrjax_and_kernels(cfg, model, batch, params, data)
    quality = _mrjax_quality(model, batch, params, truth_rms)

    conds = baselines.conditions_numpy(batch)
    timings["pyswarms"], quality["pyswarms"] = _pyswarms(cfg, conds, lo, hi, truth_rms)
    de_timings, quality["scipy DE"], out["de_vectorized_helps"] = _scipy_de(
        cfg, conds, lo, hi, truth_rms
    )
    timings.update(de_timings)
    ev_timings, ev_quality, out["evosax"] = _evosax(cfg, model, data, batch.n_conditions,
                                                    truth_rms)
    timings.update(ev_timings)
    if ev_quality is not None:
        quality["evosax float64"] = ev_quality
    out["quality"] = quality
    out["ratios"] = _ratios(timings)
    return out
