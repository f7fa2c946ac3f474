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
from ._args import require_x64
from ._lm import DEFAULT_TOL, lm_solve

#: A start on a bound is moved this fraction of the box width inside before the solve.
BOUND_NUDGE = 1e-3
#: After the solve, the free parameters within this fraction of the box width of a bound are
#: set onto it (together) if that does not raise the RMS.
BOUND_SNAP = 1e-3


#: After a polish on a view of the records (`mrjax.data.swarm_view`), the polish of the full
#: records stops at this multiple of the tolerance, or after `FULL_MAX_STEPS` steps: from the
#: view's optimum the full records need only a refinement, nearly all of it in the first few
#: steps (`benchmarks/tuning.md`). Used by `mrjax.fit`; the joint laws of `mrjax.generalize`
#: use the factor (their coupled refinement has no step cap).
FULL_TOL_FACTOR = 100.0
FULL_MAX_STEPS = 4
#: The polish on the views stops at this multiple of the tolerance: the full records'
#: refinement follows, and a tighter view polish would only be undone by it. The joint laws'
#: search polish on the full records (where their views are skipped, `mrjax.generalize`)
#: stops there too.
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
        # bound): coupled unknowns have flat directions (e.g. the unloading shape q of joint
        # laws) along which an unscaled solve crawls
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
