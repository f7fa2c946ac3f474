"""The gradient polish: bounded Levenberg-Marquardt per condition, batched."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .._errors import InputError
from ..data import Batch, check_mask
from ..models import AbstractModel, check_bounds, resolve_model
from ..objective import ConditionResidual
from ._args import as_free, as_theta, require_x64
from ._lm import DEFAULT_TOL, lm_solve, status_name
from ._uncertainty import Uncertainty, make_uncertainty, uncertainty_core, undefined_uncertainty

#: A start on a bound is moved this fraction of the box width inside before the solve.
BOUND_NUDGE = 1e-3
#: After the solve, the free parameters within this fraction of the box width of a bound are
#: set onto it (together) if that does not raise the RMS.
BOUND_SNAP = 1e-3


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


#: After a polish on a view of the records (`mrjax.fitting.swarm_view`), the polish of the full
#: records stops at this multiple of the tolerance, or after `FULL_MAX_STEPS` steps: from the
#: view's optimum the full records need only a refinement (measured on the 30 UTFSM tests,
#: modified Bouc-Wen: it lowers the RMS by 0.02 % (median), 0.23 % at most, 95 % of that in
#: the first 4 steps). Used by `mrjax.fit`; the joint laws of `mrjax.generalize` use the
#: factor (their coupled refinement has no step cap).
FULL_TOL_FACTOR = 100.0
FULL_MAX_STEPS = 4
#: The polish on the views stops at this multiple of the tolerance: the full records' refinement
#: follows (MBW on the 30 UTFSM tests: 10 x cut the view polish from 20.2 to 16.7 s with every
#: test's NRMSE unchanged to 0.001 points). The joint laws' search polish on the full records
#: (where their views are skipped, `mrjax.generalize`) stops there too.
VIEW_TOL_FACTOR = 10.0


def _to_theta(u, lo, hi):
    return lo + (hi - lo) * 0.5 * (jnp.sin(u) + 1.0)


def _snap_to_bounds(score, theta, rms, idx, lo, hi):
    """Move every free parameter within `BOUND_SNAP` of the box width of a bound onto it, all at
    once, if that does not raise the RMS (one more evaluation). The sine map only approaches an
    active bound slowly (its derivative vanishes there), so LM stops a little short of it."""
    j = np.asarray(idx)
    tol = BOUND_SNAP * (hi[j] - lo[j])
    v = theta[j]
    target = jnp.where(v - lo[j] <= tol, lo[j], jnp.where(hi[j] - v <= tol, hi[j], v))
    cand = theta.at[j].set(target)
    rc = score(cand)
    ok = jnp.any(target != v) & jnp.isfinite(rc) & (rc <= rms)
    return jnp.where(ok, cand, theta), jnp.where(ok, rc, rms)


class BoxSolution(eqx.Module):
    """Result of :func:`solve_box`, per unit (U units, K unknowns).

    **Fields:** `z` (U, K) the solution, inside the box; `rms` (U,) [N] its RMS, never above
    `rms_start` (U,) [N], the start's; `steps` (U,) Levenberg-Marquardt steps; `status` (U,)
    the code of `mrjax.refine.status_name`; `kept` (U,) whether the start was returned (the
    solve was non-finite or worse)."""

    z: Float[Array, "U K"]
    rms: Float[Array, " U"]
    rms_start: Float[Array, " U"]
    steps: Int[Array, " U"]
    status: Int[Array, " U"]
    kept: Bool[Array, " U"]


def _rms(r, n):
    """RMS [N] of residuals `r` (zero on unscored samples) over `n` scored samples: the value of
    :func:`mrjax.objective.masked_rms` (`inf` where not finite or nothing is scored)."""
    rms = jnp.sqrt(jnp.sum(r * r) / jnp.maximum(n, 1))
    return jnp.where(jnp.isfinite(rms) & (n > 0), rms, jnp.inf)


def _solve_one(residual, free_idx, max_steps, tol, jacobian, scaled, snap, z0, lo, hi, args, n):
    """Bounded LM on one unit from `z0` (already inside [lo, hi]); `free_idx` the unknowns
    varied (static), the others held at `z0`."""
    idx = np.asarray(free_idx, int)
    lo_f, hi_f = lo[idx], hi[idx]
    half = 0.5 * (hi_f - lo_f)

    def full(z_free):
        return z0.at[idx].set(z_free)

    # Start: nudge off the bounds (where d z / d u = 0), then map to u.
    w = hi_f - lo_f
    t0 = jnp.clip(z0[idx], lo_f + BOUND_NUDGE * w, hi_f - BOUND_NUDGE * w)
    u0 = jnp.arcsin(jnp.clip((t0 - lo_f) / jnp.where(half > 0, half, 1.0) - 1.0, -1.0, 1.0))

    def fn(u, a):
        return residual(full(_to_theta(u, lo_f, hi_f)), a)

    scale = None
    if scaled:
        # each variable scaled by the residuals' sensitivity to moving it across its box (the
        # Jacobian's columns at the start, without the sine map's cos u, which vanishes on a
        # bound): coupled unknowns have flat directions (e.g. the unloading shape q of the
        # UTFSM joint laws) along which the unscaled solve crawled for 100 steps
        J0 = jax.jacfwd(fn)(u0, args)
        slope = half * jnp.cos(u0)
        scale = jnp.linalg.norm(J0, axis=0) / jnp.where(slope > 0, slope, 1.0) * half
    sol = lm_solve(fn, u0, args, max_steps=max_steps, tol=tol, jacobian=jacobian, scale=scale)
    z_lm = full(_to_theta(sol.value, lo_f, hi_f))

    def score(z):
        return _rms(residual(z, args), n)

    rms0 = score(z0)
    rms_lm = score(z_lm)
    if snap:
        z_lm, rms_lm = _snap_to_bounds(score, z_lm, rms_lm, idx, lo, hi)
    take = jnp.all(jnp.isfinite(z_lm)) & jnp.isfinite(rms_lm) & (rms_lm <= rms0)
    z = jnp.where(take, z_lm, z0)
    rms = jnp.where(take, rms_lm, rms0)
    return z, rms, rms0, sol.steps, sol.status, ~take


def _paged(fn, page: int | None, *args):
    """`jax.vmap(fn)(*args)`, or `page` units at a time (`lax.map` over pages of a padded
    batch, one compiled page): each page's solves stop when its own slowest does. `args` are
    pytrees whose leaves have a leading unit axis."""
    U = jax.tree.leaves(args)[0].shape[0]
    if page is None or page >= U:
        return jax.vmap(fn)(*args)
    n = -(-U // page)
    pad = n * page - U

    def paged(a):  # (U, ...) -> (n, page, ...), padded with copies of the last unit
        a = jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)]) if pad else a
        return a.reshape((n, page) + a.shape[1:])

    out = jax.lax.map(lambda xs: jax.vmap(fn)(*xs), jax.tree.map(paged, args))
    return jax.tree.map(lambda a: a.reshape((n * page,) + a.shape[2:])[:U], out)


@eqx.filter_jit
def _solve_core(residual, free_idx, max_steps, jacobian, scaled, snap, tol, z0, lo, hi, args, n,
                page=None):
    def one(z, a, k):
        return _solve_one(residual, free_idx, max_steps, tol, jacobian, scaled, snap, z, lo, hi,
                          a, k)

    return BoxSolution(*_paged(one, page, z0, args, n))


def solve_box(
    residual: Callable[[Array, Any], Array],
    z0: Float[ArrayLike, "U K"],
    lower: Float[ArrayLike, " K"],
    upper: Float[ArrayLike, " K"],
    args: Any,
    n: Float[ArrayLike, " U"],
    *,
    max_steps: int,
    tol: float = DEFAULT_TOL,
    free: Sequence[int] | None = None,
    jacobian: str = "forward",
    scaled: bool = False,
    snap: bool = False,
    page_size: int | None = None,
) -> BoxSolution:
    """Bounded Levenberg-Marquardt of every *unit* of a problem at once: the one polish of
    mrjax (per-condition parameters through :func:`polish`, the joint laws of
    `mrjax.generalize` with one unit), batched with `jax.vmap` (or in pages) in one compiled
    function.

    The unknowns run in the MINUIT/lmfit map $z = l + (h - l)(\\sin u + 1)/2$ of their box
    (see the package docstring); a start on a bound is moved inside by `BOUND_NUDGE`. Per unit
    the result is never worse than the start (a non-finite or worse solve returns the start,
    `kept`).

    **Arguments:**

    - `residual`: an `equinox.Module` (hashable: compiled once per residual type and shapes)
        called as `residual(z (K,), unit_args) -> r` [N], zero on unscored samples.
    - `z0`: starts (U, K), inside the box (clipped to it).
    - `lower`, `upper`: the box (K,), finite; `lower < upper` for every free unknown.
    - `args`: pytree of the units' data, leading axis U.
    - `n`: (U,) the scored samples of each unit (the RMS divides by it).
    - `max_steps`: step cap (static). `tol`: the stop of :func:`lm_solve` (a runtime value).
    - `free`: indices of the unknowns varied (static; default all); the others are held.
    - `jacobian`: `"forward"` or `"linearize"` (see :func:`lm_solve`).
    - `scaled`: scale each unknown by the residuals' sensitivity to moving it across its box at
        the start (`lm_solve(scale=)`; for coupled unknowns with flat directions).
    - `snap`: after the solve, move the unknowns within `BOUND_SNAP` of a bound onto it (all at
        once) where that does not raise the RMS.
    - `page_size`: solve this many units at a time (static; see :func:`polish`).

    **Returns:** a :class:`BoxSolution`.
    """
    require_x64()
    if int(max_steps) != max_steps or max_steps < 1:
        raise InputError(f"max_steps must be a positive integer, got {max_steps!r}")
    if not (math.isfinite(tol) and tol > 0):
        raise InputError(f"tol must be a positive number, got {tol!r}")
    if page_size is not None and (isinstance(page_size, bool) or int(page_size) != page_size
                                  or page_size < 1):
        raise InputError(f"page_size must be a positive integer or None, got {page_size!r}")
    lo, hi = np.asarray(lower, float), np.asarray(upper, float)
    z0 = np.clip(np.asarray(z0, float), lo, hi)
    U, K = z0.shape
    free_idx = tuple(range(K)) if free is None else tuple(int(i) for i in free)
    if not free_idx:
        raise InputError("no free unknowns: every unknown is held")
    return _solve_core(residual, free_idx, int(max_steps), jacobian, bool(scaled), bool(snap),
                       np.asarray(tol, float), z0, lo, hi, args, np.asarray(n),
                       None if page_size is None or int(page_size) >= U else int(page_size))


def polish(
    model: AbstractModel,
    theta0: Float[ArrayLike, "C P"],
    batch: Batch,
    *,
    mask: Bool[ArrayLike, "C T"] | None = None,
    lower: Float[ArrayLike, " P"] | None = None,
    upper: Float[ArrayLike, " P"] | None = None,
    max_steps: int = 100,
    tol: float = DEFAULT_TOL,
    free: Bool[ArrayLike, " P"] | Sequence[str] | None = None,
    uncertainty: bool = True,
    page_size: int | None = None,
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
    - `tol`: stop after a step that changes the relative residuals and the bounded variables
        by less than this (root mean square; the RMS then changes by less than a fraction
        `tol` per step; see `mrjax.refine.lm_solve`). A runtime value, no recompilation.
    - `free`: (P,) bool mask or names of the parameters to fit (default all); the others are
        held at `theta0`.
    - `uncertainty`: compute the uncertainty at the result (default); `False` skips that
        Jacobian pass (e.g. for an intermediate polish) and reports NaN std-errors.
    - `page_size`: `None` (default) solves every condition in one batch, which steps until
        its slowest condition stops. An integer K (static) solves K conditions at a time
        (one compiled page): a page stops when its own slowest condition does, so one
        condition that needs 150 steps no longer makes all the others wait; each page is
        narrower, so this pays where step counts differ a lot and each step is costly. The
        results are those of one batch up to rounding (a narrower batch vectorises
        differently: about 1e-10 relative).

    **Returns:** a :class:`Polished` with `theta`, `rms`, `rms_start`, `steps`, `status`,
    `improved`, `kept_start`, `at_bound` and `uncertainty` (`stderr`, `cov`, `corr`, `ci95`,
    `identifiable`).
    """
    C = batch.n_conditions
    lo, hi = check_bounds(model, (lower, upper))
    theta0 = np.clip(as_theta(model, theta0, C, "theta0"), lo, hi)
    m = check_mask(batch, mask)
    fr = as_free(model, free)
    fit = fr & (lo < hi)
    free_idx = tuple(int(i) for i in np.flatnonzero(fit))
    if not free_idx:
        raise InputError(
            "no free parameters: every parameter is fixed (free mask or lower == upper)"
        )
    model = resolve_model(model, theta0, batch.xdot, batch.dt, batch.mask)
    mj = jax.device_put(m)
    sol = solve_box(ConditionResidual(model), theta0, lo, hi,
                    (batch.x, batch.xdot, batch.dt, batch.force, mj), m.sum(axis=1),
                    max_steps=max_steps, tol=tol, free=free_idx, jacobian="forward", snap=True,
                    page_size=page_size)
    theta, rms, rms0, steps, code, kept = (sol.z, sol.rms, sol.rms_start, sol.steps, sol.status,
                                           sol.kept)
    unc = None
    if uncertainty:
        unc = uncertainty_core(model, free_idx, theta, batch.x, batch.xdot, batch.dt,
                               batch.force, mj)
    theta_np = np.asarray(theta)
    kept_np = np.asarray(kept)
    lm_status = tuple(status_name(c) for c in np.asarray(code))
    status = tuple("kept_start" if k else s for k, s in zip(kept_np, lm_status, strict=True))
    tol = 1e-6 * (hi - lo)
    at_bound = fit & ((theta_np - lo <= tol) | (hi - theta_np <= tol))
    rms_np, rms0_np = np.asarray(rms), np.asarray(rms0)
    return Polished(
        theta=theta, rms=rms, rms_start=rms0, steps=steps,
        improved=jnp.asarray(rms_np < rms0_np), kept_start=kept,
        at_bound=jnp.asarray(at_bound),
        uncertainty=(make_uncertainty(model, theta_np, unc, fit) if unc is not None
                     else undefined_uncertainty(model, theta_np, fit)),
        lower=jnp.asarray(lo), upper=jnp.asarray(hi),
        status=status, lm_status=lm_status, labels=tuple(batch.labels),
        param_names=tuple(model.param_names),
    )
