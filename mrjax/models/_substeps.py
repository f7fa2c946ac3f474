"""The one sub-step policy of mrjax: how many integrator steps an ODE model takes per sample.

Every ODE model integrates its state with the one integrator of `_integrate`, splitting each
sample interval into `substeps` equal steps. The count is a static (compile-time) property of a
model object (`AbstractModel.substeps`); this module decides it on the host:

- :func:`choose_substeps` maps a stiffness estimate $|\\lambda|$ [1/s] and the largest sample
    interval to a count (target $|\\lambda| h \\le$ `STEP_TARGET`, at most `MAX_SUBSTEPS`);
- :func:`resolve_model` fixes the count of a model for parameter rows on data: the stiffest
    row, the largest scored |velocity| and the longest scored interval decide, optionally
    capped (the swarm caps at `SWARM_MAX_SUBSTEPS`);
- `TRACED_SUBSTEPS` is used when a model with `substeps=None` is called on traced inputs (no
    estimate can be made inside `jit`).

Every caller (the swarm, the polish, the uncertainty, the generalized models, the reported RMS)
goes through :func:`resolve_model`.
"""

from __future__ import annotations

import math

import numpy as np
from jaxtyping import ArrayLike

#: Target of $|\\lambda| h$ per RK4 sub-step used by :func:`choose_substeps` (dimensionless).
#: RK4 is stable up to 2.78 for a real eigenvalue; with the conservative stiffness estimates of the
#: models, 1.5 keeps the force NRMSE below 1e-4 on Spencer's 1997 set at 1 and 5 kHz.
STEP_TARGET = 1.5
#: Upper limit of the automatic sub-step count.
MAX_SUBSTEPS = 256
#: Sub-steps used when `substeps=None` but the inputs are traced (inside `jit`/`vmap`), so no
#: stiffness estimate can be made. `mrjax.fit` always resolves the count on the host instead.
TRACED_SUBSTEPS = 8
#: Cap on the sub-steps the swarm uses for ODE models. The stiffest corner of a wide box can ask
#: for hundreds; particles there are integrated less accurately (they typically diverge and
#: score `inf`). The polish and every reported RMS use sub-steps resolved from the found
#: parameters instead, uncapped.
SWARM_MAX_SUBSTEPS = 8


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
                  mask: ArrayLike | None = None, *, cap: int | None = None):
    """The model with its sub-step count fixed on the host for parameters `rows` on some data.

    **Arguments:**

    - `model`: an `AbstractModel`. Static models, and models whose `substeps` is already set,
        are returned unchanged.
    - `rows`: parameter rows (N, P) or one vector (P,), SI units; the stiffest row decides
        (e.g. the box corners for a swarm, the found parameters for a polish).
    - `xdot` [m/s], `dt` [s]: velocity and sample intervals of the data, any shape.
    - `mask`: which entries of `xdot`/`dt` are real samples (default all), e.g. `batch.mask`.
    - `cap`: upper limit of the count (the swarm's `SWARM_MAX_SUBSTEPS`), or None.

    **Returns:** `model.with_substeps(n)`.
    """
    if not model.dynamic or model.substeps is not None:
        return model
    v = np.asarray(xdot, float)
    h = np.broadcast_to(np.asarray(dt, float), v.shape) if np.ndim(dt) else np.asarray(dt, float)
    if mask is not None:
        m = np.asarray(mask, bool)
        v = np.where(m, v, 0.0)
        h = np.where(m, h, 0.0)
    n = model.resolve_substeps(np.atleast_2d(np.asarray(rows, float)), v, h)
    return model.with_substeps(n if cap is None else min(n, int(cap)))
