"""The swarm stage of a fit: a damper model on a batch of conditions, through the generic swarm.

`mrjax.pso` knows nothing about damper models; this module adapts one (its bounds, its sub-step
policy, its separable or full objective from `mrjax.objective`) and maps the swarm's best
positions back to model parameters.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._errors import InputError
from ..data import Batch
from ..models import AbstractModel, check_bounds, resolve_model
from ..objective import (
    FullObjective,
    LinearObjective,
    SeparableObjective,
    condition_data,
    log_search_flags,
)
from ..pso import AbstractObjective, PSOParams, SwarmResult, default_params, swarm

#: `page_size="auto"`: a dynamic model's swarms (and view polishes) are run this many
#: conditions at a time. A fixed width, and a multiple of the float64 vector width (4): a
#: condition's result then does not depend on how many others share the batch (the chunks of
#: `mrjax.fitting.chunk_plan` are aligned the same way).
AUTO_PAGE = 8


def auto_page_size(model: AbstractModel, n_conditions: int) -> int | None:
    """Conditions per page for the batched swarm and the view polish of `model` on
    `n_conditions` (see `mrjax.pso.swarm`'s `page_size`): `AUTO_PAGE` (8) for a dynamic model
    on at least 16 conditions, else `None` (one batch)."""
    if model.dynamic and n_conditions >= 2 * AUTO_PAGE:
        return AUTO_PAGE
    return None


class ModelSwarm(eqx.Module):
    """Result of :func:`fit_swarm`: the swarm outcome in model parameters.

    **Fields:** `theta` (C, P) best parameters (all of them, also in separable mode), SI units;
    `rms` (C,) [N]; `result` the underlying :class:`mrjax.pso.SwarmResult`; `mode` static.
    """

    theta: Float[Array, "C P"]
    rms: Float[Array, " C"]
    result: SwarmResult
    mode: str = eqx.field(static=True)

    @property
    def swarm(self) -> SwarmResult:
        """Deprecated alias of `result` (kept for one release)."""
        return self.result


def fit_swarm(
    model: AbstractModel,
    batch: Batch,
    *,
    key: PRNGKeyArray,
    mode: Literal["separable", "full"] = "separable",
    bounds: tuple[ArrayLike, ArrayLike] | None = None,
    mask: ArrayLike | None = None,
    params: PSOParams | None = None,
    n_particles: int = 50,
    max_generations: int = 200,
    callback: Callable | None = None,
    dtype: Any = None,
    page_size: int | Literal["auto"] | None = "auto",
) -> ModelSwarm:
    """Identify `model` on every condition of `batch` with the batched swarm.

    **Arguments:**

    - `model`: an `AbstractModel` (see `mrjax.models.get`).
    - `batch`: the conditions (`mrjax.data.Batch`).
    - `key`: PRNG key, or (C,) keys, one per condition (see `mrjax.pso.swarm`).
    - `mode`: `"separable"` (variable projection over the nonlinear parameters; default) or
        `"full"` (the paper's swarm over every parameter).
    - `bounds`: `(lower, upper)` (P,) in SI units, default `model.bounds` (see
        `mrjax.models.check_bounds`).
    - `mask`: (C, T) samples to score, default `batch.mask` (see `objective.fit_mask`).
    - `params`, `n_particles`, `max_generations`, `callback`: see `mrjax.pso.swarm`.
    - `dtype`: float dtype of the swarm (see `mrjax.pso.swarm`), e.g. `"float32"`. The returned
        `theta` and `rms` are always recomputed in the default float (float64) from the best
        swarm positions, so only the search runs in the lower precision.
    - `page_size`: score only the conditions still running, this many at a time (see
        `mrjax.pso.swarm`). `"auto"` (default): :func:`auto_page_size` (8 conditions per page for a
        dynamic model on 16 or more conditions, whose generations are costly and whose swarms
        stop at very different generations; otherwise `None`, every condition every
        generation).

    ODE models integrate with the swarm's policy of `mrjax.models.resolve_model` (one L-stable
    step per sample).

    **Returns:** a :class:`ModelSwarm` with the full parameter vectors and their RMS [N].
    """
    lo, hi = check_bounds(model, bounds)
    model = resolve_model(model, lo, batch.xdot, batch.dt, batch.mask, swarm=True)
    if params is None:
        params = default_params(mode)
    data = condition_data(batch, mask)
    lo_j, hi_j = jnp.asarray(lo), jnp.asarray(hi)
    if mode == "full":
        obj: AbstractObjective = FullObjective(model)
        s_lo, s_hi = lo_j, hi_j
    elif mode == "separable":
        nl = model.nonlinear_index
        logs = log_search_flags(model, lo)[nl]
        if nl.size == 0:
            # fully linear model: one exact solve, no swarm needed; run 1 generation anyway
            s_lo, s_hi = jnp.zeros((1,)), jnp.zeros((1,))
            obj = LinearObjective(model, lo_j, hi_j)
        else:
            obj = SeparableObjective(model, lo_j, hi_j, tuple(bool(v) for v in logs))
            s_lo = jnp.asarray(np.where(logs, np.log(np.where(logs, lo[nl], 1.0)), lo[nl]))
            s_hi = jnp.asarray(np.where(logs, np.log(np.where(logs, hi[nl], 1.0)), hi[nl]))
    else:
        raise InputError(f"swarm mode must be 'separable' or 'full', got {mode!r}")
    if page_size == "auto":
        page_size = auto_page_size(model, batch.n_conditions)
    res = swarm(obj, s_lo, s_hi, data, key=key, params=params, n_particles=n_particles,
                max_generations=max_generations, callback=callback, dtype=dtype,
                page_size=page_size)
    if dtype is None or jnp.dtype(dtype) == s_lo.dtype:
        theta = _to_params(obj, res.position, data)
        return ModelSwarm(theta=theta, rms=res.fitness, result=res, mode=mode)
    # low-precision swarm: parameters and RMS of its best positions in full precision
    theta, rms = _to_params_rms(obj, res.position.astype(s_lo.dtype), data)
    return ModelSwarm(theta=theta, rms=rms, result=res, mode=mode)


@eqx.filter_jit
def _to_params(obj, position, data):
    return jax.vmap(obj.to_params)(position, data)


@eqx.filter_jit
def _to_params_rms(obj, position, data):
    return jax.vmap(obj.to_params)(position, data), jax.vmap(obj)(position, data)
