"""The one integrator of mrjax: fixed-step RK4 over a sampled record, as a `lax.scan`.

Every ODE model (Bouc-Wen, modified Bouc-Wen, Dahl) only defines its right-hand side
`rhs(state, x, xdot, theta) -> dstate/dt`; this module steps it over the record.

Inside each sample interval $[t_k, t_{k+1}]$ the excitation is interpolated linearly,
$x(t_k + s\\,\\Delta t_k) = x_k + s (x_{k+1} - x_k)$ and likewise for $\\dot x$, and the interval is
split into `substeps` equal RK4 steps. Parameters may be constant, shape `(P,)`, or vary per
sample, shape `(T, P)`; a per-sample parameter is held constant over the interval that starts at
its sample.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

RHS = Callable[[Array, Array, Array, Array], Array]


def rk4_scan(
    rhs: RHS,
    y0: Float[ArrayLike, " S"],
    theta: Float[ArrayLike, "*T P"],
    x: Float[ArrayLike, " T"],
    xdot: Float[ArrayLike, " T"],
    dt: Float[ArrayLike, "*T"],
    substeps: int,
) -> Float[Array, "T S"]:
    """Integrate `rhs` over a sampled record with fixed-step RK4.

    **Arguments:**

    - `rhs`: right-hand side `rhs(state, x, xdot, theta) -> d state / dt` for one instant.
    - `y0`: initial state at the first sample, shape `(S,)`.
    - `theta`: parameters, `(P,)` or per sample `(T, P)`.
    - `x`: displacement [m], shape `(T,)`.
    - `xdot`: velocity [m/s], shape `(T,)`.
    - `dt`: sample interval [s], a scalar or per sample `(T,)` (the interval after each sample;
        the last entry is unused).
    - `substeps`: RK4 steps per sample interval (static).

    **Returns:** the state at every sample, shape `(T, S)`, with row 0 equal to `y0`.
    """
    x = jnp.asarray(x)
    xdot = jnp.asarray(xdot)
    n = x.shape[0]
    y0 = jnp.asarray(y0, dtype=jnp.result_type(x, y0, float))
    if n < 2:
        return y0[None, :]
    theta = jnp.asarray(theta)
    # Constant parameters are closed over, not broadcast to (T, P) scan inputs: under vmap over
    # C x N particles that broadcast was a (T, C, N, P) buffer, rebuilt every call.
    per_sample = theta.ndim > 1
    dts = jnp.broadcast_to(jnp.asarray(dt, dtype=x.dtype), (n,))[:-1]
    xs = (x[:-1], x[1:], xdot[:-1], xdot[1:], dts) + ((theta[:-1],) if per_sample else ())
    m = int(substeps)
    frac = 1.0 / m

    def interval(y, inp):
        x0, x1, v0, v1, h_all = inp[:5]
        p = inp[5] if per_sample else theta
        dx, dv = x1 - x0, v1 - v0
        h = h_all * frac

        def f(y, s):
            return rhs(y, x0 + s * dx, v0 + s * dv, p)

        def sub(j, y):
            s0 = j * frac
            k1 = f(y, s0)
            k2 = f(y + 0.5 * h * k1, s0 + 0.5 * frac)
            k3 = f(y + 0.5 * h * k2, s0 + 0.5 * frac)
            k4 = f(y + h * k3, s0 + frac)
            return y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

        if m == 1:
            y = sub(0, y)
        else:
            y = jax.lax.fori_loop(0, m, sub, y, unroll=min(m, 4))
        return y, y

    _, ys = jax.lax.scan(interval, y0, xs)
    return jnp.concatenate([y0[None, :], ys], axis=0)
