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
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from ._noise import log1m_tanh2
from ._priors import to_box
from ._start import linear_draw, log_density

#: Chains start at the mode plus this many starting standard deviations of noise (a start
#: with a non-finite log-density falls back onto the mode).
JITTER = 1.0
#: Default draws kept per chain, chains per unit and warmup steps per chain (see `Sampler`).
DRAWS, CHAINS, WARMUP = 1000, 4, 500
#: Default target acceptance rate of the step-size adaptation, by the model's kind (see
#: `Sampler.target_accept`).
TARGET_ACCEPT = {"static": 0.9, "dynamic": 0.8}
#: Default further rounds for the units that missed convergence (see `Sampler.continuations`),
#: and the highest target acceptance a continued unit that diverged is given.
CONTINUATIONS = 2
CONTINUED_TARGET = 0.995
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
        has little left to find (`benchmarks/posterior.md`).
    - `target_accept`: the step-size adaptation's target acceptance rate; None (default):
        `TARGET_ACCEPT` by the model (:meth:`for_model`): 0.9 for a static model (Stan: 0.8),
        whose parameters on short records are strongly correlated, so that smaller steps
        avoid divergent transitions at little cost; 0.8 for a dynamic model, whose every
        leapfrog step is an integration (`benchmarks/posterior.md`).
    - `max_doublings`: NUTS tree depth cap (at most 2^max_doublings - 1 leapfrog steps).
    - `dense_mass`: adapt a dense inverse mass matrix (default; the damper models' parameters
        trade off, e.g. modified Bouc-Wen's z-scale) or a diagonal one.
    - `vectorize`: `True` (or `"all"`) vmaps every chain of every unit into one batch;
        `"chains"` vmaps the chains of a unit and runs the units one after another; `False`
        (or `"none"`) runs every chain one after another with `lax.map`; all in one compiled
        program. `None` (default): `"all"` on an accelerator; on a CPU `"chains"` for a
        forward-mode gradient (a dynamic model: one sequential integration, whose small
        steps leave a CPU's vector units idle, so a batch of chains costs little more than
        one), else `"none"`: a vmapped NUTS step runs until the longest trajectory of its
        batch ends, so where one chain's residuals already fill the vector units (a static
        model on a record) the batch only adds work (`benchmarks/posterior.md`). With
        several CPU devices the chains of a unit are also spread over them
        (:func:`chain_devices`).
    - `continuations`: at most this many further rounds for the units whose chains missed
        R-hat <= `RHAT_MAX`, bulk or tail ESS >= `ESS_MIN`, or diverged: round r runs those
        units' chains again from the mode with 2^r x the warmup and 2^r x the draws, every
        2^r-th kept (same shape, about 2^r x the effective draws), and a target acceptance
        raised towards `CONTINUED_TARGET` where a unit diverged; what still misses is warned
        about (`Posterior.rounds` says how many rounds each unit took). 0: no continuation.
    - `thin`: keep every `thin`-th draw of `thin` x `draws` (the continuations set it).
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
    continuations: int = eqx.field(static=True, default=CONTINUATIONS)
    thin: int = eqx.field(static=True, default=1)

    def for_model(self, dynamic: bool) -> Sampler:
        """Self with `gradient` and `target_accept` chosen where they are None: `"forward"`
        for a dynamic model (one sequential integration, which reverse mode stores and
        replays), `"reverse"` for a static one; the target acceptance `TARGET_ACCEPT` of the
        model's kind."""
        kind = "dynamic" if dynamic else "static"
        return dataclasses.replace(
            self, gradient=self.gradient or ("forward" if dynamic else "reverse"),
            target_accept=TARGET_ACCEPT[kind] if self.target_accept is None
            else self.target_accept)

    def continued(self, round_: int, diverged: bool) -> Sampler:
        """The settings of continuation round `round_` (>= 1): 2^r x the warmup, the same kept
        draws thinned from 2^r x as many; where the unit diverged, the target acceptance moved
        towards 1, its distance to 1 divided by 4 per round (0.9 -> 0.975 -> 0.994), at most
        `CONTINUED_TARGET`: a curved posterior's divergences go only with a small step."""
        f = 2 ** int(round_)
        target = self.target_accept
        if diverged and target is not None:
            target = min(max(target, 1.0 - (1.0 - target) / 4.0 ** int(round_)),
                         max(target, CONTINUED_TARGET))
        return dataclasses.replace(self, warmup=self.warmup * f, thin=self.thin * f,
                                   target_accept=target)

    def check(self) -> Sampler:
        """Self, checked: :class:`mrjax.InputError` for a non-positive count or a target outside
        (0, 1)."""
        if isinstance(self.continuations, bool) or not isinstance(
                self.continuations, (int, np.integer)) or self.continuations < 0:
            raise InputError(f"continuations must be an integer >= 0, got "
                             f"{self.continuations!r}")
        for name in ("draws", "chains", "warmup", "max_doublings", "thin"):
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
#: The progress bar of the running sample, advanced from inside the compiled program.
BAR: list[Any] = [None]


def _tick_host(n):
    bar = BAR[0]
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

    def step(st, k):
        st, info = kernel.step(k, st)
        return st, (info.is_divergent, info.num_integration_steps, info.acceptance_rate)

    def one(st, ks):  # `thin` steps, the last kept: divergences and steps over all of them
        st, (div, n, acc) = jax.lax.scan(step, st, ks)
        out = (z0 + L @ st.position, st.logdensity, jnp.any(div), jnp.sum(n), jnp.mean(acc))
        if per_step:
            _tick(one_tick + 0 * n[-1])
        return st, out

    keys = jax.random.split(skey, sampler.draws * sampler.thin)
    last, trace = jax.lax.scan(one, state, keys.reshape(sampler.draws, sampler.thin,
                                                        *keys.shape[1:]))
    if progress and not per_step:
        _tick(sampler.draws + 0 * jnp.isnan(last.logdensity).astype(jnp.int32))
    return trace, params["step_size"], jnp.sum(warm_steps)


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
def run_chains(target, prior, sampler, progress, units, z0, L, keys):
    """Warmup and draws of every chain of every unit in one compiled program; the box map and
    the noise transforms applied in it (draws in SI units). Returns `(theta, sigma, rho,
    (lp, diverging, steps, accept), step_size, warmup_steps)`."""
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


