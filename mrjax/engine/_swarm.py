"""The swarm stage of the engine: the one caller of `mrjax.pso.swarm`."""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import pso
from .._errors import InputError
from ._problem import AbstractProblem, SwarmOutcome, SwarmSetup
from ._settings import Swarm


@functools.partial(jax.jit, static_argnums=1)
def _split(key, n: int):
    return jax.random.key_data(jax.random.split(key, n))


@functools.partial(jax.jit, static_argnums=1)
def _split_seed(seed, n: int):
    return jax.random.key_data(jax.random.split(jax.random.key(seed), n))


def row_keys(key: Any, n: int) -> np.ndarray:
    """`n` per-row keys as raw key data (n, 2) uint32 on the host: `jax.random.split(key, n)` of
    one key (an int seed, a typed key or a raw (2,) uint32 key), or `key` itself when it
    already holds `n` keys. Row i's key does not depend on `n` (JAX's partitionable threefry,
    the default), so a fit's streams are those the whole batch gives its rows, whatever the
    chunking; raw keys draw what the typed keys draw. One compiled program."""
    if isinstance(key, (int, np.integer)):
        return np.asarray(_split_seed(int(key), n))
    typed = isinstance(key, jax.Array) and jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key)
    single = np.ndim(key) == (0 if typed else 1)
    if single:
        return np.asarray(_split(key if typed else np.asarray(key, np.uint32), n))
    data = np.asarray(jax.random.key_data(key) if typed else key)
    if data.shape[0] != n:
        raise InputError(f"key: got {data.shape[0]} keys for {n} swarm rows (conditions x "
                         f"restarts); pass one key or one per row")
    return data

def progress_callback(enabled: bool | None, max_generations: int, desc: str = "swarm"):
    """A tqdm bar driven from inside the compiled swarm, or `(None, None)` (costs nothing).
    `enabled=None`: only on a terminal."""
    if enabled is None:
        enabled = sys.stderr.isatty()
    if not enabled:
        return None, None
    from tqdm.auto import tqdm  # imported here: only a run with a bar needs it

    bar = tqdm(total=max_generations, desc=desc, unit="gen", leave=False, file=sys.stderr)

    def cb(gen, done, best):
        g = int(np.max(gen))
        bar.n = min(g, max_generations)
        finite = best[np.isfinite(best)]
        bar.set_postfix(running=int(np.sum(~done)),
                        best=f"{np.max(finite):.3g}N" if finite.size else "-", refresh=False)
        bar.refresh()

    return cb, bar


def _callbacks(progress: bool | None, callback: Callable | None, max_generations: int):
    """The swarm's host callback (progress bar and/or the user's) and the bar to close."""
    cb, bar = progress_callback(progress, max_generations)
    if callback is None:
        return cb, bar
    prog = cb

    def both(g, d, b):
        if prog is not None:
            prog(g, d, b)
        callback(g, d, b)

    return both, bar


def best_restart(n: int, k: int, u: int, rms: np.ndarray) -> np.ndarray:
    """Row index (u,) of the best of `k` swarms per unit (copy j of unit i at row j*n + i, best
    = lowest finite RMS, the first of equals), padded to `u` rows with the last real unit's
    (as device padding copies it)."""
    r = np.asarray(rms, float)[: n * k].reshape(k, n)
    best = np.argmin(np.where(np.isfinite(r), r, np.inf), axis=0)
    rows = best * n + np.arange(n)
    return np.concatenate([rows, np.full(u - n, rows[-1])])


def swarm_result(setup: SwarmSetup, settings: Swarm, key: Any, *,
                 callback: Callable | None = None):
    """The batched swarm of `setup` with `settings` (the one call of `mrjax.pso.swarm`):
    its hyperparameters (the setup's default where `settings.params` is None; no statistical
    stop with `settings.generations`), size, cap and precision. Returns the
    `mrjax.pso.SwarmResult` of every row (arrays on the devices)."""
    params = settings.params if settings.params is not None else setup.params
    if settings.generations is not None:
        params = eqx.tree_at(lambda p: p.criterion, params, jnp.asarray(False))
    return pso.swarm(setup.objective, setup.lower, setup.upper, setup.data, key=key,
                   params=params, n_particles=settings.n_particles,
                   max_generations=settings.generation_cap, callback=callback,
                   dtype=settings.dtype, page_size=setup.page_size)


def run_swarm(problem: AbstractProblem, settings: Swarm, key: Any, *,
              progress: bool | None = False, callback: Callable | None = None
              ) -> tuple[SwarmOutcome, SwarmSetup]:
    """The batched swarm on every unit of `problem` (`settings.restarts` swarms each, one
    compiled program; the best kept), with its statistical stop (or exactly
    `settings.generations`).

    **Arguments:** `problem`; `settings` a :class:`Swarm`; `key` one PRNG key (split into one
    stream per row) or one per row; `progress` a tqdm bar (None: on a terminal); `callback`
    a host function `callback(generation, done, best)` per generation (see
    `mrjax.pso.swarm`).

    **Returns:** `(SwarmOutcome, SwarmSetup)`.
    """
    setup = problem.swarm_setup(settings)
    cb, bar = _callbacks(progress, callback, settings.generation_cap)
    try:
        res = swarm_result(setup, settings, key, callback=cb)
        jax.block_until_ready(res.fitness)
    finally:
        if bar is not None:
            bar.close()
    z, rms = problem.from_swarm(setup, res.position, res.fitness)
    rows = best_restart(problem.n_real, settings.n_restarts, problem.n_units, rms)
    out = SwarmOutcome(
        z=np.asarray(z, float)[rows], rms=np.asarray(rms, float)[rows],
        generations=np.asarray(res.generations)[rows],
        stopped_by_criterion=np.asarray(res.stopped_by_criterion)[rows],
        history=np.asarray(res.history)[rows], restarts=settings.n_restarts)
    return out, setup
