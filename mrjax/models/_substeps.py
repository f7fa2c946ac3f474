"""The one sub-step policy of mrjax: how an ODE model integrates a record.

Every ODE model integrates its state with the one integrator (`mrjax.models.integrate`),
splitting each sample interval into `substeps` equal steps of a scheme (`"rk4"` or the L-stable
`"sdirk"`). Both are static (compile-time) properties of a model object
(`AbstractModel.substeps`, `AbstractModel.scheme`); this module decides them on the host:

- :func:`resolve_model` fixes the scheme and count of a model for parameter rows on data: a
    swarm takes one L-stable step per sample; a polish takes RK4 where the stiffest row, the
    largest scored |velocity| and the longest scored interval ask for few sub-steps
    (its stiffness estimate), else the L-stable scheme with the count found by step
    doubling (:func:`doubled_substeps`);
- :func:`box_points` gives parameter rows inside a search box where no parameters are known
    yet (a stiffness estimate at the box's corners is both the most pessimistic and, for
    signed parameters, often not finite);
- `mrjax.models.TRACED_SUBSTEPS` is used when a model with `substeps=None` is called on traced
    inputs (no estimate can be made inside `jit`).

Every caller (the swarm, the polish, the uncertainty, the generalized models, the reported RMS)
goes through :func:`resolve_model`.
"""

from __future__ import annotations

import equinox as eqx
import jax
import numpy as np
from jaxtyping import ArrayLike

from ._base import AbstractModel
from ._integrate import max_abs

#: How the L-stable scheme of a resolved model is differentiated: by the implicit-function
#: theorem on its stage equations (`mrjax.models.integrate`, `tangent`), cheaper than through
#: the Newton iterates and as good for a Levenberg-Marquardt step or a std-error.
IMPLICIT = "implicit"


def resolve_model(model: AbstractModel, rows: ArrayLike, xdot, dt,
                  mask: ArrayLike | None = None, *, swarm: bool = False) -> AbstractModel:
    """The model with its integration (scheme and sub-step count) fixed on the host.

    The policy:

    - **a swarm** (`swarm=True`): the L-stable scheme, one step per sample. A swarm's box has
        corners far stiffer than any fit; this scheme is stable and accurate there without a
        stiffness estimate (RK4 would need hundreds of sub-steps, or diverge).
    - **a polish or a reported RMS**: RK4 with the count of `choose_substeps` for the stiffest
        row (`rows`: the parameters being refined or scored) while it is at most the model's
        `rk4_limit` (RK4 and its Jacobian are cheapest there); above, the L-stable scheme with
        the count m found by step doubling (:func:`doubled_substeps`: force NRMSE between m and
        2m steps below `DOUBLING_TOL / 2.5`) and the implicit tangent (`IMPLICIT`), unless
        RK4's count is still at most `rk4_limit` x m (RK4 is then the more accurate and its
        Jacobian pass still the cheaper; each model's `rk4_limit` is that cost ratio, measured
        in the benchmarks).

    A closed-form model (Dahl) takes one exact step per sample in every case.

    **Arguments:**

    - `model`: an `AbstractModel`. Static models, and models whose `substeps` is already set,
        are returned unchanged.
    - `rows`: parameter rows (N, P) or one vector (P,), SI units: the parameters being refined
        or scored (a polish's start, the swarm's best, a fit's result); with only a search box,
        :func:`box_points`. For the step doubling, rows that match the data rows (N = C of a
        (C, T) `xdot`) are each integrated on their own record.
    - `xdot` [m/s], `dt` [s]: velocity and sample intervals of the data, (T,) or (C, T); or
        a tuple of such arrays, groups of records of different lengths (each group's records
        are integrated side by side for the step doubling, and the largest count is taken).
    - `mask`: which entries of `xdot`/`dt` are real samples (default all), e.g. `batch.mask`
        (a tuple with groups).
    - `swarm`: the swarm's policy (above).

    **Returns:** `model.with_substeps(m, scheme)`, with the L-stable scheme's `tangent`
    `IMPLICIT` (its values are the same; its Jacobian is cheaper).
    """
    if not model.dynamic or model.substeps is not None:
        return model
    if swarm:
        return model.with_substeps(1, "sdirk", IMPLICIT)
    groups = isinstance(xdot, (tuple, list))
    xdots, dts = (tuple(xdot), tuple(dt)) if groups else ((xdot,), (dt,))
    masks = tuple(mask) if groups and mask is not None else (mask,) * len(xdots)
    vmax = hmax = 0.0
    for xd, d, mk in zip(xdots, dts, masks):
        v = np.asarray(xd, float)
        h = np.broadcast_to(np.asarray(d, float), v.shape) if np.ndim(d) else np.asarray(d, float)
        if mk is not None:
            keep = np.asarray(mk, bool)
            v = np.where(keep, v, 0.0)
            h = np.where(keep, h, 0.0)
        vmax, hmax = max(vmax, max_abs(v)), max(hmax, max_abs(h))
    rows = np.atleast_2d(np.asarray(rows, float))
    n = model.resolve_substeps(rows, vmax, hmax)
    if n <= model.rk4_limit:
        return model.with_substeps(n, "rk4")
    m = max(doubled_substeps(model, rows, xd, d, mask=mk) for xd, d, mk in zip(xdots, dts, masks))
    if n <= model.rk4_limit * m:  # RK4's Jacobian pass is still the cheaper one
        return model.with_substeps(n, "rk4")
    return model.with_substeps(m, "sdirk", IMPLICIT)


@eqx.filter_jit
def _forces(model, rows, x, v, h):
    """Forces of every record (C, T) with its parameter row (C, P), compiled once per model
    integration and shape (the step doubling runs it two or three times per model)."""
    return jax.vmap(model.force)(rows, x, v, h)


#: Target force NRMSE of the step doubling of :func:`doubled_substeps` (against the exact
#: solution, with the estimate's safety factor 2.5).
DOUBLING_TOL = 1e-3


def doubled_substeps(model, rows: ArrayLike, xdot: ArrayLike, dt: ArrayLike,
                     mask: ArrayLike | None = None, *, m_max: int = 64) -> int:
    """Sub-steps of the L-stable scheme by step doubling: starting from 1, the count is doubled
    until the force NRMSE (RMS difference / max|F|) between m and 2m steps is at most
    `DOUBLING_TOL / 2.5` on the data (the difference estimates the error of m steps within a
    factor the 2.5 covers, so the true NRMSE stays below `DOUBLING_TOL`; checked against
    LSODA in the tests). Costs two or three forward integrations (no Jacobian).

    **Arguments:** `model`; `rows` (C, P) matching the records of `xdot` (C, T), or any rows
    (the first is used on every record); `xdot` [m/s], `dt` [s] (T,) or (C, T); `mask` the
    real samples (default all): only they are compared (a padded record's jump to zero
    velocity after its end would ask for more sub-steps than the record needs); `m_max`.
    """
    rows = np.atleast_2d(np.asarray(rows, float))
    v = np.atleast_2d(np.asarray(xdot, float))
    h = np.broadcast_to(np.asarray(dt, float), np.shape(xdot))
    h = np.atleast_2d(h)
    if rows.shape[0] != v.shape[0]:
        rows = np.broadcast_to(rows[:1], (v.shape[0], rows.shape[1]))
    x = np.cumsum(v * h, axis=1)  # a displacement consistent with xdot (the force's x terms
    # cancel in the difference of two integrations of the same record)
    real = np.ones(v.shape, bool) if mask is None else np.broadcast_to(
        np.atleast_2d(np.asarray(mask, bool)), v.shape)

    def force(m):
        return np.asarray(_forces(model.with_substeps(m, "sdirk"), rows, x, v, h), float)

    m, F = 1, force(1)
    while 2 * m <= m_max:
        F2 = force(2 * m)
        ok = np.isfinite(F) & np.isfinite(F2) & real
        scale = np.max(np.abs(F2[ok])) if ok.any() else 0.0
        with np.errstate(over="ignore", invalid="ignore"):  # a row near overflow: est = inf
            est = float(np.sqrt(np.mean((F[ok] - F2[ok]) ** 2)) / scale) if scale > 0 else 0.0
        if est <= DOUBLING_TOL / 2.5:
            break
        m, F = 2 * m, F2
    return m


def exact_tangent(model: AbstractModel) -> AbstractModel | None:
    """The resolved `model` differentiated through its Newton iterates (`tangent="exact"`),
    where :func:`resolve_model` gave it the L-stable scheme's implicit tangent (`IMPLICIT`, an
    approximation of the derivatives: see `mrjax.models.integrate`); `None` where its
    derivatives are already exact (RK4, a closed-form or static model). The values are the
    same; the exact Jacobian costs more. `mrjax.posterior` uses it where the implicit
    tangent's gradient is off (`mrjax.bayes.sample`, `exact`)."""
    if getattr(model, "scheme", None) == "sdirk" and getattr(model, "tangent", None) == IMPLICIT:
        return model.with_substeps(model.substeps, "sdirk", "exact")
    return None


#: Points of :func:`box_points` inside the box, besides its centre.
BOX_POINTS = 15


def box_points(model: AbstractModel, lower: ArrayLike, upper: ArrayLike, *,
               n: int = BOX_POINTS) -> np.ndarray:
    """Parameter rows inside a search box, for a stiffness estimate where no parameters are
    known yet (:func:`resolve_model`'s `rows`): the box's centre and `n` points of a Halton
    sequence over its nonlinear parameters (the linear ones at their centre: they never enter
    the state equation), each taken in the middle half of the box along every axis (log-spaced
    for `log_params` with a positive box). Deterministic.

    The corners of a box with signed parameters hold parameter sets whose state diverges (a
    Bouc-Wen-type loop with beta + gamma < 0); an estimate there is not finite, and one at the
    stiffest corner asks for far more sub-steps than any fit needs.

    **Arguments:** `model`; `lower`, `upper` (P,) the box [SI units]; `n` points besides the
    centre.

    **Returns:** rows (n + 1, P), the centre first.
    """
    lo, hi = np.asarray(lower, float), np.asarray(upper, float)
    nl = model.nonlinear_index
    u = 0.25 + 0.5 * _halton(n, max(nl.size, 1))  # the middle half of every axis
    rows = np.repeat((0.5 * (lo + hi))[None], n + 1, axis=0)
    for j, i in enumerate(nl):
        if model.param_names[i] in model.log_params and lo[i] > 0:
            rows[0, i] = np.sqrt(lo[i] * hi[i])
            rows[1:, i] = np.exp(np.log(lo[i]) + u[:, j] * (np.log(hi[i]) - np.log(lo[i])))
        else:
            rows[1:, i] = lo[i] + u[:, j] * (hi[i] - lo[i])
    return rows


def _halton(n: int, d: int) -> np.ndarray:
    """The first `n` points (n, d) of the Halton sequence in [0, 1)^d (prime bases 2, 3, 5...,
    point 0 skipped)."""
    primes, k = [], 2
    while len(primes) < d:
        if all(k % p for p in primes):
            primes.append(k)
        k += 1
    out = np.zeros((n, d))
    for j, b in enumerate(primes):
        for i in range(n):
            f, r, q = 1.0, 0.0, i + 1
            while q:
                f /= b
                r += f * (q % b)
                q //= b
            out[i, j] = r
    return out
