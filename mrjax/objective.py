"""The one fitness of mrjax: masked RMS force error (eq 23), NaN-safe, and the one
variable-projection solve.

Every optimiser in mrjax (swarm, polish, joint generalization, benchmarks) scores parameters
through :func:`masked_rms` or :func:`residuals`, written for one parameter vector and one
condition and batched with `jax.vmap` at the call site.

**Variable projection** (Golub & Pereyra 1973). Every model declares which parameters enter
the force linearly; given the others, the linear ones are the exact solution of a masked,
column-scaled linear least-squares problem. :func:`gram_terms` forms its Gram quantities in
one pass over the samples, :func:`solve_normal` solves it (a Schur complement on the
parameter-dependent columns), and :func:`rms_from_gram` scores the solution without another
pass. :func:`solve_linear` chains them for one particle on one condition (the separable swarm);
the joint generalization sums the same Gram terms over conditions and calls the same solve.

**Swarm objectives.** :class:`FullObjective` (the paper's: every parameter searched),
:class:`SeparableObjective` (variable projection: only the nonlinear parameters searched) and
:class:`LinearObjective` (a model with no nonlinear parameter) adapt a model to the generic
swarm of `mrjax.pso`.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from .data import Batch
from .models import AbstractModel
from .pso import AbstractObjective


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


class ConditionResidual(eqx.Module):
    """The masked residuals of `model` on one condition as a module (hashable: a solve compiled
    for it is reused for every call with the same model and shapes), the one residual of the
    per-test problem: `ConditionResidual(model)(theta (P,), (x, xdot, dt, force, mask)) ->
    (T,)` [N] (see :func:`residuals`) for the polish; with `blocks=True` the posterior's form,
    `((r (1, T), mask (1, T)),)`: one block of one record (see `mrjax.bayes.Likelihood`)."""

    model: AbstractModel
    blocks: bool = eqx.field(static=True, default=False)

    def __call__(self, theta: Float[ArrayLike, " P"], data: tuple):
        x, xdot, dt, force, mask = data
        r = residuals(self.model, theta, x, xdot, dt, force, mask)
        return ((r[None, :], mask[None, :]),) if self.blocks else r


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


def rms_per_condition(model: AbstractModel, theta: ArrayLike, batch: Batch, mask=None) -> np.ndarray:
    """Host helper: RMS [N] of parameters `theta` (C, P) on every condition of `batch`."""
    m = batch.mask if mask is None else mask
    return np.asarray(_rms_batch(model, jax.device_put(np.asarray(theta, float)), batch.x,
                                 batch.xdot, batch.dt, batch.force, m))


@eqx.filter_jit
def _rms_batch(model, theta, x, xdot, dt, force, mask):
    # compiled once per model and shape: run eagerly, an ODE model's `lax.scan` was compiled
    # afresh on every call (its step function is a new closure each time)
    f = jax.vmap(lambda th, a, v, d, F, k: masked_rms(model.force(th, a, v, d), F, k))
    return f(theta, x, xdot, dt, force, mask)


# ------------------------------------------------------------------------------ variable projection
class Gram(eqx.Module):
    r"""Gram quantities of one linear least-squares problem $\min_w \|A w - y\|$ over the scored
    samples, with the regressors split as $A = [F, Z]$: `F` (T, p) parameter-free columns,
    `Z` (T, k) columns that depend on the nonlinear parameters, and $y$ = force - b.

    **Fields:** `FF` (p, p), `ZF` (k, p), `ZZ` (k, k), `Fy` (p,), `Zy` (k,), `yy` () [N²],
    `n` () the number of scored samples.
    """

    FF: Array
    ZF: Array
    ZZ: Array
    Fy: Array
    Zy: Array
    yy: Array
    n: Array

    @property
    def G(self) -> Array:
        r"""$A^\top A$, shape (p + k, p + k)."""
        if self.ZZ.shape[0] == 0:
            return self.FF
        return jnp.block([[self.FF, self.ZF.T], [self.ZF, self.ZZ]])

    @property
    def g(self) -> Array:
        r"""$A^\top y$, shape (p + k,)."""
        return jnp.concatenate([self.Fy, self.Zy]) if self.ZZ.shape[0] else self.Fy


def gram_terms(
    F: Float[ArrayLike, "T p"],
    Z: Float[ArrayLike, "T k"],
    b: Float[ArrayLike, " T"],
    force: Float[ArrayLike, " T"],
    mask: Bool[ArrayLike, " T"],
) -> Gram:
    """Gram quantities of the linear part of one condition's force, in one pass over samples.

    **Arguments:** `F` parameter-free regressors (T, p) (`model.basis`); `Z` parameter-dependent
    regressors (T, k) and `b` (T,) [N] the force of the nonlinear parameters alone
    (`model.hysteresis`); `force` (T,) [N] measured; `mask` (T,) scored samples.

    Everything built from `F`, `force` and `mask` alone does not depend on the particle, so
    under `vmap` over particles it is computed once per condition; each particle only adds the
    dot products of its `Z` and `b` columns.

    **Returns:** a :class:`Gram` for $A = [F, Z]$ against $y$ = force - b.
    """
    F, Z, b = jnp.asarray(F), jnp.asarray(Z), jnp.asarray(b)
    m = mask[:, None]
    # Particle-free part, H = [F, force]
    H = jnp.where(m, jnp.concatenate([F, force[:, None]], axis=1), 0.0)
    p = H.shape[1] - 1
    HH = H.T @ H
    # Per particle: one pass over the samples. Z is kept as (k, T) rows: a trailing size-1 axis
    # (T, 1) makes XLA:CPU loop over it element by element (measured 5-10x slower).
    Zr = jnp.where(mask[None, :], Z.T, 0.0)
    b = jnp.where(mask, b, 0.0)
    ZH = Zr @ H  # (k, p+1)
    bH = b @ H  # (p+1,)
    return Gram(FF=HH[:p, :p], ZF=ZH[:, :p], ZZ=Zr @ Zr.T, Fy=HH[:p, p] - bH[:p],
                Zy=ZH[:, p] - Zr @ b, yy=HH[p, p] - 2.0 * bH[p] + b @ b, n=jnp.sum(mask))


def solve_normal(
    FF: Float[ArrayLike, "p p"],
    ZF: Float[ArrayLike, "k p"],
    ZZ: Float[ArrayLike, "k k"],
    Fy: Float[ArrayLike, " p"],
    Zy: Float[ArrayLike, " k"],
) -> Float[Array, " L"]:
    r"""The column-scaled normal equations $[F, Z]^\top [F, Z]\, w = [F, Z]^\top y$, solved
    by a Schur complement on the Z block.

    The F block's scaled inverse depends on the data only, so under `vmap` over particles it
    is computed once; each particle solves a k x k system (k = 0 or 1 for the built-in models,
    the number of law coefficients in the joint generalization). A ridge of 1e-12 on the
    unit-diagonal scaled systems keeps a rank-deficient problem finite.

    **Returns:** `w` (p + k,), in the units of the columns' parameters.
    """
    FF, ZF, ZZ = jnp.asarray(FF), jnp.asarray(ZF), jnp.asarray(ZZ)
    Fy, Zy = jnp.asarray(Fy), jnp.asarray(Zy)
    p, k = FF.shape[0], ZZ.shape[0]
    if k:
        dZ = jnp.sqrt(jnp.diag(ZZ))
        dZ = jnp.where(dZ > 0, dZ, 1.0)
    if p == 0:
        S = ZZ / jnp.outer(dZ, dZ) + 1e-12 * jnp.eye(k, dtype=ZZ.dtype)
        return jnp.linalg.solve(S, Zy / dZ) / dZ
    dF = jnp.sqrt(jnp.diag(FF))
    dF = jnp.where(dF > 0, dF, 1.0)
    Minv = jnp.linalg.inv(FF / jnp.outer(dF, dF) + 1e-12 * jnp.eye(p, dtype=FF.dtype))
    gF = Fy / dF
    if not k:
        return (Minv @ gF) / dF
    FZ = ZF.T / jnp.outer(dF, dZ)
    S = ZZ / jnp.outer(dZ, dZ) - FZ.T @ Minv @ FZ
    r = Zy / dZ - FZ.T @ (Minv @ gF)
    if k == 1:
        wz = jnp.where(S[0, 0] > 1e-12, r / S[0, 0], 0.0).reshape(1)
    else:
        wz = jnp.linalg.solve(S + 1e-12 * jnp.eye(k, dtype=S.dtype), r)
    return jnp.concatenate([(Minv @ (gF - FZ @ wz)) / dF, wz / dZ])


def solve_linear(
    model: AbstractModel,
    theta: Float[Array, " P"],
    data: tuple[Array, ...],
    lower: Float[Array, " P"],
    upper: Float[Array, " P"],
) -> tuple[Float[Array, " P"], Float[Array, ""]]:
    """Variable projection for one particle on one condition.

    Given the nonlinear parameters in `theta` (its linear entries are ignored), solve the
    masked, column-scaled linear least-squares problem for the linear parameters
    (:func:`gram_terms`, :func:`solve_normal`), clip them to `[lower, upper]`, and return the
    full parameter vector and its RMS [N] (:func:`rms_from_gram`, after clipping, so a
    clipped particle is scored honestly).

    **Arguments:** `model`; `theta` (P,); `data` one condition's `(x, xdot, dt, force, mask)`
    (see :func:`condition_data`); `lower`, `upper` (P,) bounds, SI units.
    """
    x, xdot, dt, force, mask = data
    Z, b = model.hysteresis(theta, x, xdot, dt)
    gr = gram_terms(model.basis(x, xdot), Z, b, force, mask)
    w = solve_normal(gr.FF, gr.ZF, gr.ZZ, gr.Fy, gr.Zy)
    li = model.linear_index
    w = jnp.clip(w, lower[li], upper[li])
    full = theta.at[li].set(w)
    return full, rms_from_gram(w, gr.G, gr.g, gr.yy, gr.n)


# ------------------------------------------------------------------------------ swarm objectives
def condition_data(batch: Batch, mask: ArrayLike | None = None) -> tuple[Array, ...]:
    """The per-condition arrays the model objectives read: `(x, xdot, dt, force, mask)`,
    each (C, T). `mask` overrides `batch.mask` (e.g. to drop a transient)."""
    m = batch.mask if mask is None else jnp.asarray(mask)
    return (batch.x, batch.xdot, batch.dt, batch.force, m)


class FullObjective(AbstractObjective):
    """The paper's objective: the swarm searches every parameter; fitness is the masked RMS."""

    model: AbstractModel

    def __call__(self, position, data):
        x, xdot, dt, force, mask = data
        return masked_rms(self.model.force(position, x, xdot, dt), force, mask)


def log_search_flags(model: AbstractModel, lower: ArrayLike) -> np.ndarray:
    """(P,) which parameters the separable swarm searches in log space: those the model lists
    in `log_params` whose lower bound is positive (a wide positive range, e.g. 1..1e4 s/m)."""
    lo = np.asarray(lower)
    names = getattr(model, "log_params", ())
    return np.array([(n in names) and bool(lo[i] > 0) for i, n in enumerate(model.param_names)])


class SeparableObjective(AbstractObjective):
    """Variable-projection objective: positions hold only the nonlinear parameters (in log
    space where `log_mask` says so); the linear ones come from :func:`solve_linear`."""

    model: AbstractModel
    lower: Float[Array, " P"]
    upper: Float[Array, " P"]
    log_mask: tuple[bool, ...] = eqx.field(static=True, default=())

    def _full(self, position):
        nl = self.model.nonlinear_index
        base = 0.5 * (self.lower + self.upper)
        logs = np.asarray(self.log_mask or (False,) * len(nl), bool)
        return base.at[nl].set(jnp.where(logs, jnp.exp(position), position))

    def __call__(self, position, data):
        return solve_linear(self.model, self._full(position), data, self.lower, self.upper)[1]

    def to_params(self, position, data):
        return solve_linear(self.model, self._full(position), data, self.lower, self.upper)[0]


class LinearObjective(AbstractObjective):
    """Separable objective of a model with no nonlinear parameter (Bingham): one exact solve,
    whatever the (dummy) position."""

    model: AbstractModel
    lower: Float[Array, " P"]
    upper: Float[Array, " P"]

    def __call__(self, position, data):
        th = 0.5 * (self.lower + self.upper)
        return solve_linear(self.model, th, data, self.lower, self.upper)[1]

    def to_params(self, position, data):
        th = 0.5 * (self.lower + self.upper)
        return solve_linear(self.model, th, data, self.lower, self.upper)[0]
