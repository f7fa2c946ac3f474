"""The identification engine: view -> swarm -> view polish -> full-record polish ->
uncertainty, once, for every problem kind."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from .._errors import InputError
from .._runtime import release_code
from ..refine import Status, solve_box, status_name
from ._problem import AbstractProblem, Outcome, StageOutcome
from ._settings import Polish, Swarm
from ._swarm import run_swarm


def _stages(problem: AbstractProblem, polish: Polish, z: np.ndarray):
    """`(name, tol, max_steps)` of the polish stages from `z` (see `AbstractProblem`)."""
    if problem.has_view and problem.polish_view(z):
        cap = problem.refine_max_steps
        return [("view", polish.tol * problem.view_tol_factor, polish.max_steps),
                ("full", polish.tol * problem.refine_tol_factor,
                 polish.max_steps if cap is None else min(polish.max_steps, cap))]
    return [("full", polish.tol * problem.search_tol_factor, polish.max_steps)]


def solve(
    problem: AbstractProblem,
    *,
    swarm: Swarm | None,
    polish: Polish | None,
    uncertainty: bool = True,
    key: Any = None,
    progress: bool | None = False,
    callback: Callable | None = None,
    start: np.ndarray | None = None,
) -> Outcome:
    """Identify `problem`'s unknowns on every unit at once: the one pipeline of mrjax.

    1. **Swarm** (`swarm` given): the batched particle swarm (`mrjax.pso.swarm`) on the
        records' views (or the records), `swarm.restarts` independent swarms per unit in one
        compiled program, the best kept; without a swarm the `start` given (e.g. a retry from
        other units' optima, see `mrjax.fitting.retry_starts`) or the problem's neutral
        start.
    2. **Start**: the problem ranks its candidates (the swarm's best, a start it was given)
        on the full records (:meth:`AbstractProblem.choose_start`).
    3. **Polish** (`polish` given): bounded Levenberg-Marquardt (`mrjax.refine.solve_box`) on
        the views to a multiple of `polish.tol` where the problem polishes them, then on the
        full records (a refinement after the views, else the search); the result is kept
        per unit only where its RMS on the full records is not above the start's.
    4. **Uncertainty** (`uncertainty`): the problem's linearised uncertainty at the result.

    **Arguments:** `problem` an :class:`AbstractProblem`; `swarm`, `polish` the settings of
    the stages that run (None: skipped); `uncertainty`; `key` the swarm's PRNG key (one, or
    one per swarm row); `progress` a progress bar of the swarm (None: on a terminal);
    `callback` the swarm's host callback; `start` (U, K) the unknowns to polish from instead
    of a swarm's (then `swarm` must be None; the start's `source` is `"given"`).

    **Returns:** an :class:`Outcome` (the caller assembles its result from it), with
    `timings` [s] of `swarm`, `start`, `polish_view`, `polish`, `uncertainty`.
    """
    release_code()  # a long session's compiled programs within the OS's limit on memory maps
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    sw = None
    if start is not None:
        if swarm is not None:
            raise InputError("solve: give a swarm or a start, not both")
        z, source = np.asarray(start, float), "given"
    elif swarm is not None:
        sw, _ = run_swarm(problem, swarm, key, progress=progress, callback=callback)
        z, source = sw.z, "swarm"
        timings["swarm"] = time.perf_counter() - t0
    else:
        z, source = np.asarray(problem.default_start(), float), "default"
    t1 = time.perf_counter()
    start = problem.choose_start(z, source)
    timings["start"] = time.perf_counter() - t1
    z, rms = start.z, start.rms
    stages: list[StageOutcome] = []
    kept = np.zeros(problem.n_units, bool)
    if polish is not None:
        for name, tol, steps in _stages(problem, polish, z):
            t2 = time.perf_counter()
            spec = problem.stage(z, on_view=name == "view")
            sol = solve_box(spec.residual, z, spec.lower, spec.upper, spec.args, spec.n,
                            max_steps=steps, tol=tol, free=spec.free, jacobian=spec.jacobian,
                            scaled=spec.scaled, snap=spec.snap, page_size=spec.page_size)
            z = np.asarray(sol.z)
            status = tuple(Status.KEPT_START if k else status_name(c)
                           for k, c in zip(np.asarray(sol.kept), np.asarray(sol.status)))
            stages.append(StageOutcome(name, np.asarray(sol.steps), status, tol, steps,
                                       spec.integration))
            timings["polish_view" if name == "view" else "polish"] = time.perf_counter() - t2
        t3 = time.perf_counter()
        final = problem.score(z)
        kept = ~(final <= start.rms)  # never worse than the start (NaN-safe)
        z = np.where(kept[:, None], start.z, z)
        rms = np.where(kept, start.rms, final)
        timings["evaluate"] = time.perf_counter() - t3
    unc = None
    if uncertainty:
        t4 = time.perf_counter()
        unc = problem.uncertainty(z)
        timings["uncertainty"] = time.perf_counter() - t4
    return Outcome(z=z, rms=np.asarray(rms, float), start=start, swarm=sw, stages=tuple(stages),
                   kept_start=kept, uncertainty=unc, timings=timings)
