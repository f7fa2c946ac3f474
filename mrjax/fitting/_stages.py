"""`mrjax.fit` in named stages: prepare -> swarm -> polish -> evaluate.

Each stage is a function of a :class:`Problem` (the checked inputs, built once by
:func:`prepare`) and of the previous stage's small result, so a stage can be run, timed, tested
or replaced on its own.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from ..data import Batch, Condition, load, make_batch
from ..models import AbstractModel, check_bounds, get, resolve_model
from ..objective import fit_mask, nrmse, rms_per_condition
from ..parallel import shard_batch, unpad
from ..pso import PSOParams, default_params
from ..refine import (
    DEFAULT_TOL,
    FULL_MAX_STEPS,
    FULL_TOL_FACTOR,
    VIEW_TOL_FACTOR,
    Uncertainty,
    polish,
    uncertainty,
)
from ._result import FitResult
from ._swarm import auto_page_size, fit_swarm
from ._view import View, swarm_view

Method = Literal["pso", "pso+lm", "lm"]
SwarmMode = Literal["separable", "full"]


def as_batch(data: Batch | Condition | Sequence[Condition] | str | os.PathLike | Sequence) -> Batch:
    """Accept a :class:`mrjax.data.Batch`, one or more :class:`mrjax.data.Condition`, or
    file/directory path(s) (read by `mrjax.data.load`)."""
    if isinstance(data, Batch):
        return data
    if isinstance(data, Condition):
        return make_batch([data])
    if isinstance(data, (str, os.PathLike)):
        return make_batch(load(data))
    data = list(data)
    if data and all(isinstance(d, (str, os.PathLike)) for d in data):
        return make_batch(load(data))
    return make_batch(data)


@dataclasses.dataclass(frozen=True, eq=False)
class Problem:
    """What :func:`prepare` checked and built, passed to every later stage.

    **Fields:** `model`; `batch` and `mask` (C, T) as placed on the devices (padded to a
    multiple of the device count when sharded); `source` the unpadded batch; `view` the
    swarm's subsampled view of it (see `mrjax.fitting.swarm_view`) or None; `n_real` its
    number of conditions; `lower`, `upper` (P,) bounds [SI]; `key`, `seed`; `method`,
    `swarm_mode`, `transient`, `devices`; `swarm_options` keyword arguments of
    :func:`fit_swarm`; `restarts`; `polish_steps`; `uncertainty`; `progress`; `callback`.
    """

    model: AbstractModel
    batch: Batch
    mask: Any
    source: Batch
    view: View | None
    n_real: int
    lower: np.ndarray
    upper: np.ndarray
    key: Any
    seed: int
    method: str
    swarm_mode: str
    transient: float | str | None
    devices: Any
    swarm_options: dict[str, Any]
    restarts: int
    polish_steps: int
    polish_tol: float
    uncertainty: bool
    progress: bool | None
    callback: Callable | None

    @property
    def n_conditions(self) -> int:
        """Conditions as placed (with device padding)."""
        return self.batch.n_conditions


@dataclasses.dataclass(frozen=True)
class SwarmStage:
    """Per-condition outcome of the swarm stage (host arrays, C conditions as placed).

    `theta` (C, P) the start of the polish; `pso_rms` (C,) [N] (NaN without a swarm);
    `generations` (C,) (-1 without a swarm); `stopped_by_criterion` (C,); `history` (C, G+1).
    """

    theta: np.ndarray
    pso_rms: np.ndarray
    generations: np.ndarray
    stopped_by_criterion: np.ndarray
    history: np.ndarray


@dataclasses.dataclass(frozen=True)
class PolishStage:
    """Outcome of the polish stage: `theta` (C, P), `steps` (C,), `status` per condition, and
    the `uncertainty` at `theta` (or None)."""

    theta: np.ndarray
    steps: np.ndarray
    status: tuple[str, ...]
    uncertainty: Uncertainty | None
    timings: dict[str, float] = dataclasses.field(default_factory=dict)


def _check_records(model: AbstractModel, batch: Batch, mask) -> None:
    """Error for fewer scored samples than parameters + 1; warning for a record shorter than
    one excitation period."""
    n = np.asarray(mask).sum(axis=1)
    short = np.flatnonzero(n <= model.n_params)
    if short.size:
        i = int(short[0])
        raise InputError(
            f"condition {batch.labels[i]!r}: {int(n[i])} scored samples are too few for model "
            f"{model.name!r} with {model.n_params} parameters (at least {model.n_params + 1} "
            f"needed)")
    m = np.asarray(mask)
    rows = np.arange(m.shape[0])
    first, last = np.argmax(m, axis=1), m.shape[1] - 1 - np.argmax(m[:, ::-1], axis=1)
    t, dt = np.asarray(batch.t), np.asarray(batch.dt)
    span = t[rows, last] - t[rows, first] + dt[rows, last]  # scored duration, last interval in
    freq = np.asarray(batch.frequency, float)
    with np.errstate(invalid="ignore"):
        partial = np.flatnonzero(np.isfinite(freq) & (freq > 0) & (span * freq < 0.99))
    if partial.size:
        i = int(partial[0])
        warnings.warn(
            f"condition {batch.labels[i]!r}: the scored record spans {span[i]:.3g} s, less than "
            f"one period of its {freq[i]:g} Hz excitation ({partial.size} such condition(s)); "
            f"its parameters are poorly determined", RuntimeWarning, stacklevel=4)


def _place(batch: Batch, mask, devices) -> tuple[Batch, Any]:
    """The batch and mask on the devices (sharded and padded), or as they are."""
    return (batch, mask) if devices is None else shard_batch(batch, mask, devices)


def prepare(model: str | AbstractModel, data: Any, options: Mapping[str, Any]) -> Problem:
    """Stage 1 of `mrjax.fit`: check every option and the data, build the fit mask, place the
    batch on the devices.

    **Arguments:** `model`, `data` as `mrjax.fit`; `options` the keyword arguments of
    `mrjax.fit` (all of them, by name: `method`, `swarm_mode`, `key`, `seed`, ...). `key` may
    also be one key per swarm row (`restarts` x C, copy k of condition i at row k*C + i: how
    the chunk layer gives each condition the stream it has in the whole batch), and the
    optional `view_length` pads the swarm's view to that many samples (the view length of the
    whole batch, so that every chunk sums over the same samples); `checked=True` skips the
    checks of the records (a chunk of a batch that passed them).

    Raises :class:`mrjax.InputError`.
    """
    o = dict(options)
    method, swarm_mode, seed = o["method"], o["swarm_mode"], o["seed"]
    pso_params, max_generations, generations = (o["pso_params"], o["max_generations"],
                                                o["generations"])
    restarts, devices, key = o["restarts"], o["devices"], o["key"]
    model = get(model)
    if method not in ("pso", "pso+lm", "lm"):
        raise InputError(f"method must be 'pso', 'pso+lm' or 'lm', got {method!r}")
    if swarm_mode not in ("separable", "full"):
        raise InputError(f"swarm must be 'separable' or 'full', got {swarm_mode!r}")
    source = as_batch(data)
    lo, hi = check_bounds(model, o["bounds"])
    mask = fit_mask(source, o["transient"])
    if not o.get("checked"):  # a chunk of a batch checked as a whole is not checked again
        _check_records(model, source, mask)
    if key is None:
        key = jax.random.key(int(seed))
    if generations is not None:
        if int(generations) < 1:
            raise InputError(f"generations must be at least 1, got {generations}")
        base = pso_params or default_params(swarm_mode)
        pso_params = eqx.tree_at(lambda p: p.criterion, base, jnp.asarray(False))
        max_generations = int(generations)
    if isinstance(restarts, bool) or int(restarts) != restarts or restarts < 1:
        raise InputError(f"restarts must be an integer >= 1, got {restarts!r}")
    batch, placed_mask = _place(source, mask, devices)
    use_view = o["swarm_view"]
    if use_view is None:
        use_view = model.dynamic
    view = (swarm_view(source, o["transient"], length=o.get("view_length"))
            if use_view and method != "lm" else None)
    swarm_options = dict(mode=swarm_mode, bounds=(lo, hi), params=pso_params,
                         n_particles=o["n_particles"], max_generations=int(max_generations),
                         dtype=o["swarm_dtype"])
    return Problem(
        model=model, batch=batch, mask=placed_mask, source=source, view=view,
        n_real=source.n_conditions,
        lower=lo, upper=hi, key=key, seed=int(seed), method=method, swarm_mode=swarm_mode,
        transient=o["transient"], devices=devices, swarm_options=swarm_options,
        restarts=int(restarts), polish_steps=int(o["polish_steps"]),
        polish_tol=float(o["polish_tol"]),
        uncertainty=bool(o["uncertainty"]), progress=o["progress"], callback=o["callback"])


def _progress_callback(enabled: bool | None, max_generations: int):
    """A tqdm bar driven from inside the compiled swarm, or None (costs nothing)."""
    if enabled is None:
        enabled = sys.stderr.isatty()
    if not enabled:
        return None, None
    from tqdm.auto import tqdm  # imported here: only a terminal run draws a bar

    bar = tqdm(total=max_generations, desc="swarm", unit="gen", leave=False, file=sys.stderr)

    def cb(gen, done, best):
        g = int(np.max(gen))
        bar.n = min(g, max_generations)
        finite = best[np.isfinite(best)]
        bar.set_postfix(running=int(np.sum(~done)),
                        best=f"{np.max(finite):.3g}N" if finite.size else "-", refresh=False)
        bar.refresh()

    return cb, bar


def _callbacks(p: Problem):
    """The swarm's host callback (progress bar and/or the user's) and the bar to close."""
    cb, bar = _progress_callback(p.progress, p.swarm_options["max_generations"])
    if p.callback is None:
        return cb, bar
    user_cb, prog_cb = p.callback, cb

    def both(g, d, b):
        if prog_cb is not None:
            prog_cb(g, d, b)
        user_cb(g, d, b)

    return both, bar


def _best_restart(n: int, k: int, c: int, *arrays):
    """Rows of the best of `k` swarms per condition (copy j of condition i at row j*n + i,
    best = lowest finite RMS, the second array), padded back to `c` rows with copies of the
    last condition (as `shard_batch` pads)."""
    rms = np.asarray(arrays[1], float)[: n * k].reshape(k, n)
    best = np.argmin(np.where(np.isfinite(rms), rms, np.inf), axis=0)
    rows = best * n + np.arange(n)
    rows = np.concatenate([rows, np.full(c - n, rows[-1])])
    return tuple(np.asarray(a)[rows] for a in arrays)


def run_swarm(p: Problem) -> SwarmStage:
    """Stage 2: the batched swarm on every condition (`restarts` independent swarms each, the
    best kept), or the model's neutral start for `method="lm"`."""
    C, P = p.n_conditions, p.model.n_params
    if p.method == "lm":
        theta = np.broadcast_to(np.clip(p.model.default_start(), p.lower, p.upper), (C, P))
        return SwarmStage(theta.copy(), np.full(C, np.nan), np.full(C, -1), np.zeros(C, bool),
                          np.zeros((C, 0)))
    source = p.source if p.view is None else p.view.batch
    if p.restarts > 1:  # every condition `restarts` times: copy k of condition i at row k*n + i
        source = source.subset(np.tile(np.arange(p.n_real), p.restarts))
        batch, mask = _place(source, fit_mask(source, p.transient), p.devices)
    elif p.view is not None:
        batch, mask = _place(source, p.view.mask, p.devices)
    else:
        batch, mask = p.batch, p.mask
    cb, bar = _callbacks(p)
    try:
        # sharded over devices, the pages' gathers would move data between them: one batch
        page = "auto" if p.devices is None else None
        sw = fit_swarm(p.model, batch, key=p.key, mask=mask, callback=cb, page_size=page,
                       **p.swarm_options)
        jax.block_until_ready(sw.rms)
    finally:
        if bar is not None:
            bar.close()
    out = (np.asarray(sw.theta), np.asarray(sw.rms, float), np.asarray(sw.result.generations),
           np.asarray(sw.result.stopped_by_criterion), np.asarray(sw.result.history))
    if p.restarts > 1:
        out = _best_restart(p.n_real, p.restarts, C, *out)
    if p.view is not None:  # the swarm's RMS on the full record, as without a view
        theta = out[0]
        model = resolve_model(p.model, theta, p.batch.xdot, p.batch.dt, p.batch.mask)
        out = (theta, rms_per_condition(model, theta, p.batch, p.mask), *out[2:])
    return SwarmStage(*out)


def run_polish(p: Problem, start: SwarmStage) -> PolishStage:
    """Stage 3: the Levenberg-Marquardt polish from the swarm's best (methods `"pso+lm"` and
    `"lm"`), with the uncertainty at the result; for `"pso"` only the uncertainty (if
    asked)."""
    C = p.n_conditions
    if p.method in ("pso+lm", "lm"):
        theta, timings = start.theta, {}
        if p.view is not None:  # converge on the swarm's view first: its steps are cheap
            t0 = time.perf_counter()
            vb, vm = _place(p.view.batch, p.view.mask, p.devices)
            # the swarm's integration: on the view's coarse grid step doubling would ask for
            # many steps, and this phase only has to bring the full-record polish close
            view_model = resolve_model(p.model, theta, vb.xdot, vb.dt, vb.mask, swarm=True)
            # in pages: the solves differ a lot in length (MBW on the UTFSM views: 5 to 118
            # steps), and a page stops with its own slowest (warm 13.7 -> 11.2 s)
            page = auto_page_size(p.model, C) if p.devices is None else None
            first = polish(view_model, theta, vb, mask=vm, lower=p.lower, upper=p.upper,
                           max_steps=p.polish_steps, tol=p.polish_tol * VIEW_TOL_FACTOR,
                           uncertainty=False, page_size=page)
            theta = np.asarray(first.theta)
            timings["polish_view"] = time.perf_counter() - t0
        # from the view's converged point the full record needs only a refinement (measured
        # on the 30 UTFSM tests, modified Bouc-Wen: it lowers the RMS by 0.02 % (median),
        # 0.23 % at most, 95 % of that in the first 4 steps: 4 steps of the full record cost
        # as much as the whole view polish)
        tol, steps = p.polish_tol, p.polish_steps
        if p.view is not None:
            tol, steps = tol * FULL_TOL_FACTOR, min(steps, FULL_MAX_STEPS)
        pol = polish(p.model, theta, p.batch, mask=p.mask, lower=p.lower, upper=p.upper,
                     max_steps=steps, tol=tol)
        status = tuple(str(s) for s in pol.status)
        if p.view is not None:  # a refinement that used its few steps is what was asked for
            status = tuple(_refined(a, b) for a, b in zip(first.status, status))
        return PolishStage(np.asarray(pol.theta), np.asarray(pol.steps), status,
                           pol.uncertainty if p.uncertainty else None, timings)
    unc = uncertainty(p.model, start.theta, p.batch, mask=p.mask) if p.uncertainty else None
    return PolishStage(start.theta, np.zeros(C, int), ("none",) * C, unc)


def _refined(view_status: str, full_status: str) -> str:
    """The status of a two-phase polish: `"refined"` where the view polish converged and the
    full-record refinement ran its `FULL_MAX_STEPS` (or converged), else the first failure."""
    if full_status in ("max_steps_reached", "successful", "kept_start") and \
            view_status == "successful":
        return "refined" if full_status != "kept_start" else "successful"
    return full_status if full_status not in ("max_steps_reached", "successful") else view_status


def evaluate(p: Problem, sw: SwarmStage, pol: PolishStage, timings: dict[str, float]) -> FitResult:
    """Stage 4: score the final parameters (sub-steps resolved from them, uncapped), NRMSE,
    assemble the :class:`FitResult` and cut off the device padding."""
    batch, mask, model = p.batch, p.mask, p.model
    theta = pol.theta
    final_model = resolve_model(model, theta, batch.xdot, batch.dt, batch.mask)
    rms = rms_per_condition(final_model, theta, batch, mask)
    diverged = np.flatnonzero(~np.isfinite(rms))
    if diverged.size:
        warnings.warn(
            f"condition {batch.labels[diverged[0]]!r}: the model's force is not finite at the "
            f"fitted parameters ({diverged.size} such condition(s)); its RMS is reported as inf "
            f"(null in fit.json): narrow the bounds", RuntimeWarning, stacklevel=3)
    C, P = theta.shape
    unc = pol.uncertainty
    result = FitResult(
        model=model, method=p.method, swarm_mode=p.swarm_mode if p.method != "lm" else "none",
        seed=p.seed, labels=tuple(batch.labels), current=np.asarray(batch.current, float),
        frequency=np.asarray(batch.frequency, float), amplitude=np.asarray(batch.amplitude, float),
        n_samples=np.asarray(np.asarray(mask).sum(axis=1), int), theta=theta, rms=rms,
        nrmse=nrmse(rms, batch.force, mask), pso_rms=sw.pso_rms, generations=sw.generations,
        stopped_by_criterion=sw.stopped_by_criterion, history=sw.history,
        polish_steps=pol.steps, polish_status=pol.status,
        stderr=np.full((C, P), np.nan) if unc is None else np.asarray(unc.stderr, float),
        ci95=np.full((C, P, 2), np.nan) if unc is None else np.asarray(unc.ci95, float),
        corr=np.full((C, P, P), np.nan) if unc is None else np.asarray(unc.corr, float),
        identifiable=np.ones((C, P), bool) if unc is None else np.asarray(unc.identifiable, bool),
        timings=timings, estimated=np.asarray(batch.estimated, bool),
        bounds={"lower": np.asarray(p.lower, float), "upper": np.asarray(p.upper, float)},
    )
    return unpad(result, p.n_real) if result.n_conditions != p.n_real else result


def fit(
    model: str | AbstractModel,
    data: Batch | Condition | Sequence[Condition] | str | os.PathLike,
    *,
    method: Method = "pso+lm",
    swarm_mode: SwarmMode = "separable",
    key: ArrayLike | None = None,
    seed: int = 0,
    bounds: tuple[ArrayLike, ArrayLike] | None = None,
    transient: float | str | None = None,
    n_particles: int = 50,
    max_generations: int = 200,
    generations: int | None = None,
    pso_params: PSOParams | None = None,
    polish_steps: int = 200,
    polish_tol: float = DEFAULT_TOL,
    uncertainty: bool = True,
    progress: bool | None = False,
    devices: Sequence | None = None,
    callback: Callable | None = None,
    swarm_dtype: Any = None,
    restarts: int = 1,
    swarm_view: bool | None = None,
    max_memory: int | float | str | None = None,
    chunk_size: int | None = None,
    journal: str | os.PathLike | None = None,
    resume: bool = False,
    swarm: SwarmMode | None = None,
) -> FitResult:
    """Identify `model` on every test condition of `data` at once.

    **Arguments:**

    - `model`: a model name (`"kwok"`, `"bouc_wen"`, ...) or object.
    - `data`: a `mrjax.data.Batch`, condition(s), or file/directory path(s).
    - `method`: `"pso+lm"` (swarm, then the Levenberg-Marquardt polish; default), `"pso"`
        (swarm only), or `"lm"` (polish alone from the model's default start: it shows why the
        swarm is needed). Where `bounds` exclude the default start, it is clipped onto them.
    - `swarm_mode`: `"separable"` (variable projection; default) or `"full"` (the paper's
        swarm). `swarm=` is its deprecated alias (one release).
    - `key`: JAX PRNG key; default `jax.random.key(seed)`. Same key, same result.
    - `seed`: integer seed used when `key` is None, and recorded in the result.
    - `bounds`: `(lower, upper)`, (P,) arrays or dicts by name, SI units (default
        `model.bounds`).
    - `transient`: drop an initial span from the fitness: seconds, `"cycle"`, or None.
    - `n_particles`, `max_generations`: swarm size and generation cap.
    - `generations`: run exactly this many generations (no statistical stop; for benchmarks).
    - `pso_params`: :class:`mrjax.pso.PSOParams` hyperparameters.
    - `polish_steps`: maximum Levenberg-Marquardt steps.
    - `polish_tol`: the polish stops when 8 steps lower the RMS by less than this fraction
        (see `mrjax.refine.lm_solve`). With a swarm view (see `swarm_view`) a first polish on
        the view stops at `VIEW_TOL_FACTOR` (10) times it, then the full record is refined to
        `FULL_TOL_FACTOR` (100) times it, in at most `FULL_MAX_STEPS` (4) steps.
    - `uncertainty`: compute std-errors and intervals (needs the polish machinery; also for
        `method="pso"`).
    - `progress`: show a progress bar (None: only on a TTY).
    - `devices`: shard the condition axis over these devices: `"all"`, a count, or a list of
        `jax.Device` (default: one device); see `mrjax.parallel`. Same key, same result.
    - `callback`: host callback for the swarm, see `mrjax.pso.swarm` (called per chunk, with
        the chunk's conditions).
    - `swarm_dtype`: float dtype of the swarm's search, e.g. `"float32"` (about twice as fast
        on CPU; see benchmarks/results.md). Default: the default float (float64 when x64 is
        on). The swarm's best positions are re-scored, polished and reported in float64.
    - `restarts`: run this many independent swarms per condition (one compiled program: the
        conditions are repeated along the batch axis, each copy with its own random stream) and
        polish the best of them. Costs `restarts` times the swarm; guards the many-parameter
        ODE models (modified Bouc-Wen) against a swarm that ends in a poor basin. The reported
        generations, stop flag and history are those of the chosen swarm. Default 1.
    - `swarm_view`: let the swarm (and a first polish) score a subsampled copy of each record
        (about 128 samples per period, the first whole periods up to about 1,000 samples; see
        `mrjax.fitting.swarm_view`), then polish on the full record. `None` (default): for the
        ODE models only, whose cost is one sequential integrator step per sample. Every
        reported RMS, including `pso_rms`, is on the full record.
    - `max_memory`: memory budget of the fit [bytes], or text such as `"8GB"`, `"512MB"`.
        The conditions are fitted in chunks whose estimated working set fits it, every chunk
        with the same shape (one compiled program) and each condition with its own random
        stream, so the result does not depend on the chunking (see `mrjax.fitting.ChunkPlan`;
        for the RK4 ODE models, up to their sub-step choice). Default: the memory the process
        holds plus half of what is available (`DEFAULT_MEMORY_FRACTION`). A budget too small
        for the data and one chunk raises.
    - `chunk_size`: conditions per chunk instead of a budget (raised to the smallest chunk
        that keeps the result independent of the chunking, a multiple of the device count;
        see `mrjax.fitting.plan_chunks`).
    - `journal`: a directory where each finished chunk is written (atomically) when the fit
        has more than one chunk; `resume=True` reuses the chunks it holds, after checking that
        they were written for the same data and options, and fits only the missing ones.
        Without `resume` an existing journal is discarded. The journal is left in place (the
        `mrjax fit` command removes it after writing its outputs); see `mrjax.fitting.Journal`.
    - `resume`: see `journal`.

    The work runs in four stages (:func:`prepare`, :func:`run_swarm`, :func:`run_polish`,
    :func:`evaluate`) per chunk (`mrjax.fitting.fit_in_chunks`), each timed in
    `FitResult.timings` [s] (summed over the chunks).

    **Returns:** a :class:`FitResult`.

    Raises :class:`mrjax.InputError` for bad options or data, including a condition with no
    more scored samples than the model has parameters. Warns (`RuntimeWarning`) for a condition
    whose record is shorter than one excitation period (known frequency): it has no complete
    hysteresis loop, so its parameters are poorly determined.
    """
    options = {k: v for k, v in locals().items() if k not in ("model", "data", "swarm")}
    if swarm is not None:
        warnings.warn("fit(swarm=...) is deprecated; use swarm_mode=", DeprecationWarning,
                      stacklevel=2)
        options["swarm_mode"] = swarm
    # the chunk layer sits above the stages and calls them (imported here: it imports this
    # module)
    from ._chunks import fit_in_chunks

    return fit_in_chunks(model, data, options)
