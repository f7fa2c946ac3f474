"""One chunk of a per-test fit: its problem, the engine, its `FitResult`."""

from __future__ import annotations

import dataclasses
import time
import warnings
from typing import Any

import numpy as np

from ..data import Batch
from ..engine import Chunks, Outcome, Polish, Swarm, check_settings, solve
from ..models import AbstractModel
from ..objective import nrmse
from ..parallel import unpad
from ._problem import TestsProblem, default_restarts, tests_problem
from ._result import FitResult


@dataclasses.dataclass(frozen=True)
class Run:
    """The settings of one per-test fit, resolved once from `mrjax.fit`'s arguments
    (:func:`make_run`): the stages that run (`swarm`, `polish`: None where a stage does not
    run; `swarm.restarts` resolved for the model and the number of tests), `uncertainty`
    (std-errors at the result), `seed` (recorded; None for a key given as an array), the
    problem's `bounds` and `transient`, the `chunks` (memory, journal, devices) and
    `progress`."""

    swarm: Swarm | None
    polish: Polish | None
    uncertainty: bool
    seed: int | None
    bounds: Any = None
    transient: Any = None
    chunks: Chunks = Chunks()
    progress: bool | None = False

    @property
    def method(self) -> str:
        """The stages run, as fit.json names them: `"pso+lm"`, `"pso"` or `"lm"`."""
        if self.swarm is None:
            return "lm"
        return "pso+lm" if self.polish is not None else "pso"

    @property
    def swarm_mode(self) -> str:
        """The swarm mode reported (`"none"` without a swarm)."""
        return self.swarm.mode if self.swarm is not None else "none"

    @property
    def devices(self) -> Any:
        """The devices the conditions are sharded over (None: one)."""
        return self.chunks.devices

    @property
    def retry(self) -> bool:
        """Whether the polish asks for the retry from the neighbours' optima."""
        return self.polish is not None and self.polish.retry


def problem_of(model: str | AbstractModel, data: Batch, run: Run, *, devices: Any = ...,
               view_length: int | None = None, checked: bool = False) -> TestsProblem:
    """The per-test problem of `run` on `data` (see `tests_problem`), on `run`'s devices
    unless `devices` is given (None: not placed)."""
    return tests_problem(model, data, bounds=run.bounds, transient=run.transient,
                         swarm=run.swarm, devices=run.devices if devices is ... else devices,
                         view_length=view_length, checked=checked)


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
                "upper": np.asarray(problem.upper, float)}, transient=run.transient,
    )
    return unpad(result, problem.n_real) if result.n_conditions != problem.n_real else result


def fit_chunk(model: str | AbstractModel, data: Batch, run: Run, key: Any, *,
              uncertainty: bool | None = None, view_length: int | None = None,
              checked: bool = False) -> FitResult:
    """One batch (or chunk) of conditions through the engine with the swarm rows' `key`s, each
    stage timed in `FitResult.timings` [s]; `uncertainty` overrides `run.uncertainty` (the
    chunk layer computes std-errors once, after the retry)."""
    t0 = time.perf_counter()
    problem = problem_of(model, data, run, view_length=view_length, checked=checked)
    t_prep = time.perf_counter() - t0
    out = solve(problem, swarm=run.swarm, polish=run.polish,
                uncertainty=run.uncertainty if uncertainty is None else uncertainty,
                key=key, progress=run.progress)
    result = assemble(problem, out, run)
    timings = dict(prepare=t_prep, **result.timings, total=time.perf_counter() - t0)
    return dataclasses.replace(result, timings=timings)


def wants_retry(run: Run, model: AbstractModel, n_conditions: int) -> bool:
    """Whether the fit retries every test from its neighbours' optima
    (`mrjax.Polish(retry=True)`): with a polish, at least two tests and a parameter the force
    is not linear in (a fully linear model has one optimum)."""
    return run.retry and n_conditions >= 2 and model.nonlinear_index.size > 0


def uncertainty_fields(problem: TestsProblem, theta: np.ndarray, n: int) -> dict[str, Any]:
    """`stderr`, `ci95`, `corr`, `identifiable` of the first `n` units of `problem` at
    `theta` (U, P) (`mrjax.refine.uncertainty`), as `FitResult` holds them."""
    unc = problem.uncertainty(theta)
    return {"stderr": np.asarray(unc.stderr, float)[:n], "ci95": np.asarray(unc.ci95, float)[:n],
            "corr": np.asarray(unc.corr, float)[:n],
            "identifiable": np.asarray(unc.identifiable, bool)[:n]}


def make_run(model: AbstractModel, n_conditions: int, *, swarm: Swarm | None,
             polish: Polish | None, key: Any, bounds: Any = None, transient: Any = None,
             chunks: Chunks | None = None, progress: bool | None = False) -> Run:
    """The :class:`Run` of `mrjax.fit`'s arguments for `model` on `n_conditions` tests: the
    settings objects checked, the swarms per test chosen where `Swarm.restarts` is None
    (:func:`default_restarts`). Raises :class:`mrjax.InputError` for a settings object of the
    wrong type or no stage at all."""
    swarm, polish = check_settings(swarm, polish, chunks)
    if swarm is not None and swarm.restarts is None:
        swarm = dataclasses.replace(swarm, restarts=default_restarts(model, n_conditions))
    seed = int(key) if isinstance(key, (int, np.integer)) and not isinstance(key, bool) else None
    return Run(swarm=swarm, polish=polish,
               uncertainty=polish.uncertainty if polish is not None else True, seed=seed,
               bounds=bounds, transient=transient, chunks=chunks or Chunks(), progress=progress)


def polish_fit(result: FitResult, data: Batch, *, polish: Polish = Polish(retry=False)
               ) -> FitResult:
    """`result` (e.g. a swarm-only fit, `mrjax.fit(..., polish=None)`) polished on its records
    `data` by the engine's polish stage from its parameters, in its bounds and over its scored
    samples; the swarm's figures kept, `pso_rms` the start's RMS [N]. The retry from the
    neighbours' optima does not run (see `mrjax.fit`)."""
    bounds = None if result.bounds is None else (result.bounds["lower"], result.bounds["upper"])
    run = make_run(result.model, data.n_conditions, swarm=None, polish=polish, key=0,
                   bounds=bounds, transient=result.transient)
    problem = problem_of(result.model, data, run, checked=True)
    out = solve(problem, swarm=None, polish=polish, uncertainty=polish.uncertainty,
                start=np.asarray(result.theta, float))
    fresh = assemble(problem, out, run)
    keep = ("model", "method", "swarm_mode", "seed", "generations", "stopped_by_criterion",
            "history", "timings")
    return dataclasses.replace(
        fresh, pso_rms=out.start.rms[: result.n_conditions], method="pso+lm"
        if result.method == "pso" else result.method,
        **{k: getattr(result, k) for k in keep if k not in ("method",)})
