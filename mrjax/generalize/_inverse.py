"""The inverse model: the current that makes a generalized model produce a wanted force."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._errors import InputError
from ._model import GeneralizedModel


def _inverse_one(model, laws, x, v, fd, i_min, i_max, n_grid, iters):
    def f(i):
        i = jnp.atleast_1d(i)
        return model.force(laws(i), jnp.full(i.shape, x), jnp.full(i.shape, v), 1.0)

    grid = i_min + (i_max - i_min) * jnp.linspace(0.0, 1.0, n_grid)
    grid = grid.at[0].set(i_min).at[-1].set(i_max)
    g = f(grid) - fd
    ag = jnp.abs(g)
    neg = g <= 0.0
    change = neg[:-1] != neg[1:]
    has_root = jnp.any(change)
    k = jnp.argmax(change)  # the first bracket: the smallest current that reaches fd

    # bisection in the bracket [grid[k], grid[k+1]]
    def bis(_, lh):
        lo, hi, glo = lh
        mid = 0.5 * (lo + hi)
        gm = f(mid)[0] - fd
        same = (gm <= 0.0) == (glo <= 0.0)
        return jnp.where(same, mid, lo), jnp.where(same, hi, mid), jnp.where(same, gm, glo)

    lo, hi, _ = jax.lax.fori_loop(0, iters, bis, (grid[k], grid[k + 1], g[k]))
    cand = jnp.stack([lo, hi])
    root = cand[jnp.argmin(jnp.abs(f(cand) - fd))]

    # no root: closest force, golden-section refinement of |f - fd| next to the best node
    j = jnp.argmin(ag)
    a0 = grid[jnp.maximum(j - 1, 0)]
    b0 = grid[jnp.minimum(j + 1, n_grid - 1)]
    r = 0.5 * (math.sqrt(5.0) - 1.0)

    def gold(_, ab):
        a, b = ab
        c, d = b - r * (b - a), a + r * (b - a)
        fc, fdd = jnp.abs(f(jnp.stack([c, d])) - fd)
        return jnp.where(fc <= fdd, a, c), jnp.where(fc <= fdd, d, b)

    a, b = jax.lax.fori_loop(0, iters, gold, (a0, b0))
    cand = jnp.stack([grid[j], 0.5 * (a + b)])
    near = cand[jnp.argmin(jnp.abs(f(cand) - fd))]  # ties keep the node (exact limits)
    return jnp.clip(jnp.where(has_root, root, near), i_min, i_max)


@eqx.filter_jit
def _inverse_core(model, laws, x, v, fd, i_min, i_max, n_grid, iters):
    one = lambda a, b, c: _inverse_one(model, laws, a, b, c, i_min, i_max, n_grid, iters)
    return jax.vmap(one)(x, v, fd)


def inverse_current(
    gm: GeneralizedModel,
    x: Float[ArrayLike, "*shape"],
    xdot: Float[ArrayLike, "*shape"],
    force_desired: Float[ArrayLike, "*shape"],
    *,
    i_max: float | None = None,
    i_min: float = 0.0,
    dt: Float[ArrayLike, "*shape"] | None = None,
    n_grid: int = 64,
    iters: int = 40,
) -> Float[Array, "*shape"]:
    """Current [A] that makes the generalized tanh model produce `force_desired`.

    For each sample, $f(i) = c(i)\\dot x + k(i) x + \\alpha(i)\\tanh(\\beta(i)\\dot x +
    \\delta(i)\\,\\mathrm{sign}(x)) + f_0(i)$ is evaluated on `n_grid` currents spanning
    $[i_{min}, i_{max}]$. If $f - f_d$ changes sign, the root in the first such bracket (the
    smallest current that gives the force) is refined by `iters` bisection steps. Otherwise the
    force is out of reach and the current whose force is closest is returned (golden-section
    refinement next to the best grid node); where f is monotone in i this saturates exactly at
    $i_{min}$ or $i_{max}$.

    **Arguments:**

    - `gm`: a :class:`GeneralizedModel` of the tanh model (`"kwok"`).
    - `x` [m], `xdot` [m/s], `force_desired` [N]: broadcastable arrays (any shape).
    - `i_max`: upper current limit [A] (default: the top of `gm.current_range`).
    - `i_min`: lower current limit [A] (default 0).
    - `dt`: unused (the tanh model is static); accepted for a uniform controller interface.
    - `n_grid`, `iters`: grid size and refinement steps (static).

    Vectorised and jittable (`gm` is a constant of the trace).

    **Returns:** currents [A] of the broadcast shape, in $[i_{min}, i_{max}]$.
    """
    if not isinstance(gm, GeneralizedModel):
        raise InputError(f"inverse_current needs a GeneralizedModel, got {type(gm).__name__}")
    if gm.model.name != "kwok":
        raise InputError(f"inverse_current supports the tanh model ('kwok') only, got "
                         f"{gm.model.name!r}")
    if int(n_grid) < 2 or int(iters) < 1:
        raise InputError("n_grid must be at least 2 and iters at least 1")
    if i_max is None:
        i_max = gm.current_range[1]
    for name, v in (("i_min", i_min), ("i_max", i_max)):
        if not isinstance(v, jax.core.Tracer) and not math.isfinite(float(v)):
            raise InputError(f"{name} must be finite, got {v!r}")
    if not any(isinstance(v, jax.core.Tracer) for v in (i_min, i_max)) and \
            not float(i_min) < float(i_max):
        raise InputError(f"i_min must be below i_max, got {i_min!r} and {i_max!r}")
    x, xdot, fd = jnp.broadcast_arrays(jnp.asarray(x, float), jnp.asarray(xdot, float),
                                       jnp.asarray(force_desired, float))
    shape = x.shape
    out = _inverse_core(gm.model, gm._lawset, x.ravel(), xdot.ravel(), fd.ravel(),
                        jnp.asarray(i_min, float), jnp.asarray(i_max, float), int(n_grid),
                        int(iters))
    return out.reshape(shape)
