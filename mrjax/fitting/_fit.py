"""`mrjax.fit`: the settings objects resolved once, then the chunk layer, which builds the
per-test problem of every chunk and calls the engine."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence

from jaxtyping import ArrayLike

from ..data import Batch, Condition, Source, as_batch
from ..engine import Chunks, Polish, Swarm
from ..models import AbstractModel, fix, get
from ._chunks import fit_in_chunks
from ._result import FitResult
from ._run import make_run


def fit(
    model: str | AbstractModel,
    data: Batch | Condition | Sequence[Condition] | str | os.PathLike | Source,
    *,
    swarm: Swarm | None = Swarm(),
    polish: Polish | None = Polish(),
    key: int | ArrayLike = 0,
    bounds: tuple[ArrayLike, ArrayLike] | None = None,
    fixed: Mapping[str, float] | None = None,
    transient: float | str | None = None,
    chunks: Chunks | None = None,
    progress: bool | None = False,
) -> FitResult:
    """Identify `model` on every test condition of `data` at once.

    The settings are objects, passed the optimistix way: `mrjax.fit(model, data)` is the short
    form, `mrjax.fit(model, data, swarm=mrjax.Swarm(restarts=2), polish=mrjax.Polish(tol=1e-8),
    key=1)` the long one.

    **Arguments:**

    - `model`: a model name (`"kwok"`, `"bouc_wen"`, ...; see `mrjax.models.names`), a file
        and class (`"path/to/mine.py:Mine"`) or a model object.
    - `data`: a `mrjax.data.Batch`, condition(s), file/directory path(s), or a
        `mrjax.data.Source` (tests indexed in their files: read chunk by chunk when it does
        not hold them, so that `chunks.max_memory` bounds the whole process; same result).
    - `swarm`: the batched particle swarm's :class:`mrjax.Swarm` (default: 50 particles, at
        most 200 generations with the paper's statistical stop, separable, one swarm per test
        (two for an ODE model on a single test), on a view of each record for the ODE
        models). `None`: no swarm; the polish starts from the model's default start (clipped
        onto the bounds), which shows why the swarm is needed.
    - `polish`: the Levenberg-Marquardt polish's :class:`mrjax.Polish` (default: at most 200
        steps, tol 1e-6, std-errors, the retry from the neighbours' optima). `None`: the
        swarm's best is the result (the paper's method); its std-errors are still computed.
    - `key`: an integer seed or a JAX PRNG key (one, or one per swarm row). Same key, same
        result; an integer is recorded in the result as its `seed`.
    - `bounds`: `(lower, upper)`, (P,) arrays or dicts by name, SI units (default the model's
        bounds).
    - `fixed`: parameter name -> value [SI]: those parameters are held at the value by every
        stage (see `mrjax.models.fix`); the result's model is the fixed one.
    - `transient`: drop an initial span from the fitness: seconds, `"cycle"`, or None.
    - `chunks`: a :class:`mrjax.Chunks` (memory budget, chunk size, journal and resume,
        devices); default `Chunks()`. The result does not depend on it.
    - `progress`: show a progress bar (None: only on a terminal).

    Each chunk builds the per-test problem (`mrjax.fitting.TestsProblem`) and runs the engine
    (`mrjax.engine.solve`: view, swarm, view polish, full-record polish, uncertainty); the
    stages are timed in `FitResult.timings` [s] (summed over the chunks).

    **Returns:** a :class:`mrjax.FitResult`.

    Raises :class:`mrjax.InputError` for bad settings or data, including a condition with no
    more scored samples than the model has parameters. Warns (`RuntimeWarning`) for a condition
    whose record is shorter than one excitation period (known frequency): it has no complete
    hysteresis loop, so its parameters are poorly determined.
    """
    model = get(model)
    if fixed:
        model = fix(model, fixed)
    data = data if isinstance(data, Source) else as_batch(data)
    run = make_run(model, data.n_conditions, swarm=swarm, polish=polish, key=key,
                   bounds=bounds, transient=transient, chunks=chunks, progress=progress)
    return fit_in_chunks(model, data, run, key)
