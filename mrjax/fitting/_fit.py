"""`mrjax.fit`: the keyword options onto settings objects, then the chunk layer, which builds
the per-test problem of every chunk and calls the engine."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any

from jaxtyping import ArrayLike

from ..data import Batch, Condition, Source, as_batch
from ..engine import Polish, Swarm
from ..models import AbstractModel, get
from ..pso import PSOParams
from ._chunks import fit_in_chunks
from ._result import FitResult
from ._run import make_run


def fit(
    model: str | AbstractModel,
    data: Batch | Condition | Sequence[Condition] | str | os.PathLike | Source,
    *,
    method: str = "pso+lm",
    swarm: Swarm | None = None,
    polish: Polish | None = None,
    key: ArrayLike | None = None,
    seed: int = 0,
    bounds: tuple[ArrayLike, ArrayLike] | None = None,
    transient: float | str | None = None,
    swarm_mode: str | None = None,
    n_particles: int | None = None,
    max_generations: int | None = None,
    generations: int | None = None,
    pso_params: PSOParams | None = None,
    restarts: int | None = None,
    swarm_view: bool | None = None,
    swarm_dtype: Any = None,
    polish_steps: int | None = None,
    polish_tol: float | None = None,
    uncertainty: bool | None = None,
    retry: bool | None = None,
    progress: bool | None = False,
    devices: Sequence | None = None,
    callback: Callable | None = None,
    max_memory: int | float | str | None = None,
    chunk_size: int | None = None,
    journal: str | os.PathLike | None = None,
    resume: bool = False,
) -> FitResult:
    """Identify `model` on every test condition of `data` at once.

    The settings are objects, passed the optimistix way (`swarm=mrjax.Swarm(...)`,
    `polish=mrjax.Polish(...)`); the keyword options below set single fields of them (a
    keyword given wins over the object's field).

    **Arguments:**

    - `model`: a model name (`"kwok"`, `"bouc_wen"`, ...) or object.
    - `data`: a `mrjax.data.Batch`, condition(s), file/directory path(s), or a
        `mrjax.data.Source` (tests indexed in their files: read chunk by chunk when it does
        not hold them, so that `max_memory` bounds the whole process; same result).
    - `method`: `"pso+lm"` (swarm, then the Levenberg-Marquardt polish; default), `"pso"`
        (swarm only), or `"lm"` (polish alone from the model's default start: it shows why the
        swarm is needed). Where `bounds` exclude the default start, it is clipped onto them.
    - `swarm`: a :class:`mrjax.Swarm` (default `Swarm()`: 50 particles, at most 200
        generations with the statistical stop, one swarm per test (two for an ODE model on a
        single test, `mrjax.fitting.default_restarts`), separable, a view of the records for
        the ODE models).
    - `polish`: a :class:`mrjax.Polish` (default `Polish()`: at most 200 steps, tol 1e-6,
        std-errors, the retry from the neighbours' optima).
    - `key`: JAX PRNG key; default `jax.random.key(seed)`. Same key, same result.
    - `seed`: integer seed used when `key` is None, and recorded in the result.
    - `bounds`: `(lower, upper)`, (P,) arrays or dicts by name, SI units (default
        `model.bounds`).
    - `transient`: drop an initial span from the fitness: seconds, `"cycle"`, or None.
    - `swarm_mode` (`"separable"`: variable projection, or `"full"`: the paper's swarm),
        `n_particles`, `max_generations`, `generations` (exactly this many, no statistical
        stop; for benchmarks), `pso_params` (:class:`mrjax.pso.PSOParams`), `restarts`
        (independent swarms per condition in one compiled program, the best polished; guards
        the many-parameter ODE models against a swarm that ends in a poor basin; the reported
        generations, stop flag and history are the chosen swarm's; None: the default above),
        `swarm_view` (score the swarm and a first polish on a subsampled view of each record,
        about 128 samples per period, the first whole periods up to about 1,000 samples, see
        `mrjax.data.swarm_view`; None: for the ODE models; every reported RMS, including
        `pso_rms`, is on the full record), `swarm_dtype` (e.g. `"float32"`: about twice as
        fast on CPU; the swarm's best positions are re-scored, polished and reported in
        float64): fields of `swarm`.
    - `polish_steps`, `polish_tol` (the polish stops when 8 steps lower the RMS by less than
        this fraction, see `mrjax.refine.lm_solve`; with a swarm view a first polish on the
        view stops at `VIEW_TOL_FACTOR` (10) times it, then the full record is refined to
        `FULL_TOL_FACTOR` (100) times it, in at most `FULL_MAX_STEPS` (4) steps),
        `uncertainty` (std-errors and intervals; also for `method="pso"`), `retry` (polish
        every test again from the best of its neighbours' optima, see
        `mrjax.fitting.retry_starts`; the better is kept and both are reported in
        `FitResult.starts_rms`, with a warning where they disagree): fields of `polish`.
    - `progress`: show a progress bar (None: only on a TTY).
    - `devices`: shard the condition axis over these devices: `"all"`, a count, or a list of
        `jax.Device` (default: one device); see `mrjax.parallel`. Same key, same result.
    - `callback`: host callback for the swarm, see `mrjax.pso.swarm` (called per chunk, with
        the chunk's conditions).
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

    Each chunk builds the per-test problem (`mrjax.fitting.TestsProblem`) and runs the engine
    (`mrjax.engine.solve`: view, swarm, view polish, full-record polish, uncertainty); the
    stages are timed in `FitResult.timings` [s] (summed over the chunks).

    **Returns:** a :class:`FitResult`.

    Raises :class:`mrjax.InputError` for bad options or data, including a condition with no
    more scored samples than the model has parameters. Warns (`RuntimeWarning`) for a condition
    whose record is shorter than one excitation period (known frequency): it has no complete
    hysteresis loop, so its parameters are poorly determined.
    """
    run = make_run(method=method, swarm=swarm, polish=polish, key=key, seed=seed, bounds=bounds,
                   transient=transient, devices=devices, progress=progress, callback=callback,
                   swarm_mode=swarm_mode, n_particles=n_particles,
                   max_generations=max_generations, generations=generations,
                   pso_params=pso_params, restarts=restarts, swarm_view=swarm_view,
                   swarm_dtype=swarm_dtype, polish_steps=polish_steps, polish_tol=polish_tol,
                   uncertainty=uncertainty, retry=retry)
    data = data if isinstance(data, Source) else as_batch(data)
    return fit_in_chunks(get(model), data, run, max_memory=max_memory,
                         chunk_size=chunk_size, journal=journal, resume=resume)
