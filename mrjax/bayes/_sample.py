"""The posterior of a problem's unknowns: :class:`Likelihood` (what a problem kind supplies)
and :func:`sample` (the mode, the chains, the continuations of the units that missed)."""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from ._calls import by_units, draw_calls, group_out, join, take, warm_calls, whole
from ._chains import run_chains
from ._noise import check_noise, lag_grams
from ._pages import page_size, spread
from ._priors import box_slope, check_priors, prior_arrays, to_box
from ._result import Posterior
from ._sampler import BAR, Sampler, chain_devices
from ._start import (
    GRADIENT_TOL,
    Target,
    Unit,
    collapsible,
    find_mode,
    gradient_error,
    laplace,
    start,
    to_log,
)


@dataclasses.dataclass(frozen=True, eq=False)
class Likelihood:
    """What a problem kind supplies to the sampler, for U units side by side.

    **Fields:**

    - `residual`: `residual(theta (K,), unit_data) -> ((r, mask), ...)`, a tuple of blocks of
        residuals [N] and scored-sample masks, each (R_b, T_b) records by samples; jittable,
        written for one unit (it is vmapped); hashable (an `eqx.Module`), so that a second
        call reuses the compiled program.
    - `theta0`: (U, K) the optimum of each unit, SI units: the mode search starts there.
    - `data`: pytree whose leaves have a leading unit axis U.
    - `lower`, `upper`: (K,) or (U, K) the box of the unknowns, SI units; an unknown with
        `lower == upper` everywhere is held.
    - `names`: (K,) the unknowns' names; `units` (K,) their SI units (or None).
    - `labels`: (U,) unit labels (default `"0"`, `"1"`, ...); `row_labels` the R records of a
        unit (the `record` dim of `noise_sigma` where R > 1); `unit_dim` the unit dimension's
        name (`"condition"`).
    - `gauge`: names of the unknowns to hold first where the data leave a direction
        undetermined (e.g. a z-scale symmetry's free parameter).
    - `exact`: where `residual`'s derivatives are an approximation (an implicit scheme's
        tangent), the residual with exact ones: the approximation is checked around the mode
        and replaced where it is off by more than `GRADIENT_TOL` (`Posterior.gradient_error`).
    - `linear`: names of unknowns the residuals are affine in with a regressor no unknown
        changes: integrated out in closed form where their prior is flat and their mode lies
        well inside their box, and drawn from their conditional (`Posterior.linear`).
    - `dynamic`: a dynamic model's residuals (one sequential integration): the sampler's
        defaults for it (`Sampler.for_model`).
    - `trim`: `trim(data, n) -> data`, the units' data (leading unit axis) cut to their
        first `n` samples, whose residual blocks are the first `n` samples of the uncut
        ones' last axis; None where the data cannot be cut. With it, units of different
        lengths padded to the longest (a campaign's records) are drawn in groups of similar
        length, each cut to its longest unit's last scored sample (:func:`length_groups`):
        a gradient costs in proportion to the samples it runs through.
    """

    residual: Callable
    theta0: Any
    data: Any
    lower: Any
    upper: Any
    names: tuple[str, ...]
    units: tuple[str, ...] | None = None
    labels: tuple[str, ...] | None = None
    row_labels: tuple[str, ...] | None = None
    unit_dim: str = "condition"
    gauge: tuple[str, ...] = ()
    exact: Callable | None = None
    linear: tuple[str, ...] = ()
    dynamic: bool = False
    trim: Callable | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class _Setup:
    """The checked arrays of a :class:`Likelihood`, its priors and the start."""

    names: tuple[str, ...]
    labels: tuple[str, ...]
    theta0: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    free: tuple[int, ...]
    rows: tuple[int, ...]
    priors: dict
    prior_data: tuple


def _checked(lk: Likelihood, noise: str, prior: Mapping[str, Any] | None) -> _Setup:
    names = tuple(str(n) for n in lk.names)
    K = len(names)
    theta0 = np.asarray(lk.theta0, float)
    if theta0.ndim != 2 or theta0.shape[1] != K:
        raise InputError(f"theta0 must be (units, {K}), got shape {theta0.shape}")
    U = theta0.shape[0]
    lo = np.broadcast_to(np.asarray(lk.lower, float), (U, K))
    hi = np.broadcast_to(np.asarray(lk.upper, float), (U, K))
    if np.any(~np.isfinite(lo)) or np.any(~np.isfinite(hi)) or np.any(lo > hi):
        raise InputError("the box of the unknowns must be finite with lower <= upper")
    if not np.all(np.isfinite(theta0)):
        raise InputError("the optimum theta0 must be finite")
    priors = check_priors(prior, names)
    kind, a, b, lo, hi = prior_arrays(priors, names, lo, hi)
    free = tuple(int(j) for j in np.flatnonzero(np.any(hi > lo, axis=0)))
    if not free:
        raise InputError("no free unknowns: every lower bound equals its upper bound")
    labels = tuple(map(str, lk.labels)) if lk.labels is not None else tuple(map(str, range(U)))
    if len(labels) != U:
        raise InputError(f"{len(labels)} labels for {U} units")
    theta0 = np.clip(theta0, lo, hi)
    shapes = jax.eval_shape(lk.residual, jnp.asarray(theta0[0]),
                            jax.tree.map(lambda x: x[0], lk.data))
    return _Setup(names, labels, theta0, lo, hi, free, tuple(int(s[0].shape[0]) for s in shapes),
                  priors, (jnp.asarray(kind), jnp.asarray(a), jnp.asarray(b)))


@dataclasses.dataclass(frozen=True, eq=False)
class _Prepared:
    """The log-density's target, every unit's arrays, start `z0` and metric `L`, the box
    after the start (held unknowns), and the gradient check."""

    target: Target
    units: Unit
    z0: np.ndarray
    L: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    gradient_error: float | None


def _at_mode(lk: Likelihood, su: _Setup, st, every, target: Target, z0, L) -> _Prepared:
    """From the start: the mode (a damped Newton search from the optimum, which is the
    least-squares one, not this posterior's mode; the Hessian there replaces the Gauss-Newton
    metric), then the log coordinates and the linear unknowns integrated out, both decided
    there."""
    free, U = su.free, su.theta0.shape[0]

    def arrays(moved, lin):
        return Unit(data=lk.data, lo=jnp.asarray(st.lo[:, moved]),
                    hi=jnp.asarray(st.hi[:, moved]), soft=jnp.asarray(st.soft[:, moved]),
                    log=jnp.asarray(st.log[:, moved]), theta=jnp.asarray(su.theta0),
                    regressors=tuple(jnp.asarray(J[..., lin]) for J in st.jacobians),
                    grams=tuple(lag_grams(J[..., lin], m) for J, m in zip(st.jacobians,
                                                                          st.masks)),
                    masks=tuple(jnp.asarray(m) for m in st.masks))

    mode = lambda *a: find_mode(target, su.prior_data, *a)  # the units split over the devices
    z, m = laplace(*by_units(mode, U, arrays(every, []), jnp.asarray(z0), jnp.asarray(L)),
                   z0, L)
    Kf, Km = len(free), len(every)
    cov = m @ np.swapaxes(m, 1, 2)
    with np.errstate(invalid="ignore"):
        sd_u = np.full((U, Kf), np.nan)
        sd_u[:, every] = np.sqrt(np.diagonal(cov, axis1=1, axis2=2)[:, :Km])
    u_mode = np.zeros((U, Kf))
    u_mode[:, every] = z[:, :Km]
    centre = np.asarray(to_box(u_mode, st.lo, st.hi, st.soft, st.log))
    sd = sd_u * box_slope(u_mode, st.lo, st.hi, st.soft, st.log)
    st, z, cov = to_log(st, z, cov, every, centre, sd)  # positive unknowns far above 0
    lin = collapsible(lk.residual, su.theta0, lk.data, free, st, su.prior_data[0],
                      [su.names.index(n) for n in lk.linear if n in su.names], centre, sd)
    moved = [k for k in every if k not in lin]
    keep = np.concatenate([[every.index(k) for k in moved],
                           np.arange(Km, z.shape[1])]).astype(int)
    target = dataclasses.replace(target, free=tuple(free[k] for k in moved),
                                 linear=tuple(free[k] for k in lin))
    lo, hi = su.lo.copy(), su.hi.copy()
    lo[:, list(free)], hi[:, list(free)] = st.lo, st.hi
    return _Prepared(target, arrays(moved, lin), z[:, keep],
                     np.linalg.cholesky(cov[:, keep][:, :, keep]), lo, hi, None)


@dataclasses.dataclass(frozen=True, eq=False)
class _Group:
    """Units drawn with one log-density: `rows` of the likelihood's units, their
    :class:`_Prepared` arrays (in the order of `rows`)."""

    rows: np.ndarray
    prep: _Prepared


#: A gradient through the exact tangent costs this many through the implicit one (the
#: modified Bouc-Wen model's SDIRK scheme on the same samples: 6.8; `benchmarks/posterior.md`),
#: for the spread of a campaign's calls over the devices.
EXACT_COST = 6.0


#: A group of units of its own costs as many samples of every unit's gradient as this share
#: of the campaign's padded samples (its own compiled program; see :func:`length_groups`).
GROUP_COST = 0.05


def length_groups(lengths: np.ndarray, group_cost: float = GROUP_COST) -> list[np.ndarray]:
    """Units of `lengths` (U,) [samples] in groups of similar length: the partition of
    the units sorted by length that minimises the samples a gradient runs through, each
    group's units padded to its longest, plus `group_cost` x U x max(lengths) per group
    (dynamic programming over the sorted lengths). Returns the groups' unit indices
    (ascending), longest group first."""
    n = np.asarray(lengths, float)
    order = np.argsort(-n, kind="stable")
    s = n[order]
    U = s.size
    penalty = group_cost * U * (s[0] if U else 0.0)
    best = np.full(U + 1, np.inf)
    best[0], cut = 0.0, np.zeros(U + 1, int)
    for i in range(1, U + 1):  # best[i]: the first i sorted units grouped
        cost = best[:i] + s[:i] * (i - np.arange(i)) + penalty
        cut[i] = int(np.argmin(cost))
        best[i] = cost[cut[i]]
    bounds, i = [], U
    while i > 0:
        bounds.append((cut[i], i))
        i = cut[i]
    return [np.sort(order[a:b]) for a, b in reversed(bounds)]


def _scored_length(masks: tuple) -> np.ndarray:
    """(U,) one past each unit's last scored sample over its residual blocks' masks."""
    ends = [np.where(np.asarray(m).any(axis=-2), np.arange(m.shape[-1]) + 1, 0).max(axis=-1)
            for m in masks]
    return np.max(ends, axis=0)


def _by_length(lk: Likelihood, groups: list[_Group]) -> list[_Group]:
    """`groups` split into groups of similar length (:func:`length_groups`), each unit's
    data, masks and regressors cut to its group's longest scored sample; unchanged without
    `lk.trim`."""
    if lk.trim is None:
        return groups
    out = []
    for g in groups:
        n = _scored_length(g.prep.units.masks)
        for sel in length_groups(n):
            T = int(n[sel].max())
            u = take(g.prep.units, sel)
            u = u._replace(data=lk.trim(u.data, T), masks=tuple(m[..., :T] for m in u.masks),
                           regressors=tuple(r[..., :T, :] for r in u.regressors))
            p = g.prep
            out.append(_Group(g.rows[sel], _Prepared(p.target, u, p.z0[sel], p.L[sel],
                                                     p.lo[sel], p.hi[sel], p.gradient_error)))
    return out


def _prepare(lk: Likelihood, su: _Setup, sampler: Sampler, noise: str) -> list[_Group]:
    """The start (`mrjax.bayes._start.start`: the optimum and the Gauss-Newton covariance of
    the residuals there, one unknown held per undetermined direction), moved onto the mode;
    with an approximate derivative checked there, unit by unit, and replaced by the exact one
    in the units where it is off: those units form a group of their own (a campaign's other
    units keep the cheaper derivative)."""
    free = su.free
    st = start(lk.residual, su.theta0, su.lo[:, free], su.hi[:, free], lk.data, free, noise,
               su.names, tuple(lk.gauge))
    Kf = len(free)
    # an unknown held in every unit is no unknown of the sampler: neither a dimension nor a
    # forward-mode tangent
    every = [k for k in range(Kf) if not st.held[:, k].all()]
    keep = np.concatenate([every, np.arange(Kf, st.z0.shape[1])]).astype(int)
    # the sampler runs in whitened coordinates w, z = z0 + L w with L L^T the starting
    # covariance: every w is O(1), so the regularisation of the adapted mass matrix (towards
    # 1e-3 I) does not swamp unknowns whose posterior spans a tiny part of their box
    z0, L = st.z0[:, keep], np.linalg.cholesky(st.imm[:, keep][:, :, keep])
    target = Target(residual=lk.residual, free=tuple(free[k] for k in every), rows=su.rows,
                    noise=noise, forward=sampler.gradient == "forward")
    prep = _at_mode(lk, su, st, every, target, z0, L)
    rows = np.arange(su.theta0.shape[0])
    if lk.exact is None:
        return _by_length(lk, [_Group(rows, prep)])
    err = np.asarray(by_units(lambda *a: gradient_error(prep.target, su.prior_data, *a),
                              rows.size, prep.units, jnp.asarray(prep.z0), jnp.asarray(prep.L)))
    bad = ~(err <= GRADIENT_TOL)
    groups = []
    if not bad.all():
        groups.append(_Group(rows[~bad], _Prepared(
            prep.target, take(prep.units, ~bad), prep.z0[~bad], prep.L[~bad], prep.lo[~bad],
            prep.hi[~bad], None)))
    if bad.any():  # those units again from the start, exactly: the approximate gradient's
        # "mode" may be far from the posterior's
        lk_b = dataclasses.replace(lk, data=take(lk.data, bad))
        su_b = dataclasses.replace(su, theta0=su.theta0[bad], lo=su.lo[bad], hi=su.hi[bad])
        groups.append(_Group(rows[bad], _at_mode(
            lk_b, su_b, take(st, bad), every, dataclasses.replace(target, residual=lk.exact),
            z0[bad], L[bad])))
    return _by_length(lk, [_Group(g.rows, dataclasses.replace(
        g.prep, gradient_error=float(np.max(err)))) for g in groups])


def _unit_keys(key: Any, units: np.ndarray, chains: int, round_: int):
    """Each unit's chain keys: `split(fold_in(key, unit), chains)` in the first round,
    `fold_in` the round number on top in a continuation."""
    def one(i):
        k = jax.random.fold_in(key, i)
        return jax.random.split(k if round_ == 0 else jax.random.fold_in(k, round_), chains)

    return jax.vmap(one)(jnp.asarray(units))


def _bar(show: bool, total: int):
    """A tqdm progress bar of `total` chain steps where `show` (None otherwise), installed as
    the one the compiled program advances."""
    if not show:
        return None
    from tqdm.auto import tqdm  # imported here: only a shown bar needs it

    bar = tqdm(total=total, desc="posterior (warmup + draws, all chains)", unit="step",
               leave=False, file=sys.stderr)
    BAR[0] = bar
    return bar


def _draw(prep: _Prepared, su: _Setup, sampler: Sampler, rows: np.ndarray, keys, show: bool):
    """The NUTS chains of the units `rows`, with a progress bar where `show`; host arrays."""
    bar = _bar(show, (sampler.warmup + sampler.draws) * rows.size * sampler.chains)
    args = (jax.tree.map(lambda a: a[rows], prep.units), jnp.asarray(prep.z0[rows]),
            jnp.asarray(prep.L[rows]))
    run = lambda *a: run_chains(prep.target, su.prior_data, sampler, show, *a)
    try:  # each device its share of every unit's chains
        outs = spread([(run, (*args, keys[:, share])) for share in
                        np.split(np.arange(sampler.chains), chain_devices(sampler))])
    finally:
        BAR[0] = None
        if bar is not None:
            bar.close()
    return jax.tree.map(lambda *a: np.concatenate(a, axis=1), *outs)


@dataclasses.dataclass(frozen=True, eq=False)
class _Shared:
    """What every unit's posterior shares of the groups' preparation: the box after the start
    (U, K) and after the uniform priors, the names of the unknowns integrated out (in any
    group), the gradient check's largest error."""

    lo: np.ndarray
    hi: np.ndarray
    linear: tuple[str, ...]
    gradient_error: float | None


def _shared(su: _Setup, groups: list[_Group]) -> _Shared:
    lo, hi = su.lo.copy(), su.hi.copy()
    for g in groups:
        lo[g.rows], hi[g.rows] = g.prep.lo, g.prep.hi
    lin = sorted({j for g in groups for j in g.prep.target.linear})
    return _Shared(lo, hi, tuple(su.names[j] for j in lin), groups[0].prep.gradient_error)


def _posterior(lk: Likelihood, su: _Setup, sh: _Shared, sampler: Sampler, noise: str,
               out, seed: Any, timings: dict[str, float]) -> Posterior:
    theta, sigma, rho, (lp, div, steps, acc), step_size, warm_steps = out
    U = np.shape(theta)[0]  # the units drawn (a continuation: those it ran)
    return Posterior(
        names=su.names, labels=su.labels, unit_dim=lk.unit_dim,
        row_labels=None if lk.row_labels is None else tuple(map(str, lk.row_labels)),
        theta=np.asarray(theta), sigma=np.asarray(sigma),
        rho=None if rho is None else np.asarray(rho), lp=np.asarray(lp),
        diverging=np.asarray(div, bool), n_steps=np.asarray(steps, int),
        accept=np.asarray(acc, float), step_size=np.asarray(step_size, float),
        warmup_steps=np.asarray(warm_steps, int), warmup_length=np.full(U, sampler.warmup),
        rounds=np.zeros(U, int), gradient_error=sh.gradient_error, linear=sh.linear,
        theta0=su.theta0, lower=sh.lo, upper=sh.hi,
        free=np.isin(np.arange(len(su.names)), su.free), noise=noise,
        prior={n: p.describe() for n, p in su.priors.items()}, sampler=sampler, seed=seed,
        timings=timings, param_units=None if lk.units is None else tuple(lk.units))


def sample(
    likelihood: Likelihood,
    *,
    sampler: Sampler | None = None,
    noise: str = "iid",
    prior: Mapping[str, Any] | None = None,
    key: int | Any = 0,
    progress: bool | None = False,
) -> Posterior:
    """Sample the posterior of a problem's unknowns, on every unit at once.

    The start is the optimum `likelihood.theta0` with the Gauss-Newton covariance of the
    residuals there (one unknown held per direction the data leave undetermined); a damped
    Newton search moves it onto the posterior's mode (the noise model, the prior and the soft
    box move it), and the chains start around the mode with the inverse Hessian there as
    their metric. The kernel (`Sampler.kernel`) is NUTS, each chain on its own, or ChEES-HMC,
    every chain of every unit of a page in lockstep (see :class:`mrjax.bayes.ChEES`). Units
    whose chains miss R-hat <= 1.01, bulk or tail ESS >= 400, or diverge, are continued
    (`Sampler.continuations`).

    **Arguments:** `likelihood` the problem's :class:`Likelihood`; `sampler` the
    :class:`Sampler` (default `Sampler()`, its defaults chosen for the model's kind); `noise`
    `"iid"` or `"ar1"` (see `mrjax.bayes.block_loglik`); `prior` {name: prior} (see
    `mrjax.bayes.parse_prior`; default flat on the box); `key` an integer seed or a PRNG key
    (each unit's chains use `fold_in(key, unit)`: same key, same draws); `progress` a tqdm
    bar (None: only on a terminal).

    **Returns:** a :class:`mrjax.bayes.Posterior` (`timings["mode"]`, `["sample"]` [s]; ChEES
    also `["warmup"]`, `["draws"]` and `["continuations"]`, compilation included).

    Raises :class:`mrjax.InputError` for bad settings, an unknown noise model or prior, or
    shapes that do not match.
    """
    sampler = (sampler or Sampler()).for_model(likelihood.dynamic).check()
    noise = check_noise(noise)
    su = _checked(likelihood, noise, prior)
    t0 = time.perf_counter()
    groups = _prepare(likelihood, su, sampler, noise)
    t_mode = time.perf_counter() - t0
    seed = int(key) if isinstance(key, (int, np.integer)) and not isinstance(key, bool) else None
    key = jax.random.key(seed) if seed is not None else key
    show = sys.stderr.isatty() if progress is None else bool(progress)
    t0 = time.perf_counter()
    run = _Run(likelihood, su, groups, _shared(su, groups), noise, seed, key, show)
    post = run.lockstep(sampler) if sampler.lockstep else run.nuts(sampler)
    wall = time.perf_counter() - t0 + t_mode
    return dataclasses.replace(post, timings={"sample": wall, "mode": t_mode, **run.clock})


@dataclasses.dataclass(frozen=True, eq=False)
class _Run:
    """The draws of one :func:`sample` call: the first round of every unit, then the
    continuations of those that missed (`Sampler.continuations`), by kernel; each group of
    units (:func:`_prepare`) drawn with its own log-density."""

    lk: Likelihood
    su: _Setup
    groups: list[_Group]
    sh: _Shared
    noise: str
    seed: int | None
    key: Any
    show: bool
    #: Seconds spent per phase (ChEES: `"warmup"`, `"draws"`, `"continuations"`), added to.
    clock: dict = dataclasses.field(default_factory=dict)

    def tally(self, phase: str, t0: float) -> float:
        """Add the seconds since `t0` to `clock[phase]`; returns now."""
        now = time.perf_counter()
        self.clock[phase] = self.clock.get(phase, 0.0) + now - t0
        return now

    def weight(self, group: int) -> float:
        """Predicted cost of one gradient of a unit of `group`, relative to the others': its
        samples, times `EXACT_COST` where it runs the exact tangent."""
        prep = self.groups[group].prep
        exact = self.lk.exact is not None and prep.target.residual is self.lk.exact
        return float(_scored_length(prep.units.masks).max()) * (EXACT_COST if exact else 1.0)

    def post(self, sampler: Sampler, out) -> Posterior:
        return _posterior(self.lk, self.su, self.sh, sampler, self.noise, out, self.seed, {})

    def split(self, rows: np.ndarray):
        """`(group index, positions in rows, indices within the group)` of the units `rows`,
        group by group."""
        for i, g in enumerate(self.groups):
            pos = np.flatnonzero(np.isin(rows, g.rows))
            if pos.size:
                yield i, pos, np.searchsorted(g.rows, rows[pos])

    def draw(self, fn, sampler: Sampler, rows: np.ndarray, round_: int):
        """`fn(group index, rows within the group, their keys) -> out` for the units `rows`,
        group by group: the outs joined, their unit axes in the order of `rows`."""
        parts = list(self.split(rows))
        outs = [fn(i, local, _unit_keys(self.key, rows[pos], sampler.chains, round_))
                for i, pos, local in parts]
        return join(rows.size, [pos for _, pos, _ in parts], outs)

    def nuts(self, sampler: Sampler) -> Posterior:
        """NUTS: a continued unit runs again from the mode, 2^r x the warmup and draws."""
        def fn(s):
            return lambda i, local, keys: _draw(self.groups[i].prep, self.su, s, local, keys,
                                                self.show)

        every = np.arange(self.su.theta0.shape[0])
        post = self.post(sampler, self.draw(fn(sampler), sampler, every, 0))
        for r in range(1, sampler.continuations + 1):
            rows = np.flatnonzero(post.unconverged())
            if rows.size == 0:
                break
            s_r = sampler.continued(r, bool(post.diverging[rows].any()))
            post = post.with_units(rows, self.post(s_r, self.draw(fn(s_r), sampler, rows, r)),
                                   r)
        return post

    def paged(self, sampler: Sampler, rows: np.ndarray, round_: int, first: dict,
              states: dict | None = None):
        """ChEES chains of the units `rows`, every group's pages spread over the devices
        together (:func:`mrjax.bayes._pages.spread`): the warmup from the mode (`states`
        None), then draws in pages of units of similar trajectory length; or (`states`,
        {group: its chains' last state}) draws that extend them. Returns `(draws (in the
        order of rows), {group: (the units' positions in the group, their state after, the
        warmup's page size, their warmup leapfrog steps)})`."""
        parts = list(self.split(rows))
        keys = [_unit_keys(self.key, rows[pos], sampler.chains, round_) for _, pos, _ in parts]
        fresh = states is None
        t0 = time.perf_counter()
        bar = _bar(self.show, (sampler.warmup * fresh + sampler.draws * sampler.thin)
                   * rows.size * sampler.chains)
        try:
            warm, page = {}, {}
            if fresh:
                calls, costs, cuts = [], [], []
                for (i, _, local), k in zip(parts, keys):
                    c, co, cut, page[i] = warm_calls(self.groups[i].prep, self.su, sampler,
                                                     local, k, first.get(i), self.weight(i),
                                                     self.show)
                    calls, costs, cuts = calls + c, costs + co, cuts + [(i, x) for x in cut]
                outs = spread(calls, costs)
                states = {}
                for i, _, local in parts:
                    states[i], warm[i] = group_out(cuts, outs, i, local.size)
                t0 = self.tally("warmup" if round_ == 0 else "continuations", t0)
            calls, costs, cuts, shares = [], [], [], {}
            for (i, _, local), k in zip(parts, keys):
                st = states[i] if fresh else take(states[i], local)
                most = page.get(i) or page_size(sampler, local.size, first.get(i))
                c, co, cut, shares[i] = draw_calls(self.groups[i].prep, self.su, sampler,
                                                   local, k, st, most, self.weight(i), fresh,
                                                   self.show)
                calls, costs, cuts = calls + c, costs + co, cuts + [(i, x) for x in cut]
            outs = spread(calls, costs)
            self.tally("draws" if round_ == 0 else "continuations", t0)
        finally:
            BAR[0] = None
            if bar is not None:
                bar.close()
        joined, extra = [], {}
        for i, pos, local in parts:
            *draws, after = whole(group_out(cuts, outs, i, local.size * shares[i]),
                                  shares[i])
            joined.append(tuple(draws))
            extra[i] = (local, after, page.get(i), warm.get(i))
        return join(rows.size, [pos for _, pos, _ in parts], joined), extra

    def fresh(self, sampler: Sampler, rows: np.ndarray, round_: int, first: dict):
        """ChEES warmup and draws of the units `rows` from the mode: `(Posterior of those
        units, {group: (positions in the group, its chains' last state, the page size)})`."""
        draws, extra = self.paged(sampler, rows, round_, first)
        C = sampler.chains
        step = join(rows.size, [pos for _, pos, _ in self.split(rows)],
                    [(e[1].step_size, e[3]) for e in extra.values()])
        out = (*draws, np.repeat(step[0][:, None], C, 1), np.repeat(step[1][:, None], C, 1))
        return self.post(sampler, out), extra

    def lockstep(self, sampler: Sampler) -> Posterior:
        """ChEES: a continued unit's chains go on from where they stopped (round r: to 2^r x
        the draws, every 2^r-th kept), except where they diverged: those start again from the
        mode with 2^r x the warmup and a higher target acceptance."""
        every = np.arange(self.su.theta0.shape[0])
        post, extra = self.fresh(sampler, every, 0, {})
        states = {i: e[1] for i, e in extra.items()}
        first = {i: e[2] for i, e in extra.items()}
        for r in range(1, sampler.continuations + 1):
            rows = np.flatnonzero(post.unconverged())
            if rows.size == 0:
                break
            div = post.diverging[rows].any(axis=(1, 2))
            if div.any():
                new, extra = self.fresh(sampler.continued(r, True), rows[div], r, first)
                post = post.with_units(rows[div], new, r)
                for i, e in extra.items():
                    states[i] = _set_rows(states[i], e[0], e[1])
            if (~div).any():
                post = self.extend(sampler, post, states, rows[~div], r, first)
        return post

    def extend(self, sampler: Sampler, post: Posterior, states: dict, rows: np.ndarray,
               r: int, first: dict) -> Posterior:
        """Round `r` of the units `rows` by extension: their kept draws' every second, then
        `draws - draws // 2` new ones at 2^r x `thin` (the chains' whole length so far again,
        every 2^r-th step kept); `states` updated in place."""
        N = post.n_draws
        s_r = dataclasses.replace(sampler, draws=N - N // 2, thin=sampler.thin * 2 ** r)
        draws, extra = self.paged(s_r, rows, r, first, states)
        for i, e in extra.items():
            states[i] = _set_rows(states[i], e[0], e[1])
        old = (post.theta, post.sigma, post.rho, (post.lp, post.diverging, post.n_steps,
                                                    post.accept))
        both = jax.tree.map(lambda a, b: np.concatenate([a[rows][:, :, 1::2], b], axis=2),
                            old, draws)
        new = self.post(sampler, (*both, post.step_size[rows], post.warmup_steps[rows]))
        new = dataclasses.replace(new, warmup_length=post.warmup_length[rows])
        return post.with_units(rows, new, r)


def _set_rows(state, rows: np.ndarray, new):
    """`state` (a pytree of host arrays with a leading unit axis) with the units `rows` set to
    `new`."""
    def put(a, b):
        a = np.array(a)
        a[rows] = b
        return a

    return jax.tree.map(put, state, new)
