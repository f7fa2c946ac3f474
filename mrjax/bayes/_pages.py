"""Pages of units and where they run: how the sampler's compiled calls are cut and spread over
the CPU devices (or the one accelerator).

A call runs one page of units, padded to one compiled shape. The calls are given to the
devices longest first, each to the device with the least work so far (:func:`assign`), one
host thread per device, so that the devices stay busy to the end; each device runs calls of
its own, no collective between them (XLA aborts a program whose devices wait for each other's
collective longer than 40 s). Several CPU devices (`JAX_NUM_CPU_DEVICES`) are so many threads
running calls side by side on the first device (:func:`spread`).
ChEES's draws run in pages of units of similar adapted trajectory length
(:func:`sorted_pages`): a vmapped page advances at its longest trajectory, so a short unit
paged with a long one waits for it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

import jax
import numpy as np

from ._sampler import Sampler, vectorized

#: The fixed cost of one batched step of a page, in chains' gradients: a batch of c chains of
#: a dynamic model's views costs about (PAGE_OVERHEAD + c) single chains' gradients (the
#: integration's loop runs once for the batch; `benchmarks/posterior.md`).
PAGE_OVERHEAD = 6.0


def pages(n: int, page: int) -> list[np.ndarray]:
    """Indices `0..n-1` in pages of `page`, the last padded by repeating its last index (one
    compiled shape for all pages)."""
    return [np.minimum(np.arange(s, s + page), n - 1) for s in range(0, n, page)]


def page_size(sampler: Sampler, n: int, first: int | None) -> int:
    """Units per page for `n` units: the kernel's page (:meth:`ChEES.page_size`), in a
    continuation (`first` the first round's page) the smallest power of two that holds them,
    at most `first` (few compiled shapes); at most an equal share of the units per CPU
    device (each device runs pages of its own)."""
    page = sampler.kernel.page_size(n, sampler.chains)
    if first is not None:
        page = min(first, 1 << (n - 1).bit_length())
    d = jax.local_device_count()
    return max(1, min(page, -(-n // d)))  # at least one page per device


def assign(costs: Sequence[float], n_devices: int) -> tuple[np.ndarray, float]:
    """Devices for calls of predicted `costs` (longest processing time first: each call, the
    costliest first, to the device with the least work so far): `(device of each call,
    the busiest device's work)`."""
    load = np.zeros(max(int(n_devices), 1))
    where = np.zeros(len(costs), int)
    for i in np.argsort(-np.asarray(costs, float), kind="stable"):
        where[i] = int(np.argmin(load))
        load[where[i]] += costs[i]
    return where, float(load.max(initial=0.0))


def page_cost(n_leapfrog: np.ndarray, sampler: Sampler, chains: int | None = None) -> float:
    """Predicted cost of one step of a page whose units of `chains` chains (default
    `sampler.chains`) take `n_leapfrog` (page,) mean leapfrog steps per draw, in chains'
    gradients: its units vmapped (`"all"`) wait for the longest; mapped ones each take their
    own."""
    C = sampler.chains if chains is None else int(chains)
    n = np.asarray(n_leapfrog, float)
    if vectorized(sampler) == "all":
        return float(n.max()) * (PAGE_OVERHEAD + n.size * C)
    return float(np.sum(n)) * (PAGE_OVERHEAD + C)


def sorted_pages(n_leapfrog: np.ndarray, sampler: Sampler, most: int, n_devices: int,
                 chains: int | None = None) -> tuple[list[np.ndarray], float]:
    """The units of adapted trajectory lengths `n_leapfrog` (U,) in pages of one size (one
    compiled shape) of units of similar length: the size among `most`, `most / 2`, ... that
    leaves the busiest device the least predicted work (:func:`page_cost` of units of
    `chains` chains, :func:`assign`). Returns `(pages, the busiest device's work per
    step)`."""
    n_leapfrog = np.asarray(n_leapfrog, float)
    order = np.argsort(n_leapfrog, kind="stable")
    best, best_work = None, np.inf
    size = max(int(most), 1)
    while True:
        cut = [order[idx] for idx in pages(order.size, size)]
        _, work = assign([page_cost(n_leapfrog[p], sampler, chains) for p in cut], n_devices)
        if work < best_work * (1.0 - 1e-9):  # a smaller size only where it saves work
            best, best_work = cut, work
        if size == 1:
            return best, best_work
        size = max(size // 2, 1)


#: A unit's chains are shared out over the devices only where that cuts the busiest device's
#: predicted work by more than this fraction (each share's shape is one more compiled
#: program).
SHARE_GAIN = 0.1


def shared_pages(n_leapfrog: np.ndarray, sampler: Sampler, most: int,
                 n_devices: int) -> tuple[int, list[np.ndarray]]:
    """Pages of draws (:func:`sorted_pages`) of units of trajectory lengths `n_leapfrog` (U,),
    each unit whole or its chains in `shares` equal shares, units of their own (unit `j //
    shares`, share `j % shares`; lockstep draws have no interaction between a unit's
    chains): in as many shares as devices (the most that divide the chains) where that
    leaves the busiest device `SHARE_GAIN` less work, e.g. a few long units left on more
    devices than units. Returns `(shares, pages of those units)`."""
    C = sampler.chains
    S = max(d for d in range(1, min(max(int(n_devices), 1), C) + 1) if C % d == 0)
    whole, work = sorted_pages(n_leapfrog, sampler, most, n_devices)
    if S == 1:
        return 1, whole
    split, work_s = sorted_pages(np.repeat(np.asarray(n_leapfrog, float), S), sampler,
                                 most * S, n_devices, C // S)
    return (S, split) if work_s < work * (1.0 - SHARE_GAIN) else (1, whole)


def spread(calls: list[tuple[Callable, tuple]], costs: Sequence[float] | None = None) -> list:
    """`calls` `[(fn, args), ...]` on the local devices (:func:`assign` by `costs`, or in
    turn), each device's costliest first, the devices side by side: one host thread per
    device (a compiled call of `equinox.filter_jit` returns only when its outputs are ready,
    so calls made one after another from one thread would run one device at a time). Their
    host outputs in the order of `calls`.

    CPU devices share one memory and the same cores: there the threads all run their calls on
    the first device, side by side, so that a program is compiled once rather than once per
    device (JAX compiles a program for each device it runs on, and a dynamic model's sampler
    takes 10-20 s to compile)."""
    devices = jax.local_devices()
    costs = np.ones(len(calls)) if costs is None else np.asarray(costs, float)
    where, _ = assign(costs, len(devices))
    order = np.argsort(-costs, kind="stable")
    place = len(devices) > 1 and devices[0].platform != "cpu"

    def run(d: int) -> list:
        done = []
        for i in order[where[order] == d]:
            fn, args = calls[i]
            if place:
                args = jax.device_put(args, devices[d])
            done.append((i, jax.device_get(fn(*args))))
        return done

    busy = sorted(set(where.tolist()))
    if len(busy) == 1:
        parts = [run(busy[0])]
    else:
        with ThreadPoolExecutor(max_workers=len(busy)) as pool:
            parts = list(pool.map(run, busy))
    outs: list = [None] * len(calls)
    for i, out in (x for part in parts for x in part):
        outs[i] = out
    return outs
