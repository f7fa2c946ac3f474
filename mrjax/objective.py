"""The one fitness of mrjax: masked RMS force error (eq 23), NaN-safe.

Every optimiser in mrjax (swarm, polish, joint generalization, benchmarks) scores parameters
through :func:`masked_rms` or :func:`residuals`, written for one parameter vector and one
condition and batched with `jax.vmap` at the call site.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from ._errors import InputError
from .data._condition import Batch
from .models._base import AbstractModel


def masked_rms(
    predicted: Float[ArrayLike, " T"],
    measured: Float[ArrayLike, " T"],
    mask: Bool[ArrayLike, " T"],
) -> Float[Array, ""]:
    """RMS error [N] over the samples where `mask` is True (eq 23).

    Non-finite predictions give `inf`, never NaN, so a diverging particle can never become a
    best. An all-False mask also gives `inf`.
    """
    predicted = jnp.asarray(predicted)
    err = jnp.where(mask, predicted - measured, 0.0)
    n = jnp.sum(mask)
    # a NaN or inf prediction on a scored sample makes the sum NaN or inf: no extra pass needed
    rms = jnp.sqrt(jnp.sum(err * err) / jnp.maximum(n, 1))
    return jnp.where(jnp.isfinite(rms) & (n > 0), rms, jnp.inf)


def rms_from_gram(
    w: Float[ArrayLike, " L"],
    G: Float[ArrayLike, "L L"],
    g: Float[ArrayLike, " L"],
    yy: Float[ArrayLike, ""],
    n: Float[ArrayLike, ""],
) -> Float[Array, ""]:
    r"""RMS [N] of the linear fit `A w` to `y` from Gram quantities, without another pass over
    the samples: $\mathrm{RSS} = y^\top y - 2 w^\top g + w^\top G w$ with $G = A^\top A$ and
    $g = A^\top y$ over the `n` scored samples. Valid for any `w` (e.g. after clipping).
    Non-finite input gives `inf`, like :func:`masked_rms`."""
    w = jnp.asarray(w)
    rss = yy - 2.0 * jnp.dot(w, g) + jnp.dot(w, G @ w)
    rms = jnp.sqrt(jnp.maximum(rss, 0.0) / jnp.maximum(n, 1))
    return jnp.where(jnp.isfinite(rms) & (n > 0), rms, jnp.inf)


def residuals(
    model: AbstractModel,
    theta: Float[ArrayLike, "*T P"],
    x: Float[ArrayLike, " T"],
    xdot: Float[ArrayLike, " T"],
    dt: Float[ArrayLike, "*T"],
    force: Float[ArrayLike, " T"],
    mask: Bool[ArrayLike, " T"],
) -> Float[Array, " T"]:
    """Masked residuals `model.force - force` [N], zero where `mask` is False."""
    pred = model.force(theta, x, xdot, dt)
    return jnp.where(mask, pred - force, 0.0)


def fitness(
    model: AbstractModel,
    theta: Float[ArrayLike, "*T P"],
    x: Float[ArrayLike, " T"],
    xdot: Float[ArrayLike, " T"],
    dt: Float[ArrayLike, "*T"],
    force: Float[ArrayLike, " T"],
    mask: Bool[ArrayLike, " T"],
) -> Float[Array, ""]:
    """RMS force error [N] of `theta` on one condition (one particle, one condition)."""
    return masked_rms(model.force(theta, x, xdot, dt), force, mask)


def nrmse(
    rms: Float[ArrayLike, " C"], force: Float[ArrayLike, "C T"], mask: Bool[ArrayLike, "C T"]
) -> np.ndarray:
    """Normalised RMS error per condition (host NumPy): `rms / max|force|` over the scored
    samples (dimensionless; multiply by 100 for %). NaN where a condition's force is all zero.

    **Arguments:** `rms` (C,) [N]; `force` (C, T) measured force [N]; `mask` (C, T) scored
    samples.
    """
    fmax = np.max(np.where(np.asarray(mask, bool), np.abs(np.asarray(force, float)), 0.0), axis=1)
    return np.asarray(rms, float) / np.where(fmax > 0, fmax, np.nan)


def check_mask(batch: Batch, mask: ArrayLike | None) -> np.ndarray:
    """Host-side scored-sample mask: `batch.mask` and a user `mask` of the batch shape (C, T).

    Raises :class:`mrjax.InputError` for a mask of the wrong shape.
    """
    base = np.asarray(batch.mask, bool)
    if mask is None:
        return base
    m = np.asarray(mask)
    if m.shape != base.shape:
        raise InputError(f"mask must have the batch shape {base.shape}, got {m.shape}")
    return m.astype(bool) & base


def fit_mask(batch: Batch, transient: float | str | None = None) -> Bool[Array, "C T"]:
    """The samples a fit scores: the batch mask, optionally without an initial transient.

    **Arguments:**

    - `batch`: the conditions.
    - `transient`: `None` (keep all), a time span [s] to drop from the start of each
        condition, or `"cycle"` to drop the first excitation cycle (needs the frequency).
    """
    mask = np.asarray(batch.mask)
    if transient is None:
        return batch.mask
    t = np.asarray(batch.t) - np.asarray(batch.t)[:, :1]
    if isinstance(transient, str):
        if transient != "cycle":
            raise InputError(f"transient must be a time in s, 'cycle' or None, got {transient!r}")
        freq = np.asarray(batch.frequency)
        if np.any(~np.isfinite(freq)) or np.any(freq <= 0):
            raise InputError("transient='cycle' needs the frequency of every condition")
        span = 1.0 / freq
    else:
        span = np.full(batch.n_conditions, float(transient))
        if not np.all(np.isfinite(span)) or np.any(span < 0):
            raise InputError(f"transient must be a non-negative time in s, got {transient!r}")
    keep = mask & (t >= span[:, None])
    short = np.flatnonzero(keep.sum(axis=1) < 3)
    if short.size:
        raise InputError(
            f"condition {batch.labels[short[0]]!r}: fewer than 3 samples remain after dropping "
            f"the transient ({transient!r})"
        )
    return jnp.asarray(keep)


def rms_per_condition(model: AbstractModel, theta: ArrayLike, batch: Batch, mask=None) -> np.ndarray:
    """Host helper: RMS [N] of parameters `theta` (C, P) on every condition of `batch`."""
    m = batch.mask if mask is None else mask
    return np.asarray(_rms_batch(model, jnp.asarray(theta), batch.x, batch.xdot, batch.dt,
                                 batch.force, jnp.asarray(m)))


@eqx.filter_jit
def _rms_batch(model, theta, x, xdot, dt, force, mask):
    # compiled once per model and shape: run eagerly, an ODE model's `lax.scan` was compiled
    # afresh on every call (its step function is a new closure each time)
    f = jax.vmap(lambda th, a, v, d, F, k: fitness(model, th, a, v, d, F, k))
    return f(theta, x, xdot, dt, force, mask)
