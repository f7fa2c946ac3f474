"""The engine's last stage: the posterior of a problem's unknowns (`mrjax.posterior`).

A problem kind supplies its :class:`mrjax.bayes.Likelihood` (`AbstractProblem.likelihood`:
the residual it polishes, as blocks of records, on the records or their views); the sampler
(`mrjax.bayes.sample`: the mode, NUTS, the continuations) runs on it; a result type that can
have a posterior registers how its problem is rebuilt and its posterior presented
(:func:`register_posterior`): `mrjax.FitResult` (per-test parameters) and
`mrjax.generalize.GeneralizedModel` (laws over the current) do.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from .._errors import InputError
from ..bayes import Posterior, Sampler
from ..bayes import sample as sample_likelihood
from ..data import Batch, Condition, as_batch
from ._problem import AbstractProblem

#: What the likelihood scores: the full `record`, or the swarm's `view` of it (every k-th
#: sample of the first whole periods, `mrjax.data.swarm_view`). Default: the view for the
#: dynamic models (one sequential integration per gradient), the record for the static ones.
DATA_CHOICES: tuple[str, ...] = ("record", "view")


@dataclasses.dataclass(frozen=True, eq=False)
class PosteriorPlan:
    """How a result's posterior runs: the `problem`, the unknowns `z` (U, K) of its optimum,
    whether the likelihood scores the records' views (`on_view`), and `finish`, which turns
    the :class:`mrjax.bayes.Posterior` into the result's posterior type (and warns)."""

    problem: AbstractProblem
    z: np.ndarray
    on_view: bool
    finish: Callable[[Posterior], Any]


_PLANNERS: dict[type, tuple[Callable[..., PosteriorPlan], bool]] = {}


def register_posterior(kind: type, planner: Callable[..., PosteriorPlan], *,
                       batch: bool = True) -> None:
    """Let results of type `kind` have a posterior: `planner(result, data, likelihood_data)`
    returns their :class:`PosteriorPlan` (`likelihood_data` `"record"`, `"view"` or None for
    the default); `data` as a :class:`mrjax.data.Batch` (`batch=True`) or as the caller gave
    it (a kind whose records are not damper tests)."""
    _PLANNERS[kind] = (planner, batch)


def sample(problem: AbstractProblem, z: np.ndarray, *, on_view: bool, sampler: Sampler,
           noise: str = "iid", prior: Mapping[str, Any] | None = None, key: Any = 0,
           progress: bool | None = False) -> Posterior:
    """The posterior stage of the engine on `problem` from its optimum `z` (U, K): the
    problem's likelihood on its views (`on_view`) or records, sampled by `mrjax.bayes.sample`
    (the one call of the sampler)."""
    return sample_likelihood(problem.likelihood(np.asarray(z, float), on_view), sampler=sampler,
                             noise=noise, prior=prior, key=key, progress=progress)


def posterior(
    result: Any,
    data: Batch | Condition | Sequence[Condition] | str | os.PathLike,
    *,
    sampler: Sampler | None = None,
    noise: str = "iid",
    prior: Mapping[str, Any] | None = None,
    key: int | Any = 0,
    likelihood_data: str | None = None,
    progress: bool | None = False,
) -> Any:
    """The posterior of a fit's unknowns, by NUTS: of every test's parameters for a
    `mrjax.fit` result (a :class:`mrjax.fitting.TestPosterior`), of the laws' coefficients for
    a `mrjax.generalize.GeneralizedModel` (a :class:`mrjax.generalize.LawPosterior`).

    The chains start around the posterior's mode, found from the fit's optimum, with the
    inverse Hessian there as mass matrix; the units (tests) whose chains miss R-hat <= 1.01,
    ESS >= 400 or diverge are continued with more warmup and draws
    (`Sampler.continuations`), and what still misses is warned about.

    **Arguments:**

    - `result`: the fit (its polished optimum, bounds, fixed parameters and transient are the
        posterior's start, box and scored samples).
    - `data`: the records it was fitted on (same labels), as `mrjax.fit` takes them.
    - `sampler`: a :class:`mrjax.Sampler` (default `Sampler()`: 4 chains x (500 warmup + 1,000
        draws), its gradient and target acceptance chosen for the model's kind).
    - `noise`: `"iid"` (independent Gaussian residuals) or `"ar1"` (AR(1), rho fitted per
        unit: use it on real records, whose model error is correlated; see
        `mrjax.bayes.block_loglik`). One noise level per record.
    - `prior`: {parameter: prior}, `mrjax.bayes.Normal` / `LogNormal` / `Uniform` or text such
        as `"normal:3000:300"`; default flat on the bounds. (Laws: {node name: prior}.)
    - `key`: an integer seed or a JAX PRNG key: same key, same draws.
    - `likelihood_data`: `"record"` (every scored sample) or `"view"` (the swarm's view of
        each record). Default: the view for the dynamic models, the record for the static ones.
    - `progress`: a progress bar (None: only on a terminal).

    **Returns:** the result type's posterior (`TestPosterior`, `LawPosterior`).

    Warns (:class:`mrjax.ResultWarning`) for a fit without polish, parameters at their
    bounds, and chains that did not converge. Raises :class:`mrjax.InputError` for impossible
    settings and for data that are not the fit's records.
    """
    planner, batch = next((_PLANNERS[t] for t in type(result).__mro__ if t in _PLANNERS),
                          (None, True))
    if planner is None:
        raise InputError(f"posterior needs a mrjax.fit result (FitResult) or laws over the "
                         f"current (GeneralizedModel), got {type(result).__name__}")
    if likelihood_data is not None and likelihood_data not in DATA_CHOICES:
        raise InputError(f"likelihood_data must be one of {', '.join(DATA_CHOICES)}, got "
                         f"{likelihood_data!r}")
    if sampler is not None and not isinstance(sampler, Sampler):
        raise InputError(f"sampler must be a mrjax.Sampler, got {type(sampler).__name__}")
    plan = planner(result, as_batch(data) if batch else data, likelihood_data)
    post = sample(plan.problem, plan.z, on_view=plan.on_view, sampler=sampler or Sampler(),
                  noise=noise, prior=prior, key=key, progress=progress)
    return plan.finish(post)
