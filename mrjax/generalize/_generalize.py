"""`generalize`: a current-dependent model from per-condition fits (two-step or joint)."""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from ..data import Batch
from ..fitting import FitResult, as_batch
from ..models import AbstractModel, resolve_model
from ..objective import check_mask
from ..pso import PSOParams
from ._joint import JointStart, Layout, joint_data, joint_laws
from ._laws import Z_SCALE_MODELS, Law, canonical_z_scale, group_currents, nodes
from ._model import GeneralizedModel, total_rms
from ._two_step import covariances, law_spec, two_step_coefficients

LawKind = Literal["poly", "exp"]
GeneralizeMethod = Literal["two-step", "joint"]
Weighting = Literal["covariance", "equal"]


def _checked(result: FitResult, batch: Batch, method: str, weighting: str):
    """The per-condition parameters (C, P) and currents (C,) after checking the inputs."""
    if not isinstance(result, FitResult):
        raise InputError(f"result must be a mrjax.FitResult, got {type(result).__name__}")
    if method not in ("two-step", "joint"):
        raise InputError(f"method must be 'two-step' or 'joint', got {method!r}")
    if weighting not in ("covariance", "equal"):
        raise InputError(f"weighting must be 'covariance' or 'equal', got {weighting!r}")
    C = batch.n_conditions
    if result.n_conditions != C:
        raise InputError(f"result has {result.n_conditions} conditions but batch has {C}")
    if tuple(result.labels) != tuple(batch.labels):
        i = next(j for j, (a, b) in enumerate(zip(result.labels, batch.labels)) if a != b)
        raise InputError(f"result and batch disagree at condition {i}: {result.labels[i]!r} vs "
                         f"{batch.labels[i]!r}")
    cur = np.asarray(batch.current, float)
    bad = np.flatnonzero(~np.isfinite(cur))
    if bad.size:
        raise InputError(f"condition {batch.labels[bad[0]]!r} has no current; generalizing needs "
                         "the current of every condition")
    theta = np.asarray(result.theta, float)
    if not np.all(np.isfinite(theta)):
        i, j = np.argwhere(~np.isfinite(theta))[0]
        raise InputError(f"condition {batch.labels[i]!r}: parameter "
                         f"{result.model.param_names[j]!r} is not finite")
    return theta, cur


def _two_step_stage(result, batch, theta, cur, degrees, laws, weighting, mask):
    """The two-step laws and everything the joint stage starts from.

    **Returns:** `(JointStart, weighting used, support, info)`."""
    model = result.model
    levels, _ = group_currents(cur)
    kinds, degs = law_spec(model, degrees, laws, levels.size)
    exp_cols = np.array([k == "exp" for k in kinds])
    for p in np.flatnonzero(exp_cols):
        neg = np.flatnonzero(theta[:, p] <= 0)
        if neg.size:
            raise InputError(f"law 'exp' of {model.param_names[p]!r} needs positive values; "
                             f"condition {batch.labels[neg[0]]!r} has {theta[neg[0], p]:g}")
    m = check_mask(batch, mask)
    used, note, cov = weighting, "", None
    if weighting == "covariance":
        if model.name in Z_SCALE_MODELS:
            note = "the z-scale of Bouc-Wen models makes the covariance singular"
        else:
            cov, note = covariances(result, theta, exp_cols)
        if cov is None:
            used = "equal"
    coef, support = two_step_coefficients(theta, cur, kinds, degs, cov, used)
    lo_i, hi_i = float(levels.min()), float(levels.max())
    layout = Layout(kinds, tuple(d + 1 for d in degs),
                    tuple(nodes(lo_i, hi_i, d + 1) for d in degs))
    data = joint_data(model, batch, m, cur)
    law_rows = np.asarray(layout.lawset(coef)(jnp.asarray(cur)))
    model_eval = resolve_model(model, np.concatenate([theta, law_rows]), batch.xdot, batch.dt,
                               batch.mask)
    rms = float(total_rms(model_eval, layout.lawset(coef), data))
    start = JointStart(theta=theta, current=cur, levels=levels, layout=layout, coef=coef, rms=rms,
                       data=data, model_eval=model_eval, exp_cols=exp_cols)
    return start, used, support, {"two_step_total_rms_N": rms, "weighting_note": note}


def generalize(
    result: FitResult,
    batch: Batch,
    *,
    method: GeneralizeMethod = "two-step",
    degrees: Mapping[str, int] | int | None = None,
    laws: Mapping[str, LawKind] | None = None,
    weighting: Weighting = "covariance",
    key: ArrayLike | None = None,
    seed: int = 0,
    n_particles: int = 50,
    max_generations: int = 100,
    pso_params: PSOParams | None = None,
    polish: bool = True,
    polish_steps: int = 100,
    mask: ArrayLike | None = None,
) -> GeneralizedModel:
    """Make a current-dependent model from per-condition fits (eq 24-29).

    **Arguments:**

    - `result`: the per-condition :class:`mrjax.FitResult` of `batch`.
    - `batch`: the conditions it was fitted on (their currents must be known).
    - `method`: `"two-step"` (group by current, average, fit the laws: the paper's) or
        `"joint"` (law coefficients fitted on all conditions at once: swarm, then polish;
        never worse than two-step on these data). See the package docstring.
    - `degrees`: parameter name -> polynomial degree (or one int for all); the others get
        :func:`default_degrees`.
    - `laws`: parameter name -> `"poly"` (default) or `"exp"` ($\\exp(a + b\\,i)$ at degree 1).
    - `weighting`: two-step averaging, `"covariance"` (default; inverse-covariance weighted,
        generalized least squares) or `"equal"` (the paper's plain means).
    - `key`, `seed`: PRNG key of the joint swarm (default `jax.random.key(seed)`).
    - `n_particles`, `max_generations`, `pso_params`: joint swarm settings.
    - `polish`, `polish_steps`: joint Levenberg-Marquardt polish and its maximum steps.
    - `mask`: (C, T) samples to score (default the batch mask; combined with it).

    **Returns:** a :class:`GeneralizedModel`.
    """
    t0 = time.perf_counter()
    batch = as_batch(batch)
    method = str(method).replace("_", "-")
    theta_raw, cur = _checked(result, batch, method, weighting)
    model = result.model
    theta = canonical_z_scale(model, theta_raw)
    start, used, support, info = _two_step_stage(result, batch, theta, cur, degrees, laws,
                                                 weighting, mask)
    timings = {"two_step": time.perf_counter() - t0}
    rng = (float(start.levels.min()), float(start.levels.max()))
    if method == "two-step":
        info["timings"] = timings
        return _make(model, start.layout, start.coef, "two-step", start.rms, rng, used, support,
                     info)
    coef, rms = joint_laws(
        model, batch, start, key=jax.random.key(int(seed)) if key is None else key,
        n_particles=n_particles, max_generations=max_generations, pso_params=pso_params,
        polish=polish, polish_steps=polish_steps, info=info, timings=timings)
    timings["total"] = time.perf_counter() - t0
    info["timings"] = timings
    return _make(model, start.layout, coef, "joint", rms, rng, used, support, info)


def _make(model: AbstractModel, layout: Layout, coef, method: str, rms: float, rng, weighting,
          support, info: dict[str, Any]) -> GeneralizedModel:
    laws = {n: Law(layout.kinds[p], np.asarray(coef)[layout.block(p)])
            for p, n in enumerate(model.param_names)}
    return GeneralizedModel(model=model, laws=laws, method=method, total_rms=rms,
                            current_range=rng, weighting=weighting, support=support, info=info)
