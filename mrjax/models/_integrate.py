r"""The one integrator of mrjax: one sampled record, one `lax.scan`, two schemes, and the rule
of how many sub-steps a stiffness needs.

Every ODE model only defines its state equation (:class:`ODE`: the right-hand side
`rhs(state, x, xdot, theta) -> dstate/dt` and, optionally, its Jacobian, the box its state never
leaves, or a closed-form update); :func:`integrate` steps it over the record.

Inside each sample interval $[t_k, t_{k+1}]$ the excitation is interpolated linearly,
$x(t_k + s\,\Delta t_k) = x_k + s (x_{k+1} - x_k)$ and likewise for $\dot x$, and the interval is
split into `substeps` equal steps. Parameters may be constant, shape `(P,)`, or vary per
sample, shape `(T, P)`; a per-sample parameter is held constant over the interval that starts at
its sample.

**Schemes** (chosen by the sub-step policy, `mrjax.models.resolve_model`):

- `"rk4"`: classic explicit Runge-Kutta, 4 right-hand sides per step. Cheap and very accurate
    where the state equation is not stiff on the scale of the step, but unstable for
    $|\lambda| h \gtrsim 2.8$ (a stiff damper model at 1 kHz needs tens of steps per sample,
    and a swarm's box has far stiffer corners).
- `"sdirk"`: Alexander's (1977) 2-stage L-stable, stiffly accurate SDIRK, $g = 1 - 1/\sqrt2$,
    order 2, with 2 Newton iterations per stage and the Jacobian re-evaluated at each iterate
    (at z = 0 the Jacobian of $|z|^n$ vanishes for n > 1, so a scheme that linearises only at
    the start of an interval misses the stiff branch z is about to enter). Every iterate is
    clipped onto a box the exact solution never leaves (Bouc-Wen:
    $|z| \le (\delta/(\beta+\gamma))^{1/n}$): this removes the Newton overshoot from z = 0 and a
    2-cycle on the kinked right-hand side, without changing the solution. Its accuracy against
    LSODA is measured by `pytest -s tests/test_models.py -k lsoda` and in the benchmarks.
- A model with a closed-form update per interval (`flow`, Dahl) uses it instead of either.

Both are differentiable (forward and reverse mode agree with central finite differences in
float64; the cheaper `tangent="implicit"` of the L-stable scheme, which the sub-step policy gives
a polish, differs by the last Newton correction, see :func:`integrate`) and never raise:
parameters that make the state diverge give non-finite values, which the fitness maps to `inf`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

#: `rhs(state, x, xdot, theta) -> dstate/dt` for one instant.
RHS = Callable[[Array, Array, Array, Array], Array]
#: `linearize(state, x, xdot, theta) -> (rhs, J)` or `(rhs, J, M)`, J = d rhs / d state of
#: shape (S, S), M the matrix the Newton iterates use (default J).
LIN = Callable[[Array, Array, Array, Array], tuple[Array, ...]]
#: `box(theta) -> (lower, upper)`, each broadcastable to (S,): a region the state never leaves.
BOX = Callable[[Array], tuple[ArrayLike, ArrayLike]]
#: `flow(state, theta, (x0, v0), (x1, v1), h) -> state`: closed-form update over one step.
FLOW = Callable[[Array, Array, tuple[Array, Array], tuple[Array, Array], Array], Array]


class ODE(NamedTuple):
    """The state equation of a dynamic model, as the integrator and its callers need it.

    **Fields:**

    - `rhs(state, x, xdot, theta) -> dstate/dt` (S,) for one instant.
    - `initial(x0, v0) -> y0` (S,): the state at the first sample from its displacement [m]
        and velocity [m/s] (the models' `ode()` give it; :func:`integrate` takes `y0`).
    - `output(states, theta, x, xdot) -> (Z, b)`: the model's parameter-dependent regressors
        `Z` (..., k) and force `b` (...) [N] from states (..., S) and the parameters,
        displacement and velocity at the same samples (any leading shape; `theta` (P,) or
        (..., P)).
    - `linearize(state, x, xdot, theta) -> (rhs, J)`, J = d rhs / d state (S, S), for the
        L-stable scheme (None: forward-mode AD of `rhs`, :func:`linearize_auto`); or
        `(rhs, J, M)` with M the matrix its Newton iterates use in place of J (e.g. J with an
        unstable branch's positive entries clipped, which would make it singular): J stays
        the derivative the implicit tangent solves with.
    - `box(theta) -> (lower, upper)`, each broadcastable to (S,): a region the state never
        leaves (+-inf allowed); the L-stable scheme clips its Newton iterates onto it.
    - `flow(state, theta, (x0, v0), (x1, v1), h) -> state`: a closed-form update over one
        step; it replaces the scheme.

    Only `rhs` is needed to integrate (`ODE(rhs)`).
    """

    rhs: Callable
    initial: Callable | None = None
    output: Callable | None = None
    linearize: Callable | None = None
    box: Callable | None = None
    flow: Callable | None = None


#: The schemes of :func:`integrate`.
SCHEMES: tuple[str, ...] = ("rk4", "sdirk")
#: SDIRK2 diagonal coefficient g = 1 - 1/sqrt(2) (L-stable, order 2).
GAMMA = 1.0 - 1.0 / math.sqrt(2.0)
#: Newton iterations per SDIRK stage.
NEWTON = 2
#: Smallest determinant of the stage matrix $I - ghJ$ the implicit tangent solves with
#: (:func:`stage_solve`); below it, the guarded Newton matrix.
TANGENT_DET = 0.5
#: How :func:`integrate` differentiates the SDIRK scheme (see there).
TANGENTS: tuple[str, ...] = ("exact", "implicit")


def _check(scheme: str, tangent: str) -> None:
    if scheme not in SCHEMES:
        raise ValueError(f"scheme must be one of {SCHEMES}, got {scheme!r}")
    if tangent not in TANGENTS:
        raise ValueError(f"tangent must be one of {TANGENTS}, got {tangent!r}")


def newton_solve(J: Array, gh: Array, r: Array) -> Array:
    r"""Solve $(I - g h J)\,\delta = r$ for S = 1 or 2 in closed form, guarded.

    If J has no eigenvalue with positive real part, $\det(I - ghJ) \ge 1$. A smaller
    determinant flags a locally unstable branch (Bouc-Wen unloading with beta > gamma), where
    $I - ghJ$ can be singular inside the step; the Newton matrix then falls back to
    $I - gh\,\mathrm{diag}(\min(J_{ii}, 0))$ (determinant >= 1). The Newton matrix only affects
    convergence, never the solution of the stage equation. S > 2: a plain solve.
    """
    if J.shape[-1] == 1:
        return r / (1.0 - gh * jnp.minimum(J[0, 0], 0.0))
    return _solve(J, gh, r, 1.0 - 1e-6)


def stage_solve(J: Array, gh: Array, r: Array) -> Array:
    r"""Solve $(I - g h J)\,\delta = r$ with the stage equation's own matrix wherever its
    determinant is at least `TANGENT_DET` (S = 1 or 2), else with :func:`newton_solve`'s
    guarded one: the implicit tangent's solve (on an unstable branch the derivative is that of
    the stage's solution, not of the Newton matrix; near a singular stage matrix, where the
    solution itself turns, the guarded one keeps it finite)."""
    return _solve(J, gh, r, TANGENT_DET)


def _solve(J: Array, gh: Array, r: Array, det_min: float) -> Array:
    """`(I - gh J)^-1 r` in closed form for S <= 2, the guarded matrix where the determinant
    is below `det_min`; S > 2: a plain solve."""
    S = J.shape[-1]
    if S == 1:
        a = 1.0 - gh * J[0, 0]
        return r / jnp.where(a >= det_min, a, 1.0 - gh * jnp.minimum(J[0, 0], 0.0))
    if S == 2:
        a, b = 1.0 - gh * J[0, 0], -gh * J[0, 1]
        c, d = -gh * J[1, 0], 1.0 - gh * J[1, 1]
        det = a * d - b * c
        bad = ~(det >= det_min)  # also catches NaN
        a = jnp.where(bad, 1.0 - gh * jnp.minimum(J[0, 0], 0.0), a)
        d = jnp.where(bad, 1.0 - gh * jnp.minimum(J[1, 1], 0.0), d)
        b = jnp.where(bad, 0.0, b)
        c = jnp.where(bad, 0.0, c)
        det = jnp.where(bad, a * d, det)
        return jnp.stack([d * r[0] - b * r[1], a * r[1] - c * r[0]]) / det
    return jnp.linalg.solve(jnp.eye(S, dtype=J.dtype) - gh * J, r)


def linearize_auto(rhs: RHS) -> LIN:
    """Default `linearize`: `(rhs, J)` with J by forward-mode AD. Correct for any model; an
    analytic one is cheaper (it shares the |z|^n evaluation with the right-hand side)."""

    def lin(state, x, v, p):
        J, f = jax.jacfwd(lambda s: (rhs(s, x, v, p),) * 2, has_aux=True)(state)
        return f, J

    return lin


def _rk4_step(rhs: RHS, p, x0, dx, v0, dv, h, m: int):
    """One RK4 sub-step of an interval split into `m`; `j` the sub-step index."""
    frac = 1.0 / m

    def f(y, s):
        return rhs(y, x0 + s * dx, v0 + s * dv, p)

    def sub(j, y):
        s0 = jnp.asarray(j, h.dtype) * frac  # keeps a float32 run in float32
        k1 = f(y, s0)
        k2 = f(y + 0.5 * h * k1, s0 + 0.5 * frac)
        k3 = f(y + 0.5 * h * k2, s0 + 0.5 * frac)
        k4 = f(y + h * k3, s0 + frac)
        return y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    return sub


def _newton_lin(lin: LIN) -> Callable:
    """`lin` giving `(f, J, M)`: a model's `linearize` with its Newton matrix M (J where it
    gives none)."""

    def out(state, x, v, p):
        r = lin(state, x, v, p)
        return tuple(r) if len(r) == 3 else (r[0], r[1], r[1])

    return out


def _implicit_newton(lin: LIN) -> Callable:
    """`step(z, base, xs, vs, p, gh)`: the last Newton iterate of a stage from `z`, whose
    derivative is the implicit-function one, $(I - ghJ)^{-1}$ times the derivative of the
    stage's inputs, z held. `lin` gives `(f, J, M)` (:func:`_newton_lin`): the iterate uses
    the Newton matrix M, the derivative J itself. (With M in its place the derivative is off
    in every step of a branch where they differ, by an error that does not shrink with the
    step: Bouc-Wen's unloading branch with beta > gamma.)"""

    @jax.custom_jvp
    def step(z, base, xs, vs, p, gh):
        f, _, M = lin(z, xs, vs, p)
        return z - newton_solve(M, gh, z - base - gh * f)

    @step.defjvp
    def step_jvp(primals, tangents):
        z, base, xs, vs, p, gh = primals
        _, dbase, dxs, dvs, dp, dgh = tangents
        (f, J, M), (df, _, _) = jax.jvp(lambda a, b, q: lin(z, a, b, q), (xs, vs, p),
                                        (dxs, dvs, dp))
        out = z - newton_solve(M, gh, z - base - gh * f)
        return out, stage_solve(J, gh, dbase + dgh * f + gh * df)

    return step


def _sdirk_step(lin: LIN, proj, p, x0, dx, v0, dv, h, m: int, tangent: str = "exact"):
    """One SDIRK2 sub-step (see the module docstring; `tangent` as for :func:`integrate`)."""
    gh = GAMMA * h
    sg = jax.lax.stop_gradient
    last = _implicit_newton(lin) if tangent != "exact" else None

    def stage(base, z, s):
        xs, vs = x0 + s * dx, v0 + s * dv
        if tangent == "exact":
            for _ in range(NEWTON):
                f, _, M = lin(z, xs, vs, p)
                z = proj(z - newton_solve(M, gh, z - base - gh * f))
            return z
        # "implicit": the same iterates; only the last carries derivatives, with z held, so
        # the tangent is (I - g h J)^-1 (d base + g h d f), the implicit-function derivative
        # of the stage equation at the previous iterate
        z = sg(z)
        for _ in range(NEWTON - 1):
            f, _, M = lin(z, sg(xs), sg(vs), sg(p))
            z = proj(z - newton_solve(M, sg(gh), z - sg(base) - sg(gh) * f))
        return proj(last(z, base, xs, vs, p, gh))

    def sub(j, y):
        s0 = jnp.asarray(j, h.dtype) / m
        y1 = stage(y, y, s0 + GAMMA / m)
        base = y + ((1.0 - GAMMA) / GAMMA) * (y1 - y)  # y + (1 - g) h k1, k1 from stage 1
        return stage(base, y1, s0 + 1.0 / m)

    return sub


def _projector(box: BOX | None, p, dtype, S: int):
    """Clip onto the box the state never leaves (identity without a box)."""
    if box is None:
        return lambda z: z
    lo, hi = box(p)
    lo = jnp.broadcast_to(jnp.asarray(lo, dtype), (S,))
    hi = jnp.broadcast_to(jnp.asarray(hi, dtype), (S,))
    return lambda z: jnp.clip(z, lo, hi)


def _substep(rhs, lin, proj, flow, p, x0, x1, v0, v1, h_all, m: int, scheme: str,
             tangent: str = "exact"):
    """`sub(j, y)`: the state after sub-step `j` of `m` of one sample interval, from `y`."""
    dx, dv = x1 - x0, v1 - v0
    h = h_all / m
    if flow is not None:
        def sub(j, y):
            s0 = jnp.asarray(j, h.dtype) / m
            s1 = s0 + 1.0 / m
            return flow(y, p, (x0 + s0 * dx, v0 + s0 * dv), (x0 + s1 * dx, v0 + s1 * dv), h)
    elif scheme == "rk4":
        sub = _rk4_step(rhs, p, x0, dx, v0, dv, h, m)
    else:
        sub = _sdirk_step(lin, proj, p, x0, dx, v0, dv, h, m, tangent)
    return sub


def _interval(rhs, lin, proj, flow, y, p, x0, x1, v0, v1, h_all, m: int, scheme: str,
              tangent: str = "exact"):
    """The state after one sample interval: `m` steps of `scheme` (or of `flow`)."""
    sub = _substep(rhs, lin, proj, flow, p, x0, x1, v0, v1, h_all, m, scheme, tangent)
    if m == 1:
        return sub(0, y)
    return jax.lax.fori_loop(0, m, sub, y)


def _as_ode(ode: ODE | RHS) -> ODE:
    return ode if isinstance(ode, ODE) else ODE(ode)


def integrate_step(ode: ODE | RHS, y: Float[ArrayLike, " S"], theta: Float[ArrayLike, " P"],
                   x0: ArrayLike, x1: ArrayLike, v0: ArrayLike, v1: ArrayLike, dt: ArrayLike,
                   substeps: int, *, scheme: str = "rk4",
                   tangent: str = "exact") -> Float[Array, " S"]:
    """One sample interval of :func:`integrate`: the state at the next sample from the state
    `y` (S,) at this one, parameters `theta` (P,) held over the interval, the excitation going
    linearly from `(x0, v0)` to `(x1, v1)` [m, m/s] over `dt` [s]. The same steps as
    :func:`integrate` (arguments as there), for callers that choose the parameters of each
    interval as they go (the inverse model, a closed loop)."""
    _check(scheme, tangent)
    ode = _as_ode(ode)
    y, dt = jnp.asarray(y), jnp.asarray(dt)
    lin = _newton_lin(ode.linearize or linearize_auto(ode.rhs))
    proj = _projector(ode.box, theta, y.dtype, y.shape[0])
    return _interval(ode.rhs, lin, proj, ode.flow, y, theta, x0, x1, v0, v1, dt, int(substeps),
                     scheme, tangent)


def integrate(
    ode: ODE | RHS,
    y0: Float[ArrayLike, " S"],
    theta: Float[ArrayLike, "*T P"],
    x: Float[ArrayLike, " T"],
    xdot: Float[ArrayLike, " T"],
    dt: Float[ArrayLike, "*T"],
    substeps: int,
    *,
    scheme: str = "rk4",
    tangent: str = "exact",
) -> Float[Array, "T S"]:
    """Integrate a state equation over a sampled record.

    **Arguments:**

    - `ode`: the state equation (:class:`ODE`; its `rhs`, and `linearize`, `box`, `flow` where
        given), or its right-hand side `rhs(state, x, xdot, theta) -> d state / dt` alone.
    - `y0`: initial state at the first sample, shape `(S,)`.
    - `theta`: parameters, `(P,)` or per sample `(T, P)`.
    - `x`: displacement [m], shape `(T,)`.
    - `xdot`: velocity [m/s], shape `(T,)`.
    - `dt`: sample interval [s], a scalar or per sample `(T,)` (the interval after each sample;
        the last entry is unused).
    - `substeps`: steps per sample interval (static).
    - `scheme`: `"rk4"` or `"sdirk"` (static; see the module docstring).
    - `tangent`: how `"sdirk"` is differentiated (static; the values are the same either way):
        `"exact"`, through every Newton iterate (forward and reverse mode agree with finite
        differences of the computed states); `"implicit"`, by the implicit-function theorem
        on each stage equation at its last-but-one iterate, $(I - ghJ)^{-1}$ times the
        derivative of the stage's inputs: no second derivatives of `rhs`, so one Jacobian
        through the scan costs about a third. It differs from the exact one by the last Newton
        correction (small where two Newton iterations converge, a few per cent on very stiff
        sets): good for a Levenberg-Marquardt step or a std-error, not for a gradient check.

    **Returns:** the state at every sample, shape `(T, S)`, with row 0 equal to `y0`.
    """
    _check(scheme, tangent)
    ode = _as_ode(ode)
    x = jnp.asarray(x)
    xdot = jnp.asarray(xdot)
    n = x.shape[0]
    y0 = jnp.asarray(y0, dtype=jnp.result_type(x, y0, float))
    if n < 2:
        return y0[None, :]
    theta = jnp.asarray(theta)
    # Constant parameters are closed over, not broadcast to (T, P) scan inputs: under vmap over
    # C x N particles that broadcast would be a (T, C, N, P) buffer, rebuilt every call.
    per_sample = theta.ndim > 1
    dts = jnp.broadcast_to(jnp.asarray(dt, dtype=x.dtype), (n,))[:-1]
    xs = (x[:-1], x[1:], xdot[:-1], xdot[1:], dts) + ((theta[:-1],) if per_sample else ())
    m = int(substeps)
    # one scan step per sub-step, its interval's inputs repeated: an inner loop over the
    # sub-steps has its own overhead per interval, and unrolled sub-steps make XLA's
    # forward-mode code grow with m squared
    xs = tuple(jnp.repeat(a, m, axis=0) for a in xs) + (jnp.tile(jnp.arange(m), n - 1),)
    rhs, flow = ode.rhs, ode.flow
    lin = _newton_lin(ode.linearize or linearize_auto(rhs))
    S = y0.shape[0]

    def projector(p):
        return _projector(ode.box, p, y0.dtype, S)

    stiff = scheme == "sdirk" and flow is None
    proj_const = projector(theta) if stiff and not per_sample else None

    def step(y, inp):
        x0, x1, v0, v1, h_all = inp[:5]
        p = inp[5] if per_sample else theta
        proj = proj_const if proj_const is not None else (projector(p) if stiff else None)
        y = _substep(rhs, lin, proj, flow, p, x0, x1, v0, v1, h_all, m, scheme, tangent)(
            inp[-1], y)
        return y, y

    _, ys = jax.lax.scan(step, y0, xs)
    return jnp.concatenate([y0[None, :], ys[m - 1::m]], axis=0)


# ------------------------------------------------------------------------------ step count
#: Target of $|\\lambda| h$ per RK4 sub-step used by :func:`choose_substeps` (dimensionless).
#: RK4 is stable up to 2.78 for a real eigenvalue; the models' stiffness estimates are upper
#: bounds, and 1.5 leaves room for the state equation's nonlinearity.
STEP_TARGET = 1.5
#: Upper limit of the automatic sub-step count.
MAX_SUBSTEPS = 256
#: Sub-steps used when `substeps=None` but the inputs are traced (inside `jit`/`vmap`), so no
#: stiffness estimate can be made. `mrjax.fit` always resolves the count on the host instead.
TRACED_SUBSTEPS = 8


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
