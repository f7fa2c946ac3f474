"""The chains of the one sampler: the only module of mrjax that calls blackjax.

Two kernels draw from the log-density of :func:`mrjax.bayes._start.log_density`, in the
whitened coordinates `w` of each unit (`z = z0 + L w`, `L L^T` the covariance at the
posterior's mode; see `mrjax.bayes.sample`):

- :func:`run_chains`, NUTS (`blackjax.window_adaptation` + `blackjax.nuts`): every chain its
    own step size, mass matrix and trajectories; chains and units mapped or vmapped
    (`Sampler.vectorize`);
- :func:`warm_lockstep` then :func:`extend_lockstep`, ChEES-HMC (`blackjax.chees_adaptation`
    + `blackjax.dynamic_hmc`): the chains of a unit share one step size and one jittered
    trajectory length, tuned from all of them at once, so that every chain of every unit of
    a page takes the same number of leapfrog steps at each draw and one vmapped batch
    advances them all without waiting for a longest tree. The mass matrix of each unit is
    re-estimated from its chains during the warmup (the coordinates re-whitened by their
    covariance); :func:`extend_lockstep` draws from where the warmup or earlier draws
    stopped.

Both return the draws in SI units (the box map, the noise transforms and the draws of the
unknowns integrated out applied in the program, :func:`to_si`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._noise import log1m_tanh2
from ._priors import to_box
from ._sampler import JITTER, LINEAR_BATCH, Sampler, tick, vectorized
from ._start import linear_draw, log_density


# ------------------------------------------------------------------------------ NUTS
def _chain(target, prior, sampler: Sampler, progress: bool, unit, z0, L, key):
    """Warmup then sampling of one chain of one unit (batched at the call site), in the
    whitened coordinates `w` with `z = z0 + L w` (see `mrjax.bayes.sample`). The progress bar
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
            tick(one_tick + 0 * info.num_integration_steps)
        return info.num_integration_steps  # the warmup's cost, step by step

    warmup = blackjax.window_adaptation(
        blackjax.nuts, logdensity, is_mass_matrix_diagonal=not sampler.dense_mass,
        target_acceptance_rate=sampler.target_accept, adaptation_info_fn=info_fn,
        max_num_doublings=sampler.max_doublings)
    (state, params), warm_steps = warmup.run(wkey, w_start, num_steps=sampler.warmup)
    if progress and not per_step:  # after the warmup: it depends on its final state
        tick(sampler.warmup + 0 * jnp.isnan(state.logdensity).astype(jnp.int32))
    kernel = blackjax.nuts(logdensity, **params)

    def step(st, k):
        st, info = kernel.step(k, st)
        return st, (info.is_divergent, info.num_integration_steps, info.acceptance_rate)

    def one(st, ks):  # `thin` steps, the last kept: divergences and steps over all of them
        st, (div, n, acc) = jax.lax.scan(step, st, ks)
        out = (z0 + L @ st.position, st.logdensity, jnp.any(div), jnp.sum(n), jnp.mean(acc))
        if per_step:
            tick(one_tick + 0 * n[-1])
        return st, out

    keys = jax.random.split(skey, sampler.draws * sampler.thin)
    last, trace = jax.lax.scan(one, state, keys.reshape(sampler.draws, sampler.thin,
                                                        *keys.shape[1:]))
    if progress and not per_step:
        tick(sampler.draws + 0 * jnp.isnan(last.logdensity).astype(jnp.int32))
    return trace, params["step_size"], jnp.sum(warm_steps)


@eqx.filter_jit
def run_chains(target, prior, sampler, progress, units, z0, L, keys):
    """NUTS: warmup and draws of every chain of every unit in one compiled program; the box
    map and the noise transforms applied in it (draws in SI units). Returns `(theta, sigma,
    rho, (lp, diverging, steps, accept), step_size, warmup_steps)`."""
    chain = lambda unit, z, m, k: _chain(target, prior, sampler, progress, unit, z, m, k)
    mode = vectorized(sampler)
    over_chains = jax.vmap(chain, in_axes=(None, None, None, 0))
    if mode == "none":  # one chain after another, in the same compiled program
        over_chains = lambda u, z, m, ks: jax.lax.map(lambda k: chain(u, z, m, k), ks)
    if mode == "all":  # one batch of units x chains
        trace, step, warm = jax.vmap(over_chains)(units, z0, L, keys)
    else:  # one unit after another
        trace, step, warm = jax.lax.map(lambda a: over_chains(*a), (units, z0, L, keys))
    return (*to_si(target, prior, units, trace[0], keys), trace[1:], step, warm)


def to_si(target, prior, units, z, keys):
    """The draws `z` (U, C, N, D) of the sampler's coordinates in SI units, in the program:
    `(theta (U, C, N, K), sigma (U, C, N, R), rho (U, C, N) or None)`; the unknowns integrated
    out drawn from their conditional at each draw (each chain's from its key in `keys` (U, C):
    the same draws however a unit's chains are shared out)."""
    free = np.asarray(target.free, int)
    Kf, R = len(free), sum(target.rows)
    th = to_box(z[..., :Kf], *(a[:, None, None, :] for a in (units.lo, units.hi, units.soft,
                                                               units.log)))
    theta = jnp.broadcast_to(units.theta[:, None, None, :],
                             z.shape[:3] + units.theta.shape[-1:])
    theta = theta.at[..., free].set(th)
    if target.linear:  # the unknowns integrated out: drawn from their conditional at each draw
        def draws(unit, zu, kc):
            flat = zu.reshape(-1, zu.shape[-1])
            ks = jax.vmap(lambda k: jax.random.split(jax.random.fold_in(k, 1), zu.shape[1]))(kc)
            out = jax.lax.map(lambda a: linear_draw(target, prior, unit, *a),
                              (flat, ks.reshape(flat.shape[0], *ks.shape[2:])),
                              batch_size=LINEAR_BATCH)
            return out.reshape(zu.shape[:-1] + out.shape[-1:])

        beta = jax.lax.map(lambda a: draws(*a), (units, z, keys))
        theta = theta.at[..., np.asarray(target.linear, int)].set(beta)
    log_sigma = z[..., Kf:Kf + R]
    rho = None
    if target.noise == "ar1":
        v = z[..., Kf + R]
        log_sigma, rho = log_sigma - 0.5 * log1m_tanh2(v)[..., None], jnp.tanh(v)
    return theta, jnp.exp(log_sigma), rho


# ------------------------------------------------------------------------------ ChEES
#: Bits of the Halton sequence that jitters the trajectory lengths (its period: 2^bits draws).
HALTON_BITS = 20
#: The warmup's windows, as fractions of `Sampler.warmup`: after each but the last, the unit's
#: coordinates are re-whitened by the covariance of its chains' positions over the window's
#: second half (a dense mass matrix per unit); the last window tunes step size and
#: trajectory length in the final coordinates.
WINDOWS = (0.2, 0.3, 0.5)
#: The re-whitening's covariance is shrunk towards the current metric (the identity in the
#: current coordinates) with this many pseudo-draws.
SHRINK = 10.0
#: Weight of warmup step t in the moving averages of the step size and trajectory length
#: that the draws use: t^-DECAY (blackjax's default).
DECAY = 0.5
#: Step size the first window's dual averaging starts from (whitened coordinates: the
#: posterior spans O(1) in every direction).
FIRST_STEP = 0.5


class LockstepState(eqx.Module):
    """Where a unit's ChEES chains stopped (batched over units), to continue them: the
    coordinates `z0` (D,), `L` (D, D), each chain's `position` (C, D) in them, its log-density,
    gradient and jitter counter `arg`, and the adapted `step_size` and mean leapfrog steps
    `n_leapfrog`."""

    z0: jax.Array
    L: jax.Array
    position: jax.Array
    logdensity: jax.Array
    grad: jax.Array
    arg: jax.Array
    step_size: jax.Array
    n_leapfrog: jax.Array


def _steps_fn(arg, n_leapfrog):
    """Leapfrog steps of a jittered trajectory: `ceil(u n_leapfrog)`, `u` the Halton sequence
    at the chain's counter (the same for every chain of every unit: they stay in step)."""
    from blackjax.mcmc.dynamic_hmc import halton_sequence

    return jnp.asarray(jnp.ceil(halton_sequence(arg, HALTON_BITS) * n_leapfrog), dtype=int)


class _Moments(eqx.Module):
    """Sums of the chains' positions `s1` (D,), of their outer products `s2` (D, D) and their
    count `m` over a window's second half (the re-whitening's covariance)."""

    s1: jax.Array
    s2: jax.Array
    m: jax.Array

    @staticmethod
    def zeros(D: int, dtype) -> _Moments:
        return _Moments(jnp.zeros(D, dtype), jnp.zeros((D, D), dtype), jnp.zeros((), dtype))

    def add(self, P, on) -> _Moments:
        on = jnp.asarray(on, P.dtype)
        return _Moments(self.s1 + on * P.sum(0), self.s2 + on * P.T @ P,
                        self.m + on * P.shape[0])


def _rewhiten(mom: _Moments, w, grad, z0, L):
    """New coordinates from a window's moments: centred on the chains' mean, whitened by
    their covariance (shrunk towards the identity with `SHRINK` pseudo-draws); the chains'
    positions `w` (C, D) and log-density gradients moved into them (the density's value is
    unchanged: `z` is). Returns `(w, grad, z0, L)`."""
    D = w.shape[-1]
    m = jnp.maximum(mom.m, 2.0)
    mean = mom.s1 / m
    cov = (mom.s2 - m * jnp.outer(mean, mean)) / (m - 1.0)
    cov = (m * cov + SHRINK * jnp.eye(D, dtype=w.dtype)) / (m + SHRINK)
    Lc = jnp.linalg.cholesky(cov)
    ok = jnp.all(jnp.isfinite(Lc)) & jnp.all(jnp.isfinite(mean))
    Lc = jnp.where(ok, Lc, jnp.eye(D, dtype=w.dtype))
    mean = jnp.where(ok, mean, 0.0)
    w = jax.scipy.linalg.solve_triangular(Lc, (w - mean).T, lower=True).T
    return w, grad @ Lc, z0 + L @ mean, L @ Lc


def _unit_density(target, prior, unit, z0, L):
    """The log-density of one unit in the whitened coordinates `w` (`z = z0 + L w`)."""
    return lambda w: log_density(target, prior, unit, z0 + L @ w)


def _windows(warmup: int):
    """Per warmup step (host arrays): whether the chains' positions count towards the
    re-whitening (second half of a window of `WINDOWS`), and whether the coordinates are
    re-whitened after it (the last step of every window but the last)."""
    ends = np.cumsum([max(int(round(f * warmup)), 2) for f in WINDOWS])
    starts = np.concatenate([[0], ends[:-1]])
    t = np.arange(int(ends[-1]))
    win = np.searchsorted(ends, t, side="right")
    collect = t - starts[win] >= (ends[win] - starts[win]) // 2
    last = (t == ends[win] - 1) & (win < len(WINDOWS) - 1)
    return collect, last


def _lockstep_warmup(target, prior, sampler: Sampler, progress: bool, unit, z0, L, key):
    """The ChEES warmup of one unit's chains: `(LockstepState, warmup leapfrog steps per
    chain)`. One ChEES adaptation (`blackjax.adaptation.chees_adaptation.base`: dual averaging
    of the step size on the chains' harmonic-mean acceptance, Adam on the log trajectory
    length) runs through the windows of `WINDOWS` in one scan; after each window but the last
    the coordinates are re-whitened by the chains' covariance (:func:`_rewhiten`) and the dual
    averaging starts again from the step size reached, the trajectory length kept."""
    import optax
    from blackjax.adaptation.chees_adaptation import base as chees_base
    from blackjax.mcmc import dynamic_hmc

    C, D, kernel = sampler.chains, z0.shape[-1], sampler.kernel
    jitter = lambda i: dynamic_hmc.halton_sequence(i, HALTON_BITS)
    init, update = chees_base(jitter, lambda i: i + 1, optax.adam(kernel.learning_rate),
                              sampler.target_accept, DECAY, kernel.max_leapfrog)
    step_fn = dynamic_hmc.build_kernel(next_random_arg_fn=lambda i: i + 1,
                                       integration_steps_fn=_steps_fn)
    eye = jnp.ones(D, z0.dtype)
    jkey, wkey = jax.random.split(key)
    w = JITTER * jax.random.normal(jkey, (C, D), z0.dtype)
    ld0 = jax.vmap(_unit_density(target, prior, unit, z0, L))(w)
    w = jnp.where(jnp.isfinite(ld0)[:, None], w, 0.0)
    ld = _unit_density(target, prior, unit, z0, L)
    states = jax.vmap(lambda x: dynamic_hmc.init(x, ld, jnp.zeros((), int)))(w)
    ad = init(jnp.zeros((), int), jnp.asarray(FIRST_STEP, z0.dtype))

    def rewhiten(carry):
        states, ad, z0, L, mom = carry
        w, g, z0, L = _rewhiten(mom, states.position, states.logdensity_grad, z0, L)
        fresh = init(ad.random_generator_arg, jnp.exp(ad.log_step_size_moving_average))
        ad = fresh._replace(trajectory_length=ad.trajectory_length, optim_state=ad.optim_state)
        return (states._replace(position=w, logdensity_grad=g), ad, z0, L,
                _Moments.zeros(D, z0.dtype))

    def one(carry, xs):
        k, collect, last = xs
        states, ad, z0, L, mom = carry
        ld = _unit_density(target, prior, unit, z0, L)
        new, info = _over_chains(lambda kk, ss: step_fn(
            kk, ss, ld, ad.step_size, eye, (ad.trajectory_length / ad.step_size,)), sampler)(
            jax.random.split(k, C), states)
        ad = update(ad, info.proposal.position, info.proposal.momentum, states.position,
                    info.acceptance_rate, info.is_divergent, eye)
        if progress:
            tick(C + 0 * info.num_integration_steps[0])
        carry = (new, ad, z0, L, mom.add(new.position, collect))
        return jax.lax.cond(last, rewhiten, lambda c: c, carry), info.num_integration_steps[0]

    collect, last = _windows(sampler.warmup)
    (states, ad, z0, L, _), n_steps = jax.lax.scan(
        one, (states, ad, z0, L, _Moments.zeros(D, z0.dtype)),
        (jax.random.split(wkey, collect.size), jnp.asarray(collect), jnp.asarray(last)))
    step = jnp.exp(ad.log_step_size_moving_average)
    n_leap = jnp.exp(ad.log_trajectory_length_moving_average - ad.log_step_size_moving_average)
    return LockstepState(z0=z0, L=L, position=states.position, logdensity=states.logdensity,
                         grad=states.logdensity_grad, arg=states.random_generator_arg,
                         step_size=step, n_leapfrog=n_leap), jnp.sum(n_steps)


def _lockstep_draws(target, prior, sampler: Sampler, progress: bool, unit, st, keys):
    """`sampler.draws` draws (every `thin`-th step kept) of one unit's ChEES chains from their
    state `st` (C chains: all the unit's or a share of them), each chain's from its key in
    `keys` (C,): `(trace (C, N) arrays, the state after)`."""
    from blackjax.mcmc.dynamic_hmc import DynamicHMCState, build_kernel

    C = st.position.shape[0]
    logdensity = _unit_density(target, prior, unit, st.z0, st.L)
    kernel = build_kernel(next_random_arg_fn=lambda i: i + 1, integration_steps_fn=_steps_fn)
    eye = jnp.ones(st.z0.shape[-1], st.z0.dtype)

    def step(s, k):
        s, info = _over_chains(lambda kk, ss: kernel(kk, ss, logdensity, st.step_size, eye,
                                                     (st.n_leapfrog,)), sampler)(k, s)
        return s, (info.is_divergent, info.num_integration_steps, info.acceptance_rate)

    def one(s, ks):  # `thin` steps, the last kept
        s, (div, n, acc) = jax.lax.scan(step, s, ks)
        if progress:
            tick(C + 0 * n[-1, 0])
        out = (st.z0 + s.position @ st.L.T, s.logdensity, jnp.any(div, axis=0),
               jnp.sum(n, axis=0), jnp.mean(acc, axis=0))
        return s, out

    s0 = DynamicHMCState(st.position, st.logdensity, st.grad, st.arg)
    steps = jax.vmap(lambda k: jax.random.split(k, sampler.draws * sampler.thin))(keys)
    last, trace = jax.lax.scan(one, s0, jnp.moveaxis(steps, 0, -1).reshape(
        sampler.draws, sampler.thin, C))
    after = eqx.tree_at(lambda t: (t.position, t.logdensity, t.grad, t.arg), st,
                        (last.position, last.logdensity, last.logdensity_grad,
                         last.random_generator_arg))
    return jax.tree.map(lambda a: jnp.swapaxes(a, 0, 1), trace), after


def _over_chains(step, sampler: Sampler):
    """One lockstep step `step(key, state)` of every chain of a unit: vmapped, or (`Sampler.
    vectorize` `"none"`) one chain after another, where a chain's residuals already fill the
    CPU's caches (a static model on a long record: a batch of chains only adds memory
    traffic)."""
    if vectorized(sampler) != "none":
        return jax.vmap(step)
    return lambda keys, states: jax.lax.map(lambda a: step(*a), (keys, states))


def _over_units(fn, sampler: Sampler):
    """`fn` over the units of a page: vmapped (`Sampler.vectorize` `"all"`: every chain of
    every unit in one batch) or mapped (one unit at a time, so that a unit never waits for
    another's longer trajectories). Several CPU devices each run pages of their own, side by
    side (the caller's): one program per device, no collective between them, so a device
    never waits for another."""
    if vectorized(sampler) != "all":
        return lambda *a: jax.lax.map(lambda x: fn(*x), a)
    return jax.vmap(fn)


def _finish(target, prior, units, trace, keys):
    z, lp, div, n, acc = trace
    return (*to_si(target, prior, units, z, keys), (lp, div, n, acc))


@eqx.filter_jit
def warm_lockstep(target, prior, sampler, progress, units, z0, L, keys):
    """The ChEES warmup of every chain of every unit of a page in one compiled program (the
    units vmapped or mapped, `Sampler.vectorize`): `(LockstepState, warmup leapfrog steps per
    chain (U,))`; the draws then by :func:`extend_lockstep` with `fresh=True`."""
    def unit_fn(unit, z, m, k):
        return _lockstep_warmup(target, prior, sampler, progress, unit, z, m,
                                jax.random.split(k[0])[0])

    return _over_units(unit_fn, sampler)(units, z0, L, keys)


@eqx.filter_jit
def extend_lockstep(target, prior, sampler, progress, units, state, keys, fresh=False):
    """Draws of ChEES chains from where they stopped (`state`, a batched
    :class:`LockstepState`): the first draws after the warmup (`fresh`) or more of them. A
    unit's chains draw from their own keys (`keys` (U, C)), so a unit's chains may be shared
    out over calls (units of fewer chains) with the same draws. Returns `(theta, sigma, rho,
    (lp, diverging, steps, accept), LockstepState)`."""
    def unit_fn(unit, st, k):
        ks = jax.vmap(lambda c: jax.random.split(c)[1] if fresh
                      else jax.random.fold_in(c, 2))(k)
        return _lockstep_draws(target, prior, sampler, progress, unit, st, ks)

    trace, after = _over_units(unit_fn, sampler)(units, state, keys)
    return (*_finish(target, prior, units, trace, keys), after)
