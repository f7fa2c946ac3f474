"""The standard work of the sections and the JAX helpers they share: the ODE-model grids, the
bare fitness kernel and per-generation timing by host callbacks."""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

import mrjax  # noqa: F401  (enables float64)
from mrjax import fitting, pso
from mrjax.data import paper_grid
from mrjax.models import get

SIGMA = 20.0  # noise of the paper grid [N]
GENERATIONS = 100
DTYPES = {"float64": None, "float32": "float32"}

#: Truths used to simulate the ODE-model grids (inside the default bounds).
ODE_TRUTH = {
    "bouc_wen": dict(
        c=1500.0, k=2000.0, alpha=600.0, f0=-30.0, delta=1500.0, beta=800.0, gamma=600.0, n=2.0
    ),
    "modified_bouc_wen": dict(
        c0=3000.0,
        k0=2000.0,
        c1=30000.0,
        k1=500.0,
        alpha=800.0,
        delta=1000.0,
        beta=600.0,
        gamma=400.0,
        n=2.0,
        f0=-40.0,
    ),
}


def ode_grid(name: str):
    """The paper grid's motions and currents simulated by ODE model `name` at `ODE_TRUTH`."""
    model = get(name)
    return paper_grid(model, params=model.params(**ODE_TRUTH[name]))


def bare_kernel(
    obj, C: int, N: int, D: int, lo, hi, data, dtype=None, seed: int = 0, loops: int = 1
):
    """The bare fitness kernel `vmap(vmap(objective))` on C x N random positions.

    Returns `(one, looped, positions)`: `one()` is one jitted call (one generation of fitness
    evaluations); `looped()` runs it `loops` times inside one `lax.fori_loop`, the way the
    swarm's `while_loop` runs it (buffers allocated once; positions nudged by 1e-12 of the box
    per iteration so that XLA cannot hoist the evaluation out of the loop).
    """
    if dtype is not None:
        obj, data = pso.cast_floats((obj, data), jnp.dtype(dtype))
    rng = np.random.default_rng(seed)
    lo, hi = np.broadcast_to(lo, (C, D)), np.broadcast_to(hi, (C, D))
    pos = lo[:, None, :] + rng.uniform(size=(C, N, D)) * (hi - lo)[:, None, :]
    pos = jnp.asarray(pos, dtype=dtype or float)
    step = jnp.asarray(1e-12 * (hi - lo)[:, None, :], dtype=pos.dtype)
    ev = jax.vmap(jax.vmap(obj, in_axes=(0, None)), in_axes=(0, 0))
    one = jax.jit(ev)

    @jax.jit
    def looped(p, d):
        def body(i, acc):
            return acc + ev(p + i.astype(p.dtype) * step, d)

        return jax.lax.fori_loop(0, loops, body, jnp.zeros((C, N), p.dtype))

    return (lambda: one(pos, data)), (lambda: looped(pos, data)), pos


def per_generation_by_callback(
    model, batch, *, generations=5, dtype=None, mode="full", n_particles=50
):
    """Wall time of each swarm generation from host callbacks (after a compiling run)."""
    stamps: list[float] = []

    def cb(gen, done, best):
        stamps.append(time.perf_counter())

    params = pso.PSOParams(criterion=False)

    def run():
        stamps.clear()
        r = fitting.fit_swarm(
            model,
            batch,
            key=jax.random.key(0),
            mode=mode,
            params=params,
            max_generations=generations,
            callback=cb,
            dtype=dtype,
            n_particles=n_particles,
        )
        return jax.block_until_ready(r.rms)

    t0 = time.perf_counter()
    run()
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    run()
    total = time.perf_counter() - t0
    d = np.diff(np.asarray(stamps))
    return {
        "first_s": first,
        "warm_total_s": total,
        "per_gen_s": float(np.median(d)),
        "per_gen_all_s": d.tolist(),
        "generations": generations,
    }
