"""Linearised uncertainty of least-squares parameters: std-errors, covariance, correlation,
confidence intervals and identifiability flags, batched over conditions."""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .._errors import InputError
from ..data import Batch, check_mask
from ..models import AbstractModel, resolve_model
from ..objective import residuals
from ._args import as_free, as_theta, require_x64

#: Relative eigenvalue cutoff of the column-scaled $J^T J$ (unit diagonal) below which a
#: direction counts as numerically null (condition number of the scaled Jacobian > 1e5).
EIG_RTOL = 1e-10
#: A parameter whose squared loading on the null directions (sum over them of its squared
#: eigenvector components, in the column-scaled space) exceeds this is not identifiable: any
#: real component makes its variance infinite; 1e-6 only ignores eigenvector round-off.
NULL_LOADING = 1e-6
#: A parameter with a correlation above this in magnitude with another is not identifiable.
CORR_LIMIT = 0.9999

class Uncertainty(eqx.Module):
    """Linearised uncertainty of least-squares parameters, per condition.

    With $J$ the Jacobian of the masked residuals with respect to the free parameters (in
    their SI units) and $n$ the number of scored samples, $s^2 = \\mathrm{RSS}/(n - P)$ and
    $\\mathrm{cov} = s^2 (J^T J)^{-1}$. The inverse is taken on the column-scaled
    $J^T J$ (unit diagonal) by `eigh`, dropping eigenvalues below `EIG_RTOL` times the largest.

    **Fields** (C conditions, P parameters):

    - `theta`: parameters the linearisation is taken at, (C, P), SI units.
    - `stderr`: standard errors (C, P), SI units; 0 for fixed parameters, NaN where undefined
        (non-identifiable, $n \\le P$, or non-finite residuals).
    - `cov`: covariance (C, P, P); rows/columns of fixed parameters are 0, of undefined NaN.
    - `corr`: correlation (C, P, P); fixed parameters have 0 off the diagonal and 1 on it,
        undefined ones NaN.
    - `ci95`: 95 % confidence intervals (C, P, 2) from Student's t with $n - P$ degrees of
        freedom, SI units.
    - `identifiable`: (C, P) False where a parameter loads on a numerically null direction of
        the scaled $J^T J$ (squared loading > `NULL_LOADING`, 1e-6), has a zero or non-finite
        Jacobian column, or has |corr| > `CORR_LIMIT` with another parameter. Fixed
        parameters count as identifiable.
    - `dof`: degrees of freedom $n - P_{free}$, (C,).
    - `sigma`: residual standard deviation $s$ [N], (C,).
    - `param_names`, `free`: parameter names and which were free (static).
    """

    theta: Float[Array, "C P"]
    stderr: Float[Array, "C P"]
    cov: Float[Array, "C P P"]
    corr: Float[Array, "C P P"]
    ci95: Float[Array, "C P 2"]
    identifiable: Bool[Array, "C P"]
    dof: Int[Array, " C"]
    sigma: Float[Array, " C"]
    param_names: tuple[str, ...] = eqx.field(static=True)
    free: tuple[bool, ...] = eqx.field(static=True)

    def interval(self, level: float = 0.95) -> np.ndarray:
        """Two-sided confidence intervals at `level` (e.g. 0.68), shape (C, P, 2), SI units."""
        return intervals(np.asarray(self.theta), np.asarray(self.stderr), np.asarray(self.dof),
                          level)

    def summary(self, labels: Sequence[str] | None = None) -> str:
        """A readable table: value ± stderr per parameter and condition, `*` = not identifiable."""
        th, se, ok = (np.asarray(a) for a in (self.theta, self.stderr, self.identifiable))
        labels = list(labels) if labels is not None else [str(i) for i in range(th.shape[0])]
        width = max([len(s) for s in labels] + [9])
        head = f"{'condition':<{width}}  " + "  ".join(f"{n:>23}" for n in self.param_names)
        lines = [head]
        for i, lab in enumerate(labels):
            cells = []
            for j in range(th.shape[1]):
                flag = "" if ok[i, j] else "*"
                if not self.free[j]:
                    cells.append(f"{th[i, j]:>11.5g} (fixed)    ")
                else:
                    cells.append(f"{th[i, j]:>11.5g} ±{se[i, j]:<9.3g}{flag:1}")
            lines.append(f"{lab:<{width}}  " + "  ".join(cells))
        lines.append("* not identifiable (null direction of J^T J or |corr| > "
                     f"{CORR_LIMIT:g})")
        return "\n".join(lines)

    def __repr__(self) -> str:
        C, P = self.theta.shape
        n_bad = int(np.sum(~np.asarray(self.identifiable)))
        return (f"Uncertainty(C={C}, P={P}, params={list(self.param_names)}, "
                f"non_identifiable={n_bad}, median sigma={np.nanmedian(self.sigma):.4g} N)")


def _t_quantile(dof: np.ndarray, level: float) -> np.ndarray:
    from scipy.stats import t as student_t

    dof = np.asarray(dof, float)
    q = np.full(dof.shape, np.nan)
    ok = dof > 0
    q[ok] = student_t.ppf(0.5 + 0.5 * level, dof[ok])
    return q


def intervals(theta, stderr, dof, level: float) -> np.ndarray:
    """Two-sided Student-t intervals (C, P, 2) of `theta` ± t(dof) `stderr` at `level`."""
    if not 0.0 < level < 1.0:
        raise InputError(f"confidence level must be in (0, 1), got {level}")
    half = _t_quantile(dof, level)[:, None] * stderr
    return np.stack([theta - half, theta + half], axis=-1)



def jacobian_uncertainty(
    r: Float[ArrayLike, " N"], J: Float[ArrayLike, "N Q"], n: Float[ArrayLike, ""]
) -> tuple[Array, Array, Array, Array, Array, Array]:
    """Linearised uncertainty of least-squares variables from their residuals and Jacobian.

    The one home of mrjax's covariance rule (per-condition fits and the joint laws of
    `mrjax.generalize` both use it): $s^2 = \\mathrm{RSS}/(n - Q)$,
    $\\mathrm{cov} = s^2 (J^T J)^{-1}$ on the column-scaled $J^T J$ (unit diagonal, `eigh`,
    eigenvalues below `EIG_RTOL` times the largest treated as null); a variable loading on a
    null direction (`NULL_LOADING`), with a zero or non-finite column, or with
    |corr| > `CORR_LIMIT` to another is flagged not identifiable.

    **Arguments:** `r` (N,) residuals at the optimum [N] (zero on unscored samples); `J` (N, Q)
    their Jacobian with respect to the Q variables (in the variables' units); `n` the number
    of scored samples. Jittable.

    **Returns:** `(stderr (Q,), cov (Q, Q), corr (Q, Q), identifiable (Q,), dof (), sigma ())`,
    NaN where undefined (see :class:`Uncertainty`).
    """
    r, J = jnp.asarray(r), jnp.asarray(J)
    Pf = J.shape[-1]
    dof = n - Pf
    finite = jnp.all(jnp.isfinite(r)) & jnp.all(jnp.isfinite(J))
    J = jnp.where(finite, J, 0.0)
    rss = jnp.sum(jnp.where(finite, r, 0.0) ** 2)
    s2 = jnp.where((dof > 0) & finite, rss / jnp.maximum(dof, 1), jnp.nan)

    cn = jnp.sqrt(jnp.sum(J * J, axis=0))
    live = cn > 0
    cn_safe = jnp.where(live, cn, 1.0)
    Js = J / cn_safe
    H = Js.T @ Js
    w, V = jnp.linalg.eigh(H)
    wmax = jnp.max(w)
    null = w <= EIG_RTOL * jnp.maximum(wmax, 0.0)
    w_inv = jnp.where(null, 0.0, 1.0 / jnp.where(null, 1.0, w))
    Hp = (V * w_inv) @ V.T
    cov_f = s2 * Hp / jnp.outer(cn_safe, cn_safe)
    loading = jnp.sum(jnp.where(null[None, :], V * V, 0.0), axis=1)
    undefined = (loading > NULL_LOADING) | ~live | ~finite
    bad2 = undefined[:, None] | undefined[None, :]
    cov_f = jnp.where(bad2, jnp.nan, cov_f)
    se_f = jnp.sqrt(jnp.diag(cov_f))
    corr_f = cov_f / jnp.outer(se_f, se_f)
    off = ~jnp.eye(Pf, dtype=bool)
    high = jnp.any(off & (jnp.abs(corr_f) > CORR_LIMIT), axis=1)
    ident_f = ~(undefined | high)
    return se_f, cov_f, corr_f, ident_f, dof, jnp.sqrt(s2)


def uncertainty_one(model, free_idx, theta, x, xdot, dt, force, mask):
    """Std-errors, covariance, correlation, identifiability, dof and sigma for one condition
    (jittable); `free_idx` a static tuple of the free columns of `theta` (P,)."""
    P = theta.shape[0]
    idx = np.asarray(free_idx, int)

    def res(th_free):
        th = theta.at[idx].set(th_free)
        return residuals(model, th, x, xdot, dt, force, mask)

    r = res(theta[idx])
    J = jax.jacfwd(res)(theta[idx])  # (T, Pf), SI units
    se_f, cov_f, corr_f, ident_f, dof, sigma = jacobian_uncertainty(r, J, jnp.sum(mask))

    cov = jnp.zeros((P, P)).at[jnp.ix_(idx, idx)].set(cov_f)
    corr = jnp.eye(P).at[jnp.ix_(idx, idx)].set(corr_f)
    stderr = jnp.zeros(P).at[idx].set(se_f)
    ident = jnp.ones(P, bool).at[idx].set(ident_f)
    return stderr, cov, corr, ident, dof, sigma


@eqx.filter_jit
def uncertainty_core(model, free_idx, theta, x, xdot, dt, force, mask):
    one = lambda th, a, b, c, d, e: uncertainty_one(model, free_idx, th, a, b, c, d, e)
    return jax.vmap(one)(theta, x, xdot, dt, force, mask)


def undefined_uncertainty(model: AbstractModel, theta: np.ndarray, free) -> Uncertainty:
    """An :class:`Uncertainty` at `theta` (C, P) that was not computed: NaN std-errors,
    covariances, correlations and intervals, every parameter flagged identifiable."""
    C, P = theta.shape
    nan = np.full((C, P), np.nan)
    return Uncertainty(
        theta=jnp.asarray(theta), stderr=jnp.asarray(nan), cov=jnp.full((C, P, P), np.nan),
        corr=jnp.full((C, P, P), np.nan), ci95=jnp.full((C, P, 2), np.nan),
        identifiable=jnp.ones((C, P), bool), dof=jnp.zeros(C, int), sigma=jnp.full(C, np.nan),
        param_names=tuple(model.param_names), free=tuple(bool(f) for f in free),
    )


def make_uncertainty(model, theta, out, free) -> Uncertainty:
    """An :class:`Uncertainty` from the batched outputs of :func:`uncertainty_one` (host)."""
    stderr, cov, corr, ident, dof, sigma = (np.asarray(a) for a in out)
    theta = np.asarray(theta)
    ci = intervals(theta, stderr, dof, 0.95)
    return Uncertainty(
        **jax.device_put(dict(theta=theta, stderr=stderr, cov=cov, corr=corr, ci95=ci,
                              identifiable=ident, dof=dof, sigma=sigma)),
        param_names=tuple(model.param_names), free=tuple(bool(f) for f in free),
    )


def uncertainty(
    model: AbstractModel,
    theta: Float[ArrayLike, "C P"],
    batch: Batch,
    *,
    mask: Bool[ArrayLike, "C T"] | None = None,
    free: Bool[ArrayLike, " P"] | Sequence[str] | None = None,
) -> Uncertainty:
    """Linearised standard errors, covariance, correlation, 95 % intervals and
    identifiability of least-squares parameters on every condition.

    $J = \\partial r/\\partial\\theta$ is the Jacobian (`jax.jacfwd`, in SI units) of the masked
    residuals of :func:`mrjax.objective.residuals` over the free parameters;
    $\\mathrm{cov} = s^2 (J^T J)^{-1}$ with $s^2 = \\mathrm{RSS}/(n - P)$, $n$ the scored
    samples and $P$ the free parameters. The inverse is computed stably: columns of $J$ are
    scaled to unit norm, $J^T J$ is diagonalised with `eigh`, and eigenvalues below
    `EIG_RTOL` (1e-10) times the largest are treated as null. A parameter is flagged not
    identifiable if its squared loading on the null eigenvectors exceeds `NULL_LOADING` (1e-6)
    (its `stderr` is then NaN), if its Jacobian column is zero, or if its correlation with
    another parameter exceeds `CORR_LIMIT` (0.9999) in magnitude (its `stderr` is then kept
    but is not meaningful). Valid where `theta` is a local least-squares optimum.

    **Arguments:**

    - `model`: an :class:`mrjax.models.AbstractModel`; an ODE model with `substeps=None` gets
        its sub-steps resolved on the host from `theta`.
    - `theta`: parameters (C, P) or (P,) for all conditions, SI units.
    - `batch`: the conditions, a :class:`mrjax.data.Batch`.
    - `mask`: (C, T) samples to score (default `batch.mask`; always combined with it).
    - `free`: (P,) bool mask or names of the estimated parameters (default all); the others
        count as known exactly (zero std-error) and do not use up degrees of freedom.

    **Returns:** an :class:`Uncertainty`.
    """
    require_x64()
    C = batch.n_conditions
    theta = as_theta(model, theta, C, "theta")
    m = check_mask(batch, mask)
    fr = as_free(model, free)
    model = resolve_model(model, theta, batch.xdot, batch.dt, batch.mask)
    free_idx = tuple(int(i) for i in np.flatnonzero(fr))
    if not free_idx:
        raise InputError("no free parameters")
    out = uncertainty_core(model, free_idx, np.asarray(theta, float), batch.x, batch.xdot,
                           batch.dt, batch.force, m)
    return make_uncertainty(model, theta, out, fr)
