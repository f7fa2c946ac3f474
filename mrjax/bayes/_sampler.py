"""The one sampler of mrjax: NUTS (blackjax) on any problem kind's residual function.

A problem kind supplies a residual function of one *unit*'s unknowns (one condition of a
per-test fit; the whole data set of a joint-law fit),

    residual(theta (K,), unit_data) -> ((r (R1, T1), mask (R1, T1)), (r, mask), ...)

a tuple of blocks of records (rows) by samples, masked samples unscored, and the unknowns'
box. :func:`sample` builds one log-density per unit (the Gaussian likelihood of
`mrjax.bayes.block_loglik` with one noise level per record and, for `noise="ar1"`, one AR(1)
coefficient per unit; the priors of `mrjax.bayes.log_prior` through the bounded map
`to_box` with its log-Jacobian), adapts step size and mass matrix with
`blackjax.window_adaptation` (Stan's windows) from chains started around the posterior's mode
with an inverse mass matrix from the Hessian there (found by damped Newton from the polished
optimum, in the coordinates of the Gauss-Newton covariance of the residuals there; one
unknown held per direction the data leave undetermined), and draws with `blackjax.nuts` in a
`lax.scan`: every chain of every unit in one compiled program, like the swarm (mapped one
after another or a unit's chains at once on a CPU, vmapped on an accelerator: see
`Sampler.vectorize`).

The sampler's position is `z = [u (Kf), log s (R), v]`: `u` the unknowns it moves in the
bounded map (the free ones, less those held in every unit and the linear ones integrated out:
see `linear` in :func:`sample`); `log s` [log N] the records' noise levels, with `"ar1"`
those of the innovations,
$s = \\sigma \\sqrt{1 - \\rho^2}$ ($\\sigma$ the marginal level that is reported): on a real
record $\\rho \\to 1$ and the data fix $s$ tightly but $\\sigma$ only through each record's
first sample, so $(\\log\\sigma, v)$ is a long narrow ridge that NUTS crosses in hundreds of
steps, while $(\\log s, v)$ is not (the change is a shear: flat priors stay flat, Jeffreys'
for a scale); `v` with $\\rho = \\tanh v$ (`"ar1"` only; uniform prior on
$\\rho \\in (-1, 1)$).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from ._noise import check_noise, log1m_tanh2
from ._priors import box_slope, check_priors, prior_arrays, to_box
from ._result import Posterior
from ._start import (
    GRADIENT_TOL,
    Target,
    Unit,
    collapsible,
    find_mode,
    gradient_error,
    laplace,
    linear_draw,
    log_density,
    start,
    to_log,
)

#: Chains start at the mode plus this many starting standard deviations of noise (a start
#: with a non-finite log-density falls back onto the mode).
JITTER = 1.0
#: Default draws kept per chain, chains per unit and warmup steps per chain (see `Sampler`).
DRAWS, CHAINS, WARMUP = 1000, 4, 500
#: Default target acceptance rate of the step-size adaptation, by the model's kind (see
#: `Sampler.target_accept`).
TARGET_ACCEPT = {"static": 0.9, "dynamic": 0.8}
#: Draws whose linear unknowns (integrated out of the log-density) are drawn side by side.
LINEAR_BATCH = 64
#: What `Sampler.vectorize` may name: every chain of every unit in one batch, the chains of
#: one unit at a time, or none (one chain after another).
VECTORIZE: tuple[str, ...] = ("all", "chains", "none")


class Sampler(eqx.Module):
    """Settings of the NUTS sampler (all static: a new value compiles a new program).

    **Fields:**

    - `draws`: draws kept per chain (after warmup).
    - `chains`: independent chains per unit.
    - `warmup`: adaptation steps per chain (Stan's windows: step size, then mass matrix).
        `WARMUP` = 500 (Stan: 1,000, for chains started anywhere): the chains start at the
        posterior's mode with the inverse of its Hessian as mass matrix, and the adaptation
        has little left to find. Modified Bouc-Wen (UTFSM 10mm1Hz0x5A, AR(1)): 500 against
        1,000 steps, 115.7 against 157.7 s, bulk / tail ESS 2,180 / 1,058 against
        2,867 / 1,238; the calibration sets: `benchmarks/posterior.md`.
    - `target_accept`: the step-size adaptation's target acceptance rate; None (default):
        `TARGET_ACCEPT` by the model (:meth:`for_model`). A static model 0.9 (Stan: 0.8):
        the tanh model on short records (2 cycles, 4 mm) has correlated posteriors (c, k,
        alpha, beta to 0.9); on the 50 such records of the calibration, through the soft box
        (`mrjax.bayes.to_box`), 0.8 gave 1 divergent transition in 200,000 draws, 0.9 none,
        for 6.7 leapfrog steps per draw. A dynamic model 0.8: in log coordinates with its
        linear parameters integrated out, modified Bouc-Wen (UTFSM 10mm1Hz0x5A, AR(1), 1,000
        warmup steps) took 25.4k gradients per device against 32.1k at 0.9, for a bulk / tail
        ESS of 2,867 / 1,238 against 2,179 / 1,183.
    - `max_doublings`: NUTS tree depth cap (at most 2^max_doublings - 1 leapfrog steps).
    - `dense_mass`: adapt a dense inverse mass matrix (default; the damper models' parameters
        trade off, e.g. modified Bouc-Wen's z-scale) or a diagonal one.
    - `vectorize`: `True` (or `"all"`) vmaps every chain of every unit into one batch;
        `"chains"` vmaps the chains of a unit and runs the units one after another; `False`
        (or `"none"`) runs every chain one after another with `lax.map`; all in one compiled
        program. `None` (default): `"all"` on an accelerator; on a CPU `"chains"` for a
        forward-mode gradient (a dynamic model: one sequential integration, whose small
        steps leave a CPU's vector units idle, so a batch of chains costs little more than
        one: modified Bouc-Wen on a UTFSM view, 4 gradients 18 ms batched against 4 x 7.8 ms),
        else `"none"`. A vmapped NUTS step runs until the longest trajectory of its batch
        ends, so where one chain's residuals already fill the vector units (tanh on a record)
        the batch only adds work: tanh on the 30 UTFSM tests, 4 chains x 200 steps on the
        swarm's views, 7.0 s vmapped against 1.7 s mapped (warm), and its compilation 12.6 s
        against 5.9 s (`benchmarks/posterior.md`). With several CPU devices the chains of a
        unit are also spread over them (:func:`chain_devices`).
    - `gradient`: how the residuals are differentiated: `"reverse"` or `"forward"` (their
        Jacobian by `jax.jacfwd`, then transposed: cheaper through a sequential integration,
        e.g. the dynamic models). `None` (default): `mrjax.posterior` chooses forward mode for
        a dynamic model and reverse mode for a static one (:meth:`for_model`); `sample` alone,
        reverse mode.
    """

    draws: int = eqx.field(static=True, default=DRAWS)
    chains: int = eqx.field(static=True, default=CHAINS)
    warmup: int = eqx.field(static=True, default=WARMUP)
    target_accept: float | None = eqx.field(static=True, default=None)
    max_doublings: int = eqx.field(static=True, default=10)
    dense_mass: bool = eqx.field(static=True, default=True)
    vectorize: bool | str | None = eqx.field(static=True, default=None)
    gradient: str | None = eqx.field(static=True, default=None)

    def for_model(self, dynamic: bool) -> Sampler:
        """Self with `gradient` and `target_accept` chosen where they are None: `"forward"`
        for a dynamic model (one sequential integration: modified Bouc-Wen on a UTFSM view, one
        gradient costs 1.9 log-density evaluations forward and 5.9 reverse), `"reverse"` for
        a static one; the target acceptance `TARGET_ACCEPT` of the model's kind."""
        kind = "dynamic" if dynamic else "static"
        return dataclasses.replace(
            self, gradient=self.gradient or ("forward" if dynamic else "reverse"),
            target_accept=TARGET_ACCEPT[kind] if self.target_accept is None
            else self.target_accept)

    def check(self) -> Sampler:
        """Self, checked: :class:`mrjax.InputError` for a non-positive count or a target outside
        (0, 1)."""
        for name in ("draws", "chains", "warmup", "max_doublings"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise InputError(f"{name} must be a positive integer, got {v!r}")
        if self.target_accept is not None and not 0.0 < float(self.target_accept) < 1.0:
            raise InputError(f"target_accept must be in (0, 1), got {self.target_accept!r}")
        if self.vectorize not in (None, True, False, *VECTORIZE):
            raise InputError(f"vectorize must be None, True, False or one of "
                             f"{', '.join(VECTORIZE)}, got {self.vectorize!r}")
        if self.gradient not in (None, "reverse", "forward"):
            raise InputError(f"gradient must be None, 'reverse' or 'forward', got "
                             f"{self.gradient!r}")
        return self


# ------------------------------------------------------------------------------ progress
_BAR: list[Any] = [None]


def _tick_host(n):
    bar = _BAR[0]
    if bar is not None:
        bar.update(int(np.ravel(n)[0]))


def _tick(n):
    """Advance the progress bar by `n` steps of one chain: a `jax.debug.callback` (an effect:
    never removed as dead code; under vmap and on each device it runs once per chain)."""
    jax.debug.callback(_tick_host, n)


def vectorized(sampler: Sampler) -> str:
    """What is vmapped, `"all"`, `"chains"` or `"none"` (see `Sampler.vectorize`)."""
    v = sampler.vectorize
    if v is None:
        if jax.default_backend() != "cpu":
            return "all"
        return "chains" if sampler.gradient == "forward" else "none"
    return {True: "all", False: "none"}.get(v, v) if isinstance(v, bool) else str(v)


# ------------------------------------------------------------------------------ the program
def _chain(target, prior, sampler: Sampler, progress: bool, unit, z0, L, key):
    """Warmup then sampling of one chain of one unit (batched at the call site), in the
    whitened coordinates `w` with `z = z0 + L w` (see :func:`sample`). The progress bar
    advances every step of every chain when chains are vmapped, else once per phase (a host
    call per step would cost more than a step of a static model)."""
    import blackjax  # imported here: `import mrjax` does not need it

    logdensity = lambda w: log_density(target, prior, unit, z0 + L @ w)
    jkey, wkey, skey = jax.random.split(key, 3)
    w_try = JITTER * jax.random.normal(jkey, z0.shape, z0.dtype)
    w_start = jnp.where(jnp.isfinite(logdensity(w_try)), w_try, jnp.zeros_like(w_try))
    per_step = progress and vectorized(sampler) != "none"
    one_tick = jnp.ones((), jnp.int32)

    def info_fn(state, info, ad):
        if per_step:
            _tick(one_tick + 0 * info.num_integration_steps)
        return info.num_integration_steps  # the warmup's cost, step by step

    warmup = blackjax.window_adaptation(
        blackjax.nuts, logdensity, is_mass_matrix_diagonal=not sampler.dense_mass,
        target_acceptance_rate=sampler.target_accept, adaptation_info_fn=info_fn,
        max_num_doublings=sampler.max_doublings)
    (state, params), warm_steps = warmup.run(wkey, w_start, num_steps=sampler.warmup)
    if progress and not per_step:  # after the warmup: it depends on its final state
        _tick(sampler.warmup + 0 * jnp.isnan(state.logdensity).astype(jnp.int32))
    kernel = blackjax.nuts(logdensity, **params)

    def one(st, k):
        st, info = kernel.step(k, st)
        out = (z0 + L @ st.position, st.logdensity, info.is_divergent,
               info.num_integration_steps, info.acceptance_rate)
        if per_step:
            _tick(one_tick + 0 * info.num_integration_steps)
        return st, out

    last, trace = jax.lax.scan(one, state, jax.random.split(skey, sampler.draws))
    if progress and not per_step:
        _tick(sampler.draws + 0 * jnp.isnan(last.logdensity).astype(jnp.int32))
    return trace, params["step_size"], warm_steps


def chain_devices(sampler: Sampler) -> int:
    """Over how many devices a unit's chains are spread (1: none): with several CPU devices
    (`jax.config.update("jax_num_cpu_devices", n)` or `JAX_NUM_CPU_DEVICES=n` before JAX
    starts; the `mrjax` command sets it for a posterior) and `vectorize` other than `"all"`,
    the most that divide `chains`; each device runs its share of the chains on its own core,
    its trajectories no longer waiting for the longest of a vmapped batch."""
    n = jax.local_device_count()
    if n < 2 or jax.default_backend() != "cpu" or vectorized(sampler) == "all":
        return 1
    return max(d for d in range(1, min(n, sampler.chains) + 1) if sampler.chains % d == 0)


@eqx.filter_jit
def _run(target, prior, sampler, progress, units, z0, L, keys):
    chain = lambda unit, z, m, k: _chain(target, prior, sampler, progress, unit, z, m, k)
    mode = vectorized(sampler)
    over_chains = jax.vmap(chain, in_axes=(None, None, None, 0))
    if mode == "none":  # one chain after another, in the same compiled program
        over_chains = lambda u, z, m, ks: jax.lax.map(lambda k: chain(u, z, m, k), ks)
    n_dev = chain_devices(sampler)
    if n_dev > 1:  # the chains of a unit spread over the CPU devices, one share each
        from jax.sharding import Mesh, PartitionSpec

        mesh = Mesh(np.asarray(jax.local_devices()[:n_dev]), ("chain",))
        over_chains = jax.shard_map(over_chains, mesh=mesh, in_specs=(
            PartitionSpec(), PartitionSpec(), PartitionSpec(), PartitionSpec("chain")),
            out_specs=PartitionSpec("chain"), check_vma=False)
    if mode == "all":  # one batch of units x chains
        trace, step, warm = jax.vmap(over_chains)(units, z0, L, keys)
    else:  # one unit after another
        trace, step, warm = jax.lax.map(lambda a: over_chains(*a), (units, z0, L, keys))
    # the box map and the noise transforms, in the program: draws come back in SI units
    free = np.asarray(target.free, int)
    Kf, R = len(free), sum(target.rows)
    z = trace[0]
    th = to_box(z[..., :Kf], *(a[:, None, None, :] for a in (units.lo, units.hi, units.soft,
                                                               units.log)))
    theta = jnp.broadcast_to(units.theta[:, None, None, :],
                             z.shape[:3] + units.theta.shape[-1:])
    theta = theta.at[..., free].set(th)
    if target.linear:  # the unknowns integrated out: drawn from their conditional at each draw
        def draws(unit, zu, k):
            flat = zu.reshape(-1, zu.shape[-1])
            ks = jax.random.split(k, flat.shape[0])
            out = jax.lax.map(lambda a: linear_draw(target, prior, unit, *a), (flat, ks),
                              batch_size=LINEAR_BATCH)
            return out.reshape(zu.shape[:-1] + out.shape[-1:])

        lin_keys = jax.vmap(lambda k: jax.random.fold_in(k[0], 1))(keys)
        beta = jax.lax.map(lambda a: draws(*a), (units, z, lin_keys))
        theta = theta.at[..., np.asarray(target.linear, int)].set(beta)
    log_sigma = z[..., Kf:Kf + R]
    rho = None
    if target.noise == "ar1":
        v = z[..., Kf + R]
        log_sigma, rho = log_sigma - 0.5 * log1m_tanh2(v)[..., None], jnp.tanh(v)
    return theta, jnp.exp(log_sigma), rho, trace[1:], step, warm


# ------------------------------------------------------------------------------ entry point
def sample(
    residual: Callable,
    theta0: ArrayLike,
    data: Any,
    *,
    lower: ArrayLike,
    upper: ArrayLike,
    names: Sequence[str],
    labels: Sequence[str] | None = None,
    row_labels: Sequence[str] | None = None,
    sampler: Sampler | None = None,
    noise: str = "iid",
    prior: Mapping[str, Any] | None = None,
    key: Any = None,
    seed: int = 0,
    progress: bool | None = False,
    unit_dim: str = "condition",
    units: Sequence[str] | None = None,
    gauge: Sequence[str] = (),
    exact: Callable | None = None,
    linear: Sequence[str] = (),
) -> Posterior:
    """Sample the posterior of a residual function's unknowns with NUTS, on every unit at once.

    **Arguments:**

    - `residual`: `residual(theta (K,), unit_data) -> ((r, mask), ...)`, a tuple of blocks of
        residuals [N] and scored-sample masks, each (R_b, T_b) records by samples; jittable,
        written for one unit (it is vmapped); hashable (an `eqx.Module` or a module-level
        function, so that a second call reuses the compiled program).
    - `theta0`: (U, K) the polished optimum of each unit, SI units: the chains start around it.
    - `data`: pytree whose leaves have a leading unit axis U.
    - `lower`, `upper`: (K,) or (U, K) the box of the unknowns (the fit's bounds), SI units;
        a parameter with `lower == upper` everywhere is held fixed.
    - `names`: (K,) the unknowns' names (the posterior's variables).
    - `labels`: (U,) unit labels (coordinates of `unit_dim`); default `"0"`, `"1"`, ...
    - `row_labels`: names of the R records of a unit (coordinates of `noise_sigma`'s `record`
        dim where R > 1).
    - `sampler`: :class:`Sampler` settings (draws, chains, warmup, ...).
    - `noise`: `"iid"` or `"ar1"` (see `mrjax.bayes.block_loglik`).
    - `prior`: {name: prior} (see `mrjax.bayes.parse_prior`); default flat on the box.
    - `key`: JAX PRNG key (default `jax.random.key(seed)`); each unit's chains use
        `fold_in(key, unit index)`: same key, same draws.
    - `progress`: a tqdm bar over warmup + draws (None: only on a TTY).
    - `unit_dim`: the name of the unit dimension in the posterior (`"condition"`).
    - `units`: (K,) SI units of the unknowns, for the tables.
    - `gauge`: names of the unknowns to hold first where the data leave a direction
        undetermined (see below), e.g. `("delta",)` for the Bouc-Wen models' z scale.
    - `exact`: where `residual`'s derivatives are an approximation (the L-stable scheme's
        implicit tangent), the same residual function with exact ones: the sampler checks
        the approximation around the posterior's mode against central differences of the
        log-density (:func:`mrjax.bayes._start.gradient_error`) and, where the whitened
        gradient is off by more than `GRADIENT_TOL`, searches the mode again and samples with `exact`
        (`Posterior.gradient_error`; modified Bouc-Wen on UTFSM test 25mm0x1Hz1A: up to
        12,000, and its step size fell to 3e-5 with every tree at 1,023 steps; 0.007 on
        10mm1Hz0x5A, which keeps the cheaper implicit tangent).
    - `linear`: names of unknowns the residuals are affine in, with a regressor that no
        unknown changes (a model's `fixed_params`, e.g. the force offset `f0`). Where their
        prior is flat and the posterior's mode lies well inside their box in every unit
        (:func:`mrjax.bayes._start.collapsible`, which also checks the regressor), the
        log-density integrates them out in closed form (:func:`mrjax.bayes.linear_marginal`)
        and each draw's are drawn from their Gaussian conditional: fewer dimensions for NUTS,
        and no funnel of an offset against the AR(1) coefficient. The draws are those of the
        same posterior. `Posterior.linear` names them.

    The start is built from `theta0` and the Gauss-Newton covariance of the residuals there
    (Jacobian by forward mode, on the likelihood's own data). Where that covariance spans more
    than the box in some direction of the unknowns (a symmetry of the model, or an unknown
    these records do not inform), one unknown per such direction is held at `theta0` in that
    unit (its `lower == upper` in the result, listed by `Posterior.problems`): the others'
    posterior is conditional on it. A damped Newton search (`_start.MODE_STEPS`) then moves the start
    from `theta0`, the least-squares optimum of the fit's data, to the mode of this posterior
    (the noise model, the prior and the soft box move it), and the chains start around the
    mode with the inverse of the log-density's Hessian there as their mass matrix (modified
    Bouc-Wen on a UTFSM view with AR(1) noise: the start was 670 log-density units below the
    mode, and 150 warmup steps of one chain took 69,114 gradients from it, 3,090 from the
    mode). `Posterior.timings["mode"]` is its time [s].

    **Returns:** a :class:`mrjax.bayes.Posterior`.

    Raises :class:`mrjax.InputError` for bad settings, an unknown noise model or prior, or
    shapes that do not match.
    """
    # a gradient left None: reverse mode (mrjax.posterior has chosen for its model)
    sampler = (sampler or Sampler()).check().for_model(False)
    noise = check_noise(noise)
    names = tuple(str(n) for n in names)
    K = len(names)
    theta0 = np.asarray(theta0, float)
    if theta0.ndim != 2 or theta0.shape[1] != K:
        raise InputError(f"theta0 must be (units, {K}), got shape {theta0.shape}")
    U = theta0.shape[0]
    lo = np.broadcast_to(np.asarray(lower, float), (U, K))
    hi = np.broadcast_to(np.asarray(upper, float), (U, K))
    if np.any(~np.isfinite(lo)) or np.any(~np.isfinite(hi)) or np.any(lo > hi):
        raise InputError("the box of the unknowns must be finite with lower <= upper")
    if not np.all(np.isfinite(theta0)):
        raise InputError("the optimum theta0 must be finite")
    priors = check_priors(prior, names)
    kind, a, b, lo, hi = prior_arrays(priors, names, lo, hi)
    theta0 = np.clip(theta0, lo, hi)
    free = tuple(int(j) for j in np.flatnonzero(np.any(hi > lo, axis=0)))
    if not free:
        raise InputError("no free unknowns: every lower bound equals its upper bound")
    labels = tuple(str(s) for s in labels) if labels is not None else tuple(map(str, range(U)))
    if len(labels) != U:
        raise InputError(f"{len(labels)} labels for {U} units")
    shapes = jax.eval_shape(residual, jnp.asarray(theta0[0]),
                            jax.tree.map(lambda x: x[0], data))
    rows = tuple(int(s[0].shape[0]) for s in shapes)
    st = start(residual, theta0, lo[:, free], hi[:, free], data, free, noise, names,
               tuple(gauge))
    lo, hi = lo.copy(), hi.copy()
    lo[:, free], hi[:, free] = st.lo, st.hi
    # an unknown held in every unit is no unknown of the sampler: neither a dimension nor a
    # forward-mode tangent (modified Bouc-Wen: delta and gamma, 2 of 10)
    Kf = len(free)
    every = [k for k in range(Kf) if not st.held[:, k].all()]
    keep = np.concatenate([every, np.arange(Kf, st.z0.shape[1])]).astype(int)
    # the sampler runs in whitened coordinates w, z = z0 + L w with L L^T the starting
    # covariance: every w is O(1), so Stan's regularisation of the adapted mass matrix
    # (towards 1e-3 I) does not swamp unknowns whose posterior spans 1e-4 of their box
    z0, L = st.z0[:, keep], np.linalg.cholesky(st.imm[:, keep][:, :, keep])
    prior_data = (jnp.asarray(kind), jnp.asarray(a), jnp.asarray(b))
    start_z, start_L, start_st = z0, L, st
    t0 = time.perf_counter()

    def prepare(residual_fn):
        """From the start: the mode (a damped Newton search: the polished optimum is the
        least-squares one on the fit's data, not the mode of this posterior; the Hessian there
        replaces the Gauss-Newton metric), then the log coordinates and the linear unknowns
        integrated out, both decided there. Returns `(target, units, z0, L)`."""
        st = start_st
        t = Target(residual=residual_fn, free=tuple(free[k] for k in every), rows=rows,
                   noise=noise, forward=sampler.gradient == "forward")

        def arrays(moved, lin):
            return Unit(data=data, lo=jnp.asarray(st.lo[:, moved]),
                        hi=jnp.asarray(st.hi[:, moved]), soft=jnp.asarray(st.soft[:, moved]),
                        log=jnp.asarray(st.log[:, moved]), theta=jnp.asarray(theta0),
                        regressors=tuple(jnp.asarray(J[..., lin]) for J in st.jacobians),
                        masks=tuple(jnp.asarray(m) for m in st.masks))

        units_t = arrays(every, [])
        z, m = laplace(*jax.device_get(find_mode(t, prior_data, units_t, jnp.asarray(start_z),
                                                 jnp.asarray(start_L))), start_z, start_L)
        Km = len(every)
        cov = m @ np.swapaxes(m, 1, 2)
        with np.errstate(invalid="ignore"):
            sd_u = np.full((U, Kf), np.nan)
            sd_u[:, every] = np.sqrt(np.diagonal(cov, axis1=1, axis2=2)[:, :Km])
        u_mode = np.zeros((U, Kf))
        u_mode[:, every] = z[:, :Km]
        centre = np.asarray(to_box(u_mode, st.lo, st.hi, st.soft, st.log))
        sd = sd_u * box_slope(u_mode, st.lo, st.hi, st.soft, st.log)
        # positive unknowns far above 0 at the mode: log coordinates from here
        st, z, cov = to_log(st, z, cov, every, centre, sd)
        # linear unknowns well inside their box at the mode: integrated out, the others'
        # start the mode's (the marginal of its Gaussian approximation)
        lin = collapsible(residual, theta0, data, free, st, kind,
                          [names.index(n) for n in linear if n in names], centre, sd)
        moved = [k for k in every if k not in lin]
        keep = np.concatenate([[every.index(k) for k in moved],
                               np.arange(Km, z.shape[1])]).astype(int)
        t = dataclasses.replace(t, free=tuple(free[k] for k in moved),
                                linear=tuple(free[k] for k in lin))
        return (t, arrays(moved, lin), z[:, keep],
                np.linalg.cholesky(cov[:, keep][:, :, keep]))

    target, units_data, z0, L = prepare(residual)
    grad_error = None
    if exact is not None:  # an approximate derivative, kept where it is close around the mode
        grad_error = float(gradient_error(target, prior_data, units_data, jnp.asarray(z0),
                                          jnp.asarray(L)))
        if not grad_error <= GRADIENT_TOL:
            # all again from the start, exactly: the approximate gradient's "mode" may be far
            # from the posterior's (UTFSM 25mm0x1Hz1A: from there, trees of 1,023 steps)
            target, units_data, z0, L = prepare(exact)
    t_mode = time.perf_counter() - t0
    if key is None:
        key = jax.random.key(int(seed))
    keys = jax.vmap(lambda i: jax.random.split(jax.random.fold_in(key, i), sampler.chains))(
        jnp.arange(U))
    show = sys.stderr.isatty() if progress is None else bool(progress)
    t0 = time.perf_counter()
    bar = None
    if show:
        from tqdm.auto import tqdm  # imported here: only a shown bar needs it

        total = (sampler.warmup + sampler.draws) * U * sampler.chains
        bar = tqdm(total=total, desc="posterior (warmup + draws, all chains)", unit="step",
                   leave=False, file=sys.stderr)
        _BAR[0] = bar
    try:
        out = _run(target, prior_data, sampler, show, units_data, jnp.asarray(z0),
                   jnp.asarray(L), keys)
        out = jax.block_until_ready(out)
    finally:
        _BAR[0] = None
        if bar is not None:
            bar.close()
    theta, sigma, rho, (lp, div, steps, acc), step_size, warm_steps = out
    wall = time.perf_counter() - t0 + t_mode
    desc = {n: p.describe() for n, p in priors.items()}
    return Posterior(
        names=names, labels=labels, row_labels=None if row_labels is None else
        tuple(map(str, row_labels)), unit_dim=unit_dim,
        theta=np.asarray(theta), sigma=np.asarray(sigma),
        rho=None if rho is None else np.asarray(rho), lp=np.asarray(lp),
        diverging=np.asarray(div, bool), n_steps=np.asarray(steps, int),
        accept=np.asarray(acc, float), step_size=np.asarray(step_size, float),
        warmup_steps=np.asarray(warm_steps, int), gradient_error=grad_error,
        linear=tuple(names[j] for j in target.linear),
        theta0=theta0, lower=lo, upper=hi, free=np.isin(np.arange(K), free), noise=noise,
        prior=desc, sampler=sampler, seed=int(seed), timings={"sample": wall, "mode": t_mode},
        param_units=None if units is None else tuple(units))
