"""The posterior of a per-test fit: its plan for the engine's posterior stage (the fit's
problem rebuilt with its bounds, fixed parameters and transient) and its result,
:class:`TestPosterior`."""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

import numpy as np

from .._errors import InputError
from .._warnings import ResultWarning, WarningKind
from ..bayes import Posterior, PosteriorFront, PredictiveBand, at_bounds, predictive_band
from ..data import Batch
from ..engine import PosteriorPlan, register_posterior
from ..models import AbstractModel
from ._problem import tests_problem
from ._result import FitResult


@dataclasses.dataclass(frozen=True, eq=False)
class TestPosterior(PosteriorFront):
    """The posterior of a per-test fit: `posterior` (a :class:`mrjax.bayes.Posterior` over the
    conditions), the `model`, the `fit` it started from, and `data` (`"record"` or `"view"`,
    what the likelihood scored), `n_scored` (C,) samples it scored."""

    posterior: Posterior
    model: AbstractModel
    fit: FitResult
    data: str
    n_scored: np.ndarray

    @property
    def labels(self) -> tuple[str, ...]:
        """Condition labels."""
        return self.posterior.labels

    def to_dict(self) -> dict[str, Any]:
        """The `posterior` entry of fit.json (with `likelihood_data`)."""
        return dict(self.posterior.to_dict(), likelihood_data=self.data,
                    scored_samples=[int(n) for n in self.n_scored])

    def band(self, batch: Batch, n_draws: int, level: float, noise_draws: int,
             seed: int) -> PredictiveBand:
        """The band of `PosteriorFront.predict_band`: each record predicted with the draws of
        the condition of its label (`mrjax.bayes.predictive_band`)."""
        post = self.posterior
        total = post.n_chains * post.n_draws
        pick = np.unique(np.linspace(0, total - 1, min(n_draws, total)).round().astype(int))
        theta = post.theta.reshape(post.n_units, total, -1)[:, pick]
        sigma = post.sigma.reshape(post.n_units, total)[:, pick]
        return predictive_band(self.model, theta, sigma, self.labels, batch, level=level,
                               noise_draws=noise_draws, seed=seed)

    def __repr__(self) -> str:
        return (f"TestPosterior(model={self.model.name!r}, C={len(self.labels)}, "
                f"data={self.data!r}, {self.posterior!r})")


def _check_start(result: FitResult, lo: np.ndarray, hi: np.ndarray) -> None:
    """Warnings: a fit without polish; parameters at their bounds. An error: parameters
    outside the bounds."""
    names = result.param_names
    th = np.asarray(result.theta, float)
    tol = 1e-9 * np.maximum(hi - lo, 1e-300)
    out = (th < lo - tol) | (th > hi + tol)
    if out.any():
        i, j = np.argwhere(out)[0]
        raise InputError(f"condition {result.labels[i]!r}: {names[j]} = {th[i, j]:g} lies "
                         f"outside the bounds [{lo[j]:g}, {hi[j]:g}] of the fit")
    if result.method == "pso" or all(s == "none" for s in result.polish_status):
        warnings.warn(ResultWarning(
            WarningKind.DOUBTFUL_START, "posterior on a fit without polish: the chains start "
            "from the swarm's best, not from a least-squares optimum, and need a longer warmup",
            conditions=result.labels), stacklevel=4)
    hit = at_bounds(th, lo, hi)
    if hit.any():
        i, j = np.argwhere(hit)[0]
        warnings.warn(ResultWarning(
            WarningKind.AT_BOUND,
            f"{int(hit.sum())} parameter(s) at bounds in {int(hit.any(axis=1).sum())} "
            f"condition(s) (first: {names[j]} = {th[i, j]:g} on {result.labels[i]!r}): their "
            "posterior is cut by the bound (a prior the data did not choose)",
            conditions=[result.labels[k] for k in np.flatnonzero(hit.any(axis=1))],
            parameters=[names[k] for k in np.flatnonzero(hit.any(axis=0))]), stacklevel=4)


def posterior_plan(result: FitResult, batch: Batch, likelihood_data: str | None
                   ) -> PosteriorPlan:
    """The posterior plan of a per-test fit on its records `batch`: its problem (the fit's
    model, bounds and transient), its optimum, the view for a dynamic model by default."""
    if tuple(batch.labels) != tuple(result.labels):
        raise InputError(f"data are not the fit's conditions: {batch.n_conditions} records "
                         f"(first {batch.labels[0]!r}) for {result.n_conditions} fitted "
                         f"(first {result.labels[0]!r})")
    model = result.model
    bounds = None if result.bounds is None else (result.bounds["lower"], result.bounds["upper"])
    choice = likelihood_data or ("view" if model.dynamic else "record")
    problem = tests_problem(model, batch, bounds=bounds, transient=result.transient,
                            view=choice == "view", checked=True)
    _check_start(result, problem.lower, problem.upper)
    mask = problem.view.mask if choice == "view" else problem.mask
    n_scored = np.asarray(mask).sum(axis=1)

    def finish(post: Posterior) -> TestPosterior:
        for w in post.problems():
            warnings.warn(w, stacklevel=4)
        return TestPosterior(posterior=post, model=model, fit=result, data=choice,
                             n_scored=n_scored)

    return PosteriorPlan(problem, np.asarray(result.theta, float), choice == "view", finish)


register_posterior(FitResult, posterior_plan)
