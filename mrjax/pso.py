r"""Batched particle swarm optimisation (Kwok et al. 2006, section 4).

One compiled program runs C conditions x N particles at once. Each condition has its own
swarm, its own random stream and its own statistical stop; a stopped condition is frozen while
the others go on.

**Update rule** (eq 9-10, unit sampling time):

$$ v \leftarrow \omega v + c_1 (x_g - x) + c_2 (x_p - x),\qquad x \leftarrow x + v, $$

where $x_g$ is the group (global) best and $x_p$ the particle's personal best. Note that the
paper's $c_1$ multiplies the *group* best. $c_1 \sim U[0, c_{1,max}]$ and
$c_2 \sim U[0, c_{2,max}]$ are drawn afresh every generation, **independently per particle
and per dimension**.

**Bounds.** Particles start uniformly inside the bounds with zero velocity. After each move a
coordinate that leaves the box is clipped onto the wall and its velocity component set to zero
("absorbing walls"), so positions always stay inside the bounds. Velocities are clamped to
`velocity_clamp` times the box width.

**Statistical stop** (section 4.3). The group-best fitness never increases, so its per-generation
improvement $\Delta_t = f_{t-1} - f_t \ge 0$. The paper models $\Delta$ "after some generations"
as exponential with mean $\lambda^{-1}$ and stops, with confidence $c$ (0.905 in the paper),
once the mean improvement falls below $\gamma = -\ln(c)\,\lambda^{-1}$ (so that
$P(\Delta \le \gamma) = 1 - c$, i.e. $\gamma \approx 0.1\lambda^{-1}$ at $c = 0.905$). It
leaves open where $\lambda^{-1}$ and the mean are taken. mrjax's reading:

- $\lambda^{-1}$ is the running mean improvement per generation since the start,
  $\hat\lambda^{-1}_t = (f_0 - f_t)/t$;
- the test statistic is the mean improvement over the last `window` (W) generations;
- a condition stops at the first generation $t \ge \max(\text{min\_generations}, W)$ at
  which that mean is at most $\gamma_t = -\ln(c)\,\hat\lambda^{-1}_t$.

Why the running estimate rather than "the mean over the first W generations": the first
generations are the least exponential (one lucky initial particle can make them), and with a
first-W estimate the stop lands at exactly 2W on almost every condition of the paper grid
(measured), i.e. a fixed budget in disguise. The running estimate uses every improvement seen,
needs no separate burn-in, and gives the paper's behaviour: the full tanh swarm stops after
about 15 generations (median) with the default W = 8. `max_generations` caps every condition;
`criterion=False` runs exactly `max_generations` (for benchmarks).

**Separable mode.** Every model declares which parameters enter the force linearly. In
`"separable"` mode (variable projection, Golub & Pereyra 1973) the swarm searches only the
nonlinear parameters; each particle's linear parameters are the exact masked, column-scaled
linear least-squares solution, clipped to their bounds (the fitness is the RMS *after*
clipping, so a clipped particle is scored honestly).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PRNGKeyArray

from ._errors import InputError
from .data._condition import Batch
from .models._base import AbstractModel
from .objective import masked_rms, rms_from_gram

# ------------------------------------------------------------------------------ hyperparameters


def _f(v):
    return jnp.asarray(v, dtype=float)


def _i(v):
    return jnp.asarray(v, dtype=jnp.int32)


def _b(v):
    return jnp.asarray(v, dtype=bool)


class PSOParams(eqx.Module):
    """Swarm hyperparameters: *data*, not static arguments, so new values never recompile.

    **Fields:**

    - `inertia`: $\\omega$ (default 0.65, the paper's).
    - `c1_max`: bound of the group-best coefficient $c_1 \\sim U[0, c_{1,max}]$ (default 2).
    - `c2_max`: bound of the personal-best coefficient $c_2$ (default 2).
    - `confidence`: confidence of the statistical stop (default 0.905, the paper's).
    - `window`: generations W over which recent improvements are averaged (default 8, which
        with the paper's settings stops the tanh model's full swarm after about 15 generations;
        `default_params("separable")` uses 25, see there; at most `MAX_WINDOW`).
    - `min_generations`: never stop before this many generations (default 0; the window
        already requires W).
    - `criterion`: use the statistical stop (`True`) or run `max_generations` (`False`).
    - `velocity_clamp`: maximum |velocity| as a fraction of the box width (default 1).
    """

    inertia: Float[Array, ""] = eqx.field(default=0.65, converter=_f)
    c1_max: Float[Array, ""] = eqx.field(default=2.0, converter=_f)
    c2_max: Float[Array, ""] = eqx.field(default=2.0, converter=_f)
    confidence: Float[Array, ""] = eqx.field(default=0.905, converter=_f)
    window: Int[Array, ""] = eqx.field(default=8, converter=_i)
    min_generations: Int[Array, ""] = eqx.field(default=0, converter=_i)
    criterion: Bool[Array, ""] = eqx.field(default=True, converter=_b)
    velocity_clamp: Float[Array, ""] = eqx.field(default=1.0, converter=_f)

    def check(self) -> PSOParams:
        """Validate on the host: raises :class:`mrjax.InputError` for impossible values and warns
        (`RuntimeWarning`) when (inertia, c1_max, c2_max) is unstable (eq 14-15)."""
        conf = float(self.confidence)
        if not 0.0 < conf < 1.0:
            raise InputError(f"confidence must lie in (0, 1), got {conf}")
        w = int(self.window)
        if not 1 <= w <= MAX_WINDOW:
            raise InputError(f"window must be in [1, {MAX_WINDOW}], got {w}")
        if int(self.min_generations) < 0:
            raise InputError(f"min_generations must be >= 0, got {int(self.min_generations)}")
        if float(self.c1_max) < 0 or float(self.c2_max) < 0:
            raise InputError("c1_max and c2_max must be non-negative")
        if not float(self.velocity_clamp) > 0:
            raise InputError("velocity_clamp must be positive")
        eig, ok = stability(float(self.inertia), float(self.c1_max), float(self.c2_max))
        if not ok:
            warnings.warn(
                f"unstable swarm: inertia={float(self.inertia)}, c1_max={float(self.c1_max)}, "
                f"c2_max={float(self.c2_max)} give |eigenvalues| {np.abs(eig).round(3)} (>= 1); "
                "the swarm will not converge (eq 14-15)",
                RuntimeWarning,
                stacklevel=2,
            )
        return self


def default_params(mode: str = "full") -> PSOParams:
    """Default hyperparameters per swarm mode: the paper's for `"full"` (window 8), and
    window 25 for `"separable"`, whose two- to four-dimensional search keeps finding small
    improvements for longer; with it every paper-grid condition stops within 1.005 x the RMS
    of the true parameters (median stop after about 28 generations)."""
    return PSOParams(window=25) if mode == "separable" else PSOParams()


#: Largest supported `window` (the improvement ring buffer is this long).
MAX_WINDOW = 64


def stability(
    inertia: float, c1_max: float = 2.0, c2_max: float = 2.0
) -> tuple[np.ndarray, bool]:
    """Eigenvalues of the swarm's expected error dynamics (eq 11-15) and whether it is stable.

    With the expected coefficients $\\bar c = (c_{1,max} + c_{2,max})/2$, the error and velocity
    evolve by $A = [[1-\\bar c, -\\omega], [\\bar c, \\omega]]$, whose eigenvalues are the roots
    of $\\lambda^2 - (1 + \\omega - \\bar c)\\lambda + \\omega = 0$. The swarm converges iff both
    have $|\\lambda| < 1$.

    **Returns:** `(eigenvalues (2,) complex, stable)`.
    """
    c = 0.5 * (float(c1_max) + float(c2_max))
    w = float(inertia)
    A = np.array([[1.0 - c, -w], [c, w]])
    eig = np.linalg.eigvals(A)
    return eig, bool(np.all(np.abs(eig) < 1.0))


# ------------------------------------------------------------------------------ objectives


class AbstractObjective(eqx.Module):
    """A fitness for one particle on one condition: `objective(position, data) -> RMS [N]`.

    `data` is one condition's slice of a pytree with a leading condition axis. `to_params`
    maps a swarm position to the full parameter vector reported to the user.
    """

    def __call__(self, position: Array, data: Any) -> Array:
        raise NotImplementedError

    def to_params(self, position: Array, data: Any) -> Array:
        """Full parameter vector for a swarm position (identity by default)."""
        return position


def condition_data(batch: Batch, mask: ArrayLike | None = None) -> tuple[Array, ...]:
    """The per-condition arrays the model objectives read: `(x, xdot, dt, force, mask)`,
    each (C, T). `mask` overrides `batch.mask` (e.g. to drop a transient)."""
    m = batch.mask if mask is None else jnp.asarray(mask)
    return (batch.x, batch.xdot, batch.dt, batch.force, m)


class FullObjective(AbstractObjective):
    """The paper's objective: the swarm searches every parameter; fitness is the masked RMS."""

    model: AbstractModel

    def __call__(self, position, data):
        x, xdot, dt, force, mask = data
        return masked_rms(self.model.force(position, x, xdot, dt), force, mask)


def solve_linear(
    model: AbstractModel,
    theta: Float[Array, " P"],
    data: tuple[Array, ...],
    lower: Float[Array, " P"],
    upper: Float[Array, " P"],
) -> tuple[Float[Array, " P"], Float[Array, ""]]:
    """Variable projection for one particle on one condition.

    Given the nonlinear parameters in `theta` (its linear entries are ignored), solve the
    masked, column-scaled linear least-squares problem for the linear parameters, clip them to
    `[lower, upper]`, and return the full parameter vector and its RMS [N].

    The regressors split into parameter-free columns F (`model.basis`) and parameter-dependent
    ones Z (`model.hysteresis`). Everything that involves only F (its Gram matrix, its
    inverse, F'y) does not depend on the particle, so under `vmap` over particles it is computed
    once per condition; each particle only adds the dot products of its Z and b columns and a
    k x k Schur-complement solve (k = 1 or 0 for every built-in model).
    """
    x, xdot, dt, force, mask = data
    m = mask[:, None]
    # Particle-free part, H = [F, force]: under vmap over particles its Gram matrix, the column
    # scales of F and the inverse of the scaled F'F are computed once per condition.
    H = jnp.where(m, jnp.concatenate([model.basis(x, xdot), force[:, None]], axis=1), 0.0)
    p = H.shape[1] - 1
    HH = H.T @ H
    FF = HH[:p, :p]
    dF = jnp.sqrt(jnp.diag(FF))
    dF = jnp.where(dF > 0, dF, 1.0)
    Minv = jnp.linalg.inv(FF / jnp.outer(dF, dF) + 1e-12 * jnp.eye(p, dtype=FF.dtype))
    # Per particle: one pass over the samples. Z is kept as (k, T) rows: a trailing size-1 axis
    # (T, 1) makes XLA:CPU loop over it element by element (measured 5-10x slower).
    Z, b = model.hysteresis(theta, x, xdot, dt)
    k = Z.shape[1]
    Z = jnp.where(mask[None, :], Z.T, 0.0)
    b = jnp.where(mask, b, 0.0)
    ZH = Z @ H  # (k, p+1)
    bH = b @ H  # (p+1,)
    ZZ = Z @ Z.T
    Zb = Z @ b
    # Gram quantities of A = [F, Z] against y = force - b
    Fy = HH[:p, p] - bH[:p]
    yy = HH[p, p] - 2.0 * bH[p] + b @ b
    ZF = ZH[:, :p]
    Zy = ZH[:, p] - Zb
    G = jnp.block([[FF, ZF.T], [ZF, ZZ]]) if k else FF
    g = jnp.concatenate([Fy, Zy]) if k else Fy
    # column-scaled normal equations, solved by a Schur complement on the Z block
    gF = Fy / dF
    if k:
        dZ = jnp.sqrt(jnp.diag(ZZ))
        dZ = jnp.where(dZ > 0, dZ, 1.0)
        FZ = ZF.T / jnp.outer(dF, dZ)
        S = ZZ / jnp.outer(dZ, dZ) - FZ.T @ Minv @ FZ
        r = Zy / dZ - FZ.T @ (Minv @ gF)
        if k == 1:
            wz = jnp.where(S[0, 0] > 1e-12, r / S[0, 0], 0.0).reshape(1)
        else:
            wz = jnp.linalg.solve(S + 1e-12 * jnp.eye(k, dtype=S.dtype), r)
        w = jnp.concatenate([(Minv @ (gF - FZ @ wz)) / dF, wz / dZ])
    else:
        w = (Minv @ gF) / dF
    li = model.linear_index
    w = jnp.clip(w, lower[li], upper[li])
    full = theta.at[li].set(w)
    return full, rms_from_gram(w, G, g, yy, jnp.sum(mask))


def _log_flags(model: AbstractModel, lower) -> np.ndarray:
    """Which parameters the separable swarm searches in log space: those the model lists in
    `log_params` whose lower bound is positive (a wide positive range, e.g. 1..1000 s/m)."""
    lo = np.asarray(lower)
    names = getattr(model, "log_params", ())
    return np.array([(n in names) and bool(lo[i] > 0) for i, n in enumerate(model.param_names)])


class SeparableObjective(AbstractObjective):
    """Variable-projection objective: positions hold only the nonlinear parameters."""

    model: AbstractModel
    lower: Float[Array, " P"]
    upper: Float[Array, " P"]
    log_mask: tuple[bool, ...] = eqx.field(static=True, default=())

    def _full(self, position):
        nl = self.model.nonlinear_index
        base = 0.5 * (self.lower + self.upper)
        logs = np.asarray(self.log_mask or (False,) * len(nl), bool)
        return base.at[nl].set(jnp.where(logs, jnp.exp(position), position))

    def __call__(self, position, data):
        return solve_linear(self.model, self._full(position), data, self.lower, self.upper)[1]

    def to_params(self, position, data):
        return solve_linear(self.model, self._full(position), data, self.lower, self.upper)[0]


# ------------------------------------------------------------------------------ swarm


class SwarmState(eqx.Module):
    """State of C independent swarms of N particles in D dimensions."""

    position: Float[Array, "C N D"]
    velocity: Float[Array, "C N D"]
    fitness: Float[Array, "C N"]
    pbest_position: Float[Array, "C N D"]
    pbest_fitness: Float[Array, "C N"]
    gbest_position: Float[Array, "C D"]
    gbest_fitness: Float[Array, " C"]
    generation: Int[Array, " C"]
    done: Bool[Array, " C"]
    by_criterion: Bool[Array, " C"]
    lambda_inv: Float[Array, " C"]
    improvements: Float[Array, "C W"]
    history: Float[Array, "C G"]
    keys: Any


class SwarmResult(eqx.Module):
    """Per-condition swarm outcome.

    **Fields:** `position` (C, D) best swarm position; `fitness` (C,) best RMS [N];
    `generations` (C,) generations run; `stopped_by_criterion` (C,) bool (False: hit the cap);
    `history` (C, max_generations + 1) group-best RMS after each generation (index 0 is the
    initial swarm), held constant after a condition stopped; `lambda_inv` (C,) the estimated
    mean improvement $\\lambda^{-1}$ [N]; `n_particles` static.
    """

    position: Float[Array, "C D"]
    fitness: Float[Array, " C"]
    generations: Int[Array, " C"]
    stopped_by_criterion: Bool[Array, " C"]
    history: Float[Array, "C G"]
    lambda_inv: Float[Array, " C"]
    n_particles: int = eqx.field(static=True)


def _keys_for(key, n: int):
    key = jnp.asarray(key) if not isinstance(key, jax.Array) else key
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        return jax.random.split(key, n) if key.ndim == 0 else key
    # raw uint32 keys: shape (2,) single or (n, 2)
    return jax.random.split(key, n) if key.ndim == 1 else key


def _sanitize(f):
    return jnp.where(jnp.isnan(f), jnp.inf, f)


@eqx.filter_jit
def _swarm(
    objective: AbstractObjective,
    lower: Float[Array, "C D"],
    upper: Float[Array, "C D"],
    data: Any,
    keys,
    params: PSOParams,
    n_particles: int,
    max_generations: int,
    callback: Callable | None,
) -> SwarmResult:
    C, D = lower.shape
    N = n_particles
    G = max_generations
    span = upper - lower
    # hyperparameters in the swarm's dtype, so a float32 swarm is not promoted to float64
    params = jax.tree.map(
        lambda a: a.astype(lower.dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a, params)
    vmapped = jax.vmap(jax.vmap(objective, in_axes=(0, None)), in_axes=(0, 0))

    def evaluate(x, data):
        return vmapped(x, data).astype(lower.dtype)

    def init_one(k, lo, hi):
        u = jax.random.uniform(jax.random.fold_in(k, 0), (N, D), dtype=lo.dtype)
        return lo + u * (hi - lo)

    pos = jax.vmap(init_one)(keys, lower, upper)
    fit = _sanitize(evaluate(pos, data))
    g = jnp.argmin(fit, axis=1)
    gpos = jnp.take_along_axis(pos, g[:, None, None], axis=1)[:, 0]
    gfit = jnp.min(fit, axis=1)
    hist = jnp.broadcast_to(gfit[:, None], (C, G + 1))
    state = SwarmState(
        position=pos, velocity=jnp.zeros_like(pos), fitness=fit,
        pbest_position=pos, pbest_fitness=fit, gbest_position=gpos, gbest_fitness=gfit,
        generation=jnp.zeros((C,), jnp.int32), done=jnp.zeros((C,), bool),
        by_criterion=jnp.zeros((C,), bool), lambda_inv=jnp.zeros((C,), pos.dtype),
        improvements=jnp.zeros((C, MAX_WINDOW), pos.dtype), history=hist, keys=keys,
    )
    W = params.window
    neglog = -jnp.log(params.confidence)

    def cond(s: SwarmState):
        return jnp.any(~s.done)

    def step(s: SwarmState) -> SwarmState:
        gen = s.generation + 1  # generation being computed, per condition

        def draws(k, t):
            # r1 and r2 are the two 16-bit halves of one random 32-bit word: half the
            # threefry hashes of two separate draws (the draws cost ~25 % of a float32 tanh
            # generation otherwise), resolution 2^-16 on U[0, 1).
            bits = jax.random.bits(jax.random.fold_in(k, t), (N, D), jnp.uint32)
            scale = jnp.asarray(2.0**-16, pos.dtype)
            return ((bits & 0xFFFF).astype(pos.dtype) * scale,
                    (bits >> 16).astype(pos.dtype) * scale)

        r1, r2 = jax.vmap(draws)(s.keys, gen)
        c1 = params.c1_max * r1
        c2 = params.c2_max * r2
        vmax = (params.velocity_clamp * span)[:, None, :]
        v = (params.inertia * s.velocity
             + c1 * (s.gbest_position[:, None, :] - s.position)
             + c2 * (s.pbest_position - s.position))
        v = jnp.clip(v, -vmax, vmax)
        x = s.position + v
        lo, hi = lower[:, None, :], upper[:, None, :]
        out = (x < lo) | (x > hi)
        x = jnp.clip(x, lo, hi)
        v = jnp.where(out, 0.0, v)
        f = _sanitize(evaluate(x, data))
        better = f < s.pbest_fitness
        pb_pos = jnp.where(better[..., None], x, s.pbest_position)
        pb_fit = jnp.where(better, f, s.pbest_fitness)
        j = jnp.argmin(pb_fit, axis=1)
        cand_fit = jnp.min(pb_fit, axis=1)
        cand_pos = jnp.take_along_axis(pb_pos, j[:, None, None], axis=1)[:, 0]
        gb = cand_fit < s.gbest_fitness
        g_fit = jnp.where(gb, cand_fit, s.gbest_fitness)
        g_pos = jnp.where(gb[:, None], cand_pos, s.gbest_position)
        # statistical stop: improvements ring buffer, lambda^-1 from the first W generations
        imp = jnp.where(jnp.isfinite(s.gbest_fitness), s.gbest_fitness - g_fit, 0.0)
        imp = jnp.where(jnp.isfinite(imp), imp, 0.0)
        slot = (gen - 1) % MAX_WINDOW
        imps = s.improvements.at[jnp.arange(C), slot].set(imp)
        # running mean improvement per generation since the start: lambda^-1 estimate
        lam = s.lambda_inv + (imp - s.lambda_inv) / gen
        # mean over the last W generations (slots gen-W .. gen-1)
        ages = (slot[:, None] - jnp.arange(MAX_WINDOW)[None, :]) % MAX_WINDOW
        recent = jnp.sum(jnp.where(ages < W, imps, 0.0), axis=1) / W
        eligible = (gen >= jnp.maximum(params.min_generations, W)) & params.criterion
        stop_crit = eligible & (recent <= neglog * lam)
        stop_cap = gen >= G
        new_done = stop_crit | stop_cap
        hist = s.history.at[jnp.arange(C), jnp.minimum(gen, G)].set(g_fit)
        # after stopping, the rest of the history holds the final best
        hist = jnp.where(
            new_done[:, None] & (jnp.arange(G + 1)[None, :] > gen[:, None]), g_fit[:, None], hist
        )
        new = SwarmState(
            position=x, velocity=v, fitness=f, pbest_position=pb_pos, pbest_fitness=pb_fit,
            gbest_position=g_pos, gbest_fitness=g_fit, generation=gen, done=new_done,
            by_criterion=stop_crit, lambda_inv=lam, improvements=imps, history=hist, keys=s.keys,
        )
        frozen = s.done

        def keep(old, nw):
            if not isinstance(old, jax.Array) or old.ndim == 0 or old.shape[0] != C:
                return nw
            if jnp.issubdtype(old.dtype, jax.dtypes.prng_key):
                return nw
            return jnp.where(frozen.reshape((C,) + (1,) * (old.ndim - 1)), old, nw)

        out_state = jax.tree.map(keep, s, new)
        if callback is not None:
            jax.debug.callback(
                callback, out_state.generation, out_state.done, out_state.gbest_fitness,
                ordered=True,
            )
        return out_state

    final = jax.lax.while_loop(cond, step, state)
    return SwarmResult(
        position=final.gbest_position, fitness=final.gbest_fitness,
        generations=final.generation, stopped_by_criterion=final.by_criterion,
        history=final.history, lambda_inv=final.lambda_inv, n_particles=N,
    )


def swarm(
    objective: AbstractObjective,
    lower: Float[ArrayLike, "*C D"],
    upper: Float[ArrayLike, "*C D"],
    data: Any,
    *,
    key: PRNGKeyArray,
    params: PSOParams | None = None,
    n_particles: int = 50,
    max_generations: int = 200,
    callback: Callable[[np.ndarray, np.ndarray, np.ndarray], None] | None = None,
    dtype: Any = None,
) -> SwarmResult:
    """Minimise `objective` on every condition at once with the batched particle swarm.

    **Arguments:**

    - `objective`: an :class:`AbstractObjective` (an `eqx.Module`), called as
        `objective(position (D,), one_condition_data)`; it must return `inf`, not raise, for
        bad positions (NaN is mapped to `inf` anyway).
    - `lower`, `upper`: search box, (D,) shared or (C, D) per condition, in the units of the
        positions.
    - `data`: pytree whose leaves have a leading condition axis C.
    - `key`: a PRNG key, split into one stream per condition, or (C,) keys, one per condition
        (a condition's result then depends only on its own key and data).
    - `params`: :class:`PSOParams` hyperparameters (data: new values do not recompile).
    - `n_particles`: N (static).
    - `max_generations`: cap on generations per condition (static: the history length).
    - `callback`: optional host function `callback(generation (C,), done (C,), best (C,))`
        called after every generation (through `jax.debug.callback`); `None` costs nothing.
    - `dtype`: float dtype the swarm runs in (positions, velocities, fitness), also applied to
        the floating-point leaves of `data` and `objective`. `None` (default) keeps JAX's
        default float (float64 under mrjax). `"float32"` halves the memory traffic and lets
        XLA:CPU use twice the SIMD lanes and cheaper `exp`/`log`/`tanh` (2-4x faster fitness on
        the paper grid, see `benchmarks/`); the fitness then carries float32 rounding
        (relative 1e-6 on the RMS).

    **Returns:** a :class:`SwarmResult`.
    """
    params = (params or PSOParams()).check()
    leaves = jax.tree.leaves(data)
    if not leaves:
        raise InputError("swarm data is empty")
    C = int(leaves[0].shape[0])
    lower = jnp.asarray(lower, dtype=float)
    upper = jnp.asarray(upper, dtype=float)
    D = lower.shape[-1]
    lower = jnp.broadcast_to(lower, (C, D))
    upper = jnp.broadcast_to(upper, (C, D))
    lo_np, hi_np = np.asarray(lower), np.asarray(upper)
    if not (np.all(np.isfinite(lo_np)) and np.all(np.isfinite(hi_np))):
        raise InputError("swarm bounds must be finite")
    if np.any(lo_np > hi_np):
        i = np.argwhere(lo_np > hi_np)[0]
        raise InputError(f"swarm bounds inverted in dimension {i[-1]}: "
                         f"lower {lo_np[tuple(i)]} > upper {hi_np[tuple(i)]}")
    if n_particles < 1 or max_generations < 1:
        raise InputError("n_particles and max_generations must be at least 1")
    keys = _keys_for(key, C)
    if keys.shape[0] != C:
        raise InputError(f"key: got {keys.shape[0]} keys for {C} conditions; pass one key or "
                         f"one per condition")
    if dtype is not None:
        dtype = jnp.dtype(dtype)
        if not jnp.issubdtype(dtype, jnp.floating):
            raise InputError(f"swarm dtype must be a floating-point type, got {dtype}")
        objective, data = _cast_floats((objective, data), dtype)
        lower, upper = lower.astype(dtype), upper.astype(dtype)
    return _swarm(objective, lower, upper, data, keys, params, int(n_particles),
                  int(max_generations), callback)


def _cast_floats(tree, dtype):
    """Cast the floating-point array leaves of a pytree (e.g. an objective module) to `dtype`."""

    def cast(a):
        if eqx.is_array(a) and jnp.issubdtype(a.dtype, jnp.floating) and a.dtype != dtype:
            return a.astype(dtype)
        return a

    return jax.tree.map(cast, tree)


# ------------------------------------------------------------------------------ model swarms


class ModelSwarm(eqx.Module):
    """Result of :func:`fit_swarm`: the swarm outcome in model parameters.

    **Fields:** `theta` (C, P) best parameters (all of them, also in separable mode);
    `rms` (C,) [N]; `swarm` the underlying :class:`SwarmResult`; `mode` static.
    """

    theta: Float[Array, "C P"]
    rms: Float[Array, " C"]
    swarm: SwarmResult
    mode: str = eqx.field(static=True)


def check_bounds(model: AbstractModel, bounds) -> tuple[np.ndarray, np.ndarray]:
    """Validate `(lower, upper)` for `model` (default `model.bounds`) and return float arrays.

    Raises :class:`mrjax.InputError` naming the parameter for a wrong shape, a non-finite
    value or lower > upper.
    """
    if bounds is None:
        return model.bounds
    try:
        lo, hi = bounds
    except (TypeError, ValueError):
        raise InputError("bounds must be a pair (lower, upper)") from None
    if isinstance(lo, dict) or isinstance(hi, dict):
        for d in (lo, hi):
            unknown = [k for k in d if k not in model.param_names] if isinstance(d, dict) else []
            if unknown:
                raise InputError(f"bounds name unknown parameter {unknown[0]!r} of model "
                                 f"{model.name!r}; its parameters: {', '.join(model.param_names)}")
        d_lo, d_hi = model.bounds
        lo = np.array([lo.get(n, d_lo[i]) if isinstance(lo, dict) else lo[i]
                       for i, n in enumerate(model.param_names)], float)
        hi = np.array([hi.get(n, d_hi[i]) if isinstance(hi, dict) else hi[i]
                       for i, n in enumerate(model.param_names)], float)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    P = model.n_params
    if lo.shape != (P,) or hi.shape != (P,):
        raise InputError(
            f"bounds for model {model.name!r} need {P} values each {list(model.param_names)}, "
            f"got shapes {lo.shape} and {hi.shape}"
        )
    for i, n in enumerate(model.param_names):
        if not (math.isfinite(lo[i]) and math.isfinite(hi[i])):
            raise InputError(f"bounds of parameter {n!r} must be finite, got [{lo[i]}, {hi[i]}]")
        if lo[i] > hi[i]:
            raise InputError(f"bounds of parameter {n!r} are inverted: lower {lo[i]:g} > upper {hi[i]:g}")
    return lo, hi


#: Cap on the RK4 sub-steps the swarm uses for ODE models. The stiffest corner of a wide box
#: can ask for hundreds; particles there are integrated less accurately (they typically diverge
#: and score `inf`). The polish and every reported RMS use sub-steps resolved from the found
#: parameters instead, uncapped.
SWARM_MAX_SUBSTEPS = 8


def box_corners(model: AbstractModel, lower: ArrayLike, upper: ArrayLike) -> np.ndarray:
    """Corners of the box over the *nonlinear* parameters (linear ones at mid-range), (K, P).
    The linear parameters never enter an ODE, so the stiffest point of a box is among these
    for the monotone stiffness bounds of the built-in models."""
    lo, hi = np.asarray(lower, float), np.asarray(upper, float)
    nl = model.nonlinear_index
    mid = 0.5 * (lo + hi)
    if nl.size == 0:
        return mid[None]
    bits = (np.arange(2 ** nl.size)[:, None] >> np.arange(nl.size)[None, :]) & 1
    rows = np.repeat(mid[None], bits.shape[0], axis=0)
    rows[:, nl] = np.where(bits, hi[nl], lo[nl])
    return rows


def resolve_model(
    model: AbstractModel, rows: ArrayLike, batch: Batch, *, cap: int | None = None
) -> AbstractModel:
    """Fix the RK4 sub-step count of an ODE model on the host for parameters `rows` (N, P) on
    `batch`: the stiffest row, the largest scored |velocity| and sample interval decide (see
    `mrjax.models.choose_substeps`), optionally capped at `cap`. Static models and models with
    explicit `substeps` pass through unchanged.
    """
    if not model.dynamic or model.substeps is not None:
        return model
    mask = np.asarray(batch.mask)
    v = np.where(mask, np.asarray(batch.xdot), 0.0)
    dt = np.where(mask, np.asarray(batch.dt), 0.0)
    n = model.resolve_substeps(np.atleast_2d(np.asarray(rows, float)), v, dt)
    return model.with_substeps(n if cap is None else min(n, int(cap)))


def fit_swarm(
    model: AbstractModel,
    batch: Batch,
    *,
    key: PRNGKeyArray,
    mode: Literal["separable", "full"] = "separable",
    bounds: tuple[ArrayLike, ArrayLike] | None = None,
    mask: ArrayLike | None = None,
    params: PSOParams | None = None,
    n_particles: int = 50,
    max_generations: int = 200,
    callback: Callable | None = None,
    dtype: Any = None,
) -> ModelSwarm:
    """Identify `model` on every condition of `batch` with the batched swarm.

    **Arguments:**

    - `model`: an `AbstractModel` (see `mrjax.models.get`).
    - `batch`: the conditions (`mrjax.data.Batch`).
    - `key`: PRNG key (see :func:`swarm`).
    - `mode`: `"separable"` (variable projection over the nonlinear parameters; default) or
        `"full"` (the paper's swarm over every parameter).
    - `bounds`: `(lower, upper)` (P,) in SI units, default `model.bounds`.
    - `mask`: (C, T) samples to score, default `batch.mask` (see `objective.fit_mask`).
    - `params`, `n_particles`, `max_generations`, `callback`: see :func:`swarm`.
    - `dtype`: float dtype of the swarm (see :func:`swarm`), e.g. `"float32"`. The returned
        `theta` and `rms` are always recomputed in the default float (float64) from the best
        swarm positions, so only the search runs in the lower precision.

    **Returns:** a :class:`ModelSwarm` with the full parameter vectors and their RMS [N].
    """
    lo, hi = check_bounds(model, bounds)
    model = resolve_model(model, box_corners(model, lo, hi), batch, cap=SWARM_MAX_SUBSTEPS)
    if params is None:
        params = default_params(mode)
    data = condition_data(batch, mask)
    lo_j, hi_j = jnp.asarray(lo), jnp.asarray(hi)
    if mode == "full":
        obj: AbstractObjective = FullObjective(model)
        s_lo, s_hi = lo_j, hi_j
    elif mode == "separable":
        nl = model.nonlinear_index
        obj = SeparableObjective(model, lo_j, hi_j, tuple(bool(v) for v in _log_flags(model, lo)[nl]))
        if nl.size == 0:
            # fully linear model: one exact solve, no swarm needed; run 1 generation anyway
            s_lo, s_hi = jnp.zeros((1,)), jnp.zeros((1,))
            obj = _LinearOnly(model, lo_j, hi_j)
        else:
            logs = _log_flags(model, lo)[nl]
            s_lo = jnp.asarray(np.where(logs, np.log(np.where(logs, lo[nl], 1.0)), lo[nl]))
            s_hi = jnp.asarray(np.where(logs, np.log(np.where(logs, hi[nl], 1.0)), hi[nl]))
    else:
        raise InputError(f"swarm mode must be 'separable' or 'full', got {mode!r}")
    res = swarm(obj, s_lo, s_hi, data, key=key, params=params, n_particles=n_particles,
                max_generations=max_generations, callback=callback, dtype=dtype)
    if dtype is None or jnp.dtype(dtype) == s_lo.dtype:
        theta = _to_params(obj, res.position, data)
        return ModelSwarm(theta=theta, rms=res.fitness, swarm=res, mode=mode)
    # low-precision swarm: parameters and RMS of its best positions in full precision
    theta, rms = _to_params_rms(obj, res.position.astype(s_lo.dtype), data)
    return ModelSwarm(theta=theta, rms=rms, swarm=res, mode=mode)


class _LinearOnly(AbstractObjective):
    """Separable objective of a model with no nonlinear parameter (Bingham)."""

    model: AbstractModel
    lower: Float[Array, " P"]
    upper: Float[Array, " P"]

    def __call__(self, position, data):
        th = 0.5 * (self.lower + self.upper)
        return solve_linear(self.model, th, data, self.lower, self.upper)[1]

    def to_params(self, position, data):
        th = 0.5 * (self.lower + self.upper)
        return solve_linear(self.model, th, data, self.lower, self.upper)[0]


@eqx.filter_jit
def _to_params(obj, position, data):
    return jax.vmap(obj.to_params)(position, data)


@eqx.filter_jit
def _to_params_rms(obj, position, data):
    return jax.vmap(obj.to_params)(position, data), jax.vmap(obj)(position, data)
