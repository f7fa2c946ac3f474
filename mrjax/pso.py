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
generations are the least exponential (one lucky initial particle can make them), so a first-W
estimate overstates $\lambda^{-1}$ and stops nearly every condition as soon as it may, at 2W: a
fixed budget in disguise. The running estimate uses every improvement seen and needs no
separate burn-in. `max_generations` caps every condition; `criterion=False` runs exactly
`max_generations` (for benchmarks).

**Separable mode.** Every model declares which parameters enter the force linearly. In
`"separable"` mode (variable projection, Golub & Pereyra 1973) the swarm searches only the
nonlinear parameters; each particle's linear parameters are the exact masked, column-scaled
linear least-squares solution, clipped to their bounds (the fitness is the RMS *after*
clipping, so a clipped particle is scored honestly).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PRNGKeyArray

from ._errors import InputError
from .models import check_box

__all__ = [
    "swarm",
    "PSOParams",
    "default_params",
    "stability",
    "MAX_WINDOW",
    "AbstractObjective",
    "SwarmProblem",
    "SwarmResult",
    # one generation at a time (the loop `swarm` runs): init, then ask / evaluate / tell
    "SwarmState",
    "init",
    "ask",
    "tell",
    "step",
]

# ------------------------------------------------------------------------------ hyperparameters


def _as(v, dtype):
    """A hyperparameter as an array of `dtype`: host values stay host arrays (no compilation),
    JAX arrays (e.g. traced under `vmap`) stay JAX arrays."""
    if isinstance(v, jax.Array):
        return v.astype(dtype) if v.dtype != dtype else v
    return np.asarray(v, dtype=dtype)


def _f(v):
    return _as(v, jax.dtypes.canonicalize_dtype(float))  # the default float (float64 under mrjax)


def _i(v):
    return _as(v, np.int32)


def _b(v):
    return _as(v, np.bool_)


class PSOParams(eqx.Module):
    """Swarm hyperparameters: *data*, not static arguments, so new values never recompile.

    **Fields:**

    - `inertia`: $\\omega$ (default 0.65, the paper's).
    - `c1_max`: bound of the group-best coefficient $c_1 \\sim U[0, c_{1,max}]$ (default 2).
    - `c2_max`: bound of the personal-best coefficient $c_2$ (default 2).
    - `confidence`: confidence of the statistical stop (default 0.905, the paper's).
    - `window`: generations W over which recent improvements are averaged (default 8;
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
    improvements for longer: a shorter window would stop it before it reaches the optimum's
    basin floor."""
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


class SwarmProblem(eqx.Module):
    """What C swarms minimise, one per condition: `objective` (an :class:`AbstractObjective`),
    the search box `lower`, `upper` (C, D) in the units of the positions, and `data` (a pytree
    whose leaves have a leading condition axis C)."""

    objective: AbstractObjective
    lower: Float[Array, "C D"]
    upper: Float[Array, "C D"]
    data: Any


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
    if isinstance(key, np.ndarray) and key.dtype == np.uint32 and key.ndim == 2:
        return jax.device_put(key)  # raw key data, one row per condition (no compilation)
    key = jnp.asarray(key) if not isinstance(key, jax.Array) else key
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        return jax.random.split(key, n) if key.ndim == 0 else key
    # raw uint32 keys: shape (2,) single or (n, 2)
    return jax.random.split(key, n) if key.ndim == 1 else key


def _sanitize(f):
    return jnp.where(jnp.isnan(f), jnp.inf, f)


def _evaluate(objective: AbstractObjective, position: Array, data: Any) -> Array:
    """Fitness of every particle of every condition, (C, N), NaN mapped to `inf`."""
    vmapped = jax.vmap(jax.vmap(objective, in_axes=(0, None)), in_axes=(0, 0))
    return _sanitize(vmapped(position, data).astype(position.dtype))


def _evaluate_paged(objective: AbstractObjective, position: Array, data: Any, active: Array,
                    page: int) -> Array:
    """Fitness (C, N) of the `active` conditions only, `page` conditions at a time; stopped
    conditions get `inf` (which :func:`tell` ignores: they are frozen).

    The active conditions are gathered into ceil(n_active / page) pages of one static shape,
    so the program is compiled once and a generation costs what its active conditions cost:
    when most of a batch of swarms has stopped, the few still searching no longer pay for the
    rest. A condition's fitness depends only on its own position and data, so the result is
    the one of :func:`_evaluate`.
    """
    C = position.shape[0]
    n_pages_max = -(-C // page)
    # active conditions first (stable: ascending index), padded with an out-of-range index
    order = jnp.argsort(~active, stable=True).astype(jnp.int32)
    order = jnp.concatenate([order, jnp.full((n_pages_max * page - C,), C, jnp.int32)])
    n_pages = (jnp.sum(active.astype(jnp.int32)) + page - 1) // page
    take = lambda a, idx: jnp.take(a, idx, axis=0, mode="clip")  # noqa: E731

    def one_page(i, f):
        idx = jax.lax.dynamic_slice(order, (i * page,), (page,))
        fp = _evaluate(objective, take(position, idx),
                       jax.tree.map(lambda a: take(a, idx), data))
        return f.at[idx].set(fp, mode="drop")  # the padding index C is dropped

    f0 = jnp.full(position.shape[:2], jnp.inf, position.dtype)
    return jax.lax.fori_loop(0, n_pages, one_page, f0)


def init(problem: SwarmProblem, keys: Any, *, n_particles: int,
         max_generations: int) -> SwarmState:
    """The initial state of C swarms: N particles uniform in each condition's box, zero
    velocity, evaluated once (generation 0).

    **Arguments:** `problem`; `keys` (C,) one PRNG key per condition; `n_particles` N and
    `max_generations` G (static: the history has G + 1 entries). Pure and jittable.
    """
    C, D = problem.lower.shape
    N, G = n_particles, max_generations

    def init_one(k, lo, hi):
        u = jax.random.uniform(jax.random.fold_in(k, 0), (N, D), dtype=lo.dtype)
        return lo + u * (hi - lo)

    pos = jax.vmap(init_one)(keys, problem.lower, problem.upper)
    fit = _evaluate(problem.objective, pos, problem.data)
    g = jnp.argmin(fit, axis=1)
    gpos = jnp.take_along_axis(pos, g[:, None, None], axis=1)[:, 0]
    gfit = jnp.min(fit, axis=1)
    return SwarmState(
        position=pos, velocity=jnp.zeros_like(pos), fitness=fit,
        pbest_position=pos, pbest_fitness=fit, gbest_position=gpos, gbest_fitness=gfit,
        generation=jnp.zeros((C,), jnp.int32), done=jnp.zeros((C,), bool),
        by_criterion=jnp.zeros((C,), bool), lambda_inv=jnp.zeros((C,), pos.dtype),
        improvements=jnp.zeros((C, MAX_WINDOW), pos.dtype),
        history=jnp.broadcast_to(gfit[:, None], (C, G + 1)), keys=keys,
    )


def ask(state: SwarmState, problem: SwarmProblem, params: PSOParams
        ) -> tuple[Float[Array, "C N D"], Float[Array, "C N D"]]:
    """The next positions and velocities (eq 9-10, absorbing walls), `(x, v)` each (C, N, D).

    $c_1, c_2$ are drawn per condition, particle and dimension from the condition's key and
    the generation number, so a condition's trajectory depends on its own key only.
    """
    pos = state.position
    N, D = pos.shape[1], pos.shape[2]
    gen = state.generation + 1  # generation being computed, per condition

    def draws(k, t):
        # r1 and r2 are the two 16-bit halves of one random 32-bit word: half the threefry
        # hashes of two separate draws (a large share of a cheap model's generation),
        # resolution 2^-16 on U[0, 1).
        bits = jax.random.bits(jax.random.fold_in(k, t), (N, D), jnp.uint32)
        scale = jnp.asarray(2.0**-16, pos.dtype)
        return ((bits & 0xFFFF).astype(pos.dtype) * scale,
                (bits >> 16).astype(pos.dtype) * scale)

    r1, r2 = jax.vmap(draws)(state.keys, gen)
    lower, upper = problem.lower, problem.upper
    c1 = params.c1_max * r1
    c2 = params.c2_max * r2
    vmax = (params.velocity_clamp * (upper - lower))[:, None, :]
    v = (params.inertia * state.velocity
         + c1 * (state.gbest_position[:, None, :] - pos)
         + c2 * (state.pbest_position - pos))
    v = jnp.clip(v, -vmax, vmax)
    x = pos + v
    lo, hi = lower[:, None, :], upper[:, None, :]
    out = (x < lo) | (x > hi)
    x = jnp.clip(x, lo, hi)
    return x, jnp.where(out, 0.0, v)


def tell(
    state: SwarmState,
    x: Float[Array, "C N D"],
    v: Float[Array, "C N D"],
    f: Float[Array, "C N"],
    params: PSOParams,
    *,
    max_generations: int,
) -> SwarmState:
    """Take the fitness `f` of positions `x` (velocities `v`): update the personal and group
    bests, the statistical stop and the history. Conditions already stopped stay frozen."""
    C = f.shape[0]
    G = max_generations
    W = params.window
    neglog = -jnp.log(params.confidence)
    s = state
    gen = s.generation + 1
    better = f < s.pbest_fitness
    pb_pos = jnp.where(better[..., None], x, s.pbest_position)
    pb_fit = jnp.where(better, f, s.pbest_fitness)
    j = jnp.argmin(pb_fit, axis=1)
    cand_fit = jnp.min(pb_fit, axis=1)
    cand_pos = jnp.take_along_axis(pb_pos, j[:, None, None], axis=1)[:, 0]
    gb = cand_fit < s.gbest_fitness
    g_fit = jnp.where(gb, cand_fit, s.gbest_fitness)
    g_pos = jnp.where(gb[:, None], cand_pos, s.gbest_position)
    # statistical stop: improvements ring buffer
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

    return jax.tree.map(keep, s, new)


def step(problem: SwarmProblem, state: SwarmState, params: PSOParams, *, max_generations: int,
         page_size: int | None = None) -> SwarmState:
    """One generation of every condition: :func:`ask`, evaluate, :func:`tell`. Pure and
    jittable; `params` must be in the swarm's float dtype (see :func:`swarm`). `page_size`
    (static): evaluate only the conditions still running, this many at a time (see
    :func:`swarm`); `None` evaluates all of them in one batch."""
    x, v = ask(state, problem, params)
    C = x.shape[0]
    if page_size is None or page_size >= C:
        f = _evaluate(problem.objective, x, problem.data)
    else:
        f = _evaluate_paged(problem.objective, x, problem.data, ~state.done, page_size)
    return tell(state, x, v, f, params, max_generations=max_generations)


@eqx.filter_jit
def _swarm(problem: SwarmProblem, keys, params: PSOParams, n_particles: int,
           max_generations: int, callback: Callable | None,
           page_size: int | None = None) -> SwarmResult:
    G = max_generations
    # hyperparameters in the swarm's dtype, so a float32 swarm is not promoted to float64
    dtype = problem.lower.dtype
    params = jax.tree.map(
        lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a, params)
    state = init(problem, keys, n_particles=n_particles, max_generations=G)

    def body(s: SwarmState) -> SwarmState:
        s = step(problem, s, params, max_generations=G, page_size=page_size)
        if callback is not None:
            jax.debug.callback(callback, s.generation, s.done, s.gbest_fitness, ordered=True)
        return s

    final = jax.lax.while_loop(lambda s: jnp.any(~s.done), body, state)
    return SwarmResult(
        position=final.gbest_position, fitness=final.gbest_fitness,
        generations=final.generation, stopped_by_criterion=final.by_criterion,
        history=final.history, lambda_inv=final.lambda_inv, n_particles=n_particles,
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
    page_size: int | None = None,
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
        XLA:CPU use twice the SIMD lanes and cheaper `exp`/`log`/`tanh` (a faster fitness, see
        `benchmarks/results.md`); the fitness then carries float32 rounding (relative 1e-6 on
        the RMS).
    - `page_size`: `None` (default) scores every condition every generation, also those
        already stopped (their result is discarded), in one batch. An integer K (static)
        scores only the conditions still running, K at a time: the swarms of one batch stop
        at different generations, and with pages the last few no longer pay for the rest. Each
        page is one batch of K conditions x N particles, so K should keep the vector units
        busy (e.g. a quarter of C); results do not depend on it.

    **Returns:** a :class:`SwarmResult`.
    """
    params = (params or PSOParams()).check()
    leaves = jax.tree.leaves(data)
    if not leaves:
        raise InputError("swarm data is empty")
    C = int(leaves[0].shape[0])
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    D = lower.shape[-1]
    lower = np.broadcast_to(lower, (C, D))
    upper = np.broadcast_to(upper, (C, D))
    check_box(lower, upper, what="swarm bounds")
    if n_particles < 1 or max_generations < 1:
        raise InputError("n_particles and max_generations must be at least 1")
    if page_size is not None and (isinstance(page_size, bool) or int(page_size) != page_size
                                  or page_size < 1):
        raise InputError(f"page_size must be a positive integer or None, got {page_size!r}")
    keys = _keys_for(key, C)
    if keys.shape[0] != C:
        raise InputError(f"key: got {keys.shape[0]} keys for {C} conditions; pass one key or "
                         f"one per condition")
    if dtype is not None:
        dtype = jnp.dtype(dtype)
        if not jnp.issubdtype(dtype, jnp.floating):
            raise InputError(f"swarm dtype must be a floating-point type, got {dtype}")
        objective, data = cast_floats((objective, data), dtype)
        lower, upper = lower.astype(dtype), upper.astype(dtype)
    lower, upper = jax.device_put((np.ascontiguousarray(lower), np.ascontiguousarray(upper)))
    return _swarm(SwarmProblem(objective, lower, upper, data), keys, params, int(n_particles),
                  int(max_generations), callback,
                  None if page_size is None or page_size >= C else int(page_size))


def cast_floats(tree: Any, dtype: Any) -> Any:
    """Cast the floating-point array leaves of a pytree (e.g. an objective module and its data)
    to `dtype` (how :func:`swarm` runs in float32); other leaves pass unchanged. Not part of
    the user API (`swarm(..., dtype=...)` is); the benchmarks use it."""

    def cast(a):
        if eqx.is_array(a) and jnp.issubdtype(a.dtype, jnp.floating) and a.dtype != dtype:
            return a.astype(dtype)
        return a

    return jax.tree.map(cast, tree)
