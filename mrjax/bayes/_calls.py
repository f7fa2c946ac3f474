"""The compiled calls of the lockstep kernel (ChEES) over pages of units, and their outputs
joined back: a group's warmup calls, its draws in pages of units of similar trajectory length
(each unit's chains whole or in shares), the pages' outputs as one pytree of units.

`prep` is a group's prepared arrays (`target`, `units`, `z0`, `L`; `mrjax.bayes.sample`),
`su` the checked setup (`prior_data`)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ._chains import LockstepState, extend_lockstep, warm_lockstep
from ._pages import page_cost, page_size, pages, shared_pages, spread
from ._sampler import Sampler, warmup_vectorized


def take(tree, rows):
    """The units `rows` of a pytree of arrays with a leading unit axis."""
    return jax.tree.map(lambda a: a[rows], tree)


def join(n: int, cuts: list[np.ndarray], outs: list):
    """Outputs `outs` of the units `cuts` (index arrays; a padded page repeats an index) as
    one pytree of host arrays whose leading axis holds the `n` units."""
    def put(*leaves):
        full = np.empty((n,) + np.shape(leaves[0])[1:], np.asarray(leaves[0]).dtype)
        for cut, a in zip(cuts, leaves):
            full[cut] = a
        return full

    return jax.tree.map(put, *outs)


def by_units(fn, n: int, *args):
    """`fn(*args)` for arguments with a leading axis of `n` units, the units cut into one page
    per device (padded to one shape: one compiled program) and the pages run side by side
    (:func:`mrjax.bayes._pages.spread`): the outputs as one pytree of host arrays of `n`
    units. For an `fn` that maps its units one at a time (`lax.map`), each unit's result does
    not depend on the cut (to rounding)."""
    cuts = pages(n, max(-(-n // max(jax.local_device_count(), 1)), 1))
    return join(n, cuts, spread([(fn, take(args, c)) for c in cuts]))


def group_out(cuts: list, outs: list, group: int, n: int):
    """The `n` units of `group` joined (:func:`join`) from the outputs `outs` of the pages
    `cuts` `[(group, unit positions in the group), ...]` of several groups."""
    return join(n, *zip(*[(x, o) for (g, x), o in zip(cuts, outs) if g == group]))


def warm_calls(prep, su, sampler: Sampler, local: np.ndarray, keys, first: int | None,
               weight: float, show: bool):
    """The calls of the ChEES warmup of a group's units `local` in pages (one unit a call
    where the warmup maps its units: :func:`mrjax.bayes._sampler.warmup_vectorized`): `(calls,
    their predicted costs (units x `weight`, a unit's gradient relative to other groups'),
    the pages' unit positions in local, the page size of the draws)`."""
    page = page_size(sampler, local.size, first)
    mode = warmup_vectorized(sampler)
    warm = dataclasses.replace(sampler, vectorize=mode)
    run = lambda *a: warm_lockstep(prep.target, su.prior_data, warm, show, *a)
    cuts = pages(local.size, page if mode == "all" else 1)
    calls = [(run, (take(prep.units, local[c]), jnp.asarray(prep.z0[local[c]]),
                    jnp.asarray(prep.L[local[c]]), keys[c])) for c in cuts]
    return calls, [c.size * weight for c in cuts], cuts, page


def draw_calls(prep, su, sampler: Sampler, local: np.ndarray, keys, state, most: int,
               weight: float, fresh: bool, show: bool):
    """The calls of a group's units `local` drawing from their chains' `state` (host arrays,
    in the order of `local`), in pages of units of similar trajectory length, each unit's
    chains whole or in shares (:func:`mrjax.bayes._pages.shared_pages`, at most `most` units
    of whole chains a page): `(calls, their predicted costs (x `weight`, as in
    :func:`warm_calls`), the pages' unit positions, the shares)`; the units of the pages are
    shares where `shares > 1` (unit `j // shares`, share `j % shares`), joined again by
    :func:`whole`."""
    n = np.asarray(state.n_leapfrog, float)
    S, cuts = shared_pages(n, sampler, most, jax.local_device_count())
    state, keys = in_shares(state, S), in_shares(keys, S)
    run = lambda *a: extend_lockstep(prep.target, su.prior_data, sampler, show, *a,
                                     fresh=fresh)
    calls = [(run, (take(prep.units, local[c // S]), take(state, c), keys[c]))
             for c in cuts]
    steps = sampler.draws * sampler.thin * weight
    n = np.repeat(n, S)
    costs = [page_cost(n[c], sampler, sampler.chains // S) * steps for c in cuts]
    return calls, costs, cuts, S


def in_shares(tree, S: int):
    """A batched :class:`LockstepState` or keys (U, C) with each unit's C chains in `S`
    shares of C / S, units of their own (unit-major: `u * S + s`); a unit's coordinates,
    step size and trajectory length repeated for each share."""
    if S == 1:
        return tree

    def cut(a):  # host arrays or keys
        return a.reshape(a.shape[0] * S, a.shape[1] // S, *a.shape[2:])

    if isinstance(tree, LockstepState):
        return LockstepState(**{f: cut(getattr(tree, f)) if f in PER_CHAIN else
                                np.repeat(np.asarray(getattr(tree, f)), S, axis=0)
                                for f in FIELDS})
    return cut(tree)


#: The fields of :class:`LockstepState`, and those with a chain axis.
FIELDS = tuple(f.name for f in dataclasses.fields(LockstepState))
PER_CHAIN = ("position", "logdensity", "grad", "arg")


def whole(tree, S: int):
    """The draws `(theta, sigma, rho, (lp, ...), LockstepState)` of units in `S` shares
    (:func:`in_shares`) as the units' whole chains."""
    if S == 1:
        return tree
    *draws, after = tree
    merge = lambda a: np.asarray(a).reshape(-1, S * a.shape[1], *a.shape[2:])
    after = LockstepState(**{f: merge(getattr(after, f)) if f in PER_CHAIN else
                             np.asarray(getattr(after, f))[::S] for f in FIELDS})
    return (*jax.tree.map(merge, tuple(draws)), after)
