"""The gradient polish: bounded Levenberg-Marquardt per condition, batched, with uncertainty.

:func:`polish` refines a start (typically the swarm's best) on every condition of a
:class:`mrjax.data.Batch` at once: the residual function is written for *one* condition,
:func:`mrjax.objective.residuals`, and `jax.vmap` batches `optimistix.least_squares` with
`optimistix.LevenbergMarquardt` over conditions inside one `eqx.filter_jit` compiled function.
:func:`uncertainty` then linearises the model at the optimum for standard errors, covariances,
correlations, 95 % intervals and an identifiability flag.

**Bounds.** optimistix has no bounds, so the polish runs in the unbounded MINUIT/lmfit
reparameterisation

$$ \\theta_j = l_j + (h_j - l_j)\\,\\frac{\\sin u_j + 1}{2}, $$

which keeps every iterate inside $[l_j, h_j]$ and makes each variable $u_j$ dimensionless and
O(1) (the box maps to $[-\\pi/2, \\pi/2]$) whatever the unit and magnitude of $\\theta_j$:
mrjax's parameters span 1e-1 to 1e4, and optimistix's Levenberg-Marquardt damps every variable
alike ($\\lambda I$) and tests convergence per variable. (Scaling $u$ further by the start's
Jacobian column norms, Marquardt/MINPACK style, was tried and took as many or more steps on the
tanh, Bouc-Wen, Dahl and Spencer models, so it is not done.) At a bound
$\\partial\\theta/\\partial u = 0$, so a start on a bound is moved inside by `BOUND_NUDGE`
(1e-3) of the box width before the solve; the start itself is still what `rms_start` scores
and what is returned if the solve does not improve on it. A result can approach a bound but
the linearised uncertainty there is only that of the unconstrained problem (see `at_bound`).
Parameters with $l_j = h_j$, or not in `free`, are held at their start and are not variables
of the solve.

**Never worse.** Per condition, the LM result is returned only if it is finite and its RMS is
no larger than the start's; otherwise the start is returned with status `"kept_start"`.

Everything runs in float64 (mrjax enables `jax_enable_x64` on import).
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ._errors import InputError
from .data._condition import Batch
from .models._base import AbstractModel
from .objective import check_mask, fitness, residuals
from .pso import resolve_model

#: Relative eigenvalue cutoff of the column-scaled $J^T J$ (unit diagonal) below which a
#: direction counts as numerically null (condition number of the scaled Jacobian > 1e5).
EIG_RTOL = 1e-10
#: A parameter whose squared loading on the null directions (sum over them of its squared
#: eigenvector components, in the column-scaled space) exceeds this is not identifiable: any
#: real component makes its variance infinite; 1e-6 only ignores eigenvector round-off.
NULL_LOADING = 1e-6
#: A parameter with a correlation above this in magnitude with another is not identifiable.
CORR_LIMIT = 0.9999
#: A start on a bound is moved this fraction of the box width inside before the solve.
BOUND_NUDGE = 1e-3
#: After the solve, a free parameter within this fraction of the box width of a bound is set
#: onto the bound if that does not raise the RMS.
BOUND_SNAP = 1e-3
#: Linear solver of the damped Gauss-Newton step: the P x P damped normal equations
#: $(J^T J + \lambda I)\,\delta = -J^T r$ by Cholesky. LevenbergMarquardt's default, QR of
#: the (T + P) x P system, is as robust but about 3x slower batched on CPU (JAX's batched QR
#: is slow there); $\lambda > 0$ keeps the system positive definite, float64 keeps it accurate,
#: and a failed factorisation only makes the trust region shrink.
_LINEAR_SOLVER = lx.Normal(lx.Cholesky())

_STATUS_NAMES = {
    "nonlinear_max_steps_reached": "max_steps_reached",
}


def _status_name(code: int) -> str:
    for name, item in optx.RESULTS._name_to_item.items():
        if int(item._value) == int(code):
            return _STATUS_NAMES.get(name, name)
    return f"unknown({int(code)})"


# ------------------------------------------------------------------------------ result types
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
        return _intervals(np.asarray(self.theta), np.asarray(self.stderr), np.asarray(self.dof),
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


class Polished(eqx.Module):
    """Result of :func:`polish`, per condition.

    **Fields** (C conditions, P parameters):

    - `theta`: polished parameters (C, P), SI units, inside the bounds.
    - `rms`: RMS force error of `theta` [N], (C,); never larger than `rms_start`.
    - `rms_start`: RMS of the start (clipped to the bounds) [N], (C,).
    - `steps`: Levenberg-Marquardt steps taken, accepted and rejected (C,).
    - `improved`: whether `rms < rms_start`, (C,).
    - `kept_start`: whether the start was returned because the solve was non-finite or worse.
    - `at_bound`: (C, P) whether a free parameter ended within 1e-6 of the box width of a
        bound (its `stderr` then describes the unconstrained linearisation only).
    - `status`: readable status per condition (static): `"successful"`, `"max_steps_reached"`,
        `"nonlinear_divergence"`, `"nonfinite"`, ... from optimistix, or `"kept_start"`.
    - `lm_status`: optimistix's own status per condition (static), also where the start was
        kept.
    - `uncertainty`: :class:`Uncertainty` at `theta`.
    - `lower`, `upper`: the bounds used, (P,). `labels`, `param_names`: static.
    """

    theta: Float[Array, "C P"]
    rms: Float[Array, " C"]
    rms_start: Float[Array, " C"]
    steps: Int[Array, " C"]
    improved: Bool[Array, " C"]
    kept_start: Bool[Array, " C"]
    at_bound: Bool[Array, "C P"]
    uncertainty: Uncertainty
    lower: Float[Array, " P"]
    upper: Float[Array, " P"]
    status: tuple[str, ...] = eqx.field(static=True)
    lm_status: tuple[str, ...] = eqx.field(static=True)
    labels: tuple[str, ...] = eqx.field(static=True)
    param_names: tuple[str, ...] = eqx.field(static=True)

    @property
    def stderr(self) -> Float[Array, "C P"]:
        """Standard errors (C, P), SI units (see :class:`Uncertainty`)."""
        return self.uncertainty.stderr

    @property
    def ci95(self) -> Float[Array, "C P 2"]:
        """95 % confidence intervals (C, P, 2), SI units."""
        return self.uncertainty.ci95

    @property
    def cov(self) -> Float[Array, "C P P"]:
        """Covariances (C, P, P), SI units."""
        return self.uncertainty.cov

    @property
    def corr(self) -> Float[Array, "C P P"]:
        """Correlation matrices (C, P, P)."""
        return self.uncertainty.corr

    @property
    def identifiable(self) -> Bool[Array, "C P"]:
        """(C, P) False for parameters that are not identifiable (see :class:`Uncertainty`)."""
        return self.uncertainty.identifiable

    def summary(self) -> str:
        """Readable report: RMS before/after, steps and status per condition, then the
        parameters with standard errors."""
        rs, r0 = np.asarray(self.rms), np.asarray(self.rms_start)
        steps = np.asarray(self.steps)
        width = max([len(s) for s in self.labels] + [9])
        lines = [f"{'condition':<{width}}  {'rms_start [N]':>13}  {'rms [N]':>11}  "
                 f"{'steps':>5}  status"]
        for i, lab in enumerate(self.labels):
            lines.append(f"{lab:<{width}}  {r0[i]:>13.6g}  {rs[i]:>11.6g}  {steps[i]:>5d}  "
                         f"{self.status[i]}")
        return "\n".join(lines) + "\n\n" + self.uncertainty.summary(self.labels)

    def __repr__(self) -> str:
        C, P = self.theta.shape
        counts: dict[str, int] = {}
        for s in self.status:
            counts[s] = counts.get(s, 0) + 1
        ratio = np.asarray(self.rms) / np.asarray(self.rms_start)
        return (f"Polished(C={C}, P={P}, params={list(self.param_names)}, "
                f"median rms={np.median(np.asarray(self.rms)):.6g} N, "
                f"median rms/rms_start={np.nanmedian(ratio):.4g}, "
                f"improved={int(np.sum(np.asarray(self.improved)))}/{C}, status={counts})")


# ------------------------------------------------------------------------------ host helpers
def _require_x64():
    if not jax.config.jax_enable_x64:
        raise RuntimeError(
            "mrjax.refine needs float64: enable jax_enable_x64 (do not set MRJAX_X64=0)"
        )


def _as_theta(model: AbstractModel, theta: ArrayLike, C: int, what: str) -> np.ndarray:
    th = np.asarray(theta, dtype=float)
    P = model.n_params
    if th.ndim == 1:
        th = np.broadcast_to(th, (C, th.shape[0]))
    if th.shape != (C, P):
        raise InputError(
            f"{what} must have shape ({C}, {P}) (conditions x parameters {list(model.param_names)})"
            f" or ({P},), got {np.shape(theta)}"
        )
    if not np.all(np.isfinite(th)):
        i, j = np.argwhere(~np.isfinite(th))[0]
        raise InputError(f"{what}[{i}, {j}] ({model.param_names[j]}) is not finite: {th[i, j]}")
    return np.array(th)


def _as_free(model: AbstractModel, free) -> np.ndarray:
    P = model.n_params
    if free is None:
        return np.ones(P, bool)
    if isinstance(free, str):
        free = [free]
    items = list(np.asarray(free).tolist()) if not isinstance(free, list | tuple) else list(free)
    if items and all(isinstance(f, str) for f in items):
        unknown = [f for f in items if f not in model.param_names]
        if unknown:
            raise InputError(f"free names unknown parameters {unknown} of model {model.name!r}; "
                             f"expected some of {list(model.param_names)}")
        return np.array([n in items for n in model.param_names])
    f = np.asarray(free)
    if f.shape != (P,) or f.dtype != bool:
        raise InputError(f"free must be a ({P},) bool mask or parameter names, got {free!r}")
    return f.copy()


def _as_bounds(model: AbstractModel, lower, upper) -> tuple[np.ndarray, np.ndarray]:
    lo0, hi0 = model.bounds
    lo = lo0 if lower is None else np.asarray(lower, float)
    hi = hi0 if upper is None else np.asarray(upper, float)
    P = model.n_params
    for name, b in (("lower", lo), ("upper", hi)):
        if b.shape != (P,):
            raise InputError(f"{name} must have shape ({P},), got {b.shape}")
        if not np.all(np.isfinite(b)):
            raise InputError(f"{name} bounds must be finite, got {b.tolist()}")
    bad = np.flatnonzero(lo > hi)
    if bad.size:
        j = bad[0]
        raise InputError(f"lower > upper for {model.param_names[j]}: {lo[j]} > {hi[j]}")
    return lo.copy(), hi.copy()


def _t_quantile(dof: np.ndarray, level: float) -> np.ndarray:
    from scipy.stats import t as student_t

    dof = np.asarray(dof, float)
    q = np.full(dof.shape, np.nan)
    ok = dof > 0
    q[ok] = student_t.ppf(0.5 + 0.5 * level, dof[ok])
    return q


def _intervals(theta, stderr, dof, level) -> np.ndarray:
    if not 0.0 < level < 1.0:
        raise InputError(f"confidence level must be in (0, 1), got {level}")
    half = _t_quantile(dof, level)[:, None] * stderr
    return np.stack([theta - half, theta + half], axis=-1)


# ------------------------------------------------------------------------------ compiled cores
def _uncertainty_one(model, free_idx, theta, x, xdot, dt, force, mask):
    """Std-errors etc. for one condition; `free_idx` a static tuple of free columns."""
    P = theta.shape[0]
    idx = np.asarray(free_idx, int)
    Pf = idx.size

    def res(th_free):
        th = theta.at[idx].set(th_free)
        return residuals(model, th, x, xdot, dt, force, mask)

    r = res(theta[idx])
    J = jax.jacfwd(res)(theta[idx])  # (T, Pf), SI units
    n = jnp.sum(mask)
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

    cov = jnp.zeros((P, P)).at[jnp.ix_(idx, idx)].set(cov_f)
    corr = jnp.eye(P).at[jnp.ix_(idx, idx)].set(corr_f)
    stderr = jnp.zeros(P).at[idx].set(se_f)
    ident = jnp.ones(P, bool).at[idx].set(ident_f)
    return stderr, cov, corr, ident, dof, jnp.sqrt(s2)


@eqx.filter_jit
def _uncertainty_core(model, free_idx, theta, x, xdot, dt, force, mask):
    one = lambda th, a, b, c, d, e: _uncertainty_one(model, free_idx, th, a, b, c, d, e)
    return jax.vmap(one)(theta, x, xdot, dt, force, mask)


def _to_theta(u, lo, hi):
    return lo + (hi - lo) * 0.5 * (jnp.sin(u) + 1.0)


def _snap_to_bounds(score, theta, rms, idx, lo, hi):
    """Move each free parameter within `BOUND_SNAP` of the box width of a bound onto it, one
    at a time, where that does not raise the RMS. The sine map only approaches an active bound
    slowly (its derivative vanishes there), so LM stops a little short of it."""

    def body(k, carry):
        th, r = carry
        j = idx[k]
        tol = BOUND_SNAP * (hi[j] - lo[j])
        v = th[j]
        target = jnp.where(v - lo[j] <= tol, lo[j], jnp.where(hi[j] - v <= tol, hi[j], v))
        cand = th.at[j].set(target)
        rc = score(cand)
        ok = (target != v) & jnp.isfinite(rc) & (rc <= r)
        return jnp.where(ok, cand, th), jnp.where(ok, rc, r)

    return jax.lax.fori_loop(0, idx.shape[0], body, (theta, rms))


def _polish_one(model, free_idx, max_steps, rtol, atol, theta0, lo, hi, x, xdot, dt, force,
                mask):
    """Bounded LM on one condition from `theta0` (already inside [lo, hi])."""
    idx = np.asarray(free_idx, int)
    lo_f, hi_f = lo[idx], hi[idx]
    half = 0.5 * (hi_f - lo_f)

    def full(th_free):
        return theta0.at[idx].set(th_free)

    def res_theta(th_free):
        return residuals(model, full(th_free), x, xdot, dt, force, mask)

    # Start: nudge off the bounds (where d theta / d u = 0), then map to u.
    w = hi_f - lo_f
    t0 = jnp.clip(theta0[idx], lo_f + BOUND_NUDGE * w, hi_f - BOUND_NUDGE * w)
    u0 = jnp.arcsin(jnp.clip((t0 - lo_f) / half - 1.0, -1.0, 1.0))

    def fn(u, _):
        return res_theta(_to_theta(u, lo_f, hi_f))

    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=_LINEAR_SOLVER)
    sol = optx.least_squares(fn, solver, u0, max_steps=max_steps, throw=False)
    th_lm = full(_to_theta(sol.value, lo_f, hi_f))

    def score(th):
        return fitness(model, th, x, xdot, dt, force, mask)

    rms0 = score(theta0)
    th_lm, rms_lm = _snap_to_bounds(score, th_lm, score(th_lm), jnp.asarray(idx), lo, hi)
    take = jnp.all(jnp.isfinite(th_lm)) & jnp.isfinite(rms_lm) & (rms_lm <= rms0)
    theta = jnp.where(take, th_lm, theta0)
    rms = jnp.where(take, rms_lm, rms0)
    return theta, rms, rms0, sol.stats["num_steps"], sol.result._value, ~take


@eqx.filter_jit
def _polish_core(model, free_idx, max_steps, rtol, atol, theta0, lo, hi, x, xdot, dt, force,
                 mask):
    def one(th0, a, b, c, f, m):
        return _polish_one(model, free_idx, max_steps, rtol, atol, th0, lo, hi, a, b, c, f, m)

    theta, rms, rms0, steps, code, kept = jax.vmap(one)(theta0, x, xdot, dt, force, mask)
    unc = jax.vmap(lambda th, a, b, c, f, m: _uncertainty_one(model, free_idx, th, a, b, c, f, m))(
        theta, x, xdot, dt, force, mask)
    return (theta, rms, rms0, steps, code, kept), unc


def _make_uncertainty(model, theta, out, free) -> Uncertainty:
    stderr, cov, corr, ident, dof, sigma = (np.asarray(a) for a in out)
    theta = np.asarray(theta)
    ci = _intervals(theta, stderr, dof, 0.95)
    return Uncertainty(
        theta=jnp.asarray(theta), stderr=jnp.asarray(stderr), cov=jnp.asarray(cov),
        corr=jnp.asarray(corr), ci95=jnp.asarray(ci), identifiable=jnp.asarray(ident),
        dof=jnp.asarray(dof), sigma=jnp.asarray(sigma),
        param_names=tuple(model.param_names), free=tuple(bool(f) for f in free),
    )


# ------------------------------------------------------------------------------ public API
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
    _require_x64()
    C = batch.n_conditions
    theta = _as_theta(model, theta, C, "theta")
    m = check_mask(batch, mask)
    fr = _as_free(model, free)
    model = resolve_model(model, theta, batch)
    free_idx = tuple(int(i) for i in np.flatnonzero(fr))
    if not free_idx:
        raise InputError("no free parameters")
    out = _uncertainty_core(model, free_idx, jnp.asarray(theta), batch.x, batch.xdot, batch.dt,
                            batch.force, jnp.asarray(m))
    return _make_uncertainty(model, theta, out, fr)


def polish(
    model: AbstractModel,
    theta0: Float[ArrayLike, "C P"],
    batch: Batch,
    *,
    mask: Bool[ArrayLike, "C T"] | None = None,
    lower: Float[ArrayLike, " P"] | None = None,
    upper: Float[ArrayLike, " P"] | None = None,
    max_steps: int = 100,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    free: Bool[ArrayLike, " P"] | Sequence[str] | None = None,
) -> Polished:
    """Refine parameters on every condition with bounded Levenberg-Marquardt.

    One `optimistix.least_squares` solve per condition, on the residuals of
    :func:`mrjax.objective.residuals`, batched with `jax.vmap` in one compiled function
    (`throw=False`: a failed condition never stops the others). Bounds are enforced by the
    sine reparameterisation described in the module docstring. Per condition the result is
    never worse than the start: a non-finite solve or a larger RMS returns the start with
    status `"kept_start"`. :func:`uncertainty` is evaluated at the result.

    **Arguments:**

    - `model`: an :class:`mrjax.models.AbstractModel`. Pass ODE models with explicit
        `substeps`; if `substeps` is `None` it is resolved once on the host from the bounds
        and the starts (the stiffest row decides).
    - `theta0`: starts (C, P), or (P,) for every condition, SI units (e.g. the swarm's best).
        Clipped to the bounds; must be finite.
    - `batch`: the C conditions, a :class:`mrjax.data.Batch`.
    - `mask`: (C, T) samples to score (default `batch.mask`; always combined with it).
    - `lower`, `upper`: bounds (P,), SI units, finite (default `model.bounds`). A parameter
        with `lower == upper` is fixed.
    - `max_steps`: maximum LM steps per condition (static: a new value recompiles).
    - `rtol`, `atol`: optimistix's Cauchy termination tolerances (on the scaled variables and
        on the residuals [N]); runtime values, no recompilation.
    - `free`: (P,) bool mask or names of the parameters to fit (default all); the others are
        held at `theta0`.

    **Returns:** a :class:`Polished` with `theta`, `rms`, `rms_start`, `steps`, `status`,
    `improved`, `kept_start`, `at_bound` and `uncertainty` (`stderr`, `cov`, `corr`, `ci95`,
    `identifiable`).
    """
    _require_x64()
    if int(max_steps) != max_steps or max_steps < 1:
        raise InputError(f"max_steps must be a positive integer, got {max_steps!r}")
    if not (rtol >= 0 and atol >= 0 and rtol + atol > 0):
        raise InputError(
            f"rtol and atol must be non-negative and not both zero, got {rtol}, {atol}"
        )
    C = batch.n_conditions
    lo, hi = _as_bounds(model, lower, upper)
    theta0 = np.clip(_as_theta(model, theta0, C, "theta0"), lo, hi)
    m = check_mask(batch, mask)
    fr = _as_free(model, free)
    fit = fr & (lo < hi)
    free_idx = tuple(int(i) for i in np.flatnonzero(fit))
    if not free_idx:
        raise InputError(
            "no free parameters: every parameter is fixed (free mask or lower == upper)"
        )
    model = resolve_model(model, theta0, batch)
    (theta, rms, rms0, steps, code, kept), unc = _polish_core(
        model, free_idx, int(max_steps), jnp.asarray(rtol, float), jnp.asarray(atol, float),
        jnp.asarray(theta0), jnp.asarray(lo), jnp.asarray(hi), batch.x, batch.xdot, batch.dt,
        batch.force, jnp.asarray(m),
    )
    theta_np = np.asarray(theta)
    kept_np = np.asarray(kept)
    lm_status = tuple(_status_name(c) for c in np.asarray(code))
    status = tuple("kept_start" if k else s for k, s in zip(kept_np, lm_status, strict=True))
    tol = 1e-6 * (hi - lo)
    at_bound = fit & ((theta_np - lo <= tol) | (hi - theta_np <= tol))
    rms_np, rms0_np = np.asarray(rms), np.asarray(rms0)
    return Polished(
        theta=theta, rms=rms, rms_start=rms0, steps=steps,
        improved=jnp.asarray(rms_np < rms0_np), kept_start=kept,
        at_bound=jnp.asarray(at_bound),
        uncertainty=_make_uncertainty(model, theta_np, unc, fit),
        lower=jnp.asarray(lo), upper=jnp.asarray(hi),
        status=status, lm_status=lm_status, labels=tuple(batch.labels),
        param_names=tuple(model.param_names),
    )
