"""The one sub-step policy of mrjax: how an ODE model integrates a record.

Every ODE model integrates its state with the one integrator of `_integrate`, splitting each
sample interval into `substeps` equal steps of a scheme (`"rk4"` or the L-stable `"sdirk"`).
Both are static (compile-time) properties of a model object (`AbstractModel.substeps`,
`AbstractModel.scheme`); this module decides them on the host:

- :func:`choose_substeps` maps a stiffness estimate $|\\lambda|$ [1/s] and the largest sample
    interval to a count (target $|\\lambda| h \\le$ `STEP_TARGET`, at most `MAX_SUBSTEPS`);
- :func:`resolve_model` fixes the scheme and count of a model for parameter rows on data: a
    swarm takes one L-stable step per sample; a polish takes RK4 where the stiffest row, the
    largest scored |velocity| and the longest scored interval ask for few sub-steps, else the
    L-stable scheme with the count found by step doubling;
- `TRACED_SUBSTEPS` is used when a model with `substeps=None` is called on traced inputs (no
    estimate can be made inside `jit`).

Every caller (the swarm, the polish, the uncertainty, the generalized models, the reported RMS)
goes through :func:`resolve_model`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import equinox as eqx
import jax
import numpy as np
from jaxtyping import ArrayLike

if TYPE_CHECKING:
    from ._base import AbstractModel

#: Target of $|\\lambda| h$ per RK4 sub-step used by :func:`choose_substeps` (dimensionless).
#: RK4 is stable up to 2.78 for a real eigenvalue; with the conservative stiffness estimates of the
#: models, 1.5 keeps the force NRMSE below 1e-4 on Spencer's 1997 set at 1 and 5 kHz.
STEP_TARGET = 1.5
#: Upper limit of the automatic sub-step count.
MAX_SUBSTEPS = 256
#: Sub-steps used when `substeps=None` but the inputs are traced (inside `jit`/`vmap`), so no
#: stiffness estimate can be made. `mrjax.fit` always resolves the count on the host instead.
TRACED_SUBSTEPS = 8
#: How the L-stable scheme of a resolved model is differentiated: by the implicit-function
#: theorem on its stage equations (`mrjax.models.integrate`, `tangent`), about 3 x cheaper
#: than through the Newton iterates and as good for a Levenberg-Marquardt step or a std-error.
IMPLICIT = "implicit"

def choose_substeps(rate_hz: float, dt_s: float, *, target: float = STEP_TARGET) -> int:
    """Number of integrator sub-steps per sample interval for a given stiffness.

    **Arguments:**

    - `rate_hz`: largest magnitude of the Jacobian eigenvalue of the state equation, $|\\lambda|$
        [1/s] (see each model's `stiffness`).
    - `dt_s`: largest sample interval [s].
    - `target`: wanted $|\\lambda| h$ per sub-step (dimensionless).

    **Returns:** an integer in `[1, MAX_SUBSTEPS]`.
    """
    if not (math.isfinite(rate_hz) and math.isfinite(dt_s)) or rate_hz <= 0 or dt_s <= 0:
        return 1
    return int(min(MAX_SUBSTEPS, max(1, math.ceil(rate_hz * dt_s / target))))


def max_abs(a: ArrayLike) -> float:
    """Host-side max |a| ignoring non-finite entries (0 for an empty array)."""
    a = np.abs(np.asarray(a, dtype=float))
    a = a[np.isfinite(a)]
    return float(a.max()) if a.size else 0.0


def resolve_model(model, rows: ArrayLike, xdot: ArrayLike, dt: ArrayLike,
                  mask: ArrayLike | None = None, *, swarm: bool = False):
    """The model with its integration (scheme and sub-step count) fixed on the host.

    The policy:

    - **a swarm** (`swarm=True`): the L-stable scheme, one step per sample. A swarm's box has
        corners far stiffer than any fit; this scheme is stable and accurate there without a
        stiffness estimate (RK4 would need hundreds of sub-steps, or diverge).
    - **a polish or a reported RMS**: RK4 with the count of `choose_substeps` for the stiffest
        row (`rows`: the parameters being refined or scored) while it is at most the model's
        `rk4_limit` (RK4 and its Jacobian are cheapest there: the UTFSM fits need 1-6);
        above, the L-stable scheme with the count m found by step doubling
        (:func:`doubled_substeps`: force NRMSE between m and 2m steps below
        `DOUBLING_TOL / 2.5`) and the implicit tangent (`IMPLICIT`), unless RK4's count is
        still at most `rk4_limit` x m (RK4 is the more accurate; one MBW Jacobian on 4,000
        samples: RK4 at 1 / 2 / 4 / 8 sub-steps 5.8 / 13 / 23 / 44 ms, the L-stable scheme at
        1 / 2 sub-steps 8.9 / 19 ms with the implicit tangent, 28 / 59 ms through its Newton
        iterates: MBW's `rk4_limit` is 2; the 30 UTFSM tests' polish stage took 19.5 s with
        8, 17.2 s with 2).

    A closed-form model (Dahl) takes one exact step per sample in every case.

    **Arguments:**

    - `model`: an `AbstractModel`. Static models, and models whose `substeps` is already set,
        are returned unchanged.
    - `rows`: parameter rows (N, P) or one vector (P,), SI units (the box corners of a swarm,
        the found parameters of a polish). For the step doubling, rows that match the data
        rows (N = C of a (C, T) `xdot`) are each integrated on their own record.
    - `xdot` [m/s], `dt` [s]: velocity and sample intervals of the data, (T,) or (C, T); or
        a tuple of such arrays, groups of records of different lengths (each group's records
        are integrated side by side for the step doubling, and the largest count is taken).
    - `mask`: which entries of `xdot`/`dt` are real samples (default all), e.g. `batch.mask`
        (a tuple with groups).
    - `swarm`: the swarm's policy (above).

    **Returns:** `model.with_substeps(m, scheme)`, with the L-stable scheme's `tangent`
    `IMPLICIT` (its values are the same; its Jacobian costs about a third).
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
    integration and shape (eagerly, the step doubling on the 30 UTFSM tests took 2.5 s warm
    instead of 0.3 s)."""
    return jax.vmap(model.force)(rows, x, v, h)


#: Target force NRMSE of the step doubling of :func:`doubled_substeps` (against the exact
#: solution, with the estimate's safety factor 2.5).
DOUBLING_TOL = 1e-3


def doubled_substeps(model, rows: ArrayLike, xdot: ArrayLike, dt: ArrayLike,
                     mask: ArrayLike | None = None, *, m_max: int = 64) -> int:
    """Sub-steps of the L-stable scheme by step doubling: starting from 1, the count is doubled
    until the force NRMSE (RMS difference / max|F|) between m and 2m steps is at most
    `DOUBLING_TOL / 2.5` on the data (measured over 135 cases, the estimate is 0.4-2.1 times
    the true error against LSODA, so the true NRMSE stays below `DOUBLING_TOL`). Costs two or
    three forward integrations (no Jacobian).

    **Arguments:** `model`; `rows` (C, P) matching the records of `xdot` (C, T), or any rows
    (the first is used on every record); `xdot` [m/s], `dt` [s] (T,) or (C, T); `mask` the
    real samples (default all): only they are compared (a padded record's jump to zero
    velocity after its end asked for 8 sub-steps where the record needs 1-2); `m_max`.
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
    same; the exact Jacobian costs about 3 x more. `mrjax.posterior` uses it where the implicit
    tangent's gradient is off (`mrjax.bayes.sample`, `exact`)."""
    if getattr(model, "scheme", None) == "sdirk" and getattr(model, "tangent", None) == IMPLICIT:
        return model.with_substeps(model.substeps, "sdirk", "exact")
    return None
