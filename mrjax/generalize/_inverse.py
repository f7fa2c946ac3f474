"""The inverse model: the command that makes a generalized model produce a desired force, for
every model (a scan that carries a dynamic model's state), and a closed-loop simulation."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from .._errors import InputError
from ..models import integrate_step
from ._model import MODEL_LAG, GeneralizedModel, ModelLag, check_lag

#: A desired force counts as out of reach where the closest admissible force misses it by more
#: than this fraction of max |desired force| (default of `inverse`'s `atol`).
REACH_RTOL = 1e-3


def _solve(f, fd, lo, hi, n_grid: int, iters: int):
    """The command in [lo, hi] whose force `f(u)` ((n,) -> (n,)) is closest to `fd`: on a grid
    of `n_grid` commands, then bisection in the first bracket of a sign change (the smallest
    command that gives the force) or, without one, golden-section search of |f - fd| next to
    the best grid node. Returns `(u, reached)` (reached: a sign change was found)."""
    grid = lo + (hi - lo) * jnp.linspace(0.0, 1.0, n_grid)
    grid = grid.at[0].set(lo).at[-1].set(hi)
    g = f(grid) - fd
    ag = jnp.abs(g)
    neg = g <= 0.0
    change = neg[:-1] != neg[1:]
    has_root = jnp.any(change)
    k = jnp.argmax(change)

    def bis(_, lh):
        a, b, ga = lh
        mid = 0.5 * (a + b)
        gm = f(mid[None])[0] - fd
        same = (gm <= 0.0) == (ga <= 0.0)
        return jnp.where(same, mid, a), jnp.where(same, b, mid), jnp.where(same, gm, ga)

    a, b, _ = jax.lax.fori_loop(0, iters, bis, (grid[k], grid[k + 1], g[k]))
    cand = jnp.stack([a, b])
    root = cand[jnp.argmin(jnp.abs(f(cand) - fd))]

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
    return jnp.clip(jnp.where(has_root, root, near), lo, hi), has_root


class Inverse(eqx.Module):
    """Outcome of :func:`inverse` (T samples, or the broadcast shape of a static model's
    pointwise inverse).

    **Fields:**

    - `command`: the command v to apply, in the laws' unit (A or V), within the admissible
        range.
    - `effective`: the command u the laws see (v through the model's lag; = `command` without
        one).
    - `force`: the model's force [N] under `command` (what the damper would give).
    - `error`: `force - force_desired` [N].
    - `out_of_reach`: no admissible command gives the desired force at that sample (the
        command saturates at the closest one): |error| > `atol`.
    - `saturated`: the command is at a limit of the admissible range.
    """

    command: Float[Array, "*T"]
    effective: Float[Array, "*T"]
    force: Float[Array, "*T"]
    error: Float[Array, "*T"]
    out_of_reach: Bool[Array, "*T"]
    saturated: Bool[Array, "*T"]


@eqx.filter_jit
def _static_core(model, laws, x, v, fd, lo, hi, n_grid, iters):
    def one(xk, vk, fk):
        def f(u):
            u = jnp.atleast_1d(u)
            return model.force(laws(u), jnp.full(u.shape, xk), jnp.full(u.shape, vk), 1.0)

        u, _ = _solve(f, fk, lo, hi, n_grid, iters)
        return u, f(u[None])[0]

    return jax.vmap(one)(x, v, fd)


@eqx.filter_jit
def _dynamic_core(model, laws, x, v, dt, fd, lo, hi, eta, use_lag, n_grid, iters):
    """The command sample by sample, carrying the model's state (and the filter's output)."""
    dynamic = model.dynamic
    T = x.shape[0]
    a = jnp.exp(-eta * dt) if use_lag else jnp.zeros_like(dt)

    def target(state, k):
        """The effective command at sample k closest to the desired force there."""
        def f(u):
            return jax.vmap(lambda uu: model.force_at(laws(uu), state, x[k], v[k]))(u)

        u, _ = _solve(f, fd[k], lo, hi, n_grid, iters)
        return u

    state0 = model.initial_state(x[0], v[0]) if dynamic else jnp.zeros((1,), x.dtype)
    u0 = target(state0, 0)  # u_0 = v_0: the filter starts at the first command

    def body(carry, k):
        state, u = carry  # state and effective command at sample k
        f_k = model.force_at(laws(u), state, x[k], v[k])
        nxt = jnp.minimum(k + 1, T - 1)
        state1 = model.advance(state, laws(u), x[k], x[nxt], v[k], v[nxt], dt[k]) \
            if dynamic else state
        u_star = target(state1, nxt)
        if use_lag:  # the command that brings the filter's output to u_star at the next sample
            cmd = jnp.clip((u_star - a[k] * u) / (1.0 - a[k]), lo, hi)
            cmd = jnp.where(k == 0, u, cmd)  # the filter starts at the first command (u_0 = v_0)
            u1 = cmd + (u - cmd) * a[k]
        else:
            cmd, u1 = u, u_star
        return (state1, u1), (cmd, u, f_k)

    _, (cmd, u, f) = jax.lax.scan(body, (state0, u0), jnp.arange(T))
    if not use_lag:
        cmd = u
    return cmd, u, f


def inverse(
    gm: GeneralizedModel,
    x: Float[ArrayLike, "*T"],
    xdot: Float[ArrayLike, "*T"],
    force_desired: Float[ArrayLike, "*T"],
    *,
    dt: Float[ArrayLike, "*T"] | None = None,
    command_range: tuple[float, float] | None = None,
    lag: float | None | ModelLag = MODEL_LAG,
    atol: float | None = None,
    n_grid: int = 64,
    iters: int = 40,
) -> Inverse:
    """The command that makes the generalized model `gm` produce `force_desired`.

    - **Static models** (tanh, Bingham) without lag: pointwise. For each sample the force
        $f(u)$ is evaluated on `n_grid` commands spanning the admissible range; if $f - f_d$
        changes sign, the root in the first bracket (the smallest command giving the force) is
        refined by `iters` bisection steps, otherwise the force is out of reach and the command
        whose force is closest is returned (golden-section refinement; where f is monotone in u
        this saturates exactly at a limit).
    - **Dynamic models** (Bouc-Wen, modified Bouc-Wen, Dahl), and any model with a lag: a
        `lax.scan` over the record that carries the model's state (`AbstractModel.advance`,
        the integrator of `force` with its sub-steps) and picks, sample by sample, the command
        whose force at that sample, from the state reached, is closest to the desired one (the
        same search). With a lag $\\dot u = -\\eta(u - v)$ the command v held over an interval
        moves u only partly: the scan picks the u wanted at the next sample and the command
        that brings the filter's output there, clipped to the admissible range.

    **Arguments:**

    - `gm`: a :class:`GeneralizedModel`.
    - `x` [m], `xdot` [m/s], `force_desired` [N]: a record (T,) (static models: any
        broadcastable shape).
    - `dt`: sample interval [s], scalar or (T,): needed by dynamic models and the lag.
    - `command_range`: admissible `(low, high)` command in the laws' unit (default
        `gm.command_range`).
    - `lag`: the filter rate [1/s], None for none, default the model's own.
    - `atol`: force error [N] above which a sample is flagged out of reach (default
        `REACH_RTOL` x max |force_desired|).
    - `n_grid`, `iters`: grid size and refinement steps (static).

    **Returns:** an :class:`Inverse` (command, effective command, force, error, flags).

    Raises :class:`mrjax.InputError` for a bad range or shapes, or a missing `dt`.
    """
    if not isinstance(gm, GeneralizedModel):
        raise InputError(f"inverse needs a GeneralizedModel, got {type(gm).__name__}")
    if int(n_grid) < 2 or int(iters) < 1:
        raise InputError("n_grid must be at least 2 and iters at least 1")
    lo, hi = gm.command_range if command_range is None else command_range
    traced = any(isinstance(v, jax.core.Tracer) for v in (lo, hi))
    if not traced:
        for name, val in (("low", lo), ("high", hi)):
            if not math.isfinite(float(val)):
                raise InputError(f"command_range {name} must be finite, got {val!r}")
        if not float(lo) < float(hi):
            raise InputError(f"command_range must have low < high, got ({lo!r}, {hi!r})")
    eta = gm.lag if lag is MODEL_LAG else check_lag(lag)
    x, xdot, fd = jnp.broadcast_arrays(jnp.asarray(x, float), jnp.asarray(xdot, float),
                                       jnp.asarray(force_desired, float))
    tol = jnp.asarray(atol, float) if atol is not None else \
        REACH_RTOL * jnp.max(jnp.abs(fd))
    lo_j, hi_j = jnp.asarray(lo, float), jnp.asarray(hi, float)
    if not gm.model.dynamic and eta is None:  # pointwise, any shape, jittable
        shape = x.shape
        u, f = _static_core(gm.model, gm.lawset, x.ravel(), xdot.ravel(), fd.ravel(), lo_j,
                            hi_j, int(n_grid), int(iters))
        u, f = u.reshape(shape), f.reshape(shape)
        return _result(u, u, f, fd, tol, lo_j, hi_j)
    if traced:
        raise InputError("command_range must be concrete numbers for a dynamic model or a lag")
    if x.ndim != 1 or x.shape[0] < 2:
        raise InputError(f"a dynamic model (or a lag) needs a record: x, xdot, force_desired "
                         f"of shape (T,), T >= 2, got {x.shape}")
    if dt is None:
        raise InputError("dt (the sample interval in s) is needed by a dynamic model or a lag")
    dt_a = jnp.broadcast_to(jnp.asarray(dt, float), x.shape)
    model = gm.resolved_model(np.linspace(float(lo), float(hi), 9), np.asarray(xdot),
                         np.asarray(dt_a))
    cmd, u, f = _dynamic_core(model, gm.lawset, x, xdot, dt_a, fd, lo_j, hi_j,
                              jnp.asarray(0.0 if eta is None else eta), eta is not None,
                              int(n_grid), int(iters))
    return _result(cmd, u, f, fd, tol, lo_j, hi_j)


def _result(cmd, u, f, fd, tol, lo, hi) -> Inverse:
    err = f - fd
    span = 1e-9 * jnp.maximum(jnp.abs(hi - lo), 1.0)
    sat = (cmd <= lo + span) | (cmd >= hi - span)
    return Inverse(command=cmd, effective=u, force=f, error=err, out_of_reach=jnp.abs(err) > tol,
                   saturated=sat)


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
    lag: float | None | ModelLag = MODEL_LAG,
) -> Float[Array, "*shape"]:
    """The command (current [A], or voltage [V] for laws of a voltage) that makes `gm` produce
    `force_desired`: :func:`inverse`'s `command` with the admissible range
    `[i_min, i_max]` (`i_max` default the top of `gm.command_range`). Static models are
    inverted pointwise (any shape, `dt` unused); dynamic ones, and a lag, need a record (T,)
    and `dt` [s]. See :func:`inverse` for the search and the saturation flags."""
    if not isinstance(gm, GeneralizedModel):
        raise InputError(f"inverse_current needs a GeneralizedModel, got {type(gm).__name__}")
    if i_max is None:
        i_max = gm.command_range[1]
    return inverse(gm, x, xdot, force_desired, dt=dt, command_range=(i_min, i_max), lag=lag,
                   n_grid=n_grid, iters=iters).command


class ClosedLoop(eqx.Module):
    """Outcome of :func:`closed_loop` (T samples).

    **Fields:** `x` [m], `xdot` [m/s] the structure's response; `force` [N] the damper's force;
    `desired` [N] the control law's force; `command` the command applied (laws' unit);
    `effective` the command the laws see (after the lag)."""

    x: Float[Array, " T"]
    xdot: Float[Array, " T"]
    force: Float[Array, " T"]
    desired: Float[Array, " T"]
    command: Float[Array, " T"]
    effective: Float[Array, " T"]


@eqx.filter_jit
def _closed_core(model, laws, ag, dt, mass, stiff, damp, gain, mode, lo, hi, eta, use_lag,
                 n_grid, iters):
    a = jnp.exp(-eta * dt) if use_lag else jnp.asarray(0.0)
    dyn = model.dynamic
    state0 = model.initial_state(0.0, 0.0) if dyn else jnp.zeros((1,))

    def structure(y, _x, _xdot, p):  # m y'' + c y' + k y = -m a_g - F
        return jnp.stack([y[1], (-mass * p[0] - damp * y[1] - stiff * y[0] - p[1]) / mass])

    def body(carry, agk):
        x, xd, state, u = carry
        f = model.force_at(laws(u), state, x, xd)
        fd = gain * xd
        # the command: inverse (mode 0), always off (1) or always on (2)
        def g(uu):
            return jax.vmap(lambda w: model.force_at(laws(w), state, x, xd))(uu)
        u_star, _ = _solve(g, fd, lo, hi, n_grid, iters)
        u_star = jnp.where(mode == 1, lo, jnp.where(mode == 2, hi, u_star))
        if use_lag:
            cmd = jnp.clip((u_star - a * u) / (1.0 - a), lo, hi)
            cmd = jnp.where(mode == 0, cmd, u_star)
            u1 = cmd + (u - cmd) * a
        else:
            cmd, u1 = u_star, u_star
        # the storey over the interval: the one integrator (RK4), ground acceleration and
        # damper force held
        x1, xd1 = integrate_step(structure, jnp.stack([x, xd]), jnp.stack([agk, f]),
                                 0.0, 0.0, 0.0, 0.0, dt, 1, scheme="rk4")
        state1 = model.advance(state, laws(u), x, x1, xd, xd1, dt) if dyn else state
        return (x1, xd1, state1, u1), (x, xd, f, fd, cmd, u)

    _, out = jax.lax.scan(body, (jnp.asarray(0.0), jnp.asarray(0.0), state0, lo), ag)
    return out


def closed_loop(
    gm: GeneralizedModel,
    ground_acceleration: Float[ArrayLike, " T"],
    dt: float,
    *,
    mass: float,
    stiffness: float,
    damping: float = 0.0,
    gain: float,
    control: str = "inverse",
    command_range: tuple[float, float] | None = None,
    lag: float | None | ModelLag = MODEL_LAG,
    n_grid: int = 32,
    iters: int = 30,
) -> ClosedLoop:
    """A closed-loop simulation of a base-excited one-storey structure with the damper `gm`
    between the storey and the ground: $m\\ddot x + c\\dot x + kx = -m\\ddot x_g - F$, with $F$
    the damper's force (its model's state carried, `AbstractModel.advance`) and the command
    chosen each sample by the inverse model (:func:`inverse`'s search, from the state reached)
    so that $F$ is closest to the control law's desired force $f_d = $ `gain` $\\dot x$
    (a viscous "skyhook" law), saturated to the admissible range; with a lag, the command that
    brings the filter's output there at the next sample.

    **Arguments:** `ground_acceleration` [m/s^2] (T,); `dt` [s]; `mass` [kg], `stiffness`
    [N/m], `damping` [N s/m] of the structure; `gain` [N s/m]; `control`: `"inverse"`
    (default), `"off"` (the lowest command) or `"on"` (the highest), the passive references;
    `command_range` default `gm.command_range`; `lag` default the model's own; `n_grid`,
    `iters` the search's grid and refinement steps.

    **Returns:** a :class:`ClosedLoop`. Raises :class:`mrjax.InputError` for bad arguments.
    """
    if not isinstance(gm, GeneralizedModel):
        raise InputError(f"closed_loop needs a GeneralizedModel, got {type(gm).__name__}")
    modes = {"inverse": 0, "off": 1, "on": 2}
    if control not in modes:
        raise InputError(f"control must be one of {sorted(modes)}, got {control!r}")
    for name, val in (("dt", dt), ("mass", mass), ("stiffness", stiffness)):
        if not (math.isfinite(float(val)) and float(val) > 0):
            raise InputError(f"{name} must be positive, got {val!r}")
    ag = jnp.asarray(ground_acceleration, float)
    if ag.ndim != 1 or ag.shape[0] < 2:
        raise InputError(f"ground_acceleration must be (T,), T >= 2, got {ag.shape}")
    lo, hi = gm.command_range if command_range is None else command_range
    if not float(lo) < float(hi):
        raise InputError(f"command_range must have low < high, got ({lo!r}, {hi!r})")
    eta = gm.lag if lag is MODEL_LAG else check_lag(lag)
    # sub-steps for velocities up to a generous bound of the response
    vmax = np.full(2, 10.0 * float(np.max(np.abs(ag))) * math.sqrt(mass / stiffness) + 0.1)
    model = gm.resolved_model(np.linspace(float(lo), float(hi), 9), vmax, np.full(2, float(dt)))
    x, xd, f, fd, cmd, u = _closed_core(
        model, gm.lawset, ag, jnp.asarray(float(dt)), float(mass), float(stiffness),
        float(damping), float(gain), modes[control], jnp.asarray(float(lo)),
        jnp.asarray(float(hi)), jnp.asarray(0.0 if eta is None else eta), eta is not None,
        int(n_grid), int(iters))
    return ClosedLoop(x=x, xdot=xd, force=f, desired=fd, command=cmd, effective=u)
