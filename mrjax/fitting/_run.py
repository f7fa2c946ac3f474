"""One chunk of a per-test fit: its problem, the engine, its `FitResult`."""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from ..data import Batch
from ..engine import Outcome, Polish, Swarm, settings, solve
from ..models import AbstractModel
from ..objective import nrmse
from ..parallel import unpad
from ._problem import TestsProblem, default_restarts, tests_problem
from ._result import FitResult


@dataclasses.dataclass(frozen=True)
class Run:
    """Everything a per-test fit of one chunk needs besides the data: `method`, the settings
    (`swarm`, `polish`: None where the stage does not run; `uncertainty`), `key` (one PRNG key
    or one per swarm row), `seed`, `bounds`, `transient`, `devices`, `progress`, `callback`."""

    method: str
    swarm: Swarm | None
    polish: Polish | None
    uncertainty: bool
    key: Any
    seed: int
    bounds: Any = None
    transient: Any = None
    devices: Any = None
    progress: bool | None = False
    callback: Callable | None = None

    @property
    def swarm_mode(self) -> str:
        """The swarm mode reported (`"none"` without a swarm)."""
        return self.swarm.mode if self.swarm is not None else "none"


def problem_of(model: str | AbstractModel, data: Batch, run: Run, *,
               view_length: int | None = None, checked: bool = False) -> TestsProblem:
    """The per-test problem of `run` on `data` (see `tests_problem`)."""
    return tests_problem(model, data, bounds=run.bounds, transient=run.transient,
                         swarm=run.swarm, devices=run.devices, view_length=view_length,
                         checked=checked)


def assemble(problem: TestsProblem, out: Outcome, run: Run) -> FitResult:
    """The :class:`FitResult` of an engine outcome (device padding cut off); warns for a
    condition whose force is not finite at the fitted parameters."""
    batch, mask, model = problem.batch, problem.placed_mask, problem.model
    theta, rms = out.z, out.rms
    diverged = np.flatnonzero(~np.isfinite(rms))
    if diverged.size:
        warnings.warn(
            f"condition {batch.labels[diverged[0]]!r}: the model's force is not finite at the "
            f"fitted parameters ({diverged.size} such condition(s)); its RMS is reported as inf "
            f"(null in fit.json): narrow the bounds", RuntimeWarning, stacklevel=4)
    C, P = theta.shape
    sw, unc = out.swarm, out.uncertainty
    G = run.swarm.generation_cap + 1 if sw is not None else 0
    result = FitResult(
        model=model, method=run.method, swarm_mode=run.swarm_mode, seed=run.seed,
        labels=tuple(batch.labels), current=np.asarray(batch.current, float),
        frequency=np.asarray(batch.frequency, float), amplitude=np.asarray(batch.amplitude, float),
        n_samples=np.asarray(np.asarray(mask).sum(axis=1), int), theta=theta, rms=rms,
        nrmse=nrmse(rms, batch.force, mask),
        pso_rms=out.start.rms if sw is not None else np.full(C, np.nan),
        generations=sw.generations if sw is not None else np.full(C, -1),
        stopped_by_criterion=sw.stopped_by_criterion if sw is not None else np.zeros(C, bool),
        history=sw.history if sw is not None else np.zeros((C, G)),
        polish_steps=np.asarray(out.steps, int), polish_status=out.status,
        stderr=np.full((C, P), np.nan) if unc is None else np.asarray(unc.stderr, float),
        ci95=np.full((C, P, 2), np.nan) if unc is None else np.asarray(unc.ci95, float),
        corr=np.full((C, P, P), np.nan) if unc is None else np.asarray(unc.corr, float),
        identifiable=np.ones((C, P), bool) if unc is None else np.asarray(unc.identifiable, bool),
        timings=dict(out.timings), estimated=np.asarray(batch.estimated, bool),
        bounds={"lower": np.asarray(problem.lower, float),
                "upper": np.asarray(problem.upper, float)},
    )
    return unpad(result, problem.n_real) if result.n_conditions != problem.n_real else result


def fit_chunk(model: str | AbstractModel, data: Batch, run: Run, *,
              view_length: int | None = None, checked: bool = False) -> FitResult:
    """One batch (or chunk) of conditions through the engine, each stage timed in
    `FitResult.timings` [s]."""
    t0 = time.perf_counter()
    problem = problem_of(model, data, run, view_length=view_length, checked=checked)
    t_prep = time.perf_counter() - t0
    out = solve(problem, swarm=run.swarm, polish=run.polish, uncertainty=run.uncertainty,
                key=run.key if run.key is not None else jax.random.key(run.seed),
                progress=run.progress, callback=run.callback)
    result = assemble(problem, out, run)
    timings = dict(prepare=t_prep, **result.timings, total=time.perf_counter() - t0)
    return dataclasses.replace(result, timings=timings)


def resolve_run(run: Run, model: AbstractModel, n_conditions: int) -> Run:
    """`run` with the problem's choices made for `model` on `n_conditions` tests: the swarms
    per test where `Swarm.restarts` is None (:func:`default_restarts`)."""
    sw = run.swarm
    if sw is None or sw.restarts is not None:
        return run
    sw = dataclasses.replace(sw, restarts=default_restarts(model, n_conditions))
    return dataclasses.replace(run, swarm=sw)


def wants_retry(run: Run, model: AbstractModel, n_conditions: int) -> bool:
    """Whether the fit retries every test from its neighbours' optima
    (`mrjax.Polish(retry=True)`): with a polish, at least two tests and a parameter the force
    is not linear in (a fully linear model has one optimum)."""
    return (run.polish is not None and run.polish.retry and n_conditions >= 2
            and model.nonlinear_index.size > 0)


def uncertainty_fields(problem: TestsProblem, theta: np.ndarray, n: int) -> dict[str, Any]:
    """`stderr`, `ci95`, `corr`, `identifiable` of the first `n` units of `problem` at
    `theta` (U, P) (`mrjax.refine.uncertainty`), as `FitResult` holds them."""
    unc = problem.uncertainty(theta)
    return {"stderr": np.asarray(unc.stderr, float)[:n], "ci95": np.asarray(unc.ci95, float)[:n],
            "corr": np.asarray(unc.corr, float)[:n],
            "identifiable": np.asarray(unc.identifiable, bool)[:n]}


def make_run(*, method: str, swarm: Swarm | None, polish: Polish | None, key: Any, seed: int,
             bounds: Any, transient: Any, devices: Any, progress: bool | None,
             callback: Callable | None, **keywords: Any) -> Run:
    """The :class:`Run` of `mrjax.fit`'s arguments: its keyword options mapped onto the
    settings objects (`mrjax.engine.settings`)."""
    sw, po, unc = settings(method=method, swarm=swarm, polish=polish, **keywords)
    return Run(method=method, swarm=sw, polish=po, uncertainty=unc, key=key, seed=int(seed),
               bounds=bounds, transient=transient, devices=devices, progress=progress,
               callback=callback)
